"""Render a filter configuration to C: header, source and manifest.json.

Data flows one way: BuildConfig -> filter Model (symbolic kernels) -> emit (C statements)
-> Jinja2 templates (src/ahrsgen/codegen/templates/ + the filter's step partial) -> files. The output depends
only on the configuration and the generator's version, so regenerating reproduces it byte
for byte (no dates, no paths).
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import jinja2


from ahrsgen.codegen import emit, fastmath, folded
from ahrsgen import paths, status
from ahrsgen.generate.config import BuildConfig
from ahrsgen.codegen.model import KernelSpec
from ahrsgen.errors import ConfigError
from ahrsgen.symbolic import quat

from ahrsgen import __version__ as VERSION  # noqa: E402  (written once, in pyproject.toml)
TEMPLATES = paths.templates_dir()

VALID_BITS = [("GYRO", 0), ("ACCEL", 1), ("MAG", 2), ("GPS", 3)]
INPUT_FIELDS = [
    ("gyro", 3, "real", "angular rate, rad/s, body FRD"),
    ("accel", 3, "real", "specific force, m/s^2, body FRD (level at rest: [0, 0, -9.81])"),
    ("mag", 3, "real", "magnetic field, any unit, body FRD"),
    ("gps_vel_ned", 3, "real", "GPS velocity, m/s, NED"),
    ("valid", 1, "uint32", "VALID_* bits of the samples present this step"),
]


@dataclass
class Generated:
    files: dict[str, str]          # file name -> text
    manifest: dict
    kernels: list[emit.Kernel]


def _ctype(kind: str, real: str) -> str:
    return real if kind == "real" else "uint32_t"


def _decl(name, size, kind, real, scalar=False):
    t = _ctype(kind, real)
    return f"{t} {name};" if (size == 1 and scalar) else f"{t} {name}[{size}];"


def struct_layout(fields, real, params_bytes=0):
    """(offset, size) of each field and the struct size, for the common C ABI.

    kind "params": the runtime-parameter struct (params_bytes, aligned as a real)."""
    sizes = {"real": 4 if real == "float" else 8, "uint32": 4}
    off, align, out = 0, 1, []
    for name, count, kind in fields:
        a = sizes["real" if kind == "params" else kind]
        size = params_bytes if kind == "params" else a * count
        off = (off + a - 1) // a * a
        out.append((name, off, size))
        off += size
        align = max(align, a)
    return out, (off + align - 1) // align * align


# The aiding sensors' input checks (src/ahrsgen/codegen/templates/filter.c.j2), in the order they run: input field,
# the parameters bounding a component and the norm, the prefix of the skip bits, and whether the
# sensor is in the step's one common-path test (sampled every step: accel and mag; GPS comes at
# a few Hz, so its valid bit is usually clear and it is tested on its own).
_AIDING = [
    {"name": "accel", "field": "accel", "max": "ACCEL_MAX", "min": "ACCEL_MIN_NORM", "bit": "ACCEL", "common": True},
    {"name": "mag", "field": "mag", "max": "MAG_MAX", "min": "MAG_MIN_NORM", "bit": "MAG", "common": True},
    {"name": "gps", "field": "gps_vel_ned", "max": "GPS_VEL_MAX", "min": None, "bit": "GPS", "common": False},
]


def _runtime_param(p, value, code, lit) -> dict:
    """A runtime parameter for the templates: default, allowed range and its C check."""
    terms = []
    if p.min is not None:
        terms.append(f"p->{p.name} {'>' if p.min_exclusive else '>='} {lit(p.min)}")
    if p.max is not None:
        terms.append(f"p->{p.name} {'<' if p.max_exclusive else '<='} {lit(p.max)}")
    # a NaN fails every comparison; a range open at both ends still needs a finite value
    check = " && ".join(terms) if terms else f"isfinite(p->{p.name})"
    return {"name": p.name, "default": value, "default_lit": lit(value), "allowed": p.range_text(),
            "check": check, "code": code, "unit": p.unit, "doc": p.doc}


class _Calls:
    """How the templates call a kernel: `{{ call.predict }}s->q, ...)` opens the call of
    <prefix>_k_predict, with the state's params first if the kernel reads runtime parameters
    (Kernel.context; the step, init and helper code call kernels on the state `s`). A plain
    object, not a dict, so that a kernel may be called `update` or `items`."""

    def __init__(self, calls: dict):
        self._calls = calls

    def __getattr__(self, key):
        if key.startswith("__"):
            raise AttributeError(key)
        if key not in self._calls:
            raise ConfigError(f"the C template calls kernel '{key}', which the model does not define "
                              f"(kernels: {', '.join(sorted(self._calls))})")
        return self._calls[key]

    __getitem__ = __getattr__


def _calls(specs, kernels) -> _Calls:
    return _Calls({ks.name: k.name + "(" + ("&s->params, " if k.context else "") for ks, k in zip(specs, kernels)})


class _RuntimeGuard(dict):
    """The parameter values templates see: reading a runtime parameter's value is structural."""

    def __init__(self, values, runtime):
        super().__init__(values)
        self.runtime = set(runtime)

    def __getitem__(self, key):
        if key in self.runtime:
            raise ConfigError(f"parameter '{key}' cannot be a runtime parameter: the filter's C template "
                              f"uses its value to shape the code")
        return super().__getitem__(key)


def _model_parts(spec, params: dict, runtime: tuple, precision: str = "double"):
    """The model's kernels, state fields and template context, with the runtime parameters as
    symbols (ahrsgen.codegen.emit.runtime_symbol) instead of numbers; the kernels' series cut
    for the build's precision (quat.series_precision)."""
    values = dict(params)
    for n in runtime:
        values[n] = emit.runtime_symbol(n)
    with quat.series_precision(precision):
        model = spec.model(values)
        specs = list(model.kernels())
    fields = model.state_fields()
    for f in fields:
        for v in f.init_values():
            if isinstance(v, (ca.SX, ca.SXElem)):
                raise ConfigError(f"state field '{f.name}' starts from a runtime parameter")
    tctx = model.template_context()
    if any(isinstance(v, (ca.SX, ca.SXElem)) for v in tctx.values()):
        raise ConfigError("the step template uses a runtime parameter's value")
    return model, specs, fields, tctx


def _runtime_model(spec, params, runtime, precision: str = "double"):
    """_model_parts, turning a model that needs a runtime parameter's value into one clear line."""
    if not runtime:
        return _model_parts(spec, params, runtime, precision)
    try:
        return _model_parts(spec, params, runtime, precision)
    except Exception as first:
        culprits = []
        for n in runtime:            # name the parameter(s) the model cannot take as symbols
            try:
                _model_parts(spec, params, (n,))
            except Exception:
                culprits.append(n)
        names = ", ".join(f"'{n}'" for n in culprits or runtime)
        why = str(first).splitlines()[0][:120] if isinstance(first, ConfigError) else type(first).__name__
        raise ConfigError(f"parameter {names} of filter {spec.name} cannot be a runtime parameter: the model "
                          f"needs its value to build the code ({why})") from None


@functools.lru_cache(maxsize=16)
def _environment(folder: str) -> jinja2.Environment:
    """One Jinja environment per filter folder: it keeps the compiled templates (compiling
    them took a third of a render; jinja re-reads a template whose file changed)."""
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader([str(TEMPLATES), folder]),
        undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
        keep_trailing_newline=True)


def _folded_names(spec, params: dict, runtime: tuple, specs, fields,
                  precision: str = "double") -> tuple[dict, dict]:
    """{kernel: {(instruction, operand): name}} for the literals of the baked kernels that are
    folded parameters or named constants (src/ahrsgen/codegen/folded.py: the kernels built
    again on traced values; ahrsgen.constants), and {state field: [name or None]} for the
    initial values of the state the same way."""
    floats = [n for n, p in spec.params.items() if p.type == "float" and n not in runtime]
    values, record = folded.traced_params(params, floats)
    for n in runtime:
        values[n] = emit.runtime_symbol(n)
    try:
        with folded.tracing(record), quat.series_precision(precision):
            model = spec.model(values)
            traced = {ks.name: ks.function for ks in model.kernels()}
            traced_fields = {f.name: f.init_values() for f in model.state_fields()}
    except Exception:      # a model that needs plain numbers: its literals stay unnamed
        return {}, {}
    out = {ks.name: folded.constant_names(ks.function, traced[ks.name], record) for ks in specs if ks.name in traced}
    init = {f.name: folded.value_names(f.init_values(), traced_fields[f.name]) for f in fields
            if f.ctype == "real" and len(traced_fields.get(f.name, ())) == f.size}
    return {k: v for k, v in out.items() if v}, init


def render(cfg: BuildConfig, names: bool = True) -> Generated:
    """The files of a build. names=False: folded parameters without their names beside
    them (the same C otherwise; tests/codegen/test_folded.py compares the two)."""
    spec = cfg.spec
    runtime = tuple(getattr(cfg, "runtime", ()) or ())
    model, model_specs, fields, tctx = _runtime_model(spec, cfg.params, runtime, cfg.precision)
    kernel_names, init_names = (_folded_names(spec, cfg.params, runtime, model_specs, fields, cfg.precision)
                                if names else ({}, {}))
    real = cfg.precision
    prefix = cfg.prefix
    P = prefix.upper()
    name_derived = names

    def lit(v, name: str | None = None) -> str:
        """A literal of the build's type; a value derived from parameters carries its
        derivation beside it, as the kernels' folded constants do (`0.29844642f /* ... */`),
        and a named constant (ahrsgen.constants.Const) its name."""
        text = emit.literal(v, real)
        name = name or getattr(v, "name", None)
        return f"{text} /* {name} */" if name and name_derived else text

    # Kernels: the filter's plus the shared Euler output. Runtime parameters are read through
    # a pointer to the state's params member.
    qsym = ca.SX.sym("q", 4)
    specs = model_specs + [KernelSpec(
        "euler", emit.function("euler", {"q": qsym}, {"rpy": quat.euler(qsym)}),
        "Z-Y-X Euler angles [roll, pitch, yaw] of a unit body->NED quaternion")]
    context = (f"const {prefix}_params *par", {emit.RUNTIME_PREFIX + n: f"par->{n}" for n in runtime})
    kernels, kctx = [], []
    for ks in specs:
        k = emit.emit(ks.function, real, name=f"{prefix}_k_{ks.name}",
                      doc=ks.doc + (_in_place_note(ks.in_place) if ks.in_place else
                                    _EARLY_WRITES_NOTE if ks.early_writes else ""), context=context,
                      math=cfg.math, fma=cfg.fma, flags=ks.flags, names=kernel_names.get(ks.name),
                      early_writes=ks.early_writes, in_place=dict(ks.in_place))
        extra = [a.name for a in k.inputs if a.name.startswith(emit.RUNTIME_PREFIX) and a.expr is None]
        if extra:
            raise ConfigError(f"kernel {ks.name}: free symbol(s) {', '.join(extra)} are not runtime parameters")
        kernels.append(k)
        k.storage = _storage(ks, k)
        kctx.append({"name": ks.name, "code": k.source()})
    by_name = {ks.name: k for ks, k in zip(specs, kernels)}
    fast_helpers = sorted({h for k in kernels for h in k.helpers}
                          | (set(model.template_helpers()) if real == "float" and cfg.math == "fast" else set()))

    # Parameters as macros (numbers and booleans) or comments (strings).
    params = []
    for name, p in spec.params.items():
        v = cfg.params[name]
        if name in runtime:
            macro = None
        elif p.type == "bool":
            macro = "1" if v else "0"
        elif p.type == "int":
            macro = f"{v}"
        elif p.type == "float":
            macro = lit(v)
        else:
            macro = None
        shown = f"runtime ({prefix}_params.{name}), default {v!r}:" if name in runtime else v
        params.append({"name": name, "macro": macro, "value": shown,
                       "doc": p.doc, "unit": p.unit, "len": len(name) + len(macro or str(v)),
                       "runtime": name in runtime})
    width = max((x["len"] for x in params if not x["runtime"]), default=0)
    for x in params:
        x["pad"] = 0 if x["runtime"] else width - x["len"]

    bits = [(n, v, d) for n, v, d in status.COMMON]
    bits += [(n, v, d) for n, v, d, _ in status.extra_bits(model.extra_status)]
    fault_mask = status.fault_mask(model.extra_status)
    refused = {n for n, v, _ in bits if v & status.REFUSED_MASK}
    swidth = max(len(n) for n, _, _ in bits)
    status_ctx = [{"name": n, "value": "0u" if v == 0 else f"(1u << {v.bit_length() - 1})", "doc": d,
                   "refused": n in refused, "fault": bool(v & fault_mask), "pad": swidth - len(n)}
                  for n, v, d in bits]

    names = [f.name for f in fields]
    if "q" not in names:
        raise ValueError(f"filter {spec.name}: the state must have a field 'q' (body->NED quaternion)")
    state_ctx = []
    decls = [_decl(f.name, f.size, f.ctype, real, scalar=(f.size == 1)) for f in fields]
    dw = max(len(d) for d in decls)
    for f, d in zip(fields, decls):
        vals = f.init_values()
        known = init_names.get(f.name) or [None] * len(vals)     # the names of the initial values
        fmt = (lambda x, n=None: lit(x, n)) if f.ctype == "real" else (lambda x, n=None: f"{int(x)}u")
        fill = None
        if f.size > 4 and len(set(vals)) == 1:
            fill = fmt(vals[0], known[0] if len(set(known)) == 1 else None)
        state_ctx.append({"name": f.name, "size": f.size, "decl": d, "doc": f.doc, "pad": dw - len(d),
                          "init": [fmt(x, n) for x, n in zip(vals, known)], "fill": fill, "scalar": f.size == 1})
    in_decls = [_decl(n, s, k, real, scalar=(s == 1)) for n, s, k, _ in INPUT_FIELDS]
    iw = max(len(d) for d in in_decls)
    input_ctx = [{"decl": d, "doc": doc, "pad": iw - len(d)} for d, (_, _, _, doc) in zip(in_decls, INPUT_FIELDS)]
    runtime_ctx = [_runtime_param(spec.params[n], cfg.params[n], i + 1, lit) for i, n in enumerate(runtime)]
    params_layout, params_bytes = struct_layout([(n, 1, "real") for n in runtime], real)
    state_members = [(f.name, f.size, f.ctype) for f in fields] + ([("params", 1, "params")] if runtime else [])
    layout, state_bytes = struct_layout(state_members, real, params_bytes)
    in_layout, input_bytes = struct_layout([(n, s, k) for n, s, k, _ in INPUT_FIELDS], real)

    # The configuration this file was generated from: every value that differs from the
    # filter's defaults, the build options, and the command that reproduces it.
    defaults = spec.defaults()

    def _arg(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        s = repr(v) if isinstance(v, float) else str(v)
        return f"'{s}'" if (" " in s or not s) else s
    changed = [(n, cfg.params[n]) for n in spec.params if cfg.params[n] != defaults.get(n)]
    options = [("precision", real, "float"), ("prefix", prefix, spec.name),
               ("math", cfg.math if real == "float" else "libm", fastmath.DEFAULT_MATH if real == "float" else "libm"),
               ("fma", cfg.fma, False)] + ([("runtime", ",".join(cfg.runtime), "")] if cfg.runtime else [])
    # a folder filter by its folder (a name alone resolves only for the built-ins)
    target = spec.name if spec.origin == "built-in" else _arg(str(spec.folder))
    command = " ".join(["ahrsgen generate", target] + [f"--set {n}={_arg(v)}" for n, v in changed]
                       + [f"--{n}" if isinstance(v, bool) else f"--{n} {v}" for n, v, d in options if v != d]
                       + ["-o DIR"])
    config_record = {"changed": [f"{n} = {_arg(v)}" for n, v in changed],
                     "options": [f"{n} = {_arg(v)}" for n, v, _ in options], "command": command}

    env = _environment(str(spec.folder))
    ctx = dict(
        version=VERSION, filter=spec.name, title=spec.title,
        # where the filter came from, without machine paths (the output is reproducible anywhere)
        filter_folder=f"ahrsgen/filters/{spec.name}/" if spec.origin == "built-in" else f"filter folder {spec.name}/",
        source=_wrap_doc("Source: " + spec.source, prefix),
        init_doc=_wrap_doc("Initialisation: " + (spec.init or "{prefix}_init sets the start state."), prefix),
        prefix=prefix, P=P,
        # how the header names the largest dt: a macro, or the runtime parameter that replaces it
        dt_max_name=f"{prefix}_params.dt_max" if "dt_max" in runtime else f"{P}_DT_MAX",
        real=real, F="f" if real == "float" else "", zero=lit(0.0), one=lit(1.0), lit=lit,
        uint="uint32_t" if real == "float" else "uint64_t",
        aiding=[a for a in _AIDING if a["name"] in model.sensors],
        # the full input checks run out of the step's line: they need the state for a runtime bound
        checks_read_state=any(n in runtime for a in _AIDING if a["common"] and a["name"] in model.sensors
                              for n in (a["max"].lower(), a["min"].lower())) or "gyro_max" in runtime,
        params=params, valid_bits=VALID_BITS, status=status_ctx, state=state_ctx, input=input_ctx,
        kernels=kctx, sensors=model.sensors, state_bytes=state_bytes, runtime=runtime_ctx,
        aliasing_exceptions=_aliasing_exceptions([k.name for ks, k in zip(specs, kernels) if ks.early_writes
                                                  and not ks.in_place], prefix,
                                                 [(k.name, ks.in_place) for ks, k in zip(specs, kernels) if ks.in_place]),
        math=cfg.math if real == "float" else "libm", fastmath_code=fastmath.c_source(fast_helpers, prefix),
        fastmath_end=fastmath.c_source_end(fast_helpers),
        config_record=config_record,
        step_partial="step.c.j2",
        init_partial="init.c.j2" if (spec.folder / "init.c.j2").exists() else None,
        helpers_partial="helpers.c.j2" if (spec.folder / "helpers.c.j2").exists() else None,
        input_transform=_input_transform(getattr(cfg, "frame", None), model.sensors, lit, real),
        noinline=NOINLINE, call=_calls(specs, kernels),
        # lines within 100 columns (ahrsgen.codegen.emit.ir's printer)
        cline=emit.ir.with_comment, cdefine=emit.ir.define, ccomment=lambda t: "\n".join(emit.ir.comment(t)),
        title_line=lambda name: _wrap_doc(f"{name} - {spec.title}", prefix, 96),
        status_refused=[f"{P}_{s['name']}" for s in status_ctx if s["refused"]],
        status_faults=[f"{P}_{s['name']}" for s in status_ctx if s["fault"]],
        status_info=", ".join(s["name"] for s in status_ctx if not s["fault"] and s["value"] != "0u") or "none here",
        cfg=_RuntimeGuard(cfg.params, runtime), **tctx)
    header = env.get_template("filter.h.j2").render(ctx)
    source = env.get_template("filter.c.j2").render(ctx)

    paths = {}
    for pname, knames in model.op_paths().items():
        total = {c: 0 for c in emit.CATEGORIES}
        for kn in knames:
            for c, n in by_name[kn].ops.items():
                total[c] += n
        paths[pname] = {"kernels": knames, "ops": total, "total": sum(total.values())}

    manifest = {
        "generator": f"ahrsgen {VERSION}",
        "filter": spec.name,
        "title": spec.title,
        "prefix": prefix,
        "precision": real,
        "math": cfg.math if real == "float" else "libm",
        "fma": cfg.fma,
        "files": {"header": f"{prefix}.h", "source": f"{prefix}.c"},
        "params": {n: cfg.params[n] for n in spec.params},
        **({"sensor_frame": cfg.frame.record()} if getattr(cfg, "frame", None) is not None else {}),
        **({"runtime_params": [{"name": r["name"], "default": r["default"], "allowed": r["allowed"],
                                "code": r["code"], "unit": r["unit"], "doc": r["doc"]} for r in runtime_ctx]}
           if runtime else {}),
        "status": {n: v for n, v, _ in bits},
        "status_fault_mask": fault_mask,
        "refused_mask": sum(v for n, v, _ in bits if n in refused),
        "valid_bits": {n: 1 << b for n, b in VALID_BITS},
        "structs": {
            "state": {"size": state_bytes, "fields": [
                {"name": f.name, "type": f.ctype, "count": f.size, "offset": off, "doc": f.doc}
                for f, (_, off, _) in zip(fields, layout)]
                + ([{"name": "params", "type": "params", "count": 1, "offset": layout[-1][1], "size": params_bytes,
                     "doc": f"runtime parameters ({prefix}_params)"}] if runtime else [])},
            **({"params": {"size": params_bytes, "fields": [
                {"name": n, "type": "real", "count": 1, "offset": off, "doc": spec.params[n].doc}
                for n, off, _ in params_layout]}} if runtime else {}),
            "input": {"size": input_bytes, "fields": [
                {"name": n, "type": k, "count": s, "offset": off, "doc": doc}
                for (n, s, k, doc), (_, off, _) in zip(INPUT_FIELDS, in_layout)]},
        },
        "kernels": {ks.name: {"c_name": k.name, "ops": k.ops, "total": k.ops_total,
                              "temporaries": k.n_temporaries, "doc": ks.doc,
                              **({"branches": k.branches} if k.branches else {})}
                    for ks, k in zip(specs, kernels)},
        "step_paths": paths,
    }
    files = {f"{prefix}.h": ascii_text(header), f"{prefix}.c": ascii_text(source),
             "manifest.json": json.dumps(manifest, indent=2, sort_keys=False) + "\n"}
    return Generated(files, manifest, kernels)


def _input_transform(frame, sensors, lit, real) -> list[str]:
    """C statements taking the raw sample (in_raw) to the body frame (in_body), body = M (raw - c)
    per sensor (ahrsgen.sensor_frame), folded: zero coefficients dropped, +-1 as a sign, rows
    that are the raw value left as copied. Empty when the config has no [calibration] /
    [mounting] table (the step then reads `in` itself)."""
    if frame is None:
        return []
    out = []
    for s in ("gyro", "accel", "mag"):
        if (s != "gyro" and s not in sensors) or not frame.changes(s):
            continue
        M, c = frame.affine(s)
        src = []
        for j in range(3):
            if c[j]:
                out.append(f"const {real} {s}_{j} = in_raw->{s}[{j}] {'-' if c[j] > 0 else '+'} {lit(abs(float(c[j])))};")
                src.append(f"{s}_{j}")
            else:
                src.append(f"in_raw->{s}[{j}]")
        for i in range(3):
            if not c[i] and all(float(M[i, j]) == (1.0 if j == i else 0.0) for j in range(3)):
                continue
            terms = [(float(M[i, j]), src[j]) for j in range(3) if float(M[i, j]) != 0.0]
            text = " ".join(("-" if m < 0 else "+") + " " + (v if abs(m) == 1.0 else f"{lit(abs(m))} * {v}")
                            for m, v in terms)
            text = text[2:] if text.startswith("+ ") else "-" + text[2:]
            out.append(f"in_body.{s}[{i}] = {text};")
    return out


# A kernel the model marks noinline: GCC and clang keep it a call (its frame then does not add to
# its caller's when the caller calls several large kernels once each); other compilers ignore it.
NOINLINE = "#if defined(__GNUC__)\n__attribute__((noinline))\n#endif\n"


# The caller's rule for a kernel that stores its outputs as soon as computed (KernelSpec.early_writes).
_EARLY_WRITES_NOTE = "; outputs are stored as soon as computed (arrays restrict): no argument may overlap an output"


def _may_be(pairs) -> str:
    """'P_out may be P itself, ...': the in-place pairs of a kernel (KernelSpec.in_place) in words."""
    return ", ".join(f"{o} may be {i} itself" for o, i in pairs)


def _in_place_note(pairs) -> str:
    """The doc note of a kernel storing its outputs early with in-place pairs (KernelSpec.in_place)."""
    return f"; outputs are stored as soon as computed, each after the last read of what it overwrites: " \
           f"{_may_be(pairs)}, no other argument may overlap an output"


def _aliasing_exceptions(names: list[str], prefix: str, in_place=()) -> str:
    """The header's paragraph naming the kernels the aliasing rule does not cover
    (KernelSpec.early_writes, KernelSpec.in_place); empty when there are none."""
    text = []
    if names:
        listed = names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
        text.append(f"Exceptions: {listed} store each output as soon as it is computed and declare "
                    f"their arrays restrict: no argument of theirs may overlap one of their outputs.")
    for name, pairs in in_place:
        text.append(f"{'Also' if text else 'Exception'}: {name} stores each output as soon as it is computed, "
                    f"after the last read of the input element it may overwrite: {_may_be(pairs)}; no other "
                    "argument may overlap an output.")
    return _wrap_doc(" ".join(text), prefix) if text else ""


def _storage(ks, k) -> str:
    if ks.noinline:
        return NOINLINE + "static "
    return "static inline " if k.n_temporaries <= emit.INLINE_TEMPS else "static "


# Generated C is ASCII only (a reviewer's rule: some toolchains and diff tools still choke on
# anything else). Documentation strings of filters may use math notation; it is spelled out.
_ASCII = {
    "°": " deg", "±": "+-", "²": "^2", "¹": "^1", "³": "^3", "¼": "1/4", "½": "1/2", "×": "x",
    "Σ": "Sum", "Ω": "Omega", "β": "beta", "δ": "delta", "ε": "eps", "θ": "theta", "σ": "sigma",
    "τ": "tau", "φ": "phi", "ψ": "psi", "ω": "omega", "ᵀ": "^T", "⁺": "+", "⁻": "-", "₀": "0",
    "₁": "1", "₂": "2", "₃": "3", "₄": "4", "←": "<-", "→": "->", "∂": "d", "−": "-", "√": "sqrt",
    "∝": "~", "≡": "==", "⊗": "(x)", "⟨": "<", "⟩": ">", "≤": "<=", "≥": ">=", "≈": "~=",
    "–": "-", "—": "-", "‘": "'", "’": "'", "“": '"', "”": '"', "…": "...", "·": "*", "γ": "gamma",
    "α": "alpha", "λ": "lambda", "μ": "mu", "π": "pi", "Δ": "Delta", "Φ": "Phi", "∞": "inf",
}


def ascii_text(text: str) -> str:
    """`text` with every non-ASCII character spelled in ASCII: the table above, else the
    base letter of an accented one (u for u-umlaut, q_hat for q-circumflex), else its
    Unicode name in brackets."""
    import unicodedata
    if text.isascii():
        return text
    out = []
    for ch in text:
        if ch.isascii():
            out.append(ch)
        elif ch in _ASCII:
            out.append(_ASCII[ch])
        else:
            for c in unicodedata.normalize("NFKD", ch):
                if c.isascii() or c in _ASCII:
                    out.append(_ASCII.get(c, c))
                elif c == "\u0302":                  # combining circumflex: an estimate
                    out.append("_hat")
                elif unicodedata.category(c) != "Mn":  # other accents go, letters stay named
                    out.append(f"<{unicodedata.name(c, hex(ord(c)))}>")
    return "".join(out)


def _wrap_doc(text: str, prefix: str, width: int = 92) -> str:
    """A paragraph for the header comment: {prefix} filled in, wrapped, continuation lines ' * '."""
    import textwrap
    lines = textwrap.wrap(text.replace("{prefix}", prefix), width)
    return "\n * ".join(lines)


def write(gen: Generated, out_dir: str | Path) -> list[Path]:
    """Write the files into out_dir, each atomically (a crash never leaves half a file). A folder
    holds one generated filter: manifest.json of another prefix there is refused, not overwritten."""
    import json
    from ahrsgen.fileio import write_text_atomic
    out = Path(out_dir)
    old = out / "manifest.json"
    if old.is_file():
        try:
            other = json.loads(old.read_text()).get("prefix")
        except (ValueError, UnicodeDecodeError):
            other = None
        if other is not None and other != gen.manifest["prefix"]:
            raise ConfigError(f"{out} already holds the generated filter '{other}' (its manifest.json would be "
                              f"overwritten): generate '{gen.manifest['prefix']}' into its own folder")
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in gen.files.items():
        written.append(write_text_atomic(out / name, text))
    return written
