"""Names of folded parameters and named constants: which literal of a baked kernel is which
parameter expression or guard constant.

A baked build folds parameters into numbers (0.0049f is accel_angle_noise^2). To write the
expression beside the number, the model's kernels are built a second time with every float
parameter (except runtime ones and those at 0, 1, -1 or 2, where CasADi simplifies x * 1,
x + 0 and x * 2 and the graph would change shape) replaced by a `Traced` number: a float
whose value is the parameter slightly perturbed (a different factor per parameter), that
remembers its expression and also carries, as `shadow`, the value the same Python arithmetic
gives on the real parameters. The models' named constants (ahrsgen.constants: S_PIVOT_MIN,
a series coefficient 1/45) are traced the same way while that build runs (`tracing`), each
with a factor of its own. Every Traced number the model computes is recorded; one whose real
value is 0, 1, -1 or 2 is that plain number in both builds.

Names are given per use: for each operation of the baked kernel, each constant operand.
The traced kernel must compute the same operations in the same order on the same operands
(`_operations`: constants aside, which CasADi merges when equal, so a parameter equal to a
structural constant is one node in the baked build and two in the traced one). A constant
operand is named when its value differs between the two builds (it depends on a perturbed
number) and a recorded expression equals it in both: value == the traced constant and
shadow == the baked constant. A structural constant never changes; a constant CasADi
computed from a parameter and something else (x * (1 / p) written as x / p, a product of two
folded numbers) matches no recorded expression at two unrelated points and stays unnamed;
two recorded expressions that match alike leave it unnamed. A kernel whose operations CasADi
shaped by a value (two equal products merged, a parameter at 0.5 dividing) computes other
operations in the traced build: its numbers all stay bare. So a name is either right or
absent. The emitter (src/ahrsgen/codegen/emit, `names`) writes it as a comment beside the
literal; the arithmetic does not change.
"""
from __future__ import annotations

import contextlib
import math

import casadi as ca

from ahrsgen import constants as named

# Expressions longer than this are written as "from a, b" (the parameters they use).
MAX_TEXT = 40
# Relative perturbation of parameter i: (i + 1) * STEP * an irrational factor, so no two
# parameters (nor simple expressions of them) move alike.
STEP = 1e-6
# Values CasADi simplifies on: x * 1, x + 0, x * -1 (a negation), x * 2 (x + x). A parameter,
# named constant or derived value at one of them is not perturbed (the graph keeps its shape).
_SPECIAL = (0.0, 1.0, -1.0, 2.0)

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
        # a negated right operand is parenthesised too: a*(-b), not a*-b
        wrap = self.prec < prec or (right and (self.prec == prec or self.prec == _NEG) and prec != _ATOM)
        return f"({self.text})" if wrap else self.text

    @staticmethod
    def _operand(x):
        """(perturbed value, shadow, text, prec, uses) of an operand, or None (not a plain number)."""
        if isinstance(x, Traced):
            return x
        if isinstance(x, named.Const):       # a named constant read without use(): plain
            return _Plain(float(x), repr(float(x)) if x >= 0 else f"({float(x)!r})")
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
        if shadow in _SPECIAL:
            # 0, 1, -1 or 2 in the real build: the same number here, so that CasADi simplifies
            # x * 1 and x + 0 alike in both builds (the graphs keep one shape); not named
            return shadow
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
    """params with each float parameter in `names` (not 0, 1, -1 or 2) replaced by a perturbed
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


def _precedence(text: str) -> int:
    """How a named constant's text binds: a name, a signed number, a quotient like 1/45."""
    if text.isidentifier():
        return _ATOM
    if text.startswith("-"):
        return _NEG
    return _MUL if text.replace("/", "").replace("*", "").replace(".", "").isdigit() else _ADD


@contextlib.contextmanager
def tracing(record: list):
    """While the block runs, each named constant a model reads (ahrsgen.constants.use) is a
    Traced number appended to `record` as a parameter is: perturbed by a factor of its own
    ((j + 1) STEP sqrt(3) for the j-th name met, apart from every parameter's (i + 1) STEP
    sqrt(2)), its text its name. Constants at 0, 1, -1 or 2 stay plain (traced_params). A number
    named at build time (ahrsgen.constants.named) that is already Traced (computed from
    parameters) keeps its values and takes the name as its text; one computed by a function
    Traced arithmetic cannot follow (ahrsgen.constants.computed) is that function's value at the
    traced and at the real arguments."""
    order: dict[str, int] = {}

    def stand_in(name, v, real=None):
        if real is not None:                 # constants.computed: f of traced and of real values
            if real in _SPECIAL or not math.isfinite(real):
                return real
            return Traced(float(v), real, name, _precedence(name), frozenset([name]), record)
        if isinstance(v, Traced):            # computed from parameters: the same number, named
            v.text, v.prec = name, _precedence(name)
            return v
        v = float(v)
        if v in _SPECIAL or not math.isfinite(v):
            return v
        j = order.setdefault(name, len(order))
        factor = 1.0 + (j + 1) * STEP * math.sqrt(3.0)
        return Traced(v * factor, v, name, _precedence(name), frozenset([name]), record)
    before, named._tracer = named._tracer, stand_in
    try:
        yield record
    finally:
        named._tracer = before


def label(t: Traced) -> str:
    text = t.text if len(t.text) <= MAX_TEXT else "from " + ", ".join(sorted(t.uses))
    return text.replace("*/", "* /").replace("/*", "/ *")


def _operations(fn: ca.Function) -> tuple[list, list]:
    """The instructions of fn other than constants, as (operation, inputs/outputs it addresses,
    operands), an operand being "c" (a constant) or the position in this list of the operation
    that computed it; and, beside each, (its instruction, {operand: constant's instruction}).
    Two builds whose lists are equal compute the same operations on the same operands and
    differ at most in their constants, merged or not (CasADi merges equal ones)."""
    ops, where, source = [], [], {}
    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_CONST:
            source[fn.instruction_output(k)[0]] = ("c", k)
            continue
        if code == ca.OP_INPUT:
            addr, ins = tuple(fn.instruction_input(k)), []
        elif code == ca.OP_OUTPUT:
            addr, ins = tuple(fn.instruction_output(k)), fn.instruction_input(k)[:1]
        else:
            addr, ins = (), fn.instruction_input(k)
        operands = [source[w] for w in ins]
        ops.append((code, addr, tuple("c" if o[0] == "c" else o for o in operands)))
        where.append((k, {j: o[1] for j, o in enumerate(operands) if o[0] == "c"}))
        if code != ca.OP_OUTPUT:
            source[fn.instruction_output(k)[0]] = ("v", len(ops) - 1)
    return ops, where


def value_names(baked: list, traced: list) -> list:
    """The name of each number of `baked` (a state field's initial values) that its twin in
    `traced` (the same field of the traced build) provably is, by the rule for a kernel's
    constants: a Traced number whose value moved and whose real value is the baked number;
    None elsewhere."""
    return [label(t) if isinstance(t, Traced) and float(t) != float(v) and t.shadow == float(v) else None
            for v, t in zip(baked, traced)]


def constant_names(baked: ca.Function, traced: ca.Function, record: list) -> dict[tuple[int, int], str] | None:
    """{(instruction, operand): name} for the constants the operations of `baked` read that are
    provably a recorded expression (module doc); None when the two kernels compute different
    operations. Named per use: where the baked build merged a parameter with an equal
    structural constant, each use gets the name its traced twin has."""
    if baked.n_in() != traced.n_in() or baked.n_out() != traced.n_out():
        return None
    ops_b, where_b = _operations(baked)
    ops_t, where_t = _operations(traced)
    if ops_b != ops_t:
        return None
    by_value: dict[float, list] = {}
    for t in record:
        by_value.setdefault(float(t), []).append(t)
    names = {}
    for (k, consts_b), (_, consts_t) in zip(where_b, where_t):
        for j, kb in consts_b.items():
            c, c2 = baked.instruction_constant(kb), traced.instruction_constant(consts_t[j])
            if c == c2 or not (math.isfinite(c) and math.isfinite(c2)):
                continue
            found = {label(t) for t in by_value.get(c2, ()) if t.shadow == c}
            if len(found) == 1:
                names[(k, j)] = found.pop()
    return names
