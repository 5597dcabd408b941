"""What P does not hold about the magnetic field's axis: counted (consistency.field_attitude_extra: a fusion whose
misfit is correlated counts as that much less data, and nothing else changes) and seen (the accelerometer's slow
innovation read as a rotation about the field, consistency.heading_misfit_variance)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from firmware_py.estimator.consistency import (
    CONSISTENCY_S,
    FLAG_NIS,
    HEADING_MISFIT_RATIO,
    SLOW_INNOV_S,
    Consistency,
    accel_misfit,
    correlated_weight,
    field_attitude_extra,
    field_tilt_reading,
    field_variance,
    heading_misfit_variance,
    lean_bias_rad,
    lean_jacobian,
    lean_misfit_wind,
    lean_tilt_variance,
    slow_innovation_share,
)
from firmware_py.estimator.params import ALIGN_PULL_DOWN_MIN, LEAN_BIAS_RAD
from firmware_py.estimator.state import ATT_D, ATT_N

DT = 0.01


def kalman(p: float, q: float, r: float) -> tuple[float, float]:
    """A scalar random walk observed in white noise: the variance after the prediction and after the fusion."""
    pred = p + q
    return pred, 1.0 / (1.0 / pred + 1.0 / r)


@pytest.mark.parametrize("w", [1.0, 0.3, 0.01])
def test_a_discounted_fusion_is_the_filter_with_that_much_less_data(w):
    """The main filter fuses with noise r as if white; beside it the same steps with the fusion's information
    weighted w are the filter with noise r / w, exactly, and its steady state sqrt(1 / w) times the main's
    variance for a slow walk (the correlated error worth w independent samples per sample)."""
    q, r = 1e-9, 1e-4
    p = honest = 1e-3
    extra = 0.0
    for _ in range(20000):
        v_pred, v_fused = kalman(p, q, r)
        extra = field_attitude_extra(extra, v_pred, v_fused, v_fused, v_fused, w, 1.0)
        p = v_fused
        honest = kalman(honest, q, r / w)[1]
    assert p + extra == pytest.approx(honest, rel=1e-9)
    assert (p + extra) / p == pytest.approx(w**-0.5, rel=0.02)
    assert (extra == pytest.approx(0.0, abs=1e-18)) == (w == 1.0)


def test_the_other_slots_are_weighted_apart():
    """The three slots are the accelerometer (its weight), the barometer, winch and magnetometer (all of it), the
    tether (its weight): information in a fully weighted slot adds no extra; a step with nothing fused keeps what
    there was; a fusion that (with a clipped gain) grows the variance grows it beside P too (by less: the weight),
    and a variance that is not there (NaN, 0, negative) skips its slot."""
    assert field_attitude_extra(0.0, 2e-5, 2e-5, 1e-5, 1e-5, 0.01, 0.01) == pytest.approx(0.0, abs=1e-18)
    assert field_attitude_extra(0.0, 2e-5, 2e-5, 2e-5, 1e-5, 1.0, 0.01) > 0.0
    assert field_attitude_extra(3e-6, 2e-5, 2e-5, 2e-5, 2e-5, 0.01, 0.01) == pytest.approx(3e-6)
    grown = field_attitude_extra(3e-6, 2e-5, 2.1e-5, 2.1e-5, 2.1e-5, 0.01, 0.01)
    assert 0.0 < grown < 3e-6
    for bad in (math.nan, 0.0, -1e-5):  # the two slots it bounds are skipped, the third adds nothing
        assert field_attitude_extra(3e-6, 2e-5, bad, 2e-5, 2e-5, 0.01, 0.01) == pytest.approx(3e-6)


def test_the_weight_is_the_share_of_independent_samples():
    """A consistent source (NIS 1) whose misfit is correlated over tau counts dt / tau of what it fused, less the
    larger its innovations; only innovations far below the noise fused (NIS <= dt / tau) count fully."""
    assert correlated_weight(0.0, DT, 1.0) == 1.0
    assert correlated_weight(DT, DT, 1.0) == 1.0
    assert correlated_weight(1.0, DT, 1.0) == pytest.approx(DT)
    ws = [correlated_weight(n, DT, 1.0) for n in (0.001, 0.01, 0.1, 1.0, 5.0, 25.0)]
    assert all(a >= b for a, b in zip(ws, ws[1:])) and 0.0 < ws[-1] < ws[0] == 1.0


def test_the_field_variance_is_the_covariance_along_its_axis():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(19, 19))
    P = a @ a.T
    b = rng.normal(size=3)
    b /= np.linalg.norm(b)
    att = slice(ATT_N, ATT_D + 1)
    assert field_variance(P, *b) == pytest.approx(float(b @ P[att, att] @ b), rel=1e-12)
    assert field_variance(P, *(0.45 * b)) == pytest.approx(field_variance(P, *b), rel=1e-12)  # the axis, any length
    assert field_variance(P, 0.0, 0.0, 0.0) == 0.0 and field_variance(P, math.nan, 0.0, 0.0) == 0.0  # unknown


def rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: v turned by ``angle`` about the unit ``axis``."""
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) + axis * (axis @ v) * (1.0 - math.cos(angle))


@pytest.mark.parametrize("lean_deg", [2.0, 30.0, 70.0])
def test_what_p_does_not_hold_turns_the_lean_as_a_rotation_about_the_field_does(lean_deg):
    """An attitude error of d about the field's axis b turns the body's down axis z (along the rope) by the rotation:
    its azimuth by dpsi, its lean by dlambda. lean_tilt_variance with an extra of d^2 is the tilt whose azimuth
    turn in lean_bias_wind (d / tan(lean)) is that one, tan^2(lean) dpsi^2, with a quarter of dlambda^2 (the square
    law); P's displacement across the lean counts over cos^2(lean); an unknown field adds nothing."""
    rng = np.random.default_rng(int(lean_deg))
    lean = math.radians(lean_deg)
    d = 1e-6
    for _ in range(20):
        b = rng.normal(size=3)
        b /= np.linalg.norm(b)
        az = rng.uniform(0.0, 2.0 * math.pi)
        z = np.array([math.sin(lean) * math.cos(az), math.sin(lean) * math.sin(az), math.cos(lean)])
        z2 = rotate(z, b, d)
        dpsi = (math.atan2(z2[1], z2[0]) - az + math.pi) % (2.0 * math.pi) - math.pi
        dlam = math.atan2(math.hypot(z2[0], z2[1]), z2[2]) - lean
        want = math.tan(lean) ** 2 * dpsi**2 + 0.25 * dlam**2
        got = lean_tilt_variance(0.0, d * d, tuple(3.0 * b), *z)
        assert got == pytest.approx(want, rel=1e-4, abs=1e-8 * d * d)
        assert lean_tilt_variance(2e-6, 0.0, tuple(b), *z) == pytest.approx(2e-6 / math.cos(lean) ** 2)
        assert lean_tilt_variance(2e-6, d * d, (math.nan,) * 3, *z) == pytest.approx(2e-6 / math.cos(lean) ** 2)


@pytest.mark.parametrize("incl_deg", [-70.0, 10.0, 45.0, 66.0, 85.0])
def test_the_accelerometers_innovation_reads_a_rotation_about_the_field(incl_deg):
    """At rest the accelerometer reads f = (0, 0, -g) (NED). An estimate turned by d about the field's axis b from the
    truth (R_est = (I + [d b x]) R_true) predicts f turned the other way: the innovation, rotated to NED with the
    estimate, is d (b x f), horizontal, across the field's horizontal direction. field_tilt_reading gives back d,
    whatever the field's strength, declination and inclination; an innovation along the field's horizontal
    direction reads nothing, and so does any innovation while the field is unknown."""
    rng = np.random.default_rng(int(incl_deg) + 100)
    incl = math.radians(incl_deg)
    f = np.array([0.0, 0.0, -G0])
    for _ in range(10):
        dec = rng.uniform(0.0, 2.0 * math.pi)
        strength = rng.uniform(0.2, 0.6)
        b = strength * np.array([math.cos(incl) * math.cos(dec), math.cos(incl) * math.sin(dec), math.sin(incl)])
        d = rng.uniform(-0.002, 0.002)
        axis = b / np.linalg.norm(b)
        r_est = np.column_stack([rotate(e, axis, d) for e in np.eye(3)])  # the truth's frame is NED's here
        innov = r_est @ (f - r_est.T @ f)  # measured minus predicted, turned to NED with the estimate
        assert field_tilt_reading(innov[0], innov[1], tuple(b)) == pytest.approx(d, rel=2e-3)
        along = b[:2] / np.linalg.norm(b[:2])
        assert field_tilt_reading(0.3 * along[0], 0.3 * along[1], tuple(b)) == pytest.approx(0.0, abs=1e-15)
        assert field_tilt_reading(innov[0], innov[1], (math.nan,) * 3) == 0.0


def test_the_slow_innovation_keeps_a_persistent_misfit_and_drops_the_waves():
    """A reading held is the slow tilt after SLOW_INNOV_S to 1 - 1/e of it (a first-order low-pass of that time
    constant), and after two minutes it and its mean square are the reading's; one that changes sign every step (the
    rope's waves, a sample's noise) averages out of both."""
    rate = 100.0
    alpha = 1.0 / (CONSISTENCY_S * rate)
    held, waves = Consistency(), Consistency()
    for i in range(int(120.0 * rate)):
        held.add_slow_tilt(0.01, alpha)
        waves.add_slow_tilt(0.01 if i % 2 else -0.01, alpha)
        if i + 1 == int(SLOW_INNOV_S * rate):
            assert held.slow_tilt == pytest.approx(0.01 * (1.0 - math.exp(-1.0)), rel=2e-3)
    assert held.slow_tilt == pytest.approx(0.01, rel=1e-3)
    assert held.slow_tilt_var == pytest.approx(1e-4, rel=1e-2)
    assert waves.slow_tilt_var < 1e-4 * 1e-3
    held.reset()
    assert held.slow_tilt == held.slow_tilt_var == 0.0


def test_what_counts_of_the_innovation():
    """The innovation counts in full from a consistent accelerometer fused at its nominal noise; with the heading's
    share of the gain as the monitor flags it (half at 1.5 FLAG_NIS, none at twice it); and as an RMS with the
    nominal noise's share of the noise fused (after a placement the noise follows innovations 50 times the nominal
    RMS: a fiftieth counts). The variance seen is HEADING_MISFIT_RATIO^2 times the slow innovation's mean square."""
    nominal = 0.01
    assert slow_innovation_share(accel_misfit(0.3), nominal, nominal) == 1.0
    assert slow_innovation_share(accel_misfit(FLAG_NIS), nominal, nominal) == 1.0
    assert slow_innovation_share(accel_misfit(1.5 * FLAG_NIS), nominal, nominal) == pytest.approx(0.5)
    assert slow_innovation_share(accel_misfit(2.0 * FLAG_NIS), nominal, nominal) == 0.0
    assert slow_innovation_share(accel_misfit(25.0), nominal, nominal) == 0.0
    assert slow_innovation_share(0.0, nominal, 2500.0 * nominal) == pytest.approx(0.02)
    assert heading_misfit_variance(1e-4) == pytest.approx(HEADING_MISFIT_RATIO**2 * 1e-4)
    assert heading_misfit_variance(0.0) == 0.0


def test_the_tilts_systematic_error_follows_the_declared_walk_of_the_horizontal_bias():
    """No state holds the accelerometer's horizontal bias, so what it has walked since the boot is the random walk
    the design declares, unbounded: its variance grows by walk^2 per second, read as a tilt b / g beside the turn-on
    term. A bound at a guessed range (0.05 m/s^2) had a four-hour field-all 10-17 deg off at error/accuracy 3.5 where
    the walk had gone 0.15-0.22 m/s^2 (docs/estimator.md, "The long day")."""
    walk = 0.001
    assert lean_bias_rad(0.0, 14400.0) == pytest.approx(LEAN_BIAS_RAD)
    assert lean_bias_rad(walk, -5.0) == pytest.approx(LEAN_BIAS_RAD)  # before the boot's clock: the turn-on term
    for hours in (1.0, 4.0, 8.0):
        t = 3600.0 * hours
        added = lean_bias_rad(walk, t) ** 2 - LEAN_BIAS_RAD**2
        assert added == pytest.approx(walk * walk * t / (G0 * G0), rel=1e-12)
    # four hours of the default walk: 0.12 m/s^2, a tilt of 0.7 deg, where the guessed bound held 0.3
    assert math.degrees(lean_bias_rad(walk, 4 * 3600.0)) == pytest.approx(0.73, abs=0.01)


def test_the_held_tilt_takes_the_share_of_the_lean_across_the_field():
    """F^2 = (t + cos a)^2 + sin^2 a: the tilt about the field's horizontal direction (unfollowed, lean_bias_rad) and
    the one across it (the followed bias's, bias_tilt_rad). The same error on both is the whole formula; blown
    along the field's direction the held one does not count, blown across it it does."""
    from firmware_py.estimator.consistency import bias_tilt_rad, lean_bias_wind

    field = (0.2, 0.0, 0.45)
    lift_n, c, d = 32.0, 0.58, 0.007
    for wn, we in ((3.0, 0.0), (0.0, 3.0), (-2.0, 2.0)):  # one error on both: 1 + t^2 + 2 t cos a whole
        speed = math.hypot(wn, we)
        t, cos_a = 0.45 / 0.2 * c * speed * speed / lift_n, wn / speed
        whole = lift_n * d * math.sqrt(1.0 + t * t + 2.0 * t * cos_a + 0.25) / (c * speed)
        assert lean_bias_wind(wn, we, lift_n, c, d, field) == pytest.approx(whole, rel=1e-12)
        assert lean_bias_wind(wn, we, lift_n, c, d, field, 0.0, d) == pytest.approx(whole, rel=1e-12)
    held = bias_tilt_rad(0.0)
    assert held == pytest.approx(LEAN_BIAS_RAD)
    assert lean_bias_wind(3.0, 0.0, lift_n, c, d, field, 0.0, held) == pytest.approx(
        lean_bias_wind(3.0, 0.0, lift_n, c, d, field), rel=1e-12)  # fmt: skip
    across = lean_bias_wind(0.0, 3.0, lift_n, c, d, field, 0.0, held)
    assert across < 0.8 * lean_bias_wind(0.0, 3.0, lift_n, c, d, field)
    t = 0.45 / 0.2 * c * 9.0 / lift_n  # tan I tan(lean), a = 90 deg
    want = lift_n * math.sqrt(d * d * (t * t + 0.25) + held * held) / (c * 3.0)
    assert across == pytest.approx(want, rel=1e-12)
    assert bias_tilt_rad(0.02**2) == pytest.approx(math.hypot(LEAN_BIAS_RAD, 0.02 / G0), rel=1e-12)


def test_the_force_balance_is_the_mean_update_against_a_consistent_filters():
    """White velocity updates with the covariance they take from P read the force balance's windowed NIS near 1, and
    above the flag about one time in twenty (5.4 % here; one value alone is above it one time in seven: the window
    averages them); the same updates with a persistent pull of three sigma of the mean on one axis read
    (9 + 2) / 2 = 5.5 and stay flagged; none before any update."""
    from firmware_py.estimator.consistency import FLAG_NIS, FORCE, Consistency, balance_nis

    rng = np.random.default_rng(3)
    alpha, every = 1.0 / 2000.0, 5  # a step of a 20 s window at 100 Hz; the tether's rate, a fifth of the steps
    sigma = 0.01  # each update's 1-sigma per axis, m/s
    taken = 2.0 * sigma * sigma  # what each step takes from P_NN + P_EE
    assert balance_nis(0.0, 0.0, 0.0) == 0.0
    pull3 = sigma * math.sqrt(alpha / (2.0 - alpha)) * 3.0  # three sigma of the window's mean on one axis
    for pull, lo, hi in ((0.0, 0.8, 1.2), (pull3, 4.5, 6.5)):
        mon = Consistency()
        nis = []
        for k in range(200_000):
            dv = rng.normal(0.0, sigma, 2)
            mon.add_balance(dv[0] + pull, dv[1], taken, alpha, 0.0 if k % every else every * alpha)
            if k % every == 0 and k >= 40_000:
                nis.append(mon.nis[FORCE])
        assert lo <= float(np.mean(nis)) <= hi, (pull, np.mean(nis))
        share = float(np.mean(np.array(nis) > FLAG_NIS))
        assert (share <= 0.08) if pull == 0.0 else (share >= 0.95), (pull, share)


def test_the_force_balance_is_a_consistent_filters_while_the_variance_falls():
    """The mean update's variance is the exact one of white updates, sum alpha^2 (1 - alpha)^(2k) taken_k, from zero as
    the mean is, so the NIS of consistent updates is 1 on average from the first step on and whatever the variance does.
    After the taut entry P's fall shrinks by an order of magnitude or more as the state settles: here a hundredfold over
    the 30 s flown, 400 flights, the NIS at their end (the closed form of the variance checked). A mean of the variance
    (what the monitor followed before) reads the same updates at a quarter of 1 there (0.26), and a state unbalanced
    since the entry went unflagged for a minute and a half (`reduced-multisine` from the north and the south)."""
    from firmware_py.estimator.consistency import Consistency, balance_nis

    rng = np.random.default_rng(5)
    alpha, steps, runs = 1.0 / 2000.0, 3000, 400
    taken = 2.0e-4 * 10.0 ** (-2.0 * np.arange(steps) / steps)  # P_NN + P_EE's fall each step: hundredfold
    exact = float(np.sum(alpha**2 * (1.0 - alpha) ** (2 * np.arange(steps)[::-1]) * taken))
    nis, before = [], []
    for _ in range(runs):
        mon, mean_var = Consistency(), 0.0
        dv = rng.normal(0.0, 1.0, (steps, 2)) * np.sqrt(0.5 * taken)[:, None]
        for k in range(steps):
            mon.add_balance(float(dv[k, 0]), float(dv[k, 1]), float(taken[k]), alpha, 0.0)
            mean_var = taken[k] if k == 0 else mean_var + alpha * (taken[k] - mean_var)
        nis.append(balance_nis(mon.balance_n, mon.balance_e, mon.balance_var))
        before.append(balance_nis(mon.balance_n, mon.balance_e, mean_var * alpha / (2.0 - alpha)))
    assert mon.balance_var == pytest.approx(exact, rel=1e-9)
    assert 0.8 <= float(np.mean(nis)) <= 1.2, np.mean(nis)  # 1.12: 400 draws of a chi-square of 2 dof halved
    assert float(np.mean(before)) < 0.5, np.mean(before)


@pytest.mark.parametrize("lean_deg", [5.0, 45.0, 80.0, 89.0])
def test_lean_jacobian_is_the_turn_of_the_body_axis_along_any_component(lean_deg):
    """c . d z / d att for the body's down axis z turned by a small rotation vector d in NED (z -> z + d x z), against
    the finite difference, for a horizontal component and for the lean's tangent (aid_sources/tether.py's along
    component): the tangent reads the lean's own change, 1 per radian, at any lean (the horizontal projection only
    cos(lean) of it)."""
    th, az = math.radians(lean_deg), math.radians(30.0)
    a = np.array([math.cos(az), math.sin(az)])  # the lean's azimuth, downwind
    z = np.array([-math.sin(th) * a[0], -math.sin(th) * a[1], math.cos(th)])  # to the anchor: upwind and down
    tangent = np.array([a[0] * z[2], a[1] * z[2], math.sin(th)])
    for c in (np.array([a[0], a[1], 0.0]), np.array([-a[1], a[0], 0.0]), tangent):
        g = np.array(lean_jacobian(c[0], c[1], z[0], z[1], z[2], c[2]))
        for d in np.eye(3) * 1e-6:
            assert float(g @ d) == pytest.approx(float(c @ np.cross(d, z)), rel=1e-9, abs=1e-15)
    # the lean grown by e: z turns about the horizontal axis across the lean; along the tangent it reads -e
    e = 1e-6
    d = e * np.array([a[1], -a[0], 0.0])  # z x a's direction: the turn that leans z further
    moved = np.array(lean_jacobian(*tangent[:2], *z, tangent[2])) @ d
    assert abs(moved) == pytest.approx(e, rel=1e-6)
    horizontal = np.array(lean_jacobian(a[0], a[1], *z)) @ d
    assert abs(horizontal) == pytest.approx(e * math.cos(th), rel=1e-6, abs=1e-15)


@pytest.mark.parametrize("true_mps, state_mps", [(3.0, 3.3), (6.0, 4.0), (15.0, 110.0), (1.0, 1.2), (6.0, 2.0)])
def test_the_lean_misfit_states_the_wind_the_bodys_lean_would_tell(true_mps, state_mps):
    """The lean is the pull, tan(lean) = c |w|^2 (paper Eq. 5): a state whose wind leans the model's pull by phi while
    the body leans by theta is off by the wind that leans it by theta; the stated term is that difference (bounded by
    the state's speed), and nil where the two agree."""
    c = 0.02  # 1/(m/s)^2: a 1 m balloon, 45 deg in 7 m/s
    theta, phi = math.atan(c * true_mps**2), math.atan(c * state_mps**2)
    top = math.acos(ALIGN_PULL_DOWN_MIN)
    want = state_mps * abs(1.0 - math.sqrt(math.tan(min(theta, top)) / math.tan(min(phi, top))))
    got = lean_misfit_wind(state_mps, theta, theta - phi)
    assert got == pytest.approx(min(want, state_mps), rel=1e-9)
    if max(theta, phi) < top:  # below the steepest pull each lean is its own wind's: the term is |w_body - w_state|
        assert got == pytest.approx(min(abs(true_mps - state_mps), state_mps), rel=1e-9)
    assert lean_misfit_wind(state_mps, theta, 0.0) == pytest.approx(0.0, abs=1e-12)


def test_the_lean_misfit_is_the_lean_sensitivity_when_small_and_bounded_when_the_sense_is_lost():
    w, theta, m = 4.0, math.radians(30.0), 1e-4
    assert lean_misfit_wind(w, theta, m) == pytest.approx(w * m / math.sin(2.0 * theta), rel=1e-3)  # d tan / tan
    assert lean_misfit_wind(w, theta, -m) == pytest.approx(w * m / math.sin(2.0 * theta), rel=1e-3)
    # the pull would lean the other way, or the body is upright: nothing says the wind's scale
    assert lean_misfit_wind(w, math.radians(1.0), math.radians(2.0)) == w
    assert lean_misfit_wind(0.2, 0.0, 0.0) == 0.5


def test_the_lean_means_start_from_the_first_tilt_and_a_consistent_misfit():
    """The tilt's mean starts at its first sample, the misfit's at zero (a consistent filter's): a persistent misfit
    reaches 1 - 1/e of itself after one window; a NaN is not taken; the reset forgets both."""
    c, alpha, n = Consistency(), 0.01, 100  # 100 samples: one window
    c.add_lean(0.5, 0.1, alpha)
    assert c.lean_tilt == 0.5 and c.lean_misfit == pytest.approx(0.1 * alpha)
    for _ in range(n - 1):
        c.add_lean(0.5, 0.1, alpha)
    assert c.lean_tilt == pytest.approx(0.5) and c.lean_misfit == pytest.approx(0.1 * (1.0 - (1.0 - alpha) ** n))
    before = (c.lean_tilt, c.lean_misfit)
    c.add_lean(math.nan, 0.1, alpha)
    c.add_lean(0.5, math.nan, alpha)
    assert (c.lean_tilt, c.lean_misfit) == before
    c.reset()
    assert c.lean_tilt == 0.0 and c.lean_misfit == 0.0


def test_the_wind_of_a_heading_the_gyro_alone_has_held():
    """2 |w| sin(theta / 2), theta = b t: the chord of the wind's turn; small, |w| b t; at most 2 |w| (turned round)."""
    from firmware_py.estimator.consistency import gyro_heading_wind

    b = math.radians(0.5)
    assert math.isclose(gyro_heading_wind(3.0, b, 10.0), 3.0 * b * 10.0, rel_tol=1e-3)
    assert math.isclose(gyro_heading_wind(3.0, b, 120.0), 2 * 3.0 * math.sin(math.radians(30.0)), rel_tol=1e-12)
    assert gyro_heading_wind(3.0, b, 1e6) == 6.0 and gyro_heading_wind(3.0, b, 0.0) == 0.0


def test_what_a_taut_placement_has_still_to_settle():
    """The placement's own 1-sigma and the wind's speed in quadrature at the placement, falling by e every
    ENTRY_SETTLE_S; nothing before one (or with no time)."""
    from firmware_py.estimator.consistency import placement_settling_wind
    from firmware_py.estimator.params import ENTRY_SETTLE_S, TAUT_WIND_SIGMA_MPS

    assert placement_settling_wind(0.0, 0.0) == TAUT_WIND_SIGMA_MPS
    assert math.isclose(placement_settling_wind(0.0, 8.0), math.hypot(TAUT_WIND_SIGMA_MPS, 8.0), rel_tol=1e-12)
    assert math.isclose(placement_settling_wind(ENTRY_SETTLE_S, 2.0), math.hypot(TAUT_WIND_SIGMA_MPS, 2.0) / math.e,
                        rel_tol=1e-12)  # fmt: skip
    assert placement_settling_wind(10.0 * ENTRY_SETTLE_S, 0.0) < 1e-4 * TAUT_WIND_SIGMA_MPS
    assert placement_settling_wind(-1.0, 3.0) == 0.0 and placement_settling_wind(math.nan, 3.0) == 0.0


def test_a_flag_is_set_above_flag_nis_and_cleared_only_below_flag_nis_clear():
    """Hysteresis: a windowed NIS that hovers between FLAG_NIS_CLEAR and FLAG_NIS keeps what the source was (flagged
    or not), so the flag and its STATUSTEXT do not flip with every wobble; the accuracy factor follows the NIS (the
    accelerometer's as (1 + NIS) / 2: test_a_filter_whose_noise_is_larger_than_it_assumes_errs_by_half_the_excess)."""
    from firmware_py.estimator.consistency import ACCEL, BARO, FLAG_NIS, FLAG_NIS_CLEAR, Consistency

    mid = 0.5 * (FLAG_NIS + FLAG_NIS_CLEAR)
    mon = Consistency()
    seen = []
    for accel, baro in ((mid, mid), (FLAG_NIS * 1.1, mid), (mid, mid), (FLAG_NIS_CLEAR * 0.9, mid)):
        mon.nis[ACCEL], mon.nis[BARO] = accel, baro
        mon.evaluate()
        seen.append((mon.flags >> ACCEL & 1, mon.flags >> BARO & 1))
        assert mon.inflation == pytest.approx(max(0.5 * (1.0 + accel), baro) ** 0.5)
    assert seen == [(0, 0), (1, 0), (1, 0), (0, 0)]
    assert mon.flag_changes == 2


def test_a_filter_whose_noise_is_larger_than_it_assumes_errs_by_half_the_excess():
    """Why the accelerometer's windowed NIS enters the accuracy factor as (1 + NIS) / 2: a random walk seen in white
    noise NIS times larger than the filter assumes (its own process noise as assumed, its gain the slow one of q << R)
    has an actual error variance (1 + NIS) / 2 times the filter's P in the steady state, not NIS times (the gain
    averages the excess noise over the same steps as the walk). The exact steady state of the scalar Riccati equation
    and of the actual error's recursion, against that law."""
    q, r = 1e-4, 1.0
    p = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r))  # a priori: P^2 / (P + R) = q
    k = p / (p + r)
    for nis in (1.0, 2.0, 5.0, 20.0):
        actual = (k * k * nis * r + q) / (1.0 - (1.0 - k) ** 2)  # a priori, with the gain the filter computed
        assert actual / p == pytest.approx(0.5 * (1.0 + nis), rel=0.02), nis
        if nis > 1.0:  # NIS times P states more than the error
            assert actual / p < nis
