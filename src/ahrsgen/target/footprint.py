"""Footprint of a build: flash, static RAM, worst-case stack (call graph), instructions per step."""
from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .build import DEBUG_OPT, Build, FilterBinding, _run, build
from .emulate import StepCounts, TargetRun


# --------------------------------------------------------------------------------------
# Footprint: sizes, static stack bound, call graph
# --------------------------------------------------------------------------------------

FOOTPRINT_MAIN = r"""
/* footprint image: the filter's API reached through volatile data so nothing folds */
#include "filter_glue.h"
#include "semihost.h"
static glue_state g_s;
static ahrs_record g_r;
static ahrs_record *volatile g_rp = &g_r;   /* keeps the record in both images */
static volatile uint32_t g_sink;
int main(void)
{
    ahrs_record *rp = g_rp;
    rp->valid = g_sink;
#ifndef FP_BASELINE
    glue_init(&g_s);
    g_sink = glue_step(&g_s, rp);
#ifdef GLUE_HAS_EULER
    glue_euler(&g_s, rp->gyro);
    g_sink += (uint32_t)(rp->gyro[0] > 0.0f);
#endif
#else
    g_sink = rp->valid + (uint32_t)sizeof(g_s) * 0u;
#endif
    return (int)g_sink;
}
"""

_FLASH_SECTIONS = (".isr_vector", ".text", ".rodata", ".ARM.extab", ".ARM.exidx",
                   ".init_array", ".fini_array")


def section_sizes(path: Path) -> dict[str, int]:
    """``arm-none-eabi-size -A`` as a dict (sections of an ELF or object)."""
    out = _run(["arm-none-eabi-size", "-A", str(path)]).stdout
    sizes: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = sizes.get(parts[0], 0) + int(parts[1])
    return sizes


def image_flash_ram(elf: Path) -> tuple[int, int]:
    s = section_sizes(elf)
    flash = sum(v for k, v in s.items() if k in _FLASH_SECTIONS) + s.get(".data", 0)
    ram = s.get(".data", 0) + s.get(".bss", 0)
    return flash, ram


def object_sections(obj: Path) -> dict[str, int]:
    """text / rodata / data / bss of one object (function/data sections summed)."""
    s = section_sizes(obj)
    out = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
    for k, v in s.items():
        for kind in out:
            if k == f".{kind}" or k.startswith(f".{kind}."):
                out[kind] += v
    return out


def parse_stack_usage(paths: list[Path]) -> dict[str, tuple[int, str]]:
    """GCC .su files -> {function: (bytes, qualifier)}."""
    frames: dict[str, tuple[int, str]] = {}
    for p in paths:
        if not Path(p).exists():
            continue
        for line in Path(p).read_text().splitlines():
            parts = line.split("\t")
            if len(parts) >= 3:
                fn = parts[0].rsplit(":", 1)[-1]
                frames[fn] = (int(parts[1]), parts[2].strip())
    return frames


_FN_HDR = re.compile(r"^([0-9a-f]+) <([^>]+)>:$")
_INSN = re.compile(r"^\s*([0-9a-f]+):\s+(\S+)\s*(.*)$")
_REGLIST = re.compile(r"\{([^}]*)\}")


def _reglist_bytes(text: str) -> int:
    m = _REGLIST.search(text)
    if not m:
        return 0
    total = 0
    for item in m.group(1).split(","):
        item = item.strip()
        if "-" in item:
            a, b_ = item.split("-")
            n = int(b_[1:]) - int(a[1:]) + 1
            total += n * (8 if a.startswith("d") else 4)
        elif item:
            total += 8 if item.startswith("d") else 4
    return total


def disassemble_functions(elf: Path) -> dict[str, dict]:
    """Per function of the linked image: its call edges and a stack frame estimate.

    Frame estimate = every push/stmdb sp!/vpush plus every ``sub sp, #imm`` in the body
    (an upper bound when a function has several prologue paths).  Calls are ``bl``/``blx
    <sym>`` and tail calls (``b``/``b.w`` to another function's entry); ``blx rN`` is an
    indirect call and is flagged.
    """
    out = _run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)], timeout=120).stdout
    funcs: dict[str, dict] = {}
    cur = None
    for line in out.splitlines():
        m = _FN_HDR.match(line)
        if m:
            cur = {"addr": int(m.group(1), 16), "calls": set(), "frame": 0, "indirect": False, "n": 0}
            funcs[m.group(2)] = cur
            continue
        if cur is None:
            continue
        mi = _INSN.match(line)
        if not mi:
            continue
        op, args = mi.group(2), mi.group(3)
        cur["n"] += 1
        if op in ("push", "push.w", "vpush") or (op.startswith("stmdb") and args.startswith("sp!")):
            cur["frame"] += _reglist_bytes(args)
        elif op in ("sub", "sub.w", "subw", "subs") and re.match(r"sp,\s*(sp,\s*)?#", args):
            cur["frame"] += int(re.search(r"#(\d+)", args).group(1))
        elif op in ("bl", "blx") and "<" in args:
            tgt = re.search(r"<([^>+]+)>", args)
            if tgt:
                cur["calls"].add(tgt.group(1))
        elif op == "blx":
            cur["indirect"] = True
        elif op in ("b", "b.w", "b.n") and "<" in args:
            tgt = re.search(r"<([^>]+)>", args)
            if tgt and "+" not in tgt.group(1):
                cur["calls"].add(tgt.group(1))   # tail call to another function's entry
    return funcs


def worst_stack(root: str, funcs: dict[str, dict], su: dict[str, tuple[int, str]]) -> dict:
    """Worst-case stack from ``root`` over the call graph (no recursion allowed)."""
    memo: dict[str, tuple[int, list[str]]] = {}
    unknown: set[str] = set()
    indirect: set[str] = set()

    def frame(fn: str) -> int:
        if fn in su:
            return su[fn][0]
        if fn in funcs:
            return funcs[fn]["frame"]
        unknown.add(fn)
        return 0

    def visit(fn: str, stack: tuple[str, ...]) -> tuple[int, list[str]]:
        if fn in stack:
            raise RuntimeError(f"recursion in call graph: {' -> '.join(stack + (fn,))}")
        if fn in memo:
            return memo[fn]
        info = funcs.get(fn, {"calls": set(), "indirect": False})
        if info.get("indirect"):
            indirect.add(fn)
        best, path = 0, []
        for c in sorted(info["calls"]):
            if c == fn:
                continue
            d, p = visit(c, stack + (fn,))
            if d > best:
                best, path = d, p
        memo[fn] = (frame(fn) + best, [fn] + path)
        return memo[fn]

    total, path = visit(root, ())
    reach = sorted(memo)
    return {"bytes": total, "path": path,
            "frames": {f: frame(f) for f in path},
            "frame_source": {f: ("stack-usage" if f in su else "disassembly") for f in path},
            "reachable": reach, "unknown": sorted(unknown), "indirect_calls": sorted(indirect)}


# Soft-float helpers that betray a hidden double (or 64-bit division) in a float build.
_DOUBLE_HELPER = re.compile(r"^__aeabi_(d\w+|[fil]2d|d2\w+|ldivmod|uldivmod)$|^__(adddf3|muldf3|divdf3|subdf3)$")


@dataclass
class Footprint:
    filter: str
    opt: str
    cpu: str
    flash_bytes: int             # increase of (text + rodata + .data image) over the baseline image,
                                 # less the harness glue: the filter's API plus what it pulls from libm/libc
    own_code_bytes: int          # of which the filter's own functions and constants (init, step, euler)
    ram_static_bytes: int        # increase of (.data + .bss) over the baseline image, state included
    ram_data_bytes: int          # of which .data (newlib's errno/reent block when a wrapper needs it)
    ram_bss_bytes: int           # of which .bss (the footprint image keeps the state struct there)
    state_bytes: int             # sizeof(state struct)
    object_sections: dict        # the filter's own objects: text / rodata / data / bss
    stack_bytes: int             # static worst case of step (frames x call graph)
    stack_path: list[str]
    stack_measured_bytes: int    # deepest stack touched by step over the scenario (stack painting)
    instructions_mean: float     # per step of <prefix>_step (callees included), whole scenario
    instructions_min: int
    instructions_max: int
    instructions_steps: int      # steps the figures cover
    instructions_source: str     # "qemu-icount (checked against unicorn on N steps)" or "unicorn"
    instructions_crosscheck_exact: bool | None  # QEMU and unicorn agree on every common step
    library_calls: list[str]     # functions outside the filter's objects reached from step
    double_helpers: list[str]    # soft-double helpers reachable from step (should be empty)
    flags: list[str]
    precision: str = "float"
    stack_o0_bytes: int = -1     # static worst case of step in a -O0 (debug) build of the same sources
    stack_o0_path: list[str] = field(default_factory=list)
    variant: str = ""            # build options beside the defaults ("fma", "math=libm", the user's --cflags)
    # Estimated Cortex-M4 cycles per step (target/cycles.py: the TRM's timings weighed over the
    # instructions unicorn ran, zero wait states; an estimate, QEMU counts no cycles), over the
    # unicorn-counted steps (cycles_est_steps, the first --count-steps steps)
    cycles_est_mean: float = float("nan")
    cycles_est_min: int = -1
    cycles_est_max: int = -1
    cycles_est_steps: int = 0
    cycles_est_unmodelled: list[str] = field(default_factory=list)   # mnemonics costed 1 by default
    cycles_est_model: str = ""
    vdiv_vsqrt_per_step: float = float("nan")   # vdiv.f32 + vsqrt.f32 run per step (14 cycles each),
                                                # over the same unicorn-counted steps


def step_instructions(counts: StepCounts | None, run: TargetRun | None) -> dict:
    """Instructions per step for the whole run.

    unicorn counts <prefix>_step exactly (entry to return) on the first steps; QEMU under
    -icount counts, for every step, glue_step plus the few harness instructions between the
    two SysTick reads (2 at -O2, 7 at -Os with gcc 12).  The glue's share and the harness
    window are data-independent, so step = QEMU count - window - share, both taken from the
    steps the two emulators ran in common, where the difference must be one constant while
    the step counts themselves vary; otherwise only the unicorn figures are reported."""
    out = {"instructions_mean": float("nan"), "instructions_min": -1, "instructions_max": -1,
           "instructions_steps": 0, "instructions_source": "none", "instructions_crosscheck_exact": None}
    if counts is not None and len(counts.instructions):
        u = counts.instructions
        out.update(instructions_mean=float(u.mean()), instructions_min=int(u.min()), instructions_max=int(u.max()),
                   instructions_steps=int(len(u)), instructions_source="unicorn")
    q = run.glue_instructions_icount() if run is not None else None
    if q is None or counts is None or not len(counts.instructions):
        return out
    k = len(counts.instructions)
    share = counts.glue_instructions - counts.instructions
    window = np.unique(q[:k] - counts.glue_instructions)   # harness code between the SysTick reads
    exact = len(window) == 1 and 0 <= int(window[0]) <= 16 and len(np.unique(share)) == 1
    out["instructions_crosscheck_exact"] = exact
    if exact:
        steps = q - int(window[0]) - int(share[0])
        out.update(instructions_mean=float(steps.mean()), instructions_min=int(steps.min()),
                   instructions_max=int(steps.max()), instructions_steps=int(len(steps)),
                   instructions_source=f"qemu-icount, equal to unicorn on the first {k} steps")
    return out


def debug_stack(b: FilterBinding, workdir: Path, cpu: str = "cortex-m4f", extra_cflags: tuple[str, ...] = ()) -> dict:
    """Static worst-case stack of step when the filter is built at -O0 (what a debug build of
    the flight code needs; every temporary gets its own slot there).  Same call-graph bound
    as the optimised builds: GCC's -fstack-usage frames over the linked image's calls."""
    bld = build(b, Path(workdir), DEBUG_OPT, cpu, extra_cflags=extra_cflags)
    return worst_stack(b.step_fn, disassemble_functions(bld.elf), parse_stack_usage(bld.stack_usage_files))


def footprint(b: FilterBinding, build_: Build, counts: StepCounts | None = None,
              run: TargetRun | None = None, o0_stack: dict | None = None,
              cycles: dict | None = None) -> Footprint:
    """Sizes of the filter in one build (links a footprint image and a baseline); ``cycles``:
    the estimate of target/cycles.py (``CycleCounter.estimate``) over the counted steps."""
    wd = build_.workdir / "footprint"
    wd.mkdir(exist_ok=True)
    main_c = wd / "fp_main.c"
    main_c.write_text(FOOTPRINT_MAIN)
    with_f = build(b, wd / "with", build_.opt, build_.cpu, extra_main=str(main_c), reuse=build_,
                   extra_cflags=build_.extra_cflags)
    base_main = wd / "fp_base.c"
    base_main.write_text("#define FP_BASELINE 1\n" + FOOTPRINT_MAIN)
    base = build(b, wd / "base", build_.opt, build_.cpu, extra_main=str(base_main), reuse=build_,
                 extra_cflags=build_.extra_cflags)
    f1, r1 = image_flash_ram(with_f.elf)
    f0, r0 = image_flash_ram(base.elf)
    s1, s0 = section_sizes(with_f.elf), section_sizes(base.elf)
    d_data = s1.get(".data", 0) - s0.get(".data", 0)
    d_bss = s1.get(".bss", 0) - s0.get(".bss", 0)

    objsec = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
    own_funcs: set[str] = set()
    for o in build_.filter_objects:
        for k, v in object_sections(o).items():
            objsec[k] += v
        nm = _run(["arm-none-eabi-nm", "--defined-only", str(o)]).stdout
        own_funcs |= {ln.split()[-1] for ln in nm.splitlines() if ln.split()[1:2] and ln.split()[1] in "tTrR"}

    own_code = 0   # the filter's own functions and constants that the linked image keeps
    glue_code = 0  # the harness glue (record copy) is in the footprint image only: not the filter's
    for ln in _run(["arm-none-eabi-nm", "-S", "--defined-only", str(with_f.elf)]).stdout.splitlines():
        parts = ln.split()
        if len(parts) == 4 and parts[2] in "tTrR" and parts[3] in own_funcs:
            own_code += int(parts[1], 16)
        elif len(parts) == 4 and parts[3] in ("glue_init", "glue_step", "glue_euler"):
            glue_code += int(parts[1], 16)

    funcs = disassemble_functions(build_.elf)
    su = parse_stack_usage(build_.stack_usage_files)
    ws = worst_stack(b.step_fn, funcs, su)
    # Measured stack of step: deepest painted word in QEMU over the whole run, less the
    # glue's own frame (GCC's figure), and unicorn's painting over its steps; the larger.
    measured_stack = counts.stack_bytes if counts is not None else -1
    if run is not None and run.stack_below_main is not None and "glue_step" in su:
        measured_stack = max(measured_stack, run.stack_below_main - su["glue_step"][0])
    lib = [f for f in ws["reachable"] if f not in own_funcs]
    dbl = [f for f in ws["reachable"] if _DOUBLE_HELPER.match(f)]
    state_bytes = b.state_size if b.state_size is not None else 0
    return Footprint(
        filter=b.name, opt=build_.opt, cpu=build_.cpu,
        flash_bytes=f1 - f0 - glue_code, own_code_bytes=own_code, ram_static_bytes=r1 - r0, ram_data_bytes=d_data, ram_bss_bytes=d_bss,
        state_bytes=state_bytes,
        object_sections=objsec, stack_bytes=ws["bytes"], stack_path=ws["path"],
        stack_measured_bytes=measured_stack,
        **step_instructions(counts, run), library_calls=lib, double_helpers=dbl, flags=build_.cflags,
        precision=b.scalar,
        stack_o0_bytes=o0_stack["bytes"] if o0_stack else -1, stack_o0_path=o0_stack["path"] if o0_stack else [],
        **(cycles or {}),
    )


def format_table(rows: list[Footprint]) -> str:
    """Markdown table of footprints (library column: entry points only, no __internals)."""
    hdr = ("| filter | build | flash B (own code) | static RAM B (state) | stack B static / measured / -O0 "
           "| instructions/step mean (min-max) | est. cycles/step mean (min-max) [steps] | library functions |")
    sep = "|" + "---|" * 8
    lines = [hdr, sep]
    for r in rows:
        own = r.own_code_bytes
        libs = [f for f in r.library_calls if not f.startswith("__")]
        lines.append(
            f"| {r.filter} | {r.opt}{' double' if r.precision == 'double' else ''}{' ' + r.variant if r.variant else ''} | {r.flash_bytes} ({own}) | {r.ram_static_bytes} ({r.state_bytes}) "
            f"| {r.stack_bytes} / {r.stack_measured_bytes} / {r.stack_o0_bytes if r.stack_o0_bytes >= 0 else '-'} "
            f"| {r.instructions_mean:.0f} "
            f"({r.instructions_min}-{r.instructions_max}) | {_cycles_cell(r)} | {', '.join(libs) or '-'} |")
    return "\n".join(lines)


def _cycles_cell(r: Footprint) -> str:
    if r.cycles_est_steps <= 0:
        return "-"
    return f"{r.cycles_est_mean:.0f} ({r.cycles_est_min}-{r.cycles_est_max}) [{r.cycles_est_steps}]"


def to_json(rows: list[Footprint]) -> str:
    return json.dumps([asdict(r) for r in rows], indent=2, sort_keys=True)
