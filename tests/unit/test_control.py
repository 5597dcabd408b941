"""The control logic's schedules are times, and every re-placement of the state goes through the
filter's one reset API (firmware_py/estimator/params.py, ekf.WindEkf.reset)."""

import pytest

from balloon_core.config import Design
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.ekf import RESET_HEIGHT, RESET_INITIALISE, RESET_NAMES, RESET_TAUT
from firmware_py.estimator.params import ALIGN_RESET_S, FIELD_LEARN_S, TAUT_PERIOD_S, Schedule
from firmware_py.estimator.state import MODE_TAUT, FilterConfig
from tests.helpers.flights import stream


def test_schedule_at_the_reference_rate_is_the_flown_one():
    s = Schedule.at(100.0, 1.0)
    assert (s.taut_every, s.align_reset, s.baro_reset, s.mag_recover, s.field_learn, s.field_flight) == (
        5, 40, 40, 10, 100, 6000)
    assert (s.wind_noise_every, s.release_confirm, s.release_height, s.baro_recover) == (100, 3, 50, 20)


@pytest.mark.parametrize("rate_hz", [25.0, 50.0, 100.0, 200.0, 400.0])
def test_schedules_are_the_same_in_seconds_at_any_rate(rate_hz):
    s = Schedule.at(rate_hz, 1.0)
    step = 1.0 / rate_hz
    assert abs(s.taut_every * step - TAUT_PERIOD_S) <= step / 2 + 1e-12
    assert s.align_reset * s.taut_every * step == pytest.approx(ALIGN_RESET_S, rel=0.26)
    assert s.field_learn * step == pytest.approx(FIELD_LEARN_S)


@pytest.mark.slow
def test_every_reset_is_told_and_counted():
    """On a flight with taut entries, taut re-placements and height resets, the filter's counters per
    kind equal what the control logic did."""
    samples, _ = stream("reduced-balloon", 120.0, 5)
    est = Estimator(_reduced())
    entries, mode = 0, None
    for s in samples:
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if est.ekf.mode != mode:
            entries += est.ekf.mode == MODE_TAUT
            mode = est.ekf.mode
    c, r = est.counters, est.ekf.reset_counts
    assert len(r) == len(RESET_NAMES) and sum(r) == est.ekf.reset_count
    assert r[RESET_INITIALISE] == 1 + c.numeric_resets
    assert r[RESET_TAUT] == entries + c.taut_resets
    assert r[RESET_HEIGHT] == c.baro_resets + c.false_releases
    assert entries >= 1


def _reduced() -> Design:
    from sim_hil.scenarios import SCENARIOS

    return SCENARIOS["reduced-balloon"].design


def test_an_untold_reset_would_be_seen():
    est = Estimator(Design(), FilterConfig())
    n = est.ekf.reset_count
    est.ekf.reset(RESET_TAUT)
    assert est.ekf.reset_count == n + 1 and est.ekf.reset_counts[RESET_TAUT] == 1


def test_statuses_say_when_they_last_fused():
    samples, _ = stream("reduced-balloon", 120.0, 5)
    est = Estimator(_reduced())
    for s in samples[:6000]:
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
    now = est.t_filter_us
    assert 0 <= now - est.accel_status[0].time_last_fuse_us <= est.dt_us * 10  # fused every step
    assert 0 <= now - est.baro_status.time_last_fuse_us <= 200_000  # 20 Hz
    assert all(st.time_last_fuse_us <= now for st in (*est.mag_status, *est.taut_status))
