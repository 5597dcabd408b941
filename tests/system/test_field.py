"""The real world (the field-* scenarios): the lumped rope with its drag, vertical air, biases. The
firmware is told the design and nothing else; it must be right, or say it is unsure.

CI-sized flights (200-240 s, two seeds): the benchmarks (benchmarks/bench_accuracy.py) fly them longer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from balloon_core.config import BalloonConfig, Design, TetherConfig
from balloon_core.score import score
from firmware_py.core_c import new_core
from firmware_py.estimator.state import FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation
from sim_hil.wind import WindConfig

START_S = 90.0
PAPER_ROPE = FilterConfig(rope_model="paper", rope_normal_cd=0.0)  # the paper's rope in the filter


def fly(design, wind, truth, cfg, duration, seed, fw_design=None):
    """Simulate ``design`` and run the firmware, given ``fw_design`` (default: the same design), on it.
    Rows: wind N, E, stated accuracy, misfit flagged, accuracy factor."""
    sim = Simulation(design, wind, truth, duration, seed)
    est, _ = new_core(fw_design or design, cfg)  # the C core: held equal to the Python one (test_lockstep)
    rows = []
    for s in sim.samples():
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        rows.append((*est.wind(), est.wind_accuracy(), est.consistency.flags != 0, est.consistency.inflation))
    truth_t = {c: sim.truth[:, k] for k, c in enumerate(TRUTH_COLUMNS)}
    return np.array(rows), truth_t, est


def judge(rows, truth):
    """Mean speed error (fraction), mean direction error (deg), RMS error / RMS accuracy, share beyond 3x."""
    sel = truth["time_s"] > START_S
    e = rows[sel]
    tn, te = truth["wind_n"][sel], truth["wind_e"][sel]
    speed = np.hypot(e[:, 0].mean(), e[:, 1].mean()) / np.hypot(tn.mean(), te.mean()) - 1.0
    ang = np.degrees(np.arctan2(e[:, 1].mean(), e[:, 0].mean()) - np.arctan2(te.mean(), tn.mean()))
    ang = (ang + 180.0) % 360.0 - 180.0
    err = np.hypot(e[:, 0] - tn, e[:, 1] - te)
    ratio = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(e[:, 2] ** 2))
    beyond = float(np.mean(err > 3.0 * e[:, 2]))
    return speed, ang, ratio, beyond


@pytest.fixture(scope="module")
def field_rope_flights():
    sc = SCENARIOS["field-rope-multisine"]
    out = {}
    for seed in (2, 7):
        for label, cfg in (("catenary", sc.filter), ("paper", PAPER_ROPE)):
            rows, truth, est = fly(sc.design, sc.wind, sc.truth, cfg, 240.0, seed)
            sel = truth["time_s"] > START_S
            rms = float(np.sqrt(np.mean((rows[sel, 0] - truth["wind_n"][sel]) ** 2
                                        + (rows[sel, 1] - truth["wind_e"][sel]) ** 2)))  # fmt: skip
            out[label, seed] = (judge(rows, truth), est, rms)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 7])
def test_real_rope_is_measured_and_a_paper_rope_filter_says_it_is_worse(field_rope_flights, seed):
    """The real rope's flight through the filter's catenary is measured: within 7 % and 4 deg, honest. The same flight
    through the paper's rope (a filter whose rope is not the truth's) reads the wind 1.3-1.4 times worse (RMS), and
    must say so: its stated accuracy larger by as much, no more than 5 % beyond 3 sigma. It once stated the
    catenary's accuracy (error/accuracy 1.64-1.66, 4.4-6.2 % beyond 3 sigma), until the force balance's mean was
    judged against the variance a consistent filter's mean has (consistency.balance_nis): 1.10-1.15, none."""

    def measured(speed, ang, ratio, beyond, est) -> bool:
        return (abs(speed) < 0.07 and abs(ang) < 4.0 and 0.5 < ratio < 1.6 and beyond <= 0.05
                and est.counters.taut_resets <= 1)  # fmt: skip

    (speed, ang, ratio, beyond), est, rms = field_rope_flights["catenary", seed]
    assert measured(speed, ang, ratio, beyond, est), (speed, ang, ratio, beyond, est.counters.taut_resets)
    (_, _, p_ratio, p_beyond), _, p_rms = field_rope_flights["paper", seed]
    # worse, and stated so: the error's growth over the catenary's is in the stated accuracy (the ratio's change
    # within a fifth of it), and honest
    assert p_rms > 1.2 * rms, (p_rms, rms)
    assert p_ratio < 1.6 and p_beyond <= 0.05, (p_ratio, p_beyond)
    assert p_ratio <= 1.2 * ratio, (p_ratio, ratio)


@pytest.mark.slow
def test_outside_the_model_the_stated_accuracy_covers_the_error():
    """Truths outside the model. (1) The balloon's Cd and the rope's both 30 % above the design's (a
    balloon in the drag crisis, a braided rope): the filter learns the balloon's in the ascent; what it
    cannot learn, its stated accuracy must cover. (2) 6 m/s class-B gusts on the real rope: the rope
    moves the balloon in ways the rod does not explain; the consistency monitor must say so (a status
    flag) and grow the stated accuracy to cover the error."""
    sc = SCENARIOS["field-rope"]
    heavy = replace(sc.design, balloon=replace(sc.design.balloon, drag_coefficient=0.39))
    rows, truth, _ = fly(heavy, sc.wind, replace(sc.truth, rope_normal_cd=1.43), sc.filter, 200.0, 4, sc.design)
    _, _, ratio, beyond = judge(rows, truth)
    assert ratio < 1.4 and beyond <= 0.05, (ratio, beyond)

    g = SCENARIOS["field-gusty-6"]
    rows, truth, _ = fly(g.design, g.wind, g.truth, g.filter, 200.0, 3)
    late = truth["time_s"] > START_S
    assert rows[late, 3].mean() > 0.5 and np.median(rows[late, 4]) > 1.5  # flagged, accuracy raised
    _, _, ratio, beyond = judge(rows, truth)
    assert 0.5 < ratio < 1.4 and beyond <= 0.05, (ratio, beyond)


@pytest.mark.slow
def test_weather_moves_the_barometer_not_the_wind():
    """The ground pressure falls 2 hPa/h (16 m of apparent climb an hour): the barometer offset state
    takes it, the wind stays and the filter does not re-place itself."""
    sc = SCENARIOS["field-weather"]
    truth = replace(sc.truth, pressure_drift_hpa_h=-12.0)  # six hours of a front in 10 minutes' flight
    rows, t, est = fly(sc.design, WindConfig(kind="steady"), truth, sc.filter, 400.0, 3)
    speed, ang, ratio, beyond = judge(rows, t)
    assert abs(speed) < 0.07 and abs(ang) < 4.0 and beyond <= 0.05, (speed, ang, beyond)
    assert est.counters.taut_resets == 0 and est.counters.baro_resets == 0
    # 400 s at -12 hPa/h: 11 m of apparent climb, taken by the offset
    assert float(est.ekf.x[17]) > 6.0


@pytest.mark.slow
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    radius=st.floats(0.9, 1.3),
    length=st.floats(60.0, 300.0),
    wind=st.floats(1.0, 8.0),
)
def test_designs_near_the_envelope_stay_healthy_on_the_real_rope(radius, length, wind):
    """Small balloons, long ropes, strong winds on the lumped rope: the filter stays finite, its
    covariance symmetric positive definite, its accuracy positive; placements are counted, not endless."""
    design = Design(balloon=BalloonConfig(radius_m=radius), tether=TetherConfig(length_m=length))
    b = design.balloon
    lift = (1.2 * b.volume_m3 - b.mass_kg - design.tether.linear_density_kg_m * length) * 9.81
    if lift < 1.0:  # no lift at this length: not a flight
        return
    truth = TruthConfig(physics_hz=400.0) if length < 80.0 else TruthConfig()
    rows, _, est = fly(design, WindConfig(mean_mps=wind), truth, FilterConfig(), 90.0, 1)
    assert np.all(np.isfinite(rows)) and np.all(rows[:, 2] > 0.0)
    P = est.ekf.P
    assert np.allclose(P, P.T, atol=1e-9)
    assert np.linalg.eigvalsh(P).min() > 0.0
    assert est.counters.taut_resets <= 10


def fly_hour(truth: TruthConfig, filt: FilterConfig, seed: int):
    """``field-all``'s design and wind for an hour with ``truth`` and ``filt``: the simulation, the estimator, its rows
    (time s, wind N, wind E, stated accuracy) at 10 Hz and the truth's time and wind."""
    sc = SCENARIOS["field-all"]
    sim = Simulation(sc.design, sc.wind, truth, 3600.0, seed)
    est, _ = new_core(sc.design, filt)
    rows = []
    for s in sim.samples():
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if s.time_usec % 100_000 == 0:
            rows.append((s.time_usec * 1e-6, *est.wind(), est.wind_accuracy()))
    truth_wind = tuple(sim.truth[:, TRUTH_COLUMNS.index(c)] for c in ("time_s", "wind_n", "wind_e"))
    return sim, est, np.array(rows), truth_wind


def ten_minute_scores(t, n, e, acc, truth_wind, first_s: float) -> list:
    """``balloon_core.score.score`` of each 10-minute window of the hour from ``first_s``."""
    return [score(t[t < a + 600], n[t < a + 600], e[t < a + 600], acc[t < a + 600], *truth_wind, float(a))
            for a in range(int(first_s), 3600, 600)]  # fmt: skip


@pytest.mark.slow
def test_an_hour_of_wandering_accelerometer_bias_is_followed():
    """``field-all`` for an hour: among everything else its accelerometer's biases wander (0.001 m/s^2 per sqrt(s),
    0.06 m/s^2 in an hour). Along the body's z (the rope) a bias is read as the rope's pull, 3 % of the wind per 0.02
    m/s^2; the filter learnt it on the ground only and read the wind up to 17 % low in a 10-minute window, stated 2.5
    times too confidently. Followed in flight from the specific force along itself (accel.fuse_bias_magnitude): the
    bias within 3 sigma of the truth's after the hour, its sigma under what the walk alone leaves (0.06 m/s^2), every
    10-minute mean speed after the first within 8 % and honest (error /
    accuracy at most 1.6: the filter that kept the ground's value made 17 % and 2.5 in the same windows). The hour's
    constant true mean fails it; the truth delayed by 4 s passes, as it should: this judges the mean's drift over
    the hour and the bias, the band's dynamics are the other field tests'."""
    from firmware_py.estimator.state import ABIAS_Z

    sc = SCENARIOS["field-all"]
    sim, est, r, truth_wind = fly_hour(sc.truth, sc.filter, 1)
    tt, tn, te = truth_wind
    bias, sigma = float(est.ekf.x[ABIAS_Z]), float(est.ekf.P[ABIAS_Z, ABIAS_Z]) ** 0.5
    assert abs(bias - sim.sensors.accel_bias[2]) < 3.0 * sigma and sigma < 0.035, (bias, sim.sensors.accel_bias[2],
                                                                                  sigma)  # unfollowed: 0.06
    late = tt >= 600.0
    constant = (np.full_like(tn, tn[late].mean()), np.full_like(te, te[late].mean()), np.interp(tt, r[:, 0], r[:, 3]))

    def windows_ok(t, n, e, acc) -> bool:
        scores = ten_minute_scores(t, n, e, acc, truth_wind, 600.0)
        return all(abs(s.speed_error_pct) <= 8.0 and s.error_ratio <= 1.6 for s in scores)

    assert windows_ok(r[:, 0], r[:, 1], r[:, 2], r[:, 3])
    assert not windows_ok(tt, *constant)  # the hour's true mean: 29 % off in the first window, error/accuracy 6.4


@pytest.mark.slow
def test_a_days_walk_of_the_horizontal_bias_in_an_hour_is_followed():
    """``field-all`` with its accelerometer biases walking at 0.002 m/s^2 per sqrt(s), the filter told so: in an hour
    they go as far as the default's 0.001 in four (0.12 m/s^2, a field day's temperature swing). Along the field's
    horizontal direction no tilt can take a horizontal bias (the field holds the attitude about east), so the filter
    read it as a force across the rope and turned the wind: 11.8 deg off at error/accuracy 2.1 in a 10-minute window
    of this flight (seed 4; a four-hour field-all at the default walk: 12.6 deg at 3.5). Followed from the innovation
    along that direction (accel.follow_horizontal_bias): every 10-minute window from 20 minutes on (before, the walk
    has gone little and the loop, 20 minutes long, has not closed on it) within 8 deg (the issue's
    every-flight bar) and honest (error/accuracy at most 1.5). The followed bias lies along magnetic north only. The
    truth delayed by 4 s passes, as it should (this judges the mean's direction over the hour); the hour's constant
    true mean does not, so the bars can fail."""
    sc = SCENARIOS["field-all"]
    walk = 0.002
    sim, est, r, truth_wind = fly_hour(replace(sc.truth, accel_bias_walk_mps2_rt_s=walk),
                                       replace(sc.filter, accel_bias_walk_mps2_rt_s=walk), 4)  # fmt: skip
    tt, tn, te = truth_wind

    def worst(t, n, e, acc) -> tuple[float, float]:
        scores = ten_minute_scores(t, n, e, acc, truth_wind, 1200.0)
        return max(abs(s.direction_error_deg) for s in scores), max(s.error_ratio for s in scores)

    direction, ratio = worst(r[:, 0], r[:, 1], r[:, 2], r[:, 3])
    assert direction <= 8.0 and ratio <= 1.5, (direction, ratio)
    from balloon_core.rotation import quat_from_euler, rotation

    att = np.radians([sim.truth[-1, TRUTH_COLUMNS.index(c)] for c in ("roll_deg", "pitch_deg", "yaw_deg")])
    followed = np.reshape(rotation(*quat_from_euler(*att)), (3, 3)) @ np.array([*est.accel_hbias, 0.0])  # NED
    assert abs(followed[1]) < 0.01 < abs(followed[0]), followed  # north: the field's horizontal direction
    late = tt >= 600.0
    const = worst(tt, np.full_like(tn, tn[late].mean()), np.full_like(te, te[late].mean()),
                  np.interp(tt, r[:, 0], r[:, 3]))  # fmt: skip
    assert not (const[0] <= 8.0 and const[1] <= 1.5), const
