"""Float vs double for a filter that draws random numbers (a particle filter), as estimators.

Why not sample by sample: the float and the double build of a particle filter draw the same
random numbers, but the first resampling decision that float rounding flips (a particle whose
cumulative weight lands on the other side of a systematic-resampling threshold) sends the two
runs down different, equally valid paths; after that their attitudes differ by the particle
cloud's own spread, not by rounding. A per-sample bound would then measure particle noise, and
widening it until it passes would prove nothing.

What is sound instead (`float_vs_double`):
1. The double build is checked sample by sample against the NumPy reference elsewhere (`ahrsgen
   validate` does it at 1e-9 rad, resampling decisions included), so the double build *is* the
   reference's estimator, and it is cheap to run many times.
2. Float and double are run over the same log with K particle-noise streams (the PRNG state
   seeded 1..K in both, through the model's `random_state(stream)`); each run gives an RMS error
   per angle against the truth. Each pair shares its stream, so the paired differences
   d_i = RMS_float,i - RMS_double,i cancel most of the log's and the stream's effect.
3. A float build that computes the same estimator has E[d] = 0. The paired t statistic
   t = mean(d) / (sd(d) / sqrt(K)) is compared with Student's t at 99.9 % two-sided (K = 10,
   9 degrees of freedom: 4.781); a systematic float error (a wrong float literal, a function
   evaluated in the wrong precision) shifts mean(d) and fails. A mean difference below 0.001 deg
   (float rounding of the attitude itself, ~1e-5 rad) passes whatever its t: when the runs never
   part ways, sd(d) is rounding noise and t would be meaningless.
Power, measured (tests/filters/cpf/test_cpf.py): a float build whose process noise is 2x the double's fails on
the turntable (t 5.9 to 14) and 1.2x fails on fixedwing_gps (t up to 25); a 10 % change of tau
passes (|t| < 2): differences smaller than the particle noise between streams are not seen.

The same judgement serves a deterministic filter whose float run parts from the double one by
more than rounding, declared by its author (`[filter] rounding_sensitive`, e.g. Madgwick's fixed
size steps along the normalised gradient, which chatter about the equilibrium, so that rounding
picks another direction): there the K pairs are K seeds of the scenario instead of K noise
streams (`float_vs_double_seeds`); each pair runs float and double on the same log. Power,
measured (tests/filters/test_examples.py): a float Madgwick whose beta is 1.05x the double's fails
(|t| 26 on roll over 120 s of fixedwing_gps; the true float build: |t| <= 0.9).
"""
from __future__ import annotations

import math

import numpy as np

from ahrsgen.sim.metrics import euler_stats

STREAMS = 10
T_CRIT = 4.781            # Student's t, 9 degrees of freedom, 0.9995 quantile (99.9 % two-sided)
FLOOR_DEG = 1e-3         # deg
ANGLES = ("roll", "pitch", "yaw")


def run_stream(hf, log, model, stream: int):
    """One run of a host build with the PRNG state of `stream` (model.random_state)."""
    s = hf.new_state()
    for name, values in model.random_state(stream).items():
        arr = getattr(s, name)
        for i, v in enumerate(values):
            arr[i] = v
    return hf.run(log, state=s)


def float_vs_double(hf_float, hf_double, log, model, streams: int = STREAMS) -> dict:
    """Paired comparison of float and double accuracy over `streams` particle-noise streams."""
    if streams != STREAMS:
        raise ValueError(f"the critical value is tabulated for {STREAMS} streams")
    return _paired((run_stream(hf_float, log, model, k).q, run_stream(hf_double, log, model, k).q, log)
                   for k in range(1, streams + 1))


def float_vs_double_seeds(hf_float, hf_double, logs) -> dict:
    """Paired comparison of float and double accuracy over STREAMS logs (seeds of a scenario)."""
    logs = list(logs)
    if len(logs) != STREAMS:
        raise ValueError(f"the critical value is tabulated for {STREAMS} logs")
    return _paired((hf_float.run(lg).q, hf_double.run(lg).q, lg) for lg in logs)


def _paired(runs) -> dict:
    """The paired t test above on (float q, double q, log) runs, RMS per angle vs the log's truth."""
    rms = {"float": {a: [] for a in ANGLES}, "double": {a: [] for a in ANGLES}}
    n = 0
    for q_float, q_double, log in runs:
        n += 1
        for label, q in (("float", q_float), ("double", q_double)):
            st = euler_stats(q, log.q_true, log.t, log.settle_time)
            for a in ANGLES:
                rms[label][a].append(st[a]["rms"])
    out = {"streams": n, "t_crit": T_CRIT, "floor_deg": FLOOR_DEG, "angles": {}}
    ok = True
    for a in ANGLES:
        f, d = np.array(rms["float"][a]), np.array(rms["double"][a])
        diff = f - d
        sd = float(np.std(diff, ddof=1))
        mean = float(np.mean(diff))
        t = mean / (sd / math.sqrt(n)) if sd > 0 else (0.0 if mean == 0 else math.inf)
        passed = abs(mean) <= FLOOR_DEG or abs(t) <= T_CRIT
        ok &= passed
        out["angles"][a] = {"float_mean": float(f.mean()), "double_mean": float(d.mean()),
                            "double_sd": float(d.std(ddof=1)), "diff_mean": mean, "diff_sd": sd,
                            "t": t, "ok": bool(passed)}
    out["ok"] = bool(ok)
    return out
