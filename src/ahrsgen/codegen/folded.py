"""Names of folded parameters: which literal of a baked kernel is which parameter expression.

A baked build folds parameters into numbers (0.0049f is accel_angle_noise^2). To write the
expression beside the number, the model's kernels are built a second time with every float
parameter (except runtime ones and those at 0, 1 or -1, where CasADi simplifies x * 1 and
x + 0 and the graph would change shape) replaced by a `Traced` number: a float whose value is
the parameter slightly perturbed (a different factor per parameter), that remembers its
expression and also carries, as `shadow`, the value the same Python arithmetic gives on the
real parameters. Every Traced number the model computes is recorded.

A literal of the baked kernel gets a name only when the traced kernel has exactly the same
instructions (same operations on the same operands: the graph did not change shape), the
constant at that instruction differs between the two (it depends on a perturbed parameter),
and a recorded expression equals it in both builds: value == the traced constant and
shadow == the baked constant. A structural constant never changes; a constant CasADi
computed from a parameter and something else (x * (1 / p) written as x / p, a product of two
folded numbers) matches no recorded expression at two unrelated points and stays unnamed.
A kernel whose graph CasADi shaped by a parameter's value (two equal constants merged into
one node, as two parameters at 0.1 multiplying the same x, or a parameter equal to a
structural constant) has another shape in the traced build: its numbers all stay bare. So a
name is either right or absent. The emitter (src/ahrsgen/codegen/emit, `names`) writes it as
a comment beside the literal; the arithmetic does not change.
"""
from __future__ import annotations

import math

import casadi as ca

# Expressions longer than this are written as "from a, b" (the parameters they use).
MAX_TEXT = 40
# Relative perturbation of parameter i: (i + 1) * STEP * an irrational factor, so no two
# parameters (nor simple expressions of them) move alike.
STEP = 1e-6
_SPECIAL = (0.0, 1.0, -1.0)

# operator precedence of an expression's text, for parentheses
_ATOM, _POW, _NEG, _MUL, _ADD = 5, 4, 3, 2, 1


class Traced(float):
    """A parameter (or an expression of parameters) with a perturbed value, its real-build
    value (`shadow`), its text and the parameter names it uses."""

    def __new__(cls, value, shadow, text, prec, uses, record):
        obj = float.__new__(cls, value)
        obj.shadow, obj.text, obj.prec, obj.uses, obj.record = float(shadow), text, prec, uses, record
        record.append(obj)
        return obj

    # -- helpers -----------------------------------------------------------------------
    def _wrap(self, prec, right=False):
        return f"({self.text})" if self.prec < prec or (right and self.prec == prec and prec != _ATOM) else self.text

    @staticmethod
    def _operand(x):
        """(perturbed value, shadow, text, prec, uses) of an operand, or None (not a plain number)."""
        if isinstance(x, Traced):
            return x
        if type(x) not in (int, float):      # bool, numpy, CasADi: not ours (NotImplemented)
            return None
        return _Plain(float(x), repr(x) if x >= 0 else f"({x!r})")

    def _binary(self, other, op, sym, prec, reverse=False):
        o = self._operand(other)
        if o is None:
            return NotImplemented
        a, b = (o, self) if reverse else (self, o)
        value = op(float(a), float(b))
        shadow = op(a.shadow, b.shadow)
        if not isinstance(value, float):
            return value
        # a plain 0 added (or subtracted from) and a plain 1 multiplied by leave the text alone
        # (0.0 + ut_beta reads ut_beta; the value is the same but for the sign of a zero)
        if isinstance(a, _Plain) and a.value == (1.0 if sym == "*" else 0.0) and sym in ("*", " + "):
            return Traced(value, shadow, b.text, b.prec, b.uses, self.record)
        if isinstance(b, _Plain) and b.value == (1.0 if sym in ("*", "/") else 0.0) and sym != "^":
            return Traced(value, shadow, a.text, a.prec, a.uses, self.record)
        text = f"{_wrap(a, prec)}{sym}{_wrap(b, prec, right=True)}"
        return Traced(value, shadow, text, prec, a.uses | b.uses, self.record)

    def __add__(self, o):
        return self._binary(o, float.__add__, " + ", _ADD)

    def __radd__(self, o):
        return self._binary(o, float.__add__, " + ", _ADD, True)

    def __sub__(self, o):
        return self._binary(o, float.__sub__, " - ", _ADD)

    def __rsub__(self, o):
        return self._binary(o, float.__sub__, " - ", _ADD, True)

    def __mul__(self, o):
        return self._binary(o, float.__mul__, "*", _MUL)

    def __rmul__(self, o):
        return self._binary(o, float.__mul__, "*", _MUL, True)

    def __truediv__(self, o):
        return self._binary(o, float.__truediv__, "/", _MUL)

    def __rtruediv__(self, o):
        return self._binary(o, float.__truediv__, "/", _MUL, True)

    def __pow__(self, o):
        # a ** b binds right to left: the left operand is wrapped at equal precedence
        r = self._binary(o, float.__pow__, "^", _POW + 0.5)
        if isinstance(r, Traced):
            r.prec = _POW
        return r

    def __rpow__(self, o):
        r = self._binary(o, float.__pow__, "^", _POW + 0.5, True)
        if isinstance(r, Traced):
            r.prec = _POW
        return r

    def __neg__(self):
        return Traced(-float(self), -self.shadow, "-" + _wrap(self, _NEG), _NEG, self.uses, self.record)

    def __pos__(self):
        return self

    def __abs__(self):
        return Traced(abs(float(self)), abs(self.shadow), f"|{self.text}|", _ATOM, self.uses, self.record)


class _Plain:
    """A plain number as an operand of a Traced operation (same in both builds)."""

    def __init__(self, value, text):
        self.value, self.shadow, self.text, self.uses = value, value, text, frozenset()
        self.prec = _ATOM

    def __float__(self):
        return self.value


def _wrap(x, prec, right=False):
    if isinstance(x, Traced):
        return x._wrap(prec, right)
    return f"({x.text})" if x.prec < prec or (right and x.prec == prec) else x.text


def traced_params(params: dict, names) -> tuple[dict, list]:
    """params with each float parameter in `names` (not 0, 1 or -1) replaced by a perturbed
    Traced value; and the record every Traced number computed from them is appended to."""
    record: list = []
    out = dict(params)
    for i, n in enumerate(sorted(names)):
        v = params[n]
        if type(v) is not float or v in _SPECIAL or not math.isfinite(v):
            continue
        factor = 1.0 + (i + 1) * STEP * math.sqrt(2.0)
        out[n] = Traced(v * factor, v, n, _ATOM, frozenset([n]), record)
    return out, record


def label(t: Traced) -> str:
    text = t.text if len(t.text) <= MAX_TEXT else "from " + ", ".join(sorted(t.uses))
    return text.replace("*/", "* /").replace("/*", "/ *")


def _same_shape(a: ca.Function, b: ca.Function) -> bool:
    if a.n_instructions() != b.n_instructions() or a.n_in() != b.n_in() or a.n_out() != b.n_out():
        return False
    for k in range(a.n_instructions()):
        if a.instruction_id(k) != b.instruction_id(k):
            return False
        if a.instruction_output(k) != b.instruction_output(k):
            return False
        if a.instruction_id(k) != ca.OP_CONST and a.instruction_input(k) != b.instruction_input(k):
            return False
    return True


def constant_names(baked: ca.Function, traced: ca.Function, record: list) -> dict[int, str] | None:
    """{instruction index: name} for the constants of `baked` that are provably a recorded
    parameter expression (module doc); None when the two kernels differ in shape."""
    if not _same_shape(baked, traced):
        return None
    by_value: dict[float, list] = {}
    for t in record:
        by_value.setdefault(float(t), []).append(t)
    names = {}
    for k in range(baked.n_instructions()):
        if baked.instruction_id(k) != ca.OP_CONST:
            continue
        c, c2 = baked.instruction_constant(k), traced.instruction_constant(k)
        if c == c2 or not (math.isfinite(c) and math.isfinite(c2)):
            continue
        found = {label(t) for t in by_value.get(c2, ()) if t.shadow == c}
        if len(found) == 1:
            names[k] = found.pop()
    return names
