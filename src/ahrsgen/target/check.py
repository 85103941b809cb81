"""One filter end to end: build, run, count, footprint, and the comparison with the host build."""
from __future__ import annotations

import ctypes
import json
import subprocess
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .build import (OPT_LEVELS, PINNED_LIBM_H, Build, FilterBinding, _run, binding_from_generated, build, generate,
                    require_tools)
from .emulate import Emulator, StepCounts, TargetRun, records_from_log, run_qemu
from .footprint import Footprint, debug_stack, footprint, format_table


# --------------------------------------------------------------------------------------
# One filter, end to end
# --------------------------------------------------------------------------------------

@dataclass
class TargetResult:
    build: Build
    run: TargetRun
    counts: StepCounts
    footprint: Footprint
    cycles: object = None       # the CycleCounter of the counted steps (target/cycles.py)


def check_filter(b: FilterBinding, records: np.ndarray, workdir: Path | None = None,
                 opt: str = "-O2", cpu: str = "cortex-m4f",
                 count_steps: int | None = 50, o0_stack: bool = True,
                 cflags: tuple[str, ...] = ()) -> TargetResult:
    """Build for the target, run in QEMU, count in unicorn, measure the footprint.

    ``count_steps`` limits the unicorn run (exact counts and stack painting on the first
    steps; None = all).  The QEMU run always covers every record and gives the per-step
    counts of the whole run once it agrees with unicorn on the common steps.
    ``o0_stack`` also builds the filter at -O0 for its debug-build stack bound.
    ``cflags``: the user's own compiler flags, added to every build (``--cflags``).
    """
    require_tools()
    workdir = Path(workdir or tempfile.mkdtemp(prefix=f"ahrsgen-target-{b.name}-"))
    tag = opt.lstrip("-")
    bld = build(b, workdir / f"{b.name}-{tag}", opt, cpu, extra_cflags=cflags)
    run = run_qemu(bld.elf, records, bld.workdir)
    if b.state_size is None:
        b.state_size = run.state_bytes
    sub = records if count_steps is None else records[:count_steps]
    emu = Emulator(bld.elf)
    from .cycles import CycleCounter
    cycles = CycleCounter(emu, bld.elf)      # estimated Cortex-M4 cycles of the same steps
    counts = emu.count_steps(b.step_fn, sub, run.state_bytes)
    o0 = debug_stack(b, workdir / f"{b.name}-O0", cpu, cflags) if o0_stack else None
    est = cycles.estimate(counts.instructions)
    if est["cycles_est_steps"] > 0:
        est["vdiv_vsqrt_per_step"] = cycles.executions({"vdiv", "vsqrt"}) / est["cycles_est_steps"]
    fp = footprint(b, bld, counts, run, o0, est)
    return TargetResult(bld, run, counts, fp, cycles)


@dataclass
class HostComparison:
    steps: int
    status_equal: bool
    status_common_equal: bool     # the shared input-check bits (below FILTER_BASE) agree
    identical_steps: int          # steps whose whole state struct is bit-identical
    first_difference: int | None  # first step with any differing state byte (None: none)
    max_abs_q: float              # max |q_target - q_host| over all steps and components
    max_angle_deg: float          # max rotation angle between the two attitudes, degrees
    max_abs_state: float          # max |difference| over every real state field
    final_state_identical: bool
    pinned_libm: bool = False
    rms_target_deg: dict | None = None   # accuracy vs truth (roll/pitch/yaw RMS after settling)
    rms_host_deg: dict | None = None
    max_rms_difference_deg: float | None = None


class _HostStepper:
    """The host float build of a generated filter (src/ahrsgen/sim/host.py's compile_shared and
    ctypes structs from the manifest), stepped one sample at a time so that the whole state
    struct can be read after every step."""

    def __init__(self, gen_dir: Path, pinned_libm: bool = False):
        from ahrsgen.sim import host
        man = json.loads((Path(gen_dir) / "manifest.json").read_text())
        self.real = man["precision"]
        if pinned_libm and self.real != "float":
            raise ValueError("the pinned-libm run is for float builds")
        if pinned_libm:
            self._tmp = tempfile.TemporaryDirectory(prefix="ahrsgen-pinned-")
            lib = self._compile_pinned(host, Path(gen_dir), man, Path(self._tmp.name))
        else:
            lib = host.compile_shared(Path(gen_dir))   # the product's host build, as is
        self.lib = ctypes.CDLL(str(lib))
        st = man["structs"]
        self.State = host.ctypes_struct("State", st["state"], self.real)
        self.input_dtype = host.numpy_dtype(st["input"], self.real)
        self.lib.ahrs_step.restype = ctypes.c_uint32
        self.lib.ahrs_step.argtypes = [ctypes.c_void_p, ctypes.c_void_p,
                                       ctypes.c_float if self.real == "float" else ctypes.c_double]
        self.lib.ahrs_init.argtypes = [ctypes.c_void_p]

    @staticmethod
    def _compile_pinned(host, gen_dir: Path, man: dict, out: Path) -> Path:
        """Host build with the pinned libm forced into the filter's translation unit only
        (batch.c sets _POSIX_C_SOURCE before its own includes and must not get it)."""
        defines = [f"-DAHRS_PREFIX={man['prefix']}", f'-DAHRS_HEADER="{man["files"]["header"]}"',
                   "-DAHRS_REAL=float"]
        flags = [*host.STRICT, *host.HOST_FLAGS, f"-I{gen_dir}", *defines]
        objs = []
        for src, pin in ((gen_dir / man["files"]["source"], True), (host.C_DIR / "batch.c", False)):
            obj = out / (src.stem + ".o")
            extra = ["-include", str(PINNED_LIBM_H)] if pin else []
            _run([host.cc(), *flags, *extra, "-c", str(src), "-o", str(obj)])
            objs.append(str(obj))
        lib = out / f"lib{man['prefix']}_pinned.so"
        _run([host.cc(), "-shared", "-o", str(lib), *objs, "-lm"])
        return lib

    def run(self, rec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(rec)
        inp = np.zeros(n, dtype=self.input_dtype)
        inp["gyro"], inp["accel"], inp["mag"] = rec["gyro"], rec["accel"], rec["mag"]
        inp["gps_vel_ned"], inp["valid"] = rec["gps_vel"], rec["valid"]
        s = self.State()
        self.lib.ahrs_init(ctypes.addressof(s))
        size = ctypes.sizeof(self.State)
        states = np.zeros((n, size), np.uint8)
        status = np.zeros(n, np.uint32)
        base, isz = inp.ctypes.data, self.input_dtype.itemsize
        for k in range(n):
            status[k] = self.lib.ahrs_step(ctypes.addressof(s), base + k * isz, float(rec["dt"][k]))
            states[k] = np.frombuffer(ctypes.string_at(ctypes.addressof(s), size), np.uint8)
        return status, states


def compare_with_host(gen_dir: Path, b: FilterBinding, log, run: TargetRun,
                      pinned_libm: bool = False) -> HostComparison:
    """Step the host float build through the same float32 inputs the target saw and
    compare status and the whole state struct after every step.  ``pinned_libm`` must
    match the target build's."""
    rec = records_from_log(log)     # the exact float32 values the target saw
    h_status, h_state = _HostStepper(gen_dir, pinned_libm).run(rec)
    n = len(rec)
    same = (h_state == run.state).all(axis=1)
    t = TargetRun(h_status, h_state, run.state_bytes, 0, None, "")
    q_t, q_h = run.field(b, "q").astype(float), t.field(b, "q").astype(float)
    # rotation angle between unit quaternions: |q1 - q2| = 2 sin(theta/4) (sign-aligned);
    # exactly 0 for identical attitudes, well conditioned for tiny differences
    chord = np.minimum(np.linalg.norm(q_t - q_h, axis=1), np.linalg.norm(q_t + q_h, axis=1))
    ang = np.degrees(4.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)))
    max_state = 0.0
    for name in b.state_fields:
        d = np.abs(run.field(b, name).astype(float) - t.field(b, name).astype(float))
        d = d[np.isfinite(d)]
        if d.size:
            max_state = max(max_state, float(d.max()))
    return HostComparison(
        steps=n, status_equal=bool(np.array_equal(h_status, run.status)),
        status_common_equal=bool(np.array_equal(h_status & _COMMON_STATUS_MASK, run.status & _COMMON_STATUS_MASK)),
        identical_steps=int(same.sum()),
        first_difference=None if same.all() else int(np.argmin(same)),
        max_abs_q=float(np.max(np.abs(q_t - q_h))) if n else 0.0,
        max_angle_deg=float(ang.max()) if n else 0.0,
        max_abs_state=max_state,
        final_state_identical=bool(same[-1]) if n else True,
        pinned_libm=pinned_libm, **_accuracy(log, q_t, q_h),
    )


def _accuracy(log, q_t: np.ndarray, q_h: np.ndarray) -> dict:
    """RMS attitude error vs the log's truth for target and host (what a user judges)."""
    if getattr(log, "q_true", None) is None:
        return {}
    from ahrsgen.sim import metrics
    try:
        st = metrics.euler_stats(q_t, log.q_true, log.t, log.settle_time)
        sh = metrics.euler_stats(q_h, log.q_true, log.t, log.settle_time)
    except ValueError:
        return {}
    rt = {a: st[a]["rms"] for a in ("roll", "pitch", "yaw")}
    rh = {a: sh[a]["rms"] for a in ("roll", "pitch", "yaw")}
    return {"rms_target_deg": rt, "rms_host_deg": rh,
            "max_rms_difference_deg": max(abs(rt[a] - rh[a]) for a in rt)}


# --------------------------------------------------------------------------------------
# `ahrsgen target`
# --------------------------------------------------------------------------------------

# The scenario of each filter's source experiment (SPEC.md) is the filter's own: `scenario` in
# its defaults.toml [filter] table; --scenario overrides.
DEFAULT_TOLERANCE_DEG = 1e-3
# A filter whose run is a random process by design (`stochastic = "reason"` in its [filter]
# table): the particle filter resamples, so a 1-ulp difference between newlib's and glibc's
# logf/cosf/expf picks different particles and the trajectories part (by tenths of a degree)
# while both stay equally accurate.  For them the real-libm check compares accuracy against
# the truth instead of trajectories; the pinned-libm run must still be bit-identical.
ACCURACY_TOLERANCE_DEG = 0.1
_COMMON_STATUS_MASK = (1 << 12) - 1    # src/ahrsgen/status.py: bits below FILTER_BASE


def _stochastic(filter_name: str) -> str:
    from ahrsgen import filters
    from ahrsgen.errors import ConfigError
    try:
        return filters.load(filter_name).stochastic
    except ConfigError:          # a build without a known filter (a peer, a toy): deterministic
        return ""


def judge(filter_name: str, real: dict, pinned: dict | None, tolerance_deg: float = DEFAULT_TOLERANCE_DEG
          ) -> tuple[bool, str]:
    """PASS/FAIL of one build's comparison with the host, with the reason in words.  A FAIL
    ends with the checks that failed, so that a bound kept is not read as the failure."""
    parts, failed = [], []
    if pinned is not None:
        same = pinned["identical_steps"] == pinned["steps"] and pinned["status_equal"]
        if not same:
            failed.append("pinned libm not bit-identical (host == target needs the same code on "
                          "both sides: -ffp-contract=off, docs/target.md)")
        parts.append("pinned libm: bit-identical in every step" if same else
                     f"pinned libm: DIFFERS from step {pinned['first_difference']} "
                     f"(max {pinned['max_angle_deg']:.3g} deg)")
    if real["identical_steps"] == real["steps"]:
        parts.append("real libm: bit-identical in every step")
    elif _stochastic(filter_name):
        d = real.get("max_rms_difference_deg")
        if d is None or d > ACCURACY_TOLERANCE_DEG:
            failed.append("real libm: accuracy vs truth beyond its bound")
        parts.append(f"real libm: trajectories part from step {real['first_difference']} "
                     f"(max {real['max_angle_deg']:.3g} deg; {_stochastic(filter_name)}); "
                     f"RMS error vs truth differs by {d if d is None else f'{d:.3g}'} deg "
                     f"(bound {ACCURACY_TOLERANCE_DEG:g} deg)")
    else:
        if real["max_angle_deg"] > tolerance_deg:
            failed.append(f"real libm: attitude beyond {tolerance_deg:g} deg")
        parts.append(f"real libm: bit-identical in {real['identical_steps']}/{real['steps']} steps, first "
                     f"difference at step {real['first_difference']}, max attitude difference "
                     f"{real['max_angle_deg']:.3g} deg (bound {tolerance_deg:g} deg)")
    if not real["status_equal"]:
        parts.append("status codes DIFFER" if not real["status_common_equal"] else
                     "filter-specific status bits differ")
        parted = real["identical_steps"] != real["steps"] and _stochastic(filter_name)
        if not (parted and real["status_common_equal"]):    # a parted random run: common bits only
            failed.append("status codes differ")
    verdict = "; ".join(parts)
    return not failed, verdict + (f" -> FAIL: {'; '.join(failed)}" if failed else "")


def toolchain_versions() -> dict:
    out = {}
    for tool, args in (("arm-none-eabi-gcc", ["--version"]), ("qemu-system-arm", ["--version"])):
        try:
            out[tool] = subprocess.run([tool, *args], capture_output=True, text=True).stdout.splitlines()[0]
        except (OSError, IndexError):
            out[tool] = None
    try:
        import unicorn
        out["unicorn"] = unicorn.__version__
    except ImportError:
        out["unicorn"] = None
    return out


def check_generated(filter_name: str, opts=OPT_LEVELS, cpu: str = "cortex-m4f", scenario: str | None = None,
                    seed: int = 0, scenario_options: dict | None = None, config_file=None, sets=None,
                    prefix=None, workdir: Path | None = None, count_steps: int | None = 50,
                    log=None, pinned: bool = True, tolerance_deg: float = DEFAULT_TOLERANCE_DEG,
                    precision: str = "float", math: str | None = None, fma: bool | None = None,
                    profile: bool = False, cflags: tuple[str, ...] = ()) -> list[dict]:
    """Generate (float), cross-build at each optimisation level, run on the target, compare
    with the host float build, measure the footprint.  One dict per build; with ``profile``,
    where the counted steps' instructions go (src/ahrsgen/target/profile.py) as "profile"."""
    from ahrsgen.sim import scenarios
    require_tools()
    workdir = Path(workdir or tempfile.mkdtemp(prefix=f"ahrsgen-target-{filter_name}-"))
    gen_dir = generate(filter_name, workdir / "generated", config_file, sets, prefix, precision, math, fma)
    man = json.loads((gen_dir / "manifest.json").read_text())
    b = binding_from_generated(gen_dir)
    from ahrsgen import filters
    scen = scenario or filters.load(filter_name).scenario
    if log is None:
        log = scenarios.make(scen, seed=seed, **(scenario_options or {}))
    rec = records_from_log(log)
    results = []
    for i, opt in enumerate(opts):
        try:
            r = check_filter(b, rec, workdir, opt=opt, cpu=cpu, count_steps=count_steps, cflags=cflags)
        except RuntimeError as e:
            if not cflags:
                raise
            from ahrsgen.errors import ConfigError
            out = str(e).splitlines()[1:]                  # the compiler's own lines, after the command
            why = next((ln.strip() for ln in out if "error:" in ln), out[0] if out else str(e))
            raise ConfigError(f"--cflags {' '.join(cflags)}: the target build failed: {why}") from None
        r.footprint.variant = " ".join(v for v in (f"math={man.get('math')}" if man.get("math") == "libm"
                                                   and precision == "float" else "",
                                                   "fma" if man.get("fma") else "", *cflags) if v)
        cmp_ = asdict(compare_with_host(gen_dir, b, log, r.run))
        pin = None
        if pinned and i == 0 and precision == "float":
            pb = build(b, workdir / f"{b.name}-{opt.lstrip('-')}-pinned", opt, cpu, pinned_libm=True,
                       extra_cflags=cflags)
            prun = run_qemu(pb.elf, rec, pb.workdir, icount_shift=None)
            pin = asdict(compare_with_host(gen_dir, b, log, prun, pinned_libm=True))
        ok, verdict = judge(filter_name, cmp_, pin, tolerance_deg)
        prof = None
        if profile:
            from .profile import profile_steps
            gb = build(b, workdir / f"{b.name}-{opt.lstrip('-')}-g", opt, cpu, debug_info=True,
                       extra_cflags=cflags)
            prof = profile_steps(gb.elf, b.step_fn, man["prefix"], rec[:len(r.counts.instructions)],
                                 r.run.state_bytes, {k: v["total"] for k, v in man["kernels"].items()})
        results.append({"filter": filter_name, "precision": precision, "opt": opt, "cpu": cpu,
                        "math": man.get("math"), "fma": man.get("fma", False), "cflags": list(cflags),
                        "scenario": log.name, "seed": seed,
                        "steps": len(rec), "counted_steps": int(len(r.counts.instructions)),
                        "footprint": asdict(r.footprint), "host_comparison": cmp_,
                        "pinned_libm_comparison": pin, "pass": ok, "verdict": verdict, "profile": prof,
                        "workdir": str(r.build.workdir)})
    return results


def _print_results(results: list[dict]) -> bool:
    rows = [Footprint(**r["footprint"]) for r in results]
    print(format_table(rows))
    print()
    for r in results:
        print(f"{r['filter']} {r['opt']}: target vs host {r.get('precision', 'float')} build on {r['scenario']} "
              f"({r['steps']} steps): "
              f"{r['verdict']}{' -> PASS' if r['pass'] else ''}")
        fp = r["footprint"]
        if fp["double_helpers"] and r.get("precision", "float") == "float":
            print(f"  WARNING: soft-double helpers reachable from step: {', '.join(fp['double_helpers'])}")
    return all(r["pass"] for r in results)
