"""`ahrsgen calibrate`: hard iron, soft iron and gyro bias recovered from simulated logs whose
true values are known (written here, not by the code under test), and a log that does not turn
the sensor refused in one line."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

from ahrsgen import calibrate, cli
from ahrsgen.sim import readers
from ahrsgen.sim.log import G0, VALID_ACCEL, VALID_GYRO, VALID_MAG, SensorLog

FIELD = 48.0                                      # uT, the true field norm
H_TRUE = np.array([30.0, -55.0, 12.0])            # hard iron: about 1.3 times the field
W_TRUE = np.array([[1.10, 0.05, -0.02],           # soft iron (raw = W m_true + h): 10 % scale,
                   [0.05, 0.95, 0.04],            # a few % cross-coupling
                   [-0.02, 0.04, 1.02]])
BIAS = np.array([0.012, -0.007, 0.004])           # rad/s
NOISE = 0.3                                       # uT per axis


def _random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def sim_log(seed=0, n_turn=3000, rest_s=5.0, planar=False, field=FIELD, inclination_deg=60.0, h=H_TRUE, w=W_TRUE):
    """100 Hz: rest_s seconds still and level, then n_turn samples in random orientations (or
    turning about the vertical only, planar=True). The field is fixed in NED; raw = w m + h."""
    rng = np.random.default_rng(seed)
    inc = np.radians(inclination_deg)
    m_ned = field * np.array([np.cos(inc), 0.0, np.sin(inc)])
    n_rest = int(rest_s * 100)
    if planar:
        yaw = rng.uniform(-np.pi, np.pi, n_turn)
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.zeros((n_turn, 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    else:
        R = _random_rotations(rng, n_turn)
    R = np.concatenate([np.tile(np.eye(3), (n_rest, 1, 1)), R])
    n = len(R)
    m_body = np.einsum("nji,j->ni", R, m_ned)                  # R^T m_ned
    mag = m_body @ np.asarray(w).T + h + rng.normal(0, NOISE, (n, 3))
    accel = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, -G0])) + rng.normal(0, 0.02, (n, 3))
    gyro = np.tile(BIAS, (n, 1)) + rng.normal(0, 0.002, (n, 3))
    gyro[n_rest:] += rng.normal(0, 1.0, (n - n_rest, 3))       # turning
    t = np.arange(n) * 0.01
    return SensorLog("cal", t, np.full(n, 0.01), gyro, accel, mag, np.zeros((n, 3)),
                     np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, np.uint32))


def test_recovers_hard_iron_soft_iron_and_gyro_bias():
    cal = calibrate.calibrate([sim_log()])
    # hard iron: within 1 % of the field (noise 0.3 uT over 3000 samples: ~0.01 uT expected)
    assert np.linalg.norm(cal["hard_iron"] - H_TRUE) < 0.01 * FIELD, cal["hard_iron"]
    # soft iron: S W must be a multiple of the identity (S undoes W up to the scale det S = 1 fixes)
    SW = cal["soft_iron"] @ W_TRUE
    c = np.trace(SW) / 3
    assert np.max(np.abs(SW / c - np.eye(3))) < 0.01, SW / c
    assert abs(np.linalg.det(cal["soft_iron"]) - 1.0) < 1e-9
    assert np.allclose(cal["soft_iron"], cal["soft_iron"].T)
    # field norm in raw units: FIELD * det(W)^(1/3)
    assert abs(cal["field_norm"] - FIELD * np.linalg.det(W_TRUE) ** (1 / 3)) < 0.01 * FIELD
    assert cal["residual"] < 2 * NOISE / FIELD and cal["coverage"] == 1.0
    # gyro bias from the 5 s at rest (noise 0.002 rad/s over 500 samples)
    assert np.max(np.abs(cal["gyro_bias"] - BIAS)) < 5e-4, cal["gyro_bias"]
    assert cal["rest_seconds"] >= 4.0


def test_a_log_that_does_not_turn_enough_is_refused(tmp_path, capsys):
    log = tmp_path / "flat.csv"
    readers.write_csv(sim_log(planar=True), log)
    rc = cli.main(["calibrate", str(log), "-o", str(tmp_path / "cal.toml")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "directions a fit needs" in err, err
    assert not (tmp_path / "cal.toml").exists()


def test_cli_writes_a_toml_with_the_values(tmp_path, capsys):
    log = tmp_path / "turn.csv"
    readers.write_csv(sim_log(seed=3), log)
    out = tmp_path / "cal.toml"
    assert cli.main(["calibrate", str(log), "-o", str(out)]) == 0
    cal = tomllib.loads(out.read_text())["calibration"]
    assert np.linalg.norm(np.array(cal["mag_hard_iron"]) - H_TRUE) < 0.01 * FIELD
    assert np.array(cal["mag_soft_iron"]).shape == (3, 3)
    assert np.max(np.abs(np.array(cal["gyro_bias"]) - BIAS)) < 5e-4
    assert "m_cal = S (m - h)" in out.read_text()
    # the log itself is never an output
    rc = cli.main(["calibrate", str(log), "-o", str(log)])
    assert rc == 2 and "input" in capsys.readouterr().err


@pytest.mark.parametrize("seed", [1, 2])
def test_recovery_holds_for_other_seeds(seed):
    cal = calibrate.calibrate([sim_log(seed=seed)])
    assert np.linalg.norm(cal["hard_iron"] - H_TRUE) < 0.01 * FIELD
