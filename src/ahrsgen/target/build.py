"""Building for the target: toolchain, flags, binding a filter to the harness, cross build."""
from __future__ import annotations

from ahrsgen.errors import ToolchainMissing  # noqa: F401  (raised here; callers import it from here too)
import json
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

TARGET_DIR = Path(__file__).resolve().parent   # the bare-metal C files live beside the package
PINNED_LIBM_H = TARGET_DIR / "libm_pinned.h"

CPUS = {
    "cortex-m4f": ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"],
}
OPT_LEVELS = ("-O2", "-Os")
DEBUG_OPT = "-O0"           # built for its stack only: a debug build must fit an RTOS task too
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

# Record layout shared with src/ahrsgen/target/ahrs_record.h (56 bytes, little-endian).
RECORD_DTYPE = np.dtype([
    ("gyro", "<f4", (3,)), ("accel", "<f4", (3,)), ("mag", "<f4", (3,)),
    ("gps_vel", "<f4", (3,)), ("valid", "<u4"), ("dt", "<f4"),
])
assert RECORD_DTYPE.itemsize == 56


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
    # Someone else's code (studies/cycles_vs_peers.py: Fusion, BasicVQF) keeps its own warnings:
    # these flags replace WARN_FLAGS for the filter's own C sources (None: the strict set); its
    # C++ sources (.cpp) compile with arm-none-eabi-g++ and cxx_flags instead. CPU, optimisation,
    # MATH_FLAGS and SECTION_FLAGS apply to both; the glue and the harness stay strict.
    own_cflags: list[str] | None = None
    cxx_flags: list[str] = field(default_factory=lambda: ["-std=c++17", "-fno-exceptions", "-fno-rtti"])

    @property
    def init_fn(self) -> str:
        return f"{self.prefix}_init"

    @property
    def step_fn(self) -> str:
        return f"{self.prefix}_step"


def toy_binding() -> FilterBinding:
    """The toolchain bring-up filter in src/ahrsgen/target/toy.c (float; uses libm)."""
    return FilterBinding(
        name="toy", prefix="toy", sources=[TARGET_DIR / "toy.c"], include_dirs=[TARGET_DIR],
        header="toy.h", state_type="toy_state", input_type="toy_input",
        input_fields={"gyro": "gyro", "accel": "accel", "mag": "mag",
                      "gps_vel": "gps_vel_ned", "valid": "valid"},
        state_size=24, state_fields={"q": (0, 4), "tilt": (16, 2)},
    )


PEERS_DIR = TARGET_DIR / "peers"
PEER_NAMES = ("madgwick", "mahony")
# The like-for-like peers: the same updates behind the product's input checks (peers/checks.h),
# doing what the example filters built with initialise = false do (same status bits).
CHECKED_PEER_NAMES = ("madgwick_checked", "mahony_checked")


def peer_binding(name: str) -> FilterBinding:
    """Calibration peers (src/ahrsgen/target/peers): Madgwick's and Mahony's 9-axis updates,
    written from their papers, to put the instruction counts next to known figures; and their
    like-for-like variants with the product's input checks (CHECKED_PEER_NAMES)."""
    if name not in PEER_NAMES + CHECKED_PEER_NAMES:
        raise ValueError(f"unknown peer {name!r}; known: {', '.join(PEER_NAMES + CHECKED_PEER_NAMES)}")
    base = name.removesuffix("_checked")
    fields = {"madgwick": {"q": (0, 4)}, "mahony": {"q": (0, 4), "integral": (16, 3)}}[base]
    return FilterBinding(
        name=f"peer:{name}", prefix=name, sources=[PEERS_DIR / f"{name}.c"], include_dirs=[PEERS_DIR],
        header="peers.h", state_type=f"{name}_state", input_type=f"{name}_input",
        input_fields={"gyro": "gyro", "accel": "accel", "mag": "mag", "gps_vel": "gps_vel_ned", "valid": "valid"},
        state_size=16 if base == "madgwick" else 28, state_fields=fields,
    )


def write_glue(b: FilterBinding, out_dir: Path) -> None:
    """filter_glue.h / filter_glue.c: the harness's only filter-specific code.

    The glue functions are out of line (own translation unit, no LTO) so that the
    emulator can call them and count the filter's own step from its entry to its return.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "filter_glue.h").write_text(
        "/* generated by src/ahrsgen/target/build.py: binds the harness to one filter */\n"
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
        "/* generated by src/ahrsgen/target/build.py */\n"
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
    extra_cflags: tuple[str, ...] = ()   # the user's own flags (in cflags too, last)


def cflags_for(cpu: str, opt: str) -> list[str]:
    if cpu not in CPUS:
        raise ValueError(f"unknown cpu {cpu!r}; known: {', '.join(CPUS)}")
    if opt not in (*OPT_LEVELS, DEBUG_OPT):
        raise ValueError(f"unknown optimisation {opt!r}; known: {', '.join(OPT_LEVELS)}")
    return [*CPUS[cpu], opt, *MATH_FLAGS, *WARN_FLAGS, *SECTION_FLAGS]


def build(b: FilterBinding, workdir: Path, opt: str = "-O2", cpu: str = "cortex-m4f",
          extra_main: str | None = None, pinned_libm: bool = False, reuse: Build | None = None,
          debug_info: bool = False, extra_cflags: tuple[str, ...] = ()) -> Build:
    """Compile the filter and the harness for the target and link the test image.

    The filter's sources compile with the same strict warnings as on the host (-Werror).
    ``extra_main`` replaces harness_main.c (used for the footprint images).
    ``pinned_libm`` force-includes target/libm_pinned.h into the filter (identity check only).
    ``reuse``: link the filter objects of an earlier build instead of compiling them again.
    ``debug_info``: also -g (line information for the profile; GCC's code is the same).
    ``extra_cflags``: a user's own compiler flags, after ours (``ahrsgen target --cflags``).
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    write_glue(b, workdir)
    flags = cflags_for(cpu, opt) + (["-g"] if debug_info else []) + list(extra_cflags)
    incs = [f"-I{workdir}", f"-I{TARGET_DIR}", *[f"-I{d}" for d in b.include_dirs]]
    objs, filt_objs, sus = [], [], []
    for src in ([] if reuse is not None else b.sources):
        obj = workdir / (Path(src).stem + ".o")
        pin = ["-include", str(PINNED_LIBM_H)] if pinned_libm else []
        cc, own = "arm-none-eabi-gcc", flags
        if Path(src).suffix in (".cpp", ".cc"):
            cc, own = "arm-none-eabi-g++", [f for f in flags if f not in WARN_FLAGS] + b.cxx_flags
        elif b.own_cflags is not None:
            own = [f for f in flags if f not in WARN_FLAGS] + b.own_cflags
        _run([cc, *own, *incs, *pin, "-fstack-usage", "-c", str(src), "-o", str(obj)], cwd=workdir)
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
    return Build(b.name, opt, cpu, workdir, elf, filt_objs, sus, flags, tuple(extra_cflags))



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
             precision: str = "float", math: str | None = None, fma: bool | None = None) -> Path:
    """Render a filter configuration into out_dir (float unless asked: the M4F FPU is
    single precision, a double build runs on soft-float helpers)."""
    from ahrsgen.generate import config, render
    cfg = config.resolve(filter_name, config_file, sets, precision=precision, prefix=prefix, math=math, fma=fma)
    render.write(render.render(cfg), out_dir)
    return Path(out_dir)
