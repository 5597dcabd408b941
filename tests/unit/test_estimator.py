"""Estimator accuracy against truth, numerics, float32, time handling, bad input."""

import copy
import math
from dataclasses import replace

import numpy as np
import pytest

from balloon_core.config import Design
from balloon_core.score import score
from firmware_py.estimator.aid_sources.accel import accel_nominal_var
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import MODE_TAUT, WIND_E, WIND_N, FilterConfig
from sim_hil.scenarios import SCENARIOS
from tests.helpers.flights import feed, stream
from tools import sensor_faults

# the paper's world says so in its design file: the paper's rope, no rope drag (sim_hil/scenarios.py)
PAPER_FILTER = SCENARIOS["paper-reference"].filter


def check_covariance(P):
    assert np.all(np.isfinite(P))
    assert np.allclose(P, P.T, atol=1e-9 * max(1.0, np.abs(P).max()))
    assert np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0.0


def band_lag_s(rows, truth, start_s: float = 120.0, max_lag_s: float = 10.0) -> float:
    """Delay of the estimate behind the truth, s: the peak of the cross-correlation of both series
    low-passed below 0.05 Hz (horizontal vector), on a 10 Hz grid after ``start_s``."""
    from balloon_core.score import GRID_HZ, lowpass

    grid = np.arange(start_s, min(rows[-1, 0], truth["time_s"][-1]), 1.0 / GRID_HZ)
    e = [lowpass(np.interp(grid, rows[:, 0], rows[:, k]), GRID_HZ, 0.05) for k in (1, 2)]
    t = [lowpass(np.interp(grid, truth["time_s"], truth[c]), GRID_HZ, 0.05) for c in ("wind_n", "wind_e")]
    e = [x - x.mean() for x in e]
    t = [x - x.mean() for x in t]
    lags = np.arange(-int(max_lag_s * GRID_HZ), int(max_lag_s * GRID_HZ) + 1)
    n = len(grid)
    corr = [sum(np.dot(ek[max(0, k):n + min(0, k)], tk[max(0, -k):n - max(0, k)]) for ek, tk in zip(e, t))
            for k in lags]  # fmt: skip
    return float(lags[int(np.argmax(corr))] / GRID_HZ)


@pytest.mark.slow
def test_band_lag_measures_a_delay():
    _, truth = stream("paper-reference", 300.0, 11)
    t = truth["time_s"]
    rows = np.column_stack([t, np.interp(t - 4.0, t, truth["wind_n"]), np.interp(t - 4.0, t, truth["wind_e"])])
    assert band_lag_s(rows, truth) == pytest.approx(4.0, abs=0.3)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_paper_reference_accuracy(seed):
    samples, truth = stream("paper-reference", 300.0, seed)
    est = Estimator(Design(), PAPER_FILTER)
    rows = feed(est, samples, record=True)
    s = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"])
    # judged against the constant true mean (skill 0; the previous filter scored ~0.5 here), not an
    # RMSE bound that the constant also meets
    assert s.band_skill >= 0.6
    assert abs(s.speed_error_pct) <= 3.0
    assert abs(s.direction_error_deg) <= 2.0
    # honest to cautious: the stated accuracy allows for a drag scale learnt to 7 % in the ascent (what the
    # real rope's ascents need, params.DRAG_ASCENT_SIGMA), which the paper's rope lets it learn to 2 %
    assert 0.5 <= s.error_ratio <= 1.5
    # a copy of the truth delayed by 4 s scores skill 0.65-0.69 here: the delay itself is bounded
    assert abs(band_lag_s(rows, truth)) <= 1.0
    assert est.ekf.mode == MODE_TAUT
    assert est.counters.mode_switches >= 2  # ground -> free -> taut
    check_covariance(est.ekf.P)


@pytest.mark.slow
def test_float32_mode_is_stable_on_the_same_data():
    samples, truth = stream("paper-reference", 300.0, 11)
    est = Estimator(Design(), FilterConfig(float32=True))
    assert est.ekf.P.dtype == np.float32
    rows = feed(est, samples, record=True)
    assert np.all(np.isfinite(rows))
    s = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"])
    assert s.band_skill >= 0.6
    assert est.counters.numeric_resets == 0
    check_covariance(est.ekf.P.astype(np.float64))


@pytest.fixture(scope="module")
def flying():
    """An estimator in steady taut flight at t = 150 s, and the samples after it."""
    samples, _ = stream("paper-reference", 300.0, 11)
    est = Estimator(Design())
    feed(est, samples[:15000])
    assert est.ekf.mode == MODE_TAUT
    return est, samples[15000:]


def test_invalid_samples_leave_the_state_unchanged_and_are_counted(flying):
    est = copy.deepcopy(flying[0])
    x, P, q = est.ekf.x.copy(), est.ekf.P.copy(), est.ekf.q.copy()
    t = est.t_last_us + 10_000
    bad = [
        (t, math.nan, 0.0, -9.8, 0.0, 0.0, 0.0),
        (t, 0.0, math.inf, -9.8, 0.0, 0.0, 0.0),
        (t, 0.0, 0.0, -9.8, 0.0, -math.inf, 0.0),
        (t, 1e6, 0.0, -9.8, 0.0, 0.0, 0.0),
        (t, 0.0, 0.0, -9.8, 100.0, 0.0, 0.0),
    ]
    for b in bad:
        assert not est.on_imu(*b)
    assert not est.on_baro(t, math.nan, 20.0)
    assert not est.on_baro(t, 5000.0, 20.0)
    assert not est.on_baro(t, 1000.0, 400.0)
    assert est.counters.rejected == len(bad) + 3
    assert np.array_equal(est.ekf.x, x) and np.array_equal(est.ekf.P, P) and np.array_equal(est.ekf.q, q)


def test_duplicates_reordering_gaps_and_time_going_back(flying):
    est = copy.deepcopy(flying[0])
    samples = flying[1]
    s0 = samples[0]
    feed(est, [s0])
    c = est.counters
    x = est.ekf.x.copy()
    assert not est.on_imu(s0.time_usec, *s0.accel, *s0.gyro, *s0.mag)  # duplicate
    assert c.duplicates == 1 and np.array_equal(est.ekf.x, x)
    old = replace(s0, time_usec=s0.time_usec - 30_000)
    assert not est.on_imu(old.time_usec, *old.accel, *old.gyro, *old.mag)  # late, reordered
    assert c.reordered == 1
    # a 0.3 s dropout: predicted through, counted as a gap, the estimate stays sane
    feed(est, samples[31:200])
    assert c.gaps == 1 and c.long_gaps == 0
    wn, we = est.wind()
    assert abs(math.hypot(wn, we) - 3.0) < 1.5
    # a 5 s dropout: bounded work (0.5 s predicted), flagged
    feed(est, samples[700:800])
    assert c.long_gaps == 1
    # time going back by more than a second: the vehicle rebooted -> reset; it was flying, so the balloon is still up
    # on its tether: the new boot joins in flight, unconfirmed
    feed(est, [replace(samples[0], time_usec=1000)])
    assert c.time_resets == 1 and est.ekf.mode == MODE_TAUT and est.unconfirmed
    # the level rows' statistics start again with it: from the accelerometer's nominal noise on the tether, not from
    # zero (which fused them at the sensor's noise alone, as if the balloon did not move, for seconds)
    feed(est, [replace(s, time_usec=1000 + 10_000 * (k + 1)) for k, s in enumerate(samples[1:11])])
    assert est.level_var > 0.5 * accel_nominal_var(est), (est.level_var, accel_nominal_var(est))



@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_a_lost_second_of_imu_in_gusts_leaves_the_wind_honest(seed):
    """0.6 s of IMU samples lost on a link (a long gap, beyond max_gap_s) 15 s after the taut entry, class B gusts on
    the paper's rope: the prediction held the rate of the sample before across it, and the balloon, rocking at tens
    of degrees a second, turned otherwise. Before the gap's attitude variance (ekf.gap_attitude_var) the filter held
    its attitude to a degree where it was tens off: 16-17 % of the next 20 s beyond 3 sigma, the wind 1.7-2.0 m/s off
    at error/accuracy up to 4.7 (0 % in the same flights without the gap)."""
    _, ratio, beyond, _ = sensor_faults.fly("gusty-6", seed, "imu-gap", 15.0, 20.0, "py", skip_s=0.6, duration_s=60.0)
    assert beyond <= 0.03, (ratio, beyond)
    assert ratio <= 1.0, (ratio, beyond)


def perturb_wind(est, dn, de):
    """A wind error the filter knows it may have: its wind variance back at the initial value."""
    ekf = est.ekf
    ekf.x[WIND_N] += dn
    ekf.x[WIND_E] += de
    for i in (WIND_N, WIND_E):
        ekf.P[i, :] = 0.0
        ekf.P[:, i] = 0.0
        ekf.P[i, i] = est.cfg.init_wind_mps**2


@pytest.mark.slow
def test_converges_from_large_initial_wind_errors(flying):
    for dn, de in ((10.0, -10.0), (-8.0, 6.0), (0.0, 9.0)):
        est = copy.deepcopy(flying[0])
        perturb_wind(est, dn, de)
        rows = feed(est, flying[1][:9000], record=True)
        _, truth = stream("paper-reference", 300.0, 11)
        i0 = 15000 + 6000
        err = np.hypot(rows[6000:, 1] - truth["wind_n"][i0:24000], rows[6000:, 2] - truth["wind_e"][i0:24000])
        assert np.sqrt(np.mean(err**2)) < 0.6, (dn, de)
        check_covariance(est.ekf.P)


def test_sensor_silence_grows_the_reported_accuracy(flying):
    est = copy.deepcopy(flying[0])
    before = est.ekf.wind_accuracy()
    for _ in range(30):
        est.coast(1.0)
    assert est.ekf.wind_accuracy() > 1.5 * before
    check_covariance(est.ekf.P)


@pytest.mark.slow
def test_configured_ground_pressure_replaces_zeroing():
    from balloon_core.config import SiteConfig

    samples, truth = stream("paper-reference", 300.0, 11)
    est = Estimator(replace(Design(), site=SiteConfig(ground_pressure_hpa=1013.25)), PAPER_FILTER)
    assert not est._zeroing
    rows = feed(est, samples, record=True)
    s = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"])
    assert s.band_skill >= 0.6
    assert est.height_m() == pytest.approx(truth["height_m"][-1], abs=2.0)


@pytest.mark.parametrize("core", ["py", "c"])
def test_before_the_barometer_reads_the_air_is_the_sites(core):
    """Until its first barometer sample the filter takes the site's air: the design's ground pressure, else the
    standard atmosphere's at the site's altitude (845.6 hPa at 1500 m), at 20 C; not the sea's. A join in flight
    places the balloon with the lift of that air (at 1500 m the sea's overstated it by 20 %), and the rope's weight
    share and the vertical air's noise start from it (both cores)."""
    from balloon_core.config import SiteConfig
    from firmware_py.core_c import new_core

    def rho_of(site: SiteConfig) -> float:
        est, _ = new_core(replace(Design(), site=site), replace(FilterConfig(), core=core))
        return float(est.rho)

    at_sea = 101325.0 / (287.05 * 293.15)
    assert rho_of(SiteConfig()) == pytest.approx(at_sea, rel=1e-6)
    high = 101325.0 * (1.0 - 0.0065 * 1500.0 / 288.15) ** (9.80665 / (287.05 * 0.0065))
    assert rho_of(SiteConfig(altitude_amsl_m=1500.0)) == pytest.approx(high / (287.05 * 293.15), rel=1e-6)
    assert rho_of(SiteConfig(altitude_amsl_m=1500.0, ground_pressure_hpa=900.0)) == pytest.approx(
        90000.0 / (287.05 * 293.15), rel=1e-6
    )


@pytest.mark.parametrize("core", ["py", "c"])
def test_the_force_balance_is_judged_once_the_taut_entrys_settling_is_over(core):
    """The force balance's NIS joins the monitor BALANCE_FROM_S after the taut placement, not before, its mean from
    zero then: the placement's own convergence pulls the velocity too (which the settling states), and judged with it
    (against the variance a consistent filter's mean has) it flagged every entry for a minute after it had settled
    (both cores, the same step)."""
    from firmware_py.estimator.consistency import FORCE
    from firmware_py.estimator.params import BALANCE_FROM_S

    samples, _ = stream("paper-reference", 100.0, 11)
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    seen: dict[str, float] = {}

    def watch(s) -> None:  # the taut entry, and the first force balance's NIS
        if est.ekf.mode == MODE_TAUT:
            seen.setdefault("entry", s.time_usec * 1e-6)
        if est.consistency.nis[FORCE] != 0.0:
            seen.setdefault("first", s.time_usec * 1e-6)

    feed(est, samples, each=watch)
    entry, first = seen.get("entry"), seen.get("first")
    assert entry is not None and first is not None, seen
    assert BALANCE_FROM_S - 1e-6 <= first - entry <= BALANCE_FROM_S + 0.1, (entry, first)


@pytest.mark.parametrize("core", ["py", "c"])
def test_the_stated_accuracy_follows_the_snap_as_it_settles(core):
    """From the taut placement on, the stated accuracy is at least what the placement has still to settle
    (consistency.placement_settling_wind, from the filter's time of the placement): the placement's 1-sigma and the
    wind's speed (the larger of the placement's and the estimate's: a swing that takes the estimate towards calm does
    not take the statement with it) at the entry, falling by e every ENTRY_SETTLE_S (both cores)."""
    from firmware_py.estimator.consistency import placement_settling_wind

    samples, _ = stream("paper-reference", 60.0, 11)
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    seen: list[tuple[float, float]] = []

    def watch(s) -> None:  # taut: the time, the stated accuracy, the wind's speed, the placement's
        if est.ekf.mode == MODE_TAUT:
            seen.append((s.time_usec * 1e-6, est.wind_accuracy(), math.hypot(*est.wind()), est.wind_taut_mps))

    feed(est, samples, each=watch)
    assert len(seen) > 1000, len(seen)
    entry = seen[0][0]
    placed = seen[0][3]
    assert placed > 1.0 and placed == pytest.approx(seen[0][2], rel=0.2), seen[0]  # the static balance's wind
    for t, acc, speed, placement in seen:
        assert placement == placed  # one placement
        assert acc >= placement_settling_wind(t - entry, max(speed, placed)) * (1.0 - 1e-9), (t - entry, acc, speed)


@pytest.mark.parametrize("core", ["py", "c"])
def test_a_join_in_flight_is_a_placement_at_its_first_sample(core):
    """A filter that starts while the balloon is up (first sample 150 s after the sender's boot) places it on the
    tether at that sample: the settling and the force balance's start count from there (both cores). Placed at the
    filter's time before it (0), the settling was over from the first step and the force balance judged the join's own
    convergence at once."""
    from firmware_py.estimator.consistency import placement_settling_wind

    samples, _ = stream("paper-reference", 160.0, 11)
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    first = samples[15000]
    feed(est, samples[15000:15100])
    assert est.ekf.mode == MODE_TAUT and est.ekf.time_taut_us == first.time_usec, (est.ekf.time_taut_us, first)
    assert est.wind_taut_mps > 0.5  # the join's static balance put a wind (paper-reference: 3 m/s)
    assert est.wind_accuracy() >= placement_settling_wind(1.0, max(math.hypot(*est.wind()), est.wind_taut_mps))


def rocking_in_place(seconds: float, t0_s: float = 150.0):
    """A sender that only turns, at rest where it stands (no acceleration): 7 deg of pitch with 5 deg of rocking at
    0.2 Hz and 4 deg of roll at 0.13 Hz, 100 Hz, its readings exact (the specific force gravity's reaction, the rates
    the rotation's, the field's 0.2 G north and 0.45 G down in the body's axes); its first sample ``t0_s`` after the
    sender's boot (a join in flight). Yields (t_us, ax, ay, az, gx, gy, gz, mx, my, mz)."""
    g, field = np.array([0.0, 0.0, -9.80665]), np.array([0.2, 0.0, 0.45])
    for k in range(int(seconds * 100)):
        t = k / 100.0
        w1, w2 = 2.0 * math.pi * 0.2, 2.0 * math.pi * 0.13
        th, th_d = math.radians(7.0 + 5.0 * math.sin(w1 * t)), math.radians(5.0 * w1 * math.cos(w1 * t))
        ph, ph_d = math.radians(4.0 * math.sin(w2 * t)), math.radians(4.0 * w2 * math.cos(w2 * t))
        cp, sp, ct, st = math.cos(ph), math.sin(ph), math.cos(th), math.sin(th)
        r = np.array([[ct, st * sp, st * cp], [0.0, cp, -sp], [-st, ct * sp, ct * cp]])  # body -> NED, yaw 0
        f, m = r.T @ g, r.T @ field
        yield (int((t0_s + t) * 1e6), *f, ph_d, th_d * cp, -th_d * sp, *m)


@pytest.mark.parametrize("core", ["py", "c"])
def test_a_sender_that_only_turns_is_not_confirmed_as_a_balloon(core):
    """A join in flight is confirmed by the balloon's acceleration across its rope, in NED (control._confirm). A sender
    rocking in place (a drone on the ground, a board in the hand) moves its specific force in its own axes by 0.6-0.9
    m/s^2, all of it the gyro's rotation, which the filter's attitude explains: judged in the body's axes it was
    confirmed within the two minutes, a balloon on its tether stated where there is none. In NED its
    specific force is gravity's alone: it stays unconfirmed, and the accuracy says the wind is not known (both
    cores)."""
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    body = []
    for k, s in enumerate(rocking_in_place(120.0)):
        if k % 5 == 0:
            est.on_baro(s[0], 1000.0, 20.0)
        est.on_imu(*s)
        body.append(s[1:3])
    assert est.ekf.mode == MODE_TAUT and est.unconfirmed
    assert np.std(np.array(body), axis=0).max() > 0.5  # the body's axes move: the rule in them would be fooled
    assert est.wind_accuracy() ** 2 >= np.hypot(*est.wind()) ** 2 + 1.0 - 1e-9


@pytest.mark.parametrize("core", ["py", "c"])
def test_a_swing_towards_calm_does_not_take_the_settling_with_it(core):
    """A second after the taut entry the estimate swung to calm (the wind state set to 0): what the placement has
    still to settle keeps the scale of the wind the placement put (both cores), not the estimate's 0."""
    from firmware_py.estimator.consistency import placement_settling_wind

    samples, _ = stream("paper-reference", 60.0, 11)
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    entry = []

    def watch(s) -> None:
        if est.ekf.mode == MODE_TAUT and not entry:
            entry.append(s.time_usec)

    feed(est, samples, each=watch)
    assert entry, "never taut"
    i = next(k for k, s in enumerate(samples) if s.time_usec >= entry[0] + 1_000_000)
    est = Estimator(Design(), replace(FilterConfig(), core=core))
    feed(est, samples[: i + 1])
    placed = est.wind_taut_mps
    assert placed > 1.0, placed
    est.ekf.x[WIND_N] = est.ekf.x[WIND_E] = 0.0
    since = (samples[i].time_usec - est.ekf.time_taut_us) * 1e-6
    assert 0.9 < since < 1.2, since
    assert est.wind_accuracy() >= placement_settling_wind(since, placed) * (1.0 - 1e-9)
    assert placement_settling_wind(since, placed) > 1.5 * placement_settling_wind(since, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_firmware_restarted_in_flight_finds_the_wind(seed):
    """A firmware that boots while the balloon is up (first sample 150 s after the sender's boot)
    starts taut from the tilt, not from the ground, and finds the wind."""
    samples, truth = stream("paper-reference", 300.0, seed)
    est = Estimator(Design())
    rows = feed(est, samples[15000:], record=True)
    assert est.counters.mode_switches == 1 and est.ekf.mode == MODE_TAUT
    late = slice(6000, None)  # after 60 s
    err = np.hypot(rows[late, 1] - truth["wind_n"][21000:], rows[late, 2] - truth["wind_e"][21000:])
    assert np.sqrt(np.mean(err**2)) < 0.6
    assert est.height_m() == pytest.approx(truth["height_m"][-1], abs=3.0)
    check_covariance(est.ekf.P)


def _azimuth_turn(r: np.ndarray, axis: np.ndarray, angle: float) -> float:
    """How far a rotation by ``angle`` about ``axis`` (Rodrigues) turns the horizontal azimuth of ``-r``."""
    k = axis / np.linalg.norm(axis)
    rr = r * math.cos(angle) + np.cross(k, r) * math.sin(angle) + k * (k @ r) * (1.0 - math.cos(angle))
    return (math.atan2(-rr[1], -rr[0]) - math.atan2(-r[1], -r[0]) + math.pi) % (2.0 * math.pi) - math.pi


@pytest.mark.parametrize("inclination_deg, declination_deg", [(66.0, 3.0), (-40.0, -15.0), (20.0, 0.0)])
def test_the_lean_bias_turns_the_lean_as_the_field_geometry_says(inclination_deg, declination_deg):
    """The tilt's systematic error d on the taut balloon (consistency.lean_bias_wind) against the rotations
    themselves: the magnetometer holds all but the rotation about the field, which the accelerometer holds
    through its tilt (cos I of it), so d is a rotation d / cos I about the field, and d about the horizontal
    across it; each turns the balloon's body axis (along the rope) and with it the lean's azimuth, which is
    the wind's direction. Blown away from the field's horizontal direction the rope lies closer to the field,
    and the error is smaller than blown towards it; in calm air (a small lean) the geometry drops out."""
    from firmware_py.estimator.consistency import lean_bias_wind

    inc, dec = math.radians(inclination_deg), math.radians(declination_deg)
    b = np.array([math.cos(inc) * math.cos(dec), math.cos(inc) * math.sin(dec), math.sin(inc)])
    across = np.array([-math.sin(dec), math.cos(dec), 0.0])
    field = tuple(0.5 * b)
    lift_n, c, d = 20.0, 0.6, 1e-5
    results = {}
    for speed in (1.0, 6.0):
        for az_deg in range(0, 360, 30):
            az = math.radians(az_deg)  # the wind blows towards az; the balloon leans that way
            lean = math.atan(c * speed * speed / lift_n)
            rope = np.array([-math.sin(lean) * math.cos(az), -math.sin(lean) * math.sin(az), math.cos(lean)])
            turn = math.hypot(_azimuth_turn(rope, b, d / math.cos(inc)), _azimuth_turn(rope, across, d))
            along = lift_n * d / (2.0 * c * speed)
            expected = math.hypot(speed * turn, along)
            got = lean_bias_wind(speed * math.cos(az), speed * math.sin(az), lift_n, c, d, field)
            assert got == pytest.approx(expected, rel=1e-3), (speed, az_deg)
            results[speed, az_deg] = got
    # towards the field's horizontal direction (the rope from the balloon points away from it) against away
    towards = max(results[6.0, a] for a in range(0, 360, 30) if math.cos(math.radians(a) - dec) > 0.8)
    away = min(results[6.0, a] for a in range(0, 360, 30) if math.cos(math.radians(a) - dec) < -0.8)
    assert (towards > 1.5 * away) == (inclination_deg > 0.0)
    # the field unknown (NaN before it is learnt): the plain lean, d / tan(lean) across
    plain = lean_bias_wind(6.0, 0.0, lift_n, c, d, (math.nan, math.nan, math.nan))
    assert plain == pytest.approx(lift_n * d / (c * 6.0) * math.sqrt(1.25))
