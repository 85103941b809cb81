"""The emitter on its own: every supported CasADi operation, emitted, compiled and run in C,
equals CasADi's own numeric evaluation; unsupported operations fail with their name."""
from __future__ import annotations

import ctypes
import re
import subprocess

import casadi as ca
import numpy as np
import pytest

from ahrsgen.sim.host import STRICT, cc
from ahrsgen.codegen import emit
from conftest import REPO

x = ca.SX.sym("x")
y = ca.SX.sym("y")

# (name, expression, domain of x, domain of y)
CASES = [
    ("add", x + y, (-3, 3), (-3, 3)), ("sub", x - y, (-3, 3), (-3, 3)),
    ("mul", x * y, (-3, 3), (-3, 3)), ("div", x / y, (-3, 3), (0.5, 3)),
    ("neg", -x, (-3, 3), None), ("sq", x * x, (-3, 3), None), ("twice", 2 * x, (-3, 3), None),
    ("inv", 1 / x, (0.5, 3), None), ("sqrt", ca.sqrt(x), (0.1, 9), None),
    ("fabs", ca.fabs(x), (-3, 3), None), ("floor", ca.floor(x), (-3, 3), None), ("ceil", ca.ceil(x), (-3, 3), None),
    ("sign", ca.sign(x), (-3, 3), None), ("sin", ca.sin(x), (-3, 3), None), ("cos", ca.cos(x), (-3, 3), None),
    ("tan", ca.tan(x), (-1.2, 1.2), None), ("asin", ca.asin(x), (-0.99, 0.99), None),
    ("acos", ca.acos(x), (-0.99, 0.99), None), ("atan", ca.atan(x), (-3, 3), None),
    ("exp", ca.exp(x), (-3, 3), None), ("log", ca.log(x), (0.1, 9), None),
    ("sinh", ca.sinh(x), (-2, 2), None), ("cosh", ca.cosh(x), (-2, 2), None), ("tanh", ca.tanh(x), (-2, 2), None),
    ("asinh", ca.asinh(x), (-3, 3), None), ("acosh", ca.acosh(x), (1.1, 4), None),
    ("atanh", ca.atanh(x), (-0.9, 0.9), None), ("erf", ca.erf(x), (-2, 2), None),
    ("atan2", ca.atan2(x, y), (-3, 3), (-3, 3)), ("pow", x ** y, (0.5, 3), (-2, 2)),
    ("constpow", x ** 2.5, (0.5, 3), None), ("constpow2", x ** 3, (-3, 3), None),
    ("fmod", ca.fmod(x, y), (-3, 3), (0.5, 2)), ("copysign", ca.copysign(x, y), (-3, 3), (-3, 3)),
    ("hypot", ca.hypot(x, y), (-3, 3), (-3, 3)),
    ("expm1", ca.expm1(x), (-2, 2), None), ("log1p", ca.log1p(x), (-0.9, 3), None),
    ("fmin", ca.fmin(x, y), (-3, 3), (-3, 3)), ("fmax", ca.fmax(x, y), (-3, 3), (-3, 3)),
    ("lt", x < y, (-3, 3), (-3, 3)), ("le", x <= y, (-3, 3), (-3, 3)),
    ("eq", x == ca.floor(y), (-1, 1), (-1, 1)), ("ne", x != y, (-3, 3), (-3, 3)),
    ("not", ca.logic_not(x < y), (-3, 3), (-3, 3)), ("and", ca.logic_and(x < 0, y < 0), (-3, 3), (-3, 3)),
    ("or", ca.logic_or(x < 0, y < 0), (-3, 3), (-3, 3)),
    ("if_else", ca.if_else(x < y, ca.sin(x), ca.cos(y)), (-3, 3), (-3, 3)),
    ("if_else_zero", ca.if_else(x < 0, x * y, 0), (-3, 3), (-3, 3)),
    ("shared", ca.sin(x * y) * ca.cos(x * y) + (x * y) ** 2, (-2, 2), (-2, 2)),
]


def _build(kernels, precision, tmp_path):
    src = tmp_path / f"k_{precision}.c"
    body = "#include <math.h>\n#include <stdbool.h>\n\n" + "\n\n".join(k.source(storage="") for k in kernels) + "\n"
    src.write_text(body)
    lib = tmp_path / f"k_{precision}.so"
    # -Wno-missing-prototypes style noise does not apply: these are plain external functions.
    cmd = [cc(), *STRICT, "-O2", "-fPIC", "-shared", "-ffp-contract=off", "-o", str(lib), str(src), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return ctypes.CDLL(str(lib))


@pytest.mark.parametrize("precision", ["double", "float"])
def test_every_supported_operation_matches_casadi(precision, tmp_path):
    rng = np.random.default_rng(42)
    kernels, fns = [], []
    for name, expr, dx, dy in CASES:
        ins = {"x": x, "y": y} if dy is not None else {"x": x}
        f = emit.function(f"op_{name}", ins, {"out": expr})
        kernels.append(emit.emit(f, precision))
        fns.append((name, f, dx, dy))
    lib = _build(kernels, precision, tmp_path)
    ct = ctypes.c_double if precision == "double" else ctypes.c_float
    np_t = np.float64 if precision == "double" else np.float32
    for name, f, dx, dy in fns:
        cfun = getattr(lib, f"op_{name}")
        cfun.restype = None
        cfun.argtypes = [ct] * (2 if dy is not None else 1) + [ctypes.POINTER(ct)]
        for _ in range(50):
            xv = float(np_t(rng.uniform(*dx)))
            yv = float(np_t(rng.uniform(*dy))) if dy is not None else None
            args = [xv] + ([yv] if dy is not None else [])
            expected = float(f(*args))
            out = ct()
            cfun(*args, ctypes.byref(out))
            if precision == "double":
                assert out.value == pytest.approx(expected, rel=1e-13, abs=1e-13), (name, args)
            else:
                assert out.value == pytest.approx(expected, rel=2e-6, abs=2e-6), (name, args)


def test_unsupported_operation_is_named():
    f = emit.function("bad", {"x": x}, {"out": ca.erfinv(x)})
    with pytest.raises(emit.EmitError, match="OP_ERFINV"):
        emit.emit(f, "float")


# A floating literal (with a point or an exponent) not followed by the f suffix: a double in C.
_DOUBLE_LITERAL = re.compile(r"(?<![\w.])(?:\d+\.\d*|\.\d+|\d+(?=[eE]))(?:[eE][-+]?\d+)?(?![\w.])")


def test_double_literal_pattern():
    for text in ("x * 2.5", "1e-06 + x", "x / 1.5e3", "(-0.5)", ".25 * x", "1E+10"):
        assert _DOUBLE_LITERAL.search(text), text
    for text in ("x * 2.5f", "1e-06f + x", "x / 1.5e3f", "(-0.5f)", "tmp12 * t3", "v[3]", "x * 2"):
        assert not _DOUBLE_LITERAL.search(text), text


def test_float_source_has_no_double_math():
    exprs = ca.vertcat(*[e for _, e, _, _ in CASES],
                       x * 1e-6 + y * 3e38 + 1e-30 * x * y)       # literals the emitter writes in exponent form
    k = emit.emit(emit.function("all_ops", {"x": x, "y": y}, {"out": exprs}), "float")
    src = k.source()
    assert re.search(r"\b\d+e-0?6f\b", src)                       # (the exponent form is there to check)
    doubles = re.findall(r"\b(sqrt|sin|cos|tan|asin|acos|atan|atan2|exp|log|pow|floor|ceil|fabs|fmod|hypot|"
                         r"sinh|cosh|tanh|asinh|acosh|atanh|erf|copysign|expm1|log1p)\(", src)
    assert doubles == []
    # every literal in a float build carries the f suffix
    assert not _DOUBLE_LITERAL.findall(src)


def test_literals_round_trip():
    for v in [0.1, 1.0 / 3.0, 1e-30, 6.02e23, -2.5, 0.0, 9.80665]:
        t = emit.literal(v, "float").strip("()")
        assert t.endswith("f")
        assert np.float32(float(t[:-1])) == np.float32(v)
        d = emit.literal(v, "double").strip("()")
        assert float(d) == v


def test_outputs_may_alias_inputs(tmp_path):
    # q_new written into the same array as q: all temporaries are computed first.
    q = ca.SX.sym("q", 2)
    k = emit.emit(emit.function("swap", {"q": q}, {"q_new": ca.vertcat(q[1], q[0] + q[1])}), "double")
    lib = _build([k], "double", tmp_path)
    arr = (ctypes.c_double * 2)(1.0, 2.0)
    lib.swap(arr, arr)
    assert list(arr) == [2.0, 3.0]


def test_sparse_input_rejected():
    s = ca.SX.sym("s", ca.Sparsity.diag(3))
    f = ca.Function("sp", [s], [ca.sum1(s)], ["s"], ["o"])
    with pytest.raises(emit.EmitError, match="sparse"):
        emit.emit(f, "float")


def _run1(lib, name, n_in, n_out, args, ct=ctypes.c_double):
    f = getattr(lib, name)
    f.restype = None
    ins = [(ct * len(a))(*a) for a in args]
    outs = [(ct * n)() for n in n_out]
    f(*ins, *outs)
    return [list(o) for o in outs]


def test_costly_select_becomes_a_branch_and_a_cheap_one_stays_a_conditional(tmp_path):
    v = ca.SX.sym("v", 2)
    costly = ca.if_else(v[0] < v[1], ca.sin(v[0]) * ca.cos(v[1]), ca.sqrt(v[0] * v[0] + 1) / v[1])
    also = ca.if_else(v[0] < v[1], ca.cos(v[1]) + 1, v[1] * 3)   # same condition: same block
    cheap = ca.if_else(v[0] > 0, v[0] + 1, v[1])
    nested = ca.if_else(v[0] < 0, ca.if_else(v[1] < 0, ca.exp(v[0]), ca.log(v[1] + 1)) * ca.sin(v[1]), 2.0)
    k = emit.emit(emit.function("br", {"v": v}, {"o": ca.vertcat(costly, also, cheap, nested)}), "double")
    text = "\n".join(k.lines())
    assert text.count("if (") == 3 and "? " in text          # cheap select stays ?:
    conds = {b["condition"]: b for b in k.branches}
    assert conds["v[0] < v[1]"]["then"] == {"mul": 1, "trig": 2, "add": 1}   # sin*cos, cos + 1
    assert conds["v[0] < v[1]"]["else"] == {"mul": 2, "add": 1, "sqrt": 1, "div": 1}   # v0^2, 3 v1
    ref = emit.emit(emit.function("nobr", {"v": v}, {"o": ca.vertcat(costly, also, cheap, nested)}), "double",
                    branch_min_cost=None)
    assert "if (" not in "\n".join(ref.lines()) and ref.branches == []
    lib = _build([k, ref], "double", tmp_path)
    f = ca.Function("f", [v], [ca.vertcat(costly, also, cheap, nested)])
    rng = np.random.default_rng(5)
    for _ in range(200):
        a = rng.uniform(-2, 2, 2).tolist()
        got = _run1(lib, "br", 1, [4], [a])[0]
        assert got == _run1(lib, "nobr", 1, [4], [a])[0]   # same operations on the taken side
        np.testing.assert_allclose(got, np.array(f(a)).ravel(), rtol=1e-14, atol=1e-14)


def test_a_value_a_side_returns_and_also_reads_is_computed_on_that_side_only(tmp_path):
    # the exponential map's shape: above the threshold cos|v| is returned as is and read by the
    # other outputs' work; below it a series. cos and sin must run only when the else side does.
    v = ca.SX.sym("v", 2)
    n2 = ca.sumsqr(v)
    n = ca.sqrt(ca.fmax(n2, 0.01))
    c, s = ca.cos(n), ca.sin(n)
    out = ca.vertcat(ca.if_else(n2 < 0.01, 1 - n2 / 2, c), ca.if_else(n2 < 0.01, v[0], s / n * v[0] + c))
    k = emit.emit(emit.function("em", {"v": v}, {"o": out}), "double")
    text = "\n".join(k.lines())
    else_side = text[text.index("} else {"):]
    assert text.count("cos(") == 1 and "cos(" in else_side and "sin(" in else_side
    (br,) = k.branches
    assert br["else"]["trig"] == 2 and "trig" not in br["then"]
    lib = _build([k], "double", tmp_path)
    f = ca.Function("f", [v], [out])
    for a in ([0.01, 0.02], [0.5, -1.0], [0.0, 0.0], [-2.0, 3.0]):
        np.testing.assert_allclose(_run1(lib, "em", 1, [2], [a])[0], np.array(f(a)).ravel(), rtol=1e-15, atol=0)


def test_split_kernel_equals_the_unsplit_one_bit_for_bit(tmp_path):
    A = ca.SX.sym("A", 4, 4)
    b = ca.SX.sym("b", 4)
    M = A
    for _ in range(3):
        M = ca.mtimes(M, A) / (1 + ca.sumsqr(M))
    out = {"M": M, "r": ca.mtimes(M, b) + ca.sin(b)}
    fn = emit.function("big", {"A": A, "b": b}, out)
    whole = emit.emit(fn, "double", name="whole", split_temps=None)
    split = emit.emit(fn, "double", name="split", split_temps=40)
    assert len(split.parts) >= 3 and whole.parts == []
    assert split.ops == whole.ops
    # the values handed between parts share slots once dead: the carry array is smaller than
    # the number of values handed over (and the bit-for-bit runs below catch a live slot reused)
    pool = int(re.search(r"double carry\[(\d+)\];", "\n".join(split.lines())).group(1))
    handed = sum(len(re.findall(r"^\s*carry\[\d+\] = ", p, re.M)) for p in split.part_sources())
    assert pool < handed / 2
    lib = _build([whole, split], "double", tmp_path)
    rng = np.random.default_rng(9)
    for _ in range(20):
        a, bb = rng.normal(size=16).tolist(), rng.normal(size=4).tolist()
        assert _run1(lib, "whole", 2, [16, 4], [a, bb]) == _run1(lib, "split", 2, [16, 4], [a, bb])
    # the aliasing rule holds for a split kernel too: output into its own input
    arr = (ctypes.c_double * 4)(*bb)
    m = (ctypes.c_double * 16)()
    lib.split.restype = None
    lib.split((ctypes.c_double * 16)(*a), arr, m, arr)
    assert list(arr) == _run1(lib, "whole", 2, [16, 4], [a, bb])[1]


def test_split_kernel_hands_bools_over_as_bools(tmp_path):
    """A flag output made in a part travels to the kernel in a bool array `flags`, not as
    1.0/0.0 in the float carry read back with > 0.5 (a bool read by a later part goes the same
    way: generated/qcf's qcf_k_gravity_part_part1 takes `const bool flags[1]`, and
    tests/generate/test_generated.py keeps that file current)."""
    A, b = ca.SX.sym("A", 4, 4), ca.SX.sym("b", 4)
    c = ca.sumsqr(b) < A[0, 0] * A[1, 1] + 1
    M = A
    for _ in range(3):
        M = ca.mtimes(M, A) / (1 + ca.sumsqr(M))
    r = ca.if_else(c, ca.mtimes(M, b), ca.sin(b))
    fn = emit.function("fl", {"A": A, "b": b}, {"r": r, "ok": ca.logic_and(c, ca.sumsqr(M) < 3)})
    whole = emit.emit(fn, "double", name="fl_whole", split_temps=None, flags=["ok"])
    split = emit.emit(fn, "double", name="fl_split", split_temps=30, flags=["ok"])
    assert len(split.parts) >= 3
    src = "\n".join(split.lines() + split.part_sources())
    assert "bool flags[1];" in src, src
    assert "> 0.5" not in src and "? 1.0 : 0.0" not in src, src
    assert re.search(r"^\s*\*ok = flags\[\d+\] /\* tmp\d+ \*/;$", src, re.M), src
    lib = _build([whole, split], "double", tmp_path)
    rng = np.random.default_rng(4)
    for fun in ("fl_whole", "fl_split"):
        getattr(lib, fun).restype = None
    for _ in range(40):
        a, bb = rng.normal(size=16), rng.normal(size=4)
        got = []
        for fun in ("fl_whole", "fl_split"):
            r_out, ok = (ctypes.c_double * 4)(), ctypes.c_bool()
            getattr(lib, fun)((ctypes.c_double * 16)(*a), (ctypes.c_double * 4)(*bb), r_out, ctypes.byref(ok))
            got.append((list(r_out), ok.value))
        assert got[0] == got[1]
        want = fn(a.reshape(4, 4).T, bb)
        # the values to rounding (the three quotients by one denominator are products by its
        # reciprocal in C, test_shared_denominator_becomes_one_reciprocal), the flag exactly
        assert got[1][1] == bool(float(want[1]))
        assert np.allclose(got[1][0], np.array(want[0]).ravel(), rtol=1e-14, atol=0)


def test_early_writes_store_outputs_where_computed_bit_for_bit(tmp_path):
    """early_writes: each output stored right after its value (also from inside a split
    kernel's parts), arrays restrict; the same bits as the kernel that stores at its end."""
    A, b = ca.SX.sym("A", 4, 4), ca.SX.sym("b", 4)
    M = A
    for _ in range(3):
        M = ca.mtimes(M, A) / (1 + ca.sumsqr(M))
    fn = emit.function("big", {"A": A, "b": b}, {"M": M, "r": ca.mtimes(M, b) + ca.sin(b)})
    late = emit.emit(fn, "double", name="late", split_temps=None)
    early = emit.emit(fn, "double", name="early", split_temps=None, early_writes=True)
    split = emit.emit(fn, "double", name="early_split", split_temps=40, early_writes=True)
    assert "restrict" in early.prototype() and "restrict" not in late.prototype()
    first_write = next(i for i, ln in enumerate(early.lines()) if ln.startswith("M["))
    last_def = max(i for i, ln in enumerate(early.lines()) if ln.startswith("const double"))
    assert first_write < last_def
    assert any(re.search(r"^\s*M\[\d+\] = ", p, re.M) for p in split.part_sources())
    lib = _build([late, early, split], "double", tmp_path)
    rng = np.random.default_rng(4)
    for _ in range(20):
        a, bb = rng.normal(size=16).tolist(), rng.normal(size=4).tolist()
        ref = _run1(lib, "late", 2, [16, 4], [a, bb])
        assert _run1(lib, "early", 2, [16, 4], [a, bb]) == ref
        assert _run1(lib, "early_split", 2, [16, 4], [a, bb]) == ref


def test_in_place_early_writes_wait_for_the_last_read_of_what_they_overwrite(tmp_path):
    """early_writes with in_place {"P_out": "P"}: called with P_out the same array as P (the
    state updated in place, as mekf's update_gravity), each element is stored after every read of
    the element it overwrites, unsplit and split into parts, and P, P_out are not declared restrict
    (w, read only, is):
    the same results as the kernel that stores at its end (its first outputs are ready before
    the inputs they overwrite are read for the last time)."""
    P, w = ca.SX.sym("P", 6), ca.SX.sym("w", 2)
    y = [P[1] + w[0], P[2] * P[3]]                  # early values; P[0], P[1] read again below
    z = [ca.sin(P[0] * y[1]) + P[1] * P[4] * w[1]]
    for i in range(6):
        z.append(z[-1] * z[-1] / (1 + z[-1] * z[-1]) + P[(i + 2) % 6] * P[0])
    out = ca.vertcat(y[0], y[1], z[6], z[3] + P[1], z[5] * P[5], z[4] - P[0])
    fn = emit.function("ip", {"P": P, "w": w}, {"P_out": out})
    late = emit.emit(fn, "double", name="ip_late", split_temps=None)
    plain = emit.emit(fn, "double", name="ip_plain", split_temps=None, early_writes=True)   # restrict
    inplace = emit.emit(fn, "double", name="ip_early", split_temps=None, early_writes=True,
                        in_place={"P_out": "P"})
    split = emit.emit(fn, "double", name="ip_split", split_temps=6, early_writes=True, in_place={"P_out": "P"})
    assert "P[restrict 6]" in plain.prototype()
    proto = inplace.prototype()
    assert "P[6]" in proto and "P_out[6]" in proto and "w[restrict 2]" in proto
    first_write = next(i for i, ln in enumerate(inplace.lines()) if ln.startswith("P_out["))
    last_def = max(i for i, ln in enumerate(inplace.lines()) if ln.startswith("const double"))
    assert first_write < last_def                   # still early
    lib = _build([late, inplace, split], "double", tmp_path)
    rng = np.random.default_rng(5)

    def same_array(name, v):
        arr, ww = (ctypes.c_double * 6)(*v), (ctypes.c_double * 2)(0.5, -1.5)
        getattr(lib, name).restype = None
        getattr(lib, name)(arr, ww, arr)
        return list(arr)

    for _ in range(20):
        v = rng.normal(size=6).tolist()
        ref = _run1(lib, "ip_late", 2, [6], [v, [0.5, -1.5]])[0]
        assert same_array("ip_late", v) == ref
        assert same_array("ip_early", v) == ref
        assert same_array("ip_split", v) == ref
    with pytest.raises(emit.EmitError, match="in_place"):
        emit.emit(fn, "double", name="bad", in_place={"P_out": "P"})


def test_fma_option_fuses_products_into_sums_and_rounds_once(tmp_path):
    a, b, c = ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("c")
    fn = emit.function("fm", {"a": a, "b": b, "c": c}, {"o": ca.vertcat(a * b + c, c - a * b, a * b - c)})
    k = emit.emit(fn, "float", fma=True)
    text = "\n".join(k.lines())
    assert text.count("fmaf(") == 3 and " * " not in text    # the shared product goes into each
    assert k.ops["mul"] == 3 and k.ops["add"] == 3          # counted as the operations they fuse
    kept = emit.emit(emit.function("fs", {"a": a, "b": b, "c": c}, {"o": ca.vertcat(a * b + c, a * b)}),
                     "float", fma=True)
    assert "fmaf(" in "\n".join(kept.lines()) and " = a * b;" in "\n".join(kept.lines())   # still an output
    lib = _build([k], "float", tmp_path)
    rng = np.random.default_rng(3)
    for _ in range(300):
        v = rng.normal(size=3).astype(np.float32)
        lib.fm.restype = None
        lib.fm.argtypes = [ctypes.c_float] * 3 + [ctypes.POINTER(ctypes.c_float)]
        out = (ctypes.c_float * 3)()
        lib.fm(float(v[0]), float(v[1]), float(v[2]), out)
        got = list(out)
        p = float(v[0]) * float(v[1])                        # exact in double (24 + 24 bits)
        # one rounding of the exact result (double rounding via float64 is off with p < 2^-29)
        want = [np.float32(p + float(v[2])), np.float32(float(v[2]) - p), np.float32(p - float(v[2]))]
        assert [np.float32(g) for g in got] == want


def test_select_chained_on_one_condition_is_read_only_after_it_is_assigned(tmp_path):
    """A select whose value feeds another select on the same condition: the second's side must
    not be computed inside the if-block before the block assigns the first (it read an
    unassigned temporary). Such a group stays `?:`; the result equals CasADi's."""
    v = ca.SX.sym("v", 2)
    c = v[0] < v[1]
    a = ca.if_else(c, ca.sin(v[0]) * ca.cos(v[1]) * ca.exp(v[1]), ca.sqrt(v[0] * v[0] + 1) / v[1])
    b = ca.if_else(c, ca.sin(a * v[1]) + ca.cos(a) * ca.exp(a), ca.log(v[1] * v[1] + 2) * v[0])
    fn = emit.function("chain", {"v": v}, {"o": ca.vertcat(a, b)})
    k = emit.emit(fn, "double")
    lines = k.lines()
    for i, line in enumerate(lines):           # every temporary is assigned before it is read
        m = re.match(r"\s*(?:const )?double (tmp\d+) = ", line) or re.match(r"\s*(tmp\d+) = ", line)
        if m:
            for later in lines[:i]:
                assert not re.search(rf"\b{m.group(1)}\b(?! =)", later.split("=", 1)[-1]) or \
                    re.match(rf"\s*double {m.group(1)};", later), (m.group(1), later)
    lib = _build([k], "double", tmp_path)
    rng = np.random.default_rng(3)
    for _ in range(100):
        x = [float(rng.uniform(-2, 2)), float(rng.uniform(0.3, 2))]
        got = _run1(lib, "chain", 1, [2], [x])[0]
        np.testing.assert_allclose(got, np.array(fn(x)).ravel(), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("precision", ["double", "float"])
def test_division_by_a_power_of_two_is_an_exact_multiplication(precision, tmp_path):
    """x / 2^k becomes x * 2^-k (the same correctly rounded value, subnormals included); a
    division by another constant, or by a power of two whose reciprocal the type cannot hold,
    stays a division."""
    xv = ca.SX.sym("x", 2)        # a vector input: the kernel takes a pointer (x[0] is used)
    x = xv[0]
    big = 2.0 ** -130 if precision == "float" else 2.0 ** -1030      # 1 / big overflows the type
    outs = [x / 2, x / -0.25, x / 1024, x / 3, x / big]
    k = emit.emit(emit.function(f"p2_{precision}", {"x": xv}, {"o": ca.vertcat(*outs)}), precision)
    text = "\n".join(k.lines())
    lit = lambda v: emit.literal(v, precision)  # noqa: E731
    for c in (2, -0.25, 1024):
        assert f"x[0] * {lit(1 / c)}" in text, text
    assert f"x[0] / {lit(3.0)}" in text and f"x[0] / {lit(big)}" in text
    assert k.ops["div"] == 2 and k.ops["mul"] == 3
    ct, nt = (ctypes.c_float, np.float32) if precision == "float" else (ctypes.c_double, np.float64)
    lib = _build([k], precision, tmp_path)
    tiny = np.finfo(nt).tiny
    for v in [1.0, -3.7, 1e30, tiny, 3 * tiny, -5 * np.finfo(nt).smallest_subnormal, 0.0, 123.456]:
        got = np.array(_run1(lib, k.name, 1, [5], [[v, 0.0]], ct)[0][:3], dtype=nt)
        want = np.array([nt(v) / nt(2), nt(v) / nt(-0.25), nt(v) / nt(1024)], dtype=nt)
        assert np.array_equal(got.view(np.uint32 if nt is np.float32 else np.uint64),
                              want.view(np.uint32 if nt is np.float32 else np.uint64)), (v, got, want)


def test_small_kernels_are_inline_and_large_ones_are_not():
    """The storage rule of every committed build: a kernel of at most emit.INLINE_TEMPS
    temporaries (manifest) is `static inline` (GCC inlines it at each of its call sites), a
    larger one plain `static` (called from several places it stays one copy)."""
    import json
    from pathlib import Path
    seen = {True: 0, False: 0}
    for man_path in sorted((REPO / "generated").glob("*/manifest.json")):
        man = json.loads(man_path.read_text())
        src = (man_path.parent / man["files"]["source"]).read_text()
        for name, k in man["kernels"].items():
            m = re.search(rf"^static (inline )?void {man['prefix']}_k_{name}\(", src, re.M)
            assert m, (man["prefix"], name)
            small = k["temporaries"] <= emit.INLINE_TEMPS
            assert bool(m.group(1)) == small, (man["prefix"], name, k["temporaries"])
            seen[small] += 1
    assert seen[True] and seen[False]


@pytest.mark.parametrize("precision", ["float", "double"])
def test_shared_denominator_becomes_one_reciprocal(precision, tmp_path):
    """v / |v| for a 4-vector: one division 1 / |v| and four products, as a hand-writer
    normalises (a division is 14 cycles on the M4F, a product 1); a lone quotient and quotients
    by a literal stay divisions. Within one rounding of each quotient of the plain division."""
    v, w = ca.SX.sym("v", 4), ca.SX.sym("w")
    n = ca.sqrt(ca.sumsqr(v))
    fn = emit.function("nrm", {"v": v, "w": w}, {"u": v / n, "s": w / v[0], "k": ca.vertcat(w / 3.0, v[1] / 3.0)})
    k = emit.emit(fn, precision, name="nrm")
    text = "\n".join(k.lines())
    assert k.ops["div"] == 1 + 1 + 2, text          # 1 / |v|, w / v[0], the two by the literal 3
    assert text.count(" / ") == 4 and text.count(" * tmp") >= 4, text
    lib = _build([k], precision, tmp_path)
    ct, nt = (ctypes.c_float, np.float32) if precision == "float" else (ctypes.c_double, np.float64)
    lib.nrm.restype = None
    rng = np.random.default_rng(7)
    for _ in range(200):
        a = rng.normal(size=4).astype(nt)
        u, s_, kk = (ct * 4)(), ct(), (ct * 2)()
        lib.nrm((ct * 4)(*a), ct(nt(1.5)), u, ctypes.byref(s_), kk)
        plain = a / np.sqrt(np.sum(a.astype(np.float64) ** 2)).astype(nt)
        eps = np.finfo(nt).eps
        assert np.all(np.abs(np.array(u[:], dtype=np.float64) - plain) <= 2 * eps * np.abs(plain) + 1e-300)



@pytest.mark.parametrize("name", ["mekf", "adukf"])
def test_split_kernel_slot_reads_name_the_temporary_they_hold(name):
    """Every read of a carry or flags slot in a split kernel names the temporary the slot holds
    there: the one the last part before it stored in that slot (`carry[7] = tmp11;`), read
    from the stores in call order; and the comments are the only difference from the
    print without names."""
    from ahrsgen.codegen.emit import ir
    from ahrsgen.generate import config, render
    gen = render.render(config.resolve(name))
    split = [k for k in gen.kernels if k.parts]
    assert split
    reads = 0
    for k in split:
        held = {}
        for f in k.functions():            # the parts in call order, then the kernel's own body
            for s in ir.all_statements(f.body):
                for e in ir.exprs(s):
                    for x in ir.walk(e):
                        if isinstance(x, ir.Slot):
                            assert x.name == held[(x.array, x.index)], (k.name, f.name, x)
                            reads += 1
            for s in ir.all_statements(f.body):        # a part's exports come after its reads
                if isinstance(s, ir.Store) and isinstance(s.target, ir.Slot):
                    held[(s.target.array, s.target.index)] = s.expr.name
            on, off = "\n".join(f.lines()), "\n".join(f.lines(names=False))
            bare = lambda c: re.sub(r" ?/\*.*?\*/", "", c, flags=re.S).split()   # noqa: E731
            assert bare(on) == bare(off) and "/* tmp" not in off
    assert reads > 100
