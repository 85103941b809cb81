"""MEKF hard iron (issue 25): a magnet attached to the sensor mid-run becomes a new hard iron.

Checked against the truth of the attached_magnet scenario (the magnet's body-frame offset is
known), against the independent NumPy reference step by step through a switch, against finite
differences (the rows' Jacobians), and on real data that has no magnet (the committed BROAD
excerpt: no switch).
"""
import numpy as np
import pytest

from ahrsgen.sim import host
from ahrsgen.sim.metrics import broad_errors_deg, max_angle_diff_rad
from ahrsgen.sim.readers import read_log
from ahrsgen.sim.scenarios import make
from ahrsgen.generate import config
from ahrsgen.filters.mekf import reference as R
from ahrsgen.symbolic import aiding
from ahrsgen.npquat import q_from_euler, rotmat
from pathlib import Path

from docs_tables import min_max_rows
from conftest import REPO

EXCERPT = REPO / "src/ahrsgen/sim/data/broad_01_excerpt.csv.gz"


def build(precision="float", sets=()):
    return host.build(config.resolve("mekf", sets=list(sets), precision=precision))


def scored_heading_rms(q, log):
    keep = log.t >= log.settle_time
    return float(np.sqrt(np.mean(broad_errors_deg(q[keep], log.q_true[keep])[1] ** 2)))


def test_attached_magnet_heading_within_3_deg_and_the_hard_iron_found():
    """5 seeds, magnets of 0.3-1x the Earth's field at 40-60 s: heading RMS from 30 s after the
    arrival within 3 deg; a switch, after the arrival, to a hard iron within 3 sigma of the
    magnet's true offset, sigma being what the switch requires of the candidate (the root of its
    covariance trace below mag_bias_th = 1.5 % of the field): 4.5 % of the field. Without the estimate (mag_bias = false) and
    the heading gate (mag_head_sigmas = 0) the heading is lost (> 10 deg; measured 17.9 and 49.4
    deg): the scenario is not one the old design passes (the gate alone holds seed 0 at 2.6 deg,
    seed 1 not: 38.2)."""
    f, f_off = build(), build(sets=["mag_bias=false", "mag_head_sigmas=0"])
    for seed in range(5):
        log = make("attached_magnet", seed)
        mg = log.meta["magnet"]
        r = f.run(log)
        assert scored_heading_rms(r.q, log) <= 3.0, seed
        sw = np.nonzero(r.status & R.HARD_IRON_SWITCHED)[0]
        assert len(sw) >= 1 and log.t[sw[0]] > mg["attach_time_s"], (seed, log.t[sw])
        b = np.array(f.state_dict(f.last_state)["mag_bias"])
        th = config.resolve("mekf").params["mag_bias_th"]
        assert np.linalg.norm(b - mg["offset_body"]) <= 3 * th * 50.0, (seed, b, mg["offset_body"])
        if seed < 2:
            assert scored_heading_rms(f_off.run(log).q, log) > 10.0, seed


@pytest.mark.slow
def test_docs_table_of_attached_magnet_holds():
    """Every row of docs/scenarios.md's attached_magnet table, re-measured (seeds 0-4, to its
    0.01 deg): heading RMS from settle_time."""
    from ahrsgen.sim import peers
    runs = {"mekf": build().run, "mekf, mag_bias = false": build(sets=["mag_bias=false"]).run,
            **{f"{n}{k}": host.build(config.resolve(n, sets=s)).run for n in ("qcf", "adukf")
               for k, s in (("", []), (", mag_bias = false", ["mag_bias=false"]))}}
    stated = min_max_rows("scenarios.md", "Heading RMS from `settle_time` to the end")
    assert set(stated) == set(runs) | {"vqf", "fusion"}
    rms = {k: [] for k in stated}
    for seed in range(5):
        log = make("attached_magnet", seed)
        for k in stated:
            rms[k].append(scored_heading_rms(runs[k](log).q if k in runs else peers.run(k, log), log))
    for k, (lo, hi) in stated.items():
        assert (round(min(rms[k]), 2), round(max(rms[k]), 2)) == (lo, hi), k


def test_no_switch_without_a_magnet():
    """The same motion without the magnet, and the committed BROAD excerpt (real sensor, no
    magnet): never a switch, never suspect (MAG_DISTURBED) in the simulated log."""
    f = build()
    log = make("attached_magnet", 1, strength=0.0)
    r = f.run(log)
    assert not np.any(r.status & R.HARD_IRON_SWITCHED)
    assert not np.any(r.status[log.t > 3.0] & R.MAG_DISTURBED)
    assert np.allclose(f.state_dict(f.last_state)["mag_bias"], 0.0)
    real = read_log(EXCERPT)
    assert not np.any(f.run(real).status & R.HARD_IRON_SWITCHED)


def test_a_hard_iron_smaller_than_mag_bias_jump_is_not_taken():
    """A magnet of 0.12 of the field (the size of the spurious hard irons BROAD's phone-vibration
    trial shows without a magnet) is left to the field check; one of 0.3 (the smallest the issue
    asks to catch) is taken, seeds 0-2."""
    f = build()
    for seed in range(3):
        small = f.run(make("attached_magnet", seed, strength=0.12))
        assert not np.any(small.status & R.HARD_IRON_SWITCHED), seed
        log = make("attached_magnet", seed, strength=0.3)
        r = f.run(log)
        assert np.any(r.status & R.HARD_IRON_SWITCHED), seed
        assert scored_heading_rms(r.q, log) <= 3.0, seed


def test_hard_iron_held_while_not_turning():
    """A magnet attached while the sensor is at rest (before the rotation starts at 10 s) and
    the rotation then stopped for good: no switch while not turning; the candidate learns only
    once the sensor turns."""
    f = build()
    log = make("attached_magnet", 2, attach_time=3.0, duration=9.5)
    r = f.run(log)
    assert not np.any(r.status & R.HARD_IRON_SWITCHED)
    st = f.state_dict(f.last_state)
    assert st["mag_turn_time"] == 0.0 and np.allclose(st["mag_bias"], 0.0)


@pytest.mark.slow
def test_double_c_matches_reference_through_a_switch():
    """Double C = the NumPy reference at every step (status, attitude <= 1e-9 rad) on a log with
    a hard-iron switch and a second one that refines it (smaller than mag_bias_jump: allowed
    once the present hard iron is a magnet's). With the default mag_bias_rw (0.003) no seed of
    0-29 switches twice, so the candidate's random walk is the former default, 0.001, here."""
    sets = ["mag_bias_rw=0.001"]
    log = make("attached_magnet", 8, duration=70.0)
    r = build("double", sets=sets).run(log)
    cfg = config.resolve("mekf", sets=sets)
    rr = host.run_reference(cfg.spec.reference(cfg.params), log)
    assert np.count_nonzero(r.status & R.HARD_IRON_SWITCHED) >= 2
    assert np.array_equal(r.status, rr.status)
    assert max_angle_diff_rad(r.q, rr.q) <= 1e-9


def test_float_parts_from_double_only_at_the_switch():
    """What mekf's `rounding_sensitive` declares (validate judges its float build as an estimator
    when the status codes part): float and double C differ in status only at a few steps next to a
    hard-iron switch of either build, and their attitudes agree to float rounding throughout."""
    log = make("attached_magnet", 0)
    f, d = build("float").run(log), build("double").run(log)
    assert np.any(d.status & R.HARD_IRON_SWITCHED) and np.any(f.status & R.HARD_IRON_SWITCHED)
    differ = np.flatnonzero(f.status != d.status)
    switches = np.flatnonzero((f.status | d.status) & R.HARD_IRON_SWITCHED)
    assert len(differ) <= 20, f"{len(differ)} steps differ"
    # every differing step within 0.1 s of a switch (either build's)
    assert all(np.min(np.abs(log.t[switches] - log.t[k])) <= 0.1 for k in differ), log.t[differ]
    assert max_angle_diff_rad(f.q, d.q) <= 1e-3


def test_hard_iron_rows_jacobian_matches_finite_differences():
    """The CasADi Jacobian of the two rows (norm and down component of u - beta, less n and v)
    equals central differences at a random point."""
    import casadi as ca
    rng = np.random.default_rng(3)
    q = q_from_euler(0.3, -0.2, 1.1)
    Rq = rotmat(q)
    u = rng.normal(size=3)
    x = np.concatenate([rng.normal(size=3) * 0.2, [1.05, 0.9]])
    xs = ca.SX.sym("x", 5)
    res = aiding.hard_iron_residuals(ca.DM(u), xs, ca.DM(Rq))
    fun = ca.Function("f", [xs], [res, ca.jacobian(res, xs)])
    J = np.array(fun(x)[1])
    h = 1e-6
    num = np.column_stack([(np.array(fun(x + h * e)[0]) - np.array(fun(x - h * e)[0])).ravel() / (2 * h)
                           for e in np.eye(5)])
    assert np.max(np.abs(J - num)) < 1e-8


def test_the_reference_states_the_hard_iron_constants_as_the_model_does():
    from ahrsgen import reference_aiding
    names = ("RES_TAU", "P0", "RATIO", "NORM_MIN", "N_MIN", "TIME_CAP")
    assert [getattr(reference_aiding, "HARD_IRON_" + n) for n in names] == [getattr(aiding, "HARD_IRON_" + n)
                                                                           for n in names]
