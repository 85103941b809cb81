"""math = "fast": the float helpers against the exact functions (NumPy double) over their
whole domain, each within the maximum error src/ahrsgen/codegen/fastmath.py states; the special values
(signed zeros, infinities, NaN) as C99's atan2 gives them; and a fast build links no libm
trigonometry while the emitter still writes libm calls for math = "libm" and double."""
from __future__ import annotations

import ctypes
import subprocess

import casadi as ca
import numpy as np
import pytest

from ahrsgen.codegen import emit, fastmath

FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-fno-math-errno", "-Wall", "-Wextra", "-Wpedantic",
         "-Wconversion", "-Wdouble-promotion", "-Wshadow", "-Wfloat-equal", "-Werror"]


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    d = tmp_path_factory.mktemp("fastmath")
    src = ["#include <float.h>", "#include <math.h>", "#include <stdbool.h>", "#include <stdint.h>",
           fastmath.c_source(fastmath.HELPERS)]
    for n, h in fastmath.HELPERS.items():
        if n == "sincos":
            continue   # fast_sinf's and fast_cosf's shared body, measured through them
        two = n == "atan2"
        src.append(f"void v_{n}(const float *x, const float *y, float *o, long k);\n"
                   f"void v_{n}(const float *x, const float *y, float *o, long k)\n{{\n"
                   + ("" if two else "    (void)y;\n")
                   + f"    for (long i = 0; i < k; i++) {{ o[i] = {h.name}(x[i]{', y[i]' if two else ''}); }}\n}}")
    (d / "fm.c").write_text("\n".join(src) + "\n")
    subprocess.run(["gcc", *FLAGS, "-shared", "-fPIC", str(d / "fm.c"), "-o", str(d / "fm.so")], check=True)
    return ctypes.CDLL(str(d / "fm.so"))


def _call(lib, name, x, y=None):
    x = np.ascontiguousarray(x, np.float32)
    y = np.ascontiguousarray(x if y is None else y, np.float32)
    o = np.empty_like(x)
    getattr(lib, "v_" + name)(*(a.ctypes.data_as(ctypes.c_void_p) for a in (x, y, o)), ctypes.c_long(len(x)))
    return o


def _floats_between(lo: float, hi: float, step: int) -> np.ndarray:
    """Every step-th float32 in [lo, hi] (0 <= lo < hi): all binades, evenly by bit pattern."""
    a, b = np.float32([lo, hi]).view(np.int32)
    return np.arange(a, b + 1, step, dtype=np.int32).view(np.float32)


def _max_err(got, exact):
    ok = np.isfinite(exact)
    return float(np.max(np.abs(got[ok].astype(float) - exact[ok])))


RNG = np.random.default_rng(7)


def test_sin_cos_within_stated_error_over_the_domain(lib):
    small = _floats_between(0.0, 1.0, 1000)                        # 1 in 1000 of the floats in [0, 1]
    x = np.concatenate([small, -small, RNG.uniform(-fastmath.TRIG_MAX, fastmath.TRIG_MAX, 1_000_000),
                        np.float32([fastmath.TRIG_MAX, -fastmath.TRIG_MAX, np.pi / 4, np.pi / 2, np.pi])])
    x = x.astype(np.float32)
    for name, ref in (("sin", np.sin), ("cos", np.cos)):
        err = _max_err(_call(lib, name, x), ref(x.astype(float)))
        assert err <= fastmath.HELPERS[name].max_abs_error, (name, err)
    assert list(_call(lib, "sin", np.float32([0.0, -0.0]))) == [0.0, 0.0]   # (sign of zero not kept)
    assert list(_call(lib, "cos", np.float32([0.0, -0.0]))) == [1.0, 1.0]
    out = _call(lib, "sin", np.float32([np.nan, np.inf, -np.inf, 2 * fastmath.TRIG_MAX]))
    assert np.isnan(out).all()                                   # outside the domain: NaN, documented


def test_atan2_asin_acos_atan_within_stated_error(lib):
    y = RNG.standard_normal(1_000_000).astype(np.float32) * np.float32(10.0) ** RNG.integers(-6, 7, 1_000_000)
    x = RNG.standard_normal(1_000_000).astype(np.float32) * np.float32(10.0) ** RNG.integers(-6, 7, 1_000_000)
    err = _max_err(_call(lib, "atan2", y, x), np.arctan2(y.astype(float), x.astype(float)))
    assert err <= fastmath.HELPERS["atan2"].max_abs_error, err
    u = np.concatenate([_floats_between(0.0, 1.0, 1000), 1 - RNG.uniform(0, 1e-4, 100_000)]).astype(np.float32)
    u = np.concatenate([u, -u])
    for name, ref in (("asin", np.arcsin), ("acos", np.arccos)):
        err = _max_err(_call(lib, name, u), ref(u.astype(float)))
        assert err <= fastmath.HELPERS[name].max_abs_error, (name, err)
    assert np.isnan(_call(lib, "asin", np.float32([1.0001, -1.5, np.nan]))).all()
    t = np.concatenate([y, np.float32([np.inf, -np.inf, 3e38, 1e-45])])
    err = _max_err(_call(lib, "atan", t), np.arctan(t.astype(float)))
    assert err <= fastmath.HELPERS["atan"].max_abs_error, err


def test_exp_within_stated_relative_error(lib):
    x = np.concatenate([RNG.uniform(-87.29, 88.72, 1_000_000), _floats_between(0.0, 1.0, 1000),
                        -_floats_between(0.0, 1.0, 1000)]).astype(np.float32)
    got, exact = _call(lib, "exp", x).astype(float), np.exp(x.astype(float))
    assert float(np.max(np.abs(got - exact) / exact)) <= fastmath.HELPERS["exp"].max_rel_error
    edge = _call(lib, "exp", np.float32([np.nan, np.inf, -np.inf, -200.0, 89.0, 0.0, -87.3]))
    assert np.isnan(edge[0]) and list(edge[1:]) == [np.inf, 0.0, 0.0, np.inf, 1.0, 0.0]


def test_log_within_stated_relative_error(lib):
    """Every float of [0.5, 2] (each mantissa, both sides of the sqrt(2) switch and of 1, where
    log x -> 0 and the error must shrink with it), 2*10^6 random bit patterns over all positive
    floats with the subnormals, and the special values."""
    a, b = np.float32([0.5, 2.0]).view(np.int32)
    x = np.concatenate([np.arange(a, b + 1, dtype=np.int32).view(np.float32),
                        RNG.integers(1, 0x7F800000, 2_000_000).astype(np.int32).view(np.float32),
                        np.float32([1e-45, 1.1754942e-38, 1.1754944e-38, 3.4028235e38])])
    got, exact = _call(lib, "log", x).astype(float), np.log(x.astype(float))
    ok = exact != 0.0
    assert np.all(got[~ok] == 0.0)                                       # log 1 = 0 exactly
    assert float(np.max(np.abs(got[ok] - exact[ok]) / np.abs(exact[ok]))) <= fastmath.HELPERS["log"].max_rel_error
    edge = _call(lib, "log", np.float32([0.0, -0.0, np.inf, -1.0, -np.inf, np.nan, -1e-45]))
    assert list(edge[:3]) == [-np.inf, -np.inf, np.inf] and np.all(np.isnan(edge[3:]))


def test_atan2_special_values_as_c99(lib):
    sp = np.float32([0.0, -0.0, np.inf, -np.inf, 1.0, -1.0, 1e-45, -3e38, np.nan])
    Y, X = (a.ravel() for a in np.meshgrid(sp, sp))
    got = _call(lib, "atan2", Y, X)
    exact = np.arctan2(Y.astype(float), X.astype(float))
    both_nan = np.isnan(got) & np.isnan(exact)
    close = np.abs(got.astype(float) - exact) <= fastmath.HELPERS["atan2"].max_abs_error
    same_sign = np.signbit(got) == np.signbit(exact)
    assert np.all(both_nan | (close & same_sign)), list(zip(Y[~(both_nan | close)], X[~(both_nan | close)]))


def test_emitter_writes_helpers_only_for_fast_float():
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    fn = emit.function("k", {"x": x, "y": y}, {"o": ca.vertcat(ca.sin(x) + ca.atan2(y, x), ca.asin(y))})
    fast = emit.emit(fn, "float", math="fast")
    text = "\n".join(fast.lines())
    assert "fast_sinf(" in text and "fast_atan2f(" in text and "fast_asinf(" in text and " sinf(x)" not in text
    assert fast.helpers == ["asin", "atan2", "sin"]
    assert fastmath.closure(fast.helpers) == ["sincos", "atan2", "sin", "asin"]    # dependencies first
    libm = "\n".join(emit.emit(fn, "float", math="libm").lines())
    assert " sinf(x)" in libm and "fast_" not in libm
    dbl = emit.emit(fn, "double", math="fast")
    assert " sin(x)" in "\n".join(dbl.lines()) and dbl.helpers == []
    with pytest.raises(emit.EmitError):
        emit.emit(fn, "float", math="approx")


def test_sin_and_cos_of_one_argument_share_one_call_in_one_scope(tmp_path):
    """math = "fast": sin(a) and cos(a) in one scope become one fast_sincosf call, also when
    a kernel split puts them in different statements (the second value is then handed on
    from the first's part); a sin and a cos on the two sides of an if/else stay apart. The
    kernel's floats are checked against the double functions within the helpers' bound."""
    a, b = ca.SX.sym("a"), ca.SX.sym("b")
    big = a * b
    for _ in range(30):                 # enough work between the pair to split it into parts
        big = big * a + b
    side = ca.if_else(b < 0, ca.sin(b) * ca.exp(a) * 3, ca.cos(b) / (1 + a * a) + 2)
    out = ca.vertcat(ca.sin(a) * 2, big, ca.cos(a) + big, side)
    fn = emit.function("k", {"a": a, "b": b}, {"o": out})
    k = emit.emit(fn, "float", math="fast", split_temps=20)
    src = "\n".join(k.lines() + k.part_sources())
    assert len(k.parts) >= 2
    assert src.count("fast_sincosf(a, &") == 1 and "fast_sinf(a)" not in src and "fast_cosf(a)" not in src
    assert "fast_sinf(b)" in src and "fast_cosf(b)" in src       # if/else sides: not paired
    assert k.ops["trig"] == 5                                     # the count still names each function
    assert k.helpers == ["cos", "exp", "sin", "sincos"]
    c = tmp_path / "k.c"
    c.write_text("#include <float.h>\n#include <math.h>\n#include <stdbool.h>\n#include <stdint.h>\n"
                 + fastmath.c_source(k.helpers) + "\n" + k.source(storage="") + "\n")
    subprocess.run(["gcc", *FLAGS, "-shared", "-fPIC", str(c), "-o", str(tmp_path / "k.so")], check=True)
    lib = ctypes.CDLL(str(tmp_path / "k.so"))
    lib.k.restype = None
    f = ca.Function("f", [a, b], [out])
    for x, y in ((0.3, -0.7), (-2.0, 0.4), (1e-3, 0.99), (3.0, -0.01)):
        o = (ctypes.c_float * 4)()
        lib.k(ctypes.c_float(x), ctypes.c_float(y), o)
        exact = np.array(f(np.float32(x), np.float32(y))).ravel()
        np.testing.assert_allclose(list(o), exact, rtol=1e-5, atol=1e-6)
