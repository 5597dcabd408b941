"""tools/accuracy_terms.py and tools/ascent_scale.py: the terms add up to the accuracy the estimator reports, the
ascent is judged against the world it flew, and a wrong flight number or setting is a user error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from balloon_core.score import score
from benchmarks.bench_envelope import sample, sections_of
from study.case import fly
from study.spec import build
from tools.accuracy_terms import override, terms
from tools.ascent_scale import ascent_error

ROOT = Path(__file__).resolve().parents[2]


def test_the_terms_add_up_to_the_reported_accuracy():
    """A steady flight (no inflation: every source's windowed NIS, the force balance's too, below the flag): the mean
    square accuracy is the sum of the terms' mean squares, and the error is measured against the truth (not zero,
    not the accuracy itself)."""
    steady = next(i for i, p in enumerate(sample(64)) if p["wind_kind"] == "steady" and p["mean_mps"] > 3.0)
    t = terms(sample(64)[steady], 150.0)
    assert t["inflation"] == 1.0
    parts = t["P"] ** 2 + t["drag"] ** 2 + t["tilt"] ** 2 + t["misfit"] ** 2
    assert 0.0 < t["misfit"] < t["accuracy"]  # the lean the body and the model disagree on: a little, in steady air
    assert t["accuracy"] ** 2 == pytest.approx(parts, rel=1e-6)
    assert 0.0 < t["error"] < t["accuracy"] * 3.0 and t["error"] != pytest.approx(t["accuracy"])
    assert t["offset_sigma_m"] > 0.0 and t["offset_walk_m"] >= 0.0
    # the mean vectors' errors as the study scores them (the C core, held equal to the Python one)
    p = sample(64)[steady]
    rows, truth, _ = fly(*build(sections_of(p)), 150.0, p["seed"])
    sc = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
               start_s=120.0)  # fmt: skip
    assert t["direction_error_deg"] == pytest.approx(sc.direction_error_deg, abs=0.05)
    assert t["speed_error_pct"] == pytest.approx(sc.speed_error_pct, abs=0.05)
    # the same flight with a horizontal accelerometer bias of 10 mg the filter does not know of (a tilt of 0.6 deg):
    # the change reaches the flight, and the lean's azimuth turns with it (0.56 deg; 0.8 and more before the level
    # rows, which take the tilt from the mean specific force, the bias in it)
    biased = terms(p, 150.0, ("truth.accel_bias_mps2=0.1", "truth.accel_bias_walk_mps2_rt_s=0"))
    assert abs(biased["direction_error_deg"] - t["direction_error_deg"]) > 0.3


def test_one_thing_of_the_flight_changed():
    """``--set SECTION.KEY=VALUE``: a value as a design file writes it (a number, a flag, an array, a word) into the
    flight's own sections; a key or a section the flight does not have is refused, and on the command line that and a
    value the design refuses are user errors (one line, before any flight flies)."""
    secs = sections_of(sample(64)[0])
    override(secs, "truth.accel_bias_mps2 = 0")
    override(secs, "sensors.gyro_dps=0.1")
    override(secs, "truth.froude_krylov=false")
    override(secs, "truth.rope_model=paper")
    override(secs, "wind.multisine_hz=[0.05, 0.1]")
    override(secs, "truth.physics_hz=400")
    assert secs["truth"]["accel_bias_mps2"] == 0.0 and secs["sensors"]["gyro_dps"] == 0.1
    assert secs["truth"]["froude_krylov"] is False and secs["truth"]["rope_model"] == "paper"
    assert secs["wind"]["multisine_hz"] == [0.05, 0.1] and secs["truth"]["physics_hz"] == 400.0
    build(secs)
    for bad in ("truth.nope=1", "nope.gyro_dps=1", "sensors.gyro_dps", "gyro_dps=1"):
        with pytest.raises(ValueError, match="SECTION.KEY=VALUE"):
            override(secs, bad)
    refused = (("truth.x=1", "truth.x=1"), ("sensors.gyro_dps=abc", "gyro_dps"), ("balloon.radius_m=0.2", "lift"))
    for bad, said in refused:
        cmd = [sys.executable, str(ROOT / "tools" / "accuracy_terms.py"), "3", "--quick", "--set", bad]
        r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and said in r.stderr and not r.stdout


def test_the_ascent_tool_flies_the_world_it_is_told():
    """tools/ascent_scale.py --set: the ascent is judged against the C_d the truth flew, not the sample's; a drag 20 %
    above the sample's is learnt as such (read against the sample's it would be 20 % off); a wrong setting is a
    user error."""
    p = next(p for p in sample(200) if p["wind_kind"] == "steady" and p["rope_model"] == "lumped")
    err, _, scale, _, _ = ascent_error(p, settings=(f"truth.drag_coefficient_scale={1.2 * p['cd_scale']}",))
    assert abs(err) < 0.05 and scale / p["cd_scale"] > 1.12
    cmd = [sys.executable, str(ROOT / "tools" / "ascent_scale.py"), "steady", "--flights", "8", "--set", "truth.x=1"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "truth.x=1" in r.stderr and not r.stdout


def test_a_flight_outside_the_sample_is_a_user_error():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "accuracy_terms.py"), "64", "--quick"],
                       capture_output=True, text=True, cwd=ROOT)  # fmt: skip
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "no flight 64" in r.stderr


def test_the_misfit_along_the_rope_is_the_balloon_moving_along_it():
    """In IEC class B gusts on the real rope the accelerometer's misfit along the body's z (the rope's axis, which
    the taut model holds still) is the balloon's acceleration along its rope, as the truth has it: the rope's pull
    swings by newtons. Across the rope the misfit is the gusts the wind's state does not follow (since its noise no
    longer follows the misfit, a NIS of 2 or more there too), along it half as much again."""
    gusts = next(i for i, p in enumerate(sample(64)) if p["wind_kind"] == "gusts" and p["rope_model"] == "lumped")
    t = terms(sample(64)[gusts], 150.0)
    across = max(t["nis_accel_x"], t["nis_accel_y"])
    assert t["accel_z_along_corr"] > 0.9 and t["nis_accel_z"] > max(2.0, 1.5 * across), t
    assert t["tension_sd_n"] > 1.0
