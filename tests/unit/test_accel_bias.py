"""The accelerometer's body-z bias in flight (aid_sources/accel.fuse_bias_magnitude): read from the innovations along
the predicted specific force, which a tilt cannot move; how long a vertical gust lasts (tuning.vertical_air_samples),
which weighs the vertical air's misfit in it; and the horizontal biases (accel.follow_horizontal_bias), followed along
the field's horizontal direction only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from balloon_core.config import Design
from firmware_py.estimator.aid_sources.accel import (
    follow_horizontal_bias,
    fuse_bias_magnitude,
    horizontal_bias_variance,
)
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.ekf import FusionStatus
from firmware_py.estimator.params import ACCEL_HBIAS_MAX_MPS2, ACCEL_HBIAS_RESIDUE, ACCEL_HBIAS_S
from firmware_py.estimator.state import ABIAS_Z, FilterConfig
from firmware_py.estimator.tuning import KAIMAL_VERTICAL_LENGTH_M, vertical_air_samples

VAR = 0.01  # (m/s^2)^2 per sample


def ekf_with_bias_known():
    """A filter's state, its bias known to 0.03 m/s^2 and uncorrelated with the rest (fuse_bias_magnitude reads
    no mode: its caller gates it to the tether)."""
    est = Estimator(Design(), FilterConfig())
    ekf = est.ekf
    ekf.P[ABIAS_Z, :] = ekf.P[:, ABIAS_Z] = 0.0
    ekf.P[ABIAS_Z, ABIAS_Z] = 0.03**2
    ekf.dx.fill(0.0)
    return ekf


def statuses(innov: np.ndarray) -> list[FusionStatus]:
    st = [FusionStatus(f"accel_{a}") for a in "xyz"]
    for s, v in zip(st, innov, strict=True):
        s.innov = float(v)
    return st


def leaning_f(tilt_rad: float) -> np.ndarray:
    """The specific force of a balloon at rest, tilted about its x axis (FRD: f = R^T (-g))."""
    return np.array([0.0, -G0 * math.sin(tilt_rad), -G0 * math.cos(tilt_rad)])


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0, 45.0])
def test_a_tilt_moves_the_innovation_across_f_and_leaves_the_bias(tilt_deg):
    """The prediction turned by 1 deg from the measurement (an attitude error) makes an innovation of g sin(1 deg)
    = 0.17 m/s^2 across f: the bias moves by its second order only (g (1 - cos 1 deg) = 0.0015 m/s^2 along f), under
    a hundredth of what the same innovation along f moves it."""
    f = leaning_f(math.radians(tilt_deg))
    pred = leaning_f(math.radians(tilt_deg + 1.0))
    ekf = ekf_with_bias_known()
    fuse_bias_magnitude(ekf, *f, statuses(f - pred), VAR, FusionStatus("bias"))
    across = abs(float(ekf.dx[ABIAS_Z]))
    ekf = ekf_with_bias_known()
    along = np.linalg.norm(f - pred) * f / np.linalg.norm(f)
    fuse_bias_magnitude(ekf, *f, statuses(along), VAR, FusionStatus("bias"))
    assert across < 0.01 * abs(float(ekf.dx[ABIAS_Z]))  # (1 - cos 1 deg) / sin 1 deg = 0.0087


@pytest.mark.parametrize("tilt_deg", [0.0, 30.0])
def test_a_bias_along_z_is_found_within_its_stated_sigma(tilt_deg):
    """A body-z bias of 0.02 m/s^2 under white noise of 0.1 m/s^2 per axis, 20 Hz for a minute: the estimate within
    3 sigma of it and the sigma what 1200 samples of that noise along f make (cos of the tilt of them on z)."""
    rng = np.random.default_rng(7)
    bias = 0.02
    f_true = leaning_f(math.radians(tilt_deg))
    ekf = ekf_with_bias_known()
    status = FusionStatus("bias")
    for _ in range(1200):
        ekf.dx.fill(0.0)
        meas = f_true + np.array([0.0, 0.0, bias]) + rng.normal(0.0, math.sqrt(VAR), 3)
        pred = f_true + np.array([0.0, 0.0, float(ekf.x[ABIAS_Z])])
        fuse_bias_magnitude(ekf, *meas, statuses(meas - pred), VAR, status)
        ekf.x[ABIAS_Z] += ekf.dx[ABIAS_Z]
    sigma = math.sqrt(float(ekf.P[ABIAS_Z, ABIAS_Z]))
    cos = math.cos(math.radians(tilt_deg))
    assert sigma == pytest.approx(math.sqrt(VAR / 1200) / cos, rel=0.1)
    assert abs(float(ekf.x[ABIAS_Z]) - bias) < 3.0 * sigma
    assert status.fused == 1200 and status.rejected == 0


def test_the_vertical_air_is_worth_one_sample_in_twice_its_integral_time_scale():
    """Twice L_w / U over the sample interval (white samples of that variance have the vertical air's S(0)): 261
    samples at 20 Hz and 4.25 m/s; at least one sample; calm air counts as MIN_WIND_MPS."""
    assert vertical_air_samples(0.05, 4.25) == pytest.approx(2.0 * KAIMAL_VERTICAL_LENGTH_M / 4.25 / 0.05)
    assert vertical_air_samples(0.05, 4.25) == pytest.approx(260.9, rel=0.01)
    assert vertical_air_samples(100.0, 8.0) == 1.0
    assert vertical_air_samples(0.05, 0.0) == vertical_air_samples(0.05, 0.5)


FIELD = (0.2, 0.0, 0.45)  # gauss, NED: a 66 deg field, magnetic north along north


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 135.0])
def test_the_horizontal_bias_follows_what_the_field_holds_and_leaves_the_turn_about_it(yaw_deg):
    """An innovation along the field's horizontal direction (a bias no tilt can take: the field holds the attitude about
    east) moves the body's bias by the weight of it, back in the body frame; one across it (east: where a turn about
    the field's axis moves g, which the tilt's systematic term states) leaves it; nothing while the field is unknown;
    the bias stays within its guard."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    rt = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # R^T of a level body yawed by yaw_deg
    hb = [0.0, 0.0]
    assert follow_horizontal_bias(hb, 0.0, 0.05, FIELD, rt, 0.1)
    assert hb == [0.0, 0.0]
    assert not follow_horizontal_bias(hb, 0.05, 0.0, (math.nan, math.nan, math.nan), rt, 0.1)
    assert hb == [0.0, 0.0]
    assert follow_horizontal_bias(hb, 0.05, 0.03, FIELD, rt, 0.1)  # north 0.05 (taken), east 0.03 (not)
    assert hb == pytest.approx([0.005 * c, -0.005 * s], abs=1e-15)  # north in the body: R^T (1, 0, 0)
    for _ in range(1000):
        follow_horizontal_bias(hb, 10.0, 0.0, FIELD, rt, 1.0)
    assert max(abs(v) for v in hb) == ACCEL_HBIAS_MAX_MPS2
    assert not follow_horizontal_bias(hb, 10.0, 0.0, FIELD, rt, 1.0)  # the guard holds it: the step did not follow


def test_the_followed_bias_takes_the_fields_direction_with_a_declination_and_no_nan():
    """With the field 20 deg east of north the bias moves along it, not along north; a step that is not finite (an
    innovation or a weight of NaN, a numeric reset's) leaves the bias as it was: min/max would pin it at the guard."""
    dec = math.radians(20.0)
    field = (0.2 * math.cos(dec), 0.2 * math.sin(dec), 0.45)
    rt = np.eye(3)  # level, heading north: body x north, body y east
    hb = [0.0, 0.0]
    follow_horizontal_bias(hb, 0.05, 0.0, field, rt, 0.1)  # north 0.05: cos(20 deg) of it lies along the field
    assert hb == pytest.approx([0.005 * math.cos(dec) ** 2, 0.005 * math.cos(dec) * math.sin(dec)], abs=1e-15)
    before = list(hb)
    assert not follow_horizontal_bias(hb, math.nan, 0.0, field, rt, 0.1)
    assert not follow_horizontal_bias(hb, 0.05, 0.0, field, rt, math.nan)
    assert not follow_horizontal_bias(hb, math.inf, 0.0, field, rt, 0.1)
    assert hb == before


def test_the_followed_bias_error_settles_where_the_loop_meets_the_walk():
    """At the full share the variance settles at walk^2 ACCEL_HBIAS_S / (2 ACCEL_HBIAS_RESIDUE), the walk's over
    ACCEL_HBIAS_S / (2 x its residue) seconds; with the loop stopped (a misfit) it grows as the walk does."""
    walk, dt = 0.001, 0.05
    v = 0.0
    for _ in range(int(20 * ACCEL_HBIAS_S / dt)):
        v = horizontal_bias_variance(v, walk * walk * dt, dt / ACCEL_HBIAS_S)
    assert v == pytest.approx(walk * walk * ACCEL_HBIAS_S / (2.0 * ACCEL_HBIAS_RESIDUE), rel=0.01)
    stopped = v
    for _ in range(1000):
        stopped = horizontal_bias_variance(stopped, walk * walk * dt, 0.0)
    assert stopped == pytest.approx(v + 1000 * walk * walk * dt, rel=1e-9)
    assert horizontal_bias_variance(1e-6, 0.0, 1e9) == 0.0  # never negative
