"""`ahrsgen calibrate LOG... -o cal.toml`: the sensor's own errors, fitted from its logs.

- Magnetometer hard and soft iron by an ellipsoid fit. The model (MATLAB's magcal writes the
  same one; x-io Fusion's `S m - h` is a different one):

      m_cal = S (m - h)

  h is the hard-iron offset (raw units, body axes), S the symmetric soft-iron matrix. The raw
  samples lie on the ellipsoid (m - h)^T A (m - h) = 1; S = B A^(1/2) with B chosen so that
  det S = 1 (S changes shape, not size), and B, the radius of the corrected sphere, is the
  field norm found, in the raw units.
  Fit: the quadric m^T A m + 2 u^T m = 1 + c by linear least squares on the nine coefficients
  (A symmetric, u, with the constant fixed), h = -A^-1 u, then scaled. A fit needs the sensor
  turned through much of the sphere: the coverage of the 26 directions of a cube's faces,
  edges and corners (a direction counts with 1 % of the samples within 30 deg) must be at least
  half, else the log is refused in one line.
- Gyro bias: the mean gyro over the rest stretches (gyro steady within 0.02 rad/s and the
  accelerometer's norm within 0.3 m/s^2 of g, for at least 1 s).

Quality figures are written beside the values: the residual (RMS of |m_cal| - B, relative to
B), the coverage, the field norm, and how many seconds of rest the gyro bias comes from.

The TOML's [calibration] table goes into `generate --config` and `run --config`: the generated
C applies it to every raw sample before anything else, folded as constants
(ahrsgen/sensor_frame.py; a [mounting] table may be added to the same file).
"""
from __future__ import annotations

import math
from itertools import product
from pathlib import Path

import numpy as np

from ahrsgen.errors import ConfigError
from ahrsgen.sim.log import G0, VALID_GYRO, VALID_MAG

MIN_COVERAGE = 0.5
MIN_SAMPLES = 50
REST_GYRO_TOL = 0.02        # rad/s: spread of the gyro about its local mean at rest
REST_ACCEL_TOL = 0.3        # m/s^2: | |f| - g | at rest
REST_MIN_TIME = 1.0         # s


def _directions() -> np.ndarray:
    d = np.array([v for v in product((-1, 0, 1), repeat=3) if any(v)], float)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def coverage(unit: np.ndarray) -> float:
    """Fraction of the 26 cube directions that at least 1 % of the unit vectors (and 3) lie
    within 30 deg of."""
    dirs = _directions()
    near = (unit @ dirs.T) > math.cos(math.radians(30.0))
    need = max(3, int(0.01 * len(unit)))
    return float(np.mean(near.sum(axis=0) >= need))


def fit_ellipsoid(m: np.ndarray) -> dict:
    """Hard iron h, soft iron S (symmetric, det 1), field norm B, residual and coverage of the
    samples m (N, 3). ConfigError when the samples cannot define an ellipsoid."""
    m = np.asarray(m, float)
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < MIN_SAMPLES:
        raise ConfigError(f"{len(m)} magnetometer samples: at least {MIN_SAMPLES} are needed to fit")
    scale = float(np.median(np.linalg.norm(m - m.mean(axis=0), axis=1))) or 1.0
    x = (m - m.mean(axis=0)) / scale          # conditioning: centred and about unit size
    X, Y, Z = x.T
    D = np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z, 2 * X, 2 * Y, 2 * Z])
    coef, *_ = np.linalg.lstsq(D, np.ones(len(x)), rcond=None)
    a, b, c, d, e, f, g, h_, i = coef
    A = np.array([[a, d, e], [d, b, f], [e, f, c]])
    u = np.array([g, h_, i])
    w = np.linalg.eigvalsh(A)
    if not np.all(w > 1e-9 * max(abs(w).max(), 1e-30)):
        raise ConfigError("the magnetometer samples do not lie on an ellipsoid (the sensor did not turn enough, "
                          "or the field changed during the log)")
    centre = -np.linalg.solve(A, u)
    k = 1.0 + centre @ A @ centre
    An = A / k                                # (x - centre)^T An (x - centre) = 1
    wn, V = np.linalg.eigh(An)
    root = V @ np.diag(np.sqrt(wn)) @ V.T     # An^(1/2): unit sphere in the scaled units
    det_root = float(np.prod(np.sqrt(wn)))
    B_scaled = det_root ** (-1.0 / 3.0)       # radius that keeps det S = 1
    S = B_scaled * root
    hard = m.mean(axis=0) + scale * centre
    cal = (S @ (m - hard).T).T
    norms = np.linalg.norm(cal, axis=1)
    B = float(np.mean(norms))
    unit = cal / norms[:, None]
    return {"hard_iron": hard, "soft_iron": S, "field_norm": B,
            "residual": float(np.sqrt(np.mean((norms - B) ** 2)) / B), "coverage": coverage(unit),
            "samples": int(len(m))}


def gyro_bias(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray | None, float]:
    """Mean gyro over the rest stretches, and their total length in seconds (None, 0 without one)."""
    n = len(t)
    if n < 3:
        return None, 0.0
    dt = float(np.median(np.diff(t)))
    win = max(3, int(round(REST_MIN_TIME / dt)))
    ok = np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(accel), axis=1)
    still = ok & (np.abs(np.linalg.norm(np.where(ok[:, None], accel, 0.0), axis=1) - G0) < REST_ACCEL_TOL)
    rest = np.zeros(n, bool)
    for s in range(0, n - win + 1, max(1, win // 4)):
        sl = slice(s, s + win)
        if still[sl].all():
            g = gyro[sl]
            if np.all(np.linalg.norm(g - g.mean(axis=0), axis=1) < REST_GYRO_TOL):
                rest[sl] = True
    if not rest.any():
        return None, 0.0
    return gyro[rest].mean(axis=0), float(rest.sum() * dt)


def calibrate(logs) -> dict:
    """The calibration of the sensor the logs were recorded with (one sensor, one mounting)."""
    mags, ts, gyros, accels = [], [], [], []
    for log in logs:
        has_mag = (log.valid & VALID_MAG) != 0
        mags.append(log.mag[has_mag])
        g = (log.valid & VALID_GYRO) != 0
        ts.append(log.t[g])
        gyros.append(log.gyro[g])
        accels.append(log.accel[g])
    m = np.concatenate(mags) if mags else np.zeros((0, 3))
    fit = fit_ellipsoid(m)
    if fit["coverage"] < MIN_COVERAGE:
        raise ConfigError(f"the log turns the magnetometer through {100 * fit['coverage']:.0f} % of the directions "
                          f"a fit needs (at least {100 * MIN_COVERAGE:.0f} %): record the sensor turned through "
                          f"every orientation (a slow figure-eight about all axes)")
    bias, rest_s = None, 0.0
    for t, g, a in zip(ts, gyros, accels):
        b, s = gyro_bias(t, g, a)
        if b is not None:
            bias = b if bias is None else (bias * rest_s + b * s) / (rest_s + s)
            rest_s += s
    fit["gyro_bias"] = bias
    fit["rest_seconds"] = rest_s
    return fit


def toml_text(cal: dict, logs) -> str:
    from ahrsgen.fileio import MARK

    def vec(v):
        return "[" + ", ".join(f"{float(x):.9g}" for x in v) + "]"
    lines = [f"# {MARK} calibrate from {', '.join(str(x) for x in logs)}",
             "# model: m_cal = S (m - h): remove the hard iron h, then apply the soft-iron matrix S",
             "# (not Fusion's S m - h). generate/run --config this file: the C applies it to every raw sample.",
             f"# field norm {cal['field_norm']:.6g} (raw units), residual {100 * cal['residual']:.2f} % of it, "
             f"coverage {100 * cal['coverage']:.0f} % of directions, {cal['samples']} samples",
             "[calibration]",
             f"mag_hard_iron = {vec(cal['hard_iron'])}",
             "mag_soft_iron = [" + ", ".join(vec(r) for r in cal["soft_iron"]) + "]",
             f"mag_field_norm = {cal['field_norm']:.9g}"]
    if cal["gyro_bias"] is not None:
        lines.append(f"gyro_bias = {vec(cal['gyro_bias'])}   # rad/s, from {cal['rest_seconds']:.1f} s at rest")
    else:
        lines.append("# gyro_bias: no rest stretch of 1 s in the logs (hold the sensor still to measure it)")
    return "\n".join(lines) + "\n"


def _cmd_calibrate(args) -> int:
    from ahrsgen.fileio import check_outputs, write_text_atomic
    from ahrsgen.sim import readers
    check_outputs([("-o", args.output)], inputs=args.logs, force=args.force)
    logs = []
    for p in args.logs:
        if not Path(p).is_file():
            raise ConfigError(f"log file {p} does not exist")
        try:
            logs.append(readers.read_log(p))
        except readers.LogError as e:
            raise ConfigError(str(e)) from None
    cal = calibrate(logs)
    write_text_atomic(args.output, toml_text(cal, args.logs))
    print(f"calibration of {len(logs)} log(s) -> {args.output}")
    print(f"  magnetometer: hard iron {np.array2string(cal['hard_iron'], precision=4)}, field norm "
          f"{cal['field_norm']:.4g}, residual {100 * cal['residual']:.2f} %, coverage {100 * cal['coverage']:.0f} %")
    if cal["gyro_bias"] is not None:
        print(f"  gyro bias {np.array2string(cal['gyro_bias'], precision=5)} rad/s from {cal['rest_seconds']:.1f} s at rest")
    else:
        print("  gyro bias: no rest stretch of 1 s found")
    return 0


def register_cli(sub) -> None:
    from ahrsgen.fileio import add_force_option
    p = sub.add_parser("calibrate", help="fit magnetometer hard/soft iron and gyro bias from logs of your sensor",
                       description="Fit the magnetometer's hard and soft iron (m_cal = S (m - h), an ellipsoid fit) "
                                   "and the gyro bias (mean over rest stretches) from one or more logs of one "
                                   "sensor, turned through every orientation; write them, with the fit's "
                                   "residual, coverage and field norm, as a TOML [calibration] table.")
    p.add_argument("logs", nargs="+", metavar="LOG", help="CSV or PX4 ULog files of the sensor")
    p.add_argument("-o", "--output", required=True, metavar="CAL.toml", help="where to write the calibration")
    add_force_option(p)
    p.set_defaults(func=_cmd_calibrate)
