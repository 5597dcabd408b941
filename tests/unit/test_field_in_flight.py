"""The earth field learnt again on the taut tether (magnetometer.learn_field_in_flight): a balloon with a hard-iron
offset that turned once released has a field the boot's is not (it replaces it, and it is the one the balloon
measures in flight); a link that loses a tenth of the samples, and every sample of the window's first half second,
learns the same field; a balloon whose field is the boot's keeps the boot's; a field replaced states the heading it
cannot see."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
from pytest import approx

from firmware_py.estimator.aid_sources import magnetometer
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.params import FIELD_CHANGE_GAUSS
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation


def flown(name: str, drop: frozenset[int] = frozenset()) -> dict:
    """A flight of 130 s on the Python core, the IMU samples numbered in ``drop`` left out: the field after the boot
    and at the end, the sample that opened the window, the magnetometer's mean |m| over the last 20 s."""
    sc = SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, 130.0, 3)
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    out: dict = {"boot": None, "opened": None, "m": []}
    for i, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        if i not in drop:
            est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if out["boot"] is None and est.ekf.mode != 0:
            out["boot"] = tuple(est.field_ned)
        if out["opened"] is None and est._field_window == 1:
            out["opened"] = i
        if i >= 11_000:
            out["m"].append(math.hypot(*s.mag))
    assert est._field_window & 7 == 4  # both windows have closed
    out["after"] = tuple(est.field_ned)
    out["heading_var"] = est.field_heading_var
    wn, we = est.wind()
    out["speed"], out["accuracy"] = math.hypot(wn, we), est.wind_accuracy()
    est.field_heading_var = 0.0
    out["accuracy_without"] = est.wind_accuracy()
    return out


def inclination(f) -> float:
    return math.degrees(math.atan2(f[2], math.hypot(f[0], f[1])))


def test_a_turned_hard_iron_has_its_field_learnt_again_even_through_a_lossy_link():
    clean = flown("field-turning-hard-iron")
    assert math.dist(clean["boot"], clean["after"]) > FIELD_CHANGE_GAUSS  # replaced
    assert abs(math.hypot(*clean["after"]) - np.mean(clean["m"])) < 0.002  # the field of the balloon's heading
    rng = np.random.default_rng(7)
    first = clean["opened"]
    drop = frozenset(rng.choice(13_000, 1_300, replace=False).tolist()) | frozenset(range(first - 10, first + 50))
    lossy = flown("field-turning-hard-iron", drop)
    assert lossy["opened"] > first  # the window's first samples were lost
    assert math.dist(clean["after"], lossy["after"]) < 0.002  # a lost first sample once kept the boot's sums
    assert abs(inclination(clean["after"]) - inclination(lossy["after"])) < 0.3


def test_a_field_the_boots_can_be_is_kept():
    out = flown("field-rope")
    assert out["after"] == out["boot"]
    assert out["heading_var"] == 0.0


def test_a_replaced_field_states_the_heading_it_cannot_see():
    """The window sees the change of the field's horizontal magnitude and of its down component; an offset fixed in
    the body that turned with the balloon changed it as much across the field's horizontal direction, unseen, which
    turns the heading by |change| / B_h: that, in the stated accuracy, as a wind across it."""
    out = flown("field-turning-hard-iron")
    b, a = out["boot"], out["after"]
    change = math.hypot(math.hypot(a[0], a[1]) - math.hypot(b[0], b[1]), a[2] - b[2])
    assert math.sqrt(out["heading_var"]) == approx(change / math.hypot(a[0], a[1]))
    assert math.degrees(math.sqrt(out["heading_var"])) > 2.0  # the 0.04 G offset turned 60 deg
    across = out["speed"] * math.sqrt(out["heading_var"])
    assert out["accuracy"] == approx(math.hypot(out["accuracy_without"], across))


def test_a_field_rejected_from_a_sample_it_was_fused_is_a_jump_and_after_a_silence_the_attitudes():
    """magnetometer.watch_field on a settled taut flight: a run of rejections that began as the field was fused holds
    the rows' recover at the gate (its run set back) until it has lasted FIELD_JUMP_REJECTED_S, then is a jump; one
    that began after the magnetometer fell silent for longer (a heading the gyro alone held, which may have drifted
    past the gate) is left to the recover, which walks the attitude back to the field: no jump, nothing held."""
    sc = SCENARIOS["field-rope"]
    sim = Simulation(sc.design, sc.wind, sc.truth, 60.0, 3)
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    for s in sim.samples():
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
    assert est._field_window & magnetometer.FIELD_WINDOW_STATE and est.counters.field_jumps == 0  # settled, armed
    m = s.mag
    now = est.ekf.time_us
    for unfused_us, jumps, held in ((600_000, 0, True), (1_000_000, 1, True), (5_000_000, 0, False)):
        trial = copy.deepcopy(est)
        status = trial.mag_status[0]
        status.consecutive_rejects = trial.schedule.mag_recover - 1
        status.time_last_fuse_us = now - unfused_us
        assert magnetometer.watch_field(trial, *m) == bool(jumps), unfused_us
        assert trial.counters.field_jumps == jumps, unfused_us
        assert (status.consecutive_rejects == 0) == held, unfused_us  # the run set back: the recover held
