"""`ahrsgen run` and `ahrsgen bench`: which filter to fly, with which gains, at what cost.

- The firmware-like harness: every generated filter runs as float C through
  src/ahrsgen/sim/c/batch.c (ctypes, host.py) or through the standalone executable built from
  src/ahrsgen/sim/c/main_log.c (reads a harness log, takes dt from the timestamps, sets a valid
  bit only for the sensors that delivered a sample). Both give the same numbers.
- Scoring: per-angle RMS and mean |error| (roll, pitch, yaw, wrapped) and BROAD's
  total / heading / inclination RMS, over the scored rows: meta['movement'] where the log
  has it (BROAD's method), else after meta['settle_time']; rows without a finite reference
  are left out. Heading: the site parameters of each generated filter (declination, and
  inclination or learning it at rest where the filter has them) are set from the log, as a
  user sets them for where they fly (`site_sets`), so its heading is in the reference's north;
  a peer (no declination setting) has its estimate rotated by the log's declination
  (meta['declination_deg']; BROAD's reference is magnetic north, so 0); filters with no
  heading source have one constant heading offset removed (BROAD's rule for 6D filters).
- Peers (src/ahrsgen/sim/peers.py) run on the same logs.
- Cost: op counts per step from each filter's manifest, state size, ns per step measured
  inside C (thread CPU time, median of interleaved rounds) beside the hand-written QCF
  (src/ahrsgen/sim/c/baseline_qcf.c).
"""
from __future__ import annotations

from ahrsgen.bench.common import ANGLES, BROAD_METRICS, C_DIR, PEER_NAMES, REPO  # noqa: F401
from ahrsgen.bench.harness import (  # noqa: F401
    HARNESS_COLUMNS, baseline_filter, build_log_runner, run_log_exe, write_harness_log)
from ahrsgen.bench.scoring import (  # noqa: F401
    DECLINATION_PARAMS, Estimator, compare_frame, filter_estimator, filter_heading, peer_estimator,
    product_filters, score, score_mask, site_sets, site_values, total_error_series)
from ahrsgen.bench.run import continuous_yaw_deg, refusal_hint, run_on_log  # noqa: F401
from ahrsgen.bench.grid import (  # noqa: F401
    HAND_QCF_SETS, Progress, bench, measure_cost, scenario_configs)
from ahrsgen.bench.report import markdown  # noqa: F401
