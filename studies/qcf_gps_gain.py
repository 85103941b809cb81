"""Issue 26: QCF's GPS linear-acceleration compensation (motion_accel_model = 'gps_lowpass') and
its gain kp_gps, on the scenarios with GPS (BROAD has none: neither changes a BROAD figure).

    .venv/bin/python studies/qcf_gps_gain.py

Prints, per candidate, the mean total RMS (degrees, float C, seeds 0-2, scored as `ahrsgen bench`)
of fixedwing_gps at 12.5 and 100 Hz and the multirotor at 250 Hz, 400 Hz and 1 kHz, and their
mean: the centripetal term before (kp used with GPS too), then 'gps_lowpass' over a kp_gps grid.
The default kp_gps is the grid's best mean.
"""
from __future__ import annotations

import sys

import numpy as np

from ahrsgen.bench.scoring import filter_estimator, score
from ahrsgen.sim.scenarios import make

SEEDS = range(3)
SCENARIOS = {"fixedwing_gps": ("fixedwing_gps", {}), "fixedwing_gps_100hz": ("fixedwing_gps", {"rate_hz": 100.0}),
             "multirotor": ("multirotor", {}), "multirotor_400hz": ("multirotor", {"rate_hz": 400.0}),
             "multirotor_1khz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0})}
CANDIDATES = [["motion_accel_model=centripetal"]] + [
    ["motion_accel_model=gps_lowpass", f"kp_gps={k}"] for k in (0.25, 0.5, 0.7, 1.0, 1.4, 2.0, 3.0)]


def main() -> int:
    logs = {k: [make(n, s, **o) for s in SEEDS] for k, (n, o) in SCENARIOS.items()}
    print("| settings | " + " | ".join(SCENARIOS) + " | mean |")
    print("|---|" + "---|" * (len(SCENARIOS) + 1))
    for sets in CANDIDATES:
        est = filter_estimator("qcf", sets)
        res = []
        for ls in logs.values():
            runs = [(est.run(log), log) for log in ls]
            res.append(float(np.mean([score(r[0], log, r[1])["total_rms"] for r, log in runs])))
        print(f"| {', '.join(sets)} | " + " | ".join(f"{v:.3f}" for v in res) + f" | {np.mean(res):.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
