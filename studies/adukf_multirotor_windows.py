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

from multirotor_windows import report

ROWS = ("", "accel_lp_warm=false")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    return report(argv[0] if argv else "adukf", ROWS)


if __name__ == "__main__":
    sys.exit(main())
