"""`ahrsgen run`: one generated filter over one log, scored where the log has a reference;
its CSV and plot."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ahrsgen.sim import host, readers
from ahrsgen.sim.metrics import broad_errors_deg
from ahrsgen.npquat import euler_from_q
from ahrsgen.bench.common import ANGLES
from ahrsgen.bench.harness import build_log_runner, run_log_exe
from ahrsgen.bench.scoring import (compare_frame, filter_heading, refusal_failure, refusal_hint,  # noqa: F401
                                         score, score_mask, site_sets)


# =========================================================================================
# ahrsgen run

def status_counts(status: np.ndarray, manifest: dict) -> str:
    """'AT_REST 1200, MAG_DISTURBED 35 (fault)': every status bit a run set, by the names of the
    build's header, with the number of steps; the faults (STATUS_FAULT_MASK) marked."""
    fault = int(manifest.get("status_fault_mask", 0))
    parts = []
    for name, bit in manifest.get("status", {}).items():
        n = int(np.count_nonzero(status & np.uint32(bit))) if bit else 0
        if n:
            parts.append(f"{name} {n}" + (" (fault)" if bit & fault else ""))
    return ", ".join(parts)


def run_on_log(filter_name: str, log_path: str, config_file=None, sets=(), precision="float",
               plot=None, csv=None, exe=False, out=None, runtime=None, preset=None, log=None) -> dict:
    """Run one generated filter over a log file; score it where the log has a reference.
    runtime: parameters built as runtime parameters (their values set through set_params)."""
    from ahrsgen.generate import config
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
    named = status_counts(res.status, hf.manifest)
    if named:
        print(f"  status bits (steps): {named}", file=out)
    failed = refusal_failure(res.status, log, cfg.params, filter_name)
    hint = refusal_hint(res.status, log, cfg.params)
    if hint and not failed:
        print(f"  hint: {hint}", file=out)
    result = {"filter": filter_name, "log": str(log_path), "steps": len(log), "heading": heading,
              "precision": cfg.precision, "overrides": cfg.overrides, "site_sets": extra}
    if failed:                       # a filter that never ran gets no score (the caller exits 1)
        result["failed"] = failed
    elif log.q_true is not None and score_mask(log).any():
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
    from ahrsgen.fileio import write_text_atomic
    buf = io.StringIO()
    buf.write("# written by ahrsgen run\n")        # the marker: a later run may replace this file
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
    from ahrsgen.fileio import write_atomic
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
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    from ahrsgen.fileio import MARK
    fig.savefig(buf, dpi=110, format=fmt, metadata={"Software" if fmt == "png" else "Creator": f"{MARK} run"})
    plt.close(fig)
    write_atomic(path, buf.getvalue())


def _error_series(q_cmp, log):
    """Per step BROAD's total / heading / inclination error (degrees), NaN without a reference."""
    out = np.full((3, len(log)), np.nan)
    ok = np.all(np.isfinite(log.q_true), axis=1) & np.all(np.isfinite(q_cmp), axis=1)
    if ok.any():
        out[:, ok] = np.array(broad_errors_deg(q_cmp[ok], log.q_true[ok]))
    return out


