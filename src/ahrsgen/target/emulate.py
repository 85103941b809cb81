"""Running a test image: QEMU (whole run, -icount) and unicorn (exact per-step counts, stack painting)."""
from __future__ import annotations

import ctypes
import ctypes.util
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .build import (CPUS, ICOUNT_SHIFT, LINK_FLAGS, QEMU_MACHINE, RECORD_DTYPE, SYSTICK_HZ, TARGET_DIR,
                    FilterBinding, _run, cflags_for, require_tools)


# --------------------------------------------------------------------------------------
# Running in QEMU
# --------------------------------------------------------------------------------------

def records_from_log(log) -> np.ndarray:
    """A SensorLog as the harness's 56-byte records (float32; NaN rows kept as NaN)."""
    n = len(log)
    rec = np.zeros(n, dtype=RECORD_DTYPE)
    rec["gyro"] = log.gyro
    rec["accel"] = log.accel
    rec["mag"] = log.mag
    rec["gps_vel"] = log.gps_vel
    rec["valid"] = log.valid
    rec["dt"] = log.dt
    return rec


@dataclass
class TargetRun:
    status: np.ndarray        # (N,) uint32
    state: np.ndarray         # (N, state_bytes) uint8, raw state after each step
    state_bytes: int
    ticks: int                # SysTick ticks spent in glue_step (whole run)
    icount_shift: int | None
    console: str
    step_ticks: np.ndarray | None = None   # (N,) SysTick ticks around each glue_step call
    stack_below_main: int | None = None    # deepest stack use of glue_step (+ filter) over the run

    def glue_instructions_icount(self) -> np.ndarray | None:
        """Per step: instructions between the two SysTick reads (the glue_step call and a
        few harness instructions), exact under -icount when there are more than 2 ticks
        per instruction (shift >= 7 with the 25 MHz SysTick): each count is the nearest
        integer to ticks * 40 ns / 2**shift."""
        if self.icount_shift is None or self.step_ticks is None:
            return None
        per_insn = (2 ** self.icount_shift) * SYSTICK_HZ / 1e9       # ticks per instruction
        return np.rint(self.step_ticks / per_insn).astype(np.int64)

    @property
    def instructions_per_step_icount(self) -> float | None:
        """Mean instructions per glue_step from SysTick under -icount (includes the glue
        and the SysTick reads, ~20 instructions; resolution 40/2**shift per step)."""
        if self.icount_shift is None or len(self.status) == 0:
            return None
        ns = self.ticks * (1e9 / SYSTICK_HZ)
        return ns / (2 ** self.icount_shift) / len(self.status)

    def field(self, b: FilterBinding, name: str) -> np.ndarray:
        off, count = b.state_fields[name]
        dt = np.dtype("<f4") if b.scalar == "float" else np.dtype("<f8")
        raw = np.ascontiguousarray(self.state[:, off:off + count * dt.itemsize])
        return raw.view(dt).reshape(len(self.state), count)


def run_qemu(elf: Path, records: np.ndarray, workdir: Path, icount_shift: int | None = ICOUNT_SHIFT,
             timeout: float = 120) -> TargetRun:
    """Run the test image on the emulated Cortex-M4F and read back what it wrote."""
    require_tools(need_unicorn=False)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    np.ascontiguousarray(records, dtype=RECORD_DTYPE).tofile(workdir / "ahrs_in.bin")
    out = workdir / "ahrs_out.bin"
    if out.exists():
        out.unlink()
    cmd = ["qemu-system-arm", "-M", QEMU_MACHINE, "-nographic", "-monitor", "none", "-serial", "none",
           "-semihosting-config", "enable=on,target=native"]
    if icount_shift is not None:
        cmd += ["-icount", f"shift={icount_shift}"]
    cmd += ["-kernel", str(Path(elf).resolve())]
    p = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout)
    console = p.stdout + p.stderr
    if p.returncode != 0:
        raise RuntimeError(f"target image exited with {p.returncode}: {console.strip()}")
    m = re.search(r"AHRS_DONE n=0x([0-9a-f]+) ticks=0x([0-9a-f]{8})0x([0-9a-f]{8}) state_bytes=0x([0-9a-f]+)"
                  r" stack=0x([0-9a-f]+)", console)
    if not m:
        raise RuntimeError(f"target image did not report completion: {console.strip()!r}")
    n = int(m.group(1), 16)
    ticks = (int(m.group(2), 16) << 32) | int(m.group(3), 16)
    sbytes = int(m.group(4), 16)
    words = 2 + (sbytes + 3) // 4
    raw = np.fromfile(out, dtype="<u4")
    if raw.size != n * words or n != len(records):
        raise RuntimeError(f"target output has {raw.size} words, expected {len(records)} x {words}")
    raw = raw.reshape(n, words)
    state = raw[:, 2:].copy().view(np.uint8)[:, :sbytes]
    return TargetRun(raw[:, 0].copy(), state, sbytes, ticks, icount_shift, console, raw[:, 1].copy(),
                     int(m.group(5), 16))


# --------------------------------------------------------------------------------------
# Instruction counting and stack measurement in unicorn
# --------------------------------------------------------------------------------------

FLASH_BASE, FLASH_SIZE = 0x00000000, 4 << 20
RAM_BASE, RAM_SIZE = 0x20000000, 4 << 20
_RET_MAGIC = FLASH_BASE + FLASH_SIZE - 0x100     # a mapped, never-executed address
_PAINT = 0xA5
_PAINT_BYTES = 64 * 1024


def thumb_instruction_offsets(code: bytes) -> list[int]:
    """Byte offsets of the instructions in a straight run of Thumb-2 code (16- and 32-bit
    encodings: a first halfword 0b11101, 0b11110 or 0b11111 in its top bits takes two)."""
    offsets, i = [], 0
    while i + 1 < len(code):
        offsets.append(i)
        hw = code[i] | (code[i + 1] << 8)
        i += 4 if (hw >> 11) in (0b11101, 0b11110, 0b11111) else 2
    return offsets


def thumb_instruction_count(code: bytes) -> int:
    """Instructions in a straight run of Thumb-2 code (16- and 32-bit encodings)."""
    return len(thumb_instruction_offsets(code))


@dataclass
class StepCounts:
    instructions: np.ndarray   # (N,) instructions executed inside <prefix>_step per call
    glue_instructions: np.ndarray  # (N,) whole glue_step call (record copy + step)
    status: np.ndarray         # (N,) uint32 returned
    state: np.ndarray          # (N, state_bytes) uint8
    stack_bytes: int           # deepest stack use below step's entry SP over all calls


class Emulator:
    """Runs functions of a linked test image in unicorn (Cortex-M4 with FPU).

    The ELF's allocated sections are loaded at their run addresses (so .data starts
    initialised); RAM above .bss is used for the state and the record.  Instructions are
    counted per translation block with the Thumb-2 length rule, only while the filter's
    step (and whatever it calls) runs.
    """

    def __init__(self, elf: Path):
        require_tools()
        from elftools.elf.elffile import ELFFile
        from unicorn import UC_ARCH_ARM, UC_HOOK_BLOCK, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
        from unicorn.arm_const import UC_CPU_ARM_CORTEX_M4

        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)
        self.uc.mem_map(FLASH_BASE, FLASH_SIZE)
        self.uc.mem_map(RAM_BASE, RAM_SIZE)
        self.symbols: dict[str, tuple[int, int]] = {}
        with open(elf, "rb") as f:
            e = ELFFile(f)
            for s in e.iter_sections():
                if (s["sh_flags"] & 2) and s["sh_type"] == "SHT_PROGBITS" and s["sh_size"]:
                    self.uc.mem_write(s["sh_addr"], s.data())
            for sym in e.get_section_by_name(".symtab").iter_symbols():
                if sym["st_info"]["type"] in ("STT_FUNC", "STT_OBJECT") and sym.name:
                    self.symbols[sym.name] = (sym["st_value"] & ~1, sym["st_size"])
        self.scratch = RAM_BASE + RAM_SIZE - 0x20000   # state + record live here
        self.stack_top = RAM_BASE + RAM_SIZE - 0x100
        self.uc.mem_write(_RET_MAGIC, b"\x00\xbf" * 8)  # nops, never reached (until=)
        self._counting = False
        self._ret = None
        self._count = 0
        self._total = 0          # every instruction of the current call (glue included)
        self._entry_sp = None
        self._step_addr = None
        self._ninsn_cache: dict[tuple[int, int], int] = {}
        self.uc.hook_add(UC_HOOK_BLOCK, self._on_block)

    @property
    def in_step(self) -> bool:
        """True while the step (or what it calls) runs: the blocks counted in `count_steps`."""
        return self._counting

    def _ninsn(self, address: int, size: int) -> int:
        key = (address, size)
        n = self._ninsn_cache.get(key)
        if n is None:
            n = thumb_instruction_count(bytes(self.uc.mem_read(address, size)))
            self._ninsn_cache[key] = n
        return n

    def _on_block(self, uc, address, size, _user):
        from unicorn.arm_const import UC_ARM_REG_LR, UC_ARM_REG_SP
        if address != _RET_MAGIC:
            self._total += self._ninsn(address, size)
        if not self._counting:
            if address == self._step_addr:
                self._counting = True
                self._ret = uc.reg_read(UC_ARM_REG_LR) & ~1
                self._entry_sp = uc.reg_read(UC_ARM_REG_SP)
            else:
                return
        elif address == self._ret:
            self._counting = False
            return
        self._count += self._ninsn(address, size)

    def call(self, fn: str, *args: int) -> int:
        from unicorn.arm_const import (UC_ARM_REG_LR, UC_ARM_REG_PC, UC_ARM_REG_R0, UC_ARM_REG_R1,
                                       UC_ARM_REG_R2, UC_ARM_REG_R3, UC_ARM_REG_SP)
        regs = [UC_ARM_REG_R0, UC_ARM_REG_R1, UC_ARM_REG_R2, UC_ARM_REG_R3]
        self._count = 0
        self._total = 0
        self._counting = False
        for r, v in zip(regs, args):
            self.uc.reg_write(r, v)
        self.uc.reg_write(UC_ARM_REG_SP, self.stack_top)
        self.uc.reg_write(UC_ARM_REG_LR, _RET_MAGIC | 1)
        addr = self.symbols[fn][0]
        self.uc.emu_start(addr | 1, _RET_MAGIC, timeout=0, count=50_000_000)
        if self.uc.reg_read(UC_ARM_REG_PC) != _RET_MAGIC:
            raise RuntimeError(f"{fn} did not return within the instruction budget")
        return self.uc.reg_read(UC_ARM_REG_R0)

    def count_call_per_instruction(self, fn: str, *args: int) -> int:
        """Instructions of one whole call counted one by one (UC_HOOK_CODE).

        Slow; exists to check the per-block counting of ``call`` (``self._total``)."""
        from unicorn import UC_HOOK_CODE
        n = [0]

        def on_code(uc, address, size, _user):
            if address != _RET_MAGIC:
                n[0] += 1
        h = self.uc.hook_add(UC_HOOK_CODE, on_code)
        try:
            self.call(fn, *args)
        finally:
            self.uc.hook_del(h)
        return n[0]

    def count_steps(self, step_fn: str, records: np.ndarray, state_bytes: int) -> StepCounts:
        """glue_init, then glue_step for every record; instructions counted in step_fn."""
        self._step_addr = self.symbols[step_fn][0]
        rec_bytes = np.ascontiguousarray(records, dtype=RECORD_DTYPE)
        st = self.scratch
        rp = st + max(0x1000, (state_bytes + 0xFFF) & ~0xFFF)
        if rp + RECORD_DTYPE.itemsize > self.stack_top - _PAINT_BYTES:
            raise ValueError(f"state of {state_bytes} bytes does not fit the emulator's scratch RAM")
        self.uc.mem_write(st, b"\x00" * state_bytes)
        self.call("glue_init", st)
        paint_lo = self.stack_top - _PAINT_BYTES
        self.uc.mem_write(paint_lo, bytes([_PAINT]) * _PAINT_BYTES)
        n = len(rec_bytes)
        counts = np.zeros(n, dtype=np.int64)
        totals = np.zeros(n, dtype=np.int64)
        status = np.zeros(n, dtype=np.uint32)
        state = np.zeros((n, state_bytes), dtype=np.uint8)
        entry_sp = None
        for k in range(n):
            self.uc.mem_write(rp, rec_bytes[k:k + 1].tobytes())
            status[k] = self.call("glue_step", st, rp)
            counts[k] = self._count
            totals[k] = self._total
            if self._entry_sp is not None:
                entry_sp = self._entry_sp
            state[k] = np.frombuffer(bytes(self.uc.mem_read(st, state_bytes)), dtype=np.uint8)
        painted = bytes(self.uc.mem_read(paint_lo, _PAINT_BYTES))
        lowest = next((i for i, c in enumerate(painted) if c != _PAINT), _PAINT_BYTES)
        lowest_addr = paint_lo + lowest
        depth = (entry_sp - lowest_addr) if entry_sp is not None else 0
        return StepCounts(counts, totals, status, state, int(depth))


# --------------------------------------------------------------------------------------
# newlib vs glibc: the float libm functions, argument by argument
# --------------------------------------------------------------------------------------

# function -> (number of arguments, argument sampler); ranges the filters use
_SURVEY = {
    "sinf": (1, lambda r, n: r.uniform(-4.0, 4.0, n)),
    "cosf": (1, lambda r, n: r.uniform(-4.0, 4.0, n)),
    "asinf": (1, lambda r, n: r.uniform(-1.0, 1.0, n)),
    "atanf": (1, lambda r, n: r.normal(0.0, 3.0, n)),
    "expf": (1, lambda r, n: r.uniform(-20.0, 5.0, n)),
    "logf": (1, lambda r, n: r.uniform(1e-6, 1.0, n)),
    "atan2f": (2, lambda r, n: r.normal(0.0, 1.0, (n, 2))),
}


def libm_survey(workdir: Path, n: int = 2000, seed: int = 0, cpu: str = "cortex-m4f") -> dict:
    """Call newlib's float functions (linked for the target, run in unicorn) and the host's
    libm (ctypes) on the same float32 arguments; count differing results and the largest
    difference in ulps.  Explains why a target run and a host run can part in the last bit."""
    import struct
    require_tools()
    from unicorn.arm_const import UC_ARM_REG_S0, UC_ARM_REG_S1
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    flags = cflags_for(cpu, "-O2")
    objs = []
    for src in ("startup.c", "semihost.c", "libm_probe.c"):
        obj = workdir / (Path(src).stem + ".o")
        _run(["arm-none-eabi-gcc", *flags, f"-I{TARGET_DIR}", "-c", str(TARGET_DIR / src), "-o", str(obj)])
        objs.append(str(obj))
    elf = workdir / "libm_probe.elf"
    _run(["arm-none-eabi-gcc", *CPUS[cpu], "-O2", *LINK_FLAGS, "-T", str(TARGET_DIR / "mps2_an386.ld"),
          *objs, "-lm", "-o", str(elf)])
    emu = Emulator(elf)
    host = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")
    rng = np.random.default_rng(seed)
    out = {}
    for fn, (nargs, sample) in _SURVEY.items():
        x = np.asarray(sample(rng, n), np.float32).reshape(n, nargs)
        hf = getattr(host, fn)
        hf.restype, hf.argtypes = ctypes.c_float, [ctypes.c_float] * nargs
        t = np.zeros(n, np.float32)
        h = np.zeros(n, np.float32)
        for k in range(n):
            for reg, v in zip((UC_ARM_REG_S0, UC_ARM_REG_S1), x[k]):
                emu.uc.reg_write(reg, struct.unpack("<I", struct.pack("<f", float(v)))[0])
            emu.call(fn)
            t[k] = struct.unpack("<f", struct.pack("<I", emu.uc.reg_read(UC_ARM_REG_S0)))[0]
            h[k] = hf(*[float(v) for v in x[k]])
        ulp = np.abs(t.view(np.int32).astype(np.int64) - h.view(np.int32).astype(np.int64))
        out[fn] = {"arguments": n, "differ": int(np.count_nonzero(ulp)), "max_ulp": int(ulp.max())}
    return out
