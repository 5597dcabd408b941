"""Wind generator: variance = integral of S, spectrum shape, determinism, mean, multisine, a front that turns it."""

import math

import numpy as np
import pytest

from firmware_py.estimator.tuning import KAIMAL_LENGTH_M, kaimal_window_share
from sim_hil.wind import (
    SECONDS_PER_HOUR,
    WindConfig,
    WindStream,
    component_kaimal_psd,
    fft_grid,
    generate_wind,
    kaimal_psd,
    load_van_der_hoven,
    longitudinal_psd,
    paper_line_amplitudes,
    wind_components,
    wind_direction_deg,
)

SEEDS = range(6)


def along_wind(series, cfg):
    to = math.radians(cfg.from_deg + 180.0)
    return series.ned[:, 0] * math.cos(to) + series.ned[:, 1] * math.sin(to)


def test_variance_equals_integral_of_spectrum():
    cfg = WindConfig(gap_cph=2.0, turbulence_intensity=0.12)
    duration = 3600.0
    m, df = fft_grid(duration, cfg.sample_hz)
    # analytic target: integral of S over the resolved band [df/2, fs/2 - df/2], by quadrature
    f_fine = np.linspace(df / 2, cfg.sample_hz / 2 - df / 2, 4_000_001)
    target = np.trapezoid(longitudinal_psd(cfg, f_fine), f_fine)
    variances = [np.var(along_wind(generate_wind(cfg, duration, seed), cfg)) for seed in SEEDS]
    # the full-period variance of a random-phase sum of cosines is sum(A^2)/2 for every seed;
    # the window is two samples short of the period, the quadratures differ (stated tolerance: 2 %)
    assert np.mean(variances) == pytest.approx(target, rel=0.02)
    assert np.std(variances) / np.mean(variances) < 0.01


def test_paper_amplitude_formula_gives_four_over_pi_of_the_integral():
    f_tab, fs_tab = load_van_der_hoven()
    omega, amp = paper_line_amplitudes(0.0, 1.0)
    s = fs_tab / f_tab
    trapz = np.sum(0.5 * (s[:-1] + s[1:]) * np.diff(f_tab))
    assert len(amp) == 47
    assert np.sum(amp**2) / 2 == pytest.approx(4.0 / math.pi * trapz, rel=1e-9)
    # and it is ~4/pi of the exact integral of the digitised spectrum too
    exact = np.trapezoid(fs_tab, np.log(f_tab))
    assert 1.0 < np.sum(amp**2) / 2 / exact < 1.5


def test_paper_mode_time_series_variance_matches_its_lines():
    cfg = WindConfig(vdh_amplitude="paper", turbulence="none", gap_cph=800.0)
    omega, amp = paper_line_amplitudes(20.0 / SECONDS_PER_HOUR, 800.0 / SECONDS_PER_HOUR)
    expected = np.sum(amp**2) / 2  # lines fast enough to average out in 4 h; the slower ones are offsets
    detrended = []
    for seed in SEEDS:
        u = along_wind(generate_wind(cfg, 4 * 3600.0, seed), cfg)
        n = int(60.0 * cfg.sample_hz)
        kernel = np.ones(n) / n
        slow = np.convolve(u, kernel, mode="same")
        detrended.append(np.var((u - slow)[n:-n]))
    # lines above 20 c/h (3 min periods) survive a 60 s moving-average detrend mostly intact
    assert 0.5 * expected < np.mean(detrended) < 1.1 * expected


def test_periodogram_follows_kaimal_target():
    cfg = WindConfig(gap_cph=0.5, turbulence_intensity=0.15)
    duration = 1800.0
    psd = []
    for seed in SEEDS:
        x = along_wind(generate_wind(cfg, duration, seed), cfg)
        x = x - x.mean()
        spec = np.abs(np.fft.rfft(x)) ** 2 * 2.0 / (cfg.sample_hz * len(x))
        psd.append(spec)
    f = np.fft.rfftfreq(len(x), 1.0 / cfg.sample_hz)
    mean_psd = np.mean(psd, axis=0)
    target = component_kaimal_psd(cfg, "u", f)
    edges = np.geomspace(0.005, 2.0, 12)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        band = (f >= lo) & (f < hi)
        ratio = mean_psd[band].sum() / target[band].sum()
        assert 0.7 < ratio < 1.3, (lo, hi, ratio)


def test_same_seed_same_series_and_different_seed_differs():
    cfg = WindConfig()
    a = generate_wind(cfg, 300.0, 7).ned
    b = generate_wind(cfg, 300.0, 7).ned
    c = generate_wind(cfg, 300.0, 8).ned
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_mean_equals_v0_and_direction():
    cfg = WindConfig(mean_mps=5.0, from_deg=315.0)
    means = np.array([generate_wind(cfg, 1200.0, s).ned.mean(axis=0) for s in SEEDS])
    mean_vec = means.mean(axis=0)
    assert math.hypot(mean_vec[0], mean_vec[1]) == pytest.approx(5.0, abs=0.1)
    # from the north-west: blows towards the south-east
    assert math.degrees(math.atan2(mean_vec[1], mean_vec[0])) % 360 == pytest.approx(135.0, abs=2.0)


def test_kaimal_cross_and_vertical_components():
    cfg = WindConfig(gap_cph=0.5, turbulence_intensity=0.2, vertical=True, from_deg=0.0)
    s = generate_wind(cfg, 3600.0, 3)
    # from north -> along-wind is -N, cross-wind is -E
    m, df = fft_grid(3600.0, cfg.sample_hz)
    f = np.linspace(df / 2, cfg.sample_hz / 2, 2_000_001)
    for k, comp in ((1, "v"), (2, "w")):
        expected = np.trapezoid(component_kaimal_psd(cfg, comp, f), f)
        assert np.var(s.ned[:, k]) == pytest.approx(expected, rel=0.05)
    assert np.std(s.ned[:, 2]) < np.std(s.ned[:, 1]) < np.std(s.ned[:, 0])


def test_multisine_has_its_lines_at_equal_amplitude():
    cfg = WindConfig(kind="multisine", multisine_hz=(0.01, 0.05, 0.2), multisine_amplitude_mps=0.4)
    s = generate_wind(cfg, 1000.0, 1)
    x = along_wind(s, cfg)[: int(1000 * cfg.sample_hz)]
    spec = np.abs(np.fft.rfft(x - x.mean())) * 2.0 / len(x)
    f = np.fft.rfftfreq(len(x), 1.0 / cfg.sample_hz)
    for fk in cfg.multisine_hz:
        assert spec[np.argmin(abs(f - fk))] == pytest.approx(0.4, rel=0.02)
    assert np.mean(x) == pytest.approx(3.0, abs=0.02)


def fit_lines(x, t, freqs):
    """Least-squares amplitudes of cos/sin pairs at the given frequencies (plus a mean)."""
    cols = [np.ones_like(t)]
    for fk in freqs:
        cols += [np.cos(2 * math.pi * fk * t), np.sin(2 * math.pi * fk * t)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), x, rcond=None)
    return coef[0], np.hypot(coef[1::2], coef[2::2]), np.arctan2(-coef[2::2], coef[1::2])


@pytest.mark.parametrize("from_deg", [45.0, 170.0])
def test_two_axis_multisine_puts_each_line_on_along_and_cross_components(from_deg):
    cfg = WindConfig(kind="multisine", multisine_axes="both", from_deg=from_deg, multisine_amplitude_mps=0.4)
    s = generate_wind(cfg, 1500.0, 4)
    t = np.arange(len(s.ned)) / cfg.sample_hz
    to = math.radians(from_deg + 180.0)
    along = s.ned[:, 0] * math.cos(to) + s.ned[:, 1] * math.sin(to)
    cross = -s.ned[:, 0] * math.sin(to) + s.ned[:, 1] * math.cos(to)
    mean_u, amp_u, ph_u = fit_lines(along, t, cfg.multisine_hz)
    mean_v, amp_v, ph_v = fit_lines(cross, t, cfg.multisine_hz)
    assert mean_u == pytest.approx(3.0, abs=1e-6) and mean_v == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(amp_u, 0.4, rtol=1e-6)
    np.testing.assert_allclose(amp_v, 0.4, rtol=1e-6)
    # independent phases: the cross component is not a copy of the along one
    assert np.max(np.abs(np.angle(np.exp(1j * (ph_u - ph_v))))) > 0.5
    # in NED each line's power is shared between north and east, and sums to both axes' (2 A^2 / 2)
    _, amp_n, _ = fit_lines(s.ned[:, 0], t, cfg.multisine_hz)
    _, amp_e, _ = fit_lines(s.ned[:, 1], t, cfg.multisine_hz)
    np.testing.assert_allclose(amp_n**2 + amp_e**2, 2 * 0.4**2, rtol=1e-6)
    assert np.all(amp_n > 0.0) and np.all(amp_e > 0.0) and np.max(amp_n) > 0.2 and np.max(amp_e) > 0.2
    assert np.all(s.ned[:, 2] == 0.0)


def test_along_only_multisine_series_is_unchanged_by_the_two_axis_option():
    cfg = WindConfig(kind="multisine")
    u1, v1, _ = wind_components(cfg, 300.0, 5)
    u2, v2, _ = wind_components(WindConfig(kind="multisine", multisine_axes="both"), 300.0, 5)
    assert np.array_equal(u1, u2)
    assert np.all(v1 == 0.0) and np.std(v2) > 0.3
    # and it is the series the along-only generator has always made: phases are the first draws
    rng = np.random.default_rng(np.random.SeedSequence([5, 0x57494E44]))
    phases = rng.uniform(0.0, 2.0 * math.pi, size=len(cfg.multisine_hz))
    t = np.arange(len(u1)) / cfg.sample_hz
    expected = np.zeros_like(t)
    for fk, ph in zip(cfg.multisine_hz, phases, strict=True):
        expected += cfg.multisine_amplitude_mps * np.cos(2.0 * math.pi * fk * t + ph)
    assert np.array_equal(u1, expected)
    to = math.radians(cfg.from_deg + 180.0)
    ned = generate_wind(cfg, 300.0, 5).ned
    assert np.array_equal(ned[:, 1], (3.0 + expected) * math.sin(to) + 0.0 * math.cos(to))


def test_iec_class_b_sets_kaimal_sigma():
    cfg = WindConfig(mean_mps=6.0, iec_class="B", gap_cph=0.5)
    assert cfg.sigma_u_mps == pytest.approx(0.14 * (0.75 * 6.0 + 5.6))
    u, v, _ = wind_components(cfg, 3600.0, 2)
    m, df = fft_grid(3600.0, cfg.sample_hz)
    f = np.linspace(df / 2, cfg.sample_hz / 2, 2_000_001)
    assert np.var(v) == pytest.approx(np.trapezoid(component_kaimal_psd(cfg, "v", f), f), rel=0.05)


def test_bad_wind_config_is_rejected():
    from balloon_core.config import ConfigError

    with pytest.raises(ConfigError):
        WindConfig(kind="hurricane")
    with pytest.raises(ConfigError):
        WindConfig(kind="multisine", multisine_axes="cross")
    assert WindConfig.from_dict({"multisine_axes": "both"}).multisine_axes == "both"
    with pytest.raises(ConfigError):
        WindConfig.from_dict({"mean_mps": 3.0, "colour": "blue"})
    for bad in ({"turn_duration_s": 0.0}, {"turn_start_s": -1.0}, {"turn_deg": math.nan}):
        with pytest.raises(ConfigError):
            WindConfig.from_dict(bad)


@pytest.mark.parametrize("mean_mps", [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0])
def test_the_filter_s_window_share_is_the_kaimal_spectrum_s(mean_mps):
    """What a 60 s window sees of the along-wind variance about its own mean, 1 - int S sinc^2(f T) df / sigma^2
    (the filter's fit, estimator/tuning.py), against the simulator's Kaimal spectrum integrated here: within
    0.006 and never above it (the variance inferred from a window is then never too small), rising with the
    wind (a window of a faster wind holds more of its eddies)."""
    window_s = 60.0
    f = np.logspace(-8, 3, 400_001)
    psd = kaimal_psd(f, 1.0, KAIMAL_LENGTH_M, mean_mps)
    seen = np.trapezoid(psd * (1.0 - np.sinc(f * window_s) ** 2), f) / np.trapezoid(psd, f)
    share = kaimal_window_share(window_s, mean_mps)
    assert seen - 0.006 <= share <= seen + 1e-4
    assert kaimal_window_share(window_s, 1.01 * mean_mps) > share


def test_a_front_turns_the_wind_and_its_fluctuations_with_it():
    """[wind] turn_deg: before the front the wind of no turn, bit for bit; through it the direction follows a half
    cosine (no step in it nor in its rate), the speed and the fluctuations' share along and across the turning mean
    what they were; after it the turned wind; the long-flight stream the same series."""
    calm = WindConfig(kind="multisine", multisine_axes="both", from_deg=300.0)
    front = WindConfig(kind="multisine", multisine_axes="both", from_deg=300.0, turn_deg=-120.0, turn_start_s=100.0,
                       turn_duration_s=60.0)  # fmt: skip
    a, b = generate_wind(calm, 300.0, 3), generate_wind(front, 300.0, 3)
    t = np.arange(len(b.ned)) / front.sample_hz
    before = t < 100.0
    assert np.array_equal(a.ned[before], b.ned[before])
    d = wind_direction_deg(front, t)
    assert d[0] == 300.0 and d[-1] == pytest.approx(180.0) and wind_direction_deg(front, 130.0) == pytest.approx(240.0)
    assert np.all(np.diff(d) <= 0.0) and np.max(np.abs(np.diff(d))) * front.sample_hz <= 0.5 * math.pi * 120.0 / 60.0
    # along and across the turning mean: the calm wind's own components, at every instant
    to = np.radians(d + 180.0)
    along = b.ned[:, 0] * np.cos(to) + b.ned[:, 1] * np.sin(to)
    cross = -b.ned[:, 0] * np.sin(to) + b.ned[:, 1] * np.cos(to)
    to0 = math.radians(300.0 + 180.0)
    np.testing.assert_allclose(along, a.ned[:, 0] * math.cos(to0) + a.ned[:, 1] * math.sin(to0), atol=1e-12)
    np.testing.assert_allclose(cross, -a.ned[:, 0] * math.sin(to0) + a.ned[:, 1] * math.cos(to0), atol=1e-12)
    # after the front it blows from the south
    steady = generate_wind(WindConfig(kind="steady", from_deg=300.0, turn_deg=-120.0, turn_start_s=100.0), 800.0, 3)
    np.testing.assert_allclose(steady.ned[-1], (3.0, 0.0, 0.0), atol=1e-12)
    stream, _ = WindStream(front, 300.0, 3).window(0, len(b.ned) - 1)
    np.testing.assert_allclose(stream, b.ned, atol=1e-12)
