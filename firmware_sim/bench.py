"""`ahrsgen run` and `ahrsgen bench`: which filter to fly, with which gains, at what cost.

- The firmware-like harness: every generated filter runs as float C through
  firmware_sim/c/batch.c (ctypes, host.py) or through the standalone executable built from
  firmware_sim/c/main_log.c (reads a harness log, takes dt from the timestamps, sets a valid
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
- Peers (firmware_sim/peers.py) run on the same logs.
- Cost: op counts per step from each filter's manifest, state size, ns per step measured
  inside C (thread CPU time, median of interleaved rounds) beside the hand-written QCF
  (firmware_sim/c/baseline_qcf.c).
"""
from __future__ import annotations

import ctypes
import hashlib
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from firmware_sim import host, peers, readers
from generator import config
from firmware_sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog
from firmware_sim.metrics import broad_errors_deg, euler_errors_deg
from generator.npquat import euler_from_q, qmul

HERE = Path(__file__).resolve().parent
C_DIR = HERE / "c"
REPO = HERE.parent

PEER_NAMES = ("vqf", "fusion", "madgwick", "mahony")
ANGLES = ("roll", "pitch", "yaw")
BROAD_METRICS = ("total", "heading", "inclination")


# =========================================================================================
# Harness: the standalone executable and the hand-written baseline

HARNESS_COLUMNS = "t,gx,gy,gz,ax,ay,az,mx,my,mz,vn,ve,vd"


def write_harness_log(log: SensorLog, path: str | Path) -> Path:
    """Write a SensorLog as the text log main_log.c reads (empty fields: no sample)."""
    path = Path(path)
    groups = ((VALID_GYRO, log.gyro), (VALID_ACCEL, log.accel), (VALID_MAG, log.mag), (VALID_GPS, log.gps_vel))
    from generator.fileio import write_text_atomic
    lines = ["# ahrsgen harness log v1", f"# dt0 {float(log.dt[0])!r}", HARNESS_COLUMNS]
    for k in range(len(log)):
        v = int(log.valid[k])
        parts = [repr(float(log.t[k]))]
        for bit, arr in groups:
            if v & bit:
                parts.extend(repr(float(x)) for x in arr[k])
            else:
                parts.extend(("", "", ""))
        lines.append(",".join(parts))
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def build_log_runner(gen_dir: str | Path) -> Path:
    """Compile main_log.c with a generated filter into a cached executable."""
    gen_dir = Path(gen_dir)
    man = json.loads((gen_dir / "manifest.json").read_text())
    prefix, real = man["prefix"], man["precision"]
    sources = [C_DIR / "main_log.c", gen_dir / man["files"]["source"]]
    defines = [f"-DAHRS_PREFIX={prefix}", f'-DAHRS_HEADER="{man["files"]["header"]}"', f"-DAHRS_REAL={real}"]
    flags = host.STRICT + ["-O2", "-ffp-contract=off", "-fno-math-errno"]
    h = hashlib.sha256()
    for p in sources + [gen_dir / man["files"]["header"]]:
        h.update(p.read_bytes())
    h.update(" ".join(flags + defines).encode())
    h.update(host._compiler_id().encode())
    out_dir = host.CACHE / ("exe-" + h.hexdigest()[:20])
    exe = out_dir / f"{prefix}_log"
    if exe.exists():
        return exe
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir))
    cmd = [host.cc(), *flags, *defines, f"-I{gen_dir}", "-o", str(tmp / exe.name), *map(str, sources), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        raise host.BuildError(f"building the log runner failed:\n{' '.join(cmd)}\n{r.stderr}")
    os.replace(tmp / exe.name, exe)
    shutil.rmtree(tmp, ignore_errors=True)
    return exe


def run_log_exe(exe: str | Path, log: SensorLog) -> tuple[host.RunResult, str]:
    """Run the standalone executable over a log; (result, its stderr summary)."""
    with tempfile.TemporaryDirectory() as d:
        lp = write_harness_log(log, Path(d) / "log.csv")
        op = Path(d) / "out.csv"
        r = subprocess.run([str(exe), str(lp), str(op)], capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"{exe} failed ({r.returncode}): {r.stderr}")
        data = np.loadtxt(op, delimiter=",", skiprows=1, ndmin=2)
    return host.RunResult(data[:, 1:5], data[:, 5:8], data[:, 8].astype(np.uint32)), r.stderr.strip()


BASELINE_STATE = [("q", "real", 4), ("gyro_bias", "real", 3), ("gps_vel_hist", "real", 21),
                  ("motion_accel", "real", 3), ("gps_age", "real", 1), ("gps_count", "uint32", 1),
                  ("initialised", "uint32", 1)]
BASELINE_INPUT = [("gyro", "real", 3), ("accel", "real", 3), ("mag", "real", 3),
                  ("gps_vel_ned", "real", 3), ("valid", "uint32", 1)]


def _layout(fields):
    out, off = [], 0
    for name, typ, count in fields:
        out.append({"name": name, "type": typ, "count": count, "offset": off})
        off += 4 * count
    return {"size": off, "fields": out}


def baseline_filter() -> host.HostFilter:
    """The hand-written QCF (float) loaded through the same batch harness as generated code."""
    src = [C_DIR / "baseline_qcf.c", C_DIR / "baseline_qcf.h"]
    h = hashlib.sha256(b"".join(p.read_bytes() for p in src)).hexdigest()[:16]
    d = host.CACHE / f"baseline-{h}"
    if not (d / "manifest.json").exists():
        d.mkdir(parents=True, exist_ok=True)
        for p in src:
            shutil.copy(p, d / p.name)
        man = {"prefix": "baseline_qcf", "precision": "float", "filter": "baseline_qcf",
               "files": {"header": "baseline_qcf.h", "source": "baseline_qcf.c"},
               "structs": {"state": _layout(BASELINE_STATE), "input": _layout(BASELINE_INPUT)}}
        tmp = d / "manifest.json.tmp"
        tmp.write_text(json.dumps(man, indent=1))
        os.replace(tmp, d / "manifest.json")
    return host.HostFilter(d)


# =========================================================================================
# Estimators (generated filters, the hand-written QCF, peers) and scoring

# Site parameters (where the vehicle flies) that a user sets and the bench fills from the log:
# the filter's declination (so its heading is in the reference's north) and, for filters with a
# configured field direction, the inclination (or learning it at rest when the log has none).
DECLINATION_PARAMS = (("declination", "rad"),)   # every filter with a magnetometer names it so
_HF_CACHE: dict = {}


def site_sets(filter_name: str, meta: dict, user_keys=()) -> tuple[list[str], bool]:
    """--set strings for the site of a log, and whether a declination parameter was set.

    A log's meta['declination_deg'] is the offset from its reference's north to magnetic
    north (absent: the reference is magnetic north, as BROAD's). Parameters the user set
    (user_keys) are left alone.
    """
    from generator import filters
    names = filters.load(filter_name).params
    out, applied = [], False
    decl = float(meta.get("declination_deg", 0.0) or 0.0)
    for pname, unit in DECLINATION_PARAMS:
        if pname in names and pname not in user_keys:
            out.append(f"{pname}={decl if unit == 'deg' else math.radians(decl)!r}")
            applied = True
        elif pname in names:
            applied = True
    if "inclination_deg" in names and "inclination_deg" not in user_keys:
        if meta.get("inclination_deg") is not None:
            out.append(f"inclination_deg={float(meta['inclination_deg'])!r}")
        elif "mag_ref" in names and "mag_ref" not in user_keys:
            out.append("mag_ref=learn")
    return out, applied


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
                        from generator import config
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
            from generator import config
            user = config.resolve(self.filter, self.config, list(self.sets), "float", None).overrides
            extra, applied = site_sets(self.filter, log.meta, set(user) | set(self.runtime))
        heading = "true" if (self.heading == "mag" and applied) else self.heading
        return self.host_filter(extra).run(log, params=self.runtime).q, heading, extra


def filter_heading(filter_name: str, sets=(), config_file=None, preset=None) -> str:
    from generator import config
    cfg = config.resolve(filter_name, config_file, list(sets), "float", None, preset)
    sensors = cfg.spec.model(cfg.params).sensors
    if "mag" in sensors:
        return "mag"
    if "gps" in sensors:
        return "true"
    return "none"


def product_filters() -> list[str]:
    from generator import filters
    return filters.names()


def filter_estimator(name: str, sets=(), config_file=None, label: str | None = None) -> Estimator:
    from generator import filters
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
    q = compare_frame(q_est, log, heading, mask)[mask]
    ref = log.q_true[mask]
    ok = np.all(np.isfinite(q), axis=1)
    out = {"n": int(mask.sum()), "nonfinite": int((~ok).sum())}
    # a diverged (non-finite) estimate scores 180° on every measure rather than vanishing
    e = np.full((len(q), 3), 180.0)
    e[ok] = euler_errors_deg(q[ok], ref[ok])
    for i, a in enumerate(ANGLES):
        out[f"{a}_rms"] = float(np.sqrt(np.mean(e[:, i] ** 2)))
        out[f"{a}_mean_abs"] = float(np.mean(np.abs(e[:, i])))
    dec = np.full((3, len(q)), 180.0)
    if ok.any():
        dec[:, ok] = np.array(broad_errors_deg(q[ok], ref[ok]))
    for name, v in zip(BROAD_METRICS, dec):
        out[f"{name}_rms"] = float(np.sqrt(np.mean(v ** 2)))
    return out


def total_error_series(q_est, log, heading, max_points=2000):
    """(t, total error in degrees) downsampled for plots; NaN where no reference."""
    q = compare_frame(q_est, log, heading)
    tot = np.full(len(log), np.nan)
    ok = np.all(np.isfinite(log.q_true), axis=1) & np.all(np.isfinite(q), axis=1)
    tot[ok] = broad_errors_deg(q[ok], log.q_true[ok])[0]
    step = max(1, len(log) // max_points)
    return log.t[::step] - log.t[0], tot[::step]


# =========================================================================================
# ahrsgen run

def refusal_hint(status: np.ndarray, log, params: dict) -> str:
    """One line on why most of a log's steps were refused, when they were: the usual causes are a
    time column not in seconds or a gyro not in rad/s."""
    from generator import status as st
    n = len(status)
    if n == 0 or np.count_nonzero(status & st.REFUSED_MASK) * 2 < n:
        return ""
    dt = np.diff(log.t)
    med = float(np.median(dt)) if len(dt) else float("nan")
    if np.count_nonzero(status & st.DT_TOO_LARGE) * 2 >= n:
        return (f"most steps were refused for dt above dt_max = {params.get('dt_max', float('nan')):g} s; "
                f"the log's median dt is {med:.3g} s: is its time column t in seconds?")
    if np.count_nonzero(status & st.GYRO_RANGE) * 2 >= n:
        return (f"most steps were refused for a gyro component beyond gyro_max = "
                f"{params.get('gyro_max', float('nan')):g} rad/s: is the gyro in rad/s (not deg/s)?")
    return ""


def run_on_log(filter_name: str, log_path: str, config_file=None, sets=(), precision="float",
               plot=None, csv=None, exe=False, out=None, runtime=None, preset=None, log=None) -> dict:
    """Run one generated filter over a log file; score it where the log has a reference.
    runtime: parameters built as runtime parameters (their values set through set_params)."""
    from generator import config
    out = out or sys.stdout
    log = readers.read_log(log_path) if log is None else log
    user = config.resolve(filter_name, config_file, list(sets), precision, None, preset).overrides
    extra, applied = site_sets(filter_name, log.meta, set(user))
    cfg = config.resolve(filter_name, config_file, list(sets) + extra, precision, None, preset, runtime=runtime)
    hf = host.build(cfg)
    heading = filter_heading(filter_name, sets, config_file, preset)
    if heading == "mag" and applied:
        heading = "true"
    if extra:
        print(f"site parameters from the log (override with --set): {', '.join(extra)}", file=out)
    t0 = time.perf_counter()
    if exe:
        res, summary = run_log_exe(build_log_runner(hf.dir), log)
    else:
        res = hf.run(log)
        summary = ""
    wall = time.perf_counter() - t0
    print(f"run {filter_name} ({cfg.precision} C) on {Path(log_path).name}: {len(log)} steps, "
          f"{log.t[-1] - log.t[0]:.1f} s of data, {log.meta.get('rate_hz', 0):.0f} Hz IMU, "
          f"{'standalone executable' if exe else 'ctypes batch'} {wall:.2f} s", file=out)
    if summary:
        print(f"  {summary}", file=out)
    refused = int(np.count_nonzero(res.status & 0x20F))
    print(f"  steps with a non-zero status: {int(np.count_nonzero(res.status))}, refused: {refused}", file=out)
    hint = refusal_hint(res.status, log, cfg.params)
    if hint:
        print(f"  hint: {hint}", file=out)
    result = {"filter": filter_name, "log": str(log_path), "steps": len(log), "heading": heading,
              "precision": cfg.precision, "overrides": cfg.overrides, "site_sets": extra}
    if log.q_true is not None and score_mask(log).any():
        s = score(res.q, log, heading)
        result["score"] = s
        ref_name = {"broad": "BROAD optical reference (movement phase)",
                    "px4": "PX4 vehicle_attitude (onboard EKF, not ground truth)"}.get(
            log.meta.get("scoring"), "reference")
        decl = log.meta.get("declination_deg")
        head_note = {"mag": "magnetic heading" + (f", rotated by declination {decl:.2f}°" if decl else ""),
                     "true": "heading in the reference's north" + (f" (declination {decl:.2f}° set)" if decl else ""),
                     "none": "no heading source: one constant heading offset removed"}[heading]
        print(f"  error vs {ref_name}, {s['n']} samples ({head_note}), degrees:", file=out)
        print("           RMS   mean|e|", file=out)
        for a in ANGLES:
            print(f"    {a:<5} {s[a + '_rms']:7.3f} {s[a + '_mean_abs']:8.3f}", file=out)
        print(f"  BROAD decomposition RMS: total {s['total_rms']:.3f}, heading {s['heading_rms']:.3f}, "
              f"inclination {s['inclination_rms']:.3f}", file=out)
    elif log.q_true is not None and log.meta.get("movement") is not None:
        print("  (this log has a reference attitude but no row with movement = 1, the rows to score: "
              "nothing to score)", file=out)
    elif log.q_true is not None:
        print("  (the reference attitude has no finite row after the settle time: nothing to score)", file=out)
    else:
        print("  (no reference attitude in this log: nothing to score)", file=out)
    result["res"] = res
    if csv:
        _write_run_csv(csv, log, res, heading)
        print(f"  wrote {csv}", file=out)
    if plot:
        _plot_run(plot, log, res.q, heading, filter_name, res.status)
        print(f"  wrote {plot}", file=out)
    return result


def _write_run_csv(path, log, res, heading):
    rpy = np.degrees(res.rpy)
    cols = [log.t, res.q[:, 0], res.q[:, 1], res.q[:, 2], res.q[:, 3], rpy[:, 0], rpy[:, 1], rpy[:, 2],
            res.status.astype(float)]
    names = "t,qw,qx,qy,qz,roll_deg,pitch_deg,yaw_deg,status"
    if log.q_true is not None:
        ref = np.degrees(euler_from_q(np.where(np.isfinite(log.q_true), log.q_true, np.nan)))
        cols += [ref[:, 0], ref[:, 1], ref[:, 2]]
        names += ",ref_roll_deg,ref_pitch_deg,ref_yaw_deg"
    import io
    from generator.fileio import write_text_atomic
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack(cols), delimiter=",", header=names, comments="", fmt="%.9g")
    write_text_atomic(path, buf.getvalue())


def continuous_yaw_deg(yaw_est_deg, yaw_ref_deg=None):
    """Yaw for plotting without +-180 deg jumps: the reference unwrapped, and the estimate drawn as
    the reference plus their wrapped difference (so a 2 deg error across the wrap stays 2 deg on the
    plot, not 358); where there is no reference the estimate is unwrapped on its own."""
    est = np.asarray(yaw_est_deg, dtype=float)
    out = np.full(len(est), np.nan)
    fin = np.isfinite(est)
    out[fin] = np.degrees(np.unwrap(np.radians(est[fin])))
    if yaw_ref_deg is None:
        return out, None
    ref = np.asarray(yaw_ref_deg, dtype=float)
    ref_u = np.full(len(ref), np.nan)
    rf = np.isfinite(ref)
    ref_u[rf] = np.degrees(np.unwrap(np.radians(ref[rf])))
    both = rf & fin
    out[both] = ref_u[both] + (est[both] - ref[both] + 180.0) % 360.0 - 180.0
    return out, ref_u


def _plot_run(path, log, q_est, heading, label, status=None):
    """Roll, pitch, continuous yaw beside the reference; below, the error over time (BROAD's
    total, heading, inclination) with the steps of non-zero status marked. Written whole (atomic)."""
    import io
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from generator.fileio import write_atomic
    q_cmp = compare_frame(q_est, log, heading) if log.q_true is not None else q_est
    est = np.degrees(euler_from_q(q_cmp))
    t = log.t - log.t[0]
    ref = None
    if log.q_true is not None:
        ref = np.full((len(log), 3), np.nan)
        ok = np.all(np.isfinite(log.q_true), axis=1)
        ref[ok] = np.degrees(euler_from_q(log.q_true[ok]))
    fig, axs = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    ref_label = {"px4": "PX4 onboard estimate (vehicle_attitude)", "broad": "BROAD optical reference"}.get(
        log.meta.get("scoring"), "reference")
    decl = log.meta.get("declination_deg")
    est_label = f"{label} (generated C)" + (f", yaw + declination {decl:.2f}°" if heading == "mag" and decl else "")
    yaw_est, yaw_ref = continuous_yaw_deg(est[:, 2], None if ref is None else ref[:, 2])
    for i, a in enumerate(ANGLES):
        e = yaw_est if i == 2 else est[:, i]
        axs[i].plot(t, e, lw=0.9, label=est_label)
        if ref is not None:
            axs[i].plot(t, yaw_ref if i == 2 else ref[:, i], lw=0.9, ls="--", label=ref_label)
        axs[i].set_ylabel(f"{a} [deg]" + (" (unwrapped)" if i == 2 else ""))
        axs[i].grid(alpha=0.3)
    ax = axs[3]
    if ref is not None:
        tt, (tot, hd, inc) = t, _error_series(q_cmp, log)
        ax.plot(tt, tot, lw=0.9, label="total")
        ax.plot(tt, hd, lw=0.8, label="heading")
        ax.plot(tt, inc, lw=0.8, label="inclination")
        ax.set_ylabel("error [deg]")
    else:
        ax.set_ylabel("(no reference)")
    if status is not None:
        nz = np.flatnonzero(np.asarray(status) != 0)
        if len(nz) and ref is not None:      # room below zero error for the marks
            top = float(np.nanmax(tot)) if np.isfinite(tot).any() else 1.0
            ax.set_ylim(-0.12 * top, 1.05 * top)
        if len(nz):
            # along the bottom edge of the panel (x in data, y in axes coordinates)
            ax.plot(t[nz], np.full(len(nz), 0.03), "|", color="red", ms=8, transform=ax.get_xaxis_transform(),
                    label=f"non-zero status ({len(nz)} steps)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    axs[0].legend(loc="upper right", fontsize=8)
    axs[0].set_title(f"{label} on {log.name}")
    axs[-1].set_xlabel("time [s]")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format=Path(path).suffix.lstrip(".").lower() or "png")
    plt.close(fig)
    write_atomic(path, buf.getvalue())


def _error_series(q_cmp, log):
    """Per step BROAD's total / heading / inclination error (degrees), NaN without a reference."""
    out = np.full((3, len(log)), np.nan)
    ok = np.all(np.isfinite(log.q_true), axis=1) & np.all(np.isfinite(q_cmp), axis=1)
    if ok.any():
        out[:, ok] = np.array(broad_errors_deg(q_cmp[ok], log.q_true[ok]))
    return out


# =========================================================================================
# ahrsgen bench

def scenario_configs(quick: bool) -> list[tuple[str, str, dict]]:
    """(label, scenario, options) of the benchmark grid."""
    from firmware_sim import scenarios
    known = scenarios.names()
    if quick:
        grid = [("fixedwing_gps", "fixedwing_gps", {"duration": 120.0}),
                ("multirotor", "multirotor", {"duration": 30.0}),
                ("static_accel_disturbance", "static_accel_disturbance", {"duration": 60.0}),
                ("static_mag_disturbance", "static_mag_disturbance", {"duration": 60.0}),
                ("turntable", "turntable", {})]
    else:
        grid = [("fixedwing_gps", "fixedwing_gps", {}),
                ("fixedwing_gps_100hz", "fixedwing_gps", {"rate_hz": 100.0}),
                ("multirotor", "multirotor", {}),
                ("multirotor_400hz", "multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
                ("multirotor_400hz_repeated", "multirotor", {"rate_hz": 400.0, "mag_rate": 100.0,
                                                              "repeat_slow": True}),
                ("multirotor_jitter_dropouts", "multirotor",
                 {"jitter": 0.0004, "dropout": {"gyro": 0.005, "accel": 0.01, "mag": 0.05, "gps": 0.1}}),
                ("static_accel_disturbance", "static_accel_disturbance", {}),
                ("static_mag_disturbance", "static_mag_disturbance", {}),
                ("turntable", "turntable", {})]
    return [g for g in grid if g[1] in known]


def _estimators(filter_names, peer_names, with_baseline=True):
    ests, errors = [], {}
    for f in filter_names:
        try:   # a filter named like a peer (examples/madgwick beside ahrs' Madgwick) is labelled apart
            ests.append(filter_estimator(f, label=f"{f}_gen" if f in peer_names else None))
        except Exception as e:   # a filter still being written must not stop the bench
            errors[f] = f"{type(e).__name__}: {e}"
    if with_baseline and "qcf" in filter_names:
        ests.append(Estimator("qcf_hand", "baseline", "mag", "hand-written QCF (firmware_sim/c/baseline_qcf.c)"))
    ests += [peer_estimator(p) for p in peer_names]
    return ests, errors


def _run_task(task):
    """One log (scenario seed or real file) through every estimator. Runs in a worker."""
    kind, label, arg, opts, seed, est_specs, want_series = task
    from firmware_sim import scenarios
    t0 = time.perf_counter()
    c0 = time.process_time()
    if kind == "scenario":
        log = scenarios.make(arg, seed=seed, **opts)
    else:
        log = readers.read_log(arg)
    out = {"kind": kind, "label": label, "seed": seed, "log": log.name, "steps": len(log),
           "scores": {}, "errors": {}, "series": {}, "seconds": {}}
    for spec in est_specs:
        est = Estimator(**spec)
        t1 = time.perf_counter()
        try:
            q, heading, extra = est.run(log)
            out["scores"][est.name] = score(q, log, heading)
            if extra:
                out.setdefault("site", {})[est.name] = extra
            if want_series:
                t, e = total_error_series(q, log, heading)
                out["series"][est.name] = (t.tolist(), e.tolist())
        except Exception as e:
            out["errors"][est.name] = f"{type(e).__name__}: {e}"
        out["seconds"][est.name] = time.perf_counter() - t1
    out["wall"] = time.perf_counter() - t0
    out["cpu"] = time.process_time() - c0
    return out


def _spec(e: Estimator) -> dict:
    return {"name": e.name, "kind": e.kind, "heading": e.heading, "title": e.title, "filter": e.filter,
            "sets": list(e.sets), "config": e.config, "site": e.site}


class Progress:
    def __init__(self, total, stream=None):
        self.total, self.done, self._stream, self.t0 = total, 0, stream, time.time()

    @property
    def stream(self):
        """sys.stderr as it is now (a default bound at import is a stream pytest has closed)."""
        return self._stream if self._stream is not None else sys.stderr

    def update(self, what):
        self.done += 1
        frac = self.done / max(self.total, 1)
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        el = time.time() - self.t0
        self.stream.write(f"\r[{bar}] {self.done}/{self.total} {el:5.0f} s  {what[:50]:<50}")
        self.stream.flush()
        if self.done == self.total:
            self.stream.write("\n")


def _agg(values):
    a = np.asarray(values, dtype=float)
    return {"mean": float(np.mean(a)), "sd": float(np.std(a, ddof=1)) if len(a) > 1 else 0.0, "n": int(len(a))}


def _aggregate(results, group_key):
    groups = {}
    for r in results:
        for est, s in r["scores"].items():
            groups.setdefault(r[group_key], {}).setdefault(est, []).append(s)
    out = {}
    for g, ests in groups.items():
        out[g] = {}
        for est, lst in ests.items():
            out[g][est] = {k: _agg([s[k] for s in lst]) for k in lst[0] if k not in ("n", "nonfinite")}
            out[g][est]["nonfinite"] = int(sum(s["nonfinite"] for s in lst))
    return out


# the hand-written baseline implements SPEC.md's QCF: eq. 29's differentiator for the motion
# acceleration; the generated QCF is timed with that option too, so the ratio compares like with like
HAND_QCF_SETS = ["motion_accel_model=differentiator", "conditioning=false"]


def _cpu_timer(hf):
    """ahrs_bench_cpu_ns_per_step of a filter's library built with bench_timing.c."""
    lib = ctypes.CDLL(str(host.compile_shared(hf.dir, extra_sources=[C_DIR / "bench_timing.c"])))
    fn = lib.ahrs_bench_cpu_ns_per_step
    fn.restype = ctypes.c_double
    fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
    return fn


def measure_cost(filter_names, log: SensorLog, repeats=7, passes=3) -> dict:
    """Ops per step (manifest), state bytes, host ns/step inside C, vs the hand-written QCF.

    Timed with this thread's CPU clock (firmware_sim/c/bench_timing.c, built into the filter's
    shared library next to batch.c), so time spent descheduled on a busy machine does not
    count; the filters are timed in interleaved rounds and the median round is kept (the
    fastest round and batch.c's wall-clock median are in the JSON too).
    """
    from generator import config
    cost, built = {}, {}
    entries = [(f, f, []) for f in filter_names]
    if "qcf" in filter_names:
        entries += [("qcf_eq29", "qcf", HAND_QCF_SETS), ("qcf_hand", None, [])]
    for label, f, sets in entries:
        try:
            hf = baseline_filter() if f is None else host.build(config.resolve(f, None, sets, "float", None))
            paths = hf.manifest.get("step_paths", {}) if f is not None else {}
            worst = max(paths.items(), key=lambda kv: kv[1]["total"]) if paths else None
            cost[label] = {
                "settings": sets,
                "state_bytes": int(hf.manifest["structs"]["state"]["size"]),
                "ops_worst_path": worst[0] if worst else None,
                "ops_total": int(worst[1]["total"]) if worst else None,
                "ops": worst[1]["ops"] if worst else None,
                "paths": {k: v["total"] for k, v in paths.items()},
            }
            built[label] = hf
        except Exception as e:
            cost[label] = {"error": f"{type(e).__name__}: {e}"}
    timers = {label: _cpu_timer(hf) for label, hf in built.items()}
    packed = {label: hf.pack(log) for label, hf in built.items()}
    samples = {label: [] for label in built}
    wall = {label: [] for label in built}
    for _ in range(repeats):
        for label, hf in built.items():
            inp, dt = packed[label]
            s0 = hf.new_state()
            samples[label].append(timers[label](ctypes.byref(s0), inp.ctypes.data, dt.ctypes.data, len(log), passes))
            wall[label].append(hf.time_ns_per_step(log, repeats=1, passes=passes))
    for label, v in samples.items():
        cost[label]["ns_per_step"] = float(np.median(v))
        cost[label]["ns_per_step_min"] = float(np.min(v))
        cost[label]["wall_ns_per_step_median"] = float(np.median(wall[label]))
        cost[label]["timing_rounds"] = len(v)
    hand = cost.get("qcf_hand", {}).get("ns_per_step")
    if hand:
        for label in ("qcf", "qcf_eq29"):
            if "ns_per_step" in cost.get(label, {}):
                cost[label]["ratio_to_hand_qcf"] = cost[label]["ns_per_step"] / hand
    return cost


def bench(quick=False, seeds=None, filters=None, peer_names=PEER_NAMES, data_dir=None, out_dir="bench_out",
          jobs=2, scenarios_only=False, real_only=False, scenario_labels=None, command="", variants=(),
          scheduler=None) -> dict:
    """Run the whole benchmark; writes bench.json, bench.md and img/*.png under out_dir.

    variants: (label, filter, [name=value, ...]) rows benchmarked beside the defaults, to
    compare gains or options of one filter in the same run.
    """
    t_start = time.time()
    out_dir = Path(out_dir)
    (out_dir / "img").mkdir(parents=True, exist_ok=True)
    filter_names = list(filters) if filters else product_filters()
    notes = []
    missing = [p for p in peer_names if not peers.PEERS[p].available()]
    if missing:   # the peers are optional (the `dev` extra): say which were left out
        notes.append("peers left out, their packages are not installed: "
                     + ", ".join(f"{p} ({peers.PEERS[p].package})" for p in missing)
                     + ": pip install 'ahrsgen[dev]'.")
        peer_names = tuple(p for p in peer_names if p not in missing)
    ests, build_errors = _estimators(filter_names, peer_names, with_baseline=False)
    for label, fname, vsets in variants:
        ests.append(filter_estimator(fname, list(vsets), label=label))
    filter_names = [f for f in filter_names if f not in build_errors]
    # compile everything once in the main process (workers then hit the cache)
    for e in ests:
        if e.kind != "peer":
            try:
                e.host_filter()
            except Exception as ex:
                build_errors[e.name] = f"{type(ex).__name__}: {ex}"
    ests = [e for e in ests if e.name not in build_errors]
    specs = [_spec(e) for e in ests]
    n_seeds = seeds if seeds is not None else (1 if quick else 3)

    ddir = readers.shared_data_dir(data_dir)
    env_dir = os.environ.get(readers.DATA_ENV)
    if data_dir is None and env_dir and not Path(env_dir).is_dir():
        notes.append(f"${readers.DATA_ENV} = {env_dir} is not a folder: ignored"
                     + (f" (used {ddir})." if ddir else "."))
    tasks = []
    if not real_only:
        for label, scen, opts in scenario_configs(quick):
            if scenario_labels and label not in scenario_labels:
                continue
            for seed in range(n_seeds):
                tasks.append(("scenario", label, scen, opts, seed, specs, seed == 0))
    real = {"broad": [], "px4": []}
    if not scenarios_only:
        trials = readers.broad_trials(ddir) if ddir else []
        if quick or not trials:
            if not trials:
                notes.append("BROAD subset not found (looked in --data, $AHRSGEN_DATA, <repo>/../shared/data): "
                             "used the committed excerpt firmware_sim/data/broad_01_excerpt.csv.gz only.")
            else:
                notes.append("--quick: BROAD scored on the committed excerpt only (firmware_sim/data/broad_01_excerpt.csv.gz).")
            trials = [readers.EXCERPTS / "broad_01_excerpt.csv.gz"]
        # BROAD: product filters with a magnetometer heading, plus MEKF with its mag option
        broad_specs = [s for s in specs if s["heading"] == "mag" or s["kind"] == "peer"]
        if "mekf" in filter_names:
            try:
                broad_specs.append(_spec(filter_estimator("mekf", ["heading_source=mag"], label="mekf_mag")))
            except Exception as ex:
                build_errors["mekf_mag"] = f"{type(ex).__name__}: {ex}"
        for i, p in enumerate(trials):
            tasks.append(("broad", "BROAD", str(p), {}, 0, broad_specs, i == 0))
        ulogs = []
        if not _have("pyulog"):
            notes.append("PX4 logs left out: reading ULog needs pyulog: pip install 'ahrsgen[dev]'.")
        else:
            if ddir and (ddir / "px4").is_dir():
                ulogs = sorted((ddir / "px4").glob("*.ulg"))
            if quick or not ulogs:
                if not ulogs:
                    notes.append("PX4 logs not found: used the committed excerpts firmware_sim/data/*.ulg.")
                ulogs = sorted(readers.EXCERPTS.glob("*.ulg"))
        for p in ulogs:
            tasks.append(("px4", p.stem, str(p), {}, 0, broad_specs, True))
        real["broad"] = [str(p) for p in trials]
        real["px4"] = [str(p) for p in ulogs]

    prog = Progress(len(tasks))
    results = []
    from firmware_sim.fleet import Fleet
    # longest first so the workers finish together; a local pool or a Dask cluster (--scheduler)
    order = sorted(tasks, key=lambda t: 0 if t[0] == "broad" else 1)
    with Fleet(jobs, scheduler) as fleet:
        for r in fleet.map_unordered(_run_task, order):
            results.append(r)
            prog.update(f"{r['label']} {r['log']} seed {r['seed']}")
    # one order whatever the order they completed in (the means are summed in it)
    results.sort(key=lambda r: (r["kind"], r["label"], r["log"], r["seed"]))

    # cost: timed on the multirotor scenario (250 Hz, every sensor), seed 0
    from firmware_sim import scenarios as sc
    cost_log = sc.make("multirotor", seed=0, duration=30.0 if quick else 60.0)
    cost = measure_cost(filter_names, cost_log, repeats=5 if quick else 15)

    scen = [r for r in results if r["kind"] == "scenario"]
    broad = [r for r in results if r["kind"] == "broad"]
    px4 = [r for r in results if r["kind"] == "px4"]
    report = {
        "command": command,
        "quick": quick,
        "seeds": n_seeds,
        "date_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "host": _host_info(),
        "estimators": {e.name: {"kind": e.kind, "heading": e.heading, "title": e.title, "sets": e.sets}
                       for e in ests},
        "build_errors": build_errors,
        "notes": notes,
        "scenarios": _aggregate(scen, "label"),
        "scenario_options": {lbl: {"scenario": sc_name, **opts} for lbl, sc_name, opts in scenario_configs(quick)},
        "broad": {"trials": {r["log"]: r["scores"] for r in broad},
                  "mean": _aggregate(broad, "label").get("BROAD", {}), "files": real["broad"]},
        "px4": {r["label"]: r["scores"] for r in px4},
        "run_errors": {f"{r['label']}/{r['log']}/{r['seed']}": r["errors"] for r in results if r["errors"]},
        "site_sets": {f"{r['label']}/{r['log']}": r["site"] for r in results if r.get("site") and r["seed"] == 0},
        "cost": cost,
        "cost_log": f"multirotor seed 0, {len(cost_log)} steps (250 Hz, accel+mag+GPS)",
        "seconds": time.time() - t_start,
        "task_cpu_seconds": float(sum(r.get("cpu", 0.0) for r in results)),
        "task_wall_seconds": {f"{r['label']}/{r['log']}/{r['seed']}": round(r["wall"], 1) for r in results},
    }
    if _have("matplotlib"):
        report["plots"] = _plots(results, out_dir / "img")
    else:
        report["plots"] = {}
        notes.append("no plots: they need matplotlib: pip install 'ahrsgen[dev]'.")
    from generator.fileio import write_text_atomic     # whole files or none, also on Ctrl-C
    write_text_atomic(out_dir / "bench.json", json.dumps(report, indent=1))
    write_text_atomic(out_dir / "bench.md", markdown(report))
    return report


def _have(module: str) -> bool:
    """Whether an optional package (the `dev` extra) is installed."""
    import importlib.util
    return importlib.util.find_spec(module) is not None


def _host_info():
    import platform
    info = {"machine": platform.machine(), "python": platform.python_version()}
    try:
        info["cc"] = host._compiler_id().splitlines()[0]
    except Exception:
        pass
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def _plots(results, img_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from generator.fileio import write_atomic
    files = {}
    for r in results:
        if not r["series"]:
            continue
        key = r["label"] if r["kind"] != "broad" else f"broad_{r['log']}"
        fig, ax = plt.subplots(figsize=(10, 4))
        for est, (t, e) in sorted(r["series"].items()):
            ax.plot(t, e, lw=0.8, label=est, ls="-" if est not in PEER_NAMES else "--")
        ax.set_yscale("log")
        ax.set_ylim(1e-2, 180)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("total attitude error [deg]")
        ax.set_title(f"{r['label']}: {r['log']} (seed {r['seed']})")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, ncol=4, loc="upper right")
        fig.tight_layout()
        p = Path(img_dir) / f"err_{key}.png"
        buf = io.BytesIO()
        fig.savefig(buf, dpi=100, format="png")
        write_atomic(p, buf.getvalue())
        plt.close(fig)
        files[key] = f"img/{p.name}"      # relative to the output folder
    return files


def _pm(a, digits=2):
    if a["n"] > 1:
        return f"{a['mean']:.{digits}f} ± {a['sd']:.{digits}f}"
    return f"{a['mean']:.{digits}f}"


def markdown(rep: dict) -> str:
    L = []
    L.append("# ahrsgen bench results\n")
    if rep.get("command"):
        L.append(f"Command: `{rep['command']}`  ")
    L.append(f"Date: {rep['date_utc']}; host: {rep['host'].get('cpu', rep['host'].get('machine'))}; "
             f"{rep['host'].get('cc', '')}; run time {rep['seconds']:.0f} s wall "
             f"({rep.get('task_cpu_seconds', 0):.0f} s CPU in the workers).\n")
    for n in rep["notes"]:
        L.append(f"> {n}\n")
    if rep["build_errors"]:
        L.append("Filters left out (did not build): " +
                 "; ".join(f"`{k}`: {v.splitlines()[0][:160]}" for k, v in rep["build_errors"].items()) + "\n")
    L.append("Errors in degrees. Generated filters run as float C through the firmware harness with their "
             "default gains; the site parameters (declination; inclination, or learning it at rest when "
             "the log gives none) are set from each log as a user would for where they fly. Peers run "
             "through their Python packages (PEERS.md conventions) and their magnetic heading is "
             "rotated by the log's declination. Filters without a heading source are scored after "
             "removing one constant heading offset. "
             "`total / heading / incl.` is BROAD's decomposition of the earth-frame error.\n")
    # cost
    L.append("## Cost per step\n")
    L.append(f"ns/step: host C (`{rep['host'].get('cc', 'cc')}`, -O2), measured inside C over "
             f"{rep['cost_log']}, thread CPU time, median of interleaved rounds. Ops: the most expensive step path in the manifest. "
             "`qcf_hand` is `firmware_sim/c/baseline_qcf.c`, SPEC.md's QCF written by hand (eq. 29 "
             "differentiator); `qcf_eq29` is the generated QCF with the same option "
             "(`motion_accel_model=differentiator`), the like-for-like comparison; `qcf` is the "
             "generated default (centripetal model).\n")
    L.append("| filter | ns/step | vs hand-written QCF | ops/step (worst path) | add / mul / div / sqrt / trig | state bytes |")
    L.append("|---|---|---|---|---|---|")
    for f, c in rep["cost"].items():
        if "error" in c:
            L.append(f"| {f} | error: {c['error'].splitlines()[0][:80]} | | | | |")
            continue
        ratio = c.get("ratio_to_hand_qcf")
        rtxt = f"{ratio:.2f}×" if ratio else ("1 (baseline)" if f == "qcf_hand" else "")
        ops = c["ops"]
        optxt = " / ".join(str(ops.get(k, 0)) for k in ("add", "mul", "div", "sqrt", "trig")) if ops else "hand-written"
        L.append(f"| {f} | {c['ns_per_step']:.0f} | {rtxt} | {c['ops_total'] or ''}"
                 f"{' (' + c['ops_worst_path'] + ')' if c['ops_worst_path'] else ''} | {optxt} | {c['state_bytes']} |")
    L.append("")
    # scenarios
    if rep["scenarios"]:
        L.append(f"## Simulated scenarios (mean ± sd over {rep['seeds']} seed(s))\n")
        for scen, ests in rep["scenarios"].items():
            opts = rep["scenario_options"].get(scen) or {}
            L.append(f"### {scen}" + (f" ({', '.join(f'{k}={v}' for k, v in opts.items())})" if opts else "") + "\n")
            L.append("| estimator | roll RMS | pitch RMS | yaw RMS | roll mean\\|e\\| | pitch mean\\|e\\| | yaw mean\\|e\\| "
                     "| total RMS | heading RMS | incl. RMS |")
            L.append("|---|---|---|---|---|---|---|---|---|---|")
            for est, m in sorted(ests.items(), key=lambda kv: kv[1]["total_rms"]["mean"]):
                row = [est] + [_pm(m[f"{a}_rms"]) for a in ANGLES] + [_pm(m[f"{a}_mean_abs"]) for a in ANGLES]
                row += [_pm(m[f"{b}_rms"]) for b in BROAD_METRICS]
                flag = " (diverged rows)" if m.get("nonfinite") else ""
                L.append("| " + " | ".join(row) + flag + " |")
            img = rep.get("plots", {}).get(scen)
            if img:
                L.append(f"\nError over time (seed 0): ![{scen}]({img})")
            L.append("")
    # BROAD
    if rep["broad"]["mean"]:
        nt = len(rep["broad"]["trials"])
        L.append(f"## BROAD (BROAD's method, {nt} trial(s))\n")
        L.append("RMSE over the movement phase with a finite optical reference; one parameter set for all "
                 "trials (filter defaults; Madgwick β 0.12, Mahony Kp 0.74 / Ki 0.0012, Fusion and VQF "
                 "defaults). Data: Laidig et al., *Data* 2021, 6(7), 72 (CC BY 4.0).\n")
        L.append("| estimator | total RMSE | heading RMSE | inclination RMSE |")
        L.append("|---|---|---|---|")
        for est, m in sorted(rep["broad"]["mean"].items(), key=lambda kv: kv[1]["total_rms"]["mean"]):
            L.append(f"| {est} | {m['total_rms']['mean']:.2f} | {m['heading_rms']['mean']:.2f} | "
                     f"{m['inclination_rms']['mean']:.2f} |")
        L.append("")
        if nt > 1:
            ests = sorted(rep["broad"]["mean"])
            L.append("Total RMSE per trial:\n")
            L.append("| trial | " + " | ".join(ests) + " |")
            L.append("|---|" + "---|" * len(ests))
            for trial, sc in sorted(rep["broad"]["trials"].items()):
                L.append(f"| {trial} | " + " | ".join(
                    f"{sc[e]['total_rms']:.2f}" if e in sc else "–" for e in ests) + " |")
            L.append("")
    # PX4
    if rep["px4"]:
        L.append("## PX4 logs (reference: PX4's onboard estimate `vehicle_attitude`, not ground truth)\n")
        for logname, sc in rep["px4"].items():
            L.append(f"### {logname}\n")
            L.append("| estimator | roll RMS | pitch RMS | yaw RMS | total RMS |")
            L.append("|---|---|---|---|---|")
            for est, m in sorted(sc.items(), key=lambda kv: kv[1]["total_rms"]):
                L.append(f"| {est} | {m['roll_rms']:.2f} | {m['pitch_rms']:.2f} | {m['yaw_rms']:.2f} | "
                         f"{m['total_rms']:.2f} |")
            L.append("")
    if rep["run_errors"]:
        L.append("## Failures (full messages in bench.json)\n")
        for k, v in rep["run_errors"].items():
            for est, msg in v.items():
                lines = msg.splitlines()
                first_err = next((ln.strip() for ln in lines if "error:" in ln), "")
                L.append(f"- {k} {est}: {lines[0][:120]}" + (f" … `{first_err[:160]}`" if first_err else ""))
        L.append("")
    return "\n".join(L) + "\n"


# =========================================================================================
# CLI registration (generator/cli.py calls register_cli(subparsers))

PLOT_FORMATS = (".png", ".pdf", ".svg")


def _cmd_run(args) -> int:
    from generator.fileio import check_output_file
    from generator.model import ConfigError
    # everything that could fail after a long run is checked first
    for opt, path in (("--csv", args.csv), ("--plot", args.plot), ("--export-log", args.export_log)):
        if path:
            check_output_file(path, opt)
    if args.plot:
        if not Path(args.plot).suffix.lower() in PLOT_FORMATS:
            raise ConfigError(f"--plot {args.plot}: name the image .png, .pdf or .svg")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise ConfigError("--plot needs matplotlib: pip install 'ahrsgen[dev]'") from None
    try:
        log = readers.read_log(args.log)
    except FileNotFoundError:
        raise ConfigError(f"log file {args.log} does not exist") from None
    except (readers.LogError, OSError) as e:
        raise ConfigError(str(e) if isinstance(e, readers.LogError) else f"{args.log}: {e.strerror or e}") from None
    for w in log.meta.get("warnings", []):
        print(f"ahrsgen: warning: {w}", file=sys.stderr)
    if log.meta.get("ignored_columns"):
        print(f"  ignored columns: {', '.join(log.meta['ignored_columns'])}")
    res = run_on_log(args.filter, args.log, args.config, args.set, args.precision or "float",
                     plot=args.plot, csv=args.csv, exe=args.exe, runtime=args.runtime, preset=args.preset, log=log)
    if args.export_log:
        from generator import config
        write_harness_log(log, args.export_log)
        cfg = config.resolve(args.filter, args.config, list(args.set) + res["site_sets"],
                             args.precision or "float", None, args.preset)
        exe = build_log_runner(host.build(cfg).dir)
        print(f"  wrote {args.export_log}; run it with: {exe} {args.export_log} out.csv")
    return 0


def parse_variants(items) -> list:
    """'LABEL=FILTER:name=value,name=value' -> (label, filter, [name=value, ...]), validated."""
    from generator.model import ConfigError
    out = []
    for item in items or []:
        label, eq, rest = item.partition("=")
        fname, _, sets_text = rest.partition(":")
        if not eq or not label.isidentifier() or not fname:
            raise ConfigError(f"--variant {item!r}: expected LABEL=FILTER:name=value,name=value")
        sets = [s for s in sets_text.split(",") if s]
        fname = config.resolve(fname, None, sets).filter   # unknown filter/parameter/value: one clear error
        out.append((label, fname, sets))
    return out


def _cmd_bench(args) -> int:
    if args.data is not None and not Path(args.data).is_dir():
        from generator.model import ConfigError
        what = "is not a folder" if Path(args.data).exists() else "does not exist"
        raise ConfigError(f"--data {args.data} {what} (it should hold broad/ and px4/; without --data: "
                          f"${readers.DATA_ENV}, else <repo>/../shared/data)")
    asked = [p for p in (args.peers or ()) if not peers.PEERS[p].available()]
    if asked:
        from generator.model import ConfigError
        raise ConfigError(f"--peers {' '.join(asked)}: package {peers.PEERS[asked[0]].package} is not installed "
                          f"(pip install 'ahrsgen[dev]')")
    cmd = "ahrsgen bench " + " ".join(sys.argv[2:]) if len(sys.argv) > 1 and sys.argv[1] == "bench" else "ahrsgen bench"
    rep = bench(quick=args.quick, seeds=args.seeds, filters=args.filters or None,
                peer_names=tuple(args.peers) if args.peers is not None else PEER_NAMES,
                data_dir=args.data, out_dir=args.output, jobs=args.jobs,
                scenarios_only=args.scenarios_only, real_only=args.real_only,
                scenario_labels=args.scenarios, command=cmd, variants=parse_variants(args.variant),
                scheduler=args.scheduler)
    md = Path(args.output) / "bench.md"
    print(md.read_text())
    print(f"wrote {Path(args.output) / 'bench.json'}, {md} and {len(rep['plots'])} plot(s) in "
          f"{Path(args.output) / 'img'} ({rep['seconds']:.0f} s)", file=sys.stderr)
    return 0


def register_cli(sub) -> None:
    from generator.cli import positive_int_arg   # loaded: it is the caller
    p = sub.add_parser("run", help="run a generated filter over a real log (BROAD CSV or PX4 ULog) and score it",
                       description="Generate and compile a filter for the host, run it over a log file through "
                                   "the firmware harness, and where the log has a reference attitude score it "
                                   "(BROAD's method for BROAD data; PX4's vehicle_attitude for ULog).")
    p.add_argument("filter", help="filter name (see 'ahrsgen list') or a filter folder's path")
    p.add_argument("--log", required=True, metavar="FILE",
                   help="a CSV log (.csv/.csv.gz: t,gx,gy,gz,ax,ay,az and optional mx,my,mz, gps_vn,gps_ve,gps_vd, "
                        "qw,qx,qy,qz, movement; see docs/log-format.md; BROAD's files are in it) or a PX4 .ulg. "
                        f"Examples installed with ahrsgen: {readers.EXCERPTS / 'broad_01_excerpt.csv.gz'} (BROAD, "
                        f"optical reference), {readers.EXCERPTS / 'px4_handheld_excerpt.ulg'} (PX4, needs pyulog)")
    p.add_argument("--config", metavar="FILE.toml", help="TOML config (prefix, precision, [params])")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="override a parameter")
    p.add_argument("--preset", help="start from a named parameter set of the filter, e.g. 'faithful' "
                                    "(see 'ahrsgen list FILTER')")
    p.add_argument("--precision", choices=["float", "double"], help="C floating-point type (default float)")
    p.add_argument("--runtime", metavar="NAME,NAME", help="build these parameters as runtime parameters "
                                                          "(same figures; see 'generate --runtime')")
    p.add_argument("--plot", metavar="OUT.png", help="plot roll/pitch/yaw beside the log's reference and the "
                                                     "error over time, steps with a non-zero status marked")
    p.add_argument("--csv", metavar="OUT.csv", help="write t, q, Euler angles (deg), status (and the reference)")
    p.add_argument("--exe", action="store_true",
                   help="run through the standalone executable (firmware_sim/c/main_log.c) instead of ctypes")
    p.add_argument("--export-log", metavar="OUT.csv",
                   help="also write the log in the standalone executable's text format (main_log.c) and "
                        "print the executable's path, to run it outside Python")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("bench", help="filters x scenarios x seeds, real logs and peers: accuracy and cost tables",
                       description="Benchmark every product filter (float C through the firmware harness) and "
                                   "the peers (VQF, Fusion, Madgwick, Mahony) on the simulated scenarios, the "
                                   "BROAD subset and the PX4 logs; measure ns/step against a hand-written QCF. "
                                   "Writes bench.json, bench.md and plots.")
    p.add_argument("--quick", action="store_true", help="short CI run (1 seed, shorter scenarios, data excerpts)")
    p.add_argument("--seeds", type=positive_int_arg, help="seeds per scenario (default 3, --quick 1)")
    p.add_argument("--filters", nargs="*", help="only these filters, names or folder paths (default: all known)")
    p.add_argument("--scenarios", nargs="*", metavar="LABEL",
                   help="only these scenario rows of the grid (e.g. multirotor turntable; default: all)")
    p.add_argument("--peers", nargs="*", choices=list(peers.PEERS), help=f"peers to include (default: {' '.join(PEER_NAMES)})")
    p.add_argument("--data", metavar="DIR", help="folder holding broad/ and px4/ (default: $AHRSGEN_DATA, "
                                                 "else <repo>/../shared/data)")
    p.add_argument("-o", "--output", default="bench_out", metavar="DIR", help="output folder (default bench_out)")
    p.add_argument("-j", "--jobs", "--workers", dest="jobs", type=positive_int_arg, default=2,
                   help="local worker processes (default 2)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the logs on this Dask distributed scheduler instead of local processes "
                        "(workers must see the same data paths)")
    p.add_argument("--variant", action="append", default=[], metavar="LABEL=FILTER:k=v,k=v",
                   help="also bench FILTER with these settings under LABEL, e.g. "
                        "qcf_soft=qcf:kp=0.05,ki=0.001 (repeatable)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scenarios-only", action="store_true", help="skip the real logs")
    g.add_argument("--real-only", action="store_true", help="only the real logs (BROAD, PX4)")
    p.set_defaults(func=_cmd_bench)
