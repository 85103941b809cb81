"""Hardening of the generated C: what happens when a sensor glitches.

Three checks per generated filter directory (generated/<name>/ or any `ahrsgen generate` output):

- **fuzz**: `src/ahrsgen/sim/fuzz/fuzz_step.c` is compiled with the filter under libFuzzer,
  AddressSanitizer and UndefinedBehaviorSanitizer (clang). It feeds arbitrary bit patterns to
  every input field and dt, steps a fresh state a few hundred times per input and aborts when
  an invariant breaks (src/ahrsgen/sim/fuzz/ahrs_invariants.h).
- **soak**: `src/ahrsgen/sim/c/soak.c` steps the float build millions of times over synthesised
  varied motion with occasional glitches and reports the invariants (max | |q| - 1 |, covariance
  asymmetry, smallest LDL^T pivot, ...) as JSON, per tenth of the run so drift would show.
- **cppcheck**: static analysis of the generated source and header.

Both C harnesses are generic: the per-filter facts (which state fields are quaternions, which
is a covariance, the status bits) come from the filter's manifest.json through a small
`ahrs_layout.h` written here. Conventions read from the manifest:
  real state field named `q`, `q_*` (4 reals) or documented as quaternion(s) -> unit quaternions
  (an array of several, e.g. particles, only once the `initialised` flag is set);
  a real field named `P` (or documented as a covariance) with n*n reals -> symmetric positive
  definite; a field named `weights` -> non-negative, summing to 1 (to the real field
  `weight_sum`, if there is one: weights kept unnormalised with their sum).

Entry points: `harden(gen_dir, ...)` (all three), `run_fuzz`, `run_soak`, `run_cppcheck`, and
`ahrsgen harden FILTER|all` (register_cli).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import struct
import subprocess
import time
from pathlib import Path

from ahrsgen import paths

FUZZ_DIR = paths.harness_dir("fuzz")
C_DIR = paths.harness_dir("c")
GENERATED = paths.CHECKOUT / "generated" if paths.CHECKOUT else None   # committed builds (checkout only)
BUILD = paths.build_dir("harden", "AHRSGEN_BUILD_HARDEN")

CLANG = os.environ.get("AHRSGEN_CLANG", "clang")
CPPCHECK = os.environ.get("AHRSGEN_CPPCHECK", "cppcheck")

FUZZ_FLAGS = ["-std=c99", "-g", "-O1", "-fsanitize=fuzzer,address,undefined", "-fno-sanitize-recover=all",
              "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]
SOAK_FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra"]
# Checks asked of cppcheck; every suppression must carry a written reason (none needed so far).
CPPCHECK_ARGS = ["--enable=warning,style,performance,portability", "--std=c99", "--error-exitcode=1",
                 "--inline-suppr", "--quiet", "-U__cplusplus",
                 "--template={file}:{line}: {severity} [{id}] {message}"]
CPPCHECK_SUPPRESSIONS: dict[str, str] = {}   # id -> reason

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


class HardenError(RuntimeError):
    pass


# ---------------------------------------------------------------- manifest -> layout header

def load_manifest(gen_dir: Path) -> dict:
    return json.loads((Path(gen_dir) / "manifest.json").read_text())


def _is_quat(f: dict) -> bool:
    if f["type"] != "real" or f["count"] % 4:
        return False
    doc = f.get("doc", "").lower()
    return f["name"] == "q" or (f["name"].startswith("q_") and f["count"] == 4) or "quaternion" in doc


def _cov_dim(f: dict) -> int | None:
    if f["type"] != "real":
        return None
    n = math.isqrt(f["count"])
    if n < 2 or n * n != f["count"]:
        return None
    doc = f.get("doc", "").lower()
    if f["name"] == "P" or "covariance" in doc:
        return n
    return None


def invariant_plan(man: dict) -> dict:
    """Which state fields get which check (read from the manifest; reported with the results)."""
    fields = man["structs"]["state"]["fields"]
    names = {f["name"] for f in fields}
    return {
        "finite": [f["name"] for f in fields if f["type"] == "real"],
        "quaternions": [(f["name"], f["count"] // 4) for f in fields if _is_quat(f)],
        "covariances": [(f["name"], _cov_dim(f)) for f in fields if _cov_dim(f)],
        "weights": next((f["name"] for f in fields if f["name"] == "weights" and f["type"] == "real"), None),
        "initialised": "initialised" if "initialised" in names else None,
    }


def layout_header(man: dict) -> str:
    fields = man["structs"]["state"]["fields"]
    plan = invariant_plan(man)
    by = {f["name"]: f for f in fields}

    def ptr(name):
        return f"&(s)->{name}" if by[name]["count"] == 1 else f"(s)->{name}"

    status_all = 0
    for v in man["status"].values():
        status_all |= int(v)
    lines = [
        f"/* ahrs_layout.h for {man['filter']} ({man['precision']}): written by src/ahrsgen/check/harden.py from",
        " * manifest.json - do not edit. See src/ahrsgen/sim/fuzz/ahrs_invariants.h. */",
        "#ifndef AHRS_LAYOUT_H", "#define AHRS_LAYOUT_H",
        f"#define AHRS_PREFIX {man['prefix']}",
        f"#define AHRS_HEADER \"{man['files']['header']}\"",
        f"#define AHRS_REAL {man['precision']}",
        f"#define AHRS_REFUSED_MASK {int(man['refused_mask'])}u",
        f"#define AHRS_STATUS_ALL {status_all}u",
        "#define AHRS_FOR_EACH_REAL(X, s) " + " ".join(
            f'X("{n}", {ptr(n)}, {by[n]["count"]})' for n in plan["finite"]),
        "#define AHRS_FOR_EACH_QUAT(X, s) " + " ".join(
            f'X("{n}", {ptr(n)}, {nq}, {1 if nq > 1 else 0})' for n, nq in plan["quaternions"]),
    ]
    if plan["covariances"]:
        lines.append("#define AHRS_FOR_EACH_COV(X, s) " + " ".join(
            f'X("{n}", (s)->{n}, {d})' for n, d in plan["covariances"]))
    if plan["weights"]:
        lines += [f"#define AHRS_WEIGHTS_FIELD {plan['weights']}",
                  f"#define AHRS_WEIGHTS_COUNT {by[plan['weights']]['count']}"]
        if "weight_sum" in by and by["weight_sum"]["type"] == "real" and by["weight_sum"]["count"] == 1:
            lines.append("#define AHRS_WEIGHT_SUM_FIELD weight_sum")
    if plan["initialised"]:
        lines.append("#define AHRS_INIT_FIELD initialised")
    lines += ["#endif", ""]
    return "\n".join(lines)


def resolve_dir(filter_or_dir: str | Path) -> Path:
    """A directory with manifest.json, the committed generated/NAME of a checkout, or else any
    filter (name or filter folder, see ahrsgen.filters) generated with its defaults into the
    build directory."""
    p = Path(filter_or_dir)
    if (p / "manifest.json").exists():
        return p
    if GENERATED is not None and (GENERATED / str(filter_or_dir) / "manifest.json").exists():
        return GENERATED / str(filter_or_dir)
    from ahrsgen.generate import config, render
    cfg = config.resolve(str(filter_or_dir))       # unknown filter -> ConfigError naming it
    out = BUILD / "generated" / cfg.filter
    render.write(render.render(cfg), out)
    return out


def generated_dirs() -> list[Path]:
    """'all': the committed builds of a checkout, else every known filter's default build."""
    if GENERATED is not None and GENERATED.is_dir():
        return sorted(d for d in GENERATED.iterdir() if (d / "manifest.json").exists())
    from ahrsgen import filters
    return [resolve_dir(n) for n in filters.names()]


# ---------------------------------------------------------------- tools

def have_tool(name: str) -> bool:
    return shutil.which(name) is not None


_FUZZER_OK: dict[str, bool] = {}


def clang_fuzzer_works() -> bool:
    """clang present and -fsanitize=fuzzer,address,undefined links."""
    if CLANG in _FUZZER_OK:
        return _FUZZER_OK[CLANG]
    ok = False
    if have_tool(CLANG):
        d = BUILD / "probe"
        d.mkdir(parents=True, exist_ok=True)
        src = d / "probe.c"
        src.write_text("#include <stdint.h>\n#include <stddef.h>\n"
                       "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void)d; (void)n; return 0; }\n")
        r = subprocess.run([CLANG, "-fsanitize=fuzzer,address,undefined", str(src), "-o", str(d / "probe")],
                           capture_output=True, text=True)
        ok = r.returncode == 0
    _FUZZER_OK[CLANG] = ok
    return ok


def _build(kind: str, gen_dir: Path, compiler: str, flags: list[str], harness: Path, tag: str = "") -> Path:
    man = load_manifest(gen_dir)
    layout = layout_header(man)
    src = gen_dir / man["files"]["source"]
    hdr = gen_dir / man["files"]["header"]
    h = hashlib.sha256()
    for p in (src, hdr, harness, FUZZ_DIR / "ahrs_invariants.h"):
        h.update(p.read_bytes())
    h.update(layout.encode())
    h.update(" ".join([compiler] + flags).encode())
    out = BUILD / f"{man['prefix']}-{kind}{tag}-{h.hexdigest()[:16]}"
    exe = out / f"{kind}_{man['prefix']}"
    if exe.exists():
        return exe
    out.mkdir(parents=True, exist_ok=True)
    (out / "ahrs_layout.h").write_text(layout)
    cmd = [compiler, *flags, f"-I{out}", f"-I{FUZZ_DIR}", f"-I{gen_dir}", str(harness), str(src),
           "-o", str(exe) + ".tmp", "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise HardenError(f"building the {kind} harness for {gen_dir} failed:\n{' '.join(cmd)}\n{r.stderr}")
    os.replace(str(exe) + ".tmp", exe)
    return exe


def known_issues(gen_dir: str | Path) -> list[dict]:
    return KNOWN_ISSUES.get(load_manifest(gen_dir)["filter"], [])


def build_fuzzer(gen_dir: str | Path, exclude_known: bool = False) -> Path:
    """The libFuzzer binary; with exclude_known, compiled with the listed known-issue exclusions."""
    defines = []
    if exclude_known:
        for issue in known_issues(gen_dir):
            defines += [f"-D{k}={v}" for k, v in issue.get("defines", {}).items()]
    return _build("fuzz", Path(gen_dir), CLANG, FUZZ_FLAGS + defines, FUZZ_DIR / "fuzz_step.c",
                  "-excl" if defines else "")


def build_soak(gen_dir: str | Path) -> Path:
    cc = os.environ.get("CC", "cc")
    return _build("soak", Path(gen_dir), cc, SOAK_FLAGS, C_DIR / "soak.c")


# ---------------------------------------------------------------- fuzz input format

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


# ---------------------------------------------------------------- fuzz

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


# ---------------------------------------------------------------- soak

def site_field(params: dict) -> tuple[float, float]:
    """(declination, inclination) in rad that the filter's baked parameters assume (inclination
    60 deg when the filter does not fix one), so the soak's magnetic field matches its site."""
    decl = float(params.get("declination", 0.0))
    incl = math.radians(float(params.get("inclination_deg", 60.0)))
    return decl, incl


def run_soak(gen_dir: str | Path, steps: int = 10_000_000, seed: int = 1, glitch_rate: float = 1e-3,
             varied: bool = True, gyro_bias_scale: float = 1.0) -> dict:
    """Soak one filter (float or double build as generated); see src/ahrsgen/sim/c/soak.c."""
    gen_dir = Path(gen_dir)
    exe = build_soak(gen_dir)
    decl, incl = site_field(load_manifest(gen_dir)["params"])
    r = subprocess.run([str(exe), str(int(steps)), str(int(seed)), repr(float(glitch_rate)), "1" if varied else "0",
                        repr(decl), repr(incl), repr(float(gyro_bias_scale))],
                       capture_output=True, text=True)
    if r.returncode not in (0, 1) or not r.stdout.strip():
        raise HardenError(f"soak of {gen_dir} failed (exit {r.returncode}):\n{r.stderr}")
    out = json.loads(r.stdout)
    out["invariants"] = invariant_plan(load_manifest(gen_dir))
    return out


# ---------------------------------------------------------------- cppcheck

def build_kernels(man: dict) -> list:
    """The kernel objects (ahrsgen.codegen.emit.Kernel) of a generated build, emitted again
    from its manifest: filter, parameters, precision, prefix, math, fma, runtime parameters."""
    from ahrsgen.generate import config, render
    runtime = [r["name"] for r in man.get("runtime_params", [])]
    cfg = config.resolve(man["filter"], precision=man["precision"], prefix=man["prefix"], math=man["math"],
                         fma=man["fma"], runtime=runtime, values=man["params"])
    return render.render(cfg).kernels


def emitted_functions(text: str, kernels: list) -> tuple[list[dict], list[str]]:
    """Where each C function of the kernels (a split kernel's parts, then itself) lies in a
    generated source: its printed text (ir's printer) found as it is. Returns ([{name, function (ir.Function), lines (body lines), span}], issues: a function
    the source does not hold as the kernels print it)."""
    found, issues = [], []
    for k in kernels:
        for f in k.functions():
            code = f.source()
            at = text.find(code)
            if at < 0:
                issues.append(f"{f.name}: not in the source as its manifest's configuration emits it")
                continue
            found.append({"name": f.name, "function": f, "kernel": k, "lines": len(f.lines()),
                          "span": (at, at + len(code))})
    return found, issues


def kernel_issues(k) -> list[str]:
    """kernel_structure_issues of every function of a kernel; a split kernel's parts may each
    write some of its output elements (emit's early_writes), so across the parts and the
    kernel every output element is written exactly once."""
    issues, written = [], {}
    for f in k.functions():
        got, w = _structure(f, partial=bool(k.parts))
        issues += got
        for key, n in w.items():
            written[key] = written.get(key, 0) + n
    for p in k.function().params:
        if p.output:
            for i in range(p.size or 1):
                if written.get((p.name, i), 0) != 1:
                    issues.append(f"{k.name}: output {p.name}[{i}] written {written.get((p.name, i), 0)} times")
    return issues


def kernel_structure_issues(f, partial: bool = False) -> list[str]:
    """What cppcheck looks for in emitted code, checked exactly on the kernel's statements
    (ahrsgen.codegen.emit.ir.Function): every indexed access within the declared size of its
    array, inputs only read, every temporary defined once before use (a temporary defined inside
    a branch is visible only there; a select an If declares must be set exactly once on each
    side, and is defined after it), every output element written exactly once. A split
    kernel's own local arrays (carry, and flags for its bools) are bounded by their declarations
    and filled by its parts (each part is checked as a function of its own; a part writes only
    the slots of its exports, each at most once). partial: the function is one part of a
    kernel, writing each output element at most once (kernel_issues checks the whole)."""
    return _structure(f, partial)[0]


def _structure(f, partial: bool) -> tuple[list[str], dict]:
    from ahrsgen.codegen.emit import ir
    issues, written = [], {}
    params = {p.name: p for p in f.params}
    arrays = {p.name: p.size for p in f.params if p.size is not None}
    for name in f.unused:
        if name not in params:
            issues.append(f"{f.name}: (void) of unknown name {name}")
    scopes = [set()]            # temporaries defined, innermost scope last
    pending: set = set()        # selects declared by the enclosing Ifs and not yet defined

    def visible(t):
        return any(t in sc for sc in scopes)

    def check_expr(e, where):
        for x in ir.walk(e):
            if isinstance(x, ir.Elem):
                p = params.get(x.arg)
                if p is None:
                    issues.append(f"{where}: {x.arg} is not a parameter")
                elif (x.index is None) != (p.size is None):
                    issues.append(f"{where}: {x.arg} read unlike its declaration")
                elif x.index is not None and not 0 <= x.index < p.size:
                    issues.append(f"{where}: {x.arg}[{x.index}] out of bounds (size {p.size})")
            elif isinstance(x, ir.Slot):
                if x.array not in arrays:
                    issues.append(f"{where}: {x.array}[{x.index}] is not an array")
                elif not 0 <= x.index < arrays[x.array]:
                    issues.append(f"{where}: {x.array}[{x.index}] out of bounds (size {arrays[x.array]})")
            elif isinstance(x, ir.Ctx):
                if not any(p.pointer and p.const and p.size is None for p in f.params):
                    issues.append(f"{where}: {x.text} read without a context parameter")
            elif isinstance(x, ir.Temp) and not visible(x):
                issues.append(f"{where}: {x.name} used before it is defined")

    def define(t, where):
        if visible(t) or t in pending:
            issues.append(f"{where}: {t.name} defined twice")
        scopes[-1].add(t)

    def run(stmts, path, selects) -> set:
        """Check a statement list; returns the selects (of `selects`, the enclosing If's) it sets."""
        done = set()
        for n, s in enumerate(stmts, 1):
            where = f"{f.name} statement {path}{n}"
            if isinstance(s, ir.Let):
                check_expr(s.expr, where)
                define(s.temp, where)
            elif isinstance(s, ir.SinCos):
                check_expr(s.arg, where)
                define(s.sin, where)
                define(s.cos, where)
            elif isinstance(s, ir.If):
                check_expr(s.cond, where)
                for t in s.declare:
                    if visible(t) or t in pending:
                        issues.append(f"{where}: {t.name} defined twice")
                pending.update(s.declare)
                sides = []
                for side, block in (("then", s.then), ("else", s.orelse)):
                    scopes.append(set())
                    sides.append(run(block, f"{path}{n}.{side}.", set(s.declare)))
                    scopes.pop()
                if sides[0] != sides[1]:
                    issues.append(f"{where}: the sides set different selects: "
                                  f"{sorted(t.name for t in sides[0] ^ sides[1])}")
                for t in s.declare:
                    pending.discard(t)
                    if t in sides[0] and t in sides[1]:
                        scopes[-1].add(t)
                    else:
                        issues.append(f"{where}: {t.name} declared but not set on both sides")
            elif isinstance(s, ir.Set):
                check_expr(s.expr, where)
                if s.temp not in selects:
                    issues.append(f"{where}: {s.temp.name} set outside its branch or not declared")
                elif s.temp in done:
                    issues.append(f"{where}: {s.temp.name} set twice on one side")
                done.add(s.temp)
            elif isinstance(s, ir.Store):
                check_expr(s.expr, where)
                t = s.target
                name, i = (t.array, t.index) if isinstance(t, ir.Slot) else (t.arg, t.index or 0)
                p = params.get(name)
                if isinstance(t, ir.Slot) and name in arrays and (p is None or not p.const):
                    if not 0 <= i < arrays[name]:
                        issues.append(f"{where}: {name}[{i}] out of bounds (size {arrays[name]})")
                elif p is None or not p.output:
                    issues.append(f"{where}: writes {name}, which is not an output parameter")
                    continue
                elif (t.index is None) != (p.size is None) or (p.size is not None and not 0 <= i < p.size):
                    issues.append(f"{where}: {name}[{i}] out of bounds")
                written[(name, i)] = written.get((name, i), 0) + 1
            elif isinstance(s, ir.Local):
                arrays[s.array] = s.size
            elif isinstance(s, ir.PartCall):
                for a in s.args:
                    if a not in params and a not in arrays:
                        issues.append(f"{where}: {a} passed to {s.part} is neither a parameter nor a local array")
            elif not isinstance(s, ir.Comment):
                issues.append(f"{where}: not an emitted statement: {s!r}")
        return done

    run(f.body, "", set())
    for p in f.params:
        if not p.output:
            continue
        for i in range(p.size or 1):
            c = written.get((p.name, i), 0)
            if c != 1 and not ((partial or p.name in ("carry", "flags")) and c == 0):
                issues.append(f"{f.name}: output {p.name}[{i}] written {c} times")
    return issues, written


def _stub(f) -> str:
    """The function with a body that only touches its parameters (cppcheck sees the call sites)."""
    body = []
    for p in f.params:
        if not p.output:
            body.append(f"    (void){p.name};")
        elif p.size is None:
            body.append(f"    *{p.name} = 0;")
        else:
            body.append(f"    for (int i = 0; i < {p.size}; i++) {{\n        {p.name}[i] = 0;\n    }}")
    return f.prototype() + "\n{\n" + "\n".join(body) + "\n}"


def run_cppcheck(gen_dir: str | Path, max_kernel_lines: int | None = None, timeout: float | None = None) -> dict:
    """cppcheck the generated source (CPPCHECK_ARGS). cppcheck's value-flow analysis grows
    steeply with function length (a 3270-line emitted kernel takes it over ten minutes), so with
    max_kernel_lines the emitted kernels longer than that are checked by kernel_structure_issues
    instead (bounds, definitions, outputs - exactly, for straight-line code) and replaced by a stub
    for cppcheck; the rest of the file (template, step partial, helpers, shorter kernels) is
    analysed by cppcheck as usual. Without it the whole file goes to cppcheck."""
    gen_dir = Path(gen_dir)
    man = load_manifest(gen_dir)
    src = gen_dir / man["files"]["source"]
    text = src.read_text()
    target, structural, stubbed = src, [], []
    tmpdir = None
    if max_kernel_lines is not None:
        found, structural = emitted_functions(text, build_kernels(man))
        pieces, last, checked = [], 0, []
        for k in sorted(found, key=lambda k: k["span"]):
            if k["lines"] > max_kernel_lines:
                if not any(k["kernel"] is c for c in checked):
                    structural += kernel_issues(k["kernel"])
                    checked.append(k["kernel"])
                stubbed.append(f"{k['name']} ({k['lines']} lines)")
                pieces += [text[last:k["span"][0]], _stub(k["function"])]
                last = k["span"][1]
        if stubbed:
            pieces.append(text[last:])
            tmpdir = BUILD / "cppcheck" / f"{man['prefix']}-{os.getpid()}"
            tmpdir.mkdir(parents=True, exist_ok=True)
            target = tmpdir / src.name
            target.write_text("".join(pieces))
    supp = [f"--suppress={k}" for k in CPPCHECK_SUPPRESSIONS]
    cmd = [CPPCHECK, *CPPCHECK_ARGS, *supp, f"-I{gen_dir}", str(target)]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        rc, err, timed_out = r.returncode, r.stderr, False
    except subprocess.TimeoutExpired:
        rc, err, timed_out = None, "", True
    finally:
        if tmpdir is not None:
            shutil.rmtree(tmpdir, ignore_errors=True)
    issues = [ln for ln in err.splitlines() if ln.strip() and "missingInclude" not in ln]
    return {"filter": man["filter"], "ok": (not timed_out and rc == 0 and not issues and not structural),
            "timed_out": timed_out, "timeout_s": timeout, "returncode": rc, "issues": issues,
            "structural_issues": structural, "structurally_checked": stubbed,
            "command": " ".join(cmd), "wall_s": round(time.perf_counter() - t0, 2),
            "suppressed": CPPCHECK_SUPPRESSIONS}


# ---------------------------------------------------------------- all together

def harden(gen_dir: str | Path, fuzz_seconds: float | None = 60, fuzz_runs: int | None = None,
           soak_steps: int | None = 10_000_000, seed: int = 1, glitch_rate: float = 1e-3,
           do_cppcheck: bool = True, cppcheck_max_kernel_lines: int | None = None,
           cppcheck_timeout: float | None = 3600) -> dict:
    gen_dir = Path(gen_dir)
    man = load_manifest(gen_dir)
    res: dict = {"filter": man["filter"], "dir": str(gen_dir), "precision": man["precision"]}
    if do_cppcheck:
        res["cppcheck"] = (run_cppcheck(gen_dir, cppcheck_max_kernel_lines, cppcheck_timeout) if have_tool(CPPCHECK)
                           else {"skipped": f"{CPPCHECK} not found"})
    if fuzz_seconds or fuzz_runs:
        res["fuzz"] = (run_fuzz(gen_dir, seconds=fuzz_seconds, runs=fuzz_runs, seed=seed)
                       if clang_fuzzer_works() else {"skipped": f"{CLANG} with -fsanitize=fuzzer not available"})
    if soak_steps:
        res["soak"] = run_soak(gen_dir, steps=soak_steps, seed=seed, glitch_rate=glitch_rate)
    res["ok"] = (res.get("cppcheck", {}).get("ok", True) is not False
                 and not res.get("fuzz", {}).get("crashes")
                 and not any(k["still_present"] for k in res.get("fuzz", {}).get("known_issues", []))
                 and all(g["ok"] for g in res.get("fuzz", {}).get("regressions", []))
                 and res.get("soak", {}).get("violations", 0) == 0)
    return res


def _fmt(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


def print_table(results: list[dict]) -> None:
    # no cppcheck column when it was not run (--no-cppcheck): nothing about it to say
    show_cc = any("skipped" not in r.get("cppcheck", {"skipped": True}) for r in results)
    print(f"{'filter':<8} {'cppcheck' if show_cc else '':<9} {'fuzz execs':>11} {'exec/s':>7} {'cov':>5} {'crashes':>7} "
          f"{'soak steps':>11} {'viol':>5} {'max||q|-1|':>10} {'max|P-PT|rel':>12} {'min pivot':>10} "
          f"{'min piv rel':>11} {'ns/step':>8} {'att rms deg':>11}")
    for r in results:
        c, f, s = r.get("cppcheck", {}), r.get("fuzz", {}), r.get("soak", {})
        cc = ("" if not show_cc else "skipped" if "skipped" in c else "-" if not c else "timeout" if c["timed_out"] else "clean" if c["ok"]
              else f"{len(c['issues']) + len(c['structural_issues'])} issues")
        print(f"{r['filter']:<8} {cc:<9} {_fmt(f.get('executions'), 'd'):>11} {_fmt(f.get('exec_per_s'), 'd'):>7} "
              f"{_fmt(f.get('coverage'), 'd'):>5} {len(f.get('crashes', [])) if 'executions' in f else '-':>7} "
              f"{_fmt(s.get('steps'), 'd'):>11} {_fmt(s.get('violations'), 'd'):>5} {_fmt(s.get('max_qnorm_err')):>10} "
              f"{_fmt(s.get('max_asym_rel')):>12} {_fmt(s.get('min_pivot')):>10} {_fmt(s.get('min_pivot_rel')):>11} "
              f"{_fmt(s.get('ns_per_step'), '.0f'):>8} {_fmt(s.get('att_err_rms_deg')):>11}")
    for r in results:
        for cr in r.get("fuzz", {}).get("crashes", []):
            print(f"\n{r['filter']}: fuzz {cr['kind']}: {cr['message']}")
            for ln in cr.get("input", []):
                print(f"    {ln}")
            if "artifact" in cr:
                print(f"    input file {cr['artifact']}")
        for g in r.get("fuzz", {}).get("regressions", []):
            if not g["ok"]:
                print(f"\n{r['filter']}: REGRESSION {g['id']} is back: " + g["replay"].replace("\n", "\n    "))
        for k in r.get("fuzz", {}).get("known_issues", []):
            state = "STILL PRESENT" if k["still_present"] else "fixed (remove it from KNOWN_ISSUES)"
            print(f"\n{r['filter']}: known issue {k['id']}: {state}; fuzzed with {k['excluded_by'] or 'no exclusion'}")
            print(f"    {k['what']}")
            if k["still_present"]:
                print("    replay: " + k["replay"].replace("\n", "\n    "))
        c = r.get("cppcheck", {})
        for iss in c.get("issues", []) + c.get("structural_issues", []):
            print(f"{r['filter']}: cppcheck: {iss}")
        if c.get("structurally_checked"):
            print(f"{r['filter']}: cppcheck: long emitted kernels checked structurally instead: "
                  + ", ".join(c["structurally_checked"]))
        if c.get("timed_out"):
            print(f"{r['filter']}: cppcheck did not finish in {c['timeout_s']} s")
        s = r.get("soak", {})
        if s.get("violations"):
            print(f"{r['filter']}: soak: {s['violations']} violations, first at step {s['first_violation_step']}: "
                  f"{s['first_violation']}")


def unavailable_checks(fuzz: bool, soak: bool, cppcheck: bool) -> list[str]:
    """The asked-for checks that cannot run on this machine, each with what is missing."""
    out = []
    if cppcheck and not have_tool(CPPCHECK):
        out.append(f"cppcheck ({CPPCHECK} not found; install cppcheck, or pass --no-cppcheck)")
    if fuzz and not clang_fuzzer_works():
        out.append(f"fuzzing ({CLANG} -fsanitize=fuzzer,address,undefined does not link; install clang and "
                   f"libclang-rt-14-dev as .ci/setup does, or pass --fuzz-seconds 0)")
    if soak and not have_tool(os.environ.get("CC", "cc")):
        out.append(f"soak (no C compiler '{os.environ.get('CC', 'cc')}'; or pass --soak-steps 0)")
    return out


def cmd_harden(args) -> int:
    from ahrsgen.errors import ConfigError
    try:
        dirs = generated_dirs() if args.filter == "all" else [resolve_dir(args.filter)]
    except HardenError as e:
        raise ConfigError(str(e)) from None
    # A check that was asked for and cannot run is an error, not a '-' in the table.
    cannot = unavailable_checks(bool(args.fuzz_seconds or args.fuzz_runs), bool(args.soak_steps),
                                not args.no_cppcheck)
    if cannot:
        raise ConfigError("cannot run " + "; ".join(cannot))
    out = Path(args.json) if args.json else BUILD / "harden.json"
    from ahrsgen.fileio import check_outputs
    if out.is_dir():
        raise ConfigError(f"--json: {out} is a folder")
    if out.parent.is_dir() or args.json:
        check_outputs([("--json", out)], dirs, args.force)
    results = []
    for d in dirs:
        print(f"harden {d.name}: {'' if args.no_cppcheck else 'cppcheck, '}fuzz {args.fuzz_seconds or 0:g} s"
              f"{f' / {args.fuzz_runs} runs' if args.fuzz_runs else ''}, soak {args.soak_steps} steps ...", flush=True)
        results.append(harden(d, fuzz_seconds=args.fuzz_seconds, fuzz_runs=args.fuzz_runs,
                              soak_steps=args.soak_steps, seed=args.seed, glitch_rate=args.glitch_rate,
                              do_cppcheck=not args.no_cppcheck,
                              cppcheck_max_kernel_lines=args.cppcheck_max_kernel_lines,
                              cppcheck_timeout=args.cppcheck_timeout))
    print()
    print_table(results)
    out.parent.mkdir(parents=True, exist_ok=True)
    from ahrsgen.fileio import write_text_atomic
    write_text_atomic(out, json.dumps({"written_by": "ahrsgen harden", "results": results}, indent=2))
    print(f"\nJSON: {out}")
    return 0 if all(r["ok"] for r in results) else 1


def register_cli(sub) -> None:
    p = sub.add_parser(
        "harden", help="fuzz the step (libFuzzer+ASan+UBSan), soak it, cppcheck the generated C",
        description="For a filter (a name or folder: its committed generated/ build, else its defaults; a "
                    "directory with manifest.json; or 'all'): cppcheck the "
                    "source; fuzz its step with arbitrary float bit patterns under AddressSanitizer and "
                    "UndefinedBehaviorSanitizer, checking the state invariants after every step; soak it "
                    "over synthesised varied motion with glitches. Prints a table, writes JSON. Exit 1 "
                    "on any finding.")
    p.add_argument("filter", help="a filter (name or folder; its committed generated/NAME if there is one, else "
                                  "its defaults), a directory with manifest.json, or 'all'")
    from ahrsgen.argtypes import count_arg, nonneg_float_arg, nonneg_int_arg, positive_int_arg, positive_float_arg
    from ahrsgen.fileio import add_force_option
    p.add_argument("--fuzz-seconds", type=nonneg_float_arg, default=60, metavar="N", help="fuzzing time per filter (default 60; 0 = no fuzzing)")
    p.add_argument("--fuzz-runs", type=count_arg, metavar="N", help="stop fuzzing after N inputs")
    p.add_argument("--soak-steps", type=count_arg, default=10_000_000, metavar="N",
                   help="soak steps, a whole number >= 0 such as 100000 or 1e7 (default 1e7; 0 = no soak)")
    p.add_argument("--seed", type=nonneg_int_arg, default=1, help="fuzzer and soak seed, a whole number >= 0 (default 1)")
    p.add_argument("--glitch-rate", type=probability_arg, default=1e-3,
                   help="soak: probability of a glitch per step, 0 to 1 (default 1e-3)")
    p.add_argument("--no-cppcheck", action="store_true", help="skip cppcheck")
    p.add_argument("--cppcheck-max-kernel-lines", type=positive_int_arg, metavar="N",
                   help="emitted kernels longer than N lines are checked structurally (bounds, definitions, "
                        "outputs) instead of by cppcheck, whose analysis of a 3000-line kernel takes minutes "
                        "(default: cppcheck everything)")
    p.add_argument("--cppcheck-timeout", type=positive_float_arg, default=3600, metavar="S", help="cppcheck time limit per filter")
    p.add_argument("--json", metavar="FILE", help="write the results here (default build/harden/harden.json)")
    add_force_option(p)
    p.set_defaults(func=cmd_harden)


def probability_arg(text: str) -> float:
    """A probability: a finite number from 0 to 1."""
    import argparse
    import math
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"expected a probability from 0 to 1, got {text!r}")
    return v
