"""The shared hard iron in qcf and adukf (issue 25; mekf's own checks are test_mekf_hard_iron.py):
symbolic/aiding.hard_iron_step in the C, reference_aiding.HardIron in the references.

Checked against the truth of the attached_magnet scenario (the magnet's offset is known), against
the independent NumPy reference step by step through a switch (double C), float against double,
and on real data without a magnet (the committed BROAD excerpt: no switch).
"""
from pathlib import Path

import numpy as np
import pytest

from ahrsgen.bench.scoring import site_sets
from ahrsgen.generate import config
from ahrsgen.sim import host
from ahrsgen.sim.metrics import broad_errors_deg, max_angle_diff_rad
from ahrsgen.sim.readers import read_log
from ahrsgen.sim.scenarios import make
from conftest import REPO

EXCERPT = REPO / "src/ahrsgen/sim/data/broad_01_excerpt.csv.gz"
FILTERS = ("qcf", "adukf")


def bits(name, log, sets=(), precision="float"):
    """(HARD_IRON_SWITCHED, MAG_DISTURBED) of the filter's build for this log's site."""
    man = build(name, log, sets, precision).manifest["status"]
    return man["HARD_IRON_SWITCHED"], man["MAG_DISTURBED"]


def build(name, log, sets=(), precision="float"):
    """The build `ahrsgen bench` runs on this log (its site parameters: adukf takes the
    scenario's inclination)."""
    extra, _ = site_sets(name, log.meta)
    return host.build(config.resolve(name, sets=list(extra) + list(sets), precision=precision))


def heading_rms(q, log):
    keep = log.t >= log.settle_time
    return float(np.sqrt(np.mean(broad_errors_deg(q[keep], log.q_true[keep])[1] ** 2)))


@pytest.mark.parametrize("name", FILTERS)
def test_attached_magnet_heading_within_3_deg_and_the_hard_iron_found(name):
    """Issue 25's bound (mekf's), for qcf and adukf: heading RMS <= 3 deg from 30 s after the
    magnet arrives, one switch after its arrival with the magnet's offset to 3 mag_bias_th of the
    field, and without the hard iron more than the 3 deg bound (the figure the hard iron is for;
    5 deg before issue 26's adukf defaults, whose smaller gyro density leaves 4.5 deg on seed 0)."""
    for seed in (0, 1, 2):
        log = make("attached_magnet", seed)
        f = build(name, log)
        r = f.run(log)
        switched, _ = bits(name, log)
        mg = log.meta["magnet"]
        assert heading_rms(r.q, log) <= 3.0, (name, seed)
        sw = np.flatnonzero(r.status & switched)
        assert len(sw) >= 1 and log.t[sw[0]] > mg["attach_time_s"], (name, seed, log.t[sw])
        b = f.state_dict(f.last_state)["mag_bias"]
        th = config.resolve(name).params["mag_bias_th"]
        assert np.linalg.norm(b - mg["offset_body"]) <= 3 * th * 50.0, (name, seed, b, mg["offset_body"])
        off = build(name, log, ["mag_bias=false"]).run(log)
        assert heading_rms(off.q, log) > 3.0, (name, seed)


@pytest.mark.parametrize("name", FILTERS)
def test_no_switch_without_a_magnet(name):
    """Real data without a magnet (the BROAD excerpt) and a simulated log whose magnet never
    comes: no switch, the hard iron stays zero."""
    real = read_log(EXCERPT)
    f = build(name, real)
    r = f.run(real)
    switched, _ = bits(name, real)
    assert not np.any(r.status & switched)
    assert np.allclose(f.state_dict(f.last_state)["mag_bias"], 0.0)
    log = make("attached_magnet", 0, attach_time=1e3, duration=90.0)
    f = build(name, log)
    r = f.run(log)
    assert not np.any(r.status & switched)
    assert np.allclose(f.state_dict(f.last_state)["mag_bias"], 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("name", FILTERS)
def test_double_c_matches_reference_through_a_switch(name):
    """Double C = the NumPy reference at every step (status, attitude <= 1e-9 rad) on a log with
    a hard-iron switch (the magnet at 15 s, switched at 42 s of 60)."""
    log = make("attached_magnet", 0, attach_time=15.0, duration=60.0)
    r = build(name, log, precision="double").run(log)
    extra, _ = site_sets(name, log.meta)
    cfg = config.resolve(name, sets=extra)
    rr = host.run_reference(cfg.spec.reference(cfg.params), log)
    switched, disturbed = bits(name, log, precision="double")
    assert np.count_nonzero(r.status & switched) >= 1
    assert np.any(r.status & disturbed)        # the candidate was the better model before the switch
    assert np.array_equal(r.status, rr.status)
    assert max_angle_diff_rad(r.q, rr.q) <= 1e-9


@pytest.mark.parametrize("name", FILTERS)
def test_float_parts_from_double_only_at_the_switch(name):
    """As mekf's: float and double C differ in status only at steps within 0.1 s of a hard-iron
    switch of either build (a threshold decision on a candidate fitted over thousands of steps),
    and their attitudes agree to 1e-3 rad throughout."""
    log = make("attached_magnet", 0)
    f, d = build(name, log).run(log), build(name, log, precision="double").run(log)
    switched, _ = bits(name, log)
    assert np.any(d.status & switched) and np.any(f.status & switched)
    differ = np.flatnonzero(f.status != d.status)
    switches = np.flatnonzero((f.status | d.status) & switched)
    assert len(differ) <= 20, f"{len(differ)} steps differ"
    assert all(np.min(np.abs(log.t[switches] - log.t[k])) <= 0.1 for k in differ), log.t[differ]
    assert max_angle_diff_rad(f.q, d.q) <= 1e-3
