"""The C text of each CasADi operation, its cost category, and literals of a precision."""
from __future__ import annotations

from ahrsgen.errors import EmitError  # noqa: F401  (raised here; callers import it from here too)
import re

import casadi as ca
import numpy as np


PRECISIONS = ("float", "double")

# Operation categories for the cost report.
CATEGORIES = ("add", "mul", "div", "sqrt", "trig", "cmp")

# Relative cost of an operation (roughly Cortex-M4F cycles; a libm or fastmath call ~20).
_WEIGHT = {"add": 1, "mul": 1, "cmp": 1, "div": 8, "sqrt": 8, "trig": 20}


_OP_NAMES = {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_") and isinstance(getattr(ca, n), int)}


def op_name(code: int) -> str:
    return _OP_NAMES.get(code, f"OP_{code}")


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


_TMP_RE = re.compile(r"\bt\d+\b")
_COMPARISONS = {ca.OP_LT: "<", ca.OP_LE: "<=", ca.OP_EQ: "==", ca.OP_NE: "!="}
# Operations with a true/false result, emitted as bool: comparisons of numbers, and the
# connectives, which read their operands as conditions.
_CONNECTIVES = {ca.OP_AND: lambda a, b: f"({a}) && ({b})", ca.OP_OR: lambda a, b: f"({a}) || ({b})",
                ca.OP_NOT: lambda a: f"!({a})"}
_LOGIC = {**{c: (lambda op: lambda a, b: f"{a} {op} {b}")(op) for c, op in _COMPARISONS.items()}, **_CONNECTIVES}


def _literal_value(text: str):
    t = text.strip("()").rstrip("f")
    try:
        return float(t)
    except ValueError:
        return None
