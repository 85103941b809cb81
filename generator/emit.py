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
operation counts.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

PRECISIONS = ("float", "double")

# Operation categories for the cost report.
CATEGORIES = ("add", "mul", "div", "sqrt", "trig", "cmp")


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

    @property
    def scalar(self) -> bool:
        return self.size == 1


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
            params.append(f"{real} {a.name}" if a.scalar else f"const {real} {a.name}[{a.size}]")
        for a in self.outputs:
            params.append(f"{real} *{a.name}" if a.scalar else f"{real} {a.name}[{a.size}]")
        return f"{storage}void {self.name}({', '.join(params)})"

    def source(self, storage: str = "static ", indent: str = "    ") -> str:
        lines = []
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
    if not name.isidentifier() or name.startswith("tmp"):
        raise EmitError(f"{what} name {name!r} is not a valid C identifier (and must not start with 'tmp')")


def emit(fn: ca.Function, precision: str = "float", name: str | None = None, doc: str = "",
         context: tuple[str, dict] | None = None) -> Kernel:
    """Emit an SX Function as a C function body for the given precision.

    context = (declaration, {input name: C expression}): those scalar inputs are read through
    one leading parameter (e.g. ("const att_params *par", {"param_kp": "par->kp"})) instead of
    being arguments of their own; the kernel takes the declaration first if it reads any.
    """
    if precision not in PRECISIONS:
        raise EmitError(f"precision must be one of {PRECISIONS}, got {precision!r}")
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
        inputs.append(Arg(fn.name_in(i), sp.nnz(), (sp.size1(), sp.size2())))
        if context and fn.name_in(i) in context[1]:
            if sp.nnz() != 1:
                raise EmitError(f"kernel {name}: context input {fn.name_in(i)!r} must be a scalar")
            inputs[-1].expr = context[1][fn.name_in(i)]
    for o in range(fn.n_out()):
        sp = fn.sparsity_out(o)
        if not sp.is_dense():
            raise EmitError(f"kernel {name}: output {fn.name_out(o)!r} is sparse; densify it in the model")
        _check_name(fn.name_out(o), f"kernel {name}: output")
        outputs.append(Arg(fn.name_out(o), sp.nnz(), (sp.size1(), sp.size2())))

    work: dict[int, str] = {}       # work index -> C expression (temporary, input ref or literal)
    nodes: dict[str, dict] = {}     # temporary -> {code, cat, expr, args}
    order: list[str] = []
    writes: list[str] = []
    used_inputs: set[int] = set()

    def ref(w: int) -> str:
        return work[w]

    def condition(x: str) -> str:
        """C condition for 'x is true', folding a comparison temporary into it."""
        node = nodes.get(x)
        if node is not None and node["code"] in _COMPARISONS:
            a, b = node["args"]
            return f"{a} {_COMPARISONS[node['code']]} {b}"
        return f"{x} != {zero}"

    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_CONST:
            (w,) = fn.instruction_output(k)
            work[w] = literal(fn.instruction_constant(k), precision)
            continue
        if code == ca.OP_INPUT:
            (w,) = fn.instruction_output(k)
            i, nz = fn.instruction_input(k)
            used_inputs.add(i)
            a = inputs[i]
            work[w] = a.expr if a.expr is not None else (a.name if a.scalar else f"{a.name}[{nz}]")
            continue
        if code == ca.OP_OUTPUT:
            (w,) = fn.instruction_input(k)
            o, nz = fn.instruction_output(k)
            a = outputs[o]
            target = f"*{a.name}" if a.scalar else f"{a.name}[{nz}]"
            writes.append(f"{target} = {ref(w)};")
            continue
        if code == ca.OP_ASSIGN:
            (w_in,) = fn.instruction_input(k)[:1]
            (w,) = fn.instruction_output(k)
            work[w] = ref(w_in)
            continue
        ins = fn.instruction_input(k)
        (w,) = fn.instruction_output(k)
        args = [ref(ins[0])] + ([ref(ins[1])] if code in _BINARY or code == ca.OP_CONSTPOW else [])
        select = _as_select(code, args, nodes)
        if select is not None:
            cond, a, b = select
            cat, expr = "cmp", f"({condition(cond)}) ? {a} : {b}"
        elif code == ca.OP_CONSTPOW:
            a, b = args
            expo = _literal_value(b)
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
            cat, expr = "cmp", f"({condition(args[0])}) ? {args[1]} : {zero}"
        elif code in _BINARY:
            cat, fmt = _BINARY[code]
            expr = fmt.format(a=args[0], b=args[1], F=F, one=one, zero=zero)
        elif code in _UNARY:
            cat, fmt = _UNARY[code]
            expr = fmt.format(a=args[0], F=F, one=one, zero=zero)
        else:
            raise EmitError(
                f"kernel {name}: CasADi operation {op_name(code)} is not supported by the emitter "
                f"(supported: {', '.join(SUPPORTED)})")
        tmp = f"t{len(order)}"
        nodes[tmp] = {"code": code, "cat": cat, "expr": expr, "args": args}
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
    # Renumber so the emitted temporaries count up without gaps.
    rename = {t: f"tmp{i}" for i, t in enumerate(kept)}
    sub = lambda s: _TMP_RE.sub(lambda m: rename[m.group(0)], s)  # noqa: E731
    ops = {c: 0 for c in CATEGORIES}
    body = []
    for t in kept:
        ops[nodes[t]["cat"]] += 1
        body.append(f"const {precision} {rename[t]} = {sub(nodes[t]['expr'])};")
    body += [sub(line) for line in writes]
    unused = [a.name for i, a in enumerate(inputs) if i not in used_inputs and a.expr is None]
    reads_context = any(a.expr is not None for i, a in enumerate(inputs) if i in used_inputs)
    return Kernel(name, precision, inputs, outputs, body, ops, doc, len(kept), unused,
                  context[0] if context and reads_context else None)


_TMP_RE = re.compile(r"\bt\d+\b")
_COMPARISONS = {ca.OP_LT: "<", ca.OP_LE: "<=", ca.OP_EQ: "==", ca.OP_NE: "!="}


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
