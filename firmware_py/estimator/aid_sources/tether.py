"""The tether when taut: its placement, the radius, radial-rate and alignment rows, and the taut re-placement."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from balloon_core.atmosphere import G0
from balloon_core.rotation import rotation
from firmware_py.estimator.catenary import effective_rod, rope_chord
from firmware_py.estimator.consistency import ACCEL, accel_misfit, attitude_variance, lean_jacobian
from firmware_py.estimator.ekf import RESET_TAUT, FusionStatus, WindEkf
from firmware_py.estimator.generated import rope_direction, rope_direction_plain
from firmware_py.estimator.model import N_COLUMNS, ROPE_JAC
from firmware_py.estimator.params import (
    ALIGN_CROSS_VAR_MAX,
    ALIGN_FIELD_AXIS_SHARE,
    ALIGN_MODEL_CORR_S,
    ALIGN_PULL_DOWN_MIN,
    LEAN_COS_MIN,
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
    MODE_TAUT,
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

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def enter_taut(est: Estimator, height_m: float, from_tilt: bool = False) -> None:
    """Put the state on the taut configuration's sphere |p| = L_c + r (L_c the rope's chord).
    - the chord's polar angle from the barometric height, cos(theta) = h / (L + r);
    - its azimuth: at the end of the free ascent (``from_tilt`` False) from the ascent's horizontal
      position (the balloon drifted downwind): at the moment the rope snaps taut the balloon swings
      and its lean can point anywhere (the reduced balloon's pointed backwards); on the settled tether
      (``from_tilt``: a restart in flight, or 2 s of alignment rejected) from the balloon's lean if it
      leans more than 3 deg (its tilt is good to a few tenths of a degree; in a lighter wind the lean
      is tilt noise and the state's azimuth is kept);
    - the wind from the static balance drag = (N_b - W_eff) tan(theta) along it (W_eff the rope's
      weight on the rod, catenary.py), velocity zero;
    - position, velocity and wind covariances reset (decorrelated), wide enough for the alignment
      row and the accelerometer to move them where the tilt and the dynamics say;
    - the wind's speed it put kept (``Estimator.wind_taut_mps``): the scale of what it has still to settle
      (consistency.placement_settling_wind)."""
    ekf, rho = est.ekf, est.rho
    m = ekf.model
    x = ekf.x
    ell = ekf.rope.chord_m + m.radius_m
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
    lift = m.lift_n(rho) - ekf.rope.weight_n
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
    est.wind_taut_mps = math.hypot(float(x[WIND_N]), float(x[WIND_E]))


def lean_variance(P, cn: float, ce: float, zn: float, ze: float, zd: float) -> float:
    """The attitude's variance along a horizontal component (cn, ce) of the body's down axis z (along the rope):
    c . d z / d att P_att (..)^T with d z / d att = -[z x], rad^2."""
    return attitude_variance(P, *lean_jacobian(cn, ce, zn, ze, zd))


def field_axis_row(
    g: tuple[float, float, float], field_ned: tuple[float, float, float], weight: float
) -> tuple[float, float, float]:
    """The alignment's attitude column about the magnetic field's axis: ``weight`` of the share of ``g`` (the
    alignment component's c . d z / d att) along the field's unit axis b, (g . b) b; (0, 0, 0) while the field is
    unknown (NaN).

    About that axis the magnetometer sees nothing, and only the accelerometer's tilt (cos I of the rotation) holds
    the attitude. Blown magnetically north, the rope from the balloon points 50-60 deg from the field, and a rotation
    about the field turns the body's axis across the lean by 0.8 of it (blown south the rope lies along the field and
    it turns the balloon about its own rope: 0.1 of it). With the attitude a parameter of the alignment only, the
    state followed that weakly held rotation, and the estimate swung across the wind at the balloon's pendulum period
    (paper-reference from 180 deg: the attitude 0.7 deg RMS about the field, the cross wind 0.5 m/s RMS where the
    truth had none). The column lets the rope's direction hold it; ``weight`` is ALIGN_FIELD_AXIS_SHARE of it where
    the force model explains the accelerometer and the alignment is fused at its nominal noise, less as the
    accelerometer's windowed NIS goes from the monitor's flag to twice it (none beyond) and as the alignment's noise
    follows its innovations above the nominal (a taut state that is off, in gusts, must not turn the attitude with
    it: docs/estimator.md, "The wind from magnetic south")."""
    bn, be, bd = field_ned
    b2 = bn * bn + be * be + bd * bd
    if not b2 > 0.0:
        return 0.0, 0.0, 0.0
    s = weight * (g[0] * bn + g[1] * be + g[2] * bd) / b2
    return s * bn, s * be, s * bd


def fuse_taut(
    ekf: WindEkf, radial_var: float, radial_rate_var: float, along_var: float, cross_var: float,
    status: list[FusionStatus], field_ned: tuple[float, float, float], nominal_var: float, share: float,
    att_gain: float = 1.0,
) -> None:  # fmt: skip
    """Restricted radial motion (paper Sec. 2.3): the attachment point at the bottom of the sphere
    (Eq. 7; ``ekf.forces.attach_ned`` from the attitude) at |p_a| = L_c (the rope's chord) from the anchor, no radial
    velocity but the winch's reel (``ekf.rope.rate_mps``), and the balloon's down axis along the rope
    force (tension towards the anchor + the rope's weight, Eq. 5, + the rope's cross-flow drag if
    modelled). The attitude enters as a parameter (no attitude column: r / L ~ 1 % in the first two; in
    the alignment, see below), but for the alignment's column about the magnetic field's axis, ``share`` of it
    at the alignment's nominal noise ``nominal_var`` (``field_axis_row``).

    The alignment's residual is taken in two components about the balloon's azimuth from the anchor: ``along``
    (how far it leans: the angle in the lean's vertical plane, which the rope's shape, its weight on the balloon
    and the rocking in the gusts all move) and ``cross`` (where it leans: the horizontal azimuth, which no rope
    model changes). Each has its own noise (``control_tether``): a rope unlike the model must not cost the
    azimuth. The attitude takes ``att_gain`` of the cross component's gain (``control_tether``)."""
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
    ekf.fuse(ekf.rope.chord_m - dist, radial_var, status[0], UNGATED)
    h.fill(0.0)
    vr = vn * e[0] + ve * e[1] + vd * e[2]
    v = (vn, ve, vd)
    for i in range(3):
        h[VEL_N + i] = e[i]
        h[POS_N + i] = (v[i] - vr * e[i]) / dist  # d(v . e)/dp
    ekf.fuse(ekf.rope.rate_mps - vr, radial_rate_var, status[1], UNGATED)  # the winch's reel (0: none)
    f = ekf.forces
    if not f.taut:
        return
    wn, we, rn, re, k = float(x[WIND_N]), float(x[WIND_E]), float(x[WRATE_N]), float(x[WRATE_E]), float(x[DRAG])
    fn = rope_direction if ekf.model.rope_drag_m2 > 0.0 else rope_direction_plain
    n = fn(pn, pe, pd, vn, ve, vd, wn, we, rn, re, k, *f.params)
    r = rotation(*ekf.q.tolist())
    zn, ze, zd = r[2], r[5], r[8]  # body down axis in NED
    # the azimuth the components are taken about: the balloon's lean (from the attitude, a parameter), or in
    # calm air, where it leans less than a few degrees, the state's azimuth (taken as a parameter too)
    lean, horiz = math.hypot(zn, ze), math.hypot(pn, pe)
    if lean > TAUT_LEAN_MIN_SIN:
        an, ae = -zn / lean, -ze / lean
    elif horiz > 1e-3:
        an, ae = pn / horiz, pe / horiz
    else:
        an, ae = 1.0, 0.0
    ncol = len(MODEL_COLUMNS) - (0 if ekf.learn_drag else 1)
    jn, je = ROPE_JAC, ROPE_JAC + N_COLUMNS
    # the attitude is mostly a parameter here too: gyro, accelerometer and magnetometer measure it, and the rope's
    # alignment is the weakest model of all (the balloon rocks on its attachment, the rope waves). Let it
    # rotate the attitude freely and a wrong taut state confirms itself: a rotation about the magnetic field is
    # invisible to the magnetometer, and the alignment turns the attitude about it until the tilt points
    # where the wrong state says (docs/estimator.md); so about that axis only a share is a column (field_axis_row),
    # weighed by how well the models fit (the accelerometer's share that counts, the alignment's nominal noise over
    # the noise it follows). Where the attitude is uncertain, so is the measured lean: its variance along the
    # component (the attitude a "consider" parameter, d z / d att = -[z x]), less the column's, is added to the
    # noise, so that the row's variance is what it would be with the attitude a parameter alone. In calm air the lean
    # is a degree or two and a tenth of a degree of tilt turns its azimuth by several degrees
    # The along component is taken in the lean's vertical plane, tangent to the body's axis (c = (a cos, a cos, sin)
    # of the lean, a its azimuth): the lean's angle itself. The horizontal projection it was (sin(lean)) moves by only
    # cos(lean) of the lean's change and saturates: blown down 80 deg by 15 m/s, a state 15 deg off the balloon's
    # lean read as 2 deg, slid to the horizontal while the barometer's offset took the height, and the wind read
    # 600 m/s (docs/estimator.md, "Blown down"). Its nominal allowance is over cos^2(lean) (at most 1 / LEAN_COS_MIN^2),
    # the information the projection had where the error is small: at a steep lean the rope's static shape holds the
    # angle of its top less well (the tension's vertical share is small against the rope's weight and drag), and the
    # envelope's flights, blown down up to 74 deg, fly as before. The pull's down component follows from its unit
    # length (n_d = sqrt(1 - n_n^2 - n_e^2), at least ALIGN_PULL_DOWN_MIN)
    n_d = math.sqrt(max(1.0 - n[0] * n[0] - n[1] * n[1], ALIGN_PULL_DOWN_MIN * ALIGN_PULL_DOWN_MIN))
    cz = max(zd, LEAN_COS_MIN)
    along_var = max(along_var, nominal_var / (cz * cz))
    rows = ((an * zd, ae * zd, lean, along_var, status[2], 1.0), (-ae, an, 0.0, cross_var, status[3], att_gain))
    for cn, ce, cd, var, st, gain in rows:
        g = lean_jacobian(cn, ce, zn, ze, zd, cd)
        hb = field_axis_row(g, field_ned, share * nominal_var / var if var > 0.0 else 0.0)
        var_att = max(0.0, attitude_variance(ekf.P, *g) - attitude_variance(ekf.P, *hb))
        h.fill(0.0)
        kn, ke = cn - cd * n[0] / n_d, ce - cd * n[1] / n_d  # c . d n / d x, d n_d / d x = -(n_n dn_n + n_e dn_e) / n_d
        for j in range(ncol):
            h[MODEL_COLUMNS[j]] = -(kn * n[jn + j] + ke * n[je + j])  # residual c . (z - n(x))
        h[ATT_N], h[ATT_E], h[ATT_D] = hb
        ekf.fuse(cn * (n[0] - zn) + ce * (n[1] - ze) + cd * (n_d - zd), var + var_att, st, recover=False,
                 att_gain=gain)


def update_rope_shape(ekf: WindEkf, rho: float, alpha: float) -> None:
    """Follow the rope's real shape (catenary.py): its pull on the balloon from the static balance at
    the current state, F = -(drag + N_b up); the chord of the design's rope under that pull; the weight
    the rod must carry for its pull to be the rope's. Low-passed with ``alpha`` (model parameters)."""
    m = ekf.model
    x = ekf.x
    vn, ve, vd = float(x[VEL_N]), float(x[VEL_E]), float(x[VEL_D])
    wn, we, k = float(x[WIND_N]), float(x[WIND_E]), float(x[DRAG])
    un, ue, ud = wn - vn, we - ve, -vd
    kd = k * rho * m.half_cd_area_m2 * math.sqrt(un * un + ue * ue + ud * ud)
    lift = m.lift_n(rho)
    fn, fe, fd = -kd * un, -kd * ue, -kd * ud + lift
    w = m.rope_kg_m * G0
    cn, ce, cd = rope_chord(fn, fe, fd, m.tether_length_m, w, 0.5 * rho * m.rope_cn_d_m, wn, we)
    chord = math.sqrt(cn * cn + ce * ce + cd * cd)
    if not chord > 0.5 * m.tether_length_m:
        return  # no rope shape under this pull (lift gone): keep the last
    weight = effective_rod(fn, fe, fd, cn, ce, cd, m.rope_weight_n)
    rope = ekf.rope
    rope.chord_m += alpha * (chord - rope.chord_m)
    if weight == weight:  # NaN: a vertical chord tells no share, keep the last
        rope.weight_n += alpha * (weight - rope.weight_n)


def control_tether(est: Estimator) -> None:
    """Taut: the radius, radial-rate and alignment rows every ``TAUT_PERIOD_S``; alignment rejected for
    ``ALIGN_RESET_S`` (the tilt contradicts the taut state) re-places the taut state from the tilt."""
    ekf = est.ekf
    if ekf.mode == MODE_TAUT and est.step % est.schedule.taut_every == 0:
        cfg = est.cfg
        if est.catenary:
            update_rope_shape(ekf, est.rho, est.schedule.rope_shape_alpha)
        # each alignment component's noise follows its recent innovations, as the accelerometer's does
        # (aid_sources/accel.py): a balloon that rocks in gusts is not along its rope force to 0.01 rad,
        # and a model error taken for a precise measurement is rejected, then re-placed, again and again
        mean2 = est._align_innov2
        # the lean's noise is the innovations' spread about their mean, not their mean square: the rocking is
        # noise, a persistent misfit is a lean that is off (a noise that followed it let a lean drifting upright
        # confirm itself in class B gusts on the paper's rope, the barometer's offset taking the height: 46 m in
        # five minutes, the wind a sixth of the truth's); the azimuth's noise no more than a rocking balloon's:
        # beyond it the state, not the model, is off, and the rejections re-place it from the tilt (a noise that
        # followed such innovations would let a wrong azimuth wander on; the gusty flights' cross component
        # stays within 0.05 rad)
        along_var = max(est.align_var, mean2[0] - est._align_mean**2)
        cross_var = max(est.align_var, min(mean2[1], ALIGN_CROSS_VAR_MAX))
        # where the force model has stopped explaining the accelerometer (class B gusts, the rope's waves: its
        # windowed NIS, accel_misfit) the balloon rocks and the rope waves under it, and the alignment's misfit is
        # correlated too, over a few tenths of a second (ALIGN_MODEL_CORR_S). The cross component's noise stops at a
        # rocking balloon's (ALIGN_CROSS_VAR_MAX, above), so fused at 20 Hz as if white its row took the attitude
        # about the magnetic field's axis with the position's azimuth (through P's correlation of the two), 1-2 deg a
        # second for seconds where P allowed a tenth of that, and the pair swung across the rope after the taut entry
        # (docs/estimator.md, "The swing after the taut entry"). There the attitude takes no more of that row's gain
        # than a correlated misfit allows, sqrt(interval / ALIGN_MODEL_CORR_S), as the accelerometer's tilt does;
        # where the model fits, all of it; the position and the gyro bias always all of it, and the along component
        # (its noise follows its innovations' spread without a bound) all of its gain
        misfit = accel_misfit(est.consistency.nis[ACCEL])
        least = min(1.0, math.sqrt(est.schedule.taut_every * ekf.dt / ALIGN_MODEL_CORR_S))
        fuse_taut(ekf, cfg.radial_m**2, cfg.radial_rate_mps**2, along_var, cross_var, est.taut_status, est.field_ned,
                  est.align_var, ALIGN_FIELD_AXIS_SHARE * (1.0 - misfit), 1.0 - misfit * (1.0 - least))  # fmt: skip
        along, cross = est.taut_status[2], est.taut_status[3]
        if along.time_test_us == ekf.time_us:
            mean2[0] += est._align_alpha * (along.innov**2 - mean2[0])
            mean2[1] += est._align_alpha * (cross.innov**2 - mean2[1])
            est._align_mean += est._align_alpha * (along.innov - est._align_mean)
            # the body's tilt (its down axis, rotation()'s third column alone) and the lean the model disagrees with
            q0, q1, q2, q3 = ekf.q.tolist()
            zn, ze, zd = 2.0 * (q1 * q3 + q0 * q2), 2.0 * (q2 * q3 - q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
            est.consistency.add_lean(math.atan2(math.hypot(zn, ze), zd), along.innov, est._taut_alpha)
        if max(along.consecutive_rejects, cross.consecutive_rejects) >= est.schedule.align_reset:
            est.counters.taut_resets += 1
            along.consecutive_rejects = cross.consecutive_rejects = 0
            enter_taut(est, est._height_for_taut(), from_tilt=True)
