"""The measuring instrument: band skill, error ratio and the along/cross frequency response of
balloon_core.score, on synthetic winds whose answers are known."""

import math

import numpy as np
import pytest

from balloon_core.score import MIN_AMPLITUDE_MPS, describe, response, score

FREQS = (0.01, 0.02, 0.05, 0.1)
MULTISINE_HZ = (0.003, 0.01, 0.02, 0.05, 0.1, 0.2)  # the simulator's multisine: more lines than scored
TOWARD_DEG = 37.0  # blowing toward 037 deg: neither axis of the along/cross frame is N or E


def wind(t, along_hz=MULTISINE_HZ, cross_hz=(), amp=0.3, mean=3.0, toward_deg=TOWARD_DEG):
    """(north, east) of a mean wind plus sines along it and across it (cross = 90 deg to the right)."""
    u = mean + sum(amp * np.cos(2 * math.pi * f * t + 1.0 + 7.0 * f) for f in along_hz)
    v = sum(0.5 * amp * np.cos(2 * math.pi * f * t + 2.0 - 5.0 * f) for f in cross_hz) + 0.0 * t
    c, s = math.cos(math.radians(toward_deg)), math.sin(math.radians(toward_deg))
    return u * c - v * s, u * s + v * c


T = np.arange(0.0, 600.0, 0.1)
TRUE_N, TRUE_E = wind(T)


def resp(est_n, est_e, true=(TRUE_N, TRUE_E), freqs=FREQS, t_est=T, extra_hz=MULTISINE_HZ):
    return response(t_est, est_n, est_e, T, *true, freqs, extra_hz=extra_hz)


def test_perfect_estimate_has_unit_response_and_skill_one():
    s = score(T, TRUE_N, TRUE_E, np.full_like(T, 0.1), T, TRUE_N, TRUE_E)
    assert s.band_skill == pytest.approx(1.0, abs=1e-9)
    assert s.band_rmse_mps == pytest.approx(0.0, abs=1e-9)
    for f, h in resp(TRUE_N, TRUE_E).items():
        assert h["along"] == pytest.approx(1.0, abs=1e-9), f
        assert h["cross"] is None  # a multisine along the wind does not drive the cross axis


def test_the_constant_true_mean_has_skill_zero_and_a_poor_guess_negative_skill():
    late = T >= 120.0
    mn, me = TRUE_N[late].mean(), TRUE_E[late].mean()
    s = score(T, np.full_like(T, mn), np.full_like(T, me), np.ones_like(T), T, TRUE_N, TRUE_E)
    assert s.band_skill == pytest.approx(0.0, abs=1e-6)
    assert s.speed_error_pct == pytest.approx(0.0, abs=0.01)
    c = s.band_rmse_mps  # the truth's own fluctuation in the band
    assert 0.2 < c < 0.6
    s = score(T, np.full_like(T, mn + 0.3), np.full_like(T, me), np.ones_like(T), T, TRUE_N, TRUE_E)
    assert s.band_skill == pytest.approx(1.0 - math.hypot(c, 0.3) / c, abs=1e-3) and s.band_skill < 0.0
    assert s.direction_error_deg != pytest.approx(0.0, abs=0.5)


def test_a_steady_truth_has_no_band_skill():
    n, e = wind(T, along_hz=())
    s = score(T, n + 0.05, e, np.ones_like(T), T, n, e)
    assert math.isnan(s.band_skill)
    assert s.band_rmse_mps == pytest.approx(0.05, abs=1e-6)


@pytest.mark.parametrize("delay_s", [4.0, 1.5, 8.0])
@pytest.mark.parametrize("extra_hz, tol", [(MULTISINE_HZ, 0.002), ((), 0.05)])
def test_a_delayed_copy_has_the_phase_and_error_of_the_delay(delay_s, extra_hz, tol):
    """Exact when the truth's other lines (0.003 and 0.2 Hz) are fitted too; they leak a little when not."""
    est_n, est_e = wind(T - delay_s)
    for f, h in resp(est_n, est_e, extra_hz=extra_hz).items():
        gain, phase, err = describe(h["along"])
        want = (-360.0 * f * delay_s + 180.0) % 360.0 - 180.0
        assert gain == pytest.approx(1.0, abs=tol), f
        assert (phase - want + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=60 * tol), f
        assert err == pytest.approx(2.0 * math.sin(math.pi * f * delay_s), abs=tol), f


def test_a_delay_also_shows_in_the_band_skill():
    good = score(T, *wind(T - 1.0), np.ones_like(T), T, TRUE_N, TRUE_E).band_skill
    bad = score(T, *wind(T - 8.0), np.ones_like(T), T, TRUE_N, TRUE_E).band_skill
    assert 0.8 < good < 1.0 and bad < good - 0.3


@pytest.mark.parametrize("scale", [0.5, 1.2])
def test_a_scaled_copy_has_the_gain_of_the_scale(scale):
    for f, h in resp(scale * TRUE_N, scale * TRUE_E).items():
        gain, phase, err = describe(h["along"])
        assert gain == pytest.approx(scale, abs=0.01), f
        assert phase == pytest.approx(0.0, abs=0.5), f
        assert err == pytest.approx(abs(scale - 1.0), abs=0.01), f


def test_along_and_cross_are_separated_for_a_non_cardinal_wind():
    """Truth driven along at 0.01 and 0.05 Hz and across at 0.02 and 0.1 Hz, wind toward 037 deg; the
    estimate passes the along part with gain 0.8 and the cross part with gain 0.5, delayed 2 s."""
    along_hz, cross_hz = (0.01, 0.05), (0.02, 0.1)
    tn, te = wind(T, along_hz=along_hz, cross_hz=cross_hz)
    c, s = math.cos(math.radians(TOWARD_DEG)), math.sin(math.radians(TOWARD_DEG))
    un, ue = wind(T, along_hz=along_hz, cross_hz=())  # the along part alone (with the mean)
    vn, ve = wind(T - 2.0, along_hz=(), cross_hz=cross_hz, mean=0.0)  # the cross part alone, delayed
    est_n, est_e = 0.8 * (un - 3.0 * c) + 3.0 * c + 0.5 * vn, 0.8 * (ue - 3.0 * s) + 3.0 * s + 0.5 * ve
    r = resp(est_n, est_e, true=(tn, te))
    for f in along_hz:
        assert r[f]["cross"] is None
        assert describe(r[f]["along"])[:2] == pytest.approx((0.8, 0.0), abs=0.02)
    for f in cross_hz:
        assert r[f]["along"] is None
        gain, phase, _ = describe(r[f]["cross"])
        assert gain == pytest.approx(0.5, abs=0.02)
        assert phase == pytest.approx(-360.0 * f * 2.0, abs=1.5)


def test_an_axis_below_the_amplitude_threshold_is_not_driven():
    n, e = wind(T, along_hz=(0.05,), amp=0.5 * MIN_AMPLITUDE_MPS)
    r = resp(n, e, true=(n, e))
    assert r[0.05] == {"along": None, "cross": None}


def test_response_ignores_non_finite_estimate_samples_and_other_sample_times():
    t_est = np.arange(0.0, 600.0, 0.02)  # 50 Hz estimate against the 10 Hz truth
    n, e = wind(t_est)
    n[5000:5010] = np.nan
    for f, h in resp(n, e, t_est=t_est).items():
        assert h["along"] == pytest.approx(1.0, abs=0.01), f


def test_error_ratio_is_one_for_an_honest_accuracy():
    rng = np.random.default_rng(5)
    sigma = 0.4  # per component: the horizontal vector's RMS error is sigma * sqrt(2)
    n = TRUE_N + rng.normal(0.0, sigma, T.size)
    e = TRUE_E + rng.normal(0.0, sigma, T.size)
    honest = np.full_like(T, sigma * math.sqrt(2.0))
    assert score(T, n, e, honest, T, TRUE_N, TRUE_E).error_ratio == pytest.approx(1.0, abs=0.03)
    assert score(T, n, e, 0.5 * honest, T, TRUE_N, TRUE_E).error_ratio == pytest.approx(2.0, abs=0.06)
    assert score(T, n, e, 2.0 * honest, T, TRUE_N, TRUE_E).error_ratio == pytest.approx(0.5, abs=0.02)
