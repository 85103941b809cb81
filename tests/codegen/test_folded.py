"""Folded parameters carry their names (src/ahrsgen/codegen/folded.py): `0.0049f /* accel_angle_noise^2 */`.

Checked against things the naming does not decide: the C without comments (the build with
naming off), the numbers a parameter expression gives when evaluated here in Python from the
manifest's parameters, and a parameter set equal to the structural constants around it.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ahrsgen import cli
from ahrsgen.generate import config, render
from ahrsgen.codegen.folded import Traced, traced_params
from conftest import REPO

# a literal of the emitter (float or double) followed by its name
NAMED = re.compile(r"(\(-?[0-9.e+-]+f?\)|[0-9][0-9.e+-]*f?) /\* ([^*]+(?:\*[^/][^*]*)*) \*/")
COMMENT = re.compile(r" ?/\*.*?\*/", re.S)


# functions a template's derived constant may name (e.g. `tan(course_max_sideslip)^2`)
FUNCTIONS = {"tan": math.tan, "sin": math.sin, "cos": math.cos, "sqrt": math.sqrt, "ln": math.log}


def _named_constants() -> dict[str, float]:
    """Every named constant (ahrsgen.constants.Const) the package's modules declare, by name:
    the value a name stands for is the one its declaration states."""
    import importlib
    from ahrsgen.constants import Const
    modules = ["ahrsgen.constants"] + [f"ahrsgen.symbolic.{m}" for m in ("aiding", "attitude", "kalman", "linalg", "quat")]
    modules += [f"ahrsgen.filters.{f}.{m}" for f in ("qcf", "mekf", "adukf", "cpf") for m in ("model", "reference")]
    out: dict[str, float] = {}
    for m in modules + ["ahrsgen.filters.cpf.prng"]:
        for v in vars(importlib.import_module(m)).values():
            for c in (v if isinstance(v, tuple) else (v,)):
                if isinstance(c, Const):
                    assert out.setdefault(c.name, float(c)) == float(c), c.name
    return out


def _ut_weights(params: dict, n: int) -> dict[str, float]:
    """adukf's UT_A and UT_W from the scaled unscented transform's equations (Wan and van der
    Merwe): lambda = alpha^2 (n + kappa) - n, spread sqrt(n + lambda), W_i = 1 / (2 (n + lambda))."""
    lam = params["ut_alpha"] ** 2 * (n + params["ut_kappa"]) - n
    return {"UT_A": math.sqrt(n + lam), "UT_W": 1 / (2 * (n + lam))}


def _named(text: str) -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in NAMED.finditer(text)]


def _value(literal: str) -> float:
    return float(literal.strip("()").rstrip("f"))


def _evaluate(expr: str, params: dict) -> float:
    """A name read back as arithmetic on the parameter values (Python doubles)."""
    code = re.sub(r"\|([^|]+)\|", r"abs(\1)", expr).replace("^", "**")
    return eval(code, {"__builtins__": {}, "abs": abs, **FUNCTIONS}, dict(params))   # noqa: S307 - our own text


@pytest.mark.parametrize("name", ["qcf", "mekf", "adukf", "cpf"])
def test_every_committed_name_evaluates_to_the_number_beside_it(name):
    """Each name in generated/<name>, evaluated from the parameters in its manifest, rounds to
    the literal it stands beside (the literal's precision); and every filter names some."""
    man = json.loads((REPO / "generated" / name / "manifest.json").read_text())
    src = (REPO / "generated" / name / man["files"]["source"]).read_text()
    pairs = _named(src)
    assert pairs, f"no named literal in generated/{name}"
    # the named constants' declared values; adukf's weights of its error-state filter (n = 6)
    known = {**_named_constants(), **man["params"], **(_ut_weights(man["params"], 6) if name == "adukf" else {})}
    for lit, expr in pairs:
        if expr.startswith("from "):        # a long expression: only its parameters are named
            assert all(p in known for p in expr[5:].split(", ")), expr
            continue
        v = _evaluate(expr, known)
        if lit.rstrip(")").endswith("f"):
            assert np.float32(_value(lit)) == np.float32(v), (lit, expr, v)
        else:
            assert _value(lit) == v, (lit, expr, v)


def _render(name, names=True, **kw):
    gen = render.render(config.resolve(name, **kw), names=names)
    return gen.files[f"{gen.manifest['prefix']}.c"]


@pytest.mark.parametrize("name,kw", [("mekf", {}), ("qcf", {"runtime": "kp", "precision": "double"})],
                         ids=["mekf", "qcf-runtime-double"])
def test_names_change_no_arithmetic(name, kw):
    """Without its comments the C is the build with naming off, word for word (the lines break
    elsewhere: a name beside a number can carry a statement past 100 columns)."""
    on, off = _render(name, **kw), _render(name, names=False, **kw)
    assert _named(on) and not _named(off)
    assert _words(on) == _words(off)


def _words(c: str) -> list[str]:
    """The C without its comments, as words (line breaks and indentation left out)."""
    return COMMENT.sub("", c).split()


def test_a_set_parameter_moves_its_named_number(tmp_path, capsys):
    """ahrsgen generate mekf --set accel_angle_noise=0.05 (accel_noise_density = 0 and no GPS -
    magnetometer heading, no motion compensation - so that the gravity variance is the
    parameter's alone, without the unobserved-turn term of a stale GPS velocity; the residual
    adaptation, not written at accel_adapt_cap 1, divides by accel_adapt_sigmas² times it, set
    to 1.5 here): its square and (1.5 times it)², as float32 literals computed here, stand beside
    their names; the default's are gone."""
    assert cli.main(["generate", "mekf", "--set", "accel_angle_noise=0.05", "--set", "accel_noise_density=0",
                     "--set", "heading_source=mag", "--set", "motion_comp=none", "--set", "accel_adapt_cap=3",
                     "--set", "accel_adapt_sigmas=1.5", "-o", str(tmp_path)]) == 0
    capsys.readouterr()
    src = (tmp_path / "mekf.c").read_text()
    sq, prod = str(np.float32(0.05 ** 2)), str(np.float32((1.5 * 0.05) ** 2))
    assert f"{sq}f /* accel_angle_noise^2 */" in src
    assert f"{prod}f /* from accel_adapt_sigmas, accel_angle_noise */" in src
    assert "0.0049f" not in src and "/* accel_noise_density" not in src     # no density term left


def test_a_parameter_equal_to_structural_constants_is_not_named_with_them():
    """examples/madgwick with beta = 0.5, the value of the structural halves of q_dot = 0.5 q (x) w:
    every 0.5f is either structural, bare as many times as in the default build (beta = 0.1),
    or one of beta's uses, and beta's name stands beside 0.5f only."""
    folder = str(REPO / "examples" / "madgwick")
    default, half = _render(folder), _render(folder, sets=["beta=0.5"])
    n = default.count("0.1f /* beta */")
    assert n > 0 and default.count("/* beta */") == n
    named = half.count("0.5f /* beta */")
    assert half.count("/* beta */") == named
    bare = re.compile(r"(?<![0-9.e])0\.5f(?! /\*)")
    assert len(bare.findall(default)) > 0
    assert len(bare.findall(half)) + named == len(bare.findall(default)) + n


def test_structural_constants_of_mekf_carry_their_own_names():
    """mekf's fixed constants (S_PIVOT_MIN 1e-12, DT_Q_MIN 1e-9, the 0.01 of the series
    switch) are never bare and never named by a parameter: each stands beside its own name
    only; every name uses only parameters and named constants."""
    src = (REPO / "generated" / "mekf" / "mekf.c").read_text()
    # the code (a kernel's comment block quotes its branch conditions bare)
    src = "\n".join(ln for ln in src.splitlines() if not ln.lstrip().startswith(("*", "/*")))
    own = {"1e-12f": {"S_PIVOT_MIN", "HARD_IRON_PIVOT_MIN"}, "1e-09f": {"DT_Q_MIN"}, "0.01f": {"SERIES_MAX*SERIES_MAX"}}
    for lit, names in own.items():
        assert not re.search(rf"(?<![0-9.e]){re.escape(lit)}(?! /\*)", src), lit
        assert {e for x, e in _named(src) if x == lit} == names, lit
    params = json.loads((REPO / "generated" / "mekf" / "manifest.json").read_text())["params"]
    for _, expr in _named(src):
        words = set(re.findall(r"[A-Za-z_]\w*", expr))
        assert words <= set(params) | set(FUNCTIONS) | set(_named_constants()), expr


def test_traced_text_and_values():
    """Expression text with the parentheses it needs; value (perturbed) and shadow (real)
    computed by the same operations."""
    p, record = traced_params({"a": 1.25, "b": 3.0, "n": 4, "two": 2.0}, ["a", "b", "two"])
    a, b = p["a"], p["b"]
    assert isinstance(a, Traced) and p["n"] == 4 and float(a) != 1.25 and a.shadow == 1.25
    # 2 (as 0, 1 and -1) is not perturbed, nor is what is 1 in the real build: CasADi simplifies x * 2
    assert p["two"] == 2.0 and not isinstance(p["two"], Traced)
    assert type(a / a) is float and a / a == 1.0 and type(a - a) is float
    cases = {"(a + b)*a": (a + b) * a, "a - (b - a)": a - (b - a), "a/(a*b)": a / (a * b),
             "-a^2": -a ** 2, "9*a^2": 9 * a ** 2, "1 - a": 1 - a, "a*(-0.5)": a * -0.5,
             "(a^2)^b": (a ** 2) ** b, "a + b": 0.0 + a + b * 1 - 0.0}
    for text, t in cases.items():
        assert t.text == text
        assert t.shadow == eval(text.replace("^", "**"), {"a": 1.25, "b": 3.0})   # noqa: S307
        assert float(t) == eval(text.replace("^", "**"), {"a": float(a), "b": float(b)})   # noqa: S307
    assert len(record) >= len(cases)


def _fn(inputs, out):
    import casadi as ca
    return ca.Function("k", inputs, [out], {"cse": True, "live_variables": False})


def test_constant_names_rule():
    """A literal is named when it changes between the builds and the traced value and its real
    (shadow) value both match one recorded expression; never a structural constant, a value
    two expressions share, or a perturbed value whose real value differs."""
    import casadi as ca
    from ahrsgen.codegen.folded import constant_names
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    p, record = traced_params({"a": 0.5, "b": 0.25}, ["a", "b"])
    a, b = p["a"], p["b"]
    a2 = a ** 2
    baked = _fn([x, y], x * 0.25 + y * 0.5 + 2.0)
    traced = _fn([x, y], x * a2 + y * a + 2.0)
    names = constant_names(baked, traced, record)
    consts = {k: baked.instruction_constant(k) for k in range(baked.n_instructions())
              if baked.instruction_id(k) == ca.OP_CONST}
    assert sorted(names.values()) == ["a", "a^2"]
    assert {_operand_value(baked, k, j) for (k, j), v in names.items() if v == "a^2"} == {0.25}   # not b (0.25 too)
    assert sorted(consts.values()) == [0.25, 0.5, 2.0]       # 2.0: structural, unnamed
    # the real value must match as well: a record entry with the traced value but another shadow
    a2.shadow = 0.3
    assert sorted(constant_names(baked, traced, record).values()) == ["a"]
    # two expressions with the same values in both builds: ambiguous
    a2.shadow = 0.25
    twice = a2 * 2.0 / 2.0
    assert twice.text == "a^2*2.0/2.0" and (float(twice), twice.shadow) == (float(a2), a2.shadow)
    assert sorted(constant_names(baked, traced, record).values()) == ["a"]
    # b = 0.25 as well: CasADi merges the two equal constants of the baked build, not the traced
    # ones; each use is still named for what it is there
    p, record = traced_params({"a": 0.5, "b": 0.25}, ["a", "b"])
    a2, b = p["a"] ** 2, p["b"]
    merged = _fn([x, y], x * 0.25 + y * 0.25)
    assert sum(merged.instruction_id(k) == ca.OP_CONST for k in range(merged.n_instructions())) == 1
    names = constant_names(merged, _fn([x, y], x * a2 + y * b), record)
    assert sorted(names.values()) == ["a^2", "b"]
    assert {_operand_name(merged, k): v for (k, j), v in names.items()} == {"i0": "a^2", "i1": "b"}
    # other operations (here y * 0.25 and x * 0.25 become one product when x and y are one
    # input): nothing is named
    assert constant_names(_fn([x], x * 0.25 + x * 0.25), _fn([x], x * a2 + x * b), record) is None


def _operand_value(fn, k, j):
    """The constant operand j of instruction k."""
    import casadi as ca
    w = fn.instruction_input(k)[j]
    for i in range(k):
        if fn.instruction_output(i)[0] == w and fn.instruction_id(i) == ca.OP_CONST:
            src = i
    return fn.instruction_constant(src)


def _operand_name(fn, k):
    """The input (by name) the other operand of a binary instruction k reads, directly."""
    import casadi as ca
    ins = fn.instruction_input(k)
    for i in range(k):
        if fn.instruction_id(i) == ca.OP_INPUT and fn.instruction_output(i)[0] in ins:
            return fn.name_in(fn.instruction_input(i)[0])


@pytest.mark.parametrize("name", ["qcf", "mekf"])
def test_naming_every_constant_changes_no_arithmetic(name):
    """The emitter with a name on every constant of every kernel (true/false selects, if/else
    conditions, powers, reciprocals, fused multiply-adds, split kernels) writes the same C once
    the comments are gone."""
    import casadi as ca
    from ahrsgen.codegen import emit
    from ahrsgen import filters
    from ahrsgen.codegen.model import KernelSpec
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    own = KernelSpec("own", emit.function("own", {"x": x, "y": y}, {"o": ca.vertcat(
        ca.constpow(x, 3.0), ca.constpow(y, 2.5), x / 4.0, ca.if_else(x > 0.5, 1.0, 0.0) * y)}), "")
    for ks in filters.load(name).model().kernels() + [own]:
        fn = ks.function
        consts = {fn.instruction_output(k)[0] for k in range(fn.n_instructions()) if fn.instruction_id(k) == ca.OP_CONST}
        names = {(k, j): f"c{k}_{j}" for k in range(fn.n_instructions())
                 if fn.instruction_id(k) not in (ca.OP_CONST, ca.OP_INPUT)
                 for j, w in enumerate(fn.instruction_input(k)) if w in consts}
        for fma in (False, True):
            on = emit.emit(fn, "float", fma=fma, flags=ks.flags, names=names)
            off = emit.emit(fn, "float", fma=fma, flags=ks.flags)
            assert _words(on.source()) == _words(off.source()), ks.name
            assert on.branches == off.branches and on.ops == off.ops
            assert not names or "/* c" in on.source(), ks.name


def _kernel_literals(k):
    """Every literal (ir.Lit) the kernel's code reads, its parts' included."""
    from ahrsgen.codegen.emit import ir
    return [x for f in k.functions() for s in ir.all_statements(f.body) for e in ir.exprs(s)
            for x in ir.walk(e) if isinstance(x, ir.Lit)]


# Literals that may stand bare in a kernel: small whole numbers (|n| <= 10: the 2 of x + x, the
# 4 of a Jacobian, the 9 of a 3-sigma gate), halves and quarters (1/2 q (x) w, dt^2/4). Every
# other number is a folded parameter or a named constant (ahrsgen.constants) and says so.
def _structural(v: float) -> bool:
    return (v == int(v) and abs(v) <= 10) or abs(v) in (0.5, 0.25)


def _builds():
    from ahrsgen import filters
    return [(n, p) for n in ("qcf", "mekf", "adukf", "cpf") for p in [None] + sorted(filters.load(n).presets())]


@pytest.mark.parametrize("name,preset", _builds())
def test_no_bare_constant_in_any_kernel(name, preset):
    """Every literal of every kernel of the default build and of each preset is structural
    (above) or named, and each name, evaluated from the build's parameters and the named
    constants' declared values, is the number beside it (float32)."""
    cfg = config.resolve(name, preset=preset)
    gen = render.render(cfg)
    known = {**_named_constants(), **cfg.params}
    if name == "adukf":
        from ahrsgen.filters.adukf.model import Model
        known.update(_ut_weights(cfg.params, Model(cfg.params).n))
    bare, checked = [], 0
    for k in gen.kernels:
        for lit in _kernel_literals(k):
            if lit.value is None or (lit.name is None and _structural(lit.value)):
                continue
            if lit.name is None:
                bare.append((k.name, lit.text))
            elif not lit.name.startswith("from "):
                assert np.float32(_evaluate(lit.name, known)) == np.float32(lit.value), (k.name, lit)
                checked += 1
    assert bare == [] and checked > 0


def test_a_parameter_equal_to_a_structural_constant_leaves_the_kernel_named():
    """qcf's hard iron kernel with mag_bias_jump at its default 0.2, the value of the kernel's
    own residual low-pass HARD_IRON_RES_TAU (CasADi merges the two into one constant): its
    literals carry the same names as with mag_bias_jump = 0.25 (apart from it), mag_bias_rw^2
    among them at the value computed here, and 0.2 stands for each where it is each.
    (On 37ffcd0 every number of this kernel was bare: naming was all or nothing per kernel.)"""
    def hard_iron(**sets):
        gen = render.render(config.resolve("qcf", sets=[f"{k}={v}" for k, v in sets.items()]))
        return next(k for k in gen.kernels if k.name.endswith("_hard_iron")), gen.manifest["params"]
    merged, params = hard_iron()
    apart, _ = hard_iron(mag_bias_jump=0.25)
    assert params["mag_bias_jump"] == 0.2
    names = sorted(x.name for x in _kernel_literals(merged) if x.name)
    assert "mag_bias_jump" in names and names == sorted(x.name for x in _kernel_literals(apart) if x.name)
    assert str(np.float32(params['mag_bias_rw'] ** 2)) + "f /* mag_bias_rw^2 */" in merged.source()
    assert "0.2f /* mag_bias_jump */" in merged.source() and "0.25f /* mag_bias_jump */" in apart.source()
    assert merged.source().count("0.2f /* HARD_IRON_RES_TAU */") == apart.source().count("0.2f /* HARD_IRON_RES_TAU */") > 0


@pytest.mark.parametrize("name,preset", _builds())
def test_initial_state_values_are_named(name, preset):
    """Each initial value <prefix>_init writes (s->P[0] = 0.0625f /* (0.5*p0_att)^2 */;) is
    structural or named, the name evaluating to it (float32) from the build's parameters and
    the named constants; adukf's configured field reference (cos and sin of the inclination,
    made by math.*, which the traced build does not follow) excepted."""
    cfg = config.resolve(name, preset=preset)
    gen = render.render(cfg)
    src = gen.files[f"{gen.manifest['prefix']}.c"]
    body = src[src.index(f"void {gen.manifest['prefix']}_init("):]
    body = body[:body.index("\n}\n")]
    known = {**_named_constants(), **cfg.params}
    bare = []
    for target, lit, expr in re.findall(r"(s->\w+(?:\[\w+\])?) = (\(?-?[0-9][0-9.e+-]*f?\)?)(?: /\* (.+?) \*/)?;", body):
        v = _value(lit)
        if expr:
            assert np.float32(_evaluate(expr, known)) == np.float32(v), (target, lit, expr)
        elif not _structural(v) and not target.startswith("s->m_ref"):
            bare.append((target, lit))
    assert bare == []
