"""The firmware-like harness outside Python: the standalone executable that runs a harness log
(src/ahrsgen/sim/c/main_log.c), and the hand-written QCF baseline (src/ahrsgen/sim/c/baseline_qcf.c)."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ahrsgen.sim import host
from ahrsgen.sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog
from ahrsgen.bench.common import C_DIR


# =========================================================================================
# Harness: the standalone executable and the hand-written baseline

HARNESS_COLUMNS = "t,gx,gy,gz,ax,ay,az,mx,my,mz,vn,ve,vd"


def write_harness_log(log: SensorLog, path: str | Path) -> Path:
    """Write a SensorLog as the text log main_log.c reads (empty fields: no sample)."""
    path = Path(path)
    groups = ((VALID_GYRO, log.gyro), (VALID_ACCEL, log.accel), (VALID_MAG, log.mag), (VALID_GPS, log.gps_vel))
    from ahrsgen.fileio import write_text_atomic
    lines = ["# ahrsgen harness log v1, written by ahrsgen run --export-log", f"# dt0 {float(log.dt[0])!r}", HARNESS_COLUMNS]
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


