"""The accelerometer: its specific-force rows (paper Eq. 9) and when and how loud to fuse them."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from balloon_core.atmosphere import G0
from balloon_core.rotation import rotation
from firmware_py.estimator.consistency import ACCEL, accel_misfit, field_tilt_reading, slow_innovation_share
from firmware_py.estimator.ekf import FusionStatus, WindEkf
from firmware_py.estimator.params import (
    ACCEL_HBIAS_MAX_MPS2,
    ACCEL_HBIAS_RESIDUE,
    ACCEL_HBIAS_S,
    ACCEL_HEADING_GAIN_MIN,
    ACCEL_MODEL_CORR_S,
    LEVEL_CORR_S,
    LEVEL_MEAN_S,
    UNGATED,
)
from firmware_py.estimator.state import (
    ABIAS_Z,
    ATT_D,
    ATT_E,
    ATT_N,
    DRAG,
    MODE_GROUND,
    MODE_TAUT,
)
from firmware_py.estimator.tuning import vertical_air_samples

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def fuse_accel(
    ekf: WindEkf, fx: float, fy: float, fz: float, var: float, status: list[FusionStatus], var_z_extra: float = 0.0,
    misfit: float = 0.0, radial_var: float = 0.0,
) -> tuple[float, float, float]:  # fmt: skip
    """Specific force in FRD against the force model, f = R^T (a(x) - g) + (0, 0, b_z): tilt (through
    g) and the balloon's dynamics (drag of the wind, the air's push, the rope) through a(x), with the
    body-z bias b_z (a persistent vertical misfit would otherwise be read as a lean of the wind). On
    the ground the balloon is held (a = 0): a gravity reference, where b_z is learnt; in flight these rows leave it
    out (there it would trade with the lean) and ``fuse_bias_magnitude`` follows it. The three axes are fused as
    one vector, with ``radial_var radial radial^T`` more noise along the tether's radius: ``radial`` = R^T p, the
    balloon's position from the anchor in the body frame (its outer product over |p|^2 is the unit vector's, one
    division where the unit vector takes three and a root: the Cortex-M4F's budget). Returns ``radial`` (zeros off
    the taut tether)."""
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
    radial = [0.0, 0.0, 0.0]
    pn, pe, pd = float(ekf.x[0]), float(ekf.x[1]), float(ekf.x[2])
    taut = ekf.mode == MODE_TAUT
    rt = ekf.rt
    for i in range(3):
        cn, ce, cd = r[i], r[3 + i], r[6 + i]  # row i of R^T
        pred[i] = cn * yn + ce * ye + cd * yd
        if taut:
            radial[i] = cn * pn + ce * pe + cd * pd
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
    if ground:  # learnt at rest, where g is the only force; in flight from the length of f (fuse_bias_magnitude)
        H[2, ABIAS_Z] = 1.0
    pred[2] += float(ekf.x[ABIAS_Z])
    # in flight the tilt takes only what a correlated model error allows (params.ACCEL_MODEL_CORR_S); the heading and
    # the gyro bias less in proportion to ``misfit`` (0: the model explains the accelerometer, 1: it does not), at
    # least ACCEL_HEADING_GAIN_MIN (the position's azimuth, which these rows also move, takes all of it)
    tilt_gain = 1.0 if ground else min(1.0, math.sqrt(ekf.dt / ACCEL_MODEL_CORR_S))
    heading_gain = 1.0 - misfit * (1.0 - ACCEL_HEADING_GAIN_MIN)
    ekf.fuse3(fx - pred[0], fy - pred[1], fz - pred[2], var, status, var_z_extra, tilt_gain, heading_gain,
              (radial[0], radial[1], radial[2]), radial_var)  # fmt: skip
    return radial[0], radial[1], radial[2]


def fuse_level(ekf: WindEkf, fn: float, fe: float, var: float, status: FusionStatus) -> None:
    """A tethered balloon does not accelerate on average: the horizontal specific force in NED (``fn``, ``fe``: the
    body's turned by the attitude, m/s^2) is then gravity's tilt alone, R f = (I - [d x]) (a - g) with a ~ 0, whose
    north and east parts are g d_E and -g d_N (d the attitude's error). No force model enters: where the model's
    forces do not balance (a wind across the lean held with the attitude about the magnetic field's axis, which the
    magnetometer cannot see and the accelerometer's model rows share with the wind: docs/estimator.md, "The wind
    held across the lean by the unseen rotation") these rows still level the attitude. ``var`` the noise of each
    (params.LEVEL_CORR_S); one ``status`` for both (the east row's innovation last)."""
    h = ekf.h
    h.fill(0.0)
    h[ATT_E] = G0
    ekf.fuse(fn, var, status, UNGATED, recover=False)
    h.fill(0.0)
    h[ATT_N] = -G0
    ekf.fuse(fe, var, status, UNGATED, recover=False)


def horizontal_ned(rt: np.ndarray, x: float, y: float, z: float) -> tuple[float, float]:
    """A body-frame (FRD) vector's north and east parts; ``rt`` R^T, as the accelerometer's rows left it this step
    (fuse_accel)."""
    return (float(rt[0, 0]) * x + float(rt[1, 0]) * y + float(rt[2, 0]) * z,
            float(rt[0, 1]) * x + float(rt[1, 1]) * y + float(rt[2, 1]) * z)  # fmt: skip


def level_noise(est: Estimator, fn: float, fe: float, step_s: float, prior_var: float) -> float:
    """The level rows' noise (fuse_level) from the specific force's north and east parts (its biases taken out,
    ``horizontal_ned``): their variance about their mean over LEVEL_MEAN_S (per axis, at least the accelerometer's own
    noise, [sensors] accel_mps2) times 2 LEVEL_CORR_S / ``step_s``; the mean and the variance followed here (in flight,
    at the tether's rate: the free ascent's accelerations are what the taut entry starts from). Nothing followed yet
    (the first flying step since the filter started, or since it joined a balloon in flight on its tether): the mean
    starts at this sample and the variance at ``prior_var``, the accelerometer's nominal noise in the mode, what the
    model allows its specific force (from zero the rows were as confident as the sensor's noise for seconds)."""
    m = est.level_mean
    if est.level_var == 0.0:
        m[0], m[1] = fn, fe
        est.level_var = prior_var
    a = step_s / LEVEL_MEAN_S
    m[0] += a * (fn - m[0])
    m[1] += a * (fe - m[1])
    dn, de = fn - m[0], fe - m[1]
    est.level_var += a * (0.5 * (dn * dn + de * de) - est.level_var)
    sensor = est.design.sensors.accel_mps2
    return max(est.level_var, sensor * sensor) * 2.0 * LEVEL_CORR_S / step_s


def radial_noise(innov2_radial: float, var: float) -> float:
    """What more noise the accelerometer takes along the tether's radius on the taut tether than ``var`` on every axis,
    (m/s^2)^2: its innovations' mean square along the radius beyond that, else 0.

    The taut model holds the balloon on a sphere of the rope's chord (paper Sec. 2.3), but a real rope breathes: it
    stretches with the pull and its sag changes with it, so in gusts the balloon moves along its radius and the
    accelerometer reads it there (in IEC class B gusts the misfit along the rope is the truth's acceleration along it,
    correlation 0.95-1.00, NIS 6-40 where across it is under 1: docs/estimator.md, "Too cautious in IEC class B
    gusts"). On every axis the noise follows the three axes' mean square (``control_accel``), a third of the radius's:
    the radius's row, which carries the rope's motion, was fused at three times the weight it has. Only more, never
    less across: there a wind across the lean and the attitude about the magnetic field's axis look alike (docs/
    estimator.md, "The wind held across the lean by the unseen rotation"), and the rows across the rope fused at their
    own smaller noise swung class B gusts from the south 8 m/s across the wind."""
    return max(0.0, innov2_radial - var)


def fuse_bias_magnitude(
    ekf: WindEkf, fx: float, fy: float, fz: float, accel: list[FusionStatus], var: float, status: FusionStatus
) -> None:
    """The body-z bias on the tether, from the specific force along itself (paper Eq. 9 read as a length): the
    innovations ``fuse_accel`` left in ``accel`` projected on the predicted specific force (FRD), whose z share is
    the bias's row. A tethered balloon does not accelerate on average, and R^T (a - g) has the length |a - g|
    whatever the attitude: a tilt turns f and moves the innovation across it (along it only to second order,
    g d^2 / 2), so no tilt, lean or wind can take what this sees. The accelerometer's own rows leave the bias out in
    flight: there it traded with the lean (the paper's reduced balloon learnt 0.11 m/s^2 where there was none, and
    read the wind 6 % low), whose hold is the z row's gravity (docs/estimator.md, "Vertical air and the
    accelerometer's z"). Its noise ``var`` per sample at the tether's rate: along f the accelerometer's misfit is the
    rope's axial bounce, which changes sign within half a second (not the drag's lag behind the wind that
    ACCEL_MODEL_CORR_S holds for the tilt), and the vertical air's is worth one sample in
    ``tuning.vertical_air_samples`` (the caller weighs it so). Gated as any source, never forced."""
    nx, ny, nz = accel[0].innov, accel[1].innov, accel[2].innov
    px, py, pz = fx - nx, fy - ny, fz - nz
    pred = math.sqrt(px * px + py * py + pz * pz)
    if not pred > 0.5 * G0:  # no gravity to read the length against
        return
    ekf.h.fill(0.0)
    ekf.h[ABIAS_Z] = pz / pred
    ekf.fuse((nx * px + ny * py + nz * pz) / pred, var, status, recover=False)


def follow_horizontal_bias(
    hbias: list[float], innov_n: float, innov_e: float, field_ned: tuple[float, float, float], rt: np.ndarray,
    weight: float,
) -> bool:  # fmt: skip
    """One step of the accelerometer's body x and y biases walked since the earth field was learnt, in place, from the
    horizontal innovation ``fuse_accel`` left (NED, m/s^2): its share along the field's horizontal direction, back in
    the body frame (``rt``: R^T), ``weight`` of it (the step's interval over ACCEL_HBIAS_S, times the share of the
    innovation that counts, consistency.slow_innovation_share), within +-ACCEL_HBIAS_MAX_MPS2. The caller subtracts
    them from the samples. Nothing while the field is unknown, nor from a step that is not finite (a numeric reset's);
    False then, and where the guard holds the bias: the step did not follow (``horizontal_bias_variance``).

    A tethered balloon does not accelerate on average, so over minutes the accelerometer reads gravity in the body
    frame plus its bias. The field learnt at the boot holds the attitude about every axis but its own, so a bias that
    walks after the boot is read as a tilt only where that is a turn about the field's axis (g cos I of it, across
    the field's horizontal direction: there a bias and a turn are the same to every sensor, and the tilt's systematic
    term states it, consistency.lean_bias_rad). Along the field's horizontal direction no tilt can take it: the filter
    reads it as a force across the rope and turns the wind (a 0.1 m/s^2 step on body x, a 3 m/s wind: 9 deg), and
    about a quarter of it stays in the innovation. Summed, that residue moves the bias until none stays; where the
    model misfits (a gust, light air swinging faster than the balloon follows) the share that counts falls, and the
    step with it: a misfit is not a bias. No state (the Cortex-M4F's RAM holds 19): two floats and their own loop
    (docs/estimator.md, "The long day")."""
    bn, be = field_ned[0], field_ned[1]
    bh2 = bn * bn + be * be
    if not bh2 > 0.0:
        return False
    s = weight * (innov_n * bn + innov_e * be) / bh2  # the innovation along the field's horizontal direction, x weight
    if not math.isfinite(s):
        return False
    vn, ve = s * bn, s * be
    free = True
    for i in range(2):
        b = hbias[i] + float(rt[i, 0]) * vn + float(rt[i, 1]) * ve
        hbias[i] = max(-ACCEL_HBIAS_MAX_MPS2, min(ACCEL_HBIAS_MAX_MPS2, b))
        free = free and hbias[i] == b
    return free


def horizontal_bias_variance(var: float, walk_var: float, weight: float) -> float:
    """One step of the error variance of the bias ``follow_horizontal_bias`` follows, (m/s^2)^2: the walk's
    ``walk_var`` (its variance over the step) added, and what the loop's step ``weight`` removes, twice its gain on a
    bias (ACCEL_HBIAS_RESIDUE of the step) times the variance. With the full share it settles at walk^2
    ACCEL_HBIAS_S / (2 ACCEL_HBIAS_RESIDUE) (0.001 m/s^2 per sqrt(s): 0.025 m/s^2); where the model misfits and the loop
    stops it grows as the unfollowed walk does."""
    return max(0.0, var + walk_var - 2.0 * ACCEL_HBIAS_RESIDUE * weight * var)


def accel_nominal_var(est: Estimator) -> float:
    """The accelerometer's nominal noise in the filter's mode (on the ground, free, taut), (m/s^2)^2."""
    return (est.accel_static_var, est.accel_var, est.accel_taut_var)[est.ekf.mode]


def control_accel(est: Estimator, ax: float, ay: float, az: float) -> None:
    """Fuse the specific force every step; its noise follows its recent innovations (the force model's
    own error grows when the state is far from the truth, after a placement, or the physics departs from
    the model: a drag crisis, a gust the rate state cannot follow), so that a model that is off does not
    drag the attitude with it (the magnetometer and the gyro keep it); on the taut tether more along its radius, as
    its innovations there say (``radial_noise``: the rope's breathing). In flight its NIS against the nominal noise
    joins the consistency monitor here, where the noise it was fused with is known: the same step's readers of the
    monitor (the alignment's share about the field's axis, the attitude's extra variance) see it, and it is counted
    in the mode the step fused it in."""
    ekf = est.ekf
    hbias = est.accel_hbias
    ax -= hbias[0]
    ay -= hbias[1]
    var = nominal = accel_nominal_var(est)
    var = max(var, est._accel_innov2)
    taut = ekf.mode == MODE_TAUT
    d2, radial_var = 0.0, 0.0  # |p|^2, and radial_var per unit of |R^T p|^2 (fuse_accel)
    if taut:  # the rope's breathing along the radius is its own noise (radial_noise)
        pn, pe, pd = float(ekf.x[0]), float(ekf.x[1]), float(ekf.x[2])
        d2 = pn * pn + pe * pe + pd * pd
        if d2 > 1.0:
            radial_var = radial_noise(est._accel_radial_innov2, var) / d2
    est._accel_var_excess = var - nominal
    # the accelerometer's windowed NIS (the consistency monitor) from FLAG_NIS to twice that: the model stops
    # explaining it; the vertical air the model leaves out moves the balloon along its body z (_vertical_gust_var)
    misfit = accel_misfit(est.consistency.nis[ACCEL])
    radial = fuse_accel(ekf, ax, ay, az, var, est.accel_status,
                        est.vertical_gust_var if ekf.mode != MODE_GROUND else 0.0, misfit, radial_var)  # fmt: skip
    st = est.accel_status
    n0, n1, n2 = st[0].innov, st[1].innov, st[2].innov
    a = est._innov_alpha
    i2 = n0 * n0 + n1 * n1 + n2 * n2
    est._accel_innov2 += a * (i2 / 3.0 - est._accel_innov2)
    if taut and d2 > 1.0:
        ir = radial[0] * n0 + radial[1] * n1 + radial[2] * n2
        est._accel_radial_innov2 += a * (ir * ir / d2 - est._accel_radial_innov2)
    elif not taut:  # off the tether, the three axes' mean: the taut entry starts from it
        est._accel_radial_innov2 = est._accel_innov2
    if ekf.mode != MODE_GROUND:
        # the consistency monitor: each axis against the nominal noise (its innovations' variance less what the
        # noise followed beyond it: the rope's breathing is the model's misfit too, which the monitor must see)
        ex = var - nominal
        axis_nis = est._accel_axis_nis
        for i in range(3):
            axis_nis[i] = st[i].innov ** 2 / max(st[i].innov_var - (ex + radial_var * radial[i] * radial[i]), 1e-12)
        est.consistency.add(ACCEL, sum(axis_nis) / 3.0, est._step_alpha)
    if est.step % est.schedule.taut_every:
        return
    step_s = est.schedule.taut_every * ekf.dt
    weight = 0.0  # the horizontal bias's loop step (follow_horizontal_bias), 0 where it did not follow
    if ekf.mode != MODE_GROUND:
        # its slow horizontal innovation, NED (R^T's columns), for the stated accuracy, at the tether's rate (20 Hz:
        # plenty for a 10 s low-pass, consistency.SLOW_INNOV_S, and off the steps that are the median's), with the
        # share that counts (consistency.slow_innovation_share)
        rt = ekf.rt
        innov_n, innov_e = horizontal_ned(rt, st[0].innov, st[1].innov, st[2].innov)
        share = slow_innovation_share(misfit, nominal, var)
        est.consistency.add_slow_tilt(share * field_tilt_reading(innov_n, innov_e, est.field_ned), est._taut_alpha)
        fn, fe = horizontal_ned(rt, ax, ay, az - float(ekf.x[ABIAS_Z]))
        level_var = level_noise(est, fn, fe, step_s, nominal)
        if ekf.mode == MODE_TAUT:  # on the tether (the free ascent is a minute: the ground's value holds)
            fuse_level(ekf, fn, fe, level_var, est.level_status)
            fuse_bias_magnitude(ekf, ax, ay, az, st, var + est.vertical_gust_var * vertical_air_samples(
                step_s, est._mean_speed), est.accel_bias_status)  # fmt: skip
            w = share * step_s / ACCEL_HBIAS_S if math.isfinite(share) else 0.0
            weight = w if follow_horizontal_bias(hbias, innov_n, innov_e, est.field_ned, rt, w) else 0.0
    walk = est.cfg.accel_bias_walk_mps2_rt_s  # it walks in every mode, the ground's too
    est.accel_hbias_var = horizontal_bias_variance(est.accel_hbias_var, walk * walk * step_s, weight)
