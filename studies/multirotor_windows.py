"""The multirotor's error by time window (start, first period, second period): whether a filter's
rate gap on the multirotor (issue 26) is its start-up or its steady state. Shared by
studies/mekf_multirotor_windows.py and studies/adukf_multirotor_windows.py (also qcf), which
say what they found."""
from __future__ import annotations

import numpy as np

from ahrsgen.bench.scoring import compare_frame, filter_estimator, score_mask
from ahrsgen.sim.metrics import broad_errors_deg
from ahrsgen.sim.scenarios import make

RATES = (400.0, 1000.0)
SEEDS = range(3)
WINDOWS = ((5.0, 15.0), (15.0, 120.0), (120.0, 241.0))


def windows(sets: list[str], logs, filter_name: str) -> list[float]:
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


def report(filter_name: str, rows, labels: dict | None = None) -> int:
    """Print one line per row of settings ("" = the defaults): the windows' RMS at each rate
    (multirotor, 240 s, magnetometer 100 Hz, seeds 0-2)."""
    logs = {r: [make("multirotor", s, rate_hz=r, mag_rate=100.0, duration=240.0) for s in SEEDS] for r in RATES}
    print(f"{filter_name}, multirotor (magnetometer 100 Hz), total RMS in degrees, mean of seeds 0-2, windows "
          + ", ".join(f"{a:g}-{min(b, 240):g} s" for a, b in WINDOWS))
    print(f"{'setting':40s} " + " | ".join(f"{int(r)} Hz".center(20) for r in RATES))
    for row in rows:
        label = (labels or {}).get(row) or row or "defaults"
        cells = [" / ".join(f"{x:.2f}" for x in windows(row.split(), logs[r], filter_name)) for r in RATES]
        print(f"{label:40s} " + " | ".join(c.center(20) for c in cells), flush=True)
    return 0
