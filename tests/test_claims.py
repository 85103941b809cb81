"""Claims about the generated builds, checked against counts made independently of the emitter.

- The operation counts in each manifest (per kernel, and per step path as the sum of its
  kernels) equal two independent counts: one read from the emitted C text of each kernel (what
  the MCU executes: one classified operation per temporary, operators counted), and one from
  CasADi's own instruction list of the same Function (OP_DIV/OP_INV, OP_SQRT/OP_HYPOT, the
  trigonometric and transcendental codes, OP_MUL/OP_SQ), for the categories that the emitter's
  select folding cannot change.
"""
from __future__ import annotations

import functools
import json
import re

import casadi as ca
import pytest

from ahrsgen.generate import config, render
from ahrsgen import filters



# ------------------------------------------------------------------ counting the emitted C
_LITERAL = re.compile(r"\(-?(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?f?\)|(?<![\w.])(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?f?(?![\w.])")
_CALL = re.compile(r"\b([a-z][a-z0-9_]*)\(")
_CMP_FUNCS = {"fabs", "floor", "ceil", "copysign"}
_SQRT_FUNCS = {"sqrt", "hypot"}
_TRIG_FUNCS = {"sin", "cos", "tan", "asin", "acos", "atan", "atan2", "exp", "log", "pow", "sinh", "cosh",
               "tanh", "asinh", "acosh", "atanh", "erf", "expm1", "log1p", "fmod"}


def count_c_ops(expr: str, real: str) -> dict[str, int]:
    """Operations of one emitted right-hand side, read from the C text alone."""
    out = {"add": 0, "mul": 0, "div": 0, "sqrt": 0, "trig": 0, "cmp": 0}
    if "?" in expr:                       # a select: one comparison (its operands are temporaries)
        out["cmp"] += 1
        return out
    calls = _CALL.findall(expr)
    for c in calls:
        c = c.removeprefix("fast_")        # math = "fast": the emitter's own helpers
        base = c[:-1] if real == "float" and c.endswith("f") else c
        if base == "fma":                  # fma = true: one multiply and one add, rounded once
            out["mul"] += 1
            out["add"] += 1
            continue
        if base in _CMP_FUNCS:
            out["cmp"] += 1
        elif base in _SQRT_FUNCS:
            out["sqrt"] += 1
        elif base in _TRIG_FUNCS:
            out["trig"] += 1
        else:
            raise AssertionError(f"unknown function {c} in {expr!r}")
    if calls:
        return out
    bare = _LITERAL.sub("L", expr)
    out["div"] += bare.count("/")
    out["mul"] += bare.count("*")
    out["add"] += bare.count("+") + bare.count("-")
    return out


def kernel_bodies(src: str, prefix: str) -> dict[str, list[str]]:
    """{kernel name: right-hand sides of its temporaries} from a generated source.

    A split kernel's parts (<kernel>_part<N>) count as the kernel. A select written as a
    branch is declared without a value (`float tmpN;`) and assigned on each side: it counts
    as one select ("? :"), like one written as a conditional expression; so does a flag
    (`bool`: a comparison, or and/or/not on flags, written without `?`). A sine and a cosine
    of one argument computed by one call, `fast_sincosf(a, &tmpS, &tmpC)` after the
    declarations `float tmpS; float tmpC;`, are two temporaries: one sin, one cos."""
    out: dict[str, list[str]] = {}
    for m in re.finditer(rf"static (?:inline )?void {prefix}_k_(\w+)\([^)]*\)\n\{{\n(.*?)\n\}}", src, re.S):
        name = re.sub(r"_part\d+$", "", m.group(1))
        rhs = out.setdefault(name, [])
        paired = {t for pair in re.findall(r"fast_sincosf\(.+, &(tmp\d+), &(tmp\d+)\);", m.group(2)) for t in pair}
        for ln in m.group(2).splitlines():
            call = re.match(r"\s*fast_sincosf\((.+), &tmp\d+, &tmp\d+\);", ln)
            declared = re.fullmatch(r"\s*float (tmp\d+);", ln)
            if call:
                rhs += [f"fast_sinf({call.group(1)})", f"fast_cosf({call.group(1)})"]
            elif declared and declared.group(1) in paired:
                continue
            elif re.match(r"\s*const bool tmp\d+ = ", ln):
                rhs.append("flag ? 1 : 0")       # a flag (comparison or logic on flags): one cmp
            elif re.match(r"\s*const \w+ tmp\d+ = ", ln):
                # a folded parameter's name rides in a comment (0.15f /* 0.5*kp */): not an operation
                rhs.append(re.sub(r"/\*.*?\*/", "", ln.split(" = ", 1)[1]).rstrip(";"))
            elif re.fullmatch(r"\s*(float|double|bool) tmp\d+;", ln):
                rhs.append("branch ? taken : other")
    return out


@functools.cache
def fresh(name: str) -> tuple[dict, str]:
    """(manifest, source) of the default float build rendered now (the committed one equals it:
    test_generated.py), so an emitter change is counted here before anything is committed."""
    cfg = config.resolve(name)
    files = render.render(cfg).files
    man = json.loads(files["manifest.json"])
    return man, files[man["files"]["source"]]


@pytest.mark.parametrize("name", filters.names())
def test_manifest_op_counts_equal_the_emitted_c(name):
    man, src = fresh(name)
    bodies = kernel_bodies(src, man["prefix"])
    assert set(bodies) == set(man["kernels"]), (sorted(bodies), sorted(man["kernels"]))
    for name, k in man["kernels"].items():
        counted = {c: 0 for c in k["ops"]}
        for expr in bodies[name]:
            for c, n in count_c_ops(expr, man["precision"]).items():
                counted[c] += n
        assert counted == k["ops"], f"{name} kernel {name}: manifest {k['ops']}, emitted C {counted}"
        assert k["total"] == sum(counted.values())
        assert k["temporaries"] == len(bodies[name])
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


@pytest.mark.parametrize("name", filters.names())
def test_manifest_op_counts_equal_casadi_instruction_list(name):
    man, _ = fresh(name)
    cfg = config.resolve(name)
    model = cfg.spec.model(cfg.params)
    checked = 0
    for ks in model.kernels():
        got = casadi_counts(ks.function)
        ops = man["kernels"][ks.name]["ops"]
        for c in ("div", "sqrt", "trig", "mul"):
            assert ops[c] == got[c], f"{name} kernel {ks.name}: manifest {c} {ops[c]}, CasADi {got[c]}"
        checked += 1
    assert checked >= 1
