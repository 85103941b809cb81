"""CPF (complementary + particle filter): PRNG, generated C vs the NumPy reference, and the
behaviours the issue asks for (q = -q likelihood, wrapped mixing, weight underflow, resampling).

Independent checks: the xoroshiro64** known-answer vector of the reference implementation (as
used by Rust's rand_xoshiro), the normal distribution's moments, the systematic-resampling
count property, physical invariants (yaw continuity through ±180°), and the NumPy reference
(written from the equations) for every C run.
"""
from __future__ import annotations

import ctypes
import math
import subprocess
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from conftest import needs, REPO
from ahrsgen.sim import host, scenarios
from ahrsgen.sim.log import G0, VALID_ACCEL, VALID_GYRO, VALID_MAG, SensorLog
from ahrsgen.sim.metrics import euler_stats, max_angle_diff_rad
from ahrsgen.generate import config, render
from ahrsgen import status as st
from ahrsgen.filters.cpf import reference as R
from ahrsgen.filters.cpf import prng
from ahrsgen.filters.cpf.prng import Xoroshiro64ss, seed_state
from ahrsgen.npquat import euler_from_q, q_from_euler, rotmat

VALID_IMU = VALID_GYRO | VALID_ACCEL | VALID_MAG


# ---- helpers ----------------------------------------------------------------------------------

def _sets(params: dict) -> list[str]:
    return [f"{k}={v!r}" if isinstance(v, float) else f"{k}={str(v).lower() if isinstance(v, bool) else v}"
            for k, v in params.items()]


@cache
def _built(precision: str, items: tuple):
    cfg = config.resolve("cpf", sets=_sets(dict(items)), precision=precision)
    return cfg, host.build(cfg)


def built(precision="double", **params):
    return _built(precision, tuple(sorted(params.items())))


@cache
def _log(name: str):
    return scenarios.make(name, seed=0)


def site(name: str) -> dict:
    """The scenario's magnetic declination (a site parameter, as `ahrsgen validate` sets it)."""
    return {"declination": math.radians(float(_log(name).meta["declination_deg"]))}


@cache
def _ref_run(name: str, items: tuple):
    cfg, _ = _built("double", items)
    q, s, ref = R.run(_log(name), cfg.params, return_ref=True)
    return q, s, ref


def ref_run(name, **params):
    return _ref_run(name, tuple(sorted(params.items())))


def rms3(q, log):
    s = euler_stats(q, log.q_true, log.t, log.settle_time)
    return np.array([s[a]["rms"] for a in ("roll", "pitch", "yaw")])


def unit(q):
    return np.asarray(q) / np.linalg.norm(q)


# ---- PRNG ---------------------------------------------------------------------------------------

def test_xoroshiro_known_answer():
    # Reference implementation xoroshiro64starstar.c 1.0 from state {1, 2}
    # (the test vector of Rust's rand_xoshiro).
    g = Xoroshiro64ss()
    g.s = [1, 2]
    assert g.u32_block(10) == [3802928447, 813792938, 1618621494, 2955957307, 3252880261, 1129983909,
                               2539651700, 1327610908, 1757650787, 2763843748]


def test_seeding_is_splitmix32_and_never_all_zero():
    # fmix32 of the Weyl sequence, written out independently with numpy uint32 arithmetic.
    def fmix(x):
        x = np.uint32(x)
        with np.errstate(over="ignore"):
            x = (x ^ (x >> np.uint32(16))) * np.uint32(0x85EBCA6B)
            x = (x ^ (x >> np.uint32(13))) * np.uint32(0xC2B2AE35)
        return int(x ^ (x >> np.uint32(16)))
    for seed in (0, 1, 12345, 0xFFFFFFFF):
        expect = [fmix((seed + (i + 1) * 0x9E3779B9) & 0xFFFFFFFF) for i in range(2)]
        assert seed_state(seed) == expect
        assert any(seed_state(seed))


def _hook(precision: str):
    """The generated cpf.c compiled with the PRNG test hook (tests/c/cpf_prng_hook.c)."""
    _, hf = built(precision)
    out = hf.lib_path.parent / f"libcpf_prng_hook_{precision}.so"
    hook = REPO / "tests" / "c" / "cpf_prng_hook.c"
    if not out.exists() or out.stat().st_mtime < hook.stat().st_mtime:   # the hook changes apart from cpf.c
        cmd = [host.cc(), *host.STRICT, *host.HOST_FLAGS, f"-I{hf.dir}", '-DCPF_SOURCE="cpf.c"',
               f"-DCPF_REAL={precision}", "-shared", "-o", str(out),
               str(hook), "-lm"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    lib = ctypes.CDLL(str(out))
    R_ = ctypes.c_float if precision == "float" else ctypes.c_double
    for name in ("cpf_hook_u32", "cpf_hook_uniform", "cpf_hook_gauss4"):
        getattr(lib, name).argtypes = [ctypes.POINTER(ctypes.c_uint32), ctypes.c_uint32, ctypes.c_void_p]
    return lib, (np.float32 if precision == "float" else np.float64), R_


@pytest.mark.parametrize("seed", [1, 3141592653])
def test_prng_first_million_outputs_identical_c_python(seed):
    lib, _, _ = _hook("double")
    n = 1_000_000
    state = (ctypes.c_uint32 * 2)(*seed_state(seed))
    out = np.zeros(n, np.uint32)
    lib.cpf_hook_u32(state, n, out.ctypes.data)
    g = Xoroshiro64ss(seed)
    py = np.array(g.u32_block(n), dtype=np.uint32)
    assert np.array_equal(out, py)
    assert list(state) == g.s            # the states agree after the run as well


@pytest.mark.parametrize("precision", ["double", "float"])
def test_uniforms_identical_and_gaussians_bitwise_in_double(precision):
    lib, npr, _ = _hook(precision)
    n = 100_000
    state = (ctypes.c_uint32 * 2)(*seed_state(7))
    u = np.zeros(n, npr)
    lib.cpf_hook_uniform(state, n, u.ctypes.data)
    g = Xoroshiro64ss(7)
    pu = np.array([g.uniform() for _ in range(n)])
    assert np.array_equal(u.astype(float), pu)          # 24-bit uniforms are exact in both types
    assert u.min() > 0.0 and u.max() <= 1.0
    z = np.zeros(4 * n, npr)
    lib.cpf_hook_gauss4(state, n, z.ctypes.data)
    pz = np.array(g.normals(2 * n))
    if precision == "double":
        assert np.array_equal(z, pz)                    # same libm calls: bit for bit
    else:
        assert np.max(np.abs(z - pz)) < 1e-5            # float ziggurat on the same draws


def test_exp_nonpos_within_its_stated_bound():
    """The float build's exp for x <= 0 (likelihood factor, ziggurat wedge): within fastmath's
    stated relative error EXP_NONPOS_REL_ERROR + EXP_NONPOS_REL_ERROR_PER_UNIT |x| of the exact
    exp over [-87.29, 0] (every power of two down to the subnormals, the table's 64 nodes and
    their midpoints, 10^6 random arguments), 1 at 0, 0 at and below -87.3, NaN kept."""
    from ahrsgen.codegen import fastmath
    lib, _, _ = _hook("float")
    lib.cpf_hook_exp_nonpos.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p]
    rng = np.random.default_rng(5)
    tiny = np.float32(2.0) ** -np.arange(0, 150, dtype=np.float32)      # down to the subnormals
    nodes = -np.arange(0, 8061) * (math.log(2.0) / 64.0)                   # 2^(n/64) and halfway
    x = np.concatenate([rng.uniform(-87.29, 0.0, 1_000_000), -tiny, nodes, nodes - math.log(2.0) / 128.0,
                        [0.0, -0.0, -87.29, -87.3, -87.31, -200.0, -np.inf]]).astype(np.float32)
    got = np.empty_like(x)
    lib.cpf_hook_exp_nonpos(x.ctypes.data, len(x), got.ctypes.data)
    exact = np.exp(x.astype(float))
    inside = x > np.float32(-87.3)
    rel = np.abs(got[inside].astype(float) - exact[inside]) / exact[inside]
    bound = fastmath.EXP_NONPOS_REL_ERROR + fastmath.EXP_NONPOS_REL_ERROR_PER_UNIT * np.abs(x[inside].astype(float))
    assert np.all(rel <= bound), float(np.max(rel / bound))
    assert np.all(got[x == 0.0] == 1.0)
    assert np.all(got[~inside] == 0.0)
    nan = np.float32([np.nan])
    lib.cpf_hook_exp_nonpos(nan.ctypes.data, 1, got.ctypes.data)
    assert np.isnan(got[0])
    # the likelihood's form, 2^(t/64) of t = 64 x / ln2 folded into the caller's constant: within
    # EXP_NONPOS_REL_ERROR of the exact power over the same range, 0 below it, NaN kept
    lib.cpf_hook_exp2_64.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p]
    t = np.concatenate([rng.uniform(-8060.6, 0.0, 1_000_000), -tiny, -np.arange(0, 8061.0), -np.arange(0, 8061.0) - 0.5,
                        [0.0, -8060.62, -8060.63, -9000.0, -np.inf, np.nan]]).astype(np.float32)
    got = np.empty_like(t)
    lib.cpf_hook_exp2_64(t.ctypes.data, len(t), got.ctypes.data)
    inside = t > np.float32(-8060.626)
    exact = 2.0 ** (t[inside].astype(float) / 64.0)
    rel = np.abs(got[inside].astype(float) - exact) / exact
    assert np.all(rel <= fastmath.EXP_NONPOS_REL_ERROR), float(np.max(rel))
    assert np.all(got[(t <= np.float32(-8060.626))] == 0.0) and np.isnan(got[-1])


@pytest.mark.parametrize("precision", ["double", "float"])
def test_gaussian_moments_within_statistical_bounds(precision):
    lib, npr, _ = _hook(precision)
    n4 = 250_000                                        # 10^6 samples
    state = (ctypes.c_uint32 * 2)(*seed_state(2024))
    z = np.zeros(4 * n4, npr)
    lib.cpf_hook_gauss4(state, n4, z.ctypes.data)
    z = z.astype(float)
    n = len(z)
    # 5-sigma bounds of the sample statistics of a standard normal
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * math.sqrt(2.0 / n)
    assert abs(np.mean(z ** 4) / z.var() ** 2 - 3.0) < 5 * math.sqrt(24.0 / n)
    p1 = 0.6826894921370859                             # P(|z| < 1)
    assert abs(np.mean(np.abs(z) < 1.0) - p1) < 5 * math.sqrt(p1 * (1 - p1) / n)
    # lag-1 correlation (the two members of a pair, and consecutive pairs)
    assert abs(np.corrcoef(z[:-1], z[1:])[0, 1]) < 5 / math.sqrt(n)
    # the ziggurat's tail is bounded by the 24-bit uniform: R + 24 ln 2 / R
    assert np.all(np.abs(z) <= prng.ZIG_R + 24 * math.log(2.0) / prng.ZIG_R + 1e-6)
    # and it reaches the tail beyond R as often as a normal does: P(|z| > R) = 5.76e-4
    pt = math.erfc(prng.ZIG_R / math.sqrt(2.0))
    assert abs(np.mean(np.abs(z) > prng.ZIG_R) - pt) < 5 * math.sqrt(pt / n)


# ---- generated C vs reference ------------------------------------------------------------------

CASES = [
    ("turntable", {}),
    ("turntable", {"faithful": True}),
    ("turntable", {"mode": "complementary"}),
    ("turntable", {"mode": "particle"}),
    ("turntable", {"n_particles": 37, "seed": 99, "ess_threshold": 0.9}),
    ("fixedwing_gps", {}),
]


@pytest.mark.parametrize("scen,params", CASES, ids=[f"{s}-{'-'.join(f'{k}={v}' for k, v in p.items()) or 'default'}"
                                                    for s, p in CASES])
@pytest.mark.slow
def test_double_c_matches_reference(scen, params):
    params = {**site(scen), **params}
    log = _log(scen)
    _, hf = built("double", **params)
    c = hf.run(log)
    q, s, ref = ref_run(scen, **params)
    assert np.array_equal(c.status, s)
    assert max_angle_diff_rad(c.q, q) <= 1e-9
    if params.get("mode", "combined") != "complementary":
        state = hf.state_dict(hf.last_state)
        assert state["resample_count"] == ref.n_resample
        np.testing.assert_allclose(state["weights"], ref.weights, rtol=0, atol=1e-9)
        assert state["weight_sum"] == pytest.approx(ref.weight_sum, rel=1e-12)
        np.testing.assert_allclose(state["particles"].reshape(-1, 4), ref.particles, rtol=0, atol=1e-9)
        assert list(state["rng"]) == ref.rng.s          # the same number of draws


def test_resampling_policy():
    scen = "turntable"
    log = _log(scen)
    n_obs = len(log) - 1                                # every step has accel+mag; the first initialises
    _, hf = built("double", faithful=True, **site(scen))
    hf.run(log)
    assert hf.state_dict(hf.last_state)["resample_count"] == n_obs
    _, hf = built("double", **site(scen))
    hf.run(log)
    k = hf.state_dict(hf.last_state)["resample_count"]
    assert 0 < k < n_obs                                # only on low effective sample size


@pytest.mark.slow
@pytest.mark.parametrize("scen,bound_deg", [("turntable", 0.05), ("fixedwing_gps", 0.25)])
def test_float_accuracy_within_bound_of_reference(scen, bound_deg):
    """Float C draws the same random numbers but its particle clouds part from the double run's
    (rounding changes which particles are resampled), so the runs are compared by accuracy."""
    log = _log(scen)
    _, hf = built("float", **site(scen))
    c = hf.run(log)
    assert np.all(np.isfinite(c.q))
    assert np.max(np.abs(np.linalg.norm(c.q, axis=1) - 1.0)) < 1e-5
    q, _, _ = ref_run(scen, **site(scen))
    d = np.abs(rms3(c.q, log) - rms3(q, log))
    assert np.all(d <= bound_deg), d


def test_reproduction_shape_on_turntable():
    """Each stage alone and combined stay accurate on the turntable (absolute bounds, degrees);
    docs/cpf.md has the full table next to the paper's."""
    log = _log("turntable")
    for mode in ("complementary", "particle", "combined"):
        q, _, _ = ref_run("turntable", mode=mode, **site("turntable"))
        assert np.all(rms3(q, log) < 0.5), (mode, rms3(q, log))


# ---- behaviours ---------------------------------------------------------------------------------

def _static_inputs(yaw, n, seed=0, mag_noise=0.0, yaw_rate=0.0, dt=0.1):
    """A level, still (or yawing) IMU: gyro, accel, mag rows and the true quaternions."""
    rng = np.random.default_rng(seed)
    m_n = np.array([0.3, 0.0, 0.4])
    rows, qt = [], []
    for k in range(n):
        q = q_from_euler(0.0, 0.0, yaw + yaw_rate * dt * k)
        Rm = rotmat(q)
        f = Rm.T @ np.array([0.0, 0.0, -G0])
        m = Rm.T @ m_n + mag_noise * rng.standard_normal(3)
        rows.append(((0.0, 0.0, yaw_rate), f, m))
        qt.append(q)
    return rows, np.array(qt)


def _as_log(rows, qt, dt=0.1):
    n = len(rows)
    return SensorLog("synthetic", np.arange(n) * dt, np.full(n, dt), np.array([r[0] for r in rows]),
                     np.array([r[1] for r in rows]), np.array([r[2] for r in rows]), np.zeros((n, 3)),
                     np.full(n, VALID_IMU, np.uint32), qt)


@pytest.mark.parametrize("mode", ["combined", "complementary"])
def test_yaw_near_180_does_not_jump(mode):
    # Heading noise of ~1° on a yaw of 179.8°: the magnetometer heading keeps crossing ±180°.
    rows, qt = _static_inputs(math.radians(179.8), 300, mag_noise=0.006)
    log = _as_log(rows, qt)
    yaw_m = np.array([R.heading(r[2], 0.0, 0.0, 0.0) for r in rows])
    assert np.any(yaw_m < 0) and np.any(yaw_m > 0)      # the test does cross the seam
    _, hf = built("double", mode=mode)
    c = hf.run(log)
    q, _, _ = R.run(log, config.resolve("cpf", sets=[f"mode={mode}"], precision="double").params, return_ref=True)
    for qq in (c.q, q):
        err = np.degrees(np.abs(np.angle(np.exp(1j * (euler_from_q(qq)[:, 2] - math.radians(179.8))))))
        assert err.max() < 3.0, err.max()               # a naive average would give ~0° (180° off)
    assert max_angle_diff_rad(c.q, q) <= 1e-9


def test_yaw_rotation_through_180_is_continuous():
    rows, qt = _static_inputs(math.radians(150.0), 200, yaw_rate=math.radians(20.0))   # 150° -> 546°
    log = _as_log(rows, qt)
    _, hf = built("double")
    c = hf.run(log)
    err = np.degrees(np.abs(np.angle(np.exp(1j * (euler_from_q(c.q)[:, 2] - euler_from_q(qt)[:, 2])))))
    assert err[5:].max() < 1.0, err.max()


def _init_state(hf, n_steps=20, params=None, **kw):
    rows, qt = _static_inputs(math.radians(30.0), n_steps, **kw)
    s = hf.new_state()
    ref = R.Reference(config.resolve("cpf", sets=_sets(params or {}), precision="double").params)
    for g, f, m in rows:
        assert hf.step(s, g, f, m, (0, 0, 0), VALID_IMU, 0.1) == ref.step(g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    return s, ref, rows


def test_likelihood_and_mean_treat_q_and_minus_q_alike():
    # Without process noise the prediction maps -x to exactly -(x's prediction), so the step
    # isolates the likelihood and the weighted mean. (With noise, -x + n is not -(x + n): the
    # same draw moves a flipped particle differently - equal in distribution only.)
    params = {"process_noise": 0.0, "init_spread": 0.2}
    _, hf = built("double", **params)
    s, ref, rows = _init_state(hf, params=params)
    flipped = hf.copy_state(s)
    sign = np.where(np.arange(100) % 3 == 0, -1.0, 1.0)
    for i in range(100):
        for k in range(4):
            flipped.particles[4 * i + k] = sign[i] * s.particles[4 * i + k]
    g, f, m = rows[-1]
    a = hf.step(s, g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    b = hf.step(flipped, g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    assert a == b
    wa, wb = np.array(s.weights[:]), np.array(flipped.weights[:])
    np.testing.assert_allclose(wa, wb, rtol=1e-12, atol=0)
    assert max_angle_diff_rad(np.array([s.q[:]]), np.array([flipped.q[:]])) < 1e-12
    # the reference, flipped the same way, agrees with the C
    ref.particles = ref.particles * sign[:, None]
    ref.step(g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    np.testing.assert_allclose(ref.weights, wb, rtol=0, atol=1e-12)


@pytest.mark.parametrize("bad", [0.0, float("nan")])
def test_zero_or_corrupt_weights_reset_to_uniform(bad):
    _, hf = built("double")
    s, ref, rows = _init_state(hf)
    for i in range(100):
        s.weights[i] = bad
    ref.weights[:] = bad
    g, f, m = rows[-1]
    a = hf.step(s, g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    b = ref.step(g, f, m, (0, 0, 0), VALID_IMU, 0.1)
    assert a == b and a & R.WEIGHTS_RESET
    assert hf.manifest["status"]["WEIGHTS_RESET"] == R.WEIGHTS_RESET == st.FILTER_BASE
    w = np.array(s.weights[:])
    np.testing.assert_array_equal(w, np.full(100, 0.01))
    assert np.all(np.isfinite(s.q[:])) and abs(np.linalg.norm(s.q[:]) - 1) < 1e-12
    assert max_angle_diff_rad(np.array([s.q[:]]), np.array([ref.q])) < 1e-12


@pytest.mark.parametrize("precision", ["double", "float"])
def test_far_observation_does_not_underflow_the_weights(precision):
    """An observation 180° of yaw away from every particle: the unscaled likelihood
    exp(-4(1-|<Y,x>|)/obs_noise^2) is exp(-2.9e3) here, zero in float and double; the
    max-scaled update keeps the weights finite and needs no reset."""
    _, hf = built(precision)
    s, _, rows = _init_state(hf)
    q_far = q_from_euler(0.0, 0.0, math.radians(30.0 + 180.0))
    Rm = rotmat(q_far)
    f, m = Rm.T @ np.array([0.0, 0.0, -G0]), Rm.T @ np.array([0.3, 0.0, 0.4])
    for _ in range(5):
        code = hf.step(s, (0, 0, 0), f, m, (0, 0, 0), VALID_IMU, 0.1)
        assert code == 0
        w = np.array(s.weights[:])
        assert np.all(np.isfinite(w)) and abs(w.sum() / s.weight_sum - 1) < 1e-5
        assert R.WEIGHT_SUM_MIN <= s.weight_sum <= 1 + 1e-5
        assert np.all(np.isfinite(s.q[:]))


def test_refusals_and_skips_match_reference_and_leave_state_untouched():
    _, hf = built("double")
    s, ref, rows = _init_state(hf)
    g, f, m = rows[-1]
    nan3 = (float("nan"),) * 3
    cases = [
        ((g, f, m, VALID_IMU, 0.0), st.DT_INVALID),
        ((g, f, m, VALID_IMU, float("nan")), st.DT_INVALID),
        ((g, f, m, VALID_IMU, 5.0), st.DT_TOO_LARGE),
        ((g, f, m, VALID_ACCEL | VALID_MAG, 0.1), st.GYRO_MISSING),
        ((nan3, f, m, VALID_IMU, 0.1), st.GYRO_NONFINITE),
        (((1e3, 0, 0), f, m, VALID_IMU, 0.1), st.GYRO_RANGE),
    ]
    for (gg, ff, mm, valid, dt), code in cases:
        before = hf.state_bytes(s)
        assert hf.step(s, gg, ff, mm, (0, 0, 0), valid, dt) == code
        assert ref.step(gg, ff, mm, (0, 0, 0), valid, dt) == code
        assert hf.state_bytes(s) == before
    # skipped corrections: the step still runs, C and reference agree
    for ff, mm, code in ((nan3, m, st.ACCEL_NONFINITE), ((0, 0, 0), m, st.ACCEL_ZERO),
                         (f, nan3, st.MAG_NONFINITE), (nan3, nan3, st.ACCEL_NONFINITE | st.MAG_NONFINITE)):
        a = hf.step(s, g, ff, mm, (0, 0, 0), VALID_IMU, 0.1)
        b = ref.step(g, ff, mm, (0, 0, 0), VALID_IMU, 0.1)
        assert a == b == code
        assert max_angle_diff_rad(np.array([s.q[:]]), np.array([ref.q])) < 1e-12
        assert np.all(np.isfinite(hf.state_dict(s)["particles"]))


def test_not_initialised_until_a_usable_accelerometer_sample():
    _, hf = built("double")
    s = hf.new_state()
    before = hf.state_bytes(s)
    code = hf.step(s, (0.1, 0, 0), (0, 0, 0), (0.3, 0, 0.4), (0, 0, 0), VALID_GYRO | VALID_MAG, 0.1)
    assert code == R.NOT_INITIALISED
    assert hf.state_bytes(s) == before
    ref = R.Reference(config.resolve("cpf", precision="double").params)
    assert ref.step((0.1, 0, 0), (0, 0, 0), (0.3, 0, 0.4), (0, 0, 0), VALID_GYRO | VALID_MAG, 0.1) == code


def test_systematic_resampling_copy_counts():
    """Systematic resampling gives particle i floor(N w_i) or ceil(N w_i) copies."""
    rng = np.random.default_rng(5)
    ref = R.Reference({"n_particles": 64})
    for _ in range(50):
        w = rng.exponential(size=64) ** 3
        w /= w.sum()
        ref.weights = w.copy()
        ref.particles = np.column_stack([np.arange(64.0), np.zeros((64, 3))])   # tag = index
        ref._resample()
        counts = np.bincount(ref.particles[:, 0].astype(int), minlength=64)
        assert counts.sum() == 64
        assert np.all(counts >= np.floor(64 * w - 1e-9)) and np.all(counts <= np.ceil(64 * w + 1e-9))
        kept = np.flatnonzero(counts)                    # a selected particle keeps its own slot
        assert np.all(ref.particles[kept, 0] == kept)


# ---- generated files ----------------------------------------------------------------------------

def test_generated_cpf_is_fresh():
    gen = render.render(config.resolve("cpf"))
    d = REPO / "generated" / "cpf"
    for name, text in gen.files.items():
        assert (d / name).read_text() == text, f"generated/cpf/{name} is stale: run 'ahrsgen generate cpf -o generated/cpf'"


def test_state_holds_particles_no_heap():
    for n in (50, 100, 200):
        for precision, rb in (("float", 4), ("double", 8)):
            _, hf = built(precision, n_particles=n)
            size = hf.manifest["structs"]["state"]["size"]
            assert size == ctypes.sizeof(hf.State)
            # q, q_cf, particles, weights, scratch, weight_sum, ess (real) + rng, resample_count,
            # initialised (uint32)
            reals, words = 4 + 4 + 4 * n + n + n + 1 + 1, 2 + 1 + 1
            assert size == -(-(rb * reals + 4 * words) // rb) * rb
    src = (REPO / "generated" / "cpf" / "cpf.c").read_text()
    for word in ("malloc", "calloc", "realloc", "free(", "alloca"):
        assert word not in src


@needs("arm-none-eabi-gcc")
def test_float_build_compiles_for_cortex_m4f(tmp_path):
    d = REPO / "generated" / "cpf"
    r = subprocess.run(["arm-none-eabi-gcc", *host.STRICT, "-O2", "-mcpu=cortex-m4", "-mthumb",
                        "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-fno-math-errno", "-c", str(d / "cpf.c"),
                        f"-I{d}", "-o", str(tmp_path / "cpf.o")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    nm = subprocess.run(["arm-none-eabi-nm", "-u", str(tmp_path / "cpf.o")], capture_output=True, text=True).stdout
    undefined = {ln.split()[-1] for ln in nm.splitlines() if ln.strip()}
    # math = "fast": no libm at all (the likelihood and the ziggurat's wedge use cpf_exp_nonpos,
    # its rare tail fast_logf)
    assert not undefined & {"logf", "cosf", "sinf", "expf", "atan2f", "nanf"}
    assert not undefined & {"sqrt", "log", "cos", "sin", "exp", "atan2", "asin", "floor"}


@pytest.mark.parametrize("precision", ["double", "float"])
def test_cli_validate_on_turntable(precision, capsys):
    from ahrsgen import cli
    code = cli.main(["validate", "cpf", "--precision", precision, "--scenario", "turntable"])
    out = capsys.readouterr().out
    assert code == 0, out
    if precision == "float" and "judged as estimators" in out:
        assert "double C vs reference" in out and "particle-noise streams" in out


def test_float_vs_double_as_estimators_passes_and_sees_a_planted_float_error():
    """src/ahrsgen/sim/stochastic.py: the float build at defaults passes the paired test over 10
    particle-noise streams; a float build whose process noise is 2x the double's (standing in for a
    wrong float literal) fails it."""
    from ahrsgen.sim import stochastic
    log = _log("turntable")
    cfg, hd = built("double", **site("turntable"))
    model = cfg.spec.model(cfg.params)
    _, hf = built("float", **site("turntable"))
    good = stochastic.float_vs_double(hf, hd, log, model)
    assert good["ok"], good
    _, bad_hf = built("float", process_noise=2 * cfg.params["process_noise"], **site("turntable"))
    bad = stochastic.float_vs_double(bad_hf, hd, log, model)
    assert not bad["ok"], bad


@pytest.mark.parametrize("precision", ["double", "float"])
def test_unnormalised_weights_are_renormalised_below_the_bound(precision):
    """The weights are kept unnormalised with their sum, which each update only decreases (every
    likelihood factor <= 1); without resampling (ess_threshold 0) it falls below 2^-20 within a
    few steps, and the update then normalises the weights in place. So the sum stays in
    [2^-20, 1] and the stored weights are the normalised ones times it; in double the C follows
    the reference through every renormalisation."""
    params = {"ess_threshold": 0.0}
    _, hf = built(precision, **params)
    rows, _ = _static_inputs(math.radians(30.0), 40)
    jump, _ = _static_inputs(math.radians(34.0), 10)
    s = hf.new_state()
    ref = R.Reference(config.resolve("cpf", sets=_sets(params), precision="double").params)
    renormalised, last = 0, 1.0
    for g, f, m in rows + jump:
        code = hf.step(s, g, f, m, (0, 0, 0), VALID_IMU, 0.1)
        assert code == ref.step(g, f, m, (0, 0, 0), VALID_IMU, 0.1) == 0
        wsum = s.weight_sum
        assert R.WEIGHT_SUM_MIN <= wsum <= 1 + 1e-5
        w = np.array(s.weights[:])
        assert np.all(w >= 0) and abs(w.sum() / wsum - 1) < 1e-5
        renormalised += wsum > last       # only a renormalisation raises it (no resampling here)
        last = wsum
        if precision == "double":
            np.testing.assert_allclose(w / wsum, ref.weights / ref.weight_sum, rtol=0, atol=1e-9)
            assert max_angle_diff_rad(np.array([s.q[:]]), np.array([ref.q])) < 1e-9
    assert s.resample_count == 0 and renormalised >= 3, renormalised


@pytest.mark.parametrize("precision", ["double", "float"])
def test_genuine_weight_underflow_is_reset_not_divided(precision):
    """Never resampling (ess_threshold 0) with a sharp likelihood, the weights degenerate: all
    but one or two particles' weights underflow to exactly zero, and when the surviving ones
    random-walk away from the observation (or the heading jumps 40°) their likelihood factors
    underflow too. The weights then sum to zero, and the step resets them to 1/N with
    WEIGHTS_RESET instead of dividing by zero."""
    params = {"ess_threshold": 0.0, "obs_noise": 0.005, "process_noise": 0.1}
    _, hf = built(precision, **params)
    rows, _ = _static_inputs(math.radians(30.0), 60)
    jump, _ = _static_inputs(math.radians(70.0), 5)
    s = hf.new_state()
    ref = R.Reference(config.resolve("cpf", sets=_sets(params), precision="double").params)
    codes_c, codes_r = [], []
    for g, f, m in rows + jump:
        codes_c.append(hf.step(s, g, f, m, (0, 0, 0), VALID_IMU, 0.1))
        codes_r.append(ref.step(g, f, m, (0, 0, 0), VALID_IMU, 0.1))
        w = np.array(s.weights[:])
        assert np.all(np.isfinite(w)) and abs(w.sum() / s.weight_sum - 1) < 1e-5
        assert R.WEIGHT_SUM_MIN <= s.weight_sum <= 1 + 1e-5
        assert np.all(np.isfinite(s.q[:]))
    reset_c = [k for k, c in enumerate(codes_c) if c & R.WEIGHTS_RESET]
    assert reset_c, codes_c
    assert all(c & ~R.WEIGHTS_RESET == 0 for c in codes_c)
    if precision == "double":
        assert codes_c == codes_r
        assert max_angle_diff_rad(np.array([s.q[:]]), np.array([ref.q])) < 1e-9


def _state_whose_next_draw_is(x: int) -> list[int]:
    """A xoroshiro64** state [s0, s1] whose next output is x: the output is
    rotl(s0 * 0x9E3779BB, 5) * 5 mod 2^32, so s0 = rotr(x * 5^-1, 5) * 0x9E3779BB^-1 (both
    multipliers are odd, hence invertible mod 2^32); s1 does not enter the output."""
    m = 1 << 32
    y = (x * pow(5, -1, m)) % m
    y = ((y >> 5) | (y << 27)) & (m - 1)
    return [(y * pow(0x9E3779BB, -1, m)) % m, 1]


@pytest.mark.parametrize("precision", ["double", "float"])
def test_uniform_interval_is_open_at_zero_closed_at_one(precision):
    """The documented interval (0, 1] at its two ends, with raw draws chosen, not hoped for
    (a draw whose top 24 bits are zero comes once in 2^24): the smallest draw gives 2^-24, never
    0 (the ziggurat's tail takes log of it), the largest gives exactly 1; in C and in Python."""
    lib, npr, _ = _hook(precision)
    for raw, expect in ((0, 2.0 ** -24), (0xFF, 2.0 ** -24), (0x100, 2.0 ** -23), (0xFFFFFFFF, 1.0)):
        st0 = _state_whose_next_draw_is(raw)
        g = Xoroshiro64ss(1)
        g.s = list(st0)
        assert g.next_u32() == raw                      # the state is the one we meant
        g.s = list(st0)
        assert g.uniform() == expect, (raw, g.s)
        state = (ctypes.c_uint32 * 2)(*st0)
        u = np.zeros(1, npr)
        lib.cpf_hook_uniform(state, 1, u.ctypes.data)
        assert float(u[0]) == expect, (precision, raw)
        assert math.isfinite(-math.log(float(u[0])))
