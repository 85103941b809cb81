"""Estimators (generated filters, peers) and how they are scored against a log's reference:
site parameters from the log, the heading frame, per-angle and BROAD errors."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ahrsgen.sim import host, peers
from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.metrics import broad_errors_deg, euler_errors_deg
from ahrsgen.npquat import qmul
from ahrsgen.bench.common import ANGLES, BROAD_METRICS
from ahrsgen.bench.harness import baseline_filter


# =========================================================================================
# Estimators (generated filters, the hand-written QCF, peers) and scoring

# Site parameters (where the vehicle flies) that a user sets and the bench fills from the log:
# the filter's declination (so its heading is in the reference's north) and, for filters with a
# configured field direction, the inclination (or learning it at rest when the log has none).
DECLINATION_PARAMS = (("declination", "rad"),)   # every filter with a magnetometer names it so
_HF_CACHE: dict = {}


def site_values(filter_name: str, meta: dict, user_keys=()) -> tuple[dict, bool]:
    """Parameter values for the site of a log, and whether a declination parameter was set.

    A log's meta['declination_deg'] is the offset from its reference's north to magnetic
    north (absent: the reference is magnetic north, as BROAD's). A log that states its gyro's
    full scale (meta['gyro_full_scale_rad_s'], a simulated sensor) sets gyro_full_scale, as a
    user configures the sensor. Parameters the user set (user_keys) are left alone. Numbers
    stay numbers (config.resolve's `values`).
    """
    from ahrsgen import filters
    names = filters.load(filter_name).params
    out, applied = {}, False
    decl = float(meta.get("declination_deg", 0.0) or 0.0)
    for pname, unit in DECLINATION_PARAMS:
        if pname in names and pname not in user_keys:
            out[pname] = decl if unit == "deg" else math.radians(decl)
            applied = True
        elif pname in names:
            applied = True
    if "inclination_deg" in names and "inclination_deg" not in user_keys:
        if meta.get("inclination_deg") is not None:
            out["inclination_deg"] = float(meta["inclination_deg"])
            if "mag_ref" in names and "mag_ref" not in user_keys:      # the default learns it instead
                out["mag_ref"] = "inclination"
        elif "mag_ref" in names and "mag_ref" not in user_keys:
            out["mag_ref"] = "learn"
    fs = meta.get("gyro_full_scale_rad_s")
    if fs is not None and "gyro_full_scale" in names and "gyro_full_scale" not in user_keys:
        out["gyro_full_scale"] = float(fs)
    return out, applied


def site_sets(filter_name: str, meta: dict, user_keys=()) -> tuple[list[str], bool]:
    """site_values as --set strings (what a user would type; shown in reports and JSON)."""
    values, applied = site_values(filter_name, meta, user_keys)
    return [f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items()], applied


class StatusTally:
    """How many steps set each status bit (and any refusal bit, any bit): what the run's report
    and refusal_hint need of a log's statuses, summed a chunk at a time."""

    def __init__(self, status=None, fault_mask: int = 0):
        self.n = self.nonzero = self.refused = self.faults = 0
        self.fault_mask = int(fault_mask)
        self.bits = [0] * 32
        if status is not None:
            self.add(status)

    def add(self, status: np.ndarray) -> None:
        from ahrsgen import status as st
        status = np.asarray(status, dtype=np.uint32)
        self.n += len(status)
        self.nonzero += int(np.count_nonzero(status))
        self.refused += int(np.count_nonzero(status & np.uint32(st.REFUSED_MASK)))
        self.faults += int(np.count_nonzero(status & np.uint32(self.fault_mask)))
        seen = int(np.bitwise_or.reduce(status)) if len(status) else 0
        for b in range(32):
            if seen >> b & 1:
                self.bits[b] += int(np.count_nonzero(status & np.uint32(1 << b)))

    def count(self, mask: int) -> int:
        """Steps with any bit of `mask` set (one bit, REFUSED_MASK, the tally's fault_mask, or 0
        for any bit)."""
        from ahrsgen import status as st
        if mask == 0:
            return self.nonzero
        if mask == self.fault_mask:
            return self.faults
        if mask == st.REFUSED_MASK:
            return self.refused
        if mask & (mask - 1):
            raise ValueError(f"StatusTally counts single bits, REFUSED_MASK and 0, not {mask:#x}")
        return self.bits[mask.bit_length() - 1]


def refusal_hint(status, log, params: dict) -> str:
    """One line on why most of a log's steps were refused, when they were: the usual causes are a
    time column not in seconds or a gyro not in rad/s. `status`: the steps' statuses or their
    StatusTally; the median dt is log.t's (of a log read in chunks: its first chunk's)."""
    from ahrsgen import status as st
    tally = status if isinstance(status, StatusTally) else StatusTally(status)
    n = tally.n
    if n == 0 or tally.count(st.REFUSED_MASK) * 2 < n:
        return ""
    dt = np.diff(log.t)
    med = float(np.median(dt)) if len(dt) else float("nan")
    if tally.count(st.DT_TOO_LARGE) * 2 >= n:
        dt_max = params.get('dt_max', float('nan'))
        if med > 1.0:                # no IMU samples at less than 1 Hz: the unit of t
            return (f"most steps were refused for dt above dt_max = {dt_max:g} s; "
                    f"the log's median dt is {med:.3g} s: is its time column t in seconds (not ms or us)?")
        return (f"most steps were refused for dt above dt_max = {dt_max:g} s, below the log's median dt "
                f"{med:.3g} s: set dt_max above the sample period")
    if tally.count(st.GYRO_RANGE) * 2 >= n:
        return (f"most steps were refused for a gyro component beyond gyro_max = "
                f"{params.get('gyro_max', float('nan')):g} rad/s: is the gyro in rad/s (not deg/s)?")
    if tally.count(st.GYRO_NONFINITE) * 2 >= n:
        return "most steps were refused for a gyro sample that is not finite (NaN or Inf): check the gyro columns"
    if tally.count(st.GYRO_MISSING) * 2 >= n:
        return ("most steps were refused for a missing gyro sample (empty or NaN fields): does the log hold the "
                "gyro on every row?")
    if tally.count(st.DT_INVALID) * 2 >= n:
        return "most steps were refused for a dt that is not finite or not positive: check the time column t"
    return ""


REFUSED_FAILURE = 0.5      # a run that refused more than this fraction of its steps is a failure


class MostlyRefused(RuntimeError):
    """A filter refused most steps of a log: it never really ran, so there is nothing to score."""


def refusal_failure(status, log, params: dict, what: str = "the filter") -> str:
    """One line when `what` refused more than REFUSED_FAILURE of the log's steps (a failed run:
    no score, exit 1), else "". `status`: the statuses or their StatusTally."""
    from ahrsgen import status as st
    tally = status if isinstance(status, StatusTally) else StatusTally(status)
    n = tally.n
    refused = tally.count(st.REFUSED_MASK)
    if n == 0 or refused <= REFUSED_FAILURE * n:
        return ""
    why = refusal_hint(tally, log, params) or "see the status bits (docs/log-format.md)"
    return f"{what} refused {refused} of {n} steps of {log.name}, so it did not run: {why}"


@dataclass
class Estimator:
    name: str
    kind: str                 # "filter" | "baseline" | "peer"
    heading: str              # "mag" (magnetic north) | "true" (GPS course) | "none"
    title: str = ""
    filter: str = ""          # product filter name
    sets: list = field(default_factory=list)
    config: str | None = None
    site: bool = True         # fill site parameters (declination, inclination) from the log
    runtime: dict = field(default_factory=dict)   # runtime-parameter values, set in C per run

    def host_filter(self, extra_sets=()):
        key = (self.kind, self.filter, self.config, tuple(self.sets) + tuple(extra_sets), tuple(sorted(self.runtime)))
        if key not in _HF_CACHE:
            import fcntl
            host.CACHE.mkdir(parents=True, exist_ok=True)
            # bench workers may build the same configuration at once: one at a time
            with open(host.CACHE / ".bench-build.lock", "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)
                try:
                    if self.kind == "baseline":
                        _HF_CACHE[key] = baseline_filter()
                    else:
                        from ahrsgen.generate import config
                        cfg = config.resolve(self.filter, self.config, list(self.sets) + list(extra_sets),
                                             "float", None, runtime=sorted(self.runtime))
                        _HF_CACHE[key] = host.build(cfg)
                finally:
                    fcntl.flock(lock, fcntl.LOCK_UN)
        return _HF_CACHE[key]

    def run(self, log: SensorLog) -> tuple[np.ndarray, str, list]:
        """(q, heading frame of q for scoring, site --set strings used)."""
        if self.kind == "peer":
            return peers.run(self.name, log), self.heading, []
        extra, applied = [], False
        if self.kind == "filter" and self.site:
            from ahrsgen.generate import config
            user = config.resolve(self.filter, self.config, list(self.sets), "float", None).overrides
            extra, applied = site_sets(self.filter, log.meta, set(user) | set(self.runtime))
        heading = "true" if (self.heading == "mag" and applied) else self.heading
        hf = self.host_filter(extra)
        res = hf.run(log, params=self.runtime)
        if self.kind == "filter":
            failed = refusal_failure(res.status, log, {**hf.manifest.get("params", {}), **self.runtime}, self.name)
            if failed:
                raise MostlyRefused(failed)
        return res.q, heading, extra


def filter_heading(filter_name: str, sets=(), config_file=None, preset=None) -> str:
    from ahrsgen.generate import config
    cfg = config.resolve(filter_name, config_file, list(sets), "float", None, preset)
    sensors = cfg.spec.model(cfg.params).sensors
    if "mag" in sensors:
        return "mag"
    if "gps" in sensors:
        return "true"
    return "none"


def product_filters() -> list[str]:
    from ahrsgen import filters
    return filters.names()


def filter_estimator(name: str, sets=(), config_file=None, label: str | None = None) -> Estimator:
    from ahrsgen import filters
    return Estimator(label or name, "filter", filter_heading(name, sets, config_file),
                     filters.load(name).title, name, list(sets), config_file)


def peer_estimator(name: str) -> Estimator:
    cls = peers.PEERS[name]
    return Estimator(name, "peer", "mag" if cls.uses_mag else "none", cls.title)


def _rotz(angle_rad):
    return np.array([math.cos(angle_rad / 2), 0.0, 0.0, math.sin(angle_rad / 2)])


def score_mask(log: SensorLog) -> np.ndarray:
    """Rows that count: BROAD's movement phase where given, else after settle time; finite reference."""
    mv = log.meta.get("movement")
    mask = np.asarray(mv, dtype=bool).copy() if mv is not None else (log.t >= log.t[0] + log.settle_time)
    return mask & np.all(np.isfinite(log.q_true), axis=1)


def compare_frame(q_est: np.ndarray, log: SensorLog, heading: str, mask=None) -> np.ndarray:
    """The estimate in the reference's heading frame (see module docstring)."""
    q_est = np.asarray(q_est, dtype=float)
    if heading == "mag":
        decl = math.radians(float(log.meta.get("declination_deg", 0.0) or 0.0))
        return qmul(_rotz(decl), q_est) if decl else q_est
    if heading == "none":
        return peers.remove_heading_offset(q_est, log.q_true, score_mask(log) if mask is None else mask)
    return q_est


def score(q_est: np.ndarray, log: SensorLog, heading: str) -> dict:
    """RMS / mean |e| per Euler angle and BROAD's total / heading / inclination RMS (degrees)."""
    mask = score_mask(log)
    if not mask.any():
        raise ValueError(f"log {log.name!r}: no rows to score")
    sums = ScoreSums()
    sums.add(compare_frame(q_est, log, heading, mask)[mask], log.q_true[mask])
    return sums.result()


class ScoreSums:
    """score()'s figures as sums over rows, so a log scored a chunk at a time gets the whole
    log's figures: each RMS is sqrt(sum of squares / n), each mean |e| sum / n. One add() of
    all rows is score() exactly (np.mean is np.sum / n); chunk sums add up to the whole log's
    in another order, which changes a figure by a few units of 1e-16 relative."""

    def __init__(self):
        self.n = self.nonfinite = 0
        self.sq = {f"{a}_rms": 0.0 for a in ANGLES} | {f"{m}_rms": 0.0 for m in BROAD_METRICS}
        self.ab = {f"{a}_mean_abs": 0.0 for a in ANGLES}

    def add(self, q: np.ndarray, ref: np.ndarray) -> None:
        """Rows to score: the estimate in the reference's heading frame (compare_frame) and the reference."""
        if not len(q):
            return
        ok = np.all(np.isfinite(q), axis=1)
        self.n += len(q)
        self.nonfinite += int((~ok).sum())
        # a diverged (non-finite) estimate scores 180° on every measure rather than vanishing
        e = np.full((len(q), 3), 180.0)
        e[ok] = euler_errors_deg(q[ok], ref[ok])
        for i, a in enumerate(ANGLES):
            self.sq[f"{a}_rms"] += float(np.sum(e[:, i] ** 2))
            self.ab[f"{a}_mean_abs"] += float(np.sum(np.abs(e[:, i])))
        dec = np.full((3, len(q)), 180.0)
        if ok.any():
            dec[:, ok] = np.array(broad_errors_deg(q[ok], ref[ok]))
        for name, v in zip(BROAD_METRICS, dec):
            self.sq[f"{name}_rms"] += float(np.sum(v ** 2))

    def result(self) -> dict:
        out = {"n": self.n, "nonfinite": self.nonfinite}
        for a in ANGLES:
            out[f"{a}_rms"] = float(np.sqrt(self.sq[f"{a}_rms"] / self.n))
            out[f"{a}_mean_abs"] = float(self.ab[f"{a}_mean_abs"] / self.n)
        for name in BROAD_METRICS:
            out[f"{name}_rms"] = float(np.sqrt(self.sq[f"{name}_rms"] / self.n))
        return out


def total_error_series(q_est, log, heading, max_points=2000):
    """(t, total error in degrees) downsampled for plots; NaN where no reference."""
    q = compare_frame(q_est, log, heading)
    tot = np.full(len(log), np.nan)
    ok = np.all(np.isfinite(log.q_true), axis=1) & np.all(np.isfinite(q), axis=1)
    tot[ok] = broad_errors_deg(q[ok], log.q_true[ok])[0]
    step = max(1, len(log) // max_points)
    return log.t[::step] - log.t[0], tot[::step]


