"""Issue 27: `ahrsgen run` on CSV logs of 200 MB and 1 GB, end to end, beside the C filter alone.

    PYTHONPATH=src .venv/bin/python studies/large_log_bench.py [--sizes 200,1000] [--json out.json]
        [--before SRC_DIR] [--keep DIR]

Writes each log (MB of text) into a temporary folder by repeating the committed BROAD excerpt
(src/ahrsgen/sim/data/broad_01_excerpt.csv.gz, 15 columns, 286 Hz) with its time shifted so t
keeps increasing; then runs `python -m ahrsgen.cli run qcf --log big.csv` as a child process and
reads its wall time and peak resident memory (os.wait4's ru_maxrss of that child alone). Beside
it, the C filter alone: the host build of the same configuration stepping the same number of
rows from in-memory arrays through ctypes (hf.run, pack included), rows/s. --before runs the
smallest size with another source tree (e.g. the main branch's src, the whole-file reader) for
comparison. Prints a table and writes JSON (--json). Speed and memory are measured here, not in
a test. Nothing is written outside the temporary folder (or --keep DIR).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ahrsgen.generate import config
from ahrsgen.sim import host, readers

EXCERPT = readers.EXCERPTS / "broad_01_excerpt.csv.gz"


def write_big_csv(path: Path, megabytes: float) -> int:
    """The excerpt repeated until the file holds `megabytes` MB; returns the number of rows."""
    log = readers.read_csv(EXCERPT)
    import gzip
    lines = gzip.decompress(EXCERPT.read_bytes()).decode().splitlines()
    header, body = lines[0], [ln.partition(",")[2] for ln in lines[1:] if ln.strip()]
    t = log.t - log.t[0]
    period = float(t[-1] + np.median(np.diff(t)))
    target, rows, rep = megabytes * 1e6, 0, 0
    with open(path, "w") as fh:
        fh.write(header + "\n")
        size = len(header) + 1
        while size < target:
            tt = t + rep * period
            text = "\n".join(f"{a:.6f},{b}" for a, b in zip(tt.tolist(), body)) + "\n"
            fh.write(text)
            size += len(text)
            rows += len(body)
            rep += 1
    return rows


def run_cli_measured(log: Path, src: Path) -> dict:
    """`ahrsgen run qcf --log LOG` as a child: wall seconds, exit code, peak RSS of that child alone (MB),
    its stdout."""
    env = dict(os.environ, PYTHONPATH=str(src))
    t0 = time.perf_counter()
    with open(os.devnull, "w") as devnull, tempfile.TemporaryFile("w+") as out:
        pid = os.posix_spawn(sys.executable, [sys.executable, "-m", "ahrsgen.cli", "run", "qcf", "--log", str(log)],
                             env, file_actions=[(os.POSIX_SPAWN_DUP2, out.fileno(), 1),
                                                (os.POSIX_SPAWN_DUP2, devnull.fileno(), 2)])
        _, status, ru = os.wait4(pid, 0)
        wall = time.perf_counter() - t0
        out.seek(0)
        text = out.read()
    return {"wall_s": wall, "exit": os.waitstatus_to_exitcode(status), "peak_rss_mb": ru.ru_maxrss / 1024,
            "out": text}


def c_alone(rows: int) -> dict:
    """The same filter build stepping `rows` rows from memory (ctypes batch, pack included)."""
    log = readers.read_csv(EXCERPT)
    cfg = config.resolve("qcf", None, [], "float", None)
    hf = host.build(cfg)
    reps = max(1, int(np.ceil(min(rows, 2_000_000) / len(log))))
    big = readers.SensorLog("tiled", np.arange(len(log) * reps) * 0.0035, np.full(len(log) * reps, 0.0035),
                            np.tile(log.gyro, (reps, 1)), np.tile(log.accel, (reps, 1)), np.tile(log.mag, (reps, 1)),
                            np.tile(log.gps_vel, (reps, 1)), np.tile(log.valid, reps))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        hf.run(big)
        best = min(best, time.perf_counter() - t0)
    ns = hf.time_ns_per_step(big.slice(0, min(len(big), 200_000)), repeats=3, passes=1)
    return {"rows": len(big), "rows_per_s": len(big) / best, "c_ns_per_step": ns}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="200,1000", help="log sizes in MB, comma-separated (default 200,1000)")
    ap.add_argument("--json", metavar="OUT.json", help="write the figures here")
    ap.add_argument("--before", metavar="SRC_DIR", help="also run the smallest size with this source tree")
    ap.add_argument("--keep", metavar="DIR", help="write the logs here (kept) instead of a temporary folder")
    args = ap.parse_args(argv)
    src = Path(__file__).resolve().parents[1] / "src"
    sizes = [float(s) for s in args.sizes.split(",")]
    rows_out = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(args.keep or tmp)
        d.mkdir(parents=True, exist_ok=True)
        for mb in sizes:
            path = d / f"big_{mb:g}MB.csv"
            rows = write_big_csv(path, mb)
            size_mb = path.stat().st_size / 1e6
            trees = [("this tree", src)] + ([("before", Path(args.before))] if args.before and mb == min(sizes) else [])
            for label, tree in trees:
                r = run_cli_measured(path, tree)
                if r["exit"] != 0:
                    print(f"run failed ({label}, {mb:g} MB): exit {r['exit']}\n{r['out'][-1000:]}", file=sys.stderr)
                    return 1
                score = next((ln.strip() for ln in r["out"].splitlines() if "BROAD decomposition" in ln), "")
                rows_out.append({"tree": label, "file_mb": round(size_mb, 1), "rows": rows, "wall_s": r["wall_s"],
                                 "rows_per_s": rows / r["wall_s"], "peak_rss_mb": r["peak_rss_mb"], "score": score})
                print(f"  {label}, {size_mb:.0f} MB: {r['wall_s']:.2f} s, {r['peak_rss_mb']:.0f} MB", file=sys.stderr)
            path.unlink()
    c = c_alone(max(r["rows"] for r in rows_out))
    print("| log | rows | `run` wall s | `run` rows/s | peak RSS MB | C alone rows/s (ctypes) | C ns/step |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows_out:
        print(f"| {r['file_mb']:.0f} MB ({r['tree']}) | {r['rows']:,} | {r['wall_s']:.2f} | {r['rows_per_s'] / 1e6:.2f} M "
              f"| {r['peak_rss_mb']:.0f} | {c['rows_per_s'] / 1e6:.1f} M | {c['c_ns_per_step']:.0f} |")
    print(f"targets (issue 27): peak RSS <= 300 MB and >= 1 M rows/s on the 1 GB log; cpus: {os.cpu_count()}")
    if args.json:
        Path(args.json).write_text(json.dumps({"written_by": "ahrsgen studies/large_log_bench.py", "runs": rows_out,
                                               "c_alone": c, "cpus": os.cpu_count()}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
