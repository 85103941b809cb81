"""Fuzzing the step: libFuzzer with AddressSanitizer and UndefinedBehaviorSanitizer over
src/ahrsgen/sim/fuzz/fuzz_step.c; the input format (records of sensor bit patterns and dt), the
seed corpus, the known issues and the fixed crashes replayed on every run."""
from __future__ import annotations

import math
import os
import re
import shutil
import struct
import subprocess
import time
from pathlib import Path

from ahrsgen.check import tools
from ahrsgen.check.layout import BUILD, FUZZ_DIR, invariant_plan, load_manifest
from ahrsgen.check.tools import FUZZ_FLAGS, _build

# Bugs the fuzzer found that are not fixed yet (owned elsewhere). While listed, the fuzz run of
# that filter is compiled with the exclusion ("defines", see fuzz_step.c) so it can explore past
# the known crash, and the reproducer is replayed on every run and reported as still present or
# fixed. Entry: {"id", "what", "defines": {...}, "reproducer": hex}.
KNOWN_ISSUES: dict[str, list[dict]] = {}

# Crashes found by the fuzzer and since fixed: replayed against every generated filter of the same
# precision on every run (they are plain fuzz inputs), so none comes back anywhere.
REGRESSIONS: list[dict] = [
    {
        "id": "mekf-huge-gps-velocity", "precision": "float", "found_in": "mekf",
        "what": "finite but huge GPS velocity (3e38 m/s, valid bit set) with the accelerometer skipped "
                "(ACCEL_RANGE) made the attitude NaN on the 3rd such step, status only 0x400: no range check "
                "on GPS, and the masked update multiplied masked rows by 0 (NaN once omega x v_gps overflowed)",
        "fixed_by": "0aa25c5 (gps_vel_max, GPS_VEL_RANGE; masks as selects), 6f9890a (shared GPS range check)",
        # flags 0x01 (warm-up), record 0 (refused: dt < 0), record 1: gyro [2.99 -0.014 -0.014],
        # accel [6e-41 3e38 3e38], mag [3e38 6e-41 3e38], gps [3e38 3e38 3e38], valid 0x7f, dt 0.01
        "reproducer": "01000f00000000000000000000000000000000000000000ae81cc13d000000000000000ad7233c000fe6b1617f"
                      "0000000000000000e6b1617fe6b161ffe6b1617fe6b1617fe6b100000009617fe6b1617fe6b1617fe6b10000"
                      "0009617fe6b1617fe6b1617fe6b1617f0ad7233c",
    },
    {
        "id": "mekf-denormal-dt", "precision": "float", "found_in": "mekf",
        "what": "dt = 1.4e-45 s (smallest positive float, accepted since dt > 0) made P NaN for good: the "
                "process noise gyro_noise^2 / dt overflowed to inf, and inf times the zero entries of G is NaN",
        "fixed_by": "0aa25c5 (sigma^2 / max(dt, 1e-9))",
        # flags 0x01 (warm-up), one record: valid 0x03, gyro 0, accel [0 0 -9.80665], dt 0x1p-149
        "reproducer": "01000300000000000000000000000000000000000000000ae81cc1000000000000000000000000000000000000"
                      "00000000000001000000",
    },
    {
        "id": "mekf-P-not-pd-near-pitch-90", "precision": "float", "found_in": "mekf",
        "what": "P indefinite (LDL^T pivot 2 = -1.14e-05 with P_22 = 0.0044) at step 95 of 256, after pitch walked "
                "to 89.4 deg on dt = 1e-4 s gyro steps and GPS-course updates (H ~ 1/cos(pitch) ~ 140) hit a nearly "
                "singular roll/yaw block of P: the textbook Joseph product (I - KH) P (I - KH)^T cancelled terms "
                "|KH|^2 |P| ~ 500 down to an eigenvalue of 3e-8, which float rounding cannot hold",
        "fixed_by": "the Joseph form evaluated expanded, P - K(HP) - (HP)^T K^T + K S K^T (src/ahrsgen/symbolic/linalg.py)",
        # ahrsgen harden mekf --seed 7 --fuzz-seconds 90; also tests/data/mekf-P-not-pd.bin
        "reproducer": (
                      "00000f0000000000000000000000000ae81c4123040000000000000000004000000000000000003f0000000000000000"
                      "000000000ad7233c0000ffffffffffffffffffffffffffffffffffffffffffffffffffff00000000000000000ad7233c"
                      "0000ffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffff5e5e5e5e"
                      "ffffffffffffffffffffffffff0f0000fd00000000000000000000000000000000e7000000000000000a3de81c410400"
                      "00ffffffffffffffffffffffffffff999999999999999999999999999999999999999999999999999999999999999999"
                      "999999999999999999999999999999000000ccbc8c2b0000000000000000009999999999999999999999999999999900"
                      "0000000000000000000000000000000000000000000000000000000000000000fbffffff000000000000000000000000"
                      "00000000000000000000000000000000000000000000ccbc8c2b00000000000000000000000000999999999999999999"
                      "9999999999999999999999999999ffffffffffffffffffffffffffffff0f000000000000000000000000e70000000000"
                      "00000a3de81c410400000000000000001600003f0100000000000000000002000ad7"
        ),
    },
]


def regressions_for(man: dict) -> list[dict]:
    return [r for r in REGRESSIONS if r["precision"] == man["precision"]]


FUZZ_STEPS = 256          # steps per fuzz input (AHRS_FUZZ_STEPS in fuzz_step.c)
MAX_RECORDS = 64


def known_issues(gen_dir: str | Path) -> list[dict]:
    return KNOWN_ISSUES.get(load_manifest(gen_dir)["filter"], [])


def build_fuzzer(gen_dir: str | Path, exclude_known: bool = False) -> Path:
    """The libFuzzer binary; with exclude_known, compiled with the listed known-issue exclusions."""
    defines = []
    if exclude_known:
        for issue in known_issues(gen_dir):
            defines += [f"-D{k}={v}" for k, v in issue.get("defines", {}).items()]
    return _build("fuzz", Path(gen_dir), tools.CLANG, FUZZ_FLAGS + defines, FUZZ_DIR / "fuzz_step.c",
                  "-excl" if defines else "")


def real_fmt(man: dict) -> str:
    return "<f" if man["precision"] == "float" else "<d"


def record_size(man: dict) -> int:
    return 2 + 13 * struct.calcsize(real_fmt(man))


def make_record(man: dict, gyro=(0, 0, 0), accel=(0, 0, -9.80665), mag=(0.21, 0, 0.43), gps=(0, 0, 0),
                dt=0.01, valid=0xF, ctrl=0) -> bytes:
    fmt = real_fmt(man)
    vals = [*gyro, *accel, *mag, *gps, dt]
    return bytes([ctrl & 0xFF, valid & 0xFF]) + b"".join(struct.pack(fmt, float(v)) for v in vals)


def seed_inputs(man: dict) -> dict[str, bytes]:
    """A small starting corpus: nominal flight, then the classic glitches, with and without warm-up."""
    nan, inf = float("nan"), float("inf")
    fmt = real_fmt(man)
    tiny = 1e-40 if man["precision"] == "float" else 1e-310      # denormal
    huge = 3e38 if man["precision"] == "float" else 1e300
    dt_max = float(man["params"].get("dt_max", 0.5))
    nominal = make_record(man)
    gps = make_record(man, gps=(5, 0, 0))
    glitches = {
        "nan_gyro": make_record(man, gyro=(nan, 0, 0)),
        "inf_accel": make_record(man, accel=(inf, 0, -9.8)),
        "nan_mag": make_record(man, mag=(0.2, nan, 0.4)),
        "nan_gps": make_record(man, gps=(nan, 1, 0)),
        "zero_accel": make_record(man, accel=(0, 0, 0)),
        "zero_mag": make_record(man, mag=(0, 0, 0)),
        "denormal_all": make_record(man, gyro=(tiny,) * 3, accel=(tiny,) * 3, mag=(tiny,) * 3, gps=(tiny,) * 3, dt=tiny),
        "huge": make_record(man, gyro=(huge, 0, 0), accel=(huge, -huge, huge), mag=(huge,) * 3, gps=(huge,) * 3),
        "dt_zero": make_record(man, dt=0.0),
        "dt_smallest": make_record(man, dt=struct.unpack(fmt, (1).to_bytes(struct.calcsize(fmt), "little"))[0]),
        "dt_neg_zero": make_record(man, dt=-0.0),
        "dt_max": make_record(man, dt=dt_max),
        "dt_above_max": make_record(man, dt=dt_max * (1 + 1e-6)),
        "gyro_edge": make_record(man, gyro=(float(man["params"].get("gyro_max", 70.0)), 0, 0), dt=dt_max),
        "accel_edge": make_record(man, accel=(float(man["params"].get("accel_max", 2000.0)), 0, 0)),
        "accel_min": make_record(man, accel=(0, 0, -float(man["params"].get("accel_min_norm", 0.5)))),
        "gravity_up": make_record(man, accel=(0, 0, 9.80665)),
        "accel_along_x": make_record(man, accel=(9.80665, 0, 0), mag=(0, 0, 0.5)),
        "mag_along_gravity": make_record(man, mag=(0, 0, 0.5)),
        "no_valid": make_record(man, valid=0),
        "junk_valid_bits": make_record(man, valid=0xFF),
    }
    out = {"nominal": b"\x00" + nominal * 4 + gps, "plausible": b"\x00" + make_record(man, ctrl=0x1F) * 3}
    for name, rec in glitches.items():
        out[f"{name}"] = b"\x00" + rec
        out[f"{name}_after_warmup"] = b"\x01" + nominal + rec
    return out


def fuzz_dictionary(man: dict) -> str:
    """libFuzzer dictionary: the bytes of the float values where behaviour changes (every numeric
    parameter, its neighbours, and its square for the norm thresholds) and IEEE specials."""
    fmt = real_fmt(man)
    size = struct.calcsize(fmt)
    vals = {0.0, -0.0, 1.0, -1.0, 9.80665, -9.80665, float("inf"), float("-inf"), float("nan"),
            3.4028234663852886e38 if size == 4 else 1.7976931348623157e308,
            1.1754943508222875e-38 if size == 4 else 2.2250738585072014e-308}
    smallest = struct.unpack(fmt, (1).to_bytes(size, "little"))[0]
    vals |= {smallest, -smallest}
    for v in man["params"].values():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v != 0:
            for x in (v, -v, v * v, math.nextafter(v, math.inf), math.nextafter(v, -math.inf)):
                vals.add(float(x))
    lines = []
    for i, v in enumerate(sorted(vals, key=repr)):
        try:
            b = struct.pack(fmt, v)
        except OverflowError:
            continue
        lines.append(f'v{i}="' + "".join(f"\\x{c:02x}" for c in b) + '"')
    return "\n".join(lines) + "\n"


def decode_input(data: bytes, man: dict) -> tuple[int, list[dict]]:
    """(flags, records) of a fuzz input as the harness reads it (mirrors decode() in fuzz_step.c).

    Each record: {"ctrl", "valid", "gyro", "accel", "mag", "gps", "dt"}, values in double (the C
    rounds them to its real type; the "plausible" values are made in double there too).
    """
    fmt = real_fmt(man)
    size = struct.calcsize(fmt)
    rs = record_size(man)
    if len(data) < 1 + rs:
        return (data[0] if data else 0), []
    nrec = min((len(data) - 1) // rs, MAX_RECORDS)
    nominal = [(0, 0, 0), (0, 0, -9.80665), (0.21, 0, 0.43), (0, 0, 0)]
    spread = [3.0, 4.0, 0.2, 30.0]
    records = []
    for r in range(nrec):
        rec = data[1 + r * rs: 1 + (r + 1) * rs]
        ctrl, valid = rec[0], rec[1]
        vals = []
        for i in range(13):
            p = rec[2 + i * size: 2 + (i + 1) * size]
            k = i // 3
            if (k < 4 and ctrl & (1 << k)) or (k == 4 and ctrl & 0x10):
                u = struct.unpack("<I", p[:4])[0] / 4294967295.0
                lo, hi = (1e-4, 0.05) if k == 4 else (nominal[k][i % 3] - spread[k], nominal[k][i % 3] + spread[k])
                vals.append(lo + (hi - lo) * u)
            else:
                vals.append(struct.unpack(fmt, p)[0])
        records.append({"ctrl": ctrl, "valid": valid, "gyro": vals[0:3], "accel": vals[3:6], "mag": vals[6:9],
                        "gps": vals[9:12], "dt": vals[12]})
    return data[0], records


def describe_input(data: bytes, man: dict) -> list[str]:
    """Human-readable decoding of a fuzz input (decode_input)."""
    flags, records = decode_input(data, man)
    if not records:
        return [f"{len(data)} bytes: too short for one record (ignored by the harness)"]
    lines = [f"flags 0x{flags:02x} ({'warm-up first' if flags & 1 else 'no warm-up'})"]
    g = lambda a: "[" + ", ".join(f"{v:.6g}" for v in a) + "]"   # noqa: E731
    for r, d in enumerate(records):
        lines.append(f"record {r}: valid 0x{d['valid']:02x} gyro {g(d['gyro'])} accel {g(d['accel'])} "
                     f"mag {g(d['mag'])} gps {g(d['gps'])} dt {d['dt']:.9g} (ctrl 0x{d['ctrl']:02x})")
    return lines


_STAT = re.compile(r"stat::(\w+):\s*(\d+)")
_COV = re.compile(r"cov: (\d+) ft: (\d+)")


def run_fuzz(gen_dir: str | Path, seconds: float | None = None, runs: int | None = None, seed: int = 1,
             workdir: str | Path | None = None, max_len: int | None = None, exclude_known: bool = True) -> dict:
    """Fuzz one filter's step. Returns executions, coverage and any crash (with its decoded input).
    Known issues (KNOWN_ISSUES) are replayed and, with exclude_known, excluded from the run."""
    gen_dir = Path(gen_dir)
    man = load_manifest(gen_dir)
    known = []
    for issue in known_issues(gen_dir):
        rc, err = replay(gen_dir, bytes.fromhex(issue["reproducer"]))
        known.append({"id": issue["id"], "what": issue["what"], "still_present": rc != 0,
                      "excluded_by": issue.get("defines", {}) if exclude_known else {},
                      "replay": _failure_summary(err) if rc != 0 else "no violation"})
    regressions = []
    for reg in regressions_for(man):
        rc, err = replay(gen_dir, bytes.fromhex(reg["reproducer"]))
        regressions.append({"id": reg["id"], "ok": rc == 0, "replay": "no violation" if rc == 0 else _failure_summary(err)})
    exe = build_fuzzer(gen_dir, exclude_known=exclude_known)
    work = Path(workdir) if workdir else BUILD / "runs" / f"{man['prefix']}-fuzz-seed{seed}"
    if work.exists():
        shutil.rmtree(work)
    corpus = work / "corpus"
    corpus.mkdir(parents=True)
    for name, data in seed_inputs(man).items():
        (corpus / name).write_bytes(data)
    if max_len is None:
        max_len = 1 + record_size(man) * 16
    (work / "floats.dict").write_text(fuzz_dictionary(man))
    cmd = [str(exe), str(corpus), f"-seed={seed}", f"-max_len={max_len}", "-print_final_stats=1",
           f"-dict={work / 'floats.dict'}", "-use_value_profile=1",
           "-timeout=20", "-rss_limit_mb=2048", f"-artifact_prefix={work}/", "-reload=0"]
    if runs is not None:
        cmd.append(f"-runs={runs}")
    if seconds is not None:
        cmd.append(f"-max_total_time={int(max(1, seconds))}")
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    log = r.stderr
    (work / "fuzz.log").write_text(log)
    stats = {k: int(v) for k, v in _STAT.findall(log)}
    cov = _COV.findall(log)
    out = {
        "filter": man["filter"], "prefix": man["prefix"], "precision": man["precision"],
        "seed": seed, "runs_limit": runs, "seconds_limit": seconds, "max_len": max_len,
        "steps_per_input": FUZZ_STEPS, "wall_s": round(wall, 2),
        "executions": stats.get("number_of_executed_units"),
        "exec_per_s": stats.get("average_exec_per_sec"),
        "coverage": int(cov[-1][0]) if cov else None, "features": int(cov[-1][1]) if cov else None,
        "peak_rss_mb": stats.get("peak_rss_mb"),
        "returncode": r.returncode, "crashes": [], "known_issues": known, "regressions": regressions, "log": str(work / "fuzz.log"),
        "invariants": invariant_plan(man),
    }
    artifacts = sorted(p for p in work.iterdir() if p.name.split("-")[0] in ("crash", "leak", "timeout", "oom"))
    if r.returncode != 0 or artifacts:
        msg = _failure_summary(log)
        for a in artifacts or [None]:
            entry = {"kind": a.name.split("-")[0] if a else "exit", "message": msg}
            if a:
                data = a.read_bytes()
                entry.update(artifact=str(a), hex=data.hex(), input=describe_input(data, man))
            out["crashes"].append(entry)
    return out


def _failure_summary(log: str) -> str:
    lines = log.splitlines()
    for i, ln in enumerate(lines):
        if "*** ahrs invariant violated" in ln:
            return "\n".join(x.strip() for x in lines[i:i + 8])
    for key in ("runtime error:", "ERROR: AddressSanitizer", "ERROR: libFuzzer", "==ERROR"):
        for ln in lines:
            if key in ln:
                return ln.strip()
    return "\n".join(lines[-5:])


def replay(gen_dir: str | Path, data: bytes) -> tuple[int, str]:
    """Run one input through the fuzz binary (no mutation); (returncode, stderr)."""
    exe = build_fuzzer(gen_dir)
    BUILD.mkdir(parents=True, exist_ok=True)
    p = BUILD / f"replay-{os.getpid()}.bin"
    p.write_bytes(data)
    try:
        r = subprocess.run([str(exe), str(p)], capture_output=True, text=True)
    finally:
        p.unlink(missing_ok=True)
    return r.returncode, r.stderr
