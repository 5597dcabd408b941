"""What P does not hold about the magnetic field's axis (consistency.field_attitude_extra): a fusion whose misfit
is correlated counts as that much less data, and nothing else changes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_py.estimator.consistency import correlated_weight, field_attitude_extra, field_variance

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
    assert (extra == 0.0) == (w == 1.0)


def test_the_other_slots_are_weighted_apart():
    """The three slots are the accelerometer (its weight), the barometer, winch and magnetometer (all of it), the
    tether (its weight): information in a fully weighted slot adds no extra; a reset (v_pred, nothing fused) keeps
    what there was, and a fusion that (with a clipped gain) grows the variance takes nothing away."""
    assert field_attitude_extra(0.0, 2e-5, 2e-5, 1e-5, 1e-5, 0.01, 0.01) == 0.0
    assert field_attitude_extra(0.0, 2e-5, 2e-5, 2e-5, 1e-5, 1.0, 0.01) > 0.0
    assert field_attitude_extra(3e-6, 2e-5, 2e-5, 2e-5, 2e-5, 0.01, 0.01) == pytest.approx(3e-6)
    assert field_attitude_extra(3e-6, 2e-5, 2.1e-5, 2.1e-5, 2.1e-5, 0.01, 0.01) >= 0.0
    for bad in (math.nan, 0.0, -1e-5):
        assert field_attitude_extra(3e-6, 2e-5, bad, 2e-5, 2e-5, 0.01, 0.01) >= 0.0


def test_the_weight_is_the_share_of_independent_samples():
    """Innovations no larger than the noise the filter assumed count fully (a filter already cautious); beyond
    that a misfit correlated over tau is worth dt / tau samples per sample, less the larger it is."""
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
    assert field_variance(P, *b) == pytest.approx(float(b @ P[6:9, 6:9] @ b), rel=1e-12)
