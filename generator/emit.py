"""CasADi SX Function -> straight-line C, for float or double.

The emitter walks the SX function's instruction list (Function.instruction_id/_input/
_output/_constant) and writes one named `const` temporary per operation, so the C reads
like the equations and shares every common subexpression once. It knows nothing about
attitude: it turns any SX function whose inputs and outputs are dense into

    static void <name>(const float a[3], float b, ..., float out[4], float *scalar_out)

Rules (DESIGN.md): float builds use the f-suffixed <math.h> functions and literals so no
double is ever computed; min/max/comparisons become conditional expressions (no libm call,
NaN-safe on every target, identical on host and target); inputs and constants are inlined;
outputs are written after every temporary is computed, so an output may alias an input.
Matrices are passed flattened in CasADi's column-major order. Each kernel reports its
operation counts. With math="fast" a float kernel calls generator/fastmath.py's helpers
(no libm) instead of sinf/cosf/atan2f/asinf/acosf/atanf, and lists the helpers it uses.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from generator import fastmath

PRECISIONS = ("float", "double")

# Operation categories for the cost report.
CATEGORIES = ("add", "mul", "div", "sqrt", "trig", "cmp")
# Relative cost of an operation (roughly Cortex-M4F cycles; a libm or fastmath call ~20).
_WEIGHT = {"add": 1, "mul": 1, "cmp": 1, "div": 8, "sqrt": 8, "trig": 20}
# Selects on one condition whose exclusive operations weigh less than this stay ?: (a
# conditional move is cheaper than a branch around a few adds).
BRANCH_MIN_COST = 12
# A kernel with at most this many temporaries is declared `static inline`: GCC then inlines
# it at every call site (a small kernel called from several places, e.g. R(q) again after an
# attitude reset, otherwise stays a call with its outputs in memory). qcf 723 -> 706
# instructions/step, -120 B; larger kernels called several times stay calls (flash).
INLINE_TEMPS = 32
# A kernel with more temporaries than this is written as parts of about this many, called
# in turn (GCC inlines them at -O1 and above): at -O0 every temporary has its own stack
# slot, and one frame per part keeps a debug build's stack bounded. 40 measured best over
# 24..400 (ahrsgen target all, with the shared carry array): adukf stack 2 008 -> 1 592 B,
# -O0 2 288 -> 1 792 B, 6 222 -> 5 726 instructions/step against 160; mekf -O0 1 360 -> 856 B
# but static stack 456 -> 488 B; GCC's inlining of the parts makes the figures jump with it
# (adukf at 56-100: about 1 950 B), so re-measure when changing it.
SPLIT_TEMPS = 40


class EmitError(ValueError):
    """A function the emitter cannot turn into C (unsupported operation, sparse input...)."""


_OP_NAMES = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_") and isinstance(getattr(ca, n), int)}


def op_name(code: int) -> str:
    return _OP_NAMES.get(code, f"OP_{code}")


def _fn(precision: str, name: str) -> str:
    return name + "f" if precision == "float" else name


# code -> (category, format) where format uses {a}, {b} for operands and {F} for the
# precision's function suffix; {one}/{zero} are typed literals.
_BINARY = {
    ca.OP_ADD: ("add", "{a} + {b}"),
    ca.OP_SUB: ("add", "{a} - {b}"),
    ca.OP_MUL: ("mul", "{a} * {b}"),
    ca.OP_DIV: ("div", "{a} / {b}"),
    ca.OP_POW: ("trig", "pow{F}({a}, {b})"),
    ca.OP_ATAN2: ("trig", "atan2{F}({a}, {b})"),
    ca.OP_FMOD: ("trig", "fmod{F}({a}, {b})"),
    ca.OP_COPYSIGN: ("cmp", "copysign{F}({a}, {b})"),
    ca.OP_HYPOT: ("sqrt", "hypot{F}({a}, {b})"),
    ca.OP_FMIN: ("cmp", "({a} < {b}) ? {a} : {b}"),
    ca.OP_FMAX: ("cmp", "({a} > {b}) ? {a} : {b}"),
    ca.OP_LT: ("cmp", "({a} < {b}) ? {one} : {zero}"),
    ca.OP_LE: ("cmp", "({a} <= {b}) ? {one} : {zero}"),
    ca.OP_EQ: ("cmp", "({a} == {b}) ? {one} : {zero}"),
    ca.OP_NE: ("cmp", "({a} != {b}) ? {one} : {zero}"),
    ca.OP_AND: ("cmp", "({a} != {zero} && {b} != {zero}) ? {one} : {zero}"),
    ca.OP_OR: ("cmp", "({a} != {zero} || {b} != {zero}) ? {one} : {zero}"),
    ca.OP_IF_ELSE_ZERO: ("cmp", "({a} != {zero}) ? {b} : {zero}"),
}

_UNARY = {
    ca.OP_NEG: ("add", "-{a}"),
    ca.OP_SQ: ("mul", "{a} * {a}"),
    ca.OP_TWICE: ("add", "{a} + {a}"),
    ca.OP_INV: ("div", "{one} / {a}"),
    ca.OP_SQRT: ("sqrt", "sqrt{F}({a})"),
    ca.OP_FABS: ("cmp", "fabs{F}({a})"),
    ca.OP_FLOOR: ("cmp", "floor{F}({a})"),
    ca.OP_CEIL: ("cmp", "ceil{F}({a})"),
    ca.OP_SIGN: ("cmp", "({a} > {zero}) ? {one} : (({a} < {zero}) ? -{one} : {zero})"),
    ca.OP_NOT: ("cmp", "({a} == {zero}) ? {one} : {zero}"),
    ca.OP_SIN: ("trig", "sin{F}({a})"),
    ca.OP_COS: ("trig", "cos{F}({a})"),
    ca.OP_TAN: ("trig", "tan{F}({a})"),
    ca.OP_ASIN: ("trig", "asin{F}({a})"),
    ca.OP_ACOS: ("trig", "acos{F}({a})"),
    ca.OP_ATAN: ("trig", "atan{F}({a})"),
    ca.OP_EXP: ("trig", "exp{F}({a})"),
    ca.OP_LOG: ("trig", "log{F}({a})"),
    ca.OP_SINH: ("trig", "sinh{F}({a})"),
    ca.OP_COSH: ("trig", "cosh{F}({a})"),
    ca.OP_TANH: ("trig", "tanh{F}({a})"),
    ca.OP_ASINH: ("trig", "asinh{F}({a})"),
    ca.OP_ACOSH: ("trig", "acosh{F}({a})"),
    ca.OP_ATANH: ("trig", "atanh{F}({a})"),
    ca.OP_ERF: ("trig", "erf{F}({a})"),
}
for _name, _fmt in (("OP_LOG1P", "log1p{F}({a})"), ("OP_EXPM1", "expm1{F}({a})")):
    if hasattr(ca, _name):
        _UNARY[getattr(ca, _name)] = ("trig", _fmt)

# Operations the emitter accepts (for tests and error messages).
SUPPORTED = sorted(op_name(c) for c in list(_BINARY) + list(_UNARY) + [ca.OP_CONSTPOW, ca.OP_ASSIGN])


def literal(value: float, precision: str) -> str:
    """A C literal of the precision's type that round-trips the value in that precision."""
    v = float(value)
    if np.isnan(v):
        return "NAN" if precision == "float" else "(double)NAN"
    if np.isinf(v):
        s = "INFINITY" if precision == "float" else "(double)INFINITY"
        return s if v > 0 else "(-" + s + ")"
    if precision == "float":
        text = str(np.float32(v))  # shortest text that round-trips the float32
        if np.float32(float(text)) != np.float32(v):
            text = f"{float(np.float32(v)):.9g}"
    else:
        text = repr(v)
    if "e" not in text and "." not in text and "inf" not in text:
        text += ".0"
    if precision == "float":
        text += "f"
    return f"({text})" if text.startswith("-") else text


@dataclass
class Arg:
    name: str
    size: int
    shape: tuple[int, int]
    expr: str | None = None    # read from a context (e.g. "par->kp") instead of an argument
    flag: bool = False         # a true/false input: C type bool, read as a condition

    @property
    def scalar(self) -> bool:
        return self.size == 1

    def param(self, real: str) -> str:
        """Its declaration as a (read-only) parameter."""
        ctype = "bool" if self.flag else real
        return f"{ctype} {self.name}" if self.scalar else f"const {ctype} {self.name}[{self.size}]"


@dataclass
class Kernel:
    """One emitted C function: prototype, body lines and its operation counts."""
    name: str
    precision: str
    inputs: list[Arg]
    outputs: list[Arg]
    body: list[str]
    ops: dict[str, int]
    doc: str = ""
    n_temporaries: int = 0
    unused_inputs: list[str] = field(default_factory=list)
    helpers: list[str] = field(default_factory=list)   # generator/fastmath.py helpers called
    branches: list[dict] = field(default_factory=list)  # if/else blocks: condition, ops of each side
    parts: list[str] = field(default_factory=list)      # sources of the part functions of a split kernel
    context: str | None = None    # leading parameter declaration, e.g. "const att_params *par"

    @property
    def ops_total(self) -> int:
        return sum(self.ops.values())

    def prototype(self, storage: str = "static ") -> str:
        real = self.precision
        params = [self.context] if self.context else []
        for a in self.inputs:
            if a.expr is not None:
                continue
            params.append(a.param(real))
        for a in self.outputs:
            ctype = "bool" if a.flag else real
            params.append(f"{ctype} *{a.name}" if a.scalar else f"{ctype} {a.name}[{a.size}]")
        return f"{storage}void {self.name}({', '.join(params)})"

    def source(self, storage: str = "static ", indent: str = "    ") -> str:
        lines = []
        for part in self.parts:
            lines += [part, ""]
        if self.doc:
            lines.append("/* " + self.doc.replace("*/", "* /") + " */")
        lines.append(self.prototype(storage))
        lines.append("{")
        for name in self.unused_inputs:
            lines.append(f"{indent}(void){name};")
        lines.extend(indent + b for b in self.body)
        lines.append("}")
        return "\n".join(lines)


def _check_name(name: str, what: str) -> None:
    if not name.isidentifier() or name.startswith("tmp") or re.fullmatch(r"carry\d*", name):
        raise EmitError(f"{what} name {name!r} is not a valid C identifier (and must not start with 'tmp' "
                        "or be carry/carry<N>)")


def emit(fn: ca.Function, precision: str = "float", name: str | None = None, doc: str = "",
         math: str = "libm", branch_min_cost: int | None = BRANCH_MIN_COST, fma: bool = False,
         split_temps: int | None = SPLIT_TEMPS, context: tuple[str, dict] | None = None,
         flags: tuple[str, ...] | list[str] = (), names: dict[int, str] | None = None) -> Kernel:
    """Emit an SX Function as a C function body for the given precision.

    ``math="fast"`` (float only; double always uses libm) writes fastmath helpers for the
    trigonometric functions. ``fma=True`` writes a product feeding a sum as fmaf(a, b, c):
    the emitter decides every fusion, so host and target round alike (the compiler's
    -ffp-contract stays off).

    context = (declaration, {input name: C expression}): those scalar inputs are read through
    one leading parameter (e.g. ("const att_params *par", {"param_kp": "par->kp"})) instead of
    being arguments of their own; the kernel takes the declaration first if it reads any.

    flags: names of inputs (and outputs) that only hold 0 or 1 (masks, use-this-sensor switches): they are
    declared bool and tested as conditions, never compared with 0.0f. Comparisons and their
    logic (<, <=, ==, !=, &&, ||, !) become bool temporaries too; where one is used as a number
    it is converted explicitly, (float)x.

    names: {instruction index: text} for OP_CONST instructions that are a folded parameter
    expression (generator/folded.py); the literal is written with the text in a comment
    beside it, `0.0049f /* accel_angle_noise^2 */`. Nothing else changes: until the body is
    written, a named literal is a placeholder that every decision reads as the literal.
    """
    if precision not in PRECISIONS:
        raise EmitError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if math not in fastmath.MATH_MODES:
        raise EmitError(f"math must be one of {fastmath.MATH_MODES}, got {math!r}")
    fast = math == "fast" and precision == "float"
    helpers: set[str] = set()
    if not fn.is_a("SXFunction"):
        raise EmitError(f"kernel {fn.name()}: only SX functions can be emitted (got {fn.class_name()})")
    name = name or fn.name()
    _check_name(name, "kernel")
    F = "f" if precision == "float" else ""
    one, zero = literal(1.0, precision), literal(0.0, precision)

    inputs, outputs = [], []
    for i in range(fn.n_in()):
        sp = fn.sparsity_in(i)
        if not sp.is_dense():
            raise EmitError(f"kernel {name}: input {fn.name_in(i)!r} is sparse; only dense inputs are supported")
        _check_name(fn.name_in(i), f"kernel {name}: input")
        inputs.append(Arg(fn.name_in(i), sp.nnz(), (sp.size1(), sp.size2()), flag=fn.name_in(i) in flags))
        if context and fn.name_in(i) in context[1]:
            if sp.nnz() != 1:
                raise EmitError(f"kernel {name}: context input {fn.name_in(i)!r} must be a scalar")
            inputs[-1].expr = context[1][fn.name_in(i)]
    for o in range(fn.n_out()):
        sp = fn.sparsity_out(o)
        if not sp.is_dense():
            raise EmitError(f"kernel {name}: output {fn.name_out(o)!r} is sparse; densify it in the model")
        _check_name(fn.name_out(o), f"kernel {name}: output")
        outputs.append(Arg(fn.name_out(o), sp.nnz(), (sp.size1(), sp.size2()), flag=fn.name_out(o) in flags))

    work: dict[int, str] = {}       # work index -> C expression (temporary, input ref or literal)
    nodes: dict[str, dict] = {}     # temporary -> {code, cat, expr, args}
    order: list[str] = []
    writes: list[str] = []
    used_inputs: set[int] = set()
    booleans: set[str] = set()      # flag input references and bool temporaries
    unknown = set(flags) - {fn.name_in(i) for i in range(fn.n_in())} - {fn.name_out(o) for o in range(fn.n_out())}
    if unknown:
        raise EmitError(f"kernel {name}: flag(s) {', '.join(sorted(unknown))} are neither inputs nor outputs")

    def ref(w: int) -> str:
        return work[w]

    marks = _Marks()

    def boolish(x: str) -> bool:
        return x in booleans or marks.plain(x) in (one, zero)

    def truth(x: str) -> str:
        x0 = marks.plain(x)
        return "true" if x0 == one else "false" if x0 == zero else x

    def value(x: str) -> str:
        """x read as a number: a bool is converted explicitly."""
        return f"({precision}){x}" if x in booleans else x

    def condition(x: str) -> str:
        """C condition for 'x is true', folding a comparison temporary into it."""
        node = nodes.get(x)
        if node is not None and node["code"] in _COMPARISONS:
            a, b = node["args"]
            return f"{value(a)} {_COMPARISONS[node['code']]} {value(b)}"
        if node is not None and node["code"] == ca.OP_NOT:
            return f"!({condition(node['args'][0])})"
        if x in booleans:
            return x
        return f"{x} != {zero}"

    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_CONST:
            (w,) = fn.instruction_output(k)
            work[w] = literal(fn.instruction_constant(k), precision)
            if names and k in names:
                work[w] = marks.add(work[w], names[k])
            continue
        if code == ca.OP_INPUT:
            (w,) = fn.instruction_output(k)
            i, nz = fn.instruction_input(k)
            used_inputs.add(i)
            a = inputs[i]
            work[w] = a.expr if a.expr is not None else (a.name if a.scalar else f"{a.name}[{nz}]")
            if a.flag:
                booleans.add(work[w])
            continue
        if code == ca.OP_OUTPUT:
            (w,) = fn.instruction_input(k)
            o, nz = fn.instruction_output(k)
            a = outputs[o]
            target = f"*{a.name}" if a.scalar else f"{a.name}[{nz}]"
            if a.flag:
                x = ref(w)
                writes.append(f"{target} = {truth(x) if boolish(x) else f'{x} != {zero}'};")
            else:
                writes.append(f"{target} = {value(ref(w))};")
            continue
        if code == ca.OP_ASSIGN:
            (w_in,) = fn.instruction_input(k)[:1]
            (w,) = fn.instruction_output(k)
            work[w] = ref(w_in)
            continue
        ins = fn.instruction_input(k)
        (w,) = fn.instruction_output(k)
        sel = None
        args = [ref(ins[0])] + ([ref(ins[1])] if code in _BINARY or code == ca.OP_CONSTPOW else [])
        select = _as_select(code, args, nodes)
        args_v = [value(a) for a in args]    # operands read as numbers
        is_bool = select is None and code in _LOGIC
        if is_bool:
            cat, expr = "cmp", _LOGIC[code](*[condition(a) if code in _CONNECTIVES else value(a) for a in args])
        elif select is not None:
            cond, a, b = select
            if boolish(a) and boolish(b):      # a choice between truth values stays bool
                a, b = truth(a), truth(b)
                is_bool = True
            else:
                a, b = value(a), value(b)
            cat, expr = "cmp", f"({condition(cond)}) ? {a} : {b}"
            sel = (condition(cond), a, b)
        elif code == ca.OP_CONSTPOW:
            a, b = args_v
            expo = _literal_value(marks.plain(b))
            if expo == 2.0:
                cat, expr = "mul", f"{a} * {a}"
            elif expo == 3.0:
                cat, expr = "mul", f"{a} * {a} * {a}"
            elif expo == 0.5:
                cat, expr = "sqrt", f"sqrt{F}({a})"
            elif expo == -1.0:
                cat, expr = "div", f"{one} / {a}"
            else:
                cat, expr = "trig", f"pow{F}({a}, {b})"
        elif code == ca.OP_IF_ELSE_ZERO:
            c = condition(args[0])
            if c.startswith("!(") and c.endswith(")"):      # if_else(c, 0, x): same block as c's selects
                cat, expr = "cmp", f"({c[2:-1]}) ? {zero} : {args_v[1]}"
                sel = (c[2:-1], zero, args_v[1])
            else:
                cat, expr = "cmp", f"({c}) ? {args_v[1]} : {zero}"
                sel = (c, args_v[1], zero)
        elif fast and code in fastmath.OPS:
            h = fastmath.OPS[code]
            helpers.add(h)
            cat, expr = "trig", f"{fastmath.HELPERS[h].name}({', '.join(args_v)})"
        elif code in _BINARY:
            cat, fmt = _BINARY[code]
            expr = fmt.format(a=args_v[0], b=args_v[1], F=F, one=one, zero=zero)
        elif code in _UNARY:
            cat, fmt = _UNARY[code]
            expr = fmt.format(a=args_v[0], F=F, one=one, zero=zero)
        else:
            raise EmitError(
                f"kernel {name}: CasADi operation {op_name(code)} is not supported by the emitter "
                f"(supported: {', '.join(SUPPORTED)})")
        tmp = f"t{len(order)}"
        nodes[tmp] = {"code": code, "cat": cat, "expr": expr, "args": args, "sel": sel,
                      "vargs": args_v, "ctype": "bool" if is_bool else precision}
        if is_bool:
            booleans.add(tmp)
        order.append(tmp)
        work[w] = tmp

    # Dead-code elimination: select folding leaves some temporaries unread.
    live = set()
    for line in writes:
        live.update(_TMP_RE.findall(line))
    for tmp in reversed(order):
        if tmp in live:
            live.update(_TMP_RE.findall(nodes[tmp]["expr"]))
    kept = [t for t in order if t in live]
    kept = _exact_reciprocals(kept, nodes, precision, marks)
    if fma:
        kept = _fuse_multiply_add(kept, nodes, writes, "fmaf" if precision == "float" else "fma")
    ops = {c: 0 for c in CATEGORIES}
    for t in kept:
        ops[nodes[t]["cat"]] += 1
        for c in nodes[t].get("extra_ops", ()):
            ops[c] += 1
    body, emitted, branches, tops = _layout(kept, nodes, writes, precision, branch_min_cost, marks.plain)
    # Renumber in emission order so the temporaries count up without gaps.
    rename = {t: f"tmp{i}" for i, t in enumerate(emitted)}
    sub = lambda s: _TMP_RE.sub(lambda m: rename[m.group(0)], s)  # noqa: E731
    parts: list[str] = []
    reads_context = any(a.expr is not None for i, a in enumerate(inputs) if i in used_inputs)
    ctx_decl = context[0] if context and reads_context else None
    if split_temps and len(emitted) > split_temps:
        body, parts = _split(name, precision, inputs, body, writes, tops, split_temps, ctx_decl,
                             frozenset(t for t in kept if nodes[t]["ctype"] == "bool"))
        body, parts = [sub(line) for line in body], [sub(p) for p in parts]
    else:
        body = [sub(line) for line in body] + [sub(line) for line in writes]
    body, parts = [marks.write(line) for line in body], [marks.write(p) for p in parts]
    for br in branches:
        br["condition"] = sub(br["condition"])
    unused = [a.name for i, a in enumerate(inputs) if i not in used_inputs and a.expr is None]
    used = {h for h in helpers if any(fastmath.HELPERS[h].name + "(" in nodes[t]["expr"] for t in kept)}
    return Kernel(name, precision, inputs, outputs, body, ops, doc, len(kept), unused, helpers=sorted(used),
                  branches=branches, parts=parts, context=ctx_decl)


_WORD = re.compile(r"\b[A-Za-z_]\w*\b")


def _split(name, precision, inputs, body, writes, tops, size, ctx_decl=None, bools=frozenset()):
    """Cut the top-level statements into parts of about `size` temporaries; each part is a
    static function that reads the kernel inputs it uses and the values earlier parts
    exported, and exports what later parts and the outputs read. The exported values live in
    one array `carry` in the kernel's frame; a slot is reused once the value in it is dead (its
    last reader is an earlier part, or the part writing the new value: a part writes its
    exports after all its reads), so the frame holds the values live at once, not every value
    ever handed over. Returns the kernel's body and the parts' sources (temporaries as t<N>).
    A bool temporary travels as 1 or 0 in its carry and is read back as carry > 0.5."""
    chunks, cur, count = [], [], 0
    for item in tops:
        if cur and count + len(item[2]) > size:
            chunks.append(cur)
            cur, count = [], 0
        cur.append(item)
        count += len(item[2])
    if cur:
        chunks.append(cur)
    texts = [[ln for a, b, _ in ch for ln in body[a:b]] for ch in chunks]
    defs = [[t for _, _, d in ch for t in d] for ch in chunks]
    used = [set(_TMP_RE.findall("\n".join(tx))) for tx in texts]
    used_out = set(_TMP_RE.findall("\n".join(writes)))
    exports = []
    for k, d in enumerate(defs):
        later = set().union(*used[k + 1:]) | used_out
        exports.append([t for t in d if t in later])
    # slots: the last part reading each exported value (len(chunks): an output reads it)
    last = {t: max([j for j in range(k + 1, len(chunks)) if t in used[j]] + [len(chunks) if t in used_out else -1])
            for k, ex in enumerate(exports) for t in ex}
    slot, holder, free, pool = {}, {}, [], 0
    for k, ex in enumerate(exports):
        for s, t in list(holder.items()):
            if last[t] <= k:
                free.append(s)
                del holder[s]
        free.sort()
        for t in ex:
            if free:
                s = free.pop(0)
            else:
                s, pool = pool, pool + 1
            slot[t], holder[s] = s, t
    producer = {t: k for k, ex in enumerate(exports) for t in ex}
    real = precision

    def carried(t):
        ref = f"carry[{slot[t]}]"
        return f"({ref} > {literal(0.5, real)})" if t in bools else ref
    parts = []
    call_lines = [f"/* {len(chunks)} parts called in turn (inlined when optimising): bounded -O0 frames; "
                  f"carry holds the values handed between them (a slot reused once its value is dead) */"]
    if pool:
        call_lines.append(f"{real} carry[{pool}];")
    for k, tx in enumerate(texts):
        text = "\n".join(tx)
        words = set(_WORD.findall(text))
        ins = [a for a in inputs if a.expr is None and a.name in words]
        ctx = ctx_decl is not None and any(a.expr is not None and a.expr in text for a in inputs)
        imported = {t: carried(t) for t in used[k] if t in producer and producer[t] < k}
        params = ([ctx_decl] if ctx else []) + [a.param(real) for a in ins]
        if exports[k]:
            params.append(f"{real} carry[{pool}]")
        elif imported:
            params.append(f"const {real} carry[{pool}]")
        lines = [_TMP_RE.sub(lambda m: imported.get(m.group(0), m.group(0)), ln) for ln in tx]
        lines += [f"carry[{slot[t]}] = {t} ? {literal(1.0, real)} : {literal(0.0, real)};" if t in bools
                  else f"carry[{slot[t]}] = {t};" for t in exports[k]]
        pname = f"{name}_part{k}"
        parts.append(f"static void {pname}({', '.join(params)})\n{{\n" + "\n".join("    " + ln for ln in lines) + "\n}")
        args = ([_WORD.findall(ctx_decl)[-1]] if ctx else []) + [a.name for a in ins] + (["carry"] if exports[k] or imported else [])
        call_lines.append(f"{pname}({', '.join(args)});")
    out = [_TMP_RE.sub(lambda m: carried(m.group(0)), w) for w in writes]
    return call_lines + out, parts


def _exact_reciprocals(kept, nodes, precision, marks):
    """x / c with c a power of two -> x * (1 / c): the same value to the last bit (1 / c is
    exact), a multiplication instead of a division (14 cycles on the M4F, GCC keeps the
    division without -freciprocal-math). A named c gives a named 1 / c."""
    for t in kept:
        n = nodes[t]
        c = _literal_value(marks.plain(n["args"][1])) if n["code"] == ca.OP_DIV and n["sel"] is None else None
        if _power_of_two(c, precision):
            r = literal(1.0 / c, precision)
            if marks.name(n["args"][1]):
                r = marks.add(r, _reciprocal_name(marks.name(n["args"][1])))
            n.update(code=ca.OP_MUL, cat="mul", expr=f"{n['args'][0]} * {r}", args=[n["args"][0], r])
    return kept


def _power_of_two(c, precision) -> bool:
    """c = +-2^k with 1 / c a normal number of the precision (so x * (1 / c) == x / c)."""
    if c is None or c == 0.0 or not np.isfinite(c) or math.frexp(abs(c))[0] != 0.5:
        return False
    r = abs(1.0 / c)
    tiny, big = (np.finfo(np.float32).tiny, np.finfo(np.float32).max) if precision == "float" else \
        (np.finfo(np.float64).tiny, np.finfo(np.float64).max)
    return tiny <= r <= big


def _fuse_multiply_add(kept, nodes, writes, fname):
    """a * b + c, c + a * b, a * b - c and c - a * b -> one fused multiply-add (rounded once).
    Every sum with a product operand fuses it; the product's own temporary disappears when
    no other use is left. Counted as one mul and one add."""
    uses: dict[str, int] = {t: 0 for t in kept}
    for t in kept:
        for r in _TMP_RE.findall(nodes[t]["expr"]):
            uses[r] += 1
    for line in writes:
        for r in _TMP_RE.findall(line):
            uses[r] += 1
    fused: dict[str, int] = {}
    for t in kept:
        node = nodes[t]
        if node["code"] not in (ca.OP_ADD, ca.OP_SUB) or node["sel"] is not None:
            continue
        x, y = node["vargs"]
        for pos, m in ((0, x), (1, y)):
            mn = nodes.get(m)
            if mn is None or mn["code"] != ca.OP_MUL or m == (y if pos == 0 else x):
                continue
            a, b = mn["vargs"]
            other = y if pos == 0 else x
            if node["code"] == ca.OP_ADD:
                expr = f"{fname}({a}, {b}, {other})"
            elif pos == 0:                       # a * b - c
                expr = f"{fname}({a}, {b}, -{other})"
            else:                                # c - a * b
                expr = f"{fname}(-{a}, {b}, {other})"
            node["expr"] = expr
            node["cat"] = "mul"
            node["extra_ops"] = ["add"]
            fused[m] = fused.get(m, 0) + 1
            break
    return [t for t in kept if not (t in fused and fused[t] == uses[t])]


# --------------------------------------------------------------------------------------
# Branches: a select whose sides cost more than a few operations becomes if/else
# --------------------------------------------------------------------------------------



def _exclusive(group, side, kept, idx, nodes, users, refs):
    """Temporaries computed only for `side` (1 = then, 2 = else) of the selects in `group`:
    every use of each lies on that side (CSE-shared work stays outside)."""
    sel = set(group)
    other = 3 - side
    # Work that reads a select of this group (a chain of selects on one condition) cannot go
    # inside the block: it would read the select before the block assigns it. Left outside,
    # it makes the group depend on itself and the group stays `?:` (see _emit_groups).
    reads_sel: set[str] = set()
    for t in kept[:max(idx[s] for s in group)]:
        if refs[t] & (sel | reads_sel):
            reads_sel.add(t)
    E: set[str] = set()
    for s in group:
        r = nodes[s]["sel"][side]
        if r in idx and r not in reads_sel and users[r] <= sel and all(
                r != nodes[g]["sel"][other] and r not in _TMP_RE.findall(nodes[g]["sel"][0]) for g in group):
            E.add(r)
    top = max(idx[s] for s in group)
    for t in reversed(kept[:top]):
        if t not in E and t not in sel and t not in reads_sel and users[t] and users[t] <= E:
            E.add(t)
    return E


def _layout(kept, nodes, writes, precision, min_cost, plain=lambda s: s):
    """Body lines (temporaries as t<N>), the temporaries in emission order, and the branches.

    Selects on the same condition form a group; a group whose exclusive operations weigh
    at least `min_cost` is written as one if/else that computes only the taken side.
    Groups nest when all of a group's selects lie on one side of another. Selects are grouped
    by the plain text of their condition (`plain`: named literals as literals), which the
    if () shows."""
    idx = {t: i for i, t in enumerate(kept)}
    refs = {t: set(_TMP_RE.findall(nodes[t]["expr"])) for t in kept}
    users: dict[str, set] = {t: set() for t in kept}
    for t in kept:
        for r in refs[t]:
            users[r].add(t)
    for line in writes:
        for r in _TMP_RE.findall(line):
            users[r].add("<out>")
    by_cond: dict[str, list[str]] = {}
    for t in kept:
        if nodes[t]["sel"] is not None:       # keyed apart from temporaries: a condition may be one
            by_cond.setdefault(_IF + plain(nodes[t]["sel"][0]), []).append(t)

    def cost(E):
        return sum(_WEIGHT[nodes[t]["cat"]] for t in E)

    groups = {}
    for cond, sels in by_cond.items():
        if min_cost is None:
            break
        ea, eb = (_exclusive(sels, side, kept, idx, nodes, users, refs) for side in (1, 2))
        if cost(ea) + cost(eb) >= min_cost:
            groups[cond] = (sels, ea, eb)

    while True:
        try:
            return _emit_groups(kept, idx, nodes, refs, groups, precision, plain)
        except _Cycle as c:        # this group cannot be placed as one block: keep it ?:
            del groups[c.cond]


_IF = "if:"      # prefix of a group's key: the condition text, apart from any temporary's name


class _Cycle(Exception):
    def __init__(self, cond):
        self.cond = cond


def _emit_groups(kept, idx, nodes, refs, groups, precision, plain):
    import heapq
    # parent of each group: the (group, side) whose exclusive set holds all its selects
    parent = {}
    for c, (sels, _, _) in groups.items():
        best = None
        for d, (_, ea, eb) in groups.items():
            if d == c:
                continue
            for side, E in ((1, ea), (2, eb)):
                inside = [s in E for s in sels]
                if all(inside) and (best is None or len(E) < len(groups[best[0]][best[1]])):
                    best = (d, side)
                elif any(inside):
                    raise _Cycle(c)   # straddles a side: not a block of its own
        parent[c] = best
    lines, emitted, branches, tops = [], [], [], []

    def block(members, key, indent):
        here = [c for c in groups if parent[c] == key]
        inner = set()
        for c in here:
            inner |= groups[c][1] | groups[c][2]
        owner = {}
        items = {}
        for t in members:
            if t in inner:
                continue
            sel = nodes[t]["sel"]
            g = _IF + plain(sel[0]) if sel is not None and _IF + plain(sel[0]) in here else None
            owner[t] = g if g is not None else t
            items.setdefault(owner[t], idx[t])
            items[owner[t]] = min(items[owner[t]], idx[t])
        deps = {i: set() for i in items}
        for i in items:
            if i in groups:
                sels, ea, eb = groups[i]
                mem = set(sels) | ea | eb
            else:
                mem = {i}
            for t in mem:
                for r in refs[t]:
                    o = owner.get(r)
                    if o is not None and o != i and r not in mem:
                        deps[i].add(o)
        indeg = {i: len(d) for i, d in deps.items()}
        rdeps = {i: [] for i in items}
        for i, d in deps.items():
            for o in d:
                rdeps[o].append(i)
        ready = [(items[i], i) for i in items if indeg[i] == 0]
        heapq.heapify(ready)
        done = 0
        while ready:
            _, i = heapq.heappop(ready)
            done += 1
            start, n0 = len(lines), len(emitted)
            if i in groups:
                sels, ea, eb = groups[i]
                for s in sels:
                    lines.append(f"{indent}{nodes[s]['ctype']} {s};")
                    emitted.append(s)
                br = {"condition": i[len(_IF):], "then": _ops(ea, nodes), "else": _ops(eb, nodes)}
                branches.append(br)
                lines.append(f"{indent}if ({i[len(_IF):]}) {{")
                block(sorted(ea, key=idx.get), (i, 1), indent + "    ")
                for s in sels:
                    lines.append(f"{indent}    {s} = {nodes[s]['sel'][1]};")
                lines.append(f"{indent}}} else {{")
                block(sorted(eb, key=idx.get), (i, 2), indent + "    ")
                for s in sels:
                    lines.append(f"{indent}    {s} = {nodes[s]['sel'][2]};")
                lines.append(f"{indent}}}")
            else:
                lines.append(f"{indent}const {nodes[i]['ctype']} {i} = {nodes[i]['expr']};")
                emitted.append(i)
            if key is None:
                tops.append((start, len(lines), emitted[n0:]))
            for j in rdeps[i]:
                indeg[j] -= 1
                if indeg[j] == 0:
                    heapq.heappush(ready, (items[j], j))
        if done != len(items):
            stuck = [i for i in items if indeg[i] > 0 and i in groups]
            raise _Cycle(stuck[0] if stuck else next(iter(here)))

    block(kept, None, "")
    return lines, emitted, branches, tops


def _ops(E, nodes) -> dict:
    ops = {c: 0 for c in CATEGORIES}
    for t in E:
        ops[nodes[t]["cat"]] += 1
    return {c: n for c, n in ops.items() if n}


_TMP_RE = re.compile(r"\bt\d+\b")
_COMPARISONS = {ca.OP_LT: "<", ca.OP_LE: "<=", ca.OP_EQ: "==", ca.OP_NE: "!="}
# Operations with a true/false result, emitted as bool: comparisons of numbers, and the
# connectives, which read their operands as conditions.
_CONNECTIVES = {ca.OP_AND: lambda a, b: f"({a}) && ({b})", ca.OP_OR: lambda a, b: f"({a}) || ({b})",
                ca.OP_NOT: lambda a: f"!({a})"}
_LOGIC = {**{c: (lambda op: lambda a, b: f"{a} {op} {b}")(op) for c, op in _COMPARISONS.items()}, **_CONNECTIVES}


def _as_select(code, args, nodes):
    """Recognise CasADi's if_else(c, a, b) = if_else_zero(c, a) + if_else_zero(!c, b)."""
    if code != ca.OP_ADD:
        return None
    n1, n2 = nodes.get(args[0]), nodes.get(args[1])
    if not n1 or not n2 or n1["code"] != ca.OP_IF_ELSE_ZERO or n2["code"] != ca.OP_IF_ELSE_ZERO:
        return None
    c1, c2 = n1["args"][0], n2["args"][0]
    not1, not2 = nodes.get(c1), nodes.get(c2)
    if not2 and not2["code"] == ca.OP_NOT and not2["args"][0] == c1:
        return c1, n1["args"][1], n2["args"][1]
    if not1 and not1["code"] == ca.OP_NOT and not1["args"][0] == c2:
        return c2, n2["args"][1], n1["args"][1]
    return None


class _Marks:
    """Named literals while a kernel is emitted: each is a placeholder @<n>@ (no letters, so
    no identifier or temporary pattern matches it) that `plain` reads as the literal and
    `write` turns into `literal /* name */` in the finished lines."""
    _RE = re.compile(r"@(\d+)@")

    def __init__(self):
        self.items: list[tuple[str, str]] = []

    def add(self, lit: str, name: str) -> str:
        self.items.append((lit, name.replace("*/", "* /").replace("/*", "/ *")))
        return f"@{len(self.items) - 1}@"

    def name(self, text: str) -> str | None:
        m = self._RE.fullmatch(text)
        return self.items[int(m.group(1))][1] if m else None

    def plain(self, text: str) -> str:
        return self._RE.sub(lambda m: self.items[int(m.group(1))][0], text) if self.items else text

    def write(self, text: str) -> str:
        if not self.items:
            return text
        return self._RE.sub(lambda m: "{} /* {} */".format(*self.items[int(m.group(1))]), text)


def _reciprocal_name(name: str) -> str:
    return f"1/{name}" if name.isidentifier() else f"1/({name})"


def _literal_value(text: str):
    t = text.strip("()").rstrip("f")
    try:
        return float(t)
    except ValueError:
        return None


# Symbols named with this prefix stand for parameters read at run time (a runtime build):
# `function` makes the ones an output depends on extra scalar inputs of the kernel.
RUNTIME_PREFIX = "param_"


def runtime_symbol(name: str) -> ca.SX:
    return ca.SX.sym(RUNTIME_PREFIX + name)


def function(name: str, inputs: dict, outputs: dict) -> ca.Function:
    """Build an SX Function for emission from ordered {name: SX} dicts (CSE on, SSA work).

    Runtime-parameter symbols (runtime_symbol) the outputs use become trailing inputs, named
    after the symbol; any other free symbol is an error (CasADi's)."""
    outs = [ca.densify(v) for v in outputs.values()]
    ins, names = list(inputs.values()), list(inputs.keys())
    given = {str(s) for v in ins for s in ca.symvar(v)}
    for s in ca.symvar(ca.veccat(*outs)) if outs else []:
        n = str(s)
        if n.startswith(RUNTIME_PREFIX) and n not in given:
            ins.append(s)
            names.append(n)
            given.add(n)
    return ca.Function(name, ins, outs, names, list(outputs.keys()),
                       {"cse": True, "live_variables": False})
