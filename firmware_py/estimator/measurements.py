"""Measurement models (paper Eq. 9) and their fusion, one function per kind. Each sets the row
``ekf.h`` and calls ``ekf.fuse`` with the innovation and its noise; innovations, test ratios and
counts land in the ``FusionStatus`` it is given.

- specific force (accelerometer, 3 scalars): f = R^T (a(x) - g)
- barometric height: -p_d - h_ref
- heading (magnetometer + declination): yaw about NED down
- taut constraints: |p| = L + r, radial velocity 0, body down axis along the rope force (2 scalars)
"""

from __future__ import annotations

import math

import numpy as np

from balloon_core.atmosphere import G0
from balloon_core.rotation import rotation
from firmware_py.estimator.ekf import RESET_HEIGHT, RESET_TAUT, FusionStatus, WindEkf
from firmware_py.estimator.generated import rope_direction, rope_direction_plain
from firmware_py.estimator.model import N_COLUMNS, ROPE_JAC
from firmware_py.estimator.params import (
    TAUT_AZIMUTH_MIN_M,
    TAUT_LEAN_MIN_SIN,
    TAUT_POS_SIGMA_M,
    TAUT_VEL_SIGMA_MPS,
    TAUT_WIND_SIGMA_MPS,
    UNGATED,
)
from firmware_py.estimator.state import (
    ATT_D,
    ATT_E,
    ATT_N,
    DRAG,
    MODE_GROUND,
    MODEL_COLUMNS,
    POS_D,
    POS_E,
    POS_N,
    VEL_D,
    VEL_E,
    VEL_N,
    WIND_E,
    WIND_N,
    WRATE_E,
    WRATE_N,
)


def fuse_accel(ekf: WindEkf, fx: float, fy: float, fz: float, var: float, status: list[FusionStatus]) -> None:
    """Specific force in FRD against the force model, f = R^T (a(x) - g): tilt (through g) and the
    balloon's dynamics (drag of the wind, the air's push, the rope) through a(x). On the ground the
    balloon is held (a = 0): a gravity reference. The three axes are fused as one vector."""
    r = rotation(*ekf.q.tolist())
    f = ekf.forces
    ground = ekf.mode == MODE_GROUND
    if ground:
        yn, ye, yd = 0.0, 0.0, -G0
    else:
        yn, ye, yd = f.an, f.ae, f.ad - G0
    H = ekf.H3
    H.fill(0.0)
    pred = [0.0, 0.0, 0.0]
    rt = ekf.rt
    for i in range(3):
        cn, ce, cd = r[i], r[3 + i], r[6 + i]  # row i of R^T
        pred[i] = cn * yn + ce * ye + cd * yd
        h = ekf.H3_rows[i]
        # d/d att: R^T [y x]
        h[ATT_N] = ce * yd - cd * ye
        h[ATT_E] = cd * yn - cn * yd
        h[ATT_D] = cn * ye - ce * yn
        rt[i, 0], rt[i, 1], rt[i, 2] = cn, ce, cd
    if not ground:
        # d/d (model states): R^T (d a / d x), the two column blocks of the model (ekf.ja, set by predict)
        np.matmul(rt, ekf.ja, out=ekf.hja)
        np.copyto(ekf.H3_pv, ekf.hja_pv)
        np.copyto(ekf.H3_wk, ekf.hja_wk)
        if not ekf.learn_drag:
            H[0, DRAG] = H[1, DRAG] = H[2, DRAG] = 0.0
    ekf.fuse3(fx - pred[0], fy - pred[1], fz - pred[2], var, status)


def fuse_baro(ekf: WindEkf, height_m: float, ref_pos_d: float, var: float, status: FusionStatus) -> None:
    """Barometric height above the reference (hypsometric, computed by the caller)."""
    ekf.h.fill(0.0)
    ekf.h[POS_D] = -1.0
    pred = -(float(ekf.x[POS_D]) - ref_pos_d)
    ekf.fuse(height_m - pred, var, status)


def reset_height(ekf: WindEkf, pos_d: float, var: float) -> None:
    """Put the height where the barometer says (PX4's height reset): the model that contradicted it
    persistently (a bump taken for a release, a climb that did not happen) gives way to the sensor."""
    ekf.x[POS_D] = pos_d
    ekf.x[VEL_D] = 0.0
    P = ekf.P
    for i in (POS_D, VEL_D):
        P[i, :] = 0.0
        P[:, i] = 0.0
    P[POS_D, POS_D] = var
    P[VEL_D, VEL_D] = 1.0
    ekf.reset(RESET_HEIGHT)


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


def enter_taut(ekf: WindEkf, height_m: float, rho: float, from_tilt: bool = False) -> None:
    """Put the state on the taut configuration's sphere |p| = L + r.
    - the chord's polar angle from the barometric height, cos(theta) = h / (L + r);
    - its azimuth: at the end of the free ascent (``from_tilt`` False) from the ascent's horizontal
      position (the balloon drifted downwind): at the moment the rope snaps taut the balloon swings
      and its lean can point anywhere (the reduced balloon's pointed backwards); on the settled tether
      (``from_tilt``: a restart in flight, or 2 s of alignment rejected) from the balloon's lean if it
      leans more than 3 deg (its tilt is good to a few tenths of a degree; in a lighter wind the lean
      is tilt noise and the state's azimuth is kept);
    - the wind from the static balance drag = (N_b - W) tan(theta) along it, velocity zero;
    - position, velocity and wind covariances reset (decorrelated), wide enough for the alignment
      row and the accelerometer to move them where the tilt and the dynamics say."""
    m = ekf.model
    x = ekf.x
    ell = m.taut_radius_m
    cos_t = min(max(height_m / ell, 0.05), 1.0)
    sin_t = math.sqrt(1.0 - cos_t * cos_t)
    pn, pe = float(x[POS_N]), float(x[POS_E])
    wn, we = float(x[WIND_N]), float(x[WIND_E])
    horiz = math.hypot(pn, pe)
    r = rotation(*ekf.q.tolist())
    zn, ze = r[2], r[5]  # horizontal part of the body's down axis: it leans towards the anchor
    lean = math.hypot(zn, ze)
    wind = math.hypot(wn, we)
    if from_tilt and lean > TAUT_LEAN_MIN_SIN:
        an, ae = -zn / lean, -ze / lean
    elif horiz > TAUT_AZIMUTH_MIN_M:
        an, ae = pn / horiz, pe / horiz
    elif wind > 1e-3:
        an, ae = wn / wind, we / wind
    else:
        an = ae = 0.0
    # the wind's speed from the static balance along that azimuth, drag = (N_b - W) tan(theta): the
    # ascent's horizontal speed is observed only weakly (through the release and |u| in the climb)
    lift = (rho * m.volume_m3 - m.mass_kg - m.rope_kg_m * m.tether_length_m) * G0
    drag = max(lift, 0.0) * sin_t / cos_t
    k = max(float(x[DRAG]), 0.2)
    speed = math.sqrt(drag / (k * rho * m.half_cd_area_m2)) if drag > 0.0 else 0.0
    x[WIND_N], x[WIND_E] = speed * an, speed * ae
    x[WRATE_N] = x[WRATE_E] = 0.0
    x[VEL_N] = x[VEL_E] = x[VEL_D] = 0.0
    e = (sin_t * an, sin_t * ae, -cos_t)
    for i in range(3):
        x[POS_N + i] = ell * e[i]
    P = ekf.P
    for i in (POS_N, POS_E, POS_D, VEL_N, VEL_E, VEL_D, WIND_N, WIND_E, WRATE_N, WRATE_E):
        P[i, :] = 0.0
        P[:, i] = 0.0
    for i in (POS_N, POS_E, POS_D):
        P[i, i] = TAUT_POS_SIGMA_M**2
    for i in (VEL_N, VEL_E, VEL_D):
        P[i, i] = TAUT_VEL_SIGMA_MPS**2
    P[WIND_N, WIND_N] = P[WIND_E, WIND_E] = TAUT_WIND_SIGMA_MPS**2
    P[WRATE_N, WRATE_N] = P[WRATE_E, WRATE_E] = ekf.wind_process.sigma_rate_mps2**2
    ekf.reset(RESET_TAUT)


def fuse_taut(
    ekf: WindEkf, radial_var: float, radial_rate_var: float, align_var: float, status: list[FusionStatus]
) -> None:
    """Restricted radial motion (paper Sec. 2.3): the attachment point at the bottom of the sphere
    (Eq. 7; ``ekf.forces.attach_ned`` from the attitude) at |p_a| = L from the anchor, no radial
    velocity, and the balloon's down axis along the rope force (tension towards the anchor + the rope's
    weight, Eq. 5, + the rope's cross-flow drag if modelled). The attitude enters the first two as a
    parameter (no attitude column: r / L ~ 1 %)."""
    x = ekf.x
    pn, pe, pd, vn, ve, vd = x[:6].tolist()
    on, oe, od = ekf.forces.attach_ned
    qn, qe, qd = pn + on, pe + oe, pd + od  # the attachment point from the anchor
    dist = math.sqrt(qn * qn + qe * qe + qd * qd)
    if dist < 1.0:
        return
    e = (qn / dist, qe / dist, qd / dist)
    h = ekf.h
    h.fill(0.0)
    for i in range(3):
        h[POS_N + i] = e[i]
    ekf.fuse(ekf.model.tether_length_m - dist, radial_var, status[0], UNGATED)
    h.fill(0.0)
    vr = vn * e[0] + ve * e[1] + vd * e[2]
    v = (vn, ve, vd)
    for i in range(3):
        h[VEL_N + i] = e[i]
        h[POS_N + i] = (v[i] - vr * e[i]) / dist  # d(v . e)/dp
    ekf.fuse(-vr, radial_rate_var, status[1], UNGATED)
    f = ekf.forces
    if not f.taut:
        return
    wn, we, rn, re, k = float(x[WIND_N]), float(x[WIND_E]), float(x[WRATE_N]), float(x[WRATE_E]), float(x[DRAG])
    fn = rope_direction if ekf.model.rope_drag_m2 > 0.0 else rope_direction_plain
    n = fn(pn, pe, pd, vn, ve, vd, wn, we, rn, re, k, *f.params)
    r = rotation(*ekf.q.tolist())
    z = (r[2], r[5], r[8])  # body down axis in NED
    dz_datt = ((0.0, z[2], -z[1]), (-z[2], 0.0, z[0]))  # d z / d att = -[z x], rows N and E
    ncol = len(MODEL_COLUMNS) - (0 if ekf.learn_drag else 1)
    for c in range(2):
        h.fill(0.0)
        h[ATT_N], h[ATT_E], h[ATT_D] = dz_datt[c]
        for j in range(ncol):
            h[MODEL_COLUMNS[j]] = -n[ROPE_JAC + N_COLUMNS * c + j]  # residual z - n(x)
        ekf.fuse(n[c] - z[c], align_var, status[2 + c], recover=False)
