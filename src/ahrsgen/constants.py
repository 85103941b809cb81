"""Physical constants shared by models and references (same values as ahrsgen.sim.log), and
named constants: the guard and structural numbers of the models (a floor under a divisor, a
tolerance, a time constant, a series coefficient) declared with a name, so that the generated
C writes the name beside the literal as it writes a folded parameter's:
`1e-12f /* S_PIVOT_MIN */`, `0.022222223f /* 1/45 */`.

    S_PIVOT_MIN = Const("S_PIVOT_MIN", 1e-12)       # a float: NumPy references use it as is
    s_safe = ca.fmax(s, use(S_PIVOT_MIN))            # a model's arithmetic reads it through use()

use(c) is c's value. While src/ahrsgen/codegen/folded.py builds a model's kernels a second time
to name their literals (its `tracing`), use(c) returns the tracer's stand-in instead: a number
perturbed like a folded parameter that remembers c's name. The names then follow the one rule
for parameters (right or absent), and the arithmetic of the real build does not change. A
constant at 0, 1, -1 or 2 is not worth a name (CasADi simplifies x * 1, x + 0 and x * 2):
it is written bare. A name is an identifier or a number's own text (1/45, -2/945), which reads
back as its value.
"""
from __future__ import annotations

# Set by ahrsgen.codegen.folded.tracing while the traced build runs: Const -> stand-in.
_tracer = None


class Const(float):
    """A number with a name (a float everywhere; a model's SX arithmetic reads it via use)."""

    def __new__(cls, name: str, value: float):
        obj = float.__new__(cls, value)
        obj.name = name
        return obj

    def __reduce__(self):
        return (Const, (self.name, float(self)))


def use(c):
    """The value a model's arithmetic uses for c: float(c), or during a traced build the
    tracer's stand-in for a Const (a plain number is returned as it is)."""
    if isinstance(c, Const):
        return float(c) if _tracer is None else _tracer(c.name, float(c))
    return c


def named(name: str, x):
    """A number the model computes at build time (a weight of the unscented transform from
    its parameters) read under a name, as use(Const(name, x)): x itself, or during a traced
    build x under that name (x traced from parameters keeps their perturbation)."""
    return x if _tracer is None else _tracer(name, x)


def computed(name: str, f, *args):
    """f(*args), a number the model computes at build time with a function the traced build
    cannot follow (math.tan of a parameter), read under a name: during a traced build, f of the
    arguments as traced (perturbed) and, as its real value, f of their real values."""
    if _tracer is None:
        return f(*args)
    return _tracer(name, f(*args), f(*(float(getattr(a, "shadow", a)) for a in args)))


G0 = Const("G0", 9.80665)  # standard gravity, m/s^2
