"""Property tests (hypothesis) of filter stability."""

import copy
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from balloon_core.config import Design
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import MODE_FREE, MODE_TAUT, WIND_E, WIND_N, FilterConfig
from tests.helpers.flights import feed, stream

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def fresh_in_flight(float32: bool = False) -> Estimator:
    est = _flying_template(float32)
    return copy.deepcopy(est)


_TEMPLATE: dict[bool, Estimator] = {}


def _flying_template(float32: bool) -> Estimator:
    if float32 not in _TEMPLATE:
        samples, _ = stream("paper-reference", 300.0, 11)
        est = Estimator(Design(), FilterConfig(float32=float32))
        feed(est, samples[:6000])
        assert est.ekf.mode == MODE_TAUT
        _TEMPLATE[float32] = est
    return _TEMPLATE[float32]


def assert_healthy(est: Estimator) -> None:
    P = est.ekf.P.astype(float)
    x = est.ekf.x.astype(float)
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))
    assert np.allclose(P, P.T, rtol=0, atol=1e-9 * max(1.0, np.abs(P).max()))
    assert np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0.0
    assert np.all(np.diag(P) <= est.ekf.var_max.astype(float) * (1 + 1e-9))
    assert abs(float(np.linalg.norm(est.ekf.q)) - 1.0) < 1e-6


finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)
sample = st.tuples(
    st.integers(min_value=-3, max_value=60),  # time step in units of 10 ms (<= 0: jitter/dup/reorder)
    st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(-40, 20)),  # specific force
    st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3)),  # rates
    st.tuples(finite, finite, finite),  # field
    st.one_of(st.none(), st.tuples(st.floats(800.0, 1050.0), st.floats(-20.0, 40.0))),  # baro
)


@SETTINGS
@given(st.lists(sample, min_size=1, max_size=120), st.sampled_from(["ground", "flight"]), st.booleans())
def test_arbitrary_bounded_sequences_keep_the_filter_healthy(seq, where, float32):
    est = Estimator(Design(), FilterConfig(float32=float32)) if where == "ground" else fresh_in_flight(float32)
    t = max(est.t_last_us, 0)
    if where == "ground":
        est.on_imu(t, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    for dt, acc, gyro, mag, baro in seq:
        t += dt * 10_000
        if baro:
            est.on_baro(t, *baro)
        est.on_imu(t, *acc, *gyro, *mag)
        assert_healthy(est)


bad_float = st.sampled_from([math.nan, math.inf, -math.inf, 1e9, -1e9])


@SETTINGS
@given(st.integers(0, 8), bad_float, st.booleans())
def test_invalid_inputs_leave_the_state_unchanged_and_are_counted(field, value, baro):
    est = fresh_in_flight()
    x, P, q = est.ekf.x.copy(), est.ekf.P.copy(), est.ekf.q.copy()
    before = est.counters.rejected
    t = est.t_last_us + 10_000
    if baro:
        args = [1000.0, 20.0]
        args[field % 2] = value
        assert not est.on_baro(t, *args)
    else:
        args = [0.0, 0.0, -9.81, 0.0, 0.0, 0.0]
        if field < 6:
            args[field] = value
            assert not est.on_imu(t, *args)
        else:
            # a bad magnetometer alone is dropped, the rest of the sample is used
            assert est.on_imu(t, *args, *[value if i == field - 6 else 0.3 for i in range(3)])
            return
    assert est.counters.rejected == before + 1
    assert np.array_equal(est.ekf.x, x) and np.array_equal(est.ekf.P, P) and np.array_equal(est.ekf.q, q)


@pytest.mark.slow
@settings(max_examples=6, deadline=None)
@given(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0))
def test_converges_on_simulated_data_from_any_initial_wind_error(dn, de):
    """Start the filter with a wind error of up to 10 m/s per axis (and its initial variance) during
    free ascent; after the taut phase settles the wind is right."""
    samples, truth = stream("paper-reference", 300.0, 11)
    est = Estimator(Design())
    feed(est, samples[:800])  # released at 5 s: in free ascent now
    assert est.ekf.mode == MODE_FREE
    est.ekf.x[WIND_N] += dn
    est.ekf.x[WIND_E] += de
    rows = feed(est, samples[800:12000], record=True)
    late = slice(12000 - 800 - 3000, None)
    err = np.hypot(rows[late, 1] - truth["wind_n"][9000:12000], rows[late, 2] - truth["wind_e"][9000:12000])
    assert np.sqrt(np.mean(err**2)) < 0.6
    assert_healthy(est)


def small(scale):
    return st.floats(-scale, scale, allow_nan=False)


# near the physical envelope of the taut balloon: the samples pass the gates and are fused
near = st.tuples(
    st.integers(min_value=1, max_value=3),
    st.tuples(small(0.3), small(0.3), small(0.3)),  # specific force about a measured one, m/s^2
    st.tuples(small(0.05), small(0.05), small(0.05)),  # rates, rad/s
    st.tuples(small(0.004), small(0.004), small(0.004)),  # field about a measured one, gauss
    st.one_of(st.none(), st.tuples(small(0.5), small(1.0))),  # baro about its last sample: hPa, C
)


@settings(max_examples=30, deadline=None)
@given(st.lists(near, min_size=20, max_size=150), st.booleans())
def test_sequences_near_the_envelope_are_fused_and_keep_the_filter_healthy(seq, float32):
    est = fresh_in_flight(float32)
    samples, _ = stream("paper-reference", 300.0, 11)
    s0 = samples[6000]
    t = est.t_last_us
    fused = sum(s.fused for s in est.accel_status)
    for dt, da, dg, dm, db in seq:
        t += dt * 10_000
        if db:
            est.on_baro(t, 1002.7 + db[0], 19.4 + db[1])
        acc = [a + d for a, d in zip(s0.accel, da)]
        mag = [m + d for m, d in zip(s0.mag, dm)]
        est.on_imu(t, *acc, *dg, *mag)
        assert_healthy(est)
    assert sum(s.fused for s in est.accel_status) - fused >= len(seq)  # fused (3 axes a sample), not gated away


@pytest.mark.parametrize("float32", [False, True])
def test_numeric_reset_recovers_with_the_attitude_from_the_sensors(float32):
    est = fresh_in_flight(float32)
    samples, _ = stream("paper-reference", 300.0, 11)
    est.ekf.P[3, 3] = math.nan  # a numeric fault
    feed(est, samples[6000:6001])
    assert est.counters.numeric_resets == 1
    assert_healthy(est)
    # the attitude comes from this sample's gravity and field, not identity: level to within the
    # balloon's ~10 deg lean, heading from the magnetometer
    q = est.ekf.q.astype(float)
    assert abs(q[0]) < 0.9999
    feed(est, samples[6001:7000])
    assert_healthy(est)


@pytest.mark.parametrize("float32", [False, True])
def test_losing_lift_switches_taut_to_free_and_stays_healthy(float32):
    """Thin air (300 hPa: the balloon no longer lifts itself) -> no tension -> free after 1 s."""
    est = fresh_in_flight(float32)
    samples, _ = stream("paper-reference", 300.0, 11)
    switches = est.counters.mode_switches
    modes = []
    for s in samples[6000:6400]:
        if s.baro:
            est.on_baro(s.time_usec, 300.0, s.baro[1])
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        modes.append(est.ekf.mode)
        assert_healthy(est)
    # slack for 1 s (the dwell), then free; not back to taut within the next second
    assert modes[90] == MODE_TAUT and all(m == MODE_FREE for m in modes[110:210])
    assert est.counters.mode_switches > switches
