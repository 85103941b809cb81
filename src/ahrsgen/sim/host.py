"""Host harness: compile a generated filter with the system C compiler, load it through
ctypes (structures built from its manifest.json, never typed by hand), and run a whole
SensorLog through it.

Shared libraries are cached under build/host/<hash of sources, flags and compiler>, so an
unchanged filter is compiled once.
"""
from __future__ import annotations

from ahrsgen.errors import BuildError  # noqa: F401  (raised here; callers import it from here too)
import ctypes
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ahrsgen.sim.log import SensorLog
from ahrsgen import paths

HERE = Path(__file__).resolve().parent
C_DIR = HERE / "c"
CACHE = paths.build_dir("host", "AHRSGEN_BUILD")

STRICT = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Wdouble-promotion",
          "-Wshadow", "-Werror"]
# -ffp-contract=off: no fused multiply-add, so the host build rounds like the target build.
HOST_FLAGS = ["-O2", "-fPIC", "-ffp-contract=off", "-fno-math-errno"]


def cc() -> str:
    return os.environ.get("CC", "cc")


def _compiler_id() -> str:
    try:
        return subprocess.run([cc(), "--version"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        raise BuildError(f"no working C compiler ({cc()}): {e}") from None


def compile_shared(gen_dir: Path, extra_sources=(), extra_flags=()) -> Path:
    """Compile the generated filter in gen_dir plus batch.c into a cached shared library."""
    gen_dir = Path(gen_dir)
    man = json.loads((gen_dir / "manifest.json").read_text())
    prefix, real = man["prefix"], man["precision"]
    sources = [gen_dir / man["files"]["source"], C_DIR / "batch.c", *map(Path, extra_sources)]
    defines = [f"-DAHRS_PREFIX={prefix}", f'-DAHRS_HEADER="{man["files"]["header"]}"', f"-DAHRS_REAL={real}"]
    flags = STRICT + HOST_FLAGS + list(extra_flags)
    h = hashlib.sha256()
    for p in sources + [gen_dir / man["files"]["header"]]:
        h.update(p.read_bytes())
    h.update(" ".join(flags + defines).encode())
    h.update(_compiler_id().encode())
    out_dir = CACHE / h.hexdigest()[:20]
    lib = out_dir / f"lib{prefix}.so"
    if lib.exists():
        return lib
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir))
    cmd = [cc(), *flags, *defines, f"-I{gen_dir}", "-shared", "-o", str(tmp / lib.name),
           *map(str, sources), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        raise BuildError(f"compiling {gen_dir} failed:\n{' '.join(cmd)}\n{r.stderr}")
    os.replace(tmp / lib.name, lib)      # atomic, so parallel builds never see half a file
    shutil.rmtree(tmp, ignore_errors=True)
    return lib


_CT = {"float": ctypes.c_float, "double": ctypes.c_double}


def ctypes_struct(name: str, layout: dict, real: str, params=None):
    """ctypes Structure of a manifest layout; `params` is the class of a nested
    runtime-parameter struct (type "params")."""
    fields = []
    for f in layout["fields"]:
        if f["type"] == "params":      # without its class: as many reals, same size and alignment
            base = params or _CT[real] * (f["size"] // ctypes.sizeof(_CT[real]))
            fields.append((f["name"], base))
            continue
        base = _CT[real] if f["type"] == "real" else ctypes.c_uint32
        fields.append((f["name"], base * f["count"] if f["count"] > 1 else base))
    cls = type(name, (ctypes.Structure,), {"_fields_": fields})
    if ctypes.sizeof(cls) != layout["size"]:
        raise BuildError(f"{name}: ctypes size {ctypes.sizeof(cls)} != manifest size {layout['size']}")
    return cls


def numpy_dtype(layout: dict, real: str) -> np.dtype:
    base = {"real": np.float32 if real == "float" else np.float64, "uint32": np.uint32}
    return np.dtype({
        "names": [f["name"] for f in layout["fields"]],
        "formats": [(base[f["type"]], (f["count"],)) if f["count"] > 1 else base[f["type"]] for f in layout["fields"]],
        "offsets": [f["offset"] for f in layout["fields"]],
        "itemsize": layout["size"],
    })


@dataclass
class RunResult:
    q: np.ndarray        # (N,4)
    rpy: np.ndarray      # (N,3)
    status: np.ndarray   # (N,) uint32


class HostFilter:
    """A generated filter compiled for the host and loaded through ctypes."""

    def __init__(self, gen_dir: str | Path):
        self.dir = Path(gen_dir)
        self.manifest = json.loads((self.dir / "manifest.json").read_text())
        self.real = self.manifest["precision"]
        self.np_real = np.float32 if self.real == "float" else np.float64
        self.lib_path = compile_shared(self.dir)
        self.lib = ctypes.CDLL(str(self.lib_path))
        st = self.manifest["structs"]
        self.Params = ctypes_struct("Params", st["params"], self.real) if "params" in st else None
        self.State = ctypes_struct("State", st["state"], self.real, self.Params)
        self.Input = ctypes_struct("Input", st["input"], self.real)
        self.input_dtype = numpy_dtype(st["input"], self.real)
        if self.lib.ahrs_sizeof_state() != ctypes.sizeof(self.State):
            raise BuildError("state struct layout differs between C and the manifest")
        if self.lib.ahrs_sizeof_input() != ctypes.sizeof(self.Input):
            raise BuildError("input struct layout differs between C and the manifest")
        R = _CT[self.real]
        P = ctypes.POINTER
        self.lib.ahrs_step.restype = ctypes.c_uint32
        self.lib.ahrs_step.argtypes = [P(self.State), P(self.Input), R]
        self.lib.ahrs_init.argtypes = [P(self.State)]
        self.lib.ahrs_euler.argtypes = [P(self.State), P(R)]
        self.lib.ahrs_run.argtypes = [P(self.State), ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32,
                                      ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        self.lib.ahrs_time_ns_per_step.restype = ctypes.c_double
        self.lib.ahrs_time_ns_per_step.argtypes = [P(self.State), ctypes.c_void_p, ctypes.c_void_p,
                                                   ctypes.c_uint32, ctypes.c_uint32]

    @property
    def prefix(self) -> str:
        return self.manifest["prefix"]

    @property
    def runtime_params(self) -> list[str]:
        return [r["name"] for r in self.manifest.get("runtime_params", [])]

    def set_params(self, state, values: dict) -> int:
        """<prefix>_set_params with the build's defaults overridden by `values`: 0 applied,
        else the code of the first value out of range (state untouched)."""
        if self.Params is None:
            raise BuildError(f"{self.dir}: no runtime parameters in this build")
        unknown = set(values) - set(self.runtime_params)
        if unknown:
            raise BuildError(f"not runtime parameters of this build: {', '.join(sorted(unknown))}")
        p = self.Params()
        fn = getattr(self.lib, f"{self.prefix}_params_default")
        fn.argtypes = [ctypes.POINTER(self.Params)]
        fn(ctypes.byref(p))
        for k, v in values.items():
            setattr(p, k, float(v))
        fn = getattr(self.lib, f"{self.prefix}_set_params")
        fn.restype = ctypes.c_uint32
        fn.argtypes = [ctypes.POINTER(self.State), ctypes.POINTER(self.Params)]
        return int(fn(ctypes.byref(state), ctypes.byref(p)))

    def new_state(self):
        s = self.State()
        self.lib.ahrs_init(ctypes.byref(s))
        return s

    def copy_state(self, s):
        c = self.State()
        ctypes.memmove(ctypes.byref(c), ctypes.byref(s), ctypes.sizeof(self.State))
        return c

    def state_bytes(self, s) -> bytes:
        return ctypes.string_at(ctypes.byref(s), ctypes.sizeof(self.State))

    def state_dict(self, s) -> dict:
        out = {}
        for name, _ in self.State._fields_:
            v = getattr(s, name)
            out[name] = np.array(v[:]) if hasattr(v, "__len__") else v
        return out

    def make_input(self, gyro=(0, 0, 0), accel=(0, 0, 0), mag=(0, 0, 0), gps_vel=(0, 0, 0), valid=0):
        i = self.Input()
        for name, v in (("gyro", gyro), ("accel", accel), ("mag", mag), ("gps_vel_ned", gps_vel)):
            arr = getattr(i, name)
            for k in range(3):
                arr[k] = float(v[k])
        i.valid = int(valid)
        return i

    def step(self, s, gyro, accel, mag, gps_vel, valid, dt) -> int:
        return int(self.lib.ahrs_step(ctypes.byref(s), ctypes.byref(self.make_input(gyro, accel, mag, gps_vel, valid)), dt))

    def euler(self, s) -> np.ndarray:
        out = (_CT[self.real] * 3)()
        self.lib.ahrs_euler(ctypes.byref(s), out)
        return np.array(out[:])

    def pack(self, log: SensorLog) -> tuple[np.ndarray, np.ndarray]:
        inp = np.zeros(len(log), dtype=self.input_dtype)
        inp["gyro"] = log.gyro
        inp["accel"] = log.accel
        inp["mag"] = log.mag
        inp["gps_vel_ned"] = log.gps_vel
        inp["valid"] = log.valid
        return inp, np.ascontiguousarray(log.dt, dtype=self.np_real)

    def run(self, log: SensorLog, state=None, params: dict | None = None) -> RunResult:
        """Step through the whole log (from a fresh state unless one is given), with runtime
        parameter values set first if given."""
        s = self.new_state() if state is None else state
        if params:
            code = self.set_params(s, params)
            if code:
                raise BuildError(f"set_params refused {self.runtime_params[code - 1]} in {params}")
        n = len(log)
        inp, dt = self.pack(log)
        q = np.zeros((n, 4), self.np_real)
        rpy = np.zeros((n, 3), self.np_real)
        status = np.zeros(n, np.uint32)
        self.lib.ahrs_run(ctypes.byref(s), inp.ctypes.data, dt.ctypes.data, n,
                          q.ctypes.data, rpy.ctypes.data, status.ctypes.data)
        self.last_state = s
        return RunResult(q.astype(float), rpy.astype(float), status)

    def time_ns_per_step(self, log: SensorLog, repeats: int = 5, passes: int = 3) -> float:
        """Median over `repeats` of the mean ns per step, measured inside C."""
        inp, dt = self.pack(log)
        s0 = self.new_state()
        t = [self.lib.ahrs_time_ns_per_step(ctypes.byref(s0), inp.ctypes.data, dt.ctypes.data, len(log), passes)
             for _ in range(repeats)]
        return float(np.median(t))


def run_reference(ref, log: SensorLog, progress: bool = False) -> RunResult:
    """Step an independent NumPy reference through a log the same way.

    progress=True prints a one-line progress indicator on stderr (the reference runs at
    Python speed: ~0.1-1 ms per step).
    """
    import sys
    import time
    n = len(log)
    q = np.zeros((n, 4))
    status = np.zeros(n, np.uint32)
    t_last = t0 = time.monotonic()
    for k in range(n):
        status[k] = ref.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), float(log.dt[k]))
        q[k] = ref.q
        if progress and time.monotonic() - t_last > 0.5:
            t_last = time.monotonic()
            eta = (t_last - t0) / (k + 1) * (n - k - 1)
            print(f"\r  reference: {k + 1}/{n} steps ({100 * (k + 1) // n}%), about {eta:.0f} s left ",
                  end="", file=sys.stderr, flush=True)
    if progress and t_last != t0:
        print("\r" + " " * 70 + "\r", end="", file=sys.stderr, flush=True)
    from ahrsgen.npquat import euler_from_q
    return RunResult(q, euler_from_q(q), status)


def build(cfg, out_dir: str | Path | None = None) -> HostFilter:
    """Generate a configuration into a build directory and load it."""
    from ahrsgen.generate import render
    gen = render.render(cfg)
    h = hashlib.sha256("".join(gen.files.values()).encode()).hexdigest()[:20]
    d = Path(out_dir) if out_dir else CACHE / "gen" / h
    if not (d / "manifest.json").exists() or (d / "manifest.json").read_text() != gen.files["manifest.json"]:
        render.write(gen, d)
    return HostFilter(d)
