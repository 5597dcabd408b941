"""The attitude's and the gyro bias's reduced gains (ekf.fuse3, aid_sources/accel.py; ekf.fuse, the alignment's
rows in aid_sources/tether.py) and the free ascent's rope pick-up (model.rope_pickup_n): the covariance is the one of
the gain used, the heading's gain and the alignment's attitude gain follow the accelerometer's misfit, the pick-up is
there only while the rope is being lifted (its Jacobian: test_model.py)."""

import math

import numpy as np
import pytest

from balloon_core.config import Design
from benchmarks.bench_envelope import sample
from firmware_py.estimator.aid_sources import tether
from firmware_py.estimator.aid_sources.accel import control_accel, radial_noise
from firmware_py.estimator.consistency import ACCEL, FLAG_NIS
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.ekf import SLOW_STATES, FusionStatus
from firmware_py.estimator.model import BalloonModel, rope_pickup_n
from firmware_py.estimator.params import ACCEL_HEADING_GAIN_MIN, ACCEL_MODEL_CORR_S, ALIGN_MODEL_CORR_S, UNGATED
from firmware_py.estimator.state import ATT_D, ATT_E, ATT_N, MODE_TAUT, N_STATES
from tests.unit.test_rows import _refresh, taut_state
from tools.ascent_scale import ascent_error

MODEL = BalloonModel.from_design(Design())


def _ekf(seed: int):
    est = Estimator(Design())
    est.on_imu(0, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    ekf = est.ekf
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(N_STATES, N_STATES)) * 0.1
    ekf.P[:] = a @ a.T + 0.01 * np.eye(N_STATES)
    ekf.H3[:] = rng.normal(size=(3, N_STATES))
    return ekf


@pytest.mark.parametrize(("tilt", "heading"), [(0.1, 0.55), (0.1, 1.0), (1.0, 0.3)])
def test_the_reduced_gains_keep_the_covariance_of_the_gain_used(tilt, heading):
    """K' = D K with D the tilt's gain on the tilt, the heading's on the heading and the gyro bias, 1 elsewhere:
    the update is K' times the innovation and P the Joseph form (I - K'H) P (I - K'H)^T + K' R K'^T, not the
    optimal gain's P - KHP (the two differ, so the test can fail)."""
    ekf = _ekf(7)
    p0, h = ekf.P.copy(), ekf.H3.copy()
    r, r2 = 0.04, 0.01
    innov = np.array([0.01, -0.02, 0.015])
    ekf.begin_update()
    st = [FusionStatus(str(i)) for i in range(3)]
    assert ekf.fuse3(*innov, r, st, r2, tilt, heading)
    rr = np.diag([r, r, r + r2])
    k = p0 @ h.T @ np.linalg.inv(h @ p0 @ h.T + rr)
    d = np.ones(N_STATES)
    d[[ATT_N, ATT_E]] = tilt
    d[list(SLOW_STATES[2:])] = heading
    kp = d[:, None] * k
    ikh = np.eye(N_STATES) - kp @ h
    joseph = ikh @ p0 @ ikh.T + kp @ rr @ kp.T
    assert np.allclose(ekf.dx, kp @ innov, rtol=1e-9, atol=1e-12)
    assert np.allclose(ekf.P, joseph, rtol=1e-9, atol=1e-12)
    if tilt < 1.0 or heading < 1.0:
        assert not np.allclose(ekf.P, p0 - k @ h @ p0, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("gain", [0.35, 1.0])
def test_a_scalar_rows_reduced_attitude_gain_keeps_the_covariance_of_the_gain_used(gain):
    """ekf.fuse's ``att_gain`` (the alignment's rows, aid_sources/tether.py): K' = D K with D the gain on the
    attitude's three rows, 1 elsewhere (the gyro bias's too); the update is K' times the innovation and P the Joseph
    form, not the optimal gain's P - KHP where the gain is reduced."""
    ekf = _ekf(11)
    rng = np.random.default_rng(3)
    ekf.h[:] = rng.normal(size=N_STATES)
    p0, h, r, innov = ekf.P.copy(), ekf.h.copy(), 0.02, 0.013
    ekf.begin_update()
    assert ekf.fuse(innov, r, FusionStatus("row"), UNGATED, recover=False, att_gain=gain)
    k = p0 @ h / (h @ p0 @ h + r)
    d = np.ones(N_STATES)
    d[ATT_N : ATT_D + 1] = gain
    kp = d * k
    ikh = np.eye(N_STATES) - np.outer(kp, h)
    joseph = ikh @ p0 @ ikh.T + r * np.outer(kp, kp)
    assert np.allclose(ekf.dx, kp * innov, rtol=1e-9, atol=1e-12)
    assert np.allclose(ekf.P, joseph, rtol=1e-9, atol=1e-12)
    assert np.allclose(ekf.P, p0 - np.outer(k, h @ p0), rtol=1e-9, atol=1e-12) == (gain == 1.0)


@pytest.mark.parametrize("nis", [0.5, FLAG_NIS, 1.5 * FLAG_NIS, 2.0 * FLAG_NIS, 5.0 * FLAG_NIS])
def test_the_alignments_attitude_gain_follows_the_accelerometers_misfit(monkeypatch, nis):
    """Where the force model explains the accelerometer, the alignment's cross row moves the attitude at its whole
    gain; from twice FLAG_NIS at sqrt(interval / ALIGN_MODEL_CORR_S) of it (the rocking balloon's correlated misfit),
    linearly between; the position, the gyro bias and the along row always at the whole (ekf.fuse's att_gain)."""
    est = Estimator(Design())
    est.on_imu(0, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    est.ekf.mode = MODE_TAUT
    seen = []
    monkeypatch.setattr(tether, "fuse_taut", lambda *a: seen.append(a[-1]))
    est.consistency.nis[ACCEL] = nis
    tether.control_tether(est)
    least = math.sqrt(est.schedule.taut_every * est.ekf.dt / ALIGN_MODEL_CORR_S)
    misfit = min(1.0, max(0.0, nis / FLAG_NIS - 1.0))
    assert seen == [pytest.approx(1.0 - misfit * (1.0 - least))]
    assert 0.3 < least < 0.4


@pytest.mark.parametrize("nis", [0.5, FLAG_NIS, 1.5 * FLAG_NIS, 2.0 * FLAG_NIS, 5.0 * FLAG_NIS])
def test_the_heading_takes_the_reduced_gain_as_the_accelerometer_stops_being_explained(nis):
    """Below FLAG_NIS the heading and the gyro bias take the whole gain, from twice FLAG_NIS ACCEL_HEADING_GAIN_MIN
    of it, linearly between (never the tilt's tenth: the position's azimuth, which the same rows move, takes the
    whole); the tilt always takes its reduced gain in flight."""
    est = Estimator(Design())
    est.on_imu(0, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    ekf = est.ekf
    ekf.mode = MODE_TAUT
    ekf.x[0:3] = [3.0, 40.0, -92.0]
    ekf.x[12:14] = [0.5, 3.0]
    ekf.x[16] = 1.0
    seen = []
    ekf.fuse3 = lambda *a: seen.append(a[6:8]) or True  # (tilt_gain, heading_gain)
    est.consistency.nis[ACCEL] = nis
    control_accel(est, 0.1, -0.2, -9.7)
    tilt, heading = seen[0]
    a = math.sqrt(ekf.dt / ACCEL_MODEL_CORR_S)
    assert tilt == pytest.approx(a)
    misfit = min(1.0, max(0.0, nis / FLAG_NIS - 1.0))
    assert heading == pytest.approx(1.0 - misfit * (1.0 - ACCEL_HEADING_GAIN_MIN))
    assert ACCEL_HEADING_GAIN_MIN - 1e-12 <= heading <= 1.0
    assert a < ACCEL_HEADING_GAIN_MIN


def test_the_rope_pickup_is_the_climbs_momentum_while_rope_lies_on_the_ground():
    r, length, lam = MODEL.radius_m, MODEL.tether_length_m, MODEL.rope_kg_m
    pd = -(r + 0.5 * length)  # half the rope aloft
    assert rope_pickup_n(MODEL, pd, -4.0) == pytest.approx(lam * 16.0)
    assert rope_pickup_n(MODEL, pd, 0.0) == 0.0  # at rest
    assert rope_pickup_n(MODEL, pd, 2.0) == 0.0  # descending: the rope lays itself down
    assert rope_pickup_n(MODEL, -(r + length + 1.0), -4.0) == 0.0  # all of it aloft
    assert rope_pickup_n(MODEL, -(r - 0.1), -4.0) == 0.0  # on the ground


def test_the_real_ropes_ascent_learns_the_balloons_drag_without_the_pickups_bias():
    """The envelope's steady flights on the real rope (the first 12 of the full sample): the free ascent's drag
    scale against the truth's C_d. Without the pick-up in the ascent's model it read 3.5 % high on average (3.8 %
    RMS), and the taut wind half of that low; with it +1.1 % (1.9 % RMS)."""
    flights = [p for p in sample(200) if p["wind_kind"] == "steady" and p["rope_model"] == "lumped"][:12]
    e = np.array([ascent_error(p)[0] for p in flights])
    assert abs(e.mean()) < 0.02
    assert np.sqrt(np.mean(e**2)) < 0.03


@pytest.mark.parametrize("scale", [1.0, 90.0])
def test_the_noise_along_one_axis_is_its_outer_product(scale):
    """fuse3's ``axis_var axis axis^T`` (the rope's breathing along the tether's radius, accel.radial_noise, ``axis``
    of any length: R^T p, ``axis_var`` per its square): the update is the closed form with R = diag(r, r, r + r2) +
    v a a^T, each axis's innovation variance that covariance's diagonal; without the term the update differs (the
    test can fail)."""
    ekf = _ekf(11)
    p0, h = ekf.P.copy(), ekf.H3.copy()
    r, r2, v = 0.04, 0.01, 0.3 / scale**2
    a = scale * np.array([0.3, -0.5, 0.8]) / math.sqrt(0.98)
    innov = np.array([0.02, -0.01, 0.3])
    ekf.begin_update()
    st = [FusionStatus(str(i)) for i in range(3)]
    assert ekf.fuse3(*innov, r, st, r2, 1.0, 1.0, tuple(a), v)
    rr = np.diag([r, r, r + r2]) + v * np.outer(a, a)
    s = h @ p0 @ h.T + rr
    k = p0 @ h.T @ np.linalg.inv(s)
    assert np.allclose(ekf.dx, k @ innov, rtol=1e-9, atol=1e-12)
    assert np.allclose(ekf.P, p0 - k @ h @ p0, rtol=1e-9, atol=1e-12)
    assert [x.innov_var for x in st] == pytest.approx(np.diag(s).tolist(), rel=1e-12)
    k0 = p0 @ h.T @ np.linalg.inv(h @ p0 @ h.T + np.diag([r, r, r + r2]))
    assert not np.allclose(k0 @ innov, k @ innov, rtol=1e-3)


def test_the_ropes_breathing_adds_to_the_radius_what_its_innovations_have_beyond_the_shared_noise():
    assert radial_noise(0.5, 0.2) == pytest.approx(0.3)
    assert radial_noise(0.1, 0.2) == 0.0  # never less along the radius than on every axis


def test_the_first_taut_spell_counts_a_speed_above_the_mean_as_one_of_its_own_samples():
    """The filter's 60 s mean wind sizes the wind's process noise (q_rate ~ U^(14/3)). In the first taut spell, until it
    fills the window, a speed above the mean counts as one of the spell's own n samples, so a 10 m/s day is sized as
    one within seconds of the taut entry, not over two minutes from the design's 3 m/s; a speed below it, a spell
    after the rope went slack and a spell past its window take the running mean's weight."""
    est = Estimator(Design())
    alpha = est._speed_alpha
    window = int(round(1.0 / alpha))
    est._dwell, est._was_slack = 99, False
    assert est._mean_weight(1.0) == pytest.approx(1.0 / 100.0)
    assert est._mean_weight(-1.0) == alpha
    est._dwell = window
    assert est._mean_weight(1.0) == alpha
    est._dwell, est._was_slack = 99, True
    assert est._mean_weight(1.0) == alpha
    # from 3 m/s, 10 m/s seen since the entry: the spell's first sample sets the mean, and the spell's mean holds it
    # over its first second (100 steps), where the running mean of the whole window would have taken 1.6 % of the way
    est._was_slack, mean = False, 3.0
    for k in range(100):
        est._dwell = k
        mean += est._mean_weight(10.0 - mean) * (10.0 - mean)
    assert mean == pytest.approx(10.0)


def test_only_the_cross_row_of_the_alignment_takes_the_reduced_attitude_gain():
    """fuse_taut hands ``att_gain`` to the cross row alone; the along row (its noise follows its innovations' spread
    without a bound) and the radius rows fuse at the whole gain."""
    e = taut_state()
    _refresh(e)
    seen = []
    e.fuse = lambda innov, r, status, gate_sigma=None, recover=True, att_gain=1.0: seen.append((status, att_gain))
    e.begin_update()
    st = [FusionStatus(str(i)) for i in range(4)]
    tether.fuse_taut(e, 0.1, 0.1, 0.1, 0.1, st, (0.2, 0.0, 0.45), 0.1, 0.5, 0.35)
    assert [(s.name, g) for s, g in seen] == [("0", 1.0), ("1", 1.0), ("2", 1.0), ("3", 0.35)]
