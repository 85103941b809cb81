"""The C text of each CasADi operation, its cost category, and literals of a precision."""
from __future__ import annotations

from ahrsgen.errors import EmitError  # noqa: F401  (raised here; callers import it from here too)
import casadi as ca
import numpy as np

from ahrsgen.codegen.emit.ir import Call, Lit, Op, Select


PRECISIONS = ("float", "double")

# Operation categories for the cost report.
CATEGORIES = ("add", "mul", "div", "sqrt", "trig", "cmp")

# Relative cost of an operation (roughly Cortex-M4F cycles; a libm or fastmath call ~20).
_WEIGHT = {"add": 1, "mul": 1, "cmp": 1, "div": 8, "sqrt": 8, "trig": 20}


_OP_NAMES = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_") and isinstance(getattr(ca, n), int)}


def op_name(code: int) -> str:
    return _OP_NAMES.get(code, f"OP_{code}")


# code -> (category, builder): the builder makes the expression from the operands a, b and
# F (the precision's function suffix), one and zero (typed literals, ir.Lit).
def _sel(c, a, b):
    return Select(c, a, b)


_BINARY = {
    ca.OP_ADD: ("add", lambda a, b, F, one, zero: Op("+", (a, b))),
    ca.OP_SUB: ("add", lambda a, b, F, one, zero: Op("-", (a, b))),
    ca.OP_MUL: ("mul", lambda a, b, F, one, zero: Op("*", (a, b))),
    ca.OP_DIV: ("div", lambda a, b, F, one, zero: Op("/", (a, b))),
    ca.OP_POW: ("trig", lambda a, b, F, one, zero: Call(f"pow{F}", (a, b))),
    ca.OP_ATAN2: ("trig", lambda a, b, F, one, zero: Call(f"atan2{F}", (a, b))),
    ca.OP_FMOD: ("trig", lambda a, b, F, one, zero: Call(f"fmod{F}", (a, b))),
    ca.OP_COPYSIGN: ("cmp", lambda a, b, F, one, zero: Call(f"copysign{F}", (a, b))),
    ca.OP_HYPOT: ("sqrt", lambda a, b, F, one, zero: Call(f"hypot{F}", (a, b))),
    ca.OP_FMIN: ("cmp", lambda a, b, F, one, zero: _sel(Op("<", (a, b)), a, b)),
    ca.OP_FMAX: ("cmp", lambda a, b, F, one, zero: _sel(Op(">", (a, b)), a, b)),
    ca.OP_LT: ("cmp", lambda a, b, F, one, zero: _sel(Op("<", (a, b)), one, zero)),
    ca.OP_LE: ("cmp", lambda a, b, F, one, zero: _sel(Op("<=", (a, b)), one, zero)),
    ca.OP_EQ: ("cmp", lambda a, b, F, one, zero: _sel(Op("==", (a, b)), one, zero)),
    ca.OP_NE: ("cmp", lambda a, b, F, one, zero: _sel(Op("!=", (a, b)), one, zero)),
    ca.OP_AND: ("cmp", lambda a, b, F, one, zero: _sel(Op("&&", (Op("!=", (a, zero)), Op("!=", (b, zero)))), one, zero)),
    ca.OP_OR: ("cmp", lambda a, b, F, one, zero: _sel(Op("||", (Op("!=", (a, zero)), Op("!=", (b, zero)))), one, zero)),
    ca.OP_IF_ELSE_ZERO: ("cmp", lambda a, b, F, one, zero: _sel(Op("!=", (a, zero)), b, zero)),
}


def _call(fn):
    return lambda a, F, one, zero: Call(fn + F, (a,))


_UNARY = {
    ca.OP_NEG: ("add", lambda a, F, one, zero: Op("neg", (a,))),
    ca.OP_SQ: ("mul", lambda a, F, one, zero: Op("*", (a, a))),
    ca.OP_TWICE: ("add", lambda a, F, one, zero: Op("+", (a, a))),
    ca.OP_INV: ("div", lambda a, F, one, zero: Op("/", (one, a))),
    ca.OP_SQRT: ("sqrt", _call("sqrt")),
    ca.OP_FABS: ("cmp", _call("fabs")),
    ca.OP_FLOOR: ("cmp", _call("floor")),
    ca.OP_CEIL: ("cmp", _call("ceil")),
    ca.OP_SIGN: ("cmp", lambda a, F, one, zero: _sel(Op(">", (a, zero)), one,
                                                       _sel(Op("<", (a, zero)), Op("neg", (one,)), zero))),
    ca.OP_NOT: ("cmp", lambda a, F, one, zero: _sel(Op("==", (a, zero)), one, zero)),
}
for _code, _fn in (("OP_SIN", "sin"), ("OP_COS", "cos"), ("OP_TAN", "tan"), ("OP_ASIN", "asin"),
                   ("OP_ACOS", "acos"), ("OP_ATAN", "atan"), ("OP_EXP", "exp"), ("OP_LOG", "log"),
                   ("OP_SINH", "sinh"), ("OP_COSH", "cosh"), ("OP_TANH", "tanh"), ("OP_ASINH", "asinh"),
                   ("OP_ACOSH", "acosh"), ("OP_ATANH", "atanh"), ("OP_ERF", "erf"), ("OP_LOG1P", "log1p"),
                   ("OP_EXPM1", "expm1")):
    if hasattr(ca, _code):
        _UNARY[getattr(ca, _code)] = ("trig", _call(_fn))

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


_COMPARISONS = {ca.OP_LT: "<", ca.OP_LE: "<=", ca.OP_EQ: "==", ca.OP_NE: "!="}
# Operations with a true/false result, emitted as bool: comparisons of numbers, and the
# connectives, which read their operands as conditions.
_CONNECTIVES = {ca.OP_AND: lambda a, b: Op("&&", (a, b)), ca.OP_OR: lambda a, b: Op("||", (a, b)),
                ca.OP_NOT: lambda a: Op("!", (a,))}
_LOGIC = {**{c: (lambda op: lambda a, b: Op(op, (a, b)))(op) for c, op in _COMPARISONS.items()}, **_CONNECTIVES}


def lit(value: float, precision: str, name: str | None = None) -> Lit:
    """A literal of the precision as an expression (ir.Lit)."""
    v = float(value)
    return Lit(literal(v, precision), v if np.isfinite(v) else None, name)
