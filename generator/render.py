"""Render a filter configuration to C: header, source and manifest.json.

Data flows one way: BuildConfig -> filter Model (symbolic kernels) -> emit (C statements)
-> Jinja2 templates (templates/ + the filter's step partial) -> files. The output depends
only on the configuration and the generator's version, so regenerating reproduces it byte
for byte (no dates, no paths).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import jinja2


from generator import emit, paths, status
from generator.config import BuildConfig
from generator.model import KernelSpec
from generator.symbolic import quat

VERSION = "0.1.0"
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


def struct_layout(fields, real):
    """(offset, size) of each field and the struct size, for the common C ABI."""
    sizes = {"real": 4 if real == "float" else 8, "uint32": 4}
    off, align, out = 0, 1, []
    for name, count, kind in fields:
        a = sizes[kind]
        off = (off + a - 1) // a * a
        out.append((name, off, a * count))
        off += a * count
        align = max(align, a)
    return out, (off + align - 1) // align * align


def render(cfg: BuildConfig) -> Generated:
    spec = cfg.spec
    model = spec.model(cfg.params)
    real = cfg.precision
    prefix = cfg.prefix
    P = prefix.upper()
    lit = lambda v: emit.literal(v, real)  # noqa: E731

    # Kernels: the filter's plus the shared Euler output.
    qsym = ca.SX.sym("q", 4)
    specs = list(model.kernels()) + [KernelSpec(
        "euler", emit.function("euler", {"q": qsym}, {"rpy": quat.euler(qsym)}),
        "Z-Y-X Euler angles [roll, pitch, yaw] of a unit body->NED quaternion")]
    kernels, kctx = [], []
    for ks in specs:
        k = emit.emit(ks.function, real, name=f"{prefix}_k_{ks.name}", doc="")
        kernels.append(k)
        kctx.append({"name": ks.name, "doc": ks.doc, "code": k.source(storage="static "),
                     "ops_text": ", ".join(f"{n} {c}" for n, c in k.ops.items() if c) + f" (total {k.ops_total})"})
    by_name = {ks.name: k for ks, k in zip(specs, kernels)}

    # Parameters as macros (numbers and booleans) or comments (strings).
    params = []
    for name, p in spec.params.items():
        v = cfg.params[name]
        if p.type == "bool":
            macro = "1" if v else "0"
        elif p.type == "int":
            macro = f"{v}"
        elif p.type == "float":
            macro = lit(v)
        else:
            macro = None
        params.append({"name": name, "macro": macro, "value": v, "doc": p.doc, "unit": p.unit,
                       "len": len(name) + len(macro or str(v))})
    width = max(x["len"] for x in params)
    for x in params:
        x["pad"] = width - x["len"]

    bits = [(n, v, d) for n, v, d in status.COMMON]
    for i, (n, d) in enumerate(model.extra_status):
        bits.append((n, status.FILTER_BASE << i, d))
    refused = {n for n, v, _ in bits if v & status.REFUSED_MASK}
    swidth = max(len(n) for n, _, _ in bits)
    status_ctx = [{"name": n, "value": "0u" if v == 0 else f"(1u << {v.bit_length() - 1})", "doc": d,
                   "refused": n in refused, "pad": swidth - len(n)} for n, v, d in bits]

    fields = model.state_fields()
    names = [f.name for f in fields]
    if "q" not in names:
        raise ValueError(f"filter {spec.name}: the state must have a field 'q' (body->NED quaternion)")
    state_ctx = []
    decls = [_decl(f.name, f.size, f.ctype, real, scalar=(f.size == 1)) for f in fields]
    dw = max(len(d) for d in decls)
    for f, d in zip(fields, decls):
        vals = f.init_values()
        fmt = (lambda x: lit(x)) if f.ctype == "real" else (lambda x: f"{int(x)}u")
        fill = None
        if f.size > 4 and len(set(vals)) == 1:
            fill = fmt(vals[0])
        state_ctx.append({"name": f.name, "size": f.size, "decl": d, "doc": f.doc, "pad": dw - len(d),
                          "init": [fmt(x) for x in vals], "fill": fill, "scalar": f.size == 1})
    in_decls = [_decl(n, s, k, real, scalar=(s == 1)) for n, s, k, _ in INPUT_FIELDS]
    iw = max(len(d) for d in in_decls)
    input_ctx = [{"decl": d, "doc": doc, "pad": iw - len(d)} for d, (_, _, _, doc) in zip(in_decls, INPUT_FIELDS)]
    layout, state_bytes = struct_layout([(f.name, f.size, f.ctype) for f in fields], real)
    in_layout, input_bytes = struct_layout([(n, s, k) for n, s, k, _ in INPUT_FIELDS], real)

    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader([str(TEMPLATES), str(spec.folder)]),
        undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
        keep_trailing_newline=True)
    ctx = dict(
        version=VERSION, filter=spec.name, title=spec.title,
        # where the filter came from, without machine paths (the output is reproducible anywhere)
        filter_folder=f"generator/filters/{spec.name}/" if spec.origin == "built-in" else f"filter folder {spec.name}/", source=spec.source, prefix=prefix, P=P,
        real=real, F="f" if real == "float" else "", zero=lit(0.0), one=lit(1.0), lit=lit,
        params=params, valid_bits=VALID_BITS, status=status_ctx, state=state_ctx, input=input_ctx,
        kernels=kctx, sensors=model.sensors, state_bytes=state_bytes,
        step_partial="step.c.j2",
        init_partial="init.c.j2" if (spec.folder / "init.c.j2").exists() else None,
        helpers_partial="helpers.c.j2" if (spec.folder / "helpers.c.j2").exists() else None,
        cfg=cfg.params, **model.template_context())
    header = env.get_template("filter.h.j2").render(ctx)
    source = env.get_template("filter.c.j2").render(ctx)

    paths = {}
    for pname, knames in model.step_paths().items():
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
        "files": {"header": f"{prefix}.h", "source": f"{prefix}.c"},
        "params": {n: cfg.params[n] for n in spec.params},
        "status": {n: v for n, v, _ in bits},
        "refused_mask": sum(v for n, v, _ in bits if n in refused),
        "valid_bits": {n: 1 << b for n, b in VALID_BITS},
        "structs": {
            "state": {"size": state_bytes, "fields": [
                {"name": f.name, "type": f.ctype, "count": f.size, "offset": off, "doc": f.doc}
                for f, (_, off, _) in zip(fields, layout)]},
            "input": {"size": input_bytes, "fields": [
                {"name": n, "type": k, "count": s, "offset": off, "doc": doc}
                for (n, s, k, doc), (_, off, _) in zip(INPUT_FIELDS, in_layout)]},
        },
        "kernels": {ks.name: {"c_name": k.name, "ops": k.ops, "total": k.ops_total,
                              "temporaries": k.n_temporaries, "doc": ks.doc}
                    for ks, k in zip(specs, kernels)},
        "step_paths": paths,
    }
    files = {f"{prefix}.h": header, f"{prefix}.c": source,
             "manifest.json": json.dumps(manifest, indent=2, sort_keys=False) + "\n"}
    return Generated(files, manifest, kernels)


def write(gen: Generated, out_dir: str | Path) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in gen.files.items():
        path = out / name
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)     # atomic: a crash never leaves half a file
        written.append(path)
    return written
