"""Attitude: unit quaternions (scalar first, body FRD -> NED) and the rotation matrices and Euler angles
they stand for. The one place every program (simulator, estimator, ground station) takes them from."""

from __future__ import annotations

import math


def rotation(q0: float, q1: float, q2: float, q3: float) -> tuple[float, ...]:
    """Body(FRD) -> NED rotation matrix of a unit quaternion, row-major 9-tuple (its transpose maps
    NED to the body: unpack it column by column)."""
    return (
        q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
        2.0 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2.0 * (q2 * q3 - q0 * q1),
        2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3,
    )  # fmt: skip


def quat_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Unit quaternion of ZYX Euler angles (radians)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q0: float, q1: float, q2: float, q3: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians, ZYX convention."""
    roll = math.atan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (q0 * q2 - q3 * q1))))
    yaw = math.atan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


def rotation_error(q_true: tuple[float, ...], q_est: tuple[float, ...]) -> tuple[float, float, float]:
    """The small rotation vector d (NED, radians) that turns the estimate into the truth, R_true = (I + [d x]) R_est:
    the skew part of R_true R_est^T (the estimator's attitude error, ekf.py's ATT_N..ATT_D)."""
    t, e = rotation(*q_true), rotation(*q_est)
    m = [[sum(t[3 * i + k] * e[3 * j + k] for k in range(3)) for j in range(3)] for i in range(3)]
    return 0.5 * (m[2][1] - m[1][2]), 0.5 * (m[0][2] - m[2][0]), 0.5 * (m[1][0] - m[0][1])


def imu_mount(roll_deg: float, pitch_deg: float) -> tuple[float, ...] | None:
    """The body-to-IMU matrix (row-major, ``v_imu = M v_body``) of an IMU whose axes are the body's turned by
    ``roll_deg`` about x, then ``pitch_deg`` about the new y: ``M = (Rx(roll) Ry(pitch))^T``. None for an IMU on the
    body's axes. The simulator's truth ([truth] imu_roll_deg, imu_pitch_deg) reads through it; the firmware turns
    the readings back with its transpose (``imu_to_body``) by what the design declares ([sensors] the same keys)."""
    if not (roll_deg or pitch_deg):
        return None
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
    # Rx Ry = [[cp, 0, sp], [sr sp, cr, -sr cp], [-cr sp, sr, cr cp]]; M is its transpose
    return (cp, sr * sp, -cr * sp, 0.0, cr, sr, sp, -sr * cp, cr * cp)


def body_to_imu(m: tuple[float, ...], x: float, y: float, z: float) -> tuple[float, float, float]:
    """``M v``: a body-frame vector in the IMU's axes (``imu_mount``)."""
    return m[0] * x + m[1] * y + m[2] * z, m[3] * x + m[4] * y + m[5] * z, m[6] * x + m[7] * y + m[8] * z


def imu_to_body(m: tuple[float, ...], x: float, y: float, z: float) -> tuple[float, float, float]:
    """``M^T v``: an IMU reading in the body's axes (``imu_mount``)."""
    return m[0] * x + m[3] * y + m[6] * z, m[1] * x + m[4] * y + m[7] * z, m[2] * x + m[5] * y + m[8] * z
