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
from ahrsgen.bench.scoring import (ScoreSums, StatusTally, compare_frame, filter_heading,  # noqa: F401
                                         refusal_failure, refusal_hint, score, score_mask, site_sets)
from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.peers import heading_offset_sums, rotate_heading
from ahrsgen.status import REFUSED_MASK


# =========================================================================================
# ahrsgen run

def status_counts(status, manifest: dict) -> str:
    """'AT_REST 1200, MAG_DISTURBED 35 (fault)': every status bit a run set, by the names of the
    build's header, with the number of steps; the faults (STATUS_FAULT_MASK) marked. `status`:
    the statuses or their StatusTally."""
    fault = int(manifest.get("status_fault_mask", 0))
    tally = status if isinstance(status, StatusTally) else StatusTally(status)
    parts = []
    for name, bit in manifest.get("status", {}).items():
        n = tally.count(bit) if bit else 0
        if n:
            parts.append(f"{name} {n}" + (" (fault)" if bit & fault else ""))
    return ", ".join(parts)


# A log read in chunks (readers.CsvChunks) is scored without holding it: the score's sums are
# added chunk by chunk (ScoreSums), rows of the first SETTLE_MAX seconds wait until the settle
# time is known (min(10 s, 20 % of the log): it needs the log's length), and a filter without a
# heading source (its one constant heading offset is a mean over every scored row) is run over
# the log a second time to score it. The plot keeps at most PLOT_ROWS rows (every k-th row).
SETTLE_MAX = 10.0
PLOT_ROWS = 200_000


def run_on_log(filter_name: str, log_path: str, config_file=None, sets=(), precision="float",
               plot=None, csv=None, exe=False, out=None, runtime=None, preset=None, log=None) -> dict:
    """Run one generated filter over a log file; score it where the log has a reference.
    runtime: parameters built as runtime parameters (their values set through set_params).
    log: the log already read, a SensorLog or a readers.CsvChunks (a log of any size, run a
    chunk at a time with the filter's state carried across; result['res'] is then None)."""
    from ahrsgen.generate import config
    out = out or sys.stdout
    log = readers.read_log(log_path) if log is None else log
    whole = isinstance(log, SensorLog)
    if exe and not whole:
        raise ValueError("run_on_log: exe runs a whole SensorLog, not a log read in chunks")
    user = config.resolve(filter_name, config_file, list(sets), precision, None, preset).overrides
    extra, applied = site_sets(filter_name, log.meta, set(user))
    cfg = config.resolve(filter_name, config_file, list(sets) + extra, precision, None, preset, runtime=runtime)
    hf = host.build(cfg)
    heading = filter_heading(filter_name, sets, config_file, preset)
    if heading == "mag" and applied:
        heading = "true"
    if extra:
        print(f"site parameters from the log (override with --set): {', '.join(extra)}", file=out)
    fault_mask = int(hf.manifest.get("status_fault_mask", 0))
    tally, summary, timing = StatusTally(fault_mask=fault_mask), "", [0.0]
    if whole:
        t0 = time.perf_counter()
        if exe:
            res, summary = run_log_exe(build_log_runner(hf.dir), log)
        else:
            res = hf.run(log)
        timing[0] = time.perf_counter() - t0
        chunks = [(log, res)]
        head, steps, span = log, len(log), float(log.t[-1] - log.t[0])
    else:
        res = None
        chunks = _chunk_results(hf, log, timing)
    scorer = None if whole else _ChunkScore(heading)
    plot_rows = None if (whole or not plot) else _PlotRows()
    csv_out = _RunCsv(csv) if csv else None
    try:
        for part, r in chunks:
            tally.add(r.status)
            if csv_out:
                csv_out.add(part, r)
            if scorer:
                scorer.add(part, r, plot_rows)
    except BaseException as e:
        if csv_out:
            csv_out.abort(e)
        raise
    if csv_out:
        csv_out.close()
    if not whole:
        head, steps, span = log.head, log.rows, float(scorer.t_last - scorer.t_first)
        scorer.finish(log.meta["settle_time"], plot_rows)
        if scorer.offset_pending:          # no heading source: score in a second pass
            for part, r in _chunk_results(hf, log, [0.0], progress=False):
                scorer.add(part, r, plot_rows)
            scorer.finish(log.meta["settle_time"], plot_rows)
    wall = timing[0]
    print(f"run {filter_name} ({cfg.precision} C) on {Path(log_path).name}: {steps} steps, "
          f"{span:.1f} s of data, {log.meta.get('rate_hz', 0):.0f} Hz IMU, "
          f"{'standalone executable' if exe else 'ctypes batch'} {wall:.2f} s"
          + ("" if whole else f" (read in chunks of {log.block_bytes >> 20} MiB of text)"), file=out)
    if summary:
        print(f"  {summary}", file=out)
    refused = tally.count(REFUSED_MASK)
    print(f"  steps with a non-zero status: {tally.count(0)}, refused: {refused}", file=out)
    named = status_counts(tally, hf.manifest)
    if named:
        print(f"  status bits (steps): {named}", file=out)
    failed = refusal_failure(tally, head, cfg.params, filter_name)
    hint = refusal_hint(tally, head, cfg.params)
    if hint and not failed:
        print(f"  hint: {hint}", file=out)
    result = {"filter": filter_name, "log": str(log_path), "steps": steps, "heading": heading,
              "precision": cfg.precision, "overrides": cfg.overrides, "site_sets": extra}
    has_ref = log.q_true is not None if whole else "reference" in log.meta
    if whole:
        scorable = has_ref and bool(score_mask(log).any())
    else:
        scorable = scorer.sums.n > 0
    if failed:                       # a filter that never ran gets no score (the caller exits 1)
        result["failed"] = failed
    elif scorable:
        s = score(res.q, log, heading) if whole else scorer.sums.result()
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
    elif has_ref and (log.meta.get("movement") is not None if whole else log.meta.get("scoring") == "broad"):
        print("  (this log has a reference attitude but no row with movement = 1, the rows to score: "
              "nothing to score)", file=out)
    elif has_ref:
        print("  (the reference attitude has no finite row after the settle time: nothing to score)", file=out)
    else:
        print("  (no reference attitude in this log: nothing to score)", file=out)
    result["res"] = res
    if csv:
        print(f"  wrote {csv}", file=out)
    if plot:
        if whole:
            _plot_run(plot, log, res.q, heading, filter_name, res.status, fault_mask=fault_mask)
        else:
            plog, q_cmp, st = plot_rows.log(log.name, log.meta)
            _plot_run(plot, plog, q_cmp, heading, filter_name, st, q_cmp=q_cmp, fault_mask=fault_mask,
                      counts=(tally.count(fault_mask), tally.count(0) - tally.count(fault_mask)))
        print(f"  wrote {plot}", file=out)
    return result


def _chunk_results(hf, chunks, timing, progress=None):
    """(chunk, RunResult) for each chunk of a readers.CsvChunks, the filter's state carried from
    one chunk to the next; timing[0] adds up the seconds in C. A progress bar on stderr when it
    is a terminal (progress None) or when progress is True."""
    from ahrsgen.bench.grid import Progress
    show = sys.stderr.isatty() if progress is None else progress
    prog = Progress(max(chunks.size, 1)) if show else None
    state, rows = None, 0
    for part in _prefetched(chunks):
        t0 = time.perf_counter()
        r = hf.run(part, state=state)
        timing[0] += time.perf_counter() - t0
        state = hf.last_state
        yield part, r
        rows += len(part)
        if prog:
            prog.update(f"{rows} rows", done=min(chunks.done_bytes, prog.total - 1))
    if prog:
        prog.update(f"{rows} rows", done=prog.total)


def _prefetched(chunks, depth: int = 2):
    """The chunks of an iterable, read `depth` ahead in a thread: pyarrow's parser and numpy
    release the GIL, so the next chunk is read while this one runs through the filter and the
    score (two cores: reading and the rest overlap). An error reading a chunk is raised here,
    where that chunk would have been; leaving the loop early stops the reader."""
    import queue
    import threading
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False                        # the consumer left

    def read():
        try:
            for part in chunks:
                if not put((part, None)):
                    return
            put((end, None))
        except BaseException as e:          # raised in the consumer, where the chunk was due
            put((end, e))

    reader = threading.Thread(target=read, name="ahrsgen-log-reader", daemon=True)
    reader.start()
    try:
        while True:
            part, err = q.get()
            if part is end:
                if err is not None:
                    raise err
                return
            yield part
    finally:
        stop.set()


class _ChunkScore:
    """score() of a log run a chunk at a time (see SETTLE_MAX above): rows certainly scored are
    added as they come; rows of the first SETTLE_MAX s wait for the settle time."""

    def __init__(self, heading: str):
        self.heading = heading
        self.sums = ScoreSums()
        self.offset = None if heading == "none" else 0.0      # heading offset removed (radians)
        self.off_sums = [0.0, 0.0, 0]
        self.early = []                  # (t, q, q_true) of rows before t_first + SETTLE_MAX
        self.t_first = self.t_last = None
        self.settle = None               # known after the first pass

    @property
    def offset_pending(self) -> bool:
        return self.offset is None

    def add(self, part, r, plot_rows=None) -> None:
        if self.t_first is None:
            self.t_first = float(part.t[0])
        self.t_last = float(part.t[-1])
        q = r.q
        if self.offset is not None:
            q = compare_frame(q, part, self.heading) if self.heading != "none" else rotate_heading(q, self.offset)
            if plot_rows is not None:
                plot_rows.add(part, q, r.status)
        if part.q_true is None:
            return
        ok = np.all(np.isfinite(part.q_true), axis=1)
        mv = part.meta.get("movement")
        if mv is not None:               # BROAD's method: the movement column says which rows
            sure, early = ok & mv, np.zeros(len(part), bool)
        elif self.settle is not None:
            sure, early = ok & (part.t >= self.t_first + self.settle), np.zeros(len(part), bool)
        else:
            cut = part.t >= self.t_first + SETTLE_MAX
            sure, early = ok & cut, ok & ~cut
        if early.any():
            self.early.append((part.t[early], q[early], part.q_true[early]))
        self._add(q[sure], part.q_true[sure])

    def _add(self, q, ref) -> None:
        if self.offset is None:
            ss, sc, n = heading_offset_sums(q, ref)
            self.off_sums = [self.off_sums[0] + ss, self.off_sums[1] + sc, self.off_sums[2] + n]
        else:
            self.sums.add(q, ref)

    def finish(self, settle: float, plot_rows=None) -> None:
        """After a pass: the rows that waited are added where t >= t_first + settle; for a filter
        without a heading source the first pass ends with the offset known."""
        for t, q, ref in self.early:
            keep = t >= self.t_first + settle
            self._add(q[keep], ref[keep])
        self.early, self.settle = [], settle
        if self.offset is None:
            ss, sc, n = self.off_sums
            self.offset = float(np.arctan2(ss / n, sc / n)) if n else 0.0
            self.t_first = None


class _PlotRows:
    """Every k-th row of a log run in chunks, for the plot: k doubles whenever more than
    PLOT_ROWS rows are kept, so the plot holds PLOT_ROWS / 2 to PLOT_ROWS rows; a kept row's
    status is the OR of the k steps it stands for."""

    def __init__(self, limit: int = PLOT_ROWS):
        self.limit, self.stride, self.seen = limit, 1, 0
        self.t, self.q, self.ref, self.st = [], [], [], []

    def add(self, part, q_cmp, status) -> None:
        n = len(part)
        idx = np.flatnonzero((np.arange(self.seen, self.seen + n) % self.stride) == 0)
        self.seen += n
        if not len(idx):
            return
        self.t.append(part.t[idx])
        self.q.append(q_cmp[idx])
        self.ref.append(part.q_true[idx] if part.q_true is not None else np.full((len(idx), 4), np.nan))
        self.st.append(np.bitwise_or.reduceat(np.asarray(status, np.uint32), idx))
        if sum(map(len, self.t)) > self.limit:
            t, q, ref, st = (np.concatenate(a) for a in (self.t, self.q, self.ref, self.st))
            st2 = st[0::2].copy()
            st2[:len(st[1::2])] |= st[1::2]
            self.t, self.q, self.ref, self.st = [t[0::2]], [q[0::2]], [ref[0::2]], [st2]
            self.stride *= 2

    def log(self, name: str, meta: dict):
        """(SensorLog of the kept rows (time and reference), their estimate, their status)."""
        t, q, ref, st = (np.concatenate(a) for a in (self.t, self.q, self.ref, self.st))
        z = np.zeros((len(t), 3))
        has_ref = bool(np.isfinite(ref).any())
        return (SensorLog(name, t, np.zeros(len(t)), z, z, z, z, np.zeros(len(t), np.uint32),
                          ref if has_ref else None, {k: v for k, v in meta.items() if k != "movement"}), q, st)


class _RunCsv:
    """`run --csv`: t, q, Euler angles (deg), status (and the reference's angles) written a chunk
    at a time into a temporary file beside the target, which replaces it when done (atomic)."""

    NAMES = "t,qw,qx,qy,qz,roll_deg,pitch_deg,yaw_deg,status"

    def __init__(self, path):
        from ahrsgen.fileio import atomic_file
        self._ctx = atomic_file(path, "w")
        self.fh = self._ctx.__enter__()
        self.fh.write("# written by ahrsgen run\n")   # the marker: a later run may replace this file
        self.first = True

    def add(self, log, res) -> None:
        rpy = np.degrees(res.rpy)
        cols = [log.t, res.q[:, 0], res.q[:, 1], res.q[:, 2], res.q[:, 3], rpy[:, 0], rpy[:, 1], rpy[:, 2],
                res.status.astype(float)]
        names = self.NAMES
        if log.q_true is not None:
            ref = np.degrees(euler_from_q(np.where(np.isfinite(log.q_true), log.q_true, np.nan)))
            cols += [ref[:, 0], ref[:, 1], ref[:, 2]]
            names += ",ref_roll_deg,ref_pitch_deg,ref_yaw_deg"
        np.savetxt(self.fh, np.column_stack(cols), delimiter=",", header=names if self.first else "",
                   comments="", fmt="%.9g")
        self.first = False

    def close(self) -> None:
        """The file replaces the target."""
        self._ctx.__exit__(None, None, None)

    def abort(self, e: BaseException) -> None:
        """The temporary file is removed; the target is left as it was."""
        self._ctx.__exit__(type(e), e, e.__traceback__)


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
    # rows without a reference: the estimate unwrapped from the drawn row before (or, at the
    # start, the one after), so the line does not jump by turns where the reference stops
    idx = np.flatnonzero(fin)
    alone = ~rf[idx]
    if alone.any() and both.any():
        step = (np.diff(est[idx]) + 180.0) % 360.0 - 180.0      # wrapped change row to row
        path = np.concatenate([[0.0], np.cumsum(step)])          # the estimate, unwrapped
        anchor = np.flatnonzero(~alone)                          # positions in idx with a reference
        nearest = anchor[np.clip(np.searchsorted(anchor, np.arange(len(idx))) - 1, 0, None)]
        nearest = np.where(np.arange(len(idx)) < anchor[0], anchor[0], nearest)
        k = np.flatnonzero(alone)
        out[idx[k]] = out[idx[nearest[k]]] + path[k] - path[nearest[k]]
    return out, ref_u


def status_marks(status, fault_mask: int) -> tuple[np.ndarray, np.ndarray]:
    """(steps with a fault bit, steps with information bits only): the indices the plot marks."""
    status = np.asarray(status, dtype=np.uint32)
    fault = (status & np.uint32(fault_mask)) != 0
    return np.flatnonzero(fault), np.flatnonzero((status != 0) & ~fault)


def _plot_run(path, log, q_est, heading, label, status=None, q_cmp=None, fault_mask=0, counts=None):
    """Roll, pitch, continuous yaw beside the reference; below, the error over time (BROAD's
    total, heading, inclination) with the steps of the run's status marked along the bottom:
    faults (any bit of `fault_mask`, the build's STATUS_FAULT_MASK) in red, steps with only
    information bits (AT_REST, ...) in grey. Written whole (atomic).
    q_cmp: the estimate already in the reference's heading frame; counts: (fault steps, steps with
    information only) of the whole run when `status` is of every k-th row (a long log's plot)."""
    import io
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ahrsgen.fileio import write_atomic
    if q_cmp is None:
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
        bad, info = status_marks(status, fault_mask)
        n_bad, n_info = (len(bad), len(info)) if counts is None else counts
        if (len(bad) or len(info)) and ref is not None:      # room below zero error for the marks
            top = float(np.nanmax(tot)) if np.isfinite(tot).any() else 1.0
            ax.set_ylim(-0.16 * top, 1.05 * top)
        # along the bottom edge of the panel (x in data, y in axes coordinates)
        for idx, y, colour, text in ((info, 0.03, "0.6", f"information only ({n_info} steps)"),
                                     (bad, 0.08, "red", f"fault status ({n_bad} steps)")):
            if len(idx):
                ax.plot(t[idx], np.full(len(idx), y), "|", color=colour, ms=6,
                        transform=ax.get_xaxis_transform(), label=text)
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


