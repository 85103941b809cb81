"""Cortex-M4F target checks: cross build, run in QEMU, compare with the host, footprint.

What a flight-controller engineer asks of generated code: does it give the same answers
on my MCU as on my PC, and how much flash, RAM, stack and time does it take?  This
module answers both with real tools:

* **Cross build** with ``arm-none-eabi-gcc`` for a Cortex-M4F (``-mcpu=cortex-m4 -mthumb
  -mfpu=fpv4-sp-d16 -mfloat-abi=hard``) at ``-O2`` and ``-Os``, linked with the product's
  own startup code and linker script (``firmware_sim/target/``) into a bare-metal image.
* **Run** under ``qemu-system-arm -M mps2-an386`` (a Cortex-M4 with FPU).  The image reads
  the sensor log from a host file and writes, for every sample, the status and the raw
  bytes of the state struct back through semihosting; nothing is printed as decimal text,
  so the comparison with the host build is exact to the bit.
* **Footprint** per filter and build: flash (text + rodata + .data image) and static RAM
  (state struct, .data, .bss) as the *increase* over a baseline image that does not call
  the filter, so everything the filter drags in from newlib counts; worst-case stack of
  ``step`` from ``-fstack-usage`` plus the call graph of the linked image (objdump),
  checked against the stack actually touched (stack painting in the image and in
  unicorn); instructions per ``step`` for every step, from QEMU ``-icount`` with SysTick,
  checked step by step against an exact count of the ELF's own code run in the
  ``unicorn`` emulator.  Instructions, not cycles: QEMU does not model the M4 pipeline
  and QEMU 7.2 has no DWT CYCCNT.

Both builds use ``-ffp-contract=off`` (the M4 FPU has VFMA; a fused multiply-add rounds
once and would make the target differ from x86-64 without it) and ``-fno-math-errno``
(``sqrtf`` becomes one ``vsqrt.f32``; without it GCC adds a compare and a call to the
library ``sqrtf`` for the errno case).  Basic arithmetic and ``sqrtf`` are correctly
rounded IEEE-754 on both sides; the transcendental functions (``sinf``, ``atan2f``, ...)
come from newlib on the target and glibc on the host and differ by 1 ulp for some
arguments (``libm_survey``).  So the comparison runs twice: with the real libm against a
stated bound, and with ``target/libm_pinned.h`` (float functions through double, on both
sides), where every filter must be bit-identical in every step.  docs/target.md has the
figures.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

TARGET_DIR = Path(__file__).resolve().parent / "target"
PINNED_LIBM_H = TARGET_DIR / "libm_pinned.h"

CPUS = {
    "cortex-m4f": ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"],
}
OPT_LEVELS = ("-O2", "-Os")
# Flags every figure in the report assumes (docs/target.md says so too).
MATH_FLAGS = ["-ffp-contract=off", "-fno-math-errno"]
WARN_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion",
              "-Wdouble-promotion", "-Wshadow", "-Werror"]
SECTION_FLAGS = ["-ffunction-sections", "-fdata-sections"]
LINK_FLAGS = ["-nostartfiles", "-specs=nano.specs", "-Wl,--gc-sections"]

QEMU_MACHINE = "mps2-an386"
ICOUNT_SHIFT = 7            # 2**7 ns of virtual time per instruction under -icount
SYSTICK_HZ = 25_000_000     # mps2 SYSCLK, which drives SysTick in QEMU

APT_PACKAGES = ["gcc-arm-none-eabi", "libnewlib-arm-none-eabi", "qemu-system-arm"]
PIP_PACKAGES = ["unicorn", "pyelftools"]

# Record layout shared with firmware_sim/target/ahrs_record.h (56 bytes, little-endian).
RECORD_DTYPE = np.dtype([
    ("gyro", "<f4", (3,)), ("accel", "<f4", (3,)), ("mag", "<f4", (3,)),
    ("gps_vel", "<f4", (3,)), ("valid", "<u4"), ("dt", "<f4"),
])
assert RECORD_DTYPE.itemsize == 56


class ToolchainMissing(RuntimeError):
    """The cross toolchain, QEMU or the Python emulator packages are not installed."""


def _which(name: str) -> str | None:
    return shutil.which(name)


def missing_tools(need_unicorn: bool = True) -> list[str]:
    """Names of what is missing for the target checks (empty list: all present)."""
    missing = []
    for tool in ("arm-none-eabi-gcc", "arm-none-eabi-objdump", "arm-none-eabi-size",
                 "qemu-system-arm"):
        if _which(tool) is None:
            missing.append(tool)
    if _which("arm-none-eabi-gcc") is not None:
        # newlib: the headers and libm the image links against
        probe = subprocess.run(["arm-none-eabi-gcc", *CPUS["cortex-m4f"], "-print-file-name=libm.a"],
                               capture_output=True, text=True)
        if probe.returncode != 0 or not os.path.isabs(probe.stdout.strip()):
            missing.append("newlib (libm.a for thumb/v7e-m+fp/hard)")
    if need_unicorn:
        for mod in ("unicorn", "elftools"):
            try:
                __import__(mod)
            except ImportError:
                missing.append(f"python module {mod}")
    return missing


def require_tools(need_unicorn: bool = True) -> None:
    missing = missing_tools(need_unicorn)
    if missing:
        raise ToolchainMissing(
            "target checks need: " + ", ".join(missing) + ". Install with `apt-get install "
            + " ".join(APT_PACKAGES) + "` and `pip install " + " ".join(PIP_PACKAGES) + "`.")


def _run(cmd: list[str], cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"command failed ({p.returncode}): {' '.join(map(str, cmd))}\n{p.stdout}{p.stderr}")
    return p


# --------------------------------------------------------------------------------------
# Binding a filter to the harness
# --------------------------------------------------------------------------------------

@dataclass
class FilterBinding:
    """How the harness calls one filter's C API.

    ``input_fields`` maps the record's roles (gyro, accel, mag, gps_vel, valid) to the
    field names of the filter's input struct; a role the filter's input struct lacks is
    left out.  ``state_fields`` (name -> (byte offset, count)) lets Python decode the
    raw state bytes (at least ``q``).
    """
    name: str
    prefix: str
    sources: list[Path]
    include_dirs: list[Path]
    header: str
    state_type: str
    input_type: str
    input_fields: dict[str, str]
    state_size: int | None = None
    state_fields: dict[str, tuple[int, int]] = field(default_factory=dict)
    scalar: str = "float"
    has_euler: bool = False      # <prefix>_euler(const state *, real rpy[3]) exists

    @property
    def init_fn(self) -> str:
        return f"{self.prefix}_init"

    @property
    def step_fn(self) -> str:
        return f"{self.prefix}_step"


def toy_binding() -> FilterBinding:
    """The toolchain bring-up filter in firmware_sim/target/toy.c (float; uses libm)."""
    return FilterBinding(
        name="toy", prefix="toy", sources=[TARGET_DIR / "toy.c"], include_dirs=[TARGET_DIR],
        header="toy.h", state_type="toy_state", input_type="toy_input",
        input_fields={"gyro": "gyro", "accel": "accel", "mag": "mag",
                      "gps_vel": "gps_vel_ned", "valid": "valid"},
        state_size=24, state_fields={"q": (0, 4), "tilt": (16, 2)},
    )


PEERS_DIR = TARGET_DIR / "peers"
PEER_NAMES = ("madgwick", "mahony")


def peer_binding(name: str) -> FilterBinding:
    """Calibration peers (firmware_sim/target/peers): Madgwick's and Mahony's 9-axis updates,
    written from their papers, to put the instruction counts next to known figures."""
    if name not in PEER_NAMES:
        raise ValueError(f"unknown peer {name!r}; known: {', '.join(PEER_NAMES)}")
    fields = {"madgwick": {"q": (0, 4)}, "mahony": {"q": (0, 4), "integral": (16, 3)}}[name]
    return FilterBinding(
        name=f"peer:{name}", prefix=name, sources=[PEERS_DIR / f"{name}.c"], include_dirs=[PEERS_DIR],
        header="peers.h", state_type=f"{name}_state", input_type=f"{name}_input",
        input_fields={"gyro": "gyro", "accel": "accel", "mag": "mag", "gps_vel": "gps_vel_ned", "valid": "valid"},
        state_size=16 if name == "madgwick" else 28, state_fields=fields,
    )


def write_glue(b: FilterBinding, out_dir: Path) -> None:
    """filter_glue.h / filter_glue.c: the harness's only filter-specific code.

    The glue functions are out of line (own translation unit, no LTO) so that the
    emulator can call them and count the filter's own step from its entry to its return.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "filter_glue.h").write_text(
        "/* generated by firmware_sim/target.py: binds the harness to one filter */\n"
        "#ifndef FILTER_GLUE_H\n#define FILTER_GLUE_H\n"
        "#include <stdint.h>\n"
        f'#include "{b.header}"\n'
        '#include "ahrs_record.h"\n'
        f"typedef {b.state_type} glue_state;\n"
        "void glue_init(glue_state *s);\n"
        "uint32_t glue_step(glue_state *s, const ahrs_record *r);\n"
        + ("#define GLUE_HAS_EULER 1\nvoid glue_euler(const glue_state *s, float rpy[3]);\n" if b.has_euler else "")
        + "#endif\n")
    lines = []
    for role in ("gyro", "accel", "mag", "gps_vel"):
        fld = b.input_fields.get(role)
        if fld:
            lines.append(f"    for (int i = 0; i < 3; i++) {{ in.{fld}[i] = r->{role}[i]; }}")
    if b.input_fields.get("valid"):
        lines.append(f"    in.{b.input_fields['valid']} = r->valid;")
    dt = "r->dt" if b.scalar == "float" else "(double)r->dt"
    if b.scalar != "float":
        lines = [ln.replace("= r->", "= (double)r->") if "valid" not in ln else ln for ln in lines]
    (out_dir / "filter_glue.c").write_text(
        "/* generated by firmware_sim/target.py */\n"
        "#include <string.h>\n"
        '#include "filter_glue.h"\n\n'
        "__attribute__((noinline)) void glue_init(glue_state *s)\n"
        f"{{\n    {b.init_fn}(s);\n}}\n\n"
        "__attribute__((noinline)) uint32_t glue_step(glue_state *s, const ahrs_record *r)\n"
        f"{{\n    {b.input_type} in = {{0}};\n"
        + "\n".join(lines) + "\n"
        f"    return (uint32_t){b.step_fn}(s, &in, {dt});\n}}\n"
        + ("\n__attribute__((noinline)) void glue_euler(const glue_state *s, float rpy[3])\n"
           f"{{\n    {b.scalar} out[3];\n    {b.prefix}_euler(s, out);\n"
           "    for (int i = 0; i < 3; i++) { rpy[i] = (float)out[i]; }\n}\n" if b.has_euler else ""))


# --------------------------------------------------------------------------------------
# Building
# --------------------------------------------------------------------------------------

@dataclass
class Build:
    name: str
    opt: str
    cpu: str
    workdir: Path
    elf: Path                   # the test image (harness + filter)
    filter_objects: list[Path]  # the filter's own objects
    stack_usage_files: list[Path]
    cflags: list[str]


def cflags_for(cpu: str, opt: str) -> list[str]:
    if cpu not in CPUS:
        raise ValueError(f"unknown cpu {cpu!r}; known: {', '.join(CPUS)}")
    if opt not in OPT_LEVELS:
        raise ValueError(f"unknown optimisation {opt!r}; known: {', '.join(OPT_LEVELS)}")
    return [*CPUS[cpu], opt, *MATH_FLAGS, *WARN_FLAGS, *SECTION_FLAGS]


def build(b: FilterBinding, workdir: Path, opt: str = "-O2", cpu: str = "cortex-m4f",
          extra_main: str | None = None, pinned_libm: bool = False, reuse: Build | None = None) -> Build:
    """Compile the filter and the harness for the target and link the test image.

    The filter's sources compile with the same strict warnings as on the host (-Werror).
    ``extra_main`` replaces harness_main.c (used for the footprint images).
    ``pinned_libm`` force-includes target/libm_pinned.h into the filter (identity check only).
    ``reuse``: link the filter objects of an earlier build instead of compiling them again.
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    write_glue(b, workdir)
    flags = cflags_for(cpu, opt)
    incs = [f"-I{workdir}", f"-I{TARGET_DIR}", *[f"-I{d}" for d in b.include_dirs]]
    objs, filt_objs, sus = [], [], []
    for src in ([] if reuse is not None else b.sources):
        obj = workdir / (Path(src).stem + ".o")
        pin = ["-include", str(PINNED_LIBM_H)] if pinned_libm else []
        _run(["arm-none-eabi-gcc", *flags, *incs, *pin, "-fstack-usage", "-c", str(src), "-o", str(obj)],
             cwd=workdir)
        objs.append(obj)
        filt_objs.append(obj)
        sus.append(obj.with_suffix(".su"))
    if reuse is not None:
        objs += reuse.filter_objects
        filt_objs += reuse.filter_objects
        sus += reuse.stack_usage_files[:len(reuse.filter_objects)]
    main_src = extra_main or str(TARGET_DIR / "harness_main.c")
    for src in [str(TARGET_DIR / "startup.c"), str(TARGET_DIR / "semihost.c"),
                str(workdir / "filter_glue.c"), main_src]:
        obj = workdir / ("h_" + Path(src).stem + ".o")
        _run(["arm-none-eabi-gcc", *flags, *incs, "-fstack-usage", "-c", src, "-o", str(obj)],
             cwd=workdir)
        objs.append(obj)
        sus.append(obj.with_suffix(".su"))
    elf = workdir / "image.elf"
    _run(["arm-none-eabi-gcc", *CPUS[cpu], opt, *LINK_FLAGS, "-T", str(TARGET_DIR / "mps2_an386.ld"),
          *map(str, objs), "-lm", "-Wl,-Map=" + str(workdir / "image.map"), "-o", str(elf)], cwd=workdir)
    return Build(b.name, opt, cpu, workdir, elf, filt_objs, sus, flags)


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


def thumb_instruction_count(code: bytes) -> int:
    """Instructions in a straight run of Thumb-2 code (16- and 32-bit encodings)."""
    n, i = 0, 0
    while i + 1 < len(code):
        hw = code[i] | (code[i + 1] << 8)
        i += 4 if (hw >> 11) in (0b11101, 0b11110, 0b11111) else 2
        n += 1
    return n


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


def footprint(b: FilterBinding, build_: Build, counts: StepCounts | None = None,
              run: TargetRun | None = None) -> Footprint:
    """Sizes of the filter in one build (links a footprint image and a baseline)."""
    wd = build_.workdir / "footprint"
    wd.mkdir(exist_ok=True)
    main_c = wd / "fp_main.c"
    main_c.write_text(FOOTPRINT_MAIN)
    with_f = build(b, wd / "with", build_.opt, build_.cpu, extra_main=str(main_c), reuse=build_)
    base_main = wd / "fp_base.c"
    base_main.write_text("#define FP_BASELINE 1\n" + FOOTPRINT_MAIN)
    base = build(b, wd / "base", build_.opt, build_.cpu, extra_main=str(base_main), reuse=build_)
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
    )


def format_table(rows: list[Footprint]) -> str:
    """Markdown table of footprints (library column: entry points only, no __internals)."""
    hdr = ("| filter | build | flash B (own code) | static RAM B (state) | stack B static / measured "
           "| instructions/step mean (min-max) | library functions |")
    sep = "|" + "---|" * 7
    lines = [hdr, sep]
    for r in rows:
        own = r.own_code_bytes
        libs = [f for f in r.library_calls if not f.startswith("__")]
        lines.append(
            f"| {r.filter} | {r.opt}{' double' if r.precision == 'double' else ''} | {r.flash_bytes} ({own}) | {r.ram_static_bytes} ({r.state_bytes}) "
            f"| {r.stack_bytes} / {r.stack_measured_bytes} | {r.instructions_mean:.0f} "
            f"({r.instructions_min}-{r.instructions_max}) | {', '.join(libs) or '-'} |")
    return "\n".join(lines)


def to_json(rows: list[Footprint]) -> str:
    return json.dumps([asdict(r) for r in rows], indent=2, sort_keys=True)


# --------------------------------------------------------------------------------------
# One filter, end to end
# --------------------------------------------------------------------------------------

@dataclass
class TargetResult:
    build: Build
    run: TargetRun
    counts: StepCounts
    footprint: Footprint


def check_filter(b: FilterBinding, records: np.ndarray, workdir: Path | None = None,
                 opt: str = "-O2", cpu: str = "cortex-m4f",
                 count_steps: int | None = 50) -> TargetResult:
    """Build for the target, run in QEMU, count in unicorn, measure the footprint.

    ``count_steps`` limits the unicorn run (exact counts and stack painting on the first
    steps; None = all).  The QEMU run always covers every record and gives the per-step
    counts of the whole run once it agrees with unicorn on the common steps.
    """
    require_tools()
    workdir = Path(workdir or tempfile.mkdtemp(prefix=f"ahrsgen-target-{b.name}-"))
    tag = opt.lstrip("-")
    bld = build(b, workdir / f"{b.name}-{tag}", opt, cpu)
    run = run_qemu(bld.elf, records, bld.workdir)
    if b.state_size is None:
        b.state_size = run.state_bytes
    sub = records if count_steps is None else records[:count_steps]
    emu = Emulator(bld.elf)
    counts = emu.count_steps(b.step_fn, sub, run.state_bytes)
    fp = footprint(b, bld, counts, run)
    return TargetResult(bld, run, counts, fp)


# --------------------------------------------------------------------------------------
# Generated filters (generated/<name>/ with <prefix>.h/.c and manifest.json)
# --------------------------------------------------------------------------------------

def binding_from_generated(gen_dir: str | Path) -> FilterBinding:
    """Bind the harness to a generated filter through its manifest (no layout typed here)."""
    gen_dir = Path(gen_dir)
    man = json.loads((gen_dir / "manifest.json").read_text())
    prefix, real = man["prefix"], man["precision"]
    st = man["structs"]["state"]
    in_names = {f["name"] for f in man["structs"]["input"]["fields"]}
    roles = {"gyro": "gyro", "accel": "accel", "mag": "mag", "gps_vel": "gps_vel_ned", "valid": "valid"}
    return FilterBinding(
        name=man["filter"], prefix=prefix, sources=[gen_dir / man["files"]["source"]],
        include_dirs=[gen_dir], header=man["files"]["header"],
        state_type=f"{prefix}_state", input_type=f"{prefix}_input",
        input_fields={r: f for r, f in roles.items() if f in in_names},
        state_size=st["size"],
        state_fields={f["name"]: (f["offset"], f["count"]) for f in st["fields"] if f["type"] == "real"},
        scalar=real, has_euler=True,
    )


def generate(filter_name: str, out_dir: Path, config_file=None, sets=None, prefix=None,
             precision: str = "float") -> Path:
    """Render a filter configuration into out_dir (float unless asked: the M4F FPU is
    single precision, a double build runs on soft-float helpers)."""
    from generator import config, render
    cfg = config.resolve(filter_name, config_file, sets, precision=precision, prefix=prefix)
    render.write(render.render(cfg), out_dir)
    return Path(out_dir)


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
    """The host float build of a generated filter (firmware_sim/host.py's compile_shared and
    ctypes structs from the manifest), stepped one sample at a time so that the whole state
    struct can be read after every step."""

    def __init__(self, gen_dir: Path, pinned_libm: bool = False):
        from firmware_sim import host
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
    from firmware_sim import metrics
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

# The scenario each filter's source experiment is about (SPEC.md); --scenario overrides.
DEFAULT_SCENARIO = {"qcf": "fixedwing_gps", "mekf": "fixedwing_gps",
                    "adukf": "static_mag_disturbance", "cpf": "turntable"}
DEFAULT_TOLERANCE_DEG = 1e-3
# Filters whose run is a random process by design: the particle filter resamples, so a
# 1-ulp difference between newlib's and glibc's logf/cosf/expf picks different particles and
# the trajectories part (by tenths of a degree) while both stay equally accurate.  For them
# the real-libm check compares accuracy against the truth instead of trajectories; the
# pinned-libm run must still be bit-identical.
STOCHASTIC_FILTERS = {"cpf": "particle resampling amplifies 1-ulp libm differences"}
ACCURACY_TOLERANCE_DEG = 0.1
_COMMON_STATUS_MASK = (1 << 12) - 1    # generator/status.py: bits below FILTER_BASE


def judge(filter_name: str, real: dict, pinned: dict | None, tolerance_deg: float = DEFAULT_TOLERANCE_DEG
          ) -> tuple[bool, str]:
    """PASS/FAIL of one build's comparison with the host, with the reason in words."""
    parts, ok = [], True
    if pinned is not None:
        same = pinned["identical_steps"] == pinned["steps"] and pinned["status_equal"]
        ok &= same
        parts.append("pinned libm: bit-identical in every step" if same else
                     f"pinned libm: DIFFERS from step {pinned['first_difference']} "
                     f"(max {pinned['max_angle_deg']:.3g} deg)")
    if real["identical_steps"] == real["steps"]:
        parts.append("real libm: bit-identical in every step")
        ok &= real["status_equal"]
    elif filter_name in STOCHASTIC_FILTERS:
        d = real.get("max_rms_difference_deg")
        good = d is not None and d <= ACCURACY_TOLERANCE_DEG and real["status_common_equal"]
        ok &= good
        parts.append(f"real libm: trajectories part from step {real['first_difference']} "
                     f"(max {real['max_angle_deg']:.3g} deg; {STOCHASTIC_FILTERS[filter_name]}); "
                     f"RMS error vs truth differs by {d if d is None else f'{d:.3g}'} deg "
                     f"(bound {ACCURACY_TOLERANCE_DEG:g} deg)")
    else:
        good = real["status_equal"] and real["max_angle_deg"] <= tolerance_deg
        ok &= good
        parts.append(f"real libm: bit-identical in {real['identical_steps']}/{real['steps']} steps, first "
                     f"difference at step {real['first_difference']}, max attitude difference "
                     f"{real['max_angle_deg']:.3g} deg (bound {tolerance_deg:g} deg)")
    if not real["status_equal"]:
        parts.append("status codes DIFFER" if not real["status_common_equal"] else
                     "filter-specific status bits differ")
    return ok, "; ".join(parts)


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
                    precision: str = "float") -> list[dict]:
    """Generate (float), cross-build at each optimisation level, run on the target, compare
    with the host float build, measure the footprint.  One dict per build."""
    from firmware_sim import scenarios
    require_tools()
    workdir = Path(workdir or tempfile.mkdtemp(prefix=f"ahrsgen-target-{filter_name}-"))
    gen_dir = generate(filter_name, workdir / "generated", config_file, sets, prefix, precision)
    b = binding_from_generated(gen_dir)
    scen = scenario or DEFAULT_SCENARIO.get(filter_name, "fixedwing_gps")
    if log is None:
        log = scenarios.make(scen, seed=seed, **(scenario_options or {}))
    rec = records_from_log(log)
    results = []
    for i, opt in enumerate(opts):
        r = check_filter(b, rec, workdir, opt=opt, cpu=cpu, count_steps=count_steps)
        cmp_ = asdict(compare_with_host(gen_dir, b, log, r.run))
        pin = None
        if pinned and i == 0 and precision == "float":
            pb = build(b, workdir / f"{b.name}-{opt.lstrip('-')}-pinned", opt, cpu, pinned_libm=True)
            prun = run_qemu(pb.elf, rec, pb.workdir, icount_shift=None)
            pin = asdict(compare_with_host(gen_dir, b, log, prun, pinned_libm=True))
        ok, verdict = judge(filter_name, cmp_, pin, tolerance_deg)
        results.append({"filter": filter_name, "precision": precision, "opt": opt, "cpu": cpu,
                        "scenario": log.name, "seed": seed,
                        "steps": len(rec), "counted_steps": int(len(r.counts.instructions)),
                        "footprint": asdict(r.footprint), "host_comparison": cmp_,
                        "pinned_libm_comparison": pin, "pass": ok, "verdict": verdict,
                        "workdir": str(r.build.workdir)})
    return results


def _print_results(results: list[dict]) -> bool:
    rows = [Footprint(**r["footprint"]) for r in results]
    print(format_table(rows))
    print()
    for r in results:
        print(f"{r['filter']} {r['opt']}: target vs host {r.get('precision', 'float')} build on {r['scenario']} "
              f"({r['steps']} steps): "
              f"{r['verdict']} -> {'PASS' if r['pass'] else 'FAIL'}")
        fp = r["footprint"]
        if fp["double_helpers"] and r.get("precision", "float") == "float":
            print(f"  WARNING: soft-double helpers reachable from step: {', '.join(fp['double_helpers'])}")
    return all(r["pass"] for r in results)


def cmd_target(args) -> int:
    from generator import filters
    from generator.model import ConfigError
    missing = missing_tools()
    if missing:
        raise ConfigError("target checks need " + ", ".join(missing) + " (apt-get install "
                          + " ".join(APT_PACKAGES) + "; pip install " + " ".join(PIP_PACKAGES) + ")")
    names = filters.names() if args.filter == "all" else [args.filter]
    if args.filter == "all" and (args.config or args.set):
        raise ConfigError("--config/--set apply to one filter, not 'all'")
    for n in names:
        filters.load(n)   # unknown filter -> ConfigError
    opts = args.opt or list(OPT_LEVELS)
    sopts = {}
    for item in args.scenario_opt:
        k, _, v = item.partition("=")
        try:
            sopts[k] = float(v) if any(c in v for c in ".e") else int(v)
        except ValueError:
            sopts[k] = v
    results = []
    with tempfile.TemporaryDirectory(prefix="ahrsgen-target-") as tmp:
        root = Path(args.workdir) if args.workdir else Path(tmp)
        for n in names:
            try:
                results += check_generated(n, opts, args.cpu, args.scenario, args.seed, sopts, args.config,
                                           args.set, args.prefix, root / n,
                                           None if args.count_steps == 0 else args.count_steps,
                                           pinned=not args.no_pinned, tolerance_deg=args.tolerance,
                                           precision=args.precision)
            except KeyError as e:
                raise ConfigError(str(e.args[0])) from None
    if not args.workdir:
        for r in results:
            r.pop("workdir", None)
    peer_rows = []
    if args.peers:
        from firmware_sim import scenarios
        log = scenarios.make("fixedwing_gps", seed=args.seed)
        with tempfile.TemporaryDirectory(prefix="ahrsgen-peers-") as tmp:
            for pn in PEER_NAMES:
                for opt in opts:
                    r = check_filter(peer_binding(pn), records_from_log(log), Path(tmp), opt=opt, cpu=args.cpu,
                                     count_steps=None if args.count_steps == 0 else args.count_steps)
                    peer_rows.append(r.footprint)
    print(f"target {args.cpu}: {' '.join(CPUS[args.cpu])} {' '.join(MATH_FLAGS)}; QEMU {QEMU_MACHINE}; "
          f"instructions (not cycles) per step under QEMU -icount, checked step by step against unicorn")
    ok = _print_results(results)
    survey = None
    if args.libm_survey:
        with tempfile.TemporaryDirectory(prefix="ahrsgen-libm-") as tmp:
            survey = libm_survey(Path(tmp), cpu=args.cpu)
        print("\nnewlib (target) vs host libm, float functions on the same float32 arguments:")
        for fn, v in survey.items():
            print(f"  {fn:<7} differs in {v['differ']}/{v['arguments']} arguments, by at most {v['max_ulp']} ulp")
    if peer_rows:
        print("\ncalibration peers (firmware_sim/target/peers, fixedwing_gps; counts only):")
        print(format_table(peer_rows))
    doc = {"cpu": args.cpu, "cpu_flags": CPUS[args.cpu], "math_flags": MATH_FLAGS, "qemu_machine": QEMU_MACHINE,
           "tools": toolchain_versions(), "tolerance_deg": args.tolerance, "results": results,
           "peers": [asdict(r) for r in peer_rows], "libm_survey": survey}
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    print(f"wrote {out}")
    return 0 if ok else 1


def register_cli(sub) -> None:
    p = sub.add_parser(
        "target", help="cross-build for a Cortex-M4F, run in QEMU, compare with the host, report footprint",
        description="Generate the float C of a filter, build it with arm-none-eabi-gcc at -O2 and -Os, run a "
                    "scenario through it on an emulated Cortex-M4F (QEMU mps2-an386), check the outputs against "
                    "the host float build, and report flash, static RAM, worst-case stack and instructions per "
                    "step (table on stdout, JSON file). Exit 1 if target and host disagree beyond the bound.")
    p.add_argument("filter", help="filter name (see 'ahrsgen list'), or 'all'")
    p.add_argument("--config", metavar="FILE.toml", help="TOML config (its precision is ignored: see --precision)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="override one parameter (repeatable)")
    p.add_argument("--prefix", help="C identifier prefix (default: the filter name)")
    p.add_argument("--cpu", choices=sorted(CPUS), default="cortex-m4f", help="target CPU (default cortex-m4f)")
    p.add_argument("--precision", choices=["float", "double"], default="float",
                   help="float (default; the M4F FPU) or double (soft-float: shows what a double build costs, "
                        "compared with the host double build)")
    p.add_argument("--opt", action="append", choices=list(OPT_LEVELS),
                   help="optimisation level (repeatable; default both -O2 and -Os)")
    p.add_argument("--scenario", help="scenario (default: the filter's source experiment, e.g. fixedwing_gps for qcf)")
    p.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    p.add_argument("--scenario-opt", metavar="NAME=VALUE", action="append", default=[],
                   help="scenario option, e.g. duration=30 (repeatable)")
    p.add_argument("--count-steps", type=int, default=50, metavar="N",
                   help="steps also run in unicorn (exact instruction count cross-check); 0 = all; "
                        "default 50. QEMU counts instructions and paints the stack over every step.")
    p.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_DEG, metavar="DEG",
                   help=f"largest allowed target-vs-host attitude difference (default {DEFAULT_TOLERANCE_DEG:g} deg)")
    p.add_argument("--peers", action="store_true",
                   help="also measure the calibration peers (Madgwick, Mahony with integral) for scale")
    p.add_argument("--libm-survey", action="store_true",
                   help="also compare newlib's float sinf/cosf/asinf/atanf/expf/logf/atan2f with the host's, in ulps")
    p.add_argument("--no-pinned", action="store_true",
                   help="skip the pinned-libm identity run (float libm evaluated through double on both sides)")
    p.add_argument("--json", default="build/target/target.json", metavar="FILE",
                   help="where to write the JSON report (default build/target/target.json)")
    p.add_argument("--workdir", metavar="DIR", help="keep build products here (default: a temporary directory)")
    p.set_defaults(func=cmd_target)
