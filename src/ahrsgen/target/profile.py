"""Where a step's instructions go: `ahrsgen target --profile`.

The same build with line information (-g: GCC's code does not change, the test checks that the
profile's total equals the step's instruction count) runs the first counted steps in unicorn
with a hook on every block executed inside the step (instructions taken by the counter's own
Thumb-2 length rule, so IT instructions count as in `ahrsgen target`); each instruction's address is
mapped to the source function it came from (addr2line, innermost inlined frame). The parts of
a kernel split for the -O0 stack (`<prefix>_k_<name>_part<N>`) count as that kernel; the
step's own code (control, input checks, copies) is the step's line; helpers (fast math, the
input-check helpers, libc) keep their names. Beside a kernel: its operation count from the
manifest (every side of its branches, per call), to set its instructions against; and the
estimated Cortex-M4 cycles of the same instructions (target/cycles.py: the TRM's timings, an
estimate) per function.

The total is exact; the split is as good as GCC's line information at -O2, which can give a
few scheduled instructions (typically the step's prologue and first loads) the location of a
neighbouring inlined function: the example Madgwick's step shows 20 instructions per step
under `fast_atan2f`, which only its first step calls.
"""
from __future__ import annotations

import re
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np


def _functions(elf: Path, addresses: list[int]) -> dict[int, str]:
    """address -> innermost source function (inlined frames resolved), one addr2line call."""
    out: dict[int, str] = {}
    if not addresses:
        return out
    text = subprocess.run(["arm-none-eabi-addr2line", "-a", "-f", "-i", "-e", str(elf),
                           *(hex(a) for a in addresses)], capture_output=True, text=True, check=True).stdout
    current = None
    expect_fn = False
    for line in text.splitlines():
        if line.startswith("0x"):
            current, expect_fn = int(line, 16), True
        elif expect_fn and current is not None:
            out[current] = line.strip()      # the first function after an address: innermost
            expect_fn = False
    return out


def group_name(fn: str, prefix: str) -> str:
    """Kernel parts and the kernel's own wrapper -> 'kernel <name>'; the step -> 'step'."""
    m = re.fullmatch(rf"{re.escape(prefix)}_k_(\w+?)(?:_part\d+)?", fn)
    if m:
        return f"kernel {m.group(1)}"
    if fn == f"{prefix}_step":
        return "step (control, input checks, copies)"
    return fn


def profile_steps(elf: Path, step_fn: str, prefix: str, records: np.ndarray, state_bytes: int,
                  kernel_ops: dict[str, int] | None = None) -> dict:
    """Run `records` through the step in unicorn, counting every instruction inside it by
    source function. Returns {"steps", "instructions_per_step", "rows": [{name, per_step,
    share, ops}]}, rows by cost."""
    from unicorn import UC_HOOK_BLOCK

    from .cycles import CycleCounter
    from .emulate import Emulator, thumb_instruction_offsets
    emu = Emulator(elf)
    blocks: Counter[tuple[int, int]] = Counter()
    cycles = CycleCounter(emu, elf)        # estimated cycles of the same steps, per address

    def on_block(_uc, address, size, _user):
        if emu.in_step:     # the emulator's own block hook (added first) has set it for this block
            blocks[(address, size)] += 1
    emu.uc.hook_add(UC_HOOK_BLOCK, on_block)
    counts = emu.count_steps(step_fn, records, state_bytes)
    hits: Counter[int] = Counter()
    for (address, size), n in blocks.items():     # every instruction of a block, as the counter sees it
        for offset in thumb_instruction_offsets(bytes(emu.uc.mem_read(address, size))):
            hits[address + offset] += n
    names = _functions(elf, sorted(hits))
    per: Counter[str] = Counter()
    for a, n in hits.items():
        per[group_name(names.get(a, "?"), prefix)] += n
    steps = len(records)
    total = sum(per.values())
    if total != int(counts.instructions.sum()):
        raise RuntimeError(f"profile counted {total} instructions, the step {int(counts.instructions.sum())}")
    est = cycles.estimate(counts.instructions)
    per_cyc: Counter[str] = Counter()
    for a, c in cycles.per_address().items():
        per_cyc[group_name(names.get(a, "?"), prefix)] += c
    ops = kernel_ops or {}
    rows = [{"name": k, "per_step": n / steps, "share": n / total, "cycles_est_per_step": per_cyc[k] / steps,
             "ops": ops.get(k.removeprefix("kernel ")) if k.startswith("kernel ") else None}
            for k, n in per.most_common()]
    return {"steps": steps, "instructions_per_step": total / steps, "rows": rows,
            "cycles_est_per_step": est["cycles_est_mean"], "cycles_est_model": est["cycles_est_model"]}


def format_profile(filter_name: str, opt: str, prof: dict) -> str:
    lines = [f"{filter_name} {opt}: where the step's {prof['instructions_per_step']:.0f} instructions "
             f"(estimated {prof['cycles_est_per_step']:.0f} cycles) go "
             f"(first {prof['steps']} steps, unicorn; kernel parts counted as their kernel, inlined "
             f"code as the function GCC's line information gives it: the total is exact, a few "
             f"scheduled instructions such as the prologue can land on a neighbouring function; "
             f"cycles: {prof['cycles_est_model']})",
             "| function | instructions/step | share | est. cycles/step | kernel operations (manifest: every side, per call) |",
             "|---|---|---|---|---|"]
    for r in prof["rows"]:
        ops = r["ops"]
        lines.append(f"| {r['name']} | {r['per_step']:.1f} | {100 * r['share']:.1f} % | "
                     f"{r['cycles_est_per_step']:.1f} | {ops if ops is not None else ''} |")
    return "\n".join(lines)
