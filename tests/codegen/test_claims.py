"""Claims about the generated builds, checked against counts made independently of the emitter.

- The operation counts in each manifest (per kernel, and per step path as the sum of its
  kernels) equal two independent counts: one made from the kernel objects' statements (what the
  MCU executes: the operators and calls of each expression tree, one select per branch-decided
  value; not the emitter's own cost labels), and one from CasADi's own instruction list of the
  same Function (OP_DIV/OP_INV, OP_SQRT/OP_HYPOT, the trigonometric and transcendental codes,
  OP_MUL/OP_SQ), for the categories that the emitter's select folding cannot change.
"""
from __future__ import annotations

import casadi as ca
import pytest

from ahrsgen.codegen.emit import ir
from ahrsgen.generate import config, render
from ahrsgen import filters
from ahrsgen.symbolic import quat
from conftest import RUNTIME_BUILDS, rendered



# ------------------------------------------------------------------ counting the kernel objects
_CMP_FUNCS = {"fabs", "floor", "ceil", "copysign"}
_SQRT_FUNCS = {"sqrt", "hypot"}
_TRIG_FUNCS = {"sin", "cos", "tan", "asin", "acos", "atan", "atan2", "exp", "log", "pow", "sinh", "cosh",
               "tanh", "asinh", "acosh", "atanh", "erf", "expm1", "log1p", "fmod"}
_OPERATORS = {"+": "add", "-": "add", "neg": "add", "*": "mul", "/": "div"}


def count_expr(e, real: str) -> dict[str, int]:
    """Operations of one right-hand side, read from its expression tree alone."""
    out = {"add": 0, "mul": 0, "div": 0, "sqrt": 0, "trig": 0, "cmp": 0}
    if isinstance(e, ir.Select):          # a select: one comparison (its operands are values)
        out["cmp"] += 1
        return out
    calls = [x for x in ir.walk(e) if isinstance(x, ir.Call)]
    for c in calls:
        f = c.fn.removeprefix("fast_")        # math = "fast": the emitter's own helpers
        base = f[:-1] if real == "float" and f.endswith("f") else f
        if base == "fma":                  # fma = true: one multiply and one add, rounded once
            out["mul"] += 1
            out["add"] += 1
        elif base in _CMP_FUNCS:
            out["cmp"] += 1
        elif base in _SQRT_FUNCS:
            out["sqrt"] += 1
        elif base in _TRIG_FUNCS:
            out["trig"] += 1
        else:
            raise AssertionError(f"unknown function {c.fn} in {ir.print_expr(e)!r}")
    if calls:                              # a sign flip of a call's operand is free (vfms)
        return out
    for x in ir.walk(e):
        if isinstance(x, ir.Op):
            if x.op not in _OPERATORS:
                raise AssertionError(f"operator {x.op} outside a flag or select in {ir.print_expr(e)!r}")
            out[_OPERATORS[x.op]] += 1
    return out


def kernel_counts(k, real: str) -> tuple[dict[str, int], int]:
    """(operation counts, temporaries) of a kernel from its statements, parts included. A value
    decided by a branch counts as one select, like one written as a conditional expression; so
    does a flag (`bool`: a comparison, or and/or/not on flags). fast_sincosf is one sin and one cos."""
    ops = {"add": 0, "mul": 0, "div": 0, "sqrt": 0, "trig": 0, "cmp": 0}
    temporaries = 0
    for f in k.functions():
        for s in ir.all_statements(f.body):
            if isinstance(s, ir.Let):
                temporaries += 1
                got = {"cmp": 1} if s.temp.ctype == "bool" else count_expr(s.expr, real)
            elif isinstance(s, ir.If):
                temporaries += len(s.declare)
                got = {"cmp": len(s.declare)}
            elif isinstance(s, ir.SinCos):
                temporaries += 2
                got = {"trig": 2}
            else:
                continue
            for c, n in got.items():
                ops[c] += n
    return ops, temporaries


def fresh(name: str, precision: str = "float", runtime: str = "", math: str | None = None,
          fma: bool = False) -> render.Generated:
    """A build of the filter rendered now (the committed default float one equals it:
    test_generated.py), so an emitter change is counted here before anything is committed."""
    return rendered(name, precision, runtime, math, fma)


@pytest.mark.parametrize("name", filters.names())
def test_manifest_op_counts_equal_the_kernel_statements(name):
    gen = fresh(name)
    man = gen.manifest
    by_c = {k.name: k for k in gen.kernels}
    assert {k["c_name"] for k in man["kernels"].values()} == set(by_c)
    for kname, k in man["kernels"].items():
        counted, temporaries = kernel_counts(by_c[k["c_name"]], man["precision"])
        assert counted == k["ops"], f"{name} kernel {kname}: manifest {k['ops']}, statements {counted}"
        assert k["total"] == sum(counted.values())
        assert k["temporaries"] == temporaries
    for pname, path in man["step_paths"].items():
        total = {c: sum(man["kernels"][kn]["ops"][c] for kn in path["kernels"]) for c in path["ops"]}
        assert path["ops"] == total, f"{name} path {pname!r}"
        assert path["total"] == sum(total.values())


# ------------------------------------------------------------------ counting CasADi's instructions
def _exact_reciprocal(c) -> bool:
    """c = +-2^k whose reciprocal a float holds exactly (a normal float)."""
    import math
    return c is not None and c != 0.0 and math.isfinite(c) and math.frexp(abs(c))[0] == 0.5 and \
        2.0 ** -126 <= abs(1.0 / c) <= 2.0 ** 127


def casadi_counts(fn: ca.Function) -> dict[str, int]:
    """div, sqrt, trig and mul-like counts from CasADi's instruction list (no emitter involved).
    Quotients by one computed denominator count as one division and a product each, as a
    hand-writer (and the emitter) writes them: r = 1 / d, x * r."""
    div = {ca.OP_DIV, ca.OP_INV}
    sqrt = {ca.OP_SQRT, ca.OP_HYPOT}
    trig = {ca.OP_SIN, ca.OP_COS, ca.OP_TAN, ca.OP_ASIN, ca.OP_ACOS, ca.OP_ATAN, ca.OP_ATAN2, ca.OP_EXP,
            ca.OP_LOG, ca.OP_POW, ca.OP_SINH, ca.OP_COSH, ca.OP_TANH, ca.OP_ASINH, ca.OP_ACOSH, ca.OP_ATANH,
            ca.OP_ERF, ca.OP_FMOD} | {getattr(ca, n) for n in ("OP_EXPM1", "OP_LOG1P") if hasattr(ca, n)}
    mul = {ca.OP_MUL, ca.OP_SQ}
    out = {"div": 0, "sqrt": 0, "trig": 0, "mul": 0}
    const = {}                         # work index -> constant it holds now (the work vector is reused)
    value = {}                         # work index -> the value it holds now: (instruction) or (input, nz)
    per_den: dict = {}                 # computed denominator value -> quotients by it
    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code == ca.OP_DIV and fn.instruction_input(k)[1] not in const:
            per_den[value[fn.instruction_input(k)[1]]] = per_den.get(value[fn.instruction_input(k)[1]], 0) + 1
        if code == ca.OP_CONSTPOW:
            # x^c with a constant exponent: 2 -> x*x, 3 -> x*x*x, 0.5 -> sqrt, -1 -> 1/x, else pow
            expo = const.get(fn.instruction_input(k)[1])
            cat, n = {2.0: ("mul", 1), 3.0: ("mul", 2), 0.5: ("sqrt", 1), -1.0: ("div", 1)}.get(expo, ("trig", 1))
            out[cat] += n
        elif code == ca.OP_DIV and _exact_reciprocal(const.get(fn.instruction_input(k)[1])):
            out["mul"] += 1            # x / 2^k is written x * 2^-k (the same value, a multiplication)
        elif code == ca.OP_DIV and fn.instruction_input(k)[1] not in const:
            pass                       # by a computed denominator: counted below, per denominator
        elif code in div:
            out["div"] += 1
        elif code in sqrt:
            out["sqrt"] += 1
        elif code in trig:
            out["trig"] += 1
        elif code in mul:
            out["mul"] += 1
        if code == ca.OP_CONST:
            const[fn.instruction_output(k)[0]] = fn.instruction_constant(k)
            value.pop(fn.instruction_output(k)[0], None)
        elif code != ca.OP_OUTPUT:
            for w in fn.instruction_output(k):
                const.pop(w, None)
                value[w] = (value[fn.instruction_input(k)[0]] if code == ca.OP_ASSIGN else
                            ("in",) + tuple(fn.instruction_input(k)) if code == ca.OP_INPUT else ("op", k))
    # quotients by one computed denominator share one reciprocal: 1 / d once, then x * (1 / d)
    for n in per_den.values():
        out["div"] += 1
        out["mul"] += n if n >= 2 else 0
    return out


# Runtime builds: the kernels read parameters through the context pointer, the counts must
# not change with that.
_BUILDS = [(n, p, r, m, f) for n in filters.names() for p in ("float", "double")
           for r in ("", RUNTIME_BUILDS.get(n, "")) for m in ((None, "libm") if p == "float" else (None,))
           for f in ((False, True) if p == "float" and m is None and not r else (False,))]
_BUILDS = sorted(set(_BUILDS), key=str)


@pytest.mark.parametrize("name,precision,runtime,math,fma", _BUILDS)
def test_statement_op_counts_equal_the_emitter_and_casadi(name, precision, runtime, math, fma):
    """Every kernel of every filter, float and double, default and runtime builds, libm and
    fast math, with and without fused multiply-adds: the counts made from the kernel's
    statements equal the emitter's own (Kernel.ops, the manifest's) and CasADi's instruction
    list of the Function it was emitted from (mul not with fma: a product read by two sums is
    multiplied again in each fmaf)."""
    gen = fresh(name, precision, runtime, math, fma)
    for k in gen.kernels:
        counted, temporaries = kernel_counts(k, precision)
        assert counted == k.ops, f"{k.name}: emitter {k.ops}, statements {counted}"
        assert temporaries == k.n_temporaries
        got = casadi_counts(k.source_fn)
        for c in ("div", "sqrt", "trig") + (() if fma else ("mul",)):
            assert counted[c] == got[c], f"{k.name}: statements {c} {counted[c]}, CasADi {got[c]}"


@pytest.mark.parametrize("name", filters.names())
def test_manifest_op_counts_equal_casadi_instruction_list(name):
    man = fresh(name).manifest
    cfg = config.resolve(name)
    with quat.series_precision(cfg.precision):     # the build's kernels: series cut for its precision
        kernels = list(cfg.spec.model(cfg.params).kernels())
    checked = 0
    for ks in kernels:
        got = casadi_counts(ks.function)
        ops = man["kernels"][ks.name]["ops"]
        for c in ("div", "sqrt", "trig", "mul"):
            assert ops[c] == got[c], f"{name} kernel {ks.name}: manifest {c} {ops[c]}, CasADi {got[c]}"
        checked += 1
    assert checked >= 1
