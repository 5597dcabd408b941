"""The magnetometer: the earth field learnt on the ground, the field-vector and heading rows."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from balloon_core.rotation import rotation
from firmware_py.estimator.ekf import FusionStatus, WindEkf
from firmware_py.estimator.state import (
    ATT_D,
    ATT_E,
    ATT_N,
    MODE_GROUND,
)

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def fuse_heading(
    ekf: WindEkf, mx: float, my: float, mz: float, declination_rad: float, sigma_gauss: float, status: FusionStatus
) -> None:
    """Tilt-compensated magnetic heading against the declination. The azimuth of R m depends on the
    tilt too (by tan(inclination) per radian: 2.25 for a 66 deg field), so the row carries the tilt
    terms, taken from the measured field itself (no assumed strength or inclination)."""
    r = rotation(*ekf.q.tolist())
    mn = r[0] * mx + r[1] * my + r[2] * mz
    me = r[3] * mx + r[4] * my + r[5] * mz
    md = r[6] * mx + r[7] * my + r[8] * mz
    h2 = mn * mn + me * me
    horiz = math.sqrt(h2)
    if horiz < 1e-3:
        status.rejected += 1
        return
    innov = declination_rad - math.atan2(me, mn)
    innov = (innov + math.pi) % (2.0 * math.pi) - math.pi
    ekf.h.fill(0.0)
    ekf.h[ATT_N] = -mn * md / h2
    ekf.h[ATT_E] = -me * md / h2
    ekf.h[ATT_D] = 1.0
    var = (sigma_gauss / horiz) ** 2 + math.radians(0.5) ** 2
    ekf.fuse(innov, var, status)


def fuse_mag_field(
    ekf: WindEkf, mx: float, my: float, mz: float, field_ned: tuple[float, float, float], var: float,
    status: list[FusionStatus],
) -> None:
    """The whole magnetic field vector (FRD) against the earth field learnt on the ground at boot:
    m = R^T B. Unlike the heading, it also measures the tilt about the axes across the field (about
    East for a field in the North-Down plane), independently of the balloon's acceleration: the
    accelerometer is then free to measure the dynamics. Rows: d(R^T B)/d att = R^T [B x]."""
    r = rotation(*ekf.q.tolist())
    bn, be, bd = field_ned
    H = ekf.H3
    H.fill(0.0)
    pred = [0.0, 0.0, 0.0]
    for i in range(3):
        cn, ce, cd = r[i], r[3 + i], r[6 + i]  # row i of R^T
        h = ekf.H3_rows[i]
        h[ATT_N] = ce * bd - cd * be
        h[ATT_E] = cd * bn - cn * bd
        h[ATT_D] = cn * be - ce * bn
        pred[i] = cn * bn + ce * be + cd * bd
    ekf.fuse3(mx - pred[0], my - pred[1], mz - pred[2], var, status)


def learn_field(est: Estimator, ax: float, ay: float, az: float, mx: float, my: float, mz: float) -> None:
    """The earth field in NED from the body-frame averages of the field and of gravity while the
    balloon rests on the ground station: its down component is the field along gravity, the rest is
    horizontal and points to the declination. No assumed strength or inclination; no dependence on
    the filter's own attitude (whose heading is still settling at boot)."""
    s = est._field_sum
    for i, v in enumerate((ax, ay, az, mx, my, mz)):
        s[i] += v
    est._field_n += 1
    if est._field_n < est.schedule.field_learn:
        return
    fx, fy, fz, bx, by, bz = s
    fnorm = math.sqrt(fx * fx + fy * fy + fz * fz)
    n = est._field_n
    down = -(fx * bx + fy * by + fz * bz) / (fnorm * n)  # at rest the specific force points up
    horiz = math.sqrt(max(0.0, (bx * bx + by * by + bz * bz) / (n * n) - down * down))
    est.field_ned = (horiz * math.cos(est.declination), horiz * math.sin(est.declination), down)


def control_mag(est: Estimator, ax: float, ay: float, az: float, mx: float, my: float, mz: float) -> None:
    """Every sample with a valid field: learn the earth field from rotation-invariant averages (|m| and
    m . f: at rest on the ground, or after a restart in flight on the quasi-static balloon, whose mean
    acceleration is 0), then fuse the whole field vector once it is known in flight, else the heading."""
    ekf = est.ekf
    sched = est.schedule
    if ekf.mode == MODE_GROUND or (est._joined and est._field_n < sched.field_flight):
        learn_field(est, ax, ay, az, mx, my, mz)
    if est._field_n >= sched.field_learn and ekf.mode != MODE_GROUND:
        fuse_mag_field(ekf, mx, my, mz, est.field_ned, est.mag_var, est.mag_status)
    else:
        fuse_heading(ekf, mx, my, mz, est.declination, est.mag_sigma, est.heading_status)
