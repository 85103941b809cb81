"""Build configurations: a filter's defaults, a TOML file, and --set overrides, validated.

A config file:

    filter = "qcf"            # optional; must match the filter being generated
    preset = "faithful"       # optional: start from a named preset of the filter
    prefix = "att"            # C identifier prefix (default: the filter's name)
    precision = "float"       # or "double"
    runtime = ["kp"]          # parameters read at run time (set_params), not folded in
    math = "fast"             # or "libm": float trigonometry without libm (src/ahrsgen/codegen/fastmath.py)
    fma = false               # true: the emitter writes fmaf(a, b, c) for a product feeding one sum
    [params]
    kp = 1.5

Every problem is a ConfigError whose message names the file, the parameter and what is
allowed; the CLI prints it on one line and exits with status 2.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ahrsgen.codegen import fastmath
from ahrsgen import filters
from ahrsgen.errors import ConfigError
from ahrsgen import sensor_frame
from ahrsgen.sensor_frame import SensorFrame

PRECISIONS = ("float", "double")
TOP_KEYS = {"filter", "prefix", "precision", "params", "preset", "runtime", "math", "fma", "calibration", "mounting"}


@dataclass
class BuildConfig:
    filter: str
    params: dict
    precision: str = "float"
    prefix: str = ""
    overrides: dict = field(default_factory=dict)   # what differs from the defaults
    runtime: tuple = ()       # parameters read at run time from <prefix>_params, in this order
    math: str = fastmath.DEFAULT_MATH                # float trigonometry: "fast" helpers or "libm"
    fma: bool = False                                # emitter-written fused multiply-adds
    frame: SensorFrame | None = None                 # [calibration] / [mounting]: raw sample -> body

    @property
    def spec(self):
        return filters.load(self.filter)


# The prefix names the files (<prefix>.h) and every identifier: it must not be a C keyword, nor
# shadow a standard header the generated code or the user's build includes (#include "math.h"
# would pick ours up before <math.h> wherever the folder is on the include path).
C_KEYWORDS = frozenset("""auto break case char const continue default do double else enum extern float for goto
    if inline int long register restrict return short signed sizeof static struct switch typedef union
    unsigned void volatile while""".split())
STANDARD_HEADERS = frozenset("""assert complex ctype errno fenv float inttypes iso646 limits locale math setjmp signal
    stdalign stdarg stdatomic stdbool stddef stdint stdio stdlib stdnoreturn string tgmath threads time uchar
    wchar wctype unistd strings fcntl malloc alloca memory endian""".split())


# Longest prefix: its longest macro (<PREFIX>_STATUS_FAULT_MASK and the like, ~25 more
# characters) stays within C99's 63 significant characters of an internal identifier, and the
# file names within any file system's 255.
PREFIX_MAX = 32


def _check_prefix(prefix: str) -> str:
    if prefix == "":
        raise ConfigError("prefix is empty: give a lower-case C identifier, or leave --prefix out for the filter's name")
    if len(prefix) > PREFIX_MAX:
        raise ConfigError(f"prefix {prefix[:20]!r}... is {len(prefix)} characters long; at most {PREFIX_MAX}")
    if not prefix.isidentifier() or not prefix.isascii() or prefix.lower() != prefix:
        raise ConfigError(f"prefix {prefix!r} must be a lower-case C identifier (letters, digits, _)")
    if prefix.startswith("_"):
        raise ConfigError(f"prefix {prefix!r}: identifiers starting with '_' are reserved in C")
    if prefix in C_KEYWORDS:
        raise ConfigError(f"prefix {prefix!r} is a C keyword")
    if prefix in STANDARD_HEADERS:
        raise ConfigError(f"prefix {prefix!r} would write {prefix}.h, which shadows the standard header "
                          f"<{prefix}.h>; choose another prefix")
    return prefix


def resolve(filter_name: str, config_file: str | Path | None = None, sets: list[str] | None = None,
            precision: str | None = None, prefix: str | None = None, preset: str | None = None,
            runtime: list[str] | str | None = None, math: str | None = None,
            fma: bool | None = None, values: dict | None = None) -> BuildConfig:
    """Defaults, then a preset, then the config file's [params], then `values` (typed, e.g. a
    log's site parameters), then --set (last wins).
    `filter_name` is a name or a filter folder's path (ahrsgen.filters); the config keeps the name.

    runtime (--runtime, else the file's `runtime`): parameters kept out of the folding.

    math, fma (--math, --fma, else the file's): float trigonometry and fused multiply-adds."""
    spec = filters.load(filter_name)
    filter_name = spec.name
    given, values = values or {}, spec.defaults()
    overrides = {}
    file_prefix = file_precision = file_math = file_fma = None
    file_data = _read_config(config_file) if config_file is not None else {}
    preset = preset or file_data.get("preset")
    if preset is not None:
        presets = spec.presets()
        if preset not in presets:
            raise ConfigError(f"unknown preset '{preset}' for filter {filter_name} "
                              f"(known: {', '.join(presets) or 'none'})")
        data = _read_config(presets[preset])
        for name, value in data.get("params", {}).items():
            values[name] = overrides[name] = _check(spec, name, value, f"preset {preset}")
    if config_file is not None:
        path = Path(config_file)
        data = file_data
        unknown = set(data) - TOP_KEYS
        if unknown:
            raise ConfigError(f"{path}: unknown key(s) {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(TOP_KEYS))}")
        if "filter" in data:
            ref = config_filter_ref(path, data["filter"])
            if (filters.load(ref).name if filters.is_path(ref) else ref) != filter_name:
                raise ConfigError(f"{path}: written for filter '{data['filter']}', not '{filter_name}'")
        file_prefix, file_precision, file_math = data.get("prefix"), data.get("precision"), data.get("math")
        file_fma = data.get("fma")
        if file_fma is not None and not isinstance(file_fma, bool):
            raise ConfigError(f"{path}: fma must be true or false, got {file_fma!r}")
        table = data.get("params", {})
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: 'params' must be a table ([params])")
        for name, value in table.items():
            values[name] = overrides[name] = _check(spec, name, value, str(path))
    for name, value in given.items():
        values[name] = overrides[name] = _check(spec, name, value, "site")
    for item in sets or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected name=value")
        name, text = item.split("=", 1)
        name = name.strip()
        values[name] = overrides[name] = _check(spec, name, text.strip(), "--set")
    precision = precision or file_precision or "float"
    if precision not in PRECISIONS:
        raise ConfigError(f"precision {precision!r} must be one of {', '.join(PRECISIONS)}")
    if not (prefix or file_prefix) and not (filter_name.isidentifier() and filter_name.isascii()
                                            and filter_name.lower() == filter_name):
        raise ConfigError(f"filter '{filter_name}': its name is not a lower-case C identifier, so it cannot be "
                          f"the C prefix; give one with --prefix (or rename the folder)")
    prefix = _check_prefix(prefix if prefix is not None else file_prefix if file_prefix is not None else filter_name)
    if runtime is None:
        runtime, source = file_data.get("runtime", []), str(config_file)
        if not isinstance(runtime, list) or not all(isinstance(x, str) for x in runtime):
            raise ConfigError(f"{config_file}: 'runtime' must be a list of parameter names")
    else:
        source = "--runtime"
        if isinstance(runtime, str):
            runtime = [x.strip() for x in runtime.split(",") if x.strip()]
    math = math or file_math or fastmath.DEFAULT_MATH
    if math not in fastmath.MATH_MODES:
        raise ConfigError(f"math {math!r} must be one of {', '.join(fastmath.MATH_MODES)}")
    fma = bool(fma if fma is not None else (file_fma or False))
    frame = sensor_frame.from_config(file_data, str(config_file)) if config_file is not None else None
    return BuildConfig(filter_name, values, precision, prefix, overrides,
                       check_runtime(spec, list(runtime), source), math=math, fma=fma, frame=frame)


def check_runtime(spec, names: list[str], source: str = "--runtime") -> tuple:
    """Names of runtime parameters, each known, once, and a number the equations take as it is.

    Only real-valued parameters can be read at run time: a choice, a boolean or an integer
    (n_particles) selects or sizes code, which is structural. A real parameter the model
    needs while building the code is refused when the code is generated (render)."""
    out = []
    for n in names:
        if n not in spec.params:
            raise ConfigError(f"runtime parameter '{n}' ({source}) is not a parameter of filter {spec.name}; "
                              f"known: {', '.join(sorted(spec.params))}")
        if n in out:
            raise ConfigError(f"runtime parameter '{n}' ({source}) is listed twice")
        p = spec.params[n]
        if p.type != "float":
            kind = "a choice" if p.choices else {"bool": "a boolean", "int": "an integer", "str": "text"}[p.type]
            raise ConfigError(f"parameter '{n}' ({source}) is {kind}: it shapes the generated code, so it "
                              f"cannot be a runtime parameter (only real-valued ones can)")
        out.append(n)
    return tuple(out)


def _read_config(path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a directory") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: malformed TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text (byte {e.start}); TOML files are UTF-8") from None
    except PermissionError:
        raise ConfigError(f"config file {path} is not readable") from None


def config_filter_ref(config_file, ref):
    """A config's `filter = "..."`: a built-in name as it is; a folder path relative to the
    config file's own folder (not to wherever the command runs)."""
    if isinstance(ref, str) and filters.is_path(ref) and not Path(ref).is_absolute():
        return str(Path(config_file).parent / ref)
    return ref


def filter_of(config_file) -> str:
    """The filter a config file names (filter = "..."), for commands given no filter name. A
    folder it names is code that will run: say so, in one line on stderr."""
    import sys
    if config_file is None:
        raise ConfigError("name a filter (see 'ahrsgen list'), or give a --config file that names one")
    name = _read_config(config_file).get("filter")
    if not isinstance(name, str):
        raise ConfigError(f"{config_file}: no 'filter = \"...\"' line; name the filter on the command line")
    name = config_filter_ref(config_file, name)
    if filters.is_path(name):
        print(f"ahrsgen: note: {config_file} brings in the filter folder {Path(name).resolve()}: its model.py "
              f"and reference.py run as Python", file=sys.stderr)
    return name


def _check(spec, name, value, source):
    if name not in spec.params:
        raise ConfigError(f"unknown parameter '{name}' for filter {spec.name} ({source}); "
                          f"known: {', '.join(sorted(spec.params))}")
    return spec.params[name].coerce(value, source)
