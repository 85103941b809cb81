"""A-DUKF, issue 26: r_time, the per-sample terms of R as those of a sample standing for r_time
seconds (docs/adukf.md, "One default set for any rate"), checked on the generated C against the
formula written out: R = (sigma² + min(k eps², adapt_max)) r_time / s + density² / s."""
from __future__ import annotations

import numpy as np

from ahrsgen.generate import config
from ahrsgen.sim import host
from ahrsgen.sim.scenarios import make


def _run(sets, log):
    hf = host.build(config.resolve("adukf", sets=["mag_ref=inclination", *sets], precision="double"))
    s = hf.new_state()
    q, r = [], []
    for k in range(len(log)):
        hf.step(s, log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), float(log.dt[k]))
        q.append(np.array(s.q[:]))
        r.append(np.array(s.r_diag[:]))
    return np.array(q), np.array(r)


def test_r_time_scales_the_per_sample_terms_only():
    """At a constant IMU interval dt, r_time = c dt is the filter with r_time = 0 and sigma_acc²,
    sigma_mag², k_a, k_m and adapt_max each times c, the density terms unchanged: the same
    attitude and the same R at every step (multirotor at 400 Hz, magnetometer at 100 Hz, so its
    samples stand for 4 IMU steps; 10 s, double C). A factor r_time / s instead of r_time / dt,
    the bound or sigma left per sample, or the density scaled too, all fail it."""
    log = make("multirotor", 0, duration=10.0, rate_hz=400.0, mag_rate=100.0)
    dt = float(log.dt[1])
    assert np.allclose(log.dt[1:], dt)
    p = config.resolve("adukf").params
    c = 3.0
    dens = ["sigma_acc_density=0.02", "sigma_mag_density=0.03"]       # both density terms on
    q1, r1 = _run([f"r_time={c * dt!r}", *dens], log)
    scaled = [f"sigma_acc={p['sigma_acc'] * float(np.sqrt(c))!r}", f"sigma_mag={p['sigma_mag'] * float(np.sqrt(c))!r}",
              f"k_a={p['k_a'] * c!r}", f"k_m={p['k_m'] * c!r}", f"adapt_max={p['adapt_max'] * c!r}"]
    q0, r0 = _run(["r_time=0", *dens, *scaled], log)
    assert np.count_nonzero(r0[:, 3]) > 0.2 * len(log)          # magnetometer updates took place
    assert np.any(r0[:, 0] > 2 * c * p["sigma_acc"] ** 2)          # the adaptation acted
    np.testing.assert_allclose(r1, r0, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.abs(np.sum(q1 * q0, axis=1)), 1.0, rtol=0, atol=1e-12)
