"""The magnetometer: the earth field learnt on the ground and again on the tether, the field-vector and heading rows."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from balloon_core.atmosphere import G0
from balloon_core.rotation import rotation
from firmware_py.estimator.ekf import FusionStatus, WindEkf
from firmware_py.estimator.params import (
    FIELD_CHANGE_GAUSS,
    FIELD_FLIGHT_S,
    FIELD_HEADING_VAR_MAX,
    FIELD_JUMP_GAUSS,
    FIELD_JUMP_LONG_S,
    FIELD_JUMP_REJECTED_S,
    FIELD_JUMP_SHORT_S,
    FIELD_RELEARN_AGAIN_FROM_S,
    FIELD_RELEARN_FROM_S,
    FIELD_RELEARN_S,
)
from firmware_py.estimator.state import (
    ATT_D,
    ATT_E,
    ATT_N,
    MODE_GROUND,
    MODE_TAUT,
)

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator

# the windows after a taut placement (from, length; us, as the C core casts): a short one once the rope's catch is
# damped, a long one once the balloon has turned to the wind
FIELD_FLIGHT_US = int(FIELD_FLIGHT_S * 1e6)
FIELD_WINDOW_STATE = 7  # Estimator._field_window: its state (2k armed for window k, 2k + 1 summing, 4 done) ...
FIELD_REPLACED_EARLY = 16  # ... and this bit: the first window replaced the field
FIELD_JUMPED = 32  # ... and this one: the magnetometer's own field jumped, and a window learns it since (field_jump)
FIELD_JUMP_REJECTED_US = int(FIELD_JUMP_REJECTED_S * 1e6)
FIELD_RELEARN_WINDOWS_US = (
    (int(FIELD_RELEARN_FROM_S * 1e6), int(FIELD_RELEARN_S * 1e6)),
    (int(FIELD_RELEARN_AGAIN_FROM_S * 1e6), FIELD_FLIGHT_US),
)


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


def learn_field_in_flight(est: Estimator, ax: float, ay: float, az: float, mx: float, my: float, mz: float) -> None:
    """The earth field learnt again on the taut tether, at its rate, twice after each taut placement (the windows of
    ``FIELD_RELEARN_WINDOWS_US``; ``_field_window`` 2k armed for window k, 2k + 1 summing, 4 done, and whether the
    first replaced the field): into ``_field_sum`` the specific force in NED through the filter's attitude ([0:3]),
    ``m . f`` ([3]), ``|m|^2`` ([4]) and the samples ([5]: the link may lose any of them); at the first sample past
    each window, the field. The first
    window, FIELD_RELEARN_S from FIELD_RELEARN_FROM_S after the placement, once the rope's catch is damped: until the
    field is replaced a hard-iron offset tilted with the balloon pulls the attitude and the wind with it (a stale
    field's residual of 0.03 G at a 25 deg lean: the wind 3-4 m/s off for the minute and a half the second window alone
    took); it replaces the field only beyond twice FIELD_CHANGE_GAUSS, the scatter of a quarter of the samples (class B
    gusts move its means by up to 0.011 G). The second, FIELD_FLIGHT_S from FIELD_RELEARN_AGAIN_FROM_S, once a
    released balloon has turned to the wind and with four times the first's samples: it takes the place of a field
    the first replaced whatever it differs by (a balloon released into a wind may still turn in the first). On a
    tether that does not accelerate on average the mean specific force is gravity's, so the field's down component
    is ``-mean(m . f) / |mean(R f)|``: ``m . f`` does not change as the balloon turns or rocks, and the attitude's
    error turns the mean in NED without shortening it (a body-frame mean is shortened by the rocking, a per-sample
    ``f / |f|`` by the balloon's own accelerations: each put the inclination a few hundredths of a degree off, which
    turned the wind by a degree). Its magnitude from ``mean(|m|^2)`` less the magnetometer's noise; the horizontal
    part along the declination, as learnt.

    The field learnt at the boot (``learn_field``) holds at the boot's heading and tilt only. A balloon turns once
    released (a sphere is a weak vane: a seam, the valve, the avionics; the rope twists) and leans on its tether: a
    hard-iron offset (the avionics' own field, fixed in the body) then adds another part to the field's component
    along gravity, and an accelerometer's bias another part to the specific force's direction. The field vector
    fused against the boot's then disagrees with what the balloon measures, and the filter tilts its attitude to
    fit, which turns the lean and the wind (`field-turning-hard-iron`: 25-35 deg off, error/accuracy 1.6-2.2; 5-11 deg
    learnt again). Only a field beyond FIELD_CHANGE_GAUSS of the boot's replaces it: at rest and level the boot's is
    the better measurement, where in flight the accelerometer's bias reads differently at the lean and gusts shake
    the means (a turned balloon's accelerometer bias alone moves it 0.002 G, within that: `field-turning` is not
    helped). Twice a placement, not followed: an accelerometer bias that walks after it must stay the tilt the field
    contradicts, which the bias's own loop follows (accel.follow_horizontal_bias); a field that followed it would
    take it as a tilt (a continuous mean over FIELD_FLIGHT_S held a 0.2 m/s^2 step to a fifth of it).

    What the window cannot see is the field's horizontal direction: it is the heading's reference. An offset fixed in
    the body that turned with the balloon moved the field it measures along the field's horizontal direction and
    down, which the window sees (the change ``|Δ|``), and across it (east of magnetic north), which turns the heading
    unseen. A balloon turns about the vertical, and the change is then horizontal: as likely across as along, so the
    heading takes ``(|Δ| / B_h)²`` of variance (``field_heading_var``, in the stated accuracy: its share across the
    wind, ``|w| |Δ| / B_h``; a second replacement's adds to it, cautiously where the balloon turned back between
    spells; at most FIELD_HEADING_VAR_MAX). A field whose
    horizontal part is gone (within FIELD_CHANGE_GAUSS of none: a design whose magnetometer noise leaves none of it
    after the noise's share) replaces nothing. A field replaced because the boot's was disturbed (a steel vehicle
    beside the ground station) costs the same, cautiously: the window cannot tell the two apart.

    After a jump of the magnetometer's own field (``field_jump``) one window of FIELD_RELEARN_S starts at once, timed
    by its samples, and learns the whole vector: its down component and strength as above, and its horizontal
    direction from the field turned into NED by the attitude ([0:2] north and east of R m instead of R f, the down
    part's magnitude then (R f) down's). Without the magnetometer the gyro holds the heading across the window (to
    its noise and bias: P's heading), so the field it reads is the new one where the balloon is; what the heading had
    wrong when the window closed stays in the reference, and ``field_heading_var`` takes P's heading variance. No
    more windows in that taut spell. The windows skip samples the field's rows reject (a burst beside the
    magnetometer: summed, 0.2 s of 0.1 G in every 2 s made a field 0.01 G off)."""
    # from the taut spell's start or its last placement, the later: a re-placement starts the windows again
    since_us = min(est.ekf.time_us - est.ekf.time_taut_us, est._dwell * est.dt_us)
    s = est._field_sum
    if since_us < FIELD_RELEARN_WINDOWS_US[0][0]:
        est._field_window = 0
        follow_field_strength(est, mx, my, mz, True)
        return
    jumped = est._field_window & FIELD_JUMPED
    k = (est._field_window & FIELD_WINDOW_STATE) // 2  # the window: even armed, odd summing
    rejected = est.mag_status[0].consecutive_rejects > 0  # (before watch_field holds the rows' recover)
    if jumped:  # a jump's window starts at once and is timed by its samples (field_jump)
        length_us = FIELD_RELEARN_WINDOWS_US[0][1]
        summing = s[5] * est.schedule.taut_every * est.dt_us < length_us
    else:
        if watch_field(est, mx, my, mz) or k >= len(FIELD_RELEARN_WINDOWS_US):
            return
        start_us, length_us = FIELD_RELEARN_WINDOWS_US[k]
        if since_us < start_us:
            return
        if est._field_window & 1 == 0:
            s[0] = s[1] = s[2] = s[3] = s[4] = s[5] = 0.0
            est._field_window += 1
        summing = since_us < start_us + length_us
    if summing:
        if rejected:  # a field the rows reject (a burst beside the magnetometer)
            return
        r = rotation(*est.ekf.q.tolist())
        # [0:2] north and east of the specific force turned into NED, after a jump of the field (its direction)
        hx, hy, hz = (mx, my, mz) if jumped else (ax, ay, az)
        s[0] += r[0] * hx + r[1] * hy + r[2] * hz
        s[1] += r[3] * hx + r[4] * hy + r[5] * hz
        s[2] += r[6] * ax + r[7] * ay + r[8] * az
        s[3] += ax * mx + ay * my + az * mz
        s[4] += mx * mx + my * my + mz * mz
        s[5] += 1.0
        return
    est._field_window = 2 * len(FIELD_RELEARN_WINDOWS_US) if jumped else est._field_window + 1
    c = s[5]
    f = -s[2] if jumped else math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    if not f > 0.5 * G0 * c:  # no gravity to read the field's down component against (nor any sample)
        return
    down = -s[3] / f  # at rest the specific force points up
    bn, be, bd = est.field_ned
    h = h_old = math.sqrt(bn * bn + be * be)
    h_new = math.sqrt(max(0.0, s[4] / c - 3.0 * est.mag_sigma * est.mag_sigma - down * down))
    change2 = (h_new - h_old) ** 2 + (down - bd) ** 2
    # a shorter window's scatter is larger; the second window, four times the first's samples, takes the place of a
    # field the first replaced whatever it differs by
    gate2 = FIELD_CHANGE_GAUSS * FIELD_CHANGE_GAUSS * FIELD_FLIGHT_US / length_us
    if jumped:  # the whole field, its direction through the heading the gyro held; the strength's means from here
        est.field_strength[0] = est.field_strength[1] = s[4] / c
        if h_new > FIELD_CHANGE_GAUSS:
            psi = math.atan2(s[1], s[0])
            est.field_ned = (h_new * math.cos(psi), h_new * math.sin(psi), down)
            est.field_heading_var = min(est.field_heading_var + float(est.ekf.P[ATT_D, ATT_D]), FIELD_HEADING_VAR_MAX)
            h, bd = h_new, down
    elif h_old > 0.0 and h_new > FIELD_CHANGE_GAUSS and (change2 > gate2 or est._field_window & FIELD_REPLACED_EARLY):
        est.field_ned = (bn * h_new / h_old, be * h_new / h_old, down)
        # each replacement's unseen part adds to the last's (each against the field before it), to a radian's at most
        est.field_heading_var = min(est.field_heading_var + change2 / (h_new * h_new), FIELD_HEADING_VAR_MAX)
        h, bd = h_new, down
        if k == 0:
            est._field_window |= FIELD_REPLACED_EARLY
    # the sums learn_field would have taken of the field at rest, level, from as many samples as it had: a balloon
    # back on the ground station adds its own to them
    n = float(est._field_n)
    s[0], s[1], s[2], s[3], s[4], s[5] = 0.0, 0.0, -G0 * n, h * n, 0.0, bd * n


def watch_field(est: Estimator, mx: float, my: float, mz: float) -> bool:
    """Whether the magnetometer's own field jumped (then ``field_jump``), at the tether's rate on the taut tether once
    the rope's catch is damped. A heater, a radio or a servo switched beside the magnetometer adds a field fixed in the
    body, which the field learnt at the boot (or again on the tether) cannot hold: fused against it, the field vector
    turns the attitude to fit, the tilt most, and the tilt is the wind's (0.02 G along the body's x, 4 % of the
    field: the attitude 1.5 deg off in a second, the wind 1.6-2.3 m/s off at error/accuracy 0.9-1.0 for a minute and a
    half, `field-rope`). Two signs of it that no turn of the balloon makes: the field's strength |m| leaving its own
    mean (``field_strength``: over FIELD_JUMP_SHORT_S against FIELD_JUMP_LONG_S, by FIELD_JUMP_GAUSS), and the field
    vector rejected for FIELD_JUMP_REJECTED_S in a row from a sample it was fused (a change across the field and the
    gravity: a rotation would explain it, but the gyro says the balloon did not turn). Meanwhile the rows' recover at
    the gate (``mag_recover``, which walks the attitude to the field) is held: its run of rejections set back before
    it gets there. A filter whose attitude has lost the gyro's track has its variance grown (a gap's, a placement's),
    and its field is not rejected; a magnetometer silent for longer than that before its field is rejected is the
    heading the gyro alone held (the recover walks it back); a burst (a radio's transmission, tenths of a second) is
    rejected and is neither."""
    st, status = est.field_strength, est.mag_status[0]
    rejected = False
    if status.consecutive_rejects == 0:  # (a rejected sample, a burst's or a jump's, is not the field's strength)
        follow_field_strength(est, mx, my, mz, False)
    else:
        # a run of rejections that began as the field was being fused: a jump once it lasts FIELD_JUMP_REJECTED_S
        # (seen at the one tether step that crosses it), the recover held until then. One that began after the
        # magnetometer fell silent for longer (its heading the gyro's since) is the attitude's: the recover walks it
        unfused_us = est.ekf.time_us - status.time_last_fuse_us
        young = unfused_us < FIELD_JUMP_REJECTED_US + est.schedule.taut_every * est.dt_us
        rejected = young and unfused_us >= FIELD_JUMP_REJECTED_US
        if young and status.consecutive_rejects >= max(1, est.schedule.mag_recover - est.schedule.taut_every):
            for m in est.mag_status:  # not fused at the gate: here a field rejected is the magnetometer's
                m.consecutive_rejects = 0
    jump = abs(math.sqrt(st[0]) - math.sqrt(st[1]))
    if not (jump > FIELD_JUMP_GAUSS or rejected):
        return False
    field_jump(est, jump * jump / st[0] if jump > FIELD_JUMP_GAUSS else 0.0)
    return True


def follow_field_strength(est: Estimator, mx: float, my: float, mz: float, settling: bool) -> None:
    """The field's strength squared, its means over FIELD_JUMP_SHORT_S and FIELD_JUMP_LONG_S (``field_strength``),
    at the tether's rate. While a taut placement ``settling`` (the rope's catch) both are the short one: the long one
    starts from a second's mean, not from one sample's noise (which its ten seconds take to forget: 0.005 G against
    a gate of 0.004 G)."""
    st = est.field_strength
    m2 = mx * mx + my * my + mz * mz
    if st[0] == 0.0:
        st[0] = m2
    step_s = est.schedule.taut_every * est.dt_us * 1e-6
    st[0] += step_s / FIELD_JUMP_SHORT_S * (m2 - st[0])
    st[1] = st[0] if settling else st[1] + step_s / FIELD_JUMP_LONG_S * (m2 - st[1])


def field_jump(est: Estimator, tilt_var: float) -> None:
    """The magnetometer's own field jumped (``watch_field``): counted, the field vector no longer fused, and learnt
    again over FIELD_RELEARN_S from now (``learn_field_in_flight``); the attitude's variance grown by ``tilt_var``
    (rad^2, the jump's share of the field: what the rows may have turned it by before the jump was seen)."""
    est.counters.field_jumps += 1
    est._field_window = FIELD_JUMPED
    s = est._field_sum
    s[0] = s[1] = s[2] = s[3] = s[4] = s[5] = 0.0
    for st in est.mag_status:
        st.consecutive_rejects = 0
    if tilt_var > 0.0:
        est.ekf.inflate_attitude(tilt_var)


def control_mag(est: Estimator, ax: float, ay: float, az: float, mx: float, my: float, mz: float) -> None:
    """Every sample with a valid field: learn the earth field from rotation-invariant averages (|m| and
    m . f: at rest on the ground, or after a restart in flight on the quasi-static balloon, whose mean
    acceleration is 0), then fuse the whole field vector once it is known in flight, else the heading; on the taut
    tether learn it again twice after each taut placement (``learn_field_in_flight``; a
    sender joined in flight learnt it there already)."""
    ekf = est.ekf
    sched = est.schedule
    if ekf.mode == MODE_GROUND or (est._joined and est._field_n < sched.field_flight):
        learn_field(est, ax, ay, az, mx, my, mz)
    elif (ekf.mode == MODE_TAUT and not est._joined and est._field_n >= sched.field_learn
          and est.step % sched.taut_every == 0):
        learn_field_in_flight(est, ax, ay, az, mx, my, mz)
    if est._field_n >= sched.field_learn and ekf.mode != MODE_GROUND:
        if not est._field_window & FIELD_JUMPED:  # a jumped field is learnt again before it is fused (field_jump)
            fuse_mag_field(ekf, mx, my, mz, est.field_ned, est.mag_var, est.mag_status)
    else:
        fuse_heading(ekf, mx, my, mz, est.declination, est.mag_sigma, est.heading_status)
