"""Is the model explaining the data? The consistency monitor (docs/estimator.md, "Honest accuracy").

A filter whose model is wrong does not see it in its covariance: P shrinks with every fusion whatever
the data say. What does see it is the innovation sequence. PX4 tests each innovation against its
variance (the test ratio) and rejects the outliers; a model that is slightly but persistently wrong
passes every single test. So here each aid source's normalised innovation squared,
NIS = innovation^2 / innovation variance, is averaged over a window of ``CONSISTENCY_S``: in a
consistent filter its mean is 1 or less; a mean of 3 says the source's innovations are sqrt(3) times
what the filter expects, for tens of seconds, and the model does not explain that source.

One more source has no sensor of its own: the force balance (``balance_nis``). A tethered balloon does not
accelerate on average, so what the model's forces put into the velocity the measurements must take out only as
the swing's noise; a wind across the lean held together with the attitude about the magnetic field's axis (which
the accelerometer cannot tell apart and the magnetometer cannot see) leaves the model's forces unbalanced, and
every step the measurements pull the balloon back by the same amount. The innovations of each row stay small;
their mean pull on the velocity, over the window, does not.

What the monitor does with it:
- ``flags``: one bit per source whose windowed NIS is above ``FLAG_NIS`` (until it is below ``FLAG_NIS_CLEAR``); the
  firmware reports them (SYS_STATUS, a STATUSTEXT when they change, the summary) and the products carry them;
- ``inflation``: the factor on the reported wind accuracy, the square root of the largest windowed
  NIS (>= 1): innovations sqrt(NIS) times larger than the filter expects say its errors are too. The
  accelerometer's counts as (1 + NIS) / 2 (``stated_nis``): it is fused every sample at a slow gain, and a filter
  whose noise is NIS times what it assumes errs by (1 + NIS) / 2 of its P (the gain averages the excess over as many
  samples as the state's walk); in class B gusts its misfit is the gusts the wind's state does not follow, and
  sqrt(NIS) stated them 1.6-3 times too cautiously. The other sources' misfits are the state's own (the force
  balance, the lean) and keep sqrt(NIS).

The accuracy itself also carries what the covariance cannot know (``systematic_variance``): the
drag scale's uncertainty (inhibited on the taut tether, so decorrelated from the wind in P) and the
tilt's systematic error. Not the rope's drag coefficient, which the design gives only as a typical
value: the balloon's lean is the pull at the rope's top, the balloon's own drag against its own lift,
whatever the rope below does (the full envelope's truths, the rope's C_n drawn to 30 %: the speed error
moves 0.9 % per unit of it, 0.3 % at one sigma; a steady 7 m/s flight with half and 1.5 times the
rope's C_n: within 0.7 %).

The attitude's slow error about the magnetic field's axis, which P does not hold, is estimated from two sides, and
the larger is stated: the information its sources fused counted as correlated (``field_attitude_extra``), and what
the accelerometer's slow innovation shows of it (``heading_misfit_variance``). Their sum counted the same error
twice: flights that were honest grew more cautious (the envelope: 30.0 % of flights with error/accuracy within
0.75-1.33 where the larger gives 32.0 %), the tails beyond 3 sigma no better.

Plain numbers, fixed memory: a C port is a struct of fourteen floats and two integers.
"""

from __future__ import annotations

import math

from balloon_core.atmosphere import G0
from firmware_py.estimator.params import (
    ALIGN_PULL_DOWN_MIN,
    ENTRY_SETTLE_S,
    LEAN_BIAS_RAD,
    LEAN_COS_MIN,
    TAUT_WIND_SIGMA_MPS,
)
from firmware_py.estimator.state import ATT_D, ATT_E, ATT_N

SOURCES = ("accel", "align", "radius", "baro", "mag", "force")
ACCEL, ALIGN, RADIUS, BARO, MAG, FORCE = range(len(SOURCES))
CONSISTENCY_S = 20.0  # averaging time of each source's NIS
NIS_CLIP = 25.0  # one innovation counts at most as a 5-sigma one: a transient does not rule the window
# ... but the force balance's NIS is a window's mean already (add_balance), not one innovation: clipped at 25 its factor
# stated at most 5 times P's where the forces were unbalanced by 30 sigma for a minute (field-turning-hard-iron
# before the field is learnt again in flight: the wind 6 m/s off at 1.7 stated, 65-86 % beyond 3 sigma)
FORCE_NIS_CLIP = 400.0
FLAG_NIS = 2.0  # a windowed NIS above this flags the source: its innovations are 1.4x their expectation
# a flagged source is cleared once its windowed NIS is below this (1.2x): a NIS that hovers about FLAG_NIS does not
# flip the flag, and its STATUSTEXT, every few seconds (a four-hour field-all through balloon-fw: 119 STATUSTEXT
# about it at 2.0 alone, 61 with this)
FLAG_NIS_CLEAR = 1.5
# the accelerometer's slow innovation (``field_tilt_reading``) is low-passed over this long: longer than the rope's
# waves and the balloon's response to a gust (seconds), shorter than the attitude's wander about the field's axis
# (tens of seconds); over 20 s it lost what turns a 1.9 m/s multisine's heading (envelope flight 181: 3.4 % beyond 3
# sigma where 10 s gave 2.1 %)
SLOW_INNOV_S = 10.0
# the attitude's error about the field's axis over what the slow innovation shows of it, RMS over a flight: the
# innovation keeps only the share of the misfit that the attitude did not take. 1.15 / 0.53, 0.84 / 0.31 and
# 0.41 / 0.27 deg (2.2, 2.7, 1.5) in the envelope's three light-air multisines that went beyond 3 sigma without it
# (python tools/accuracy_terms.py 187 181 151: the attitude's error about the field against the slow innovation)
HEADING_MISFIT_RATIO = 2.0


def stated_nis(source: int, nis: float) -> float:
    """What a source's windowed NIS says of the wind's error, as a variance ratio (the accuracy factor is the square
    root of the largest): the NIS itself, but the accelerometer's (1 + NIS) / 2. It is fused every sample at a slow
    gain, and a filter whose noise is NIS times what it assumes errs by (1 + NIS) / 2 of its P in the steady state
    (tests/unit/test_consistency.py; at most that here, where the fused noise already follows part of the
    innovations)."""
    return 0.5 * (1.0 + nis) if source == ACCEL else nis


class Consistency:
    """Windowed NIS per aid source, the status bits and the accuracy factor; the accelerometer's slow innovation
    read as a rotation about the field, and its mean square (``heading_misfit_variance``)."""

    __slots__ = (
        "nis",
        "flags",
        "inflation",
        "flag_changes",
        "slow_tilt",
        "slow_tilt_var",
        "balance_n",
        "balance_e",
        "balance_var",
        "lean_tilt",
        "lean_misfit",
    )

    def __init__(self) -> None:
        self.nis = [0.0] * len(SOURCES)
        self.flags = 0
        self.inflation = 1.0
        self.flag_changes = 0
        self.slow_tilt = 0.0  # the accelerometer's innovation as a tilt about the field (field_tilt_reading), rad
        self.slow_tilt_var = 0.0  # its square's mean over CONSISTENCY_S, rad^2
        self.balance_n = self.balance_e = 0.0  # the velocity's measurement updates, N and E, their mean (m/s per step)
        self.balance_var = 0.0  # the variance of that mean in a consistent filter ((m/s)^2)
        self.lean_tilt = 0.0  # the body's tilt on the taut tether, its mean over the window (rad; 0: none yet)
        self.lean_misfit = 0.0  # the alignment's along innovation (the tilt less the model pull's lean), its mean (rad)

    def reset(self) -> None:
        for i in range(len(SOURCES)):
            self.nis[i] = 0.0
        self.flags = 0
        self.inflation = 1.0
        self.slow_tilt = self.slow_tilt_var = 0.0
        self.balance_n = self.balance_e = self.balance_var = 0.0
        self.lean_tilt = self.lean_misfit = 0.0

    def add(self, source: int, nis: float, alpha: float, clip: float = NIS_CLIP) -> None:
        """One normalised innovation squared of ``source``, weight ``alpha`` (its interval / window), at most
        ``clip``."""
        if nis == nis:  # NaN: not evaluated
            self.nis[source] += alpha * (min(nis, clip) - self.nis[source])

    def add_slow_tilt(self, reading: float, alpha: float) -> None:
        """One ``field_tilt_reading`` (rad, with the share that counts: aid_sources/accel.py), weight ``alpha`` (its
        interval / CONSISTENCY_S): low-passed over SLOW_INNOV_S, its square averaged over the window."""
        self.slow_tilt += alpha * (CONSISTENCY_S / SLOW_INNOV_S) * (reading - self.slow_tilt)
        self.slow_tilt_var += alpha * (self.slow_tilt * self.slow_tilt - self.slow_tilt_var)

    def add_balance(self, dv_n: float, dv_e: float, var_taken: float, alpha: float, judge_alpha: float) -> None:
        """One step's measurement update of the horizontal velocity (``dv_n``, ``dv_e``, m/s: after the step's fusions
        less after its prediction) and what the fusions took from its variance (``var_taken``, P_NN + P_EE's fall,
        (m/s)^2), weight ``alpha`` (the step over CONSISTENCY_S): the updates' mean over the window, and the variance
        that mean has where each update is white with what it took, ``sum alpha^2 (1 - alpha)^(2k) taken_k``: both from
        zero, so the NIS is a consistent filter's from the first step on, whatever the variance did. After the taut
        entry P's fall shrinks by an order of magnitude or more as the state settles; a mean of the variance lagged it
        (tens of seconds old, several times today's), and a state unbalanced from the entry went unflagged for a minute
        or two (docs/estimator.md, "Honest accuracy"). Where ``judge_alpha`` > 0 (the tether's rate, its weight) the
        force balance's NIS of the mean (``balance_nis``) joins the source's window as any innovation's does: one such
        NIS is a chi-square of two degrees of freedom halved, above FLAG_NIS in one draw of seven in a consistent
        filter."""
        self.balance_n += alpha * (dv_n - self.balance_n)
        self.balance_e += alpha * (dv_e - self.balance_e)
        keep = 1.0 - alpha
        self.balance_var = keep * keep * self.balance_var + alpha * alpha * max(var_taken, 0.0)
        if judge_alpha > 0.0:
            self.add(FORCE, balance_nis(self.balance_n, self.balance_e, self.balance_var), judge_alpha, FORCE_NIS_CLIP)

    def add_lean(self, tilt_rad: float, misfit_rad: float, alpha: float) -> None:
        """One taut alignment: the body's tilt from the vertical and the along innovation (the tilt less the lean of
        the pull the model puts on the balloon at the state), weight ``alpha`` (its interval / CONSISTENCY_S): their
        means over the window (``lean_misfit_wind``): the tilt's from its first sample, the misfit's from zero (a
        consistent filter's, so that the taut entry's settling does not count in full; a persistent misfit has its
        mean within a window). A NaN (an innovation not evaluated) is not taken."""
        if not (tilt_rad == tilt_rad and misfit_rad == misfit_rad):
            return
        self.lean_tilt = tilt_rad if self.lean_tilt == 0.0 else self.lean_tilt + alpha * (tilt_rad - self.lean_tilt)
        self.lean_misfit += alpha * (misfit_rad - self.lean_misfit)

    def evaluate(self) -> None:
        """The flags (set above FLAG_NIS, cleared below FLAG_NIS_CLEAR) and the accuracy factor from the windowed
        NIS (the factor follows the NIS itself, the accelerometer's as ``stated_nis`` counts it: the flags are what is
        said, not what is stated)."""
        flags = 0
        worst = 1.0
        for i, v in enumerate(self.nis):
            if v > FLAG_NIS or (self.flags >> i & 1 and v > FLAG_NIS_CLEAR):
                flags |= 1 << i
            v = stated_nis(i, v)
            if v > worst:
                worst = v
        if flags != self.flags:
            self.flag_changes += 1
        self.flags = flags
        self.inflation = worst**0.5

    def names(self) -> list[str]:
        return [name for i, name in enumerate(SOURCES) if self.flags >> i & 1]


def balance_nis(mean_n: float, mean_e: float, mean_var: float) -> float:
    """The force balance's NIS: a tethered balloon does not accelerate on average, so over the window the
    measurements take out of the velocity what the model's forces put in and the swing did not (paper Eq. 8: the
    drag of the wind, the lift, the rope). In a consistent filter the velocity's updates are white with the
    covariance they take from P (K S K^T = P- - P+), and their mean over the window has the variance ``mean_var``
    (Consistency.add_balance); a model whose forces do not balance where the state says (a wind across the lean with
    the attitude about the magnetic field's axis, which the accelerometer alone cannot tell apart) has the
    measurements pull the balloon back every step, and the mean is far from zero. Its square over that variance
    (both horizontal axes, so 1 in a consistent filter); 0 before any update."""
    if not mean_var > 0.0:
        return 0.0
    return (mean_n * mean_n + mean_e * mean_e) / mean_var


def gyro_heading_wind(speed_mps: float, gyro_bias_rad_s: float, seconds: float) -> float:
    """The wind error (m/s) of a heading the gyro alone has held for ``seconds``, no magnetometer ever fused: the
    accelerometer sees only the tilt, and the filter's wind turns with its heading, which a gyro bias of
    ``gyro_bias_rad_s`` (the design's 1-sigma before any heading: ``init_gyro_bias_dps``) walks by theta = b t; the
    wind read theta off is 2 |w| sin(theta / 2) off, at most 2 |w|. Without it a magnetometer lost before the field was
    learnt read the wind 2-6 m/s off (a heading 100 deg off in four minutes, a gyro bias learnt from the model's
    misfit) at an accuracy of 0.35 m/s."""
    theta = min(max(gyro_bias_rad_s * seconds, 0.0), math.pi)
    return 2.0 * speed_mps * math.sin(0.5 * theta)


def placement_settling_wind(seconds: float, speed_mps: float) -> float:
    """The wind error (m/s) still to settle ``seconds`` after a taut placement (``WindEkf.time_taut_us``): the
    placement's own 1-sigma, TAUT_WIND_SIGMA_MPS, and the wind's own speed ``speed_mps`` in quadrature, falling by e
    every ENTRY_SETTLE_S. The placement puts the balloon at rest on the rod's sphere, but the snap is not the rod's: on
    a real rope the balloon climbs on for seconds as the sag is taken up (its radial speed 3-7 m/s at the entry, gone
    in 3-8 s), on a stiff one it bounces; the rigid model can climb only by swinging towards the vertical, and the
    wind follows the swing, as far as to calm (docs/estimator.md, "Mode switching"): the swing's share of the error
    is the wind's own size (a steady 8 m/s blown 72 deg down: 2.5-3.4 m/s RMS off in the first 10 s from every
    direction). Every row is taken as consistent meanwhile, and P fell from the placement's 1.5 m/s to 0.8 in five
    seconds where the error was 0.7-1.5 m/s (p50-p90 over the envelope's first entries, params.ENTRY_SETTLE_S) and 4-5
    m/s in the worst. Before the placement (negative ``seconds``, or none yet): 0."""
    if not seconds >= 0.0:
        return 0.0
    return math.hypot(TAUT_WIND_SIGMA_MPS, speed_mps) * math.exp(-seconds / ENTRY_SETTLE_S)


def lean_misfit_wind(speed_mps: float, tilt_rad: float, misfit_rad: float) -> float:
    """The wind error (m/s) of a lean that the balloon's body and the taut model disagree on, persistently: the body
    is tilted by ``tilt_rad`` from the vertical (the window's mean), the pull the model puts on the balloon at the state
    leans by that less ``misfit_rad`` (the alignment's along innovation, its mean: ``Consistency.add_lean``). The lean
    is the pull, tan(lean) = D / N_b with D ~ |w|^2 (paper Eq. 5), so the wind that would lean the pull as the body
    leans is sqrt(tan(tilt) / tan(pull's lean)) of the state's: the two measures of the lean tell two winds, and the
    state may be either. A consistent filter's misfit is the rocking's mean, near zero, and the term with it; blown
    down, where tan grows without bound, a few degrees between the two are the wind's whole scale (a 14 m/s class B
    gust flight on the paper's rope: the body at 77 deg, the model's pull at 87 (the state's position at 89), the
    misfit -0.2 rad, the wind read 110 m/s where 15 blew, with 20 m/s stated). Each lean at most the pull's steepest
    (ALIGN_PULL_DOWN_MIN); bounded by a wind whose scale is unknown (its own speed, or 0.5 m/s), which is also the
    answer where either lean is not above the vertical."""
    bound = max(speed_mps, 0.5)
    lean = tilt_rad - misfit_rad
    if not (tilt_rad > 0.0 and lean > 0.0):
        return bound
    top = math.atan2(math.sqrt(1.0 - ALIGN_PULL_DOWN_MIN * ALIGN_PULL_DOWN_MIN), ALIGN_PULL_DOWN_MIN)  # 87 deg
    a, b = min(tilt_rad, top), min(lean, top)
    ratio = math.sin(a) * math.cos(b) / (math.cos(a) * math.sin(b))
    return min(speed_mps * abs(1.0 - math.sqrt(ratio)), bound)


def accel_misfit(nis: float) -> float:
    """How far the force model has stopped explaining the accelerometer, 0..1: its windowed NIS from FLAG_NIS (0)
    to twice that (1)."""
    return min(1.0, max(0.0, nis / FLAG_NIS - 1.0))


def field_tilt_reading(innov_n: float, innov_e: float, field_ned: tuple[float, float, float]) -> float:
    """The accelerometer's horizontal innovation (NED, m/s^2) read as a rotation about the magnetic field's axis,
    rad: such a rotation d tilts the body about the field's horizontal direction by d cos I (I the inclination),
    so the specific force moves by g d cos I across that direction. Its sign: an estimate turned by d from the
    truth, R_est = (I + [d b x]) R_true (b the field's unit axis), reads d; a misfit that the attitude followed reads
    the part it did not follow, with the attitude's sign (tools/accuracy_terms.py's error about the field is the
    truth's from the estimate: the first correlates negatively with it, the second positively). 0 while the field
    is unknown (NaN)."""
    bn, be, bd = field_ned
    bh2 = bn * bn + be * be
    if not bh2 > 0.0:
        return 0.0
    return (innov_e * bn - innov_n * be) * math.sqrt(bh2 + bd * bd) / (G0 * bh2)


def slow_innovation_share(misfit: float, nominal_var: float, var: float) -> float:
    """The share of the accelerometer's innovation that counts as the settled force model's slow misfit that the
    heading took: the heading's share of the gain, ``1 - misfit`` (``accel_misfit``: none once the monitor flags the
    accelerometer, whose factor then states the misfit), times the nominal noise's share of the noise fused, as an RMS
    (``nominal_var`` against ``var``, which follows the innovations: after a placement they are metres a second
    squared while the state settles and the attitude is right; the taut entry of realistic-mems read 2.5 deg about
    the field that way, and stated it for a minute, where the attitude was 0.3 deg off)."""
    return (1.0 - misfit) * math.sqrt(nominal_var / var)


def heading_misfit_variance(slow_tilt_var: float) -> float:
    """The attitude's variance about the magnetic field's axis that the accelerometer's slow misfit shows, rad^2, from
    the mean square of its slow innovation read as that rotation (Consistency.slow_tilt_var).

    The heading takes the accelerometer at its full gain until the monitor flags it (aid_sources/accel.py), so
    a force model that misfits slowly (light air swinging by half its mean at 0.05-0.2 Hz: the balloon's lag
    behind it is seconds, the rope's shape a minute) turns the attitude about the field's axis with it, where
    the magnetometer sees nothing. What the attitude did not take stays in the innovation: low-passed and read
    as a rotation about the field (``field_tilt_reading``) it follows that error (correlation 0.6-0.9 in the
    envelope's light-air multisines; an RMS of 0.00 deg in steady air), HEADING_MISFIT_RATIO times smaller. It is
    fed with the share that counts (``slow_innovation_share``)."""
    return HEADING_MISFIT_RATIO * HEADING_MISFIT_RATIO * slow_tilt_var


def field_variance(P, fn: float, fe: float, fd: float) -> float:
    """The attitude's variance about the magnetic field's axis (fn, fe, fd, any length), b^T P_att b with b the unit
    axis, rad^2; 0 while the field is unknown (zero or NaN)."""
    b = math.sqrt(fn * fn + fe * fe + fd * fd)
    if not b > 0.0:
        return 0.0
    return attitude_variance(P, fn / b, fe / b, fd / b)


def attitude_variance(P, g0: float, g1: float, g2: float) -> float:
    """g^T P_att g: the variance of what moves by g . d with the attitude's error d (over ATT_N, ATT_E, ATT_D)."""
    return float(
        g0 * (g0 * P[ATT_N, ATT_N] + 2.0 * (g1 * P[ATT_N, ATT_E] + g2 * P[ATT_N, ATT_D]))
        + g1 * (g1 * P[ATT_E, ATT_E] + 2.0 * g2 * P[ATT_E, ATT_D])
        + g2 * g2 * P[ATT_D, ATT_D]
    )


def lean_jacobian(
    cn: float, ce: float, zn: float, ze: float, zd: float, cd: float = 0.0
) -> tuple[float, float, float]:  # fmt: skip
    """c . d z / d att = (z x c) over ATT_N, ATT_E, ATT_D: how the body's down axis z (along the rope) moves along a
    component c = (cn, ce, cd) (horizontal where cd = 0) with the attitude's error d (d z / d att = -[z x])."""
    return ze * cd - ce * zd, cn * zd - zn * cd, ce * zn - cn * ze


def correlated_weight(nis: float, dt_s: float, corr_s: float) -> float:
    """The share of a fusion's information that counts where the source's misfit is correlated over ``corr_s``:
    ``dt_s / (nis corr_s)``, ``dt_s`` the source's interval and ``nis`` its windowed NIS against (about) the noise it
    was fused with. Its innovations, ``nis`` times that noise, are a model error worth dt / corr_s independent
    samples per sample: a consistent filter (nis = 1) counts dt / corr_s of what it fused, one whose innovations are
    far smaller than its noise (nis <= dt / corr_s) all of it, never more."""
    return 1.0 if nis * corr_s <= dt_s else dt_s / (nis * corr_s)


def field_attitude_extra(
    extra: float, v_pred: float, v_accel: float, v_aids: float, v_end: float, w_accel: float, w_align: float
) -> float:  # fmt: skip
    """One step of the attitude's variance about the magnetic field's axis that P does not hold, rad^2 (>= 0).

    About that axis the magnetometer sees nothing and only the accelerometer (its tilt, cos I of it, and on the
    taut tether the pull's azimuth) and the alignment (through the position, and a share directly:
    tether.field_axis_row) hold the attitude. Both fuse every
    sample as if their misfit were white, but what they misfit is the rope's waves and the drag's lag behind the
    wind, correlated over seconds: P about that axis shrinks as if it had a hundred times the data, and the wind across
    the lean follows the attitude's slow error (docs/estimator.md, "Honest accuracy"). So beside P the same
    step is taken again, each fusion's information 1/v_after - 1/v_before counted with its weight
    (``correlated_weight``: the accelerometer's, the alignment's (with the radius's rows, fused with it); the
    barometer's, the winch's and the magnetometer's fully) from the prediction's variance ``v_pred`` (P's after the
    step's prediction, plus ``extra``) through ``v_accel`` (after the accelerometer), ``v_aids`` (after the
    barometer, the winch, the magnetometer) to ``v_end`` (after the tether). Simplified: the prediction adds P's own
    growth only (a gyro bias error would add to it), and what reaches the attitude through its correlations counts
    as if the field's axis were seen directly."""
    s = v_pred + extra
    for v0, v1, w in ((v_pred, v_accel, w_accel), (v_accel, v_aids, 1.0), (v_aids, v_end, w_align)):
        inv = 1.0 / s + w * (1.0 / v1 - 1.0 / v0) if v0 > 0.0 and v1 > 0.0 and s > 0.0 else 0.0
        if inv > 0.0:
            s = 1.0 / inv
    return max(0.0, s - v_end) if math.isfinite(s) else 0.0


def lean_tilt_variance(
    cross_var: float, extra: float, field_ned: tuple[float, float, float], zn: float, ze: float, zd: float
) -> float:  # fmt: skip
    """The tilt variance across the lean that ``lean_bias_wind`` takes (rad^2: a tilt d turns the lean's azimuth by
    d / tan(lean)), from the variance of the body's down axis z = (zn, ze, zd) displaced across the lean,
    ``cross_var`` (P's, tether.lean_variance), and ``extra``, the attitude's variance about the magnetic field's axis
    that P does not hold (``field_attitude_extra``). A rotation about the field's axis displaces z across the lean by
    sin(lean) of the azimuth's turn and along it by cos(lean) of the lean's; a quarter of the latter's variance
    counts (the square law: the speed moves by half the lean's relative change, at the small leans where the
    barometer does not hold the lean). A displacement across turns the azimuth by itself over sin(lean), so both are
    taken over cos^2(lean), the lean at most acos(``LEAN_COS_MIN``). The field unknown (NaN): P's alone."""
    lean = math.sqrt(zn * zn + ze * ze)
    if not lean > 0.0:
        return cross_var
    cn, ce = ze / lean, -zn / lean  # across the lean, horizontal
    bn, be, bd = field_ned
    b = math.sqrt(bn * bn + be * be + bd * bd)
    if b > 0.0:
        g0, g1, g2 = lean_jacobian(cn, ce, zn, ze, zd)
        across = (g0 * bn + g1 * be + g2 * bd) / b
        along = zd * (cn * bn + ce * be) / b
        cross_var += extra * (across * across + 0.25 * along * along)
    c = max(zd, LEAN_COS_MIN)
    return cross_var / (c * c)


def systematic_variance(
    speed_mps: float, drag_scale: float, drag_scale_var: float, lean_wind_mps: float = 0.0
) -> float:  # fmt: skip
    """Variance of the horizontal wind from what the filter's P does not hold, (m/s)^2: the drag
    scale's uncertainty (F ~ k |w|^2: dw / w = dk / 2k) and the tilt's systematic error
    ``lean_wind_mps`` (``lean_bias_wind``), which no averaging removes."""
    k = max(drag_scale, 1e-3)
    rel_k = 0.5 * (drag_scale_var**0.5) / k
    return speed_mps * speed_mps * rel_k * rel_k + lean_wind_mps * lean_wind_mps


def lean_bias_rad(walk_mps2_rt_s: float, seconds: float) -> float:
    """The tilt's systematic error, rad: LEAN_BIAS_RAD (the accelerometer's turn-on bias and the learnt field's
    direction) and what the accelerometer's horizontal bias has wandered since the boot, read as a tilt (b / g): the
    random walk the design declares, ``walk_mps2_rt_s`` (m/s^2 per sqrt(s)), ``sqrt(seconds)`` of it. No state holds
    the horizontal bias, so no measurement bounds it: a MEMS part's 0.001 walks 0.025 m/s^2 in ten minutes (0.25 deg
    with the turn-on term's 0.2), 0.06 in an hour (0.40 deg), 0.12 in four (0.73 deg). Bounded at a guessed range
    (0.05 m/s^2, a temperature drift's), a four-hour field-all read the direction 10-17 deg off at error/accuracy 3.5
    where the walk had gone 0.15-0.22 m/s^2 (docs/estimator.md, "The long day")."""
    return bias_tilt_rad(walk_mps2_rt_s * walk_mps2_rt_s * max(seconds, 0.0))


def bias_tilt_rad(hbias_var: float) -> float:
    """The tilt's systematic error, rad, of a horizontal bias of variance ``hbias_var`` ((m/s^2)^2) read as a tilt
    (b / g), beside the turn-on term LEAN_BIAS_RAD: the walk since the boot across the field's horizontal direction
    (lean_bias_rad), and the error of the bias followed along it (accel.horizontal_bias_variance), where the
    magnetometer tells a tilt from a bias."""
    return math.sqrt(LEAN_BIAS_RAD * LEAN_BIAS_RAD + max(hbias_var, 0.0) / (G0 * G0))


def lean_bias_wind(
    wind_n: float, wind_e: float, lift_n: float, drag_per_speed2: float, lean_bias_rad: float,
    field_ned: tuple[float, float, float], cross_tilt_var: float = 0.0, held_bias_rad: float | None = None,
    mount_rad: float = 0.0,
) -> float:  # fmt: skip
    """The wind error (m/s, horizontal) of a tilt error ``lean_bias_rad`` on the taut balloon: its lean is the
    pull, tan(lean) = D / N_b with D = c |w|^2, so a tilt d across the lean turns its azimuth by d / tan(lean),
    dw = N_b d / (c |w|) across the wind, and a tilt along it half that along (the square law). Large in calm
    air, where the lean is a degree; bounded by a wind whose direction is unknown (its own speed, or 0.5 m/s).

    Across the lean the geometry of the magnetic field adds to it. The magnetometer holds every rotation but
    the one about the field's axis (inclination I), which only the accelerometer holds, through that
    rotation's tilt about the field's horizontal direction (cos I of it): a tilt error d there is a rotation
    d / cos I about the field, mostly a heading error. It turns the balloon's body axis, which lies along the
    rope, and with it the lean's azimuth: by d (tan I + cos a / tan(lean)), a the lean's azimuth from
    magnetic north; the tilt about the horizontal across the field (which the magnetometer holds to the same
    d, the field having been learnt against the accelerometer) turns it by d sin a / tan(lean). Across the
    wind then dw = N_b d F / (c |w|), F^2 = 1 + t^2 + 2 t cos a, t = tan I tan(lean): for a 66 deg field and
    a 30 deg lean F is 2.3 blown towards magnetic north (the rope from the balloon points away from the
    field) and 0.3 blown south (the rope along the field).

    ``cross_tilt_var`` (rad^2): the filter's own attitude variance across the lean as a tilt (``lean_tilt_variance``:
    P's and what P does not hold about the field's axis), which turns the azimuth the same way. The alignment
    takes it as white noise, and the position and the wind average it away; but the attitude's error is slow (about
    the field's axis only the accelerometer holds it), so its share of the wind is stated here.

    ``held_bias_rad``: the tilt about the horizontal across the field has its own systematic error where the horizontal
    bias is followed along the field (``bias_tilt_rad``; None: ``lean_bias_rad``). F^2 is (t + cos a)^2 from the
    tilt about the field's horizontal direction and sin^2 a from the one across it, so each takes its own: the
    quarter along the lean and an unknown field take ``lean_bias_rad``, the larger.

    ``mount_rad``: the IMU's mounting against the tether's axis, 1-sigma per axis ([sensors] imu_alignment_deg). The
    body's axis the alignment reads is then that far off the rope, across the lean and along it, with no attitude
    error behind it (the field's geometry plays no part): its whole across, a quarter along."""
    speed = math.sqrt(wind_n * wind_n + wind_e * wind_e)
    if not (drag_per_speed2 > 0.0 and lift_n > 0.0):
        return 0.0
    held = lean_bias_rad if held_bias_rad is None else held_bias_rad
    about, across = 1.0, 0.0  # (t + cos a)^2 and sin^2 a; the field unknown: all of it the unfollowed tilt's
    bn, be, bd = field_ned
    bh = math.sqrt(bn * bn + be * be)
    if bh > 0.0 and speed > 0.0:  # False while the field is unknown (NaN)
        t = bd / bh * drag_per_speed2 * speed * speed / lift_n
        cos_a = (wind_n * bn + wind_e * be) / (speed * bh)
        about, across = (t + cos_a) * (t + cos_a), max(0.0, 1.0 - cos_a * cos_a)
    d2 = lean_bias_rad * lean_bias_rad
    v2 = d2 * (about + 0.25) + held * held * across + cross_tilt_var + 1.25 * mount_rad * mount_rad
    v = lift_n * math.sqrt(v2) / (drag_per_speed2 * max(speed, 1e-3))
    return min(v, max(speed, 0.5))
