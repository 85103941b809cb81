"""Fixed-wing flight with GPS velocity, after the QCF paper (seeds/000_84f3e96dc1974420.txt,
section 4 and Table 1).

The paper flew a real UAV ("acceleration, turns, glides, climbs"), 80 ms filter period,
initial attitude pitch -3.2°, roll -28.2°, yaw 44.8°. This scenario simulates such a flight
with exact truth:

Trajectory (deterministic, independent of the seed; 600 s by default, the schedule repeats
every 600 s if longer, a shorter run is its first part):
- airspeed V 18-30 m/s (never below 18 m/s, so the GPS course is a heading), changed 10 times
  by smooth quintic ramps of 2-8 s: longitudinal accelerations 1.25-1.6 m/s² on average,
  peaks 2.3-3.0 m/s²;
- coordinated turns: bank φ ramps (3-4 s) to ±20-35° and holds 15-30 s, turn rate
  χ̇ = g tan φ / V, so the roll is exactly φ = atan(V χ̇ / g) (sustained centripetal
  acceleration 3.6-6.9 m/s², the case the GPS-derived motion acceleration of the paper's
  section 3.2 is for: | |f| - g | exceeds 0.5 m/s² on more than 30 % of the samples);
  one 50° bank reversal. Near-coordinated: the lateral specific force is 0.03 m/s² on
  average, up to 1.4 m/s² during bank ramps combined with climbs or speed changes;
- climbs and glides: flight-path angle γ ramps (3 s) to ±5-8° and holds 25-40 s;
- attitude: roll φ, pitch θ = γ + α cos φ with the angle of attack
  α = 3° (22 m/s / V)² / cos φ, yaw ψ = air-relative course χ (zero sideslip). The run
  starts in a steady left turn and glide so that at t = 0 exactly: pitch -3.2°, roll -28.2°,
  yaw 44.8°;
- NED velocity V [cos γ cos χ, cos γ sin χ, -sin γ] + wind (default no wind; then the GPS
  course equals the yaw), NED acceleration its exact time derivative.

Rates: IMU (gyro, accel, mag) 12.5 Hz (80 ms, as published; `rate_hz=100` for the 100 Hz
variant), GPS velocity 5 Hz (each fix delivered at the first IMU step at or after its time).

Sensor noise, paper's Table 1: gyro white noise 0.05 °/s/√Hz (sigma 0.177 °/s at 12.5 Hz,
0.5 °/s at 100 Hz), bias stability 0.007 °/s modelled as a bias random walk of
0.007 °/s per √300 s; a constant gyro bias of 0.1-0.5 °/s per axis (random sign), drawn from
the seed; accelerometer 0.5 mg/√Hz; magnetometer 0.066 mgauss/√Hz on a 0.5 gauss field
(inclination 53°, declination -4°, a central-China field; the paper does not say where it
flew). Table 1's accelerometer and magnetometer "bias stability" entries (0.2 g, 1 gauss)
are larger than the signals and read as range/resolution typos, so no accel/mag bias is
added. GPS velocity noise (not in the paper): 0.1 m/s north/east, 0.15 m/s down, white.
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG
from ahrsgen.npquat import q_from_euler

DESCRIPTION = ("fixed-wing UAV after the QCF paper: 600 s, 18-30 m/s with ±1-3 m/s² speed changes, "
               "coordinated turns at 20-35° bank, ±5-8° climbs/glides; IMU 12.5 Hz (80 ms; 100 Hz "
               "variant), GPS velocity 5 Hz; Table 1 noise (gyro 0.05°/s/√Hz, accel 0.5 mg/√Hz, "
               "mag 0.066 mG/√Hz), gyro bias 0.1-0.5°/s; starts at pitch -3.2°, roll -28.2°, yaw 44.8°")

PITCH0, ROLL0, YAW0 = -3.2 * DEG, -28.2 * DEG, 44.8 * DEG
ALPHA_REF, V_REF = 3.0 * DEG, 22.0
PERIOD = 600.0   # schedule period, s

# (start time of the ramp, new value, ramp length) - the first entry is the initial value
SPEED = [(-1e9, 22.0, 1.0), (25, 28.0, 4.0), (60, 20.0, 5.0), (110, 25.0, 4.0), (170, 18.0, 5.0),
         (230, 30.0, 8.0), (300, 24.0, 4.0), (360, 27.0, 2.0), (420, 19.0, 5.0), (480, 26.0, 5.0),
         (540, 22.0, 3.0), (597, 22.0, 1.0)]
BANK = [(-1e9, -28.2, 1.0), (22, 0.0, 3.0), (40, 30.0, 3.0), (75, 0.0, 3.0), (95, -25.0, 3.0),
        (130, 0.0, 3.0), (150, 35.0, 3.0), (175, 0.0, 3.0), (200, -20.0, 3.0), (240, 0.0, 3.0),
        (260, 32.0, 3.0), (290, 0.0, 3.0), (320, -35.0, 3.0), (345, 0.0, 3.0), (370, 25.0, 3.0),
        (400, -25.0, 4.0), (430, 0.0, 3.0), (455, 30.0, 3.0), (490, 0.0, 3.0), (510, -30.0, 3.0),
        (540, 0.0, 3.0), (560, 20.0, 3.0), (590, 0.0, 3.0)]
# flight-path angle; the first value is fixed below so that pitch(0) = -3.2°
GAMMA = [(-1e9, None, 1.0), (22, 0.0, 3.0), (45, 6.0, 3.0), (80, 0.0, 3.0), (100, -6.0, 3.0),
         (140, 0.0, 3.0), (180, 8.0, 3.0), (215, 0.0, 3.0), (250, -8.0, 3.0), (285, 0.0, 3.0),
         (330, 5.0, 3.0), (370, 0.0, 3.0), (400, -5.0, 3.0), (440, 0.0, 3.0), (470, 7.0, 3.0),
         (510, 0.0, 3.0), (550, -6.0, 3.0), (585, 0.0, 3.0)]


def _alpha(V, phi):
    return ALPHA_REF * (V_REF / V) ** 2 / np.cos(phi)


def _gamma0():
    return PITCH0 - _alpha(SPEED[0][1], ROLL0) * np.cos(ROLL0)


def _profile(table, t, scale=1.0, first=None):
    """Keyframe profile repeated with period PERIOD (every cycle starts from the last value of
    the previous one; the schedule ends on the initial values of speed and level flight, and
    turns/glides are re-entered by ramps at the start of each further cycle)."""
    times = [e[0] for e in table]
    vals = [e[1] for e in table]
    if first is not None:
        vals[0] = first
    ramps = [e[2] for e in table]
    ncyc = int(np.ceil(max(t.max(), 1.0) / PERIOD))
    T_all, V_all, R_all = [times[0]], [vals[0]], [ramps[0]]
    for c in range(ncyc):
        for (ti, vi, ri) in zip(times[1:], vals[1:], ramps[1:]):
            T_all.append(ti + c * PERIOD)
            V_all.append(vi)
            R_all.append(ri)
        if c + 1 < ncyc:   # return to the initial state (turn/glide) before the next cycle
            T_all.append((c + 1) * PERIOD - 3.0)
            V_all.append(vals[0])
            R_all.append(2.5)
    y, dy = _sim.keyframes(t, T_all, np.asarray(V_all) * scale, R_all)
    return y, dy


def truth(duration: float, period: float, wind_ned=(0.0, 0.0, 0.0)) -> _sim.Truth:
    """The flight on a fine grid (step <= 2 ms, an integer fraction of the IMU period)."""
    m = int(np.ceil(period / 0.002 - 1e-9))
    h = period / m
    k0 = int(np.ceil(1.0 / h))            # 1 s before t = 0
    k1 = int(np.ceil((duration + 1.0) / h))
    t = np.arange(-k0, k1 + 1) * h
    V, dV = _profile(SPEED, t)
    phi, dphi = _profile(BANK, t, DEG)
    gam, dgam = _profile(GAMMA, t, DEG, first=_gamma0() / DEG)
    chidot = G0 * np.tan(phi) / V
    chi = _sim.cumtrapz(chidot, h)
    chi = chi - chi[k0] + YAW0            # yaw exactly 44.8° at t = 0 (grid point k0)
    alpha = _alpha(V, phi)
    theta = gam + alpha * np.cos(phi)
    roll = phi.copy()
    roll[k0] = ROLL0                       # the profile holds these exactly before t = 22 s;
    theta[k0] = PITCH0                     # pin them against floating-point dust
    q = q_from_euler(roll, theta, chi)
    cg, sg, cc, sc = np.cos(gam), np.sin(gam), np.cos(chi), np.sin(chi)
    v = V[:, None] * np.stack([cg * cc, cg * sc, -sg], -1) + np.asarray(wind_ned, dtype=float)
    a = (dV[:, None] * np.stack([cg * cc, cg * sc, -sg], -1)
         + V[:, None] * np.stack([-sg * dgam * cc - cg * sc * chidot,
                                  -sg * dgam * sc + cg * cc * chidot,
                                  -cg * dgam], -1))
    return _sim.Truth(t[0], h, q, v, a)


def make(seed: int = 0, *, rate_hz: float = 12.5, duration: float = 600.0, gps_rate: float = 5.0,
         wind_ned=(0.0, 0.0, 0.0), noise: bool = True, bias_walk: bool = True,
         gyro_bias_deg_s=None, jitter: float = 0.0, dropout: dict | None = None,
         settle_time: float = 10.0) -> SensorLog:
    """Build the scenario. rate_hz 12.5 (published 80 ms) or 100 (variant); duration s;
    gyro_bias_deg_s: None = drawn from the seed (0.1-0.5 °/s per axis, random sign)."""
    period = 1.0 / rate_hz
    tr = truth(duration, period, wind_ned)
    if gyro_bias_deg_s is None:
        r = _sim.rng(seed, _sim._S_GYRO_BIAS)
        bias = r.uniform(0.1, 0.5, 3) * r.choice([-1.0, 1.0], 3) * DEG
    else:
        bias = np.asarray(gyro_bias_deg_s, dtype=float) * DEG
    sensors = _sim.SensorModel(
        gyro_nd=0.05 * DEG, gyro_bias=bias,
        gyro_bias_rw=(0.007 * DEG / np.sqrt(300.0)) if bias_walk else 0.0,
        accel_nd=0.5e-3 * G0, mag_nd=0.066e-3, gps_sigma=(0.1, 0.1, 0.15))
    return _sim.simulate(
        "fixedwing_gps", tr, rate_hz=rate_hz, duration=duration, seed=seed, sensors=sensors,
        noise=noise, gps_rate=gps_rate, mag_field=0.5, inclination_deg=53.0, declination_deg=-4.0,
        jitter=jitter, dropout=dropout, description=DESCRIPTION, settle_time=settle_time,
        meta={"initial_euler_deg": [-28.2, -3.2, 44.8], "wind_ned": list(map(float, wind_ned)),
              "airspeed_range_m_s": [18.0, 30.0], "bank_max_deg": 35.0})
