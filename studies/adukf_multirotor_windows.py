"""Issue 26: what limits adukf on the multirotor at 400 Hz and 1 kHz (magnetometer 100 Hz, as the
per-rate tunes ran): the total RMS error in three windows of a 240 s run (the scenario's 120 s
schedule twice), seeds 0-2, float C, the site declination set as `ahrsgen bench` sets it:

- 5-15 s, the start (the bench scores from 5 s);
- 15-120 s, the rest of the first period;
- 120-240 s, the second period: the same manoeuvres with the start long gone.

    PYTHONPATH=src .venv/bin/python studies/adukf_multirotor_windows.py [adukf | qcf]

The filter is the argument (default adukf); qcf has the same accel_lp_warm (issue 26).

Rows: the defaults and the low-pass started cold (accel_lp_warm = false, before issue 26's warm
start). studies/mekf_multirotor_windows.py is the same for mekf. No BROAD files needed.

Result (2026-12-04): the gap at 1 kHz was the start. Cold low-pass (accel_lp_warm = false) 400 Hz
0.70 / 0.30 / 0.13 deg, 1 kHz 2.12 / 1.09 / 0.10; warm (the defaults since) 0.53 / 0.19 / 0.13
and 0.56 / 0.15 / 0.10: the second period is the same, the start and the rest of the first
period (the gyro bias and heading it disturbed) are what the warm start removes.

qcf (2026-12-04): cold 400 Hz 0.70 / 0.58 / 0.54, 1 kHz 0.74 / 0.54 / 0.54; warm 0.60 / 0.58 /
0.54 and 0.64 / 0.54 / 0.54: only the start moves; the QCF's multirotor error is its steady state.
"""
from __future__ import annotations

import sys

import numpy as np

from ahrsgen.bench.scoring import compare_frame, filter_estimator, score_mask
from ahrsgen.sim.metrics import broad_errors_deg
from ahrsgen.sim.scenarios import make

RATES = (400.0, 1000.0)
SEEDS = range(3)
WINDOWS = ((5.0, 15.0), (15.0, 120.0), (120.0, 241.0))
ROWS = ("", "accel_lp_warm=false")


def windows(sets: list[str], logs, filter_name: str = "adukf") -> list[float]:
    """Mean over the logs of the total RMS (deg) in each window."""
    est = filter_estimator(filter_name, sets)
    out = []
    for log in logs:
        q, frame, _ = est.run(log)
        m = score_mask(log)
        tot = np.asarray(broad_errors_deg(compare_frame(q, log, frame, m), log.q_true)[0])
        t = log.t - log.t[0]
        out.append([float(np.sqrt(np.mean(tot[m & (t >= a) & (t < b)] ** 2))) for a, b in WINDOWS])
    return list(np.mean(out, axis=0))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    filter_name = argv[0] if argv else "adukf"
    logs = {r: [make("multirotor", s, rate_hz=r, mag_rate=100.0, duration=240.0) for s in SEEDS] for r in RATES}
    print(f"{filter_name}, multirotor (magnetometer 100 Hz), total RMS in degrees, mean of seeds 0-2, windows "
          + ", ".join(f"{a:g}-{min(b, 240):g} s" for a, b in WINDOWS))
    print(f"{'setting':40s} " + " | ".join(f"{int(r)} Hz".center(20) for r in RATES))
    for row in ROWS:
        sets = row.split()
        label = row or "defaults"
        cells = [" / ".join(f"{x:.2f}" for x in windows(sets, logs[r], filter_name)) for r in RATES]
        print(f"{label:40s} " + " | ".join(c.center(20) for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
