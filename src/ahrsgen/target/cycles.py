"""Estimated Cortex-M4 cycles per step, beside the exact instruction count (issue 29).

QEMU and unicorn count instructions, not cycles. This module weighs every instruction the step
executes in unicorn by the Cortex-M4 Technical Reference Manual's timing table (ARM DDI 0439,
section 3.3 "Instruction set summary" for the integer core, and the FPU chapter's instruction
table for VFPv4-SP), taking each executed address's mnemonic from `arm-none-eabi-objdump -d`
of the same ELF. Whether a conditional branch was taken comes from the block that ran next: a
block ending in a conditional branch whose successor starts at the block's end fell through.

It is an ESTIMATE under stated assumptions, not a measurement:

- zero wait states on every fetch and data access, no cache, no bus contention, no interrupts
  (a real MCU at a higher clock has flash wait states and an accelerator, ART or similar);
- P, the pipeline refill after a taken branch (1 to 3 cycles in the TRM, depending on the
  alignment and width of the target and on early address speculation), is BRANCH_REFILL = 2;
- SDIV/UDIV take 2 to 12 cycles depending on the operands; SDIV_CYCLES = 12, the worst case;
- load pipelining (TRM 3.3.2): a single load (LDR, LDRB, LDRH, LDRSB, LDRSH without base
  write-back) right after another one in the same block costs 1 instead of 2 (a STR costs 1
  anyway); the stall of an address that depends on the previous instruction's result, and an
  LDR from a literal pool contending with the fetch, are not modelled;
- VLDR/VSTR 2 each, not pipelined; VDIV/VSQRT block for their 14 cycles (the M4 FPU can let
  independent integer instructions run meanwhile; not modelled: an upper estimate there);
- an IT instruction costs 1 (the TRM allows folding it onto a preceding 16-bit instruction
  for 0; not modelled), and an instruction inside an IT block costs the same whether its
  condition passed or not (unicorn's block hook cannot tell);
- a mnemonic the table does not know costs 1 and is listed (`unmodelled`) so a gap shows.
"""
from __future__ import annotations

import re
import subprocess
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# --------------------------------------------------------------------------------------
# The model: Cortex-M4 TRM (ARM DDI 0439) timings, zero wait states
# --------------------------------------------------------------------------------------

BRANCH_REFILL = 2      # P: pipeline refill after a taken branch, 1..3 in the TRM (assumed 2)
SDIV_CYCLES = 12       # SDIV/UDIV: 2..12 in the TRM, early termination on the operands (worst case)

MODEL_TEXT = (f"Cortex-M4 TRM timings, zero wait states, no cache, P = {BRANCH_REFILL}, "
              f"SDIV/UDIV {SDIV_CYCLES}, VDIV/VSQRT 14; an estimate (QEMU does not count cycles)")

# Integer data processing, 1 cycle (TRM 3.3.1, Table 3-1: ADD, SUB, MOV, CMP, logical, shifts,
# bit-field, extend, reverse, saturate, MUL: 1; the M4's multiplier is single cycle, so MUL,
# MLA, MLS, and the long multiplies UMULL/SMULL/UMLAL/SMLAL with the DSP multiplies are 1).
_ALU1 = set("""
adc add addw adr and asr bfc bfi bic clz cmn cmp eor lsl lsr mov movw movt mvn neg nop orn orr
rbit rev rev16 revsh ror rrx rsb sbc sbfx ssat sub subw sxtb sxth sxtab sxtah teq tst ubfx usat
uxtb uxth uxtab uxtah sel qadd qsub qdadd qdsub
mul mla mls umull smull umlal smlal smmul smmla smmls smulbb smulbt smultb smultt smulwb smulwt
smlabb smlabt smlatb smlatt smlawb smlawt smlad smlald smuad smusd
cpsid cpsie dmb dsb isb sev wfe wfi yield bkpt svc
""".split())

# FPU data processing (TRM, FPU chapter, instruction table): 1 cycle ...
_FP1 = {"vadd", "vsub", "vmul", "vnmul", "vabs", "vneg", "vcmp", "vcmpe", "vcvt", "vcvtr", "vcvtb",
        "vcvtt", "vmrs", "vmsr"}
# ... multiply-accumulate, chained (VMLA family) and fused (VFMA family): 3 ...
_FP3 = {"vmla", "vmls", "vnmla", "vnmls", "vfma", "vfms", "vfnma", "vfnms"}
# ... divide and square root: 14
_FP14 = {"vdiv", "vsqrt"}

_LOAD1 = {"ldr", "ldrb", "ldrh", "ldrsb", "ldrsh", "ldrex", "ldrexb", "ldrexh", "ldrt", "ldrbt",
          "ldrht", "ldrsbt", "ldrsht"}      # single loads: 2 (1 when pipelined after a load)
_STORE1 = {"str", "strb", "strh", "strex", "strexb", "strexh", "strt", "strbt", "strht"}   # 1
_MULTI = {"ldm", "ldmia", "ldmfd", "ldmdb", "ldmea", "stm", "stmia", "stmea", "stmdb", "stmfd",
          "push", "pop"}                    # 1 + N registers (+ P when the list holds pc)
_FPMULTI = {"vldm", "vldmia", "vldmdb", "vstm", "vstmia", "vstmdb", "vpush", "vpop"}   # 1 + N words
_BRANCH = {"b", "bl", "blx", "bx"}          # taken 1 + P (BL, BLX, BX always taken); not taken 1
_CBRANCH = {"cbz", "cbnz"}                  # conditional by nature: taken 1 + P, not taken 1
_TABLEBRANCH = {"tbb", "tbh"}               # 2 + P (a load, then the refill)
_PLD = {"pld", "pli"}                       # 1

_KNOWN = (_ALU1 | _FP1 | _FP3 | _FP14 | _LOAD1 | _STORE1 | _MULTI | _FPMULTI | _BRANCH | _CBRANCH
          | _TABLEBRANCH | _PLD | {"vldr", "vstr", "vmov", "ldrd", "strd", "sdiv", "udiv", "it"})
_CONDS = {"eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt",
          "le", "al"}
_IT = re.compile(r"^it[te]{0,3}$")
_REGLIST = re.compile(r"\{([^}]*)\}")


def split_mnemonic(mnemonic: str) -> tuple[str, bool]:
    """objdump's mnemonic -> (base name in the table, conditional?): 'bne.n' -> ('b', True),
    'vmovgt.f32' -> ('vmov', True), 'lsls' -> ('lsl', False), 'bls' -> ('b', True)."""
    m = mnemonic.lower().split(".")[0]       # .n/.w widths and .f32/.s32 data types
    if _IT.match(m):
        return "it", False
    if m in _KNOWN:
        return m, False
    if len(m) > 2 and m[-2:] in _CONDS:
        rest = m[:-2]
        if rest in _KNOWN:
            return rest, True
        if rest.endswith("s") and rest[:-1] in _KNOWN:
            return rest[:-1], True
    if m.endswith("s") and m[:-1] in _KNOWN:
        return m[:-1], False
    return m, False


def _reglist_words(operands: str) -> tuple[int, bool]:
    """Registers in a {list} as 32-bit words (a d register is 2), and whether pc is in it."""
    m = _REGLIST.search(operands)
    if not m:
        return 0, False
    n, pc = 0, False
    for item in (x.strip() for x in m.group(1).split(",")):
        if not item:
            continue
        width = 2 if item.startswith("d") else 1
        if "-" in item:
            a, b = item.split("-")
            n += (int(b[1:]) - int(a[1:]) + 1) * width
        else:
            n += width
            pc |= item == "pc"
    return n, pc


@dataclass(frozen=True)
class Cost:
    """Cycles of one instruction: taken (or unconditional) and not taken; `load` marks a single
    load after which the next load or store pipelines."""
    taken: int
    not_taken: int
    load: bool = False
    known: bool = True


def instruction_cost(mnemonic: str, operands: str) -> Cost:
    """Cycles of one instruction by the TRM table (before load pipelining)."""
    P = BRANCH_REFILL
    base, cond = split_mnemonic(mnemonic)
    ops = operands.replace(" ", "")
    if base in _BRANCH:
        return Cost(1 + P, 1) if cond else Cost(1 + P, 1 + P)     # B<cond>, BXEQ in an IT block
    if base in _CBRANCH:
        return Cost(1 + P, 1)
    if base in _TABLEBRANCH:
        return Cost(2 + P, 2 + P)
    if base in _LOAD1:
        if ops.startswith("pc,"):                        # LDR pc: a load then a refill
            c = 2 + P
            return Cost(c, 1 if cond else c)
        writeback = "]!" in ops or re.search(r"\],", ops) is not None
        return Cost(2, 2, load=not writeback)
    if base in _STORE1 | _PLD:
        return Cost(1, 1)
    if base in ("ldrd", "strd"):
        return Cost(3, 3)                                # 1 + N, N = 2 words
    if base in _MULTI:
        n, pc = _reglist_words(ops)
        c = 1 + n + (P if pc and base in ("pop", "ldm", "ldmia", "ldmfd", "ldmdb", "ldmea") else 0)
        return Cost(c, 1 + n if pc and cond else c)
    if base in _FPMULTI:
        n, _ = _reglist_words(ops)
        return Cost(1 + n, 1 + n)
    if base in ("vldr", "vstr"):
        return Cost(2, 2)
    if base == "vmov":                                   # two core registers <-> two FPU registers: 2
        c = 2 if ops.count(",") == 3 or (ops.count(",") == 2 and ops.split(",")[0].startswith(("r", "d"))
                                         and ops.split(",")[1].startswith("r")) else 1
        return Cost(c, c)
    if base in _FP14:
        return Cost(14, 14)
    if base in _FP3:
        return Cost(3, 3)
    if base in _FP1:
        return Cost(1, 1)
    if base in ("sdiv", "udiv"):
        return Cost(SDIV_CYCLES, SDIV_CYCLES)
    if base == "it":
        return Cost(1, 1)
    if base in _ALU1:
        if ops.startswith("pc,"):                        # MOV pc / ADD pc: a branch
            return Cost(1 + P, 1 if cond else 1 + P)
        return Cost(1, 1)
    return Cost(1, 1, known=False)


# --------------------------------------------------------------------------------------
# Disassembly: address -> (mnemonic, operands)
# --------------------------------------------------------------------------------------

_INSN = re.compile(r"^\s*([0-9a-f]+):\s+([a-z][\w.]*)\s*(.*)$")


def disassemble(elf: Path) -> dict[int, tuple[str, str]]:
    """Every instruction of the image as objdump decodes it (data words in code excluded)."""
    out = subprocess.run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)],
                         capture_output=True, text=True, check=True, timeout=120).stdout
    insns: dict[int, tuple[str, str]] = {}
    for line in out.splitlines():
        m = _INSN.match(line)
        if m and not m.group(2).startswith("."):
            ops = m.group(3).split(";")[0].split("@")[0].strip()
            insns[int(m.group(1), 16)] = (m.group(2), ops)
    return insns


# --------------------------------------------------------------------------------------
# Counting in unicorn
# --------------------------------------------------------------------------------------

@dataclass
class _Block:
    addresses: list[int]
    costs: list[Cost]
    end: int
    taken_total: int = 0          # cycles when its last instruction branches (or always)
    not_taken_total: int = 0      # when it falls through
    per_address_taken: list[int] = field(default_factory=list)
    per_address_not_taken: list[int] = field(default_factory=list)


class CycleCounter:
    """Estimated cycles of every step an Emulator runs in `count_steps` (attach before it).

    A block hook (added after the emulator's own, so `emu.in_step` is already set for the
    block) notes each block the step executes and which block ran next; the costs come from
    `instruction_cost` over the ELF's disassembly."""

    def __init__(self, emu, elf: Path):
        from unicorn import UC_HOOK_BLOCK
        self.emu = emu
        self.insns = disassemble(elf)
        self._blocks: dict[tuple[int, int], _Block] = {}
        self._prev: tuple[int, int] | None = None
        self.transitions: Counter[tuple[int, int, bool]] = Counter()
        self.step_cycles: list[int] = []
        self.step_instructions: list[int] = []
        self.unmodelled: Counter[str] = Counter()
        emu.uc.hook_add(UC_HOOK_BLOCK, self._on_block)

    def _block(self, address: int, size: int) -> _Block:
        key = (address, size)
        b = self._blocks.get(key)
        if b is not None:
            return b
        from .emulate import thumb_instruction_offsets
        addrs = [address + o for o in thumb_instruction_offsets(bytes(self.emu.uc.mem_read(address, size)))]
        costs = []
        for a in addrs:
            mn, ops = self.insns.get(a, ("?", ""))
            costs.append(instruction_cost(mn, ops))
        # load pipelining (TRM 3.3.2): a single load right after a single load loses a cycle
        per = [c.taken for c in costs]
        for i in range(1, len(costs)):
            if costs[i - 1].load and costs[i].load:    # base write-back: neither pipelines
                per[i] -= 1
        last_nt = list(per)
        if costs:
            last_nt[-1] = costs[-1].not_taken
        b = _Block(addrs, costs, address + size, sum(per), sum(last_nt), per, last_nt)
        self._blocks[key] = b
        return b

    def _on_block(self, _uc, address, size, _user):
        prev = self._prev
        if prev is not None:
            taken = address != prev[0] + prev[1]
            self.transitions[(prev[0], prev[1], taken)] += 1
            b = self._block(*prev)
            self.step_cycles[-1] += b.taken_total if taken else b.not_taken_total
            self.step_instructions[-1] += len(b.addresses)
        if self.emu.in_step:
            if prev is None:                      # the step's entry block: a new call
                self.step_cycles.append(0)
                self.step_instructions.append(0)
            self._prev = (address, size)
        else:
            self._prev = None

    def per_address(self) -> Counter[int]:
        """Estimated cycles at each executed address, over every counted step."""
        out: Counter[int] = Counter()
        for (a, s, taken), n in self.transitions.items():
            b = self._block(a, s)
            for addr, c in zip(b.addresses, b.per_address_taken if taken else b.per_address_not_taken):
                out[addr] += n * c
        return out

    def executions(self, bases: set[str]) -> int:
        """How many instructions with these base mnemonics (`split_mnemonic`, e.g. {"vdiv",
        "vsqrt"}) ran over every counted step."""
        n = 0
        for (a, s, _t), times in self.transitions.items():
            b = self._block(a, s)
            n += times * sum(split_mnemonic(self.insns.get(addr, ("?", ""))[0])[0] in bases for addr in b.addresses)
        return n

    def unmodelled_mnemonics(self) -> list[str]:
        """Executed mnemonics the table does not know (costed 1 each)."""
        seen = set()
        for (a, s, _t) in self.transitions:
            b = self._block(a, s)
            for addr, c in zip(b.addresses, b.costs):
                if not c.known:
                    seen.add(self.insns.get(addr, ("?", ""))[0])
        return sorted(seen)

    def estimate(self, instructions: np.ndarray | None = None) -> dict:
        """Per-step figures; `instructions` (the emulator's own per-step counts) must agree
        with the instructions this hook saw, step by step."""
        cyc = np.asarray(self.step_cycles, dtype=np.int64)
        if instructions is not None:
            seen = np.asarray(self.step_instructions, dtype=np.int64)
            if len(seen) != len(instructions) or not np.array_equal(seen, np.asarray(instructions)):
                raise RuntimeError("cycle counter saw other instructions than the step counter")
        if not len(cyc):
            return {"cycles_est_mean": float("nan"), "cycles_est_min": -1, "cycles_est_max": -1,
                    "cycles_est_steps": 0, "cycles_est_unmodelled": [], "cycles_est_model": MODEL_TEXT}
        return {"cycles_est_mean": float(cyc.mean()), "cycles_est_min": int(cyc.min()),
                "cycles_est_max": int(cyc.max()), "cycles_est_steps": int(len(cyc)),
                "cycles_est_unmodelled": self.unmodelled_mnemonics(), "cycles_est_model": MODEL_TEXT}
