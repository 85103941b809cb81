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
FUNCTIONS = {"tan": math.tan, "sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}


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
    for lit, expr in pairs:
        if expr.startswith("from "):        # a long expression: only its parameters are named
            assert all(p in man["params"] for p in expr[5:].split(", ")), expr
            continue
        v = _evaluate(expr, man["params"])
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
    """ahrsgen generate mekf --set accel_angle_noise=0.05 (accel_noise_density = 0, so that the
    gravity variance is the parameter's alone): its square and nine times it, as float32
    literals computed here, stand beside their names; the default's are gone."""
    assert cli.main(["generate", "mekf", "--set", "accel_angle_noise=0.05", "--set", "accel_noise_density=0",
                     "-o", str(tmp_path)]) == 0
    capsys.readouterr()
    src = (tmp_path / "mekf.c").read_text()
    sq, nine = str(np.float32(0.05 ** 2)), str(np.float32(9 * 0.05 ** 2))
    assert f"{sq}f /* accel_angle_noise^2 */" in src
    assert f"{nine}f /* 9*accel_angle_noise^2 */" in src
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


def test_structural_constants_of_mekf_are_not_named():
    """mekf's fixed constants (S_PIVOT_MIN 1e-12, DT_Q_MIN 1e-9, the 0.01 of the series
    switch) are written bare, and no parameter of the defaults prints as one of them (none is
    named there); every name uses only parameters."""
    src = (REPO / "generated" / "mekf" / "mekf.c").read_text()
    for lit in ("1e-12f", "1e-09f", "0.01f"):
        assert re.search(rf"(?<![0-9.e]){re.escape(lit)}(?! /\*)", src), lit
    assert {e for lit, e in _named(src) if lit in ("1e-12f", "1e-09f", "0.01f")} == set()
    params = json.loads((REPO / "generated" / "mekf" / "manifest.json").read_text())["params"]
    for _, expr in _named(src):
        assert set(re.findall(r"[A-Za-z_]\w*", expr)) <= set(params) | set(FUNCTIONS), expr


def test_traced_text_and_values():
    """Expression text with the parentheses it needs; value (perturbed) and shadow (real)
    computed by the same operations."""
    p, record = traced_params({"a": 2.0, "b": 3.0, "n": 4}, ["a", "b"])
    a, b = p["a"], p["b"]
    assert isinstance(a, Traced) and p["n"] == 4 and float(a) != 2.0 and a.shadow == 2.0
    cases = {"(a + b)*a": (a + b) * a, "a - (b - a)": a - (b - a), "a/(a*b)": a / (a * b),
             "-a^2": -a ** 2, "9*a^2": 9 * a ** 2, "1 - a": 1 - a, "a*(-0.5)": a * -0.5,
             "(a^2)^b": (a ** 2) ** b, "a + b": 0.0 + a + b * 1 - 0.0}
    for text, t in cases.items():
        assert t.text == text
        assert t.shadow == eval(text.replace("^", "**"), {"a": 2.0, "b": 3.0})   # noqa: S307
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
    assert {consts[k] for k, v in names.items() if v == "a^2"} == {0.25}   # not b, which is 0.25 too
    assert sorted(consts.values()) == [0.25, 0.5, 2.0]       # 2.0: structural, unnamed
    # the real value must match as well: a record entry with the traced value but another shadow
    a2.shadow = 0.3
    assert sorted(constant_names(baked, traced, record).values()) == ["a"]
    # two expressions with the same values in both builds: ambiguous
    a2.shadow = 0.25
    twice = a2 * 2.0 / 2.0
    assert twice.text == "a^2*2.0/2.0" and (float(twice), twice.shadow) == (float(a2), a2.shadow)
    assert sorted(constant_names(baked, traced, record).values()) == ["a"]
    # b = 0.25 as well: CasADi merges the two equal constants of the baked build, not the traced ones
    assert constant_names(_fn([x, y], x * 0.25 + y * 0.25), _fn([x, y], x * a2 + y * b), record) is None


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
        names = {k: f"c{k}" for k in range(fn.n_instructions()) if fn.instruction_id(k) == ca.OP_CONST}
        for fma in (False, True):
            on = emit.emit(fn, "float", fma=fma, flags=ks.flags, names=names)
            off = emit.emit(fn, "float", fma=fma, flags=ks.flags)
            assert _words(on.source()) == _words(off.source()), ks.name
            assert on.branches == off.branches and on.ops == off.ops
            assert not names or "/* c" in on.source(), ks.name
