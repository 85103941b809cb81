"""Attitude from the accelerometer and magnetometer: tilt, tilt-compensated heading, FQA.

Accelerometer input is specific force in FRD (level at rest: [0, 0, -g]); SPEC.md:
    roll_a  = atan2(-f_y, -f_z)
    pitch_a = atan2(f_x, sqrt(f_y^2 + f_z^2))
    X_h = m_x cos(pitch) + m_y sin(pitch) sin(roll) + m_z sin(pitch) cos(roll)
    Y_h = m_y cos(roll) - m_z sin(roll)
    yaw_m = atan2(-Y_h, X_h) + declination
"""
from __future__ import annotations

import casadi as ca

from ahrsgen.constants import Const, use

from . import quat

# FQA divides by cos(pitch); below this the roll is taken as zero (pitch at +-90 deg).
FQA_COS_PITCH_MIN = Const("FQA_COS_PITCH_MIN", 1e-6)
# FQA divides by the horizontal field norm; it is floored here (a field straight down: any heading).
FQA_FIELD_H_MIN = Const("FQA_FIELD_H_MIN", 1e-30)


def tilt_angles(f):
    """(roll, pitch) of the accelerometer's specific force f."""
    roll = ca.atan2(-f[1], -f[2])
    pitch = ca.atan2(f[0], ca.sqrt(f[1] * f[1] + f[2] * f[2]))
    return roll, pitch


def tilt_compensated_heading(m, roll, pitch, declination=0.0):
    """Magnetic heading of body-frame field m given roll and pitch (radians, (-pi, pi])."""
    sr, cr = ca.sin(roll), ca.cos(roll)
    sp, cp = ca.sin(pitch), ca.cos(pitch)
    xh = m[0] * cp + m[1] * sp * sr + m[2] * sp * cr
    yh = m[1] * cr - m[2] * sr
    return quat.wrap(ca.atan2(-yh, xh) + declination)


def fqa_tilt(f):
    """FQA's elevation and roll quaternions (Yun et al. 2008, eqs. 20-32) in FRD/NED.

    Returns (q_pitch, q_roll) with body->level = q_pitch ⊗ q_roll, using half-angle formulas
    only (no trigonometric calls).
    """
    a = f / ca.sqrt(ca.sumsqr(f))
    s_theta = ca.fmin(ca.fmax(a[0], -1), 1)           # sin(pitch) = f_x/|f|
    c_theta = ca.sqrt(1 - s_theta * s_theta)
    c_th2, s_th2 = quat.half_angle(c_theta, s_theta)
    c_safe = ca.fmax(c_theta, use(FQA_COS_PITCH_MIN))
    singular = c_theta < use(FQA_COS_PITCH_MIN)
    s_phi = ca.if_else(singular, 0, -a[1] / c_safe)
    c_phi = ca.if_else(singular, 1, -a[2] / c_safe)
    c_ph2, s_ph2 = quat.half_angle(c_phi, s_phi)
    return quat.axis_quat(1, c_th2, s_th2), quat.axis_quat(0, c_ph2, s_ph2)


def fqa(f, m, declination=0.0):
    """Factored quaternion algorithm: body->NED quaternion from specific force and field.

    Heading is measured from magnetic north, then rotated by the (baked) declination.
    """
    q_pitch, q_roll = fqa_tilt(f)
    q_tilt = quat.qmul(q_pitch, q_roll)               # body -> level frame
    m_level = quat.rotate(q_tilt, m)                  # field in the level frame
    nxy = ca.sqrt(m_level[0] * m_level[0] + m_level[1] * m_level[1])
    nxy = ca.fmax(nxy, use(FQA_FIELD_H_MIN))
    c_psi = m_level[0] / nxy                          # m_level = Rz(-psi) [m_N, 0, m_D]
    s_psi = -m_level[1] / nxy
    c_ps2, s_ps2 = quat.half_angle(c_psi, s_psi)
    q_yaw = quat.axis_quat(2, c_ps2, s_ps2)
    q = quat.qmul(q_yaw, q_tilt)
    if declination != 0.0:
        q = quat.qmul(quat.vec(ca.cos(declination / 2), 0, 0, ca.sin(declination / 2)), q)
    return q


def tilt_with_yaw(f, yaw):
    """FQA tilt quaternion with a given yaw (for steps without a magnetometer)."""
    q_pitch, q_roll = fqa_tilt(f)
    q_yaw = quat.vec(ca.cos(yaw / 2), 0, 0, ca.sin(yaw / 2))
    return quat.qmul(q_yaw, quat.qmul(q_pitch, q_roll))
