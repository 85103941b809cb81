"""Multirotor (product scenario): hover, aggressive manoeuvres, motor vibration.

Truth (120 s by default; deterministic, independent of the seed). Attitude schedule:
- 0-10 s hover (yaw 0);
- 10-20 s fast yaw: a full +360° turn at up to 240 °/s, then -360°;
- 20-32 s flips: roll to +45°, through to -45°, back to level (0.4-0.6 s ramps, peaks
  ~170 °/s), the same on pitch;
- 32-44 s dash: pitch -30° for 3 s (5.7 m/s² forward), then +35° to brake, level;
- 44-56 s tilted circles: roll 30° sin / pitch 30° cos at 0.5 Hz while yawing at 90 °/s;
- 56-70 s climbs/descents: ±4 m/s² vertical bursts with ±20° roll;
- 70-120 s hover with gentle sway (±5° sum of sines) and slow yaw; then repeats.
Translational dynamics: specific thrust T along body -z,
a_n = g_n + R(q) [0, 0, -T] - c v_n (linear rotor/air drag, c = 0.3 /s), with T holding the
commanded vertical acceleration and damping the vertical speed
(T = (g + a_up + 1.0 v_d) / (cos φ cos θ)); integrated by Heun's method on a 1 ms grid. The
accelerometer therefore also sees the drag in x/y, as on a real multirotor.

Rates: IMU (gyro, accelerometer) 250 Hz (`rate_hz` for more), magnetometer 50 Hz (`mag_rate`),
GPS velocity 5 Hz (`gps_rate`; 0 = no receiver, as indoors), each sensor's valid bit set only
when its sample arrived; `repeat_slow=True` instead repeats the last magnetometer sample with its bit set on every IMU step (the bench's
`multirotor_400hz` / `multirotor_400hz_repeated` pair: IMU 400 Hz, magnetometer 100 Hz).
Noise (Pixhawk class, MPU-6000 / HMC5883L figures): gyro 0.005 °/s/√Hz, constant bias
0.05-0.3 °/s per axis (random sign, from the seed) plus a bias random walk 0.001 °/s/√s;
accelerometer 400 µg/√Hz; magnetometer 2 mgauss 1σ on a 0.5 gauss field (inclination 60°,
declination 2°); GPS velocity 0.1 m/s N/E, 0.15 m/s D.
Motor vibration (sensor error, not in the truth attitude: the mount's sub-milliradian jitter
is left out): at the blade-pass frequency f_m = 120 + 130 clip((T/g - 0.5)/1.5, 0, 1) Hz
(163 Hz in hover, 250 Hz at 2 g; 130-200 Hz over the default run), accelerometer amplitude [1.5, 1.5, 3.0] m/s² plus its second
harmonic at half amplitude, gyro amplitude [0.03, 0.03, 0.01] rad/s, both sampled as they are
(aliased, as an IMU without anti-alias filtering sees them), plus broadband vibration noise
0.3 m/s² and 0.01 rad/s 1σ per sample. `vibration=False` turns it off; `noise=False` turns off
all sensor errors including vibration.
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG
from ahrsgen.npquat import q_from_euler

DESCRIPTION = ("multirotor: 120 s hover, ±360° yaw at 240°/s, ±45° roll/pitch flips, 30° dash/brake, "
               "tilted circles, ±4 m/s² climbs; IMU 250 Hz, mag 50 Hz, GPS 5 Hz; MPU-6000/HMC5883L "
               "noise, gyro bias 0.05-0.3°/s; motor vibration 130-200 Hz, 163 Hz in hover (accel 1.5-3 m/s², gyro "
               "0.03 rad/s) + broadband")

PERIOD = 120.0
DRAG = 0.3          # 1/s
KV = 1.0            # 1/s vertical speed damping of the thrust law

ROLL = [(-1e9, 0, 1), (20, 45, 0.4), (21.5, -45, 0.6), (23.0, 0, 0.4),
        (56, 20, 1.0), (59, -20, 1.0), (62, 0, 1.0), (PERIOD - 1, 0, 0.5)]
PITCH = [(-1e9, 0, 1), (26, 45, 0.4), (27.5, -45, 0.6), (29.0, 0, 0.4),
         (32, -30, 0.5), (35, 35, 0.8), (37.5, 0, 0.6), (PERIOD - 1, 0, 0.5)]
YAWRATE = [(-1e9, 0, 1), (10, 240, 0.5), (11.0, 0, 0.5), (14, -240, 0.5), (15.0, 0, 0.5),
           (44, 90, 1.0), (55, 0, 1.0), (72, 10, 2.0), (110, 0, 2.0)]
UP = [(-1e9, 0, 1), (64, 4, 0.3), (65, 0, 0.3), (66.5, -4, 0.3), (67.5, 0, 0.3), (69, 4, 0.3),
      (69.7, 0, 0.3)]


def _cyc(table, t, scale=1.0):
    ncyc = int(np.ceil(max(t.max(), 1.0) / PERIOD))
    T, V, R = [table[0][0]], [table[0][1]], [table[0][2]]
    for c in range(ncyc):
        for ti, vi, ri in table[1:]:
            T.append(ti + c * PERIOD)
            V.append(vi)
            R.append(ri)
    return _sim.keyframes(t, T, np.asarray(V, dtype=float) * scale, R)[0]


def _window(t, a, b, ramp=1.0):
    tc = np.mod(t, PERIOD)
    return _sim.smoothstep((tc - a) / ramp) * (1 - _sim.smoothstep((tc - b + ramp) / ramp))


def profiles(t):
    """roll, pitch, yaw (rad, yaw unwrapped) and commanded upward acceleration (m/s²) at t."""
    h = t[1] - t[0]
    roll = _cyc(ROLL, t, DEG)
    pitch = _cyc(PITCH, t, DEG)
    yawrate = _cyc(YAWRATE, t, DEG)
    w = 2 * np.pi * 0.5
    circ = _window(t, 44.0, 56.0)
    roll = roll + circ * 30 * DEG * np.sin(w * t)
    pitch = pitch + circ * 30 * DEG * np.cos(w * t)
    sway = _window(t, 70.0, 119.0, 2.0)
    roll = roll + sway * DEG * (3 * np.sin(2 * np.pi * 0.31 * t) + 2 * np.sin(2 * np.pi * 0.83 * t + 1))
    pitch = pitch + sway * DEG * (3 * np.sin(2 * np.pi * 0.23 * t + 2) + 2 * np.sin(2 * np.pi * 0.67 * t))
    yaw = _sim.cumtrapz(yawrate, h)
    i0 = int(np.argmin(np.abs(t)))
    yaw = yaw - yaw[i0]
    up = _cyc(UP, t)
    return roll, pitch, yaw, up


def truth(duration: float, period: float):
    m = max(1, int(np.ceil(period / 0.001 - 1e-9)))
    h = period / m
    k0 = int(np.ceil(1.0 / h))
    k1 = int(np.ceil((duration + 1.0) / h))
    t = np.arange(-k0, k1 + 1) * h
    roll, pitch, yaw, up = profiles(t)
    q = q_from_euler(roll, pitch, yaw)
    R = _sim.rotmats(q)
    zb = R[:, :, 2]                       # body z axis in NED
    cc = np.cos(roll) * np.cos(pitch)
    n = len(t)
    # T cos(phi)cos(theta) = T * zb_d, so unless T is clipped the vertical channel is the linear
    # a_d = -up - (KV + DRAG) v_d; integrate it with the clip, then the horizontal channel
    # a_h = -T zb_h - DRAG v_h (both by Heun's method, plain floats for speed).
    gz, lo, hi = G0, 2.0, 3.0 * G0
    upl, ccl, zbl = up.tolist(), cc.tolist(), zb.tolist()

    def thrust_of(i, vd):
        return min(max((gz + upl[i] + KV * vd) / ccl[i], lo), hi)

    def ad_of(i, vd):
        return gz - thrust_of(i, vd) * zbl[i][2] - DRAG * vd

    vd = [0.0] * n
    for i in range(n - 1):
        a0 = ad_of(i, vd[i])
        vp = vd[i] + h * a0
        vd[i + 1] = vd[i] + 0.5 * h * (a0 + ad_of(i + 1, vp))
    vd = np.asarray(vd)
    thrust = np.clip((G0 + up + KV * vd) / cc, lo, hi)
    force = -thrust[:, None] * zb[:, :2]
    vh = np.zeros((n, 2))
    fx, fy = force[:, 0].tolist(), force[:, 1].tolist()
    vx, vy = [0.0] * n, [0.0] * n
    for i in range(n - 1):
        ax0, ay0 = fx[i] - DRAG * vx[i], fy[i] - DRAG * vy[i]
        px, py = vx[i] + h * ax0, vy[i] + h * ay0
        vx[i + 1] = vx[i] + 0.5 * h * (ax0 + fx[i + 1] - DRAG * px)
        vy[i + 1] = vy[i] + 0.5 * h * (ay0 + fy[i + 1] - DRAG * py)
    vh[:, 0], vh[:, 1] = vx, vy
    v = np.column_stack([vh, vd])
    a = np.array([0.0, 0.0, G0]) - thrust[:, None] * zb - DRAG * v
    return _sim.Truth(t[0], h, q, v, a), t, thrust


def make(seed: int = 0, *, rate_hz: float = 250.0, duration: float = 120.0, mag_rate: float = 50.0,
         gps_rate: float = 5.0, noise: bool = True, vibration: bool = True, jitter: float = 0.0,
         dropout: dict | None = None, settle_time: float = 5.0, repeat_slow: bool = False) -> SensorLog:
    period = 1.0 / rate_hz
    tr, tf, thrust = truth(duration, period)
    r = _sim.rng(seed, _sim._S_GYRO_BIAS)
    bias = r.uniform(0.05, 0.3, 3) * r.choice([-1.0, 1.0], 3) * DEG
    sensors = _sim.SensorModel(gyro_nd=0.005 * DEG, gyro_bias=bias, gyro_bias_rw=0.001 * DEG,
                               accel_nd=400e-6 * G0, mag_nd=2e-3 / np.sqrt(min(mag_rate, rate_hz)),
                               gps_sigma=(0.1, 0.1, 0.15))
    # blade-pass frequency and its phase on the fine grid
    fm = 120.0 + 130.0 * np.clip((thrust / G0 - 0.5) / 1.5, 0.0, 1.0)
    phase = 2 * np.pi * _sim.cumtrapz(fm, tr.h)
    ph0 = _sim.rng(seed, _sim._S_SCENARIO).uniform(0, 2 * np.pi, 4)

    def phase_at(ts):
        return np.interp(ts, tf, phase)

    def acc_vib(ts, rr):
        p = phase_at(ts)[:, None]
        amp = np.array([1.5, 1.5, 3.0])
        return (amp * np.sin(p + ph0[:3]) + 0.5 * amp * np.sin(2 * p + ph0[3])
                + rr.normal(size=(len(ts), 3)) * 0.3)

    def gyro_vib(ts, rr):
        p = phase_at(ts)[:, None]
        return (np.array([0.03, 0.03, 0.01]) * np.sin(p + ph0[1:4])
                + rr.normal(size=(len(ts), 3)) * 0.01)

    return _sim.simulate(
        "multirotor", tr, rate_hz=rate_hz, duration=duration, seed=seed, sensors=sensors,
        noise=noise, mag_rate=mag_rate, gps_rate=gps_rate, mag_field=0.5, inclination_deg=60.0,
        declination_deg=2.0, jitter=jitter, dropout=dropout,
        accel_disturbance=acc_vib if vibration else None,
        gyro_disturbance=gyro_vib if vibration else None,
        description=DESCRIPTION, settle_time=settle_time, repeat_slow=repeat_slow,
        meta={"vibration": bool(vibration and noise),
              "vibration_hz_range": [float(fm.min()), float(fm.max())],
              "sensor_class": "MPU-6000 gyro/accel, HMC5883L magnetometer (Pixhawk class)"})
