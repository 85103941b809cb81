"""The steps of qcf, mekf and adukf skip the gyro over-range kernel on a step where it can change
nothing: |gyro|^2 below the smaller of gyro_full_scale^2 and gyro_plateau_rate^2, no plateau run
counting and no recovery time left (codegen/templates/gyro_recovery.c.j2). The skip must be
exact: checked on the two edges a wrong gate would miss, against each filter's NumPy reference
(which has no gate) and, in float, against the rule.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import host_build
from ahrsgen.generate import config
from ahrsgen.sim import host
from ahrsgen.sim.scenarios import make


def _quiet_log(n=600):
    """gyro_clip without its clip: a slow flip, every gyro component well below 3.5 rad/s."""
    log = make("gyro_clip", seed=0, clip_s=0.0, range_stated=False).slice(0, n)
    log.gyro = log.gyro.copy()
    assert np.abs(log.gyro).max() < 3.0
    return log


FILTERS = ["qcf", "mekf", "adukf"]


def _recovery(name, name_sets, log, precision="float"):
    f = host_build(name, precision, tuple(name_sets))
    return (f.run(log).status & np.uint32(f.manifest["status"]["GYRO_RECOVERY"])) != 0


def _reference_recovery(name, name_sets, log):
    cfg = config.resolve(name, sets=list(name_sets), precision="double")
    r = host.run_reference(cfg.spec.reference(cfg.params), log)
    return (r.status & np.uint32(host.build(cfg).manifest["status"]["GYRO_RECOVERY"])) != 0


@pytest.mark.parametrize("name", FILTERS)
def test_a_plateau_count_ends_on_a_slow_sample_the_gate_would_skip(name):
    """x repeats 3.5 rad/s (the default gyro_plateau_rate) 3 times (its run count reaches 2),
    then 3.5 - 5e-7 (the same value within PLATEAU_TOL but below the rate: the count restarts,
    and |gyro|^2 < 3.5^2, so only the running count makes the step run the kernel), then 3.5
    again: a count of 1, no clip. Had the slow step been skipped, the count would have gone on to
    3 and flagged a clip. The positive control, 3.5 four times, is a clip at its 4th sample."""
    k = 300
    logs = {}
    for label, x3 in (("interrupted", 3.5 - 5e-7), ("four equal", 3.5)):
        log = _quiet_log()
        for j, x in enumerate((3.5, 3.5, 3.5, x3, 3.5)):
            log.gyro[k + j] = (x, 1e-4 * (j + 1), -1e-4 * (j + 1))      # y, z change: no duplicate
        logs[label] = log
    g = logs["interrupted"].gyro[k + 3].astype(np.float32)
    assert np.sum(g * g, dtype=np.float32) < np.float32(3.5) * np.float32(3.5)   # the gate's bound holds
    for precision in ("float", "double"):
        on = _recovery(name, (), logs["interrupted"], precision)
        assert not on.any(), precision
        control = _recovery(name, (), logs["four equal"], precision)
        assert control[k + 3] and not control[:k + 3].any(), precision
    assert not _reference_recovery(name, (), logs["interrupted"]).any()
    assert _reference_recovery(name, (), logs["four equal"])[k + 3]


@pytest.mark.parametrize("name", FILTERS)
def test_a_full_scale_below_the_plateau_rate_bounds_the_gate(name):
    """gyro_full_scale = 3 rad/s, below the plateau rate: a single 3.2 rad/s sample (|gyro|^2 <
    3.5^2) is a clip, recovering for clip_recovery_time (2 s) from it, as the reference says."""
    sets = ("gyro_full_scale=3.0",)
    k = 300
    log = _quiet_log(1200)
    log.gyro[k] = (3.2, 0.01, -0.02)
    on = _recovery(name, sets, log)
    assert on[k] and not on[:k].any()
    assert abs(np.count_nonzero(on) - 2.0 / np.median(log.dt)) <= 2
    np.testing.assert_array_equal(_recovery(name, sets, log, "double"), _reference_recovery(name, sets, log))
    assert not _recovery(name, (), log).any()          # the default full scale (2000 deg/s): no clip
