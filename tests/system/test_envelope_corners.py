"""The envelope's corners (benchmarks/bench_envelope.py found them failing), kept short, judged by their
worst case: every wind direction of one multisine flight on the paper's and the real rope (one in nine
locked 100 deg off at the taut entry), a balloon near its lift limit on a short real rope (a stiff rope's
modes aliased into the accelerometer), a calm steady wind (a degree of lean: honest, not confident), a
multisine in light air (the wind meanders by half its speed: followed, and honestly stated; over ten minutes it
turns the heading, and says so), the wind that blows the balloon towards the earth field's horizontal direction (in
either hemisphere: the rope turns with the rotation the magnetometer cannot see), a release into turbulence on a short
rope (the ascent learnt the drag from a wind it had only just guessed), a front (the wind turns by 90-120 deg in 10-60
s: followed, not lagged), the taut entry's snap (its half minute stated, not yet settled) and the minutes after it (a
state that swings across its rope, light air on a long one).

Each judgement is also passed through two references that must fail it: the constant true mean and the
truth delayed by 4 s, both with the filter's own stated accuracy. The C core and the compiled truth: a
flight takes about a second."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from balloon_core.score import on_grid, response, score
from benchmarks import bench_envelope as be
from firmware_py.estimator.state import MODE_TAUT
from sim_hil.scenarios import SCENARIOS
from study.case import fly
from study.spec import build, scenario_sections
from tools import sensor_faults

START_S = 90.0
DURATION_S = 240.0
DELAY_S = 4.0
RESPONSE_HZ = (0.02, 0.05)  # the band's lines of the multisine where the complex error is judged (H_ERR_MAX)
H_ERR_MAX = 0.8  # |H - 1| there, the worst axis: the 4 s delay's is 0.5 and 1.18


def flights(p: dict[str, Any], duration_s: float = DURATION_S, start_s: float = START_S) -> dict[str, dict[str, float]]:
    """The estimate and the two references, each scored against the truth (after ``start_s``)."""
    return judged(be.sections_of(p), p["seed"], duration_s, start_s)


def judged(
    sections: dict[str, Any], seed: int, duration_s: float, start_s: float, extra: Callable | None = None
) -> dict[str, dict[str, float]]:
    """``flights`` for a flight's sections as they are (a scenario's, changed); ``extra(wind, t, n, e, truth)`` more
    metrics of each candidate (its times and NED wind) to add to its own."""
    design, wind, truth_cfg, filt = build(sections)
    rows, truth, est = fly(design, wind, truth_cfg, filt, duration_s, seed)
    t, tn, te = truth["time_s"], truth["wind_n"], truth["wind_e"]
    out = {}
    for name, (tt, en, ee) in candidates(rows, truth, start_s).items():
        acc = np.interp(tt, rows[:, 0], rows[:, 3])
        sc = score(tt, en, ee, acc, t, tn, te, start_s)
        _, gn, ge, ac, gtn, gte = on_grid(tt, en, ee, acc, t, tn, te, start_s)
        h_err = []  # a multisine's lines only: elsewhere a single-frequency fit is not the wind's response
        if wind.kind == "multisine":
            h = response(tt, en, ee, t, tn, te, RESPONSE_HZ, start_s, extra_hz=wind.multisine_hz)
            h_err = [abs(v - 1.0) for f in RESPONSE_HZ for v in h[f].values() if v is not None]
        out[name] = {
            "dir": abs(sc.direction_error_deg), "speed": abs(sc.speed_error_pct), "skill": sc.band_skill,
            "err_acc": sc.error_ratio, "beyond_3sigma": float(np.mean(np.hypot(gn - gtn, ge - gte) > 3.0 * ac)),
            "replacements": float(est.counters.taut_resets), "h_err": max(h_err) if h_err else math.nan,
        }  # fmt: skip
        if extra is not None:
            out[name].update(extra(wind, tt, en, ee, truth))
    return out


def candidates(rows: np.ndarray, truth: dict[str, np.ndarray], start_s: float, end_s: float = math.inf):
    """(times, north, east) of the estimate and the two references: the constant true mean over ``start_s`` to
    ``end_s``, the truth DELAY_S late."""
    t, tn, te = truth["time_s"], truth["wind_n"], truth["wind_e"]
    w = (t >= start_s) & (t <= end_s)
    return {
        "estimate": (rows[:, 0], rows[:, 1], rows[:, 2]),
        "constant": (t, np.full_like(tn, tn[w].mean()), np.full_like(te, te[w].mean())),
        "delayed": (t + DELAY_S, tn, te),
    }


def base(**kw: Any) -> dict[str, Any]:
    p = dict(from_deg=0.0, mean_mps=6.0, wind_kind="multisine", rope_model="paper", radius_m=1.25, tether_m=128.0,
             pressure_drift_hpa_h=0.0, bias_scale=0.35, sensor_grade="table2", seed=76402)  # fmt: skip
    p.update(kw)
    return p


def fluctuating_ok(m: dict[str, float], min_skill: float = 0.25) -> list[str]:
    """What a fluctuating wind's estimate must meet: the mean's direction and speed, the band's skill (a
    floor: the envelope's target is 0.6, which the flights from 160-200 deg miss: 0.52 from 160 deg on the
    real rope (0.46 before the alignment's column about the field's axis), 0.1 with seeds 3 and 7), honesty
    (error / stated accuracy, and the share beyond 3 sigma: at most 5 %, where the envelope's target is 3 %; seeds
    76402, 3 and 7 of every direction reach 3.0 %, 22 % while the gyro bias walked at 0.005 deg/s per sqrt(s) and
    the yaw followed the force model's misfit), no taut re-placement. The constant true mean has no skill at all."""
    bad = []
    if not m["dir"] <= 3.0:
        bad.append(f"direction {m['dir']:.1f} deg")
    if not m["speed"] <= 4.0:
        bad.append(f"speed {m['speed']:.1f} %")
    if not m["skill"] >= min_skill:
        bad.append(f"band skill {m['skill']:.2f}")
    if not 0.35 <= m["err_acc"] <= 2.1:
        bad.append(f"error/accuracy {m['err_acc']:.2f}")
    if m["h_err"] > H_ERR_MAX:  # NaN (not a multisine, or no line there): not judged
        bad.append(f"|H - 1| {m['h_err']:.2f} in the band")
    if not m["beyond_3sigma"] <= 0.05:
        bad.append(f"{100 * m['beyond_3sigma']:.0f} % beyond 3 sigma")
    if m["replacements"] > 0:
        bad.append(f"{m['replacements']:.0f} taut re-placements")
    return bad


@pytest.mark.parametrize("rope", ["paper", "lumped"])
def test_every_direction_of_a_multisine_flight(rope):
    """Nine directions of the same flight (6 m/s multisine, r = 1.25 m on 128 m, Table 2 sensors): each one
    within 3 deg and the envelope's 4 % (the real rope read 4-6 % low before the ascent stopped learning the
    drag where the rope's pull is not known), skilful, honest, no re-placement; the constant and the delayed
    truth fail."""
    worst: list[str] = []
    for d in range(0, 360, 40):
        m = flights(base(from_deg=float(d), rope_model=rope))
        worst += [f"from {d} deg: {b}" for b in fluctuating_ok(m["estimate"])]
        assert fluctuating_ok(m["constant"]), f"from {d}: the constant true mean passes"
        assert fluctuating_ok(m["delayed"]), f"from {d}: the truth delayed by {DELAY_S} s passes"
    assert not worst, "; ".join(worst)


@pytest.mark.parametrize("seed", [11, 13])
def test_the_wind_from_magnetic_south(seed):
    """A 3 m/s two-axis multisine on the real rope (r = 1.0 m on 100 m, Table 2 sensors) from the south, against the
    same flight from the north. Blown magnetically north, the rope from the balloon points 55 deg from the earth
    field, and the one rotation the magnetometer cannot see (about the field's axis) turns the rope's direction
    across the wind by 0.8 of it; from the north the rope lies along the field and the same rotation turns the
    balloon about its rope. With the attitude only a parameter of the alignment, the state followed that weakly held
    rotation and the estimate swung across the wind at the pendulum's period: 4.5 deg off, band skill 0.43-0.46,
    error/accuracy 1.5-1.6, 3.0-4.6 % beyond 3 sigma; now 0.4-1.3 deg, 0.68-0.69, 1.08-1.13, 0-0.2 %
    (tether.field_axis_row). Seed 12 is still the worst: 5.0 deg, 0.42, 1.46, 3.2 % (it was 7.0 deg, 0.26, 1.86,
    11 %). Ten minutes, judged from 120 s; the constant true mean and the truth delayed by 4 s fail."""

    def ok(x: dict[str, float]) -> bool:
        return (x["dir"] <= 3.0 and x["skill"] >= 0.55 and x["err_acc"] <= 1.33 and x["beyond_3sigma"] <= 0.03
                and x["replacements"] == 0)  # fmt: skip

    for from_deg in (180.0, 0.0):
        p = base(from_deg=from_deg, mean_mps=3.0, rope_model="lumped", radius_m=1.0, tether_m=100.0, bias_scale=0.5,
                 seed=seed)  # fmt: skip
        m = flights(p, duration_s=be.FULL_DURATION_S, start_s=120.0)
        assert ok(m["estimate"]), (from_deg, m["estimate"])
        assert not ok(m["constant"]) and not ok(m["delayed"]), from_deg


@pytest.mark.parametrize(("field_down_gauss", "from_deg"), [(0.45, 180.0), (-0.45, 0.0)])
def test_the_wind_that_blows_the_balloon_towards_the_field(field_down_gauss, from_deg):
    """`multisine` (the paper's balloon and rope, 3 m/s along the wind) blown towards the earth field's horizontal
    direction: in the northern hemisphere (the field down) from the south, in the southern (the field up) from the
    north. There the rope from the balloon points away from the field's axis and turns with the rotation about it
    that the magnetometer cannot see. Before the alignment's column about that axis both were confidently wrong
    (seeds 1 and 2: error/accuracy 1.8-2.4, 9-27 % beyond 3 sigma, skill 0.53-0.59); now 0.61-0.76, none beyond,
    0.60-0.71, as the other directions are. Seed 1, ten minutes from 120 s; the constant true mean (no skill) and the
    truth delayed by 4 s (error/accuracy 2.2) fail."""
    sections = scenario_sections(SCENARIOS["multisine"])
    sections["wind"]["from_deg"] = from_deg
    sections["truth"]["mag_field_z_gauss"] = field_down_gauss

    def ok(x: dict[str, float]) -> bool:
        return x["skill"] >= 0.5 and 0.5 <= x["err_acc"] <= 1.33 and x["beyond_3sigma"] <= 0.03 and x["dir"] <= 2.0

    m = judged(sections, 1, be.FULL_DURATION_S, 120.0)
    assert ok(m["estimate"]), m["estimate"]
    assert not ok(m["constant"]) and not ok(m["delayed"])


@pytest.mark.parametrize("from_deg", [0.0, 180.0])
def test_the_wind_along_the_field_at_the_magnetic_equator(from_deg):
    """`field-rope-multisine` from the north and the south where the earth field is horizontal (0.35 G north, none
    down): the one rotation the magnetometer cannot see is about north, a pure east-west tilt of a balloon blown along
    the meridian, across its lean. Held by the accelerometer's model rows alone, the attitude wandered 3-4 deg with
    the state's cross wind and position (2.9 m/s RMS, skill -0.15 to -4.2, 11-13 % beyond 3 sigma, the estimate
    swinging across at a two-minute period). The level rows (a tethered balloon does not accelerate on average) hold
    it: from the south skill 0.30, error/accuracy 0.98, 0.6 % beyond 3 sigma; from the north 0.13, 0.76, 2.6 % (weak,
    and said so). Seed 1, five minutes from 90 s; the constant true mean (no skill) and the truth delayed by 4 s
    (|H - 1| 1.18 at 0.05 Hz) fail."""
    sections = scenario_sections(SCENARIOS["field-rope-multisine"])
    sections["wind"]["from_deg"] = from_deg
    sections["truth"]["mag_field_h_gauss"] = 0.35
    sections["truth"]["mag_field_z_gauss"] = 0.0

    def ok(x: dict[str, float]) -> bool:
        return (x["skill"] >= 0.1 and x["h_err"] <= H_ERR_MAX and x["beyond_3sigma"] <= 0.03
                and 0.5 <= x["err_acc"] <= 1.33)  # fmt: skip

    m = judged(sections, 1, 300.0, START_S)
    assert ok(m["estimate"]), m["estimate"]
    assert not ok(m["constant"]) and not ok(m["delayed"])


def test_a_balloon_near_its_lift_limit_on_a_short_real_rope():
    """r = 0.88 m on 54 m of the real rope (20 % spare lift), Kaimal turbulence with vertical air at 4.2 m/s:
    the rope's stiff modes once aliased into 1.2 m/s^2 of false vertical acceleration (44 % low, 43 deg off).
    Kaimal's broad band: a 4 s delay keeps a skill of 0.5, so the skill asked is the envelope's 0.6."""
    m = flights(base(from_deg=102.7, mean_mps=4.25, wind_kind="kaimal", rope_model="lumped", radius_m=0.8824,
                     tether_m=53.58, pressure_drift_hpa_h=2.97, bias_scale=0.72, sensor_grade="tactical",
                     seed=662609))  # fmt: skip
    assert not fluctuating_ok(m["estimate"], 0.6), fluctuating_ok(m["estimate"], 0.6)
    assert fluctuating_ok(m["constant"], 0.6) and fluctuating_ok(m["delayed"], 0.6)


def test_a_calm_steady_wind_is_honest():
    """1.1 m/s steady on the paper's rope: the balloon leans 1 deg, and a tenth of a degree of tilt turns its
    azimuth by several degrees. The direction may be off; the stated accuracy must say so (error/accuracy
    0.5-2, nothing beyond 3 sigma), and a perfect constant or delayed truth, far below their stated accuracy,
    fails the same test."""
    m = flights(base(from_deg=164.5, mean_mps=1.13, wind_kind="steady", radius_m=1.2, tether_m=107.4,
                     pressure_drift_hpa_h=2.39, bias_scale=0.93, sensor_grade="tactical", seed=697092))  # fmt: skip

    def honest(x: dict[str, float]) -> bool:
        return 0.5 <= x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03 and x["speed"] <= 6.0

    assert honest(m["estimate"]), m["estimate"]
    assert math.isnan(m["estimate"]["skill"])  # a steady wind has no band to be skilful in
    assert not honest(m["constant"]) and not honest(m["delayed"])


LIGHT_AIR = {
    "lumped 1.13 m/s": dict(from_deg=127.97, mean_mps=1.131, rope_model="lumped", radius_m=1.5175, tether_m=79.44,
                            pressure_drift_hpa_h=-1.907, bias_scale=0.0364, sensor_grade="table2", seed=840974),
    "paper 1.48 m/s": dict(from_deg=208.13, mean_mps=1.477, radius_m=1.006, tether_m=93.64,
                           pressure_drift_hpa_h=-0.744, bias_scale=0.7927, sensor_grade="tactical", seed=820760),
    "paper 1.39 m/s": dict(from_deg=285.47, mean_mps=1.39, radius_m=1.4487, tether_m=88.31,
                           pressure_drift_hpa_h=-1.139, bias_scale=0.8785, sensor_grade="mems", seed=565112),
}  # fmt: skip


@pytest.mark.parametrize("name", LIGHT_AIR)
def test_a_multisine_in_light_air(name):
    """The multisine's 0.3 m/s lines in a 1.1-1.5 m/s mean: the wind meanders by half its speed, where the
    filter's noise for sigma_u = TI U expects a fifth. It once lagged (band skill 0, 24 % low), and said
    so too little (error/accuracy 1.8, 14 % beyond 3 sigma); its own turbulence now raises the noise. The floor of
    error/accuracy is 0.42: the attitude's slow error about the field's axis is stated at twice what the
    accelerometer's slow innovation shows of it (consistency.HEADING_MISFIT_RATIO), and in the paper's 1.39 m/s the
    error is 1.5 times it (0.32 deg, 0.51 stated): 0.47 where it was 0.51 (the lumped 1.13 m/s: 0.52 either way); and
    the tilt's systematic error carries the accelerometer's horizontal bias wandering since the boot
    (consistency.lean_bias_rad: 0.22 deg after these 240 s where it was 0.20): 0.45. The floor is now 0.28: in light
    air the measurements pull the balloon's velocity persistently, more than a consistent filter's would, and the
    force balance's factor (consistency.balance_nis) states it. Over ten minutes from 120 s the lumped 1.13 m/s and
    the paper's 1.39 m/s read 0.31 and 0.27 (0.31 and 0.28 before); over these 240 s they read 0.40 and 0.43 while the
    force balance's mean was judged against a mean of the variance the updates took, which lags the entry's settling,
    and 0.37 and 0.31 since it is judged against the variance a consistent filter's mean has (the estimate the
    same). The complex error in the band (|H - 1| at 0.02 and 0.05 Hz) is what the delayed truth fails."""

    def ok(x: dict[str, float]) -> bool:
        return (x["dir"] <= 5.0 and x["speed"] <= 12.0 and x["skill"] >= 0.4 and 0.28 <= x["err_acc"] <= 1.6
                and x["beyond_3sigma"] <= 0.03 and x["h_err"] <= H_ERR_MAX)  # fmt: skip

    m = flights(base(**LIGHT_AIR[name]))
    assert ok(m["estimate"]), m["estimate"]
    assert not ok(m["constant"]) and not ok(m["delayed"])


HEADING_TURNED = {  # the envelope's flights 187 and 151: the two-axis multisine in light air, the C_d drawn
    "lumped 1.10 m/s": dict(from_deg=247.5, mean_mps=1.102, rope_model="lumped", radius_m=1.1859, tether_m=121.27,
                            pressure_drift_hpa_h=1.0, bias_scale=0.2802, sensor_grade="table2", seed=467609,
                            cd_scale=0.835, rope_cd_scale=1.15),
    "paper 1.48 m/s": dict(from_deg=208.13, mean_mps=1.477, radius_m=1.006, tether_m=93.64,
                           pressure_drift_hpa_h=-0.744, bias_scale=0.7927, sensor_grade="tactical", seed=820760,
                           cd_scale=0.92, rope_cd_scale=0.744),
}  # fmt: skip


@pytest.mark.parametrize("name", HEADING_TURNED)
def test_light_air_that_turns_the_heading_says_so(name):
    """Ten minutes of a multisine swinging by half its 1.1-1.5 m/s mean: the force model's slow misfit turns the
    attitude about the magnetic field's axis (1.2 and 0.4 deg RMS), which only the accelerometer holds, and the
    lean's azimuth with it (the first: 22 deg off and 32 % low over the flight; its C_d 16 % below the design's).
    Where the heading's error was stated only from the information its sources fused, 5.2 and 4.0 % of the estimates
    were beyond 3 sigma; the accelerometer's slow innovation (consistency.heading_misfit_variance) now states it.
    The envelope's honesty bars: error/accuracy 0.5-2, at most 3 % beyond 3 sigma (2.5 and 1.4 % then). The floor is
    now 0.4: the force model does not balance where the heading turned, and the force balance's factor
    (consistency.balance_nis) states it (the first: 0.46 and none beyond 3 sigma, where it was 1.33 and 2.7 %)."""

    def honest(x: dict[str, float]) -> bool:
        return 0.4 <= x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03

    m = flights(base(**HEADING_TURNED[name]), duration_s=be.FULL_DURATION_S, start_s=120.0)
    assert honest(m["estimate"]), m["estimate"]
    if m["estimate"]["skill"] < 0.3:
        # no skill in the band (the first: -0.2), and the stated accuracy says so: it covers the wind's whole spread
        # about its mean (the constant true mean's error is within it), so no reference can be dishonest against it
        assert m["constant"]["err_acc"] <= 1.0, m["constant"]
    else:
        assert not honest(m["constant"]) and not honest(m["delayed"])


ASCENTS = {  # the balloon's C_d unlike its design's, as a user's would be
    "steady": dict(from_deg=299.53, mean_mps=4.85, wind_kind="steady", radius_m=1.1767, tether_m=130.5,
                   pressure_drift_hpa_h=0.274, bias_scale=0.1923, sensor_grade="mems", seed=552026, cd_scale=0.7996,
                   rope_cd_scale=1.1364),
    "gusts": dict(from_deg=316.41, mean_mps=7.27, wind_kind="gusts", rope_model="lumped", radius_m=1.4961,
                  tether_m=71.33, pressure_drift_hpa_h=-2.508, bias_scale=0.7242, sensor_grade="mems", seed=869505,
                  cd_scale=0.9843, rope_cd_scale=1.2696),
}  # fmt: skip


@pytest.mark.parametrize("name", ASCENTS)
def test_the_ascent_is_worth_what_the_turbulence_allows(name):
    """The free ascent's drag scale, weighed again once the taut flight has measured the turbulence
    (control._weigh_ascent): in steady air it is worth more than the 10 % it was capped at (the drag's share
    of the stated accuracy shrinks: 3.8 % on the scale with the design's 10 % prior and the scale's walk since
    the cap, where the cap left 7.5 %), in gusts less (a downdraft through the climb read as 34 % more drag
    here); in both the truth's C_d is within 3 sigma of it. Weighed once: the cap and the weighing are the two
    drag-scale re-placements."""
    from firmware_py.estimator.ekf import RESET_DRAG
    from firmware_py.estimator.state import DRAG

    p = base(**ASCENTS[name])
    design, wind, truth_cfg, filt = build(be.sections_of(p))
    _, _, est = fly(design, wind, truth_cfg, filt, 170.0, p["seed"])
    k, sigma = float(est.ekf.x[DRAG]), math.sqrt(float(est.ekf.P[DRAG, DRAG]))
    assert (sigma < 0.06) if name == "steady" else (sigma > 0.08), sigma
    assert abs(k - p["cd_scale"]) < 3.0 * sigma, (k, sigma)
    assert est.ekf.reset_counts[RESET_DRAG] == 2


def test_a_release_into_turbulence_does_not_learn_the_drag_from_a_wind_it_has_just_guessed():
    """A held-out corner (``python -m benchmarks.bench_envelope --quick --sample-seed 12``, flight 16): a small
    balloon (r = 0.85 m, 18 % spare lift) on 51 m of the paper's rope, released into a 5.3 m/s Kaimal wind, its C_d
    17 % above the design's. The ascent may learn the drag for 2 s only (then the rope's pull is not known), and
    learnt it just after the release, while the balloon still sat in the whole wind: the wind the state had taken
    from the first acceleration at rest (3 m/s off, stated to 0.2) read the drag scale 24 % low, claimed to 4 %. The
    wind read 11 % fast at error/accuracy 2.5, 21 % of it beyond 3 sigma. The climb tells the drag only where the air
    flows past the balloon mostly from above (params.ASCENT_AIRFLOW_RATIO): 5.6 % fast at 1.55, 1 % beyond 3 sigma.
    Held to the envelope's bounds (error/accuracy at most 2, at most 3 % beyond 3 sigma), within 8 % and band skill
    0.3; the constant true mean (no skill, 30 % beyond 3 sigma) and the truth 4 s late (10 % beyond) both fail."""
    p = base(from_deg=165.234, mean_mps=5.273, wind_kind="kaimal", rope_model="paper", radius_m=0.848, tether_m=51.17,
             pressure_drift_hpa_h=0.28, bias_scale=0.4531, sensor_grade="tactical", seed=670699, cd_scale=1.1694,
             rope_cd_scale=1.1355)  # fmt: skip
    m = flights(p, be.QUICK_DURATION_S, 120.0)

    def good(x: dict[str, float]) -> bool:
        return x["speed"] <= 8.0 and x["skill"] >= 0.3 and x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03

    assert good(m["estimate"]), m["estimate"]
    assert not good(m["constant"]) and not good(m["delayed"]), (m["constant"], m["delayed"])


@pytest.mark.parametrize("seed", [1, 2])
def test_the_paper_rope_in_class_b_gusts_keeps_its_lean(seed):
    """``gusty-6`` (6 m/s, IEC class B, the paper's world), 600 s: the balloon rocks on its rope by 0.2 rad, and
    the alignment's along noise follows its innovations. It once followed their mean square, so a lean drifting
    upright confirmed itself (0.4-0.8 rad innovations, never rejected), the barometer's offset took the height
    (46 m in five minutes, where the weather moves it metres an hour) and the wind fell to a sixth of the truth's,
    stated to 1 m/s (error/accuracy 4.7, band skill -1.6). The noise now follows their spread about their mean:
    a persistent along misfit says the state is off and pulls the lean back. The mean wind within 8 %, honest,
    skilful (the barometer's offset still ends 14 m off with seed 1: the rope model's height in the gusts). Honest
    from 0.35: the gusts' drag outruns the wind's state, the measurements pull the balloon back for seconds at a time,
    and the force balance's factor (consistency.balance_nis) states that too (0.42-0.51, where it was 0.6-0.7); and
    the rocking body leans 1-3 deg further than the model's pull for minutes, which the lean's misfit states
    (consistency.lean_misfit_wind: 0.39-0.48), the price of a blown-down balloon that says its wind is unknown."""
    from sim_hil.scenarios import SCENARIOS

    sc = SCENARIOS["gusty-6"]
    rows, truth, _ = fly(sc.design, sc.wind, sc.truth, sc.filter, 600.0, seed)
    s = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
              120.0)  # fmt: skip
    assert abs(s.speed_error_pct) <= 8.0, s
    assert 0.35 <= s.error_ratio <= 1.5, s
    assert s.band_skill >= 0.5, s


@pytest.mark.parametrize("seed", [1, 2])
def test_class_b_gusts_on_the_real_rope_say_how_fast_they_read(seed):
    """``field-gusty-6`` (6 m/s, IEC class B with vertical air, the real rope), ten minutes from 120 s, the two seeds
    of docs/estimator.md ("Gusts on the real rope read fast"). The wind reads 4.6-5.7 % fast (7.5-8.4 % before the
    wind's noise stopped following the force model's misfit): the ascent's drag scale in the vertical air, and a bias
    that grows with the turbulence's square, which the real rope's aerodynamic damping brings and the taut model leaves
    out. What this holds is that it is said: error/accuracy 0.6-1.33 (0.71-0.76: the accelerometer's misfit, no longer
    followed by the wind, raises the stated accuracy more than the error; the envelope's band starts at 0.75), at most
    3 % beyond 3 sigma (none), band skill 0.5 (0.71-0.75), and the bias no larger. Against the same stated accuracy
    the constant true mean (error/accuracy 1.9, 8.7-9.2 % beyond 3 sigma) and the truth delayed by 4 s (1.44-1.48,
    3.2-3.8 %) are not honest."""
    m = judged(scenario_sections(SCENARIOS["field-gusty-6"]), seed, be.FULL_DURATION_S, 120.0)
    est = m["estimate"]

    def honest(x: dict[str, float]) -> bool:
        return 0.6 <= x["err_acc"] <= 1.33 and x["beyond_3sigma"] <= 0.03

    assert honest(est) and est["skill"] >= 0.5 and est["speed"] <= 10.0 and est["dir"] <= 3.0, est
    assert not honest(m["constant"]) and not honest(m["delayed"]), (m["constant"], m["delayed"])


def test_an_hour_of_steady_wind_keeps_its_stated_accuracy():
    """A field day's hour in a steady 3 m/s on the real rope (``field-catenary``): nothing measures the drag scale on
    the taut tether, so its stated uncertainty grows only by its random walk, the balloon's gas (3 % an hour). At
    0.002 per sqrt(s) it grew from 7 % to 12 % in the hour and the stated accuracy with it, the estimate the same
    to a centimetre a second. The tilt's systematic error grows too, by the accelerometer's horizontal bias
    walking as the design declares (consistency.lean_bias_rad: 0.25 deg after ten minutes, 0.40 deg after the hour)
    across the field's horizontal direction, and along it by what the followed bias misses (bias_tilt_rad), and
    the stated accuracy with it: 8 % over the hour, under 12 % (19 % with the walk whole on both tilts), the error
    within it."""
    from firmware_py.estimator.consistency import lean_bias_rad
    from firmware_py.estimator.state import DRAG
    from sim_hil.scenarios import SCENARIOS

    sc = SCENARIOS["field-catenary"]
    rows, truth, est = fly(sc.design, sc.wind, sc.truth, sc.filter, 3600.0, 1)
    t = rows[:, 0]
    early, late = (t > 540.0) & (t < 660.0), t > 3480.0
    c = sc.filter
    walk = c.accel_bias_walk_mps2_rt_s
    assert lean_bias_rad(walk, 3540.0) > lean_bias_rad(walk, 600.0)
    assert rows[early, 3].mean() < rows[late, 3].mean() < 1.12 * rows[early, 3].mean(), (
        rows[early, 3].mean(),
        rows[late, 3].mean(),
    )
    assert math.sqrt(float(est.ekf.P[DRAG, DRAG])) < 0.06
    err = np.hypot(rows[late, 1] - np.interp(t[late], truth["time_s"], truth["wind_n"]),
                   rows[late, 2] - np.interp(t[late], truth["time_s"], truth["wind_e"]))  # fmt: skip
    assert np.sqrt(np.mean(err**2)) < rows[late, 3].mean()


@pytest.mark.parametrize("name", ["realistic-mems", "field-rope"])
def test_the_taut_entrys_settling_is_not_read_as_the_headings_error(name):
    """At the taut entry the balloon is placed on the tether's sphere and the state settles for tens of seconds: the
    accelerometer's innovations are metres a second squared, its noise follows them, the attitude is right. Fed in
    full, that settling read 2.5 deg about the field in realistic-mems and the stated accuracy carried it for a
    minute (0.31 m/s at 40 s where the error was 0.03-0.09 m/s). Fed with the nominal noise's share
    (consistency.slow_innovation_share), the seen error about the field stays within the attitude's actual one
    there. The Python core, which exposes the per-step state (the C core is held equal to it)."""
    import dataclasses

    from balloon_core.rotation import quat_from_euler, rotation_error
    from firmware_py.estimator.consistency import heading_misfit_variance
    from firmware_py.estimator.control import Estimator
    from sim_hil.scenarios import SCENARIOS
    from sim_hil.simulator import TRUTH_COLUMNS, Simulation

    sc = SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, 100.0, 1)
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    col = {c: j for j, c in enumerate(TRUTH_COLUMNS)}
    entry, seen, actual = None, [], []
    for i, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        t = s.time_usec * 1e-6
        if entry is None and est.ekf.mode == MODE_TAUT:
            entry = t
        if entry is None or t > entry + 60.0 or i % 50:
            continue
        seen.append(math.degrees(math.sqrt(heading_misfit_variance(est.consistency.slow_tilt_var))))
        row = sim.truth[i]
        q_true = quat_from_euler(*np.radians([row[col["roll_deg"]], row[col["pitch_deg"]], row[col["yaw_deg"]]]))
        b = np.array(est.field_ned) / np.linalg.norm(est.field_ned)
        actual.append(abs(math.degrees(np.array(rotation_error(q_true, tuple(est.ekf.q.tolist()))) @ b)))
    assert entry is not None and len(seen) > 100
    assert max(seen) < max(0.5, 2.0 * max(actual)), (max(seen), max(actual))


SNAPS = (63, 21, 97, 0)  # the full sample's flights: steady and Kaimal on the real rope, multisines on both


@pytest.mark.parametrize("flight", SNAPS)
def test_the_snap_says_the_wind_is_still_settling(flight):
    """The taut entry places the balloon at rest on the rod's sphere, but the snap is not the rod's: on the real rope
    the balloon climbs on at 3-5 m/s while the sag is taken up, on the paper's it bounces, and the rigid model can only
    swing it towards the vertical, the wind with it (a steady 4.3 m/s read 0.2 m/s a second after the entry). For the
    half minute after the entry the wind is 1.2-1.6 m/s RMS off, worse than the constant true mean or the truth 4 s late
    (0.4-0.8 m/s): this judges what the filter says of it. P, taking every row as consistent, fell from the placement's
    1.5 m/s to 0.8 in five seconds: 8.7-10.7 % of three of these flights' estimates were beyond 3 sigma there, error /
    accuracy up to 2.1. The placement's own 1-sigma settling by e in ENTRY_SETTLE_S
    (consistency.placement_settling_wind) stated it: 0-2.7 %, error / accuracy 1.2-1.7; with the wind's own speed in
    it (the swing's share, as large as the wind in a steady 8 m/s; the larger of the placement's and the estimate's)
    none, 0.57-0.72. Held: at most 5 % and the envelope's 0.5-2 (said neither much too confidently nor too cautiously:
    the references, with the same stated accuracy, read 0-0.35)."""
    p = be.sample(200)[flight]
    design, wind, truth_cfg, filt = build(be.sections_of(p))
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 80.0, p["seed"])
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT)
    assert len(taut), "never taut"
    t0 = rows[taut[0], 0]
    t, tn, te = truth["time_s"], truth["wind_n"], truth["wind_e"]
    judged_ok = {}
    for name, (tt, en, ee) in candidates(rows, truth, t0, t0 + be.ENTRY_WINDOW_S).items():
        m = tt <= t0 + be.ENTRY_WINDOW_S
        acc = np.interp(tt[m], rows[:, 0], rows[:, 3])
        sc = score(tt[m], en[m], ee[m], acc, t, tn, te, t0)
        judged_ok[name] = (0.5 <= sc.error_ratio <= 2.0 and sc.beyond_3sigma <= 0.05, sc.error_ratio, sc.beyond_3sigma)
    assert judged_ok["estimate"][0], judged_ok["estimate"]
    for ref in ("constant", "delayed"):
        assert not judged_ok[ref][0], (ref, judged_ok[ref])


def honest_or_says_it_has_no_skill(m: dict[str, dict[str, float]]) -> None:
    """The estimate honest (error / accuracy 0.4-1.5, at most 3 % beyond 3 sigma); where it has no skill in the band,
    its stated accuracy covers the wind's whole spread about its mean (the constant true mean's error within it, at
    most the envelope band's 1.33: no reference can be dishonest against it); where it has, both references fail, or,
    where the stated accuracy is cautious enough to call a reference honest too, their RMS error is at least 1.25
    times the estimate's (judged with the same stated accuracy, error / accuracy compares the errors).
    At least 0.4, not 0.5: a force balance that found the forces out of balance states it for its window after
    (consistency.FORCE_NIS_CLIP: flight 52 of the first minutes below, 1.9 m/s off at 55-60 s, reads 0.43 over 60-150 s;
    the hard iron from the south-east 0.48 over ten minutes)."""
    est = m["estimate"]
    assert 0.4 <= est["err_acc"] <= 1.5 and est["beyond_3sigma"] <= 0.03, est
    if est["skill"] < 0.3:
        assert m["constant"]["err_acc"] <= 1.33, (est, m["constant"])
    else:
        for ref in ("constant", "delayed"):
            honest = 0.5 <= m[ref]["err_acc"] <= 1.5 and m[ref]["beyond_3sigma"] <= 0.05
            assert not honest or m[ref]["err_acc"] > 1.25 * est["err_acc"], (ref, m[ref], est)


AFTER_THE_ENTRY = {  # name: (sample seed, flight): a sample's flights (None: the benchmark's own)
    "Kaimal 6.3 m/s on a 142 m paper rope": (51, 96),
    "a 1.1 m/s multisine on a 146 m lumped rope": (None, 52),
}


@pytest.mark.parametrize("name", AFTER_THE_ENTRY)
def test_the_first_minutes_after_the_entry_are_honest(name):
    """From 60 to 150 s, where a user starts to read the wind (the entry at 19-30 s). The held-out sample's flight 96
    swings across its rope after the entry, the wind 4 m/s across at 0.6 m/s stated; flight 52's light air on a long
    rope reads 0.6 m/s off. The force balance (consistency.balance_nis), judged from 60 s after the mode switch, saw
    neither in time: 14 and 3.8 % beyond 3 sigma, error / accuracy 1.58 and 1.42. Judged from BALANCE_FROM_S after the
    placement, its mean from zero once the placement has settled: none, error / accuracy 0.80 and 0.55 (0.57 and 0.43
    since its window is clipped at FORCE_NIS_CLIP, not at 25). Neither
    estimate had skill in the band there, and said so: the constant true mean's error is within the stated accuracy
    (as in the unseen rotation's corners). Since the alignment's attitude gain follows the accelerometer's misfit
    (params.ALIGN_MODEL_CORR_S) flight 96 no longer swings: band skill 0.52, error / accuracy 0.64, where the constant
    true mean reads 1.31 and the truth 4 s late 1.11 with the same stated accuracy."""
    sample_seed, flight = AFTER_THE_ENTRY[name]
    p = (be.sample(200) if sample_seed is None else be.sample(200, seed=sample_seed))[flight]
    m = judged(be.sections_of(p), p["seed"], 150.0, 60.0)
    honest_or_says_it_has_no_skill(m)


UNSEEN_ROTATION = {  # name: (scenario, wind from, seed)
    "reduced-balloon from S": ("reduced-balloon", 180.0, 2),
    "hard-iron from NE": ("hard-iron", 45.0, 1),
    "reduced-multisine from N": ("reduced-multisine", 0.0, 1),
    "reduced-multisine from S": ("reduced-multisine", 180.0, 2),
    "hard-iron from SE": ("hard-iron", 135.0, 1),
}


@pytest.mark.parametrize("name", UNSEEN_ROTATION)
def test_a_wind_held_across_the_lean_by_the_unseen_rotation_says_so(name):
    """The paper's world, ten minutes from 120 s: the reduced balloon from the south, the hard iron from the north-east
    and the south-east, the reduced balloon's multisine from the north and the south. The attitude turns 2-3 deg
    about the magnetic field's axis (which the magnetometer cannot see) together with a wind 1-1.6 m/s across the
    lean, and the accelerometer cannot tell the pair apart: every row's windowed NIS stays near 1, and the stated
    accuracy was 2.7, 2.9 and 2.6 times too small (up to 71 % beyond 3 sigma). (The reduced balloon from the south
    with seed 1 read 5.0 and 19 deg off; since the rope's breathing is noise along the radius (accel.radial_noise)
    it is 1.9 deg off with a band skill of 0.31, no longer this corner.) The model's forces do not balance there,
    and the measurements pull the balloon back every step; the force balance (consistency.balance_nis) states it:
    error / accuracy 0.6-0.8 (0.48-0.75 since its window is clipped at FORCE_NIS_CLIP, not at 25), at most 0.1 %
    beyond 3 sigma. The estimate has no skill in the band (-1.4 to 0.17) and says so: its stated accuracy covers the
    wind's whole spread about its mean, so the constant true mean's error is within it (error/accuracy at most 1.33,
    the top of the envelope's band), and no reference can be dishonest against it (were it ever skilful, they must
    be dishonest). While the force balance's mean was judged against a mean of the variance the updates took, which
    after the taut entry is tens of seconds old and several times today's, the hard iron from the south-east read
    5.5 % beyond 3 sigma and the multisines 3.1 and 4.0 %."""
    scenario, from_deg, seed = UNSEEN_ROTATION[name]
    sections = scenario_sections(SCENARIOS[scenario])
    sections["wind"]["from_deg"] = from_deg
    m = judged(sections, seed, be.FULL_DURATION_S, 120.0)
    honest_or_says_it_has_no_skill(m)


def test_a_balloon_blown_down_by_a_strong_wind_says_how_little_it_knows():
    """Beyond the envelope: the full sample's first flight (Kaimal with vertical air, the real rope, r = 1.2 m on
    143 m) in 15 m/s, ten minutes from 120 s. The balloon leans 75-80 deg, where a tenth of a degree of lean is a
    per cent of the wind and the rope's static shape holds the angle of its top loosely. The alignment's along
    component once was the horizontal projection of the body's axis, which moves by only cos(lean) of the lean's
    change and saturates: the state slid to the horizontal, the barometer's offset took the height, and the wind
    read 79 % fast at error/accuracy 2.1, 7.6 % beyond 3 sigma (the same flight on the paper's rope: 1678 % fast).
    Taken along the lean's tangent (aid_sources/tether.py fuse_taut) it read 43 % fast, and said so; with the wind's
    process noise bounded at IEC class A turbulence 5.6 % fast (no longer raised by the misfit at all,
    control._turbulence_excess), held within 15 %: error /
    accuracy within the envelope's 0.5-2 (1.18 with the lean's misfit stated, consistency.lean_misfit_wind; 1.52
    before it), at most 3 % beyond 3 sigma. No skill in the band: its stated accuracy covers the wind's whole spread,
    so the constant true mean's error is within it; the constant and the truth delayed by 4 s, against the same
    stated accuracy, fell below the error/accuracy band (0.29 and 0.28) while the accelerometer's misfit counted in
    full (sqrt(NIS)); counted as a slow gain's error ((1 + NIS) / 2, consistency.stated_nis) the stated accuracy is
    the wind's own spread, and a reference within that spread is as honest as the estimate (0.66 and 0.75): what is
    held is that the estimate says it knows no more than the wind's spread (the constant's error/accuracy at most
    1.33, the top of the envelope's band)."""
    p = dict(be.sample(200)[0], mean_mps=15.0)
    m = judged(be.sections_of(p), p["seed"], be.FULL_DURATION_S, 120.0)
    est = m["estimate"]

    def honest(x: dict[str, float]) -> bool:
        return 0.5 <= x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03 and x["speed"] < 15.0

    assert honest(est), est
    assert est["skill"] < 0.3 and m["constant"]["err_acc"] <= 1.33, (est, m["constant"])


def test_a_balloon_blown_down_on_the_paper_rope_in_class_b_gusts_says_its_wind_is_unknown():
    """Beyond the envelope: the stress sample's flight 8 (``bench_envelope --quick --max-wind 15``), class B gusts of
    14.4 m/s with vertical air on the paper's rope, r = 1.06 m on 52 m, five minutes from 120 s. The balloon leans
    75-85 deg. Its state slid to the horizontal, the barometer's offset taking the height, and the wind read seven
    times the truth (616 % fast): the accelerometer's misfit raised the wind's process noise without bound, the
    noisier wind the model's drag and tension. Bounded at IEC class A turbulence, and since not raised by the misfit
    at all (control._turbulence_excess), it reads
    within 1 %, and held here within 20 %. The body's tilt (77 deg) and the lean of the model's pull (87) had
    disagreed by 0.2 rad for minutes, which the lean's misfit states (consistency.lean_misfit_wind): error/accuracy
    within the envelope's 0.5-2 (1.5; 5.1 before it) and none of the estimates beyond 3 sigma (99 % before). The
    constant true mean and the truth delayed by 4 s, against the same stated accuracy, fell below the band (0.04)
    while the accelerometer's misfit counted in full; as a slow gain's error ((1 + NIS) / 2, consistency.stated_nis)
    they are within the wind's spread as the estimate is (0.80 and 0.75). The estimate has no skill there: a
    reference within the wind's spread is not held to fail; its error/accuracy at most 1.33 (the top of the
    envelope's band) says the stated accuracy covers that spread
    (test_a_balloon_blown_down_by_a_strong_wind_says_how_little_it_knows)."""
    p = dict(be.sample(64, max_wind_mps=15.0)[8])
    m = judged(be.sections_of(p), p["seed"], 300.0, 120.0)
    est = m["estimate"]

    def honest(x: dict[str, float]) -> bool:
        return 0.5 <= x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03

    assert honest(est) and abs(est["speed"]) <= 20.0, est
    if est["skill"] < 0.3:
        assert m["constant"]["err_acc"] <= 1.33, (est, m["constant"])
    else:
        assert not honest(m["constant"]) and not honest(m["delayed"]), (m["constant"], m["delayed"])


def test_a_sphere_through_its_drag_crisis_says_its_drag_is_unknown():
    """``drag-crisis`` (the paper's world, the sphere's C_d by its Reynolds number, 0.30 as designed only at about 3
    m/s), ten minutes from 120 s. The ascent climbs at 4-5 m/s through the air, where the C_d is half the tether's;
    combined with the design's as one C_d, it read the tethered wind 36 % fast, stated five times too confidently
    (error/accuracy 5.3, most estimates beyond 3 sigma). The ascent and the design now disagree beyond
    DRAG_CONFLICT_SIGMA, so the drag scale is their mixture (WindEkf.weigh_information): 17 % fast, and said
    (error/accuracy 0.82, none beyond 3 sigma). What this holds is that the error is stated, not that the wind is
    followed: with its 17 % the flight has no band skill (-0.12), and its stated accuracy covers the wind's spread
    about its mean (the constant true mean 0.75, none beyond 3 sigma, since the cap states the conflict too: the
    test below)."""
    sc = SCENARIOS["drag-crisis"]
    m = judged(scenario_sections(sc), 1, be.FULL_DURATION_S, 120.0)
    honest_or_says_it_has_no_skill(m)
    assert m["estimate"]["speed"] < 25.0, m["estimate"]


@pytest.mark.parametrize("from_deg", [70.0, 270.0])
def test_a_strong_wind_says_its_snap_is_as_large_as_the_wind(from_deg):
    """``steady-8`` (8 m/s, blown 72 deg down), the first 10 s after the taut entry: the swing after the snap takes the
    wind as far as to calm, 2.5-3.4 m/s RMS off from every direction. Stated as the calm placement's 1.5 m/s settling,
    error/accuracy 3.1-4.1 and 35-45 % of the estimates beyond 3 sigma; with the wind's own speed in the settling
    (consistency.placement_settling_wind) 1.4-1.5, none. Held: 0.5-2 and at most 5 %; the constant true mean and the
    truth 4 s late (a steady wind: both exact) fall below the band."""
    sections = scenario_sections(SCENARIOS["steady-8"])
    sections["wind"]["from_deg"] = from_deg
    design, wind, truth_cfg, filt = build(sections)
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 40.0, 1)
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT)
    assert len(taut), "never taut"
    t0 = rows[taut[0], 0]
    w = (rows[:, 0] >= t0) & (rows[:, 0] < t0 + 10.0)
    t, acc = rows[w, 0], rows[w, 3]
    tn, te = (np.interp(t, truth["time_s"], truth[c]) for c in ("wind_n", "wind_e"))

    def honest(n: np.ndarray, e: np.ndarray) -> bool:
        err = np.hypot(n - tn, e - te)
        return 0.5 <= np.sqrt(np.mean(err**2) / np.mean(acc**2)) <= 2.0 and np.mean(err > 3.0 * acc) <= 0.05

    assert honest(rows[w, 1], rows[w, 2])
    assert not honest(np.full_like(tn, tn.mean()), np.full_like(te, te.mean()))
    late = [np.interp(t - DELAY_S, truth["time_s"], truth[c]) for c in ("wind_n", "wind_e")]
    assert not honest(*late)


@pytest.mark.parametrize(("seed", "from_deg"), [(1, None), (2, 70.0)])
def test_a_sphere_through_its_drag_crisis_says_so_from_its_taut_entry(seed, from_deg):
    """``drag-crisis`` as the stop's check scores a flight: from 60 s, here to 130 s, before the taut flight's
    turbulence has been measured and the ascent weighed again (TURBULENCE_TO_S after the entry). The ascent's drag
    scale (0.46: the climb's C_d is half the tether's) and the design's (1 +- 0.1) are 3.8 sigma apart even at the
    cap's weight; the cap combined them as one C_d, 0.73 +- 0.07, and the wind, 15-19 % fast, was stated at a third
    of its error until the weighing two minutes later found the conflict (error/accuracy 2.4-2.7, 10-49 % of the
    estimates beyond 3 sigma in a minute). The cap now finds it (WindEkf.cap_information): the same estimate, stated
    as the mixture it is (0.64-0.80, none beyond 3 sigma). The estimate has no skill there (band skill -1.8 and -3.8):
    its stated accuracy covers the wind's spread about its mean (the constant true mean 0.25-0.28)."""
    sections = scenario_sections(SCENARIOS["drag-crisis"])
    if from_deg is not None:
        sections["wind"]["from_deg"] = from_deg
    m = judged(sections, seed, 130.0, 60.0)
    honest_or_says_it_has_no_skill(m)
    assert m["estimate"]["speed"] < 25.0, m["estimate"]


@pytest.mark.parametrize("from_deg", [0.0, 270.0])
def test_a_small_balloon_on_a_short_tether_in_a_strong_wind_reads_its_speed(from_deg):
    """Beyond the envelope (``balloon-study examples/long-tether-study.toml``): r = 0.8 m on 30 m of the real rope,
    Kaimal with vertical air at 10 m/s, blown 77 deg down, ten minutes from 120 s. The accelerometer's misfit raised
    the wind's process noise without bound, and the noisier wind read 10-18 % fast (band skill -0.16 and -0.99 from
    the north and the west) at error/accuracy 1.2-1.5. Bounded at IEC class A turbulence, and since not raised by the
    misfit at all (control._turbulence_excess):
    within 2 % and skilful (0.50-0.60), stated cautiously (0.6-0.7). Held: within 5 %, band skill 0.4, honest within
    the envelope's 0.5-2 and at most 3 % beyond 3 sigma; the constant true mean has no skill and fails. The truth 4 s
    late would pass (skill 0.60, error/accuracy 0.86-0.91): at 10 m/s the band below 0.05 Hz is slow against 4 s,
    and the estimate is as good as such a truth; what it fails is the speed it read before (10-18 %)."""
    sections = scenario_sections(SCENARIOS["field-rope"])
    sections["balloon"]["radius_m"], sections["tether"]["length_m"] = 0.8, 30.0
    sections["wind"]["from_deg"], sections["wind"]["mean_mps"] = from_deg, 10.0
    m = judged(sections, 1, be.FULL_DURATION_S, 120.0)

    def good(x: dict[str, float]) -> bool:
        return x["speed"] <= 5.0 and x["skill"] >= 0.4 and 0.5 <= x["err_acc"] <= 2.0 and x["beyond_3sigma"] <= 0.03

    assert good(m["estimate"]), m["estimate"]
    assert not good(m["constant"]), m["constant"]


@pytest.mark.parametrize(("from_deg", "mean_mps"), [(180.0, 6.0), (180.0, 10.0), (195.0, 6.0), (195.0, 10.0)])
def test_a_long_tether_blown_towards_magnetic_north_does_not_swing_across_its_rope(from_deg, mean_mps):
    """Beyond the envelope (``balloon-study examples/long-tether-study.toml``, its ``south`` sweep): r = 2.0 m on 300 m
    of the real rope, Kaimal with vertical air, blown towards magnetic north, ten minutes from 120 s. After the taut
    entry the state swung across the rope, +-40-100 m with a period of about 40 s, its wind with its velocity and its
    attitude about the magnetic field's axis (which the magnetometer cannot see) with both: 4.3 m/s RMS at
    error/accuracy 2.4 in 6 m/s from the south. The heading then took a tenth of the accelerometer's gain where the
    position's azimuth took all of it; at least half (params.ACCEL_HEADING_GAIN_MIN), this balloon does not swing from
    either direction in either wind (within 2.3 %, band skill 0.47-0.51, error/accuracy 0.86-1.04). Held: band skill
    0.3, within 5 %, honest within 0.5-1.33 and at most 3 % beyond 3 sigma; the constant true mean has no skill and
    fails. The truth 4 s late would pass (skill 0.60-0.67, error/accuracy 1.03-1.07): the swing's 40 s period is slow
    against 4 s, and what this fails is the swing.

    The mode itself is not gone (docs/estimator.md, "The swing across the rope"): a balloon with less lift per metre
    of its rope makes it softer, and r = 1.5 m on the same rope still swings in three of these four winds (band skill
    -1.21, 0.09 and 0.07; 0.29 in 10 m/s from 180 deg), whichever of them a change of the ascent's first second
    happens to excite (from 195 deg in 10 m/s: 0.41 before the ascent's airflow gate, 0.07 after; the drag scale the
    ascent left 1.025 and 1.021). In 6 m/s from the south it says so only in part (error/accuracy 1.42, 6 % beyond
    3 sigma, before and after)."""
    sections = scenario_sections(SCENARIOS["field-rope"])
    sections["balloon"]["radius_m"], sections["tether"]["length_m"] = 2.0, 300.0
    sections["wind"]["from_deg"], sections["wind"]["mean_mps"] = from_deg, mean_mps
    m = judged(sections, 1, be.FULL_DURATION_S, 120.0)

    def good(x: dict[str, float]) -> bool:
        return x["speed"] <= 5.0 and x["skill"] >= 0.3 and 0.5 <= x["err_acc"] <= 1.33 and x["beyond_3sigma"] <= 0.03

    assert good(m["estimate"]), m["estimate"]
    assert not good(m["constant"]), m["constant"]



@pytest.mark.parametrize(("seed", "from_deg"), [(1, 180.0), (2, 200.0)])
def test_class_b_gusts_blown_towards_magnetic_north_do_not_swing_after_the_entry(seed, from_deg):
    """``gusty-6`` (6 m/s, IEC class B, the paper's rope) blown towards magnetic north, 10-40 s after the taut entry,
    where a user who starts to read the wind at once reads it. The state swung across the rope (+-20 m on 100 m, a
    period of about 25 s), its wind with its velocity: 1.5-2.7 m/s RMS off, worse than the constant true mean
    (1.05-1.26) and the truth 4 s late (1.25-1.53), 13 % beyond 3 sigma from 160 and 180 deg. The alignment's cross
    row, fused at 20 Hz as if its misfit were white where the accelerometer's says the balloon rocks (its noise stops
    at a rocking balloon's), had turned the attitude about the field's axis with the position's azimuth at 1-2 deg/s
    (params.ALIGN_MODEL_CORR_S); at the
    gain a correlated misfit allows, 0.44-1.1 m/s from 160, 180 and 200 deg, seeds 1-3, none beyond 3 sigma. Held:
    the estimate nearer the truth than either reference (three quarters of the better one's RMS error, which no
    reference can be of itself), and honest (error/accuracy at most 1.5, at most 5 % beyond 3 sigma)."""
    sections = scenario_sections(SCENARIOS["gusty-6"])
    sections["wind"]["from_deg"] = from_deg
    design, wind, truth_cfg, filt = build(sections)
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 60.0, seed)
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT)
    assert len(taut), "never taut"
    a, b = rows[taut[0], 0] + 10.0, rows[taut[0], 0] + 40.0
    m = {}
    for name, (tt, en, ee) in candidates(rows, truth, a, b).items():
        w = tt <= b
        acc = np.interp(tt[w], rows[:, 0], rows[:, 3])
        m[name] = score(tt[w], en[w], ee[w], acc, truth["time_s"], truth["wind_n"], truth["wind_e"], a)
    est, best = m["estimate"], min(m["constant"].raw_rmse_mps, m["delayed"].raw_rmse_mps)
    assert est.raw_rmse_mps <= 0.75 * best, (est, best)
    assert est.error_ratio <= 1.5 and est.beyond_3sigma <= 0.05, est


@pytest.mark.parametrize("seed", [1, 3])
def test_a_balloon_that_turns_once_released_with_a_hard_iron_offset(seed):
    """A sphere with a seam, a valve or its avionics on the skin is a weak vane ([truth] yaw_moment_coefficient
    0.01): released at its boot heading of 30 deg into a wind towards 90 deg, it turns 60 deg once blown over. A
    hard-iron offset (0.04 G, fixed in the body) then adds another part to the field along gravity than at the boot,
    and the field vector fused against the boot's tilted the attitude: 1.4-2.1 m/s RMS, 25-35 deg off at
    error/accuracy 1.6-2.2 (seeds 1-3). The field learnt again on the tether (magnetometer.learn_field_in_flight,
    0.014-0.016 G from the boot's, beyond FIELD_CHANGE_GAUSS): 0.37-0.65 m/s, 5-11 deg. What stays is the hard
    iron's part across the field, which turns the heading as the balloon follows the wind's direction and which no
    invariant of the field sees: stated as large as the part the window saw (Estimator.field_heading_var, 3.6-4.2
    deg), error/accuracy 1.2-1.9 -> 1.0-1.5 (seeds 1-5). A regression guard on the failure, not a target: the
    references (the constant true mean, the truth 4 s late) are no filters that learn a field."""
    design, wind, truth_cfg, filt = build(scenario_sections(SCENARIOS["field-turning-hard-iron"]))
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 300.0, seed)
    late = truth["time_s"] > 120.0
    yaw = truth["yaw_deg"][late]
    assert abs(np.median(yaw) - 90.0) < 10.0, (yaw.min(), yaw.max())  # it turned
    sc = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], 120.0)
    assert sc.raw_rmse_mps <= 0.7 and abs(sc.direction_error_deg) <= 12.0 and abs(sc.speed_error_pct) <= 4.0, sc
    assert sc.error_ratio <= 1.6, sc


@pytest.mark.parametrize("from_deg", [10.0, 190.0])
def test_a_large_hard_iron_is_learnt_again_in_the_minute_after_the_entry(from_deg):
    """An uncalibrated magnetometer beside the avionics' battery: a hard-iron offset of 0.14 G, a third of the
    field, fixed in the body. Leaning 25 deg on its tether (blown north or south: the lean turns the offset in the
    plane of the field) the balloon measures a field 0.03 G from the boot's, and the field vector fused against the
    boot's pulled the attitude and the wind with it: 3.7-4.0 m/s RMS from 30 to 100 s after the entry, 6-14 % beyond
    3 sigma (seeds 1-2), until the field learnt again 30-90 s after the entry replaced it. Learnt first 5-20 s after
    the entry (magnetometer.FIELD_RELEARN_WINDOWS_US): 0.27-0.42 m/s, none beyond 3 sigma. A regression guard on the
    failure, not a target: the references are no filters that learn a field (the constant true mean of this light
    turbulence reads 0.24 m/s)."""
    sections = scenario_sections(SCENARIOS["hard-iron"])
    sections["wind"]["from_deg"] = from_deg
    sections["truth"]["mag_hard_iron_gauss"] = [0.1, -0.08, 0.05]
    design, wind, truth_cfg, filt = build(sections)
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 130.0, 1)
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT)
    a = rows[taut[0], 0] + 30.0
    w = (rows[:, 0] >= a) & (rows[:, 0] <= a + 70.0)
    sc = score(rows[w, 0], rows[w, 1], rows[w, 2], rows[w, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], a)
    assert sc.raw_rmse_mps <= 1.0 and sc.beyond_3sigma <= 0.03, sc


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("field", [(0.02, 0.0, 0.0), (0.0, 0.05, 0.0)])
def test_a_current_switched_beside_the_magnetometer_is_learnt_as_the_fields_jump(field, seed):
    """A heater, a radio or a servo switched on beside the magnetometer 60 s after the boot (35-40 s after the taut
    entry): a field fixed in the body ([truth] mag_switched_gauss) that the field learnt at the boot cannot hold.
    Fused against it, the field vector turned the attitude to fit, the tilt most: 0.02 G along the body's x (4 % of
    the field; seen in its strength) read 1.6-1.9 m/s RMS over the next 90 s, 17-18 % beyond 3 sigma; 0.05 G along
    its y (across the field and the gravity: no strength changes, the rows rejected and then fused at the gate) 2.4-2.9
    m/s, 10-12 %. Seen as a jump (magnetometer.watch_field) and the field learnt again, its direction through the
    attitude the gyro held (learn_field_in_flight): 0.15-0.27 m/s, at most 0.2 % beyond 3 sigma. A regression guard on
    the failure, not a target: the references are no filters that learn a field (the constant true mean of this light
    turbulence reads 0.22-0.25 m/s)."""
    sections = scenario_sections(SCENARIOS["field-rope"])
    sections["truth"]["mag_switched_gauss"] = list(field)
    sections["truth"]["mag_switched_on_s"] = 60.0
    design, wind, truth_cfg, filt = build(sections)
    rows, truth, est = fly(design, wind, truth_cfg, filt, 150.0, seed)
    w = rows[:, 0] >= 60.0
    sc = score(rows[w, 0], rows[w, 1], rows[w, 2], rows[w, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], 60.0)
    assert est.counters.field_jumps == 1, est.counters.as_dict()
    assert sc.raw_rmse_mps <= 0.6 and sc.beyond_3sigma <= 0.03 and sc.error_ratio <= 1.2, sc


@pytest.mark.parametrize("seed", [2, 3])
def test_bursts_beside_the_magnetometer_are_rejected_not_learnt(seed):
    """A radio's transmissions beside the magnetometer (tools/sensor_faults.py ``burst``: 0.2 s of 0.1 G in every
    2 s) from 30 s after the taut entry: each burst rejected by the field's rows, neither a jump nor a field. The
    placement's second window (30-90 s after it) had summed them into a field 0.01 G off and the attitude went with
    it: 3.7-4.4 times the flight's RMS error without them over the next 90 s, error/accuracy 1.3-1.4. Now the windows
    skip what the rows reject: 1.00-1.02 times, error/accuracy 0.34-0.43."""
    rms, err_acc, beyond, jumps = sensor_faults.fly("field-rope", seed, "burst", 30.0, 90.0, "c")
    clean = sensor_faults.fly("field-rope", seed, "none", 30.0, 90.0, "c")
    assert jumps == 0 and rms <= 1.5 * clean[0] and err_acc <= 1.0 and beyond <= 0.03, (rms, clean, err_acc, beyond)


@pytest.mark.parametrize("from_deg", [90.0, 120.0])
def test_a_turned_balloon_with_a_hard_iron_offset_says_so_before_it_learns_its_field_again(from_deg):
    """The same balloon from 60 to 110 s, before the field is learnt again on the tether (30-90 s after the entry):
    the wind 4-6 m/s off (the heading the boot's field gives the turned balloon, the attitude about the field's axis
    with it), the forces 30 sigma out of balance (the force balance's NIS of its mean 700-1300). Clipped at the
    innovations' 25 the window stated at most five times P's accuracy: error/accuracy 4.6 and 3.3, 97 and 67 % beyond
    3 sigma; clipped at consistency.FORCE_NIS_CLIP it says the wind is unknown there."""
    sections = scenario_sections(SCENARIOS["field-turning-hard-iron"])
    sections["wind"]["from_deg"] = from_deg
    honest_or_says_it_has_no_skill(judged(sections, 1, 110.0, 60.0))


FRONT_SMOOTH_S = 10.0  # the direction judged through a front is the 10 s mean wind's (the turbulence's own turns out)
FRONT_LAG_MAX_S = 3.0  # how late the estimate's direction may follow the truth's through a front (the reference: 4 s)
FRONT_DIR_RMS_MAX_DEG = 8.0  # and how far off it may be meanwhile (the 4 s late truth: 6-18 deg)


def front_metrics(wind, t, n, e, truth) -> dict[str, float]:
    """How a candidate follows a front (``[wind] turn_deg`` over ``turn_duration_s`` from ``turn_start_s``): the lag
    (s) that best lays the truth's direction onto its own, and its direction's RMS error (deg), both from the front's
    start to 20 s after its end, on the 10 s mean wind of each."""
    a, b = wind.turn_start_s, wind.turn_start_s + wind.turn_duration_s + 20.0
    grid = np.arange(a - 30.0, b + 30.0, 0.1)
    box = np.ones(int(FRONT_SMOOTH_S / 0.1)) / int(FRONT_SMOOTH_S / 0.1)

    def direction(tt, xn, xe):
        sn, se = (np.convolve(np.interp(grid, tt, x), box, mode="same") for x in (xn, xe))
        return np.unwrap(np.arctan2(se, sn))

    mine, true = direction(t, n, e), direction(truth["time_s"], truth["wind_n"], truth["wind_e"])
    sel = (grid >= a) & (grid <= b)

    def off(lag_s: float) -> np.ndarray:  # wrapped: an unwrapped series may step by a turn in a calm moment
        return (mine[sel] - np.interp(grid[sel] - lag_s, grid, true) + math.pi) % (2.0 * math.pi) - math.pi

    lags = np.arange(-5.0, 10.01, 0.1)
    lag = float(lags[np.argmin([np.mean(off(x) ** 2) for x in lags])])
    return {"front_lag_s": lag, "front_dir_rms_deg": math.degrees(math.sqrt(np.mean(off(0.0) ** 2)))}


def front_ok(m: dict[str, float]) -> list[str]:
    """A fluctuating wind's judgement (``fluctuating_ok``) and the front followed: not late, not far off."""
    bad = fluctuating_ok(m)
    if not m["front_lag_s"] <= FRONT_LAG_MAX_S:
        bad.append(f"{m['front_lag_s']:.1f} s late through the front")
    if not m["front_dir_rms_deg"] <= FRONT_DIR_RMS_MAX_DEG:
        bad.append(f"{m['front_dir_rms_deg']:.1f} deg off through the front")
    return bad


@pytest.mark.parametrize(
    ("scenario", "wind", "directions"),
    [
        ("field-front", {"turn_start_s": 150.0}, (0.0, 120.0, 240.0)),  # veers 90 deg in a minute
        ("field-reduced", {"turn_deg": 90.0, "turn_start_s": 150.0, "turn_duration_s": 10.0}, (60.0,)),
        ("field-gusty-6", {"turn_deg": -120.0, "turn_start_s": 150.0, "turn_duration_s": 30.0}, (300.0,)),
    ],
)
def test_a_front_turns_the_wind(scenario, wind, directions):
    """A front, a sea breeze setting in: the wind turns by 90-120 deg in a minute or less ([wind] turn_deg; the balloon
    swings round the anchor after it). The reference balloon in 3 m/s from three directions, the small one (r = 0.92
    m) in a front of 10 s, the reference in 6 m/s class B gusts backing 120 deg in 30 s: followed within a second
    (0-1.2 s late; the 4 s late truth 4.0), 2-7 deg off through the front (the 4 s late truth 6-18), the whole flight
    as every fluctuating wind's judgement asks, no re-placement of the taut balloon, honest. The constant true mean
    (no turn) and the truth 4 s late fail."""
    worst: list[str] = []
    for d in directions:
        secs = scenario_sections(SCENARIOS[scenario])
        secs["wind"].update(from_deg=d, **wind)
        m = judged(secs, 1, 330.0, START_S, extra=front_metrics)
        worst += [f"from {d:.0f} deg: {b}" for b in front_ok(m["estimate"])]
        assert front_ok(m["constant"]), f"from {d:.0f}: the constant true mean passes"
        assert front_ok(m["delayed"]), f"from {d:.0f}: the truth delayed by {DELAY_S} s passes"
    assert not worst, "; ".join(worst)



def askew_flight(sensors: dict[str, float], roll_deg: float, from_deg: float) -> tuple[np.ndarray, dict[str, float]]:
    """The real rope in 3 m/s (``field-rope``, seed 1, 300 s) with the truth's IMU rolled and pitched ``roll_deg``
    against the balloon, the design's [sensors] as given: the estimate's rows and its score."""
    secs = scenario_sections(SCENARIOS["field-rope"])
    secs["wind"]["from_deg"] = from_deg
    secs["truth"].update(imu_roll_deg=roll_deg, imu_pitch_deg=roll_deg)
    secs["sensors"].update(sensors)
    design, wind, truth_cfg, filt = build(secs)
    rows, truth, _ = fly(design, wind, truth_cfg, filt, 300.0, 1)
    sc = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], 120.0)
    return rows, {"dir": abs(sc.direction_error_deg), "speed": abs(sc.speed_error_pct), "err_acc": sc.error_ratio}


def rms_apart(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of the distance between two flights' wind estimates from 120 s (``a``'s times)."""
    late = a[:, 0] >= 120.0
    dn = a[late, 1] - np.interp(a[late, 0], b[:, 0], b[:, 1])
    de = a[late, 2] - np.interp(a[late, 0], b[:, 0], b[:, 2])
    return float(np.sqrt(np.mean(dn * dn + de * de)))


def test_an_imu_mounted_askew():
    """An IMU board is never quite on the balloon's axis (the tether's pull through the centre): rolled and pitched 1
    deg ([truth] imu_roll_deg, imu_pitch_deg), the alignment reads the lean that far off and no sensor on the balloon
    can tell. Not declared (from 90 and 180 deg): 8.7 and 3.5 deg off, 3.2 and 9.0 % off, 0.47 and 0.28 m/s (RMS)
    from the flight with the IMU on the axis, at error/accuracy 2.34 and 1.41. Its mounting declared as measured
    ([sensors] imu_roll_deg, imu_pitch_deg: the readings turned into the balloon's axes): the wind of the flight with
    the IMU on the axis, within 0.003 m/s. Only its uncertainty declared ([sensors] imu_alignment_deg = 1.5, in the
    tilt's systematic term): as wrong, and honest (0.77 and 0.55)."""
    for d in (90.0, 180.0):
        aligned, _ = askew_flight({}, 0.0, d)
        blind, mb = askew_flight({}, 1.0, d)
        told, _ = askew_flight({"imu_roll_deg": 1.0, "imu_pitch_deg": 1.0}, 1.0, d)
        _, mh = askew_flight({"imu_alignment_deg": 1.5}, 1.0, d)
        assert rms_apart(told, aligned) < 0.01, d  # the trim undoes the mounting
        assert rms_apart(blind, aligned) > 0.1 and mb["dir"] > 3.0 and mb["err_acc"] > 1.33, (d, mb)  # it does not
        assert 0.35 <= mh["err_acc"] <= 1.33, (d, mh)  # stated, it is honest
