"""Recovery after gyro over-range (issue 26). mekf: a clipped gyro sample widens the attitude
covariance by the rotation it may have missed, and the sensors then bring the attitude back;
qcf: the correction takes the sensors as they come with kp_recovery; adukf (error state): the
covariance is widened as mekf's and R is not adapted while recovering.

Checked against the truth of the gyro_clip scenario (a roll flip that holds the gyro at its
+-500 deg/s range for 0.3 s), against the same flip below the range (no status, no change), and
against the independent NumPy reference step by step through the clip.
"""
import numpy as np
import pytest

from ahrsgen import status as st
from ahrsgen.generate import config
from ahrsgen.npquat import qconj, qmul
from ahrsgen.sim import host
from ahrsgen.sim.metrics import max_angle_diff_rad
from ahrsgen.sim.scenarios import make
from docs_tables import min_max_rows

RANGE = f"gyro_full_scale={float(np.radians(500.0))!r}"      # the scenario's gyro: +-500 deg/s


FILTERS = ["mekf", "qcf", "adukf"]


def build(name, precision="float", sets=()):
    return host.build(config.resolve(name, sets=list(sets), precision=precision))


def error_deg(q, q_true):
    d = qmul(qconj(q_true), q)
    return np.degrees(2 * np.arccos(np.clip(np.abs(d[:, 0]), 0.0, 1.0)))


@pytest.mark.parametrize("name", FILTERS)
def test_back_within_2_deg_within_3_s_of_the_clip(name):
    """5 seeds: from 3 s after the last clipped sample to the end (9 s), the attitude is within
    2 deg of the truth (issue 26's acceptance). Without the over-range handling
    (gyro_full_scale = 0) the same filter is still 5+ deg off there: the clip costs 14-19 deg
    and the low-passed corrections take it back slowly (measured mekf 8-13 deg, qcf 10-13,
    adukf 13-18). mekf's gyro_rate_noise alone widens the covariance at the clipped 500 deg/s
    too and takes part of it back (3.2-8.2 deg without the handling), so it is off in the
    comparison: this test is about the handling."""
    f_off = build(name, sets=["gyro_full_scale=0"] + (["gyro_rate_noise=0"] if name == "mekf" else []))
    f = build(name, sets=[RANGE])
    for seed in range(5):
        log = make("gyro_clip", seed=seed)
        clip = log.meta["clip"]
        assert 0.25 <= clip["end_s"] - clip["start_s"] <= 0.35, clip       # the scenario: 0.3 s
        after = log.t >= clip["end_s"] + 3.0
        assert error_deg(f.run(log).q, log.q_true)[after].max() <= 2.0, seed
        assert error_deg(f_off.run(log).q, log.q_true)[after].max() > 5.0, seed


@pytest.mark.parametrize("name", FILTERS)
def test_a_clip_below_the_default_range_is_found_by_its_plateau(name):
    """The user left gyro_full_scale at its default (2000 deg/s) and the gyro clips at 500: the
    log does not state its range. A clipped component repeats the range's end exactly, and the
    filters take 4 such samples in a row (gyro_plateau_rate) for a clip. At 200 Hz, 5 seeds:
    back within 2 deg within 3 s, as with the range configured; with gyro_plateau_rate = 0 more
    than 3 deg off on every seed (measured: mekf 3.2-8.2, qcf 10-13, adukf 12-18). At 90 Hz (the
    held-back pendulum's rate) the result with the range unstated is within 0.1 deg of the one
    with it configured (the plateau costs 3 samples of detection)."""
    f = build(name)
    f_off = build(name, sets=["gyro_plateau_rate=0"])
    f_told = build(name, sets=[RANGE])
    for seed in range(5):
        log = make("gyro_clip", seed=seed, range_stated=False)
        assert "gyro_full_scale_rad_s" not in log.meta
        after = log.t >= log.meta["clip"]["end_s"] + 3.0
        assert error_deg(f.run(log).q, log.q_true)[after].max() <= 2.0, seed
        assert error_deg(f_off.run(log).q, log.q_true)[after].max() > 3.0, seed
        slow = make("gyro_clip", seed=seed, rate_hz=90.0, range_stated=False)
        after = slow.t >= slow.meta["clip"]["end_s"] + 3.0
        e, e_told = (error_deg(g.run(slow).q, slow.q_true)[after].max() for g in (f, f_told))
        assert abs(e - e_told) <= 0.1, (seed, e, e_told)


def test_the_reference_states_the_plateau_rule_as_the_model_does():
    from ahrsgen import reference_aiding
    from ahrsgen.symbolic import aiding
    assert (reference_aiding.PLATEAU_SAMPLES, reference_aiding.PLATEAU_TOL) == (aiding.PLATEAU_SAMPLES,
                                                                             aiding.PLATEAU_TOL)


def test_the_plateau_is_not_a_duplicate_or_a_slow_repeat():
    """What the plateau is not, in the C (qcf's kernel, the one all three filters share): a whole
    sample repeated (a logger's duplicate), a component repeating below gyro_plateau_rate, or a
    fast one repeating only 3 times in a row; and what it is: the 4th equal fast sample."""
    f = build("qcf")
    bit = np.uint32(f.manifest["status"]["GYRO_RECOVERY"])
    n, rate = 1000, 200.0
    base = make("gyro_clip", seed=0, clip_s=0.0, range_stated=False)
    cases = {}
    for label, rows, value, other_changes in [("duplicate samples", 6, 5.0, False),
                                              ("slow component", 6, 3.0, True),
                                              ("3 equal fast samples", 3, 5.0, True),
                                              ("4 equal fast samples", 4, 5.0, True)]:
        log = base.slice(0, n)
        log.gyro = log.gyro.copy()
        k = np.arange(300, 300 + rows)
        log.gyro[k, 0] = value
        if not other_changes:
            log.gyro[k, 1:] = log.gyro[300, 1:]
        on = (f.run(log).status & bit) != 0
        cases[label] = on
    assert not any(cases[k].any() for k in ("duplicate samples", "slow component", "3 equal fast samples"))
    on = cases["4 equal fast samples"]
    assert on[303] and not on[:303].any()
    assert abs(np.count_nonzero(on) - 2.0 * rate) <= 2            # clip_recovery_time (2 s) from there


def test_no_plateau_in_the_full_broad_trials():
    """The default gyro_plateau_rate (200 deg/s) finds no clip in the 10 BROAD trials (286 Hz,
    rotations up to 1 350 deg/s, a gyro that never clips): GYRO_RECOVERY is never set."""
    from ahrsgen.sim import readers
    trials = readers.broad_trials()
    if not trials:
        pytest.skip("BROAD subset not found (../shared/data/broad or $AHRSGEN_DATA)")
    f = build("qcf")
    bit = np.uint32(f.manifest["status"]["GYRO_RECOVERY"])
    for p in trials:
        assert not np.any(f.run(readers.read_broad(p)).status & bit), p.name


@pytest.mark.parametrize("name", FILTERS)
def test_recovery_status_spans_the_clip_and_clip_recovery_time(name):
    """GYRO_RECOVERY is set from the first clipped sample to clip_recovery_time after the last,
    and never on the same flip done slowly enough that the gyro stays in range; there the
    handling changes nothing (bit-identical to gyro_full_scale = 0)."""
    f = build(name, sets=[RANGE, "clip_recovery_time=1.5"])
    bit = f.manifest["status"]["GYRO_RECOVERY"]
    assert bit >= st.FILTER_BASE and not bit & f.manifest["status_fault_mask"]
    log = make("gyro_clip", seed=1)
    on = (f.run(log).status & np.uint32(bit)) != 0
    raw = np.any(np.abs(log.gyro) >= np.radians(500.0), axis=1)
    t_on = log.t[on]
    assert t_on[0] == log.t[raw][0]
    assert abs(t_on[-1] - (log.t[raw][-1] + 1.5)) <= 1.5 * np.max(log.dt)
    assert np.count_nonzero(on) == np.count_nonzero((log.t >= t_on[0]) & (log.t <= t_on[-1]))
    slow = make("gyro_clip", seed=1, clip_s=0.0)
    assert np.abs(slow.gyro).max() < np.radians(500.0)
    r = f.run(slow)
    assert not np.any(r.status & np.uint32(bit))
    assert np.array_equal(r.q, build(name, sets=["gyro_full_scale=0"]).run(slow).q)


@pytest.mark.parametrize("name", FILTERS)
def test_double_c_equals_the_reference_through_the_clip(name):
    cfg = config.resolve(name, sets=[RANGE], precision="double")
    log = make("gyro_clip", seed=2)
    c = host.build(cfg).run(log)
    r = host.run_reference(cfg.spec.reference(cfg.params), log)
    assert np.array_equal(c.status, r.status)
    assert np.any(c.status & np.uint32(host.build(cfg).manifest["status"]["GYRO_RECOVERY"]))
    assert max_angle_diff_rad(c.q, r.q) <= 1e-9


def test_the_log_states_its_gyro_range_as_a_user_sets_it():
    """gyro_clip states its gyro's range; run, validate and bench set gyro_full_scale from it
    (bench.site_values) unless the user set it."""
    from ahrsgen.bench import site_values
    meta = make("gyro_clip", seed=0).meta
    for name in FILTERS:
        assert site_values(name, meta)[0]["gyro_full_scale"] == np.radians(500.0)
        assert "gyro_full_scale" not in site_values(name, meta, {"gyro_full_scale"})[0]
    assert "gyro_full_scale" not in site_values("cpf", meta)[0]


def test_docs_table_of_gyro_clip_holds():
    """Every row of docs/scenarios.md's gyro_clip table, re-measured (seeds 0-4, to its 0.01 deg)."""
    from ahrsgen.sim import peers
    fs = float(np.radians(500.0))
    runs = {}
    for name in FILTERS:
        runs[name] = build(name, sets=[f"gyro_full_scale={fs!r}"]).run
        runs[f"{name}, gyro_full_scale = 0"] = build(name, sets=["gyro_full_scale=0"]).run
    stated = min_max_rows("scenarios.md", "Largest attitude error from 3 s after the clip")
    assert set(stated) == set(runs) | {"vqf", "fusion (defaults)", "fusion, gyroscope_range = 500", "mahony"}
    peer = {"vqf": ("vqf", {}), "fusion (defaults)": ("fusion", {}),
            "fusion, gyroscope_range = 500": ("fusion", {"gyroscope_range": 500.0}), "mahony": ("mahony", {})}
    worst = {k: [] for k in stated}
    for seed in range(5):
        log = make("gyro_clip", seed=seed)
        after = log.t >= log.meta["clip"]["end_s"] + 3.0
        for k in stated:
            q = runs[k](log).q if k in runs else peers.run(peer[k][0], log, **peer[k][1])
            worst[k].append(error_deg(q, log.q_true)[after].max())
    for k, (lo, hi) in stated.items():
        assert (round(min(worst[k]), 2), round(max(worst[k]), 2)) == (lo, hi), k


@pytest.mark.parametrize("name", FILTERS)
def test_gyro_plateau_rate_0_set_at_run_time_turns_the_plateau_off(name):
    """gyro_plateau_rate = 0 means "only gyro_full_scale" (its doc) whether it is baked in or set
    at run time (<prefix>_set_params): a fast component held for 6 samples, the others changing,
    sets GYRO_RECOVERY with the default rate and never with 0, in both builds, as in the
    reference (which treats 0 as off)."""
    log = make("gyro_clip", seed=0, clip_s=0.0, range_stated=False).slice(0, 1000)
    log.gyro = log.gyro.copy()
    log.gyro[300:306, 0] = 5.0                       # rad/s, above the default 3.5, below full scale
    rt = host.build(config.resolve(name, precision="double", runtime="gyro_plateau_rate"))
    bit = np.uint32(rt.manifest["status"]["GYRO_RECOVERY"])
    baked_off = build(name, precision="double", sets=["gyro_plateau_rate=0"])
    assert (rt.run(log).status & bit).any()                             # the default rate: a clip
    assert not (rt.run(log, params={"gyro_plateau_rate": 0.0}).status & bit).any()
    assert not (baked_off.run(log).status & bit).any()
