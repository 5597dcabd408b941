"""The block-by-block wind of long flights (WindStream): the same statistics as the whole-flight
generator, continuous across blocks, random access, and small whatever the duration."""

import math

import numpy as np
import pytest

from sim_hil.wind import (
    SPLIT_HZ,
    WindConfig,
    WindSeries,
    WindStream,
    component_kaimal_psd,
    fft_grid,
    longitudinal_psd,
    wind_source,
)

BLOCK = 2**14  # 13.7 min blocks: many joins in a short test flight


def along(ned, cfg):
    to = math.radians(cfg.from_deg + 180.0)
    return ned[:, 0] * math.cos(to) + ned[:, 1] * math.sin(to)


def flight(cfg, duration, seed, block=BLOCK):
    ws = WindStream(cfg, duration, seed, block_samples=block)
    return ws, ws.window(0, ws.n - 1)


def test_variance_equals_integral_of_spectrum():
    cfg = WindConfig(gap_cph=2.0, turbulence_intensity=0.12)
    duration = 3 * 3600.0
    m, df = fft_grid(duration, cfg.sample_hz)
    f = np.linspace(df / 2, cfg.sample_hz / 2 - df / 2, 2_000_001)
    target = np.trapezoid(longitudinal_psd(cfg, f), f)
    variances = [np.var(along(flight(cfg, duration, seed)[1][0], cfg)) for seed in range(4)]
    assert np.mean(variances) == pytest.approx(target, rel=0.05)


def test_kaimal_band_spectrum_across_the_split():
    cfg = WindConfig(gap_cph=0.5, turbulence_intensity=0.15)
    duration = 3600.0
    psd = []
    for seed in range(4):
        x = along(flight(cfg, duration, seed)[1][0], cfg)
        x = x - x.mean()
        psd.append(np.abs(np.fft.rfft(x)) ** 2 * 2.0 / (cfg.sample_hz * len(x)))
    f = np.fft.rfftfreq(len(x), 1.0 / cfg.sample_hz)
    mean_psd, target = np.mean(psd, axis=0), component_kaimal_psd(cfg, "u", f)
    edges = np.geomspace(0.003, 2.0, 12)
    assert edges[0] < SPLIT_HZ < edges[-1]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        band = (f >= lo) & (f < hi)
        assert 0.7 < mean_psd[band].sum() / target[band].sum() < 1.3, (lo, hi)


def test_continuous_across_block_joins_and_random_access():
    cfg = WindConfig(turbulence_intensity=0.2, vertical=True)
    ws, (ned, rate) = flight(cfg, 2 * 3600.0, 3)
    steps = np.diff(ned, axis=0)
    joins = np.arange(BLOCK // 2, len(steps), BLOCK // 2)
    for k in range(3):  # Gaussian steps: the largest of 144 000 is ~5 sigma; a jump at a join would be far more
        sigma = steps[:, k].std()
        assert np.abs(steps[:, k]).max() < 7.0 * sigma
        assert np.abs(steps[joins, k]).max() < 4.5 * sigma
    a, b = 40_000, 61_000  # spans a block join (every BLOCK / 2 samples)
    part, part_rate = WindStream(cfg, 2 * 3600.0, 3, block_samples=BLOCK).window(a, b)
    np.testing.assert_allclose(part, ned[a : b + 1], atol=1e-12)
    np.testing.assert_allclose(part_rate[1:-1], rate[a + 1 : b], atol=1e-9)
    assert not np.allclose(flight(cfg, 2 * 3600.0, 4)[1][0], ned)


def test_mean_direction_and_multisine_lines():
    cfg = WindConfig(kind="multisine", multisine_axes="both", from_deg=45.0, multisine_amplitude_mps=0.4)
    _, (ned, _) = flight(cfg, 1500.0, 1)
    x = along(ned, cfg)[: int(1500 * cfg.sample_hz)]
    spec = np.abs(np.fft.rfft(x - x.mean())) * 2.0 / len(x)
    f = np.fft.rfftfreq(len(x), 1.0 / cfg.sample_hz)
    for fk in (0.02, 0.05, 0.1, 0.2):
        assert spec[np.argmin(abs(f - fk))] == pytest.approx(0.4, rel=0.03)
    assert np.mean(x) == pytest.approx(3.0, abs=0.05)
    _, (steady, _) = flight(WindConfig(kind="steady", mean_mps=5.0, from_deg=270.0), 100.0, 1)
    np.testing.assert_allclose(steady, np.tile([0.0, 5.0, 0.0], (len(steady), 1)), atol=1e-12)


def test_long_flights_stream_and_stay_small():
    cfg = WindConfig()
    assert isinstance(wind_source(cfg, 3600.0, 1), WindSeries)
    day = wind_source(cfg, 86400.0, 1, 2.0)
    assert isinstance(day, WindStream)
    week = WindStream(cfg, 7 * 86400.0, 1, 2.0)
    week.window(10_000_000, 10_010_000)
    held = week.low.nbytes + sum(b.nbytes for b in week._cache.values())
    assert held < 30e6  # 7 days: the 1 Hz low band (14 MB) and two blocks
