"""The truth cases outside the firmware's model: what each scenario holds, that each runs, that the
firmware is not told, that they survive a design file, and the hard-iron offset's effect."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from balloon_core.config import ConfigError
from firmware_py.estimator.state import FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.scenarios import SCENARIOS, resolve
from sim_hil.simulator import Simulation
from sim_hil.wind import WindConfig

PAPER_FILTER = FilterConfig(rope_model="paper", rope_normal_cd=0.0)  # the paper's world: its rope, told
PAPER_TRUTH = TruthConfig(rope_model="paper", rope_drag=False)
PAPER_WIND = WindConfig(vertical=False)
FIELD = ("field-rope", "field-rope-multisine", "field-catenary", "field-shear", "field-weather", "field-biases",
         "field-reduced", "field-gusty-6", "field-all")  # fmt: skip
NEW = (
    "multisine-2d", "multisine-2d-ne", "multisine-2d-s", "reduced-multisine", "steady-1", "steady-8", "gusty-6",
    "com-offset", "hard-iron", "drag-crisis",
)  # fmt: skip


def test_new_scenarios_hold_their_truth_case_and_the_firmware_is_not_told():
    s = SCENARIOS
    for name in NEW:
        assert s[name].filter == PAPER_FILTER, name
    for name in FIELD:  # the real world: the firmware knows the design and nothing else
        assert s[name].filter == FilterConfig(), name
        assert s[name].truth.rope_model == "lumped" and s[name].wind.vertical, name
    assert s["field-catenary"].truth.rope_drag is False and s["field-rope"].truth.rope_drag is True
    assert s["multisine"].wind == replace(PAPER_WIND, kind="multisine")  # the along-only case is unchanged
    for name, from_deg in (("multisine-2d", 270.0), ("multisine-2d-ne", 45.0), ("multisine-2d-s", 170.0)):
        w = s[name].wind
        assert (w.kind, w.multisine_axes, w.mean_mps, w.from_deg) == ("multisine", "both", 3.0, from_deg)
        assert s[name].design == s["paper-reference"].design
    assert s["reduced-multisine"].design.balloon.radius_m == 0.92
    assert s["reduced-multisine"].wind == s["multisine-2d"].wind
    assert (s["steady-1"].wind.kind, s["steady-1"].wind.mean_mps) == ("steady", 1.0)
    assert (s["steady-8"].wind.kind, s["steady-8"].wind.mean_mps) == ("steady", 8.0)
    g = s["gusty-6"].wind
    assert (g.kind, g.mean_mps, g.iec_class, g.turbulence) == ("vdh", 6.0, "B", "kaimal")
    assert s["com-offset"].truth == replace(PAPER_TRUTH, avionics_offset_m=0.8)
    assert s["drag-crisis"].truth == replace(PAPER_TRUTH, drag_model="reynolds")
    assert s["hard-iron"].truth.mag_hard_iron_gauss == (0.03, -0.02, 0.015)
    for name in ("com-offset", "drag-crisis", "hard-iron"):
        assert s[name].wind == PAPER_WIND and s[name].design == s["paper-reference"].design


@pytest.mark.parametrize("name", NEW)
def test_every_new_scenario_runs(name):
    sc = SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, 30.0, seed=2)
    assert sim.run() == 3000
    assert np.all(np.isfinite(sim.truth))
    assert np.max(np.abs(sim.truth[:, 7:10])) < 15.0


def test_cli_lists_the_new_scenarios():
    out = subprocess.run([sys.executable, "-m", "sim_hil", "--list-scenarios"], capture_output=True, text=True)
    assert out.returncode == 0
    listed = [line.split()[0] for line in out.stdout.splitlines() if line.strip()]
    for name in NEW:
        assert name in listed


@pytest.mark.parametrize("name", ["hard-iron", "com-offset", "drag-crisis", "multisine-2d-ne", "gusty-6"])
def test_new_scenario_design_file_round_trips(name, tmp_path):
    sc = SCENARIOS[name]
    path = tmp_path / "design.toml"
    path.write_text(sc.to_toml())
    again = resolve("paper-reference", str(path))
    assert (again.design, again.wind, again.truth, again.filter) == (sc.design, sc.wind, sc.truth, sc.filter)


def test_bad_truth_options_are_rejected(tmp_path):
    with pytest.raises(ConfigError):
        TruthConfig.from_dict({"mag_hard_iron_gauss": [0.1, 0.0]})
    with pytest.raises(ConfigError):
        TruthConfig.from_dict({"mag_hard_iron_gauss": [0.1, "x", 0.0]})
    assert TruthConfig.from_dict({"mag_hard_iron_gauss": [1, 0, 0]}).mag_hard_iron_gauss == (1.0, 0.0, 0.0)
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[truth]\ndrag_model = 'cubic'\n")
    with pytest.raises(ConfigError, match="drag_model"):
        resolve("paper-reference", str(cfg))


def test_a_switched_field_shifts_the_magnetometer_while_it_is_on():
    """A current switched beside the magnetometer ([truth] mag_switched_*): its field added to every reading from
    its time on to its time off, in body axes, and nothing else of the flight changed."""
    sc = SCENARIOS["field-rope"]
    on = replace(sc.truth, mag_switched_gauss=(0.02, -0.01, 0.005), mag_switched_on_s=10.0, mag_switched_off_s=20.0)
    clean = Simulation(sc.design, sc.wind, sc.truth, 30.0, seed=4)
    switched = Simulation(sc.design, sc.wind, on, 30.0, seed=4)
    rows = [(smp.time_usec * 1e-6, *smp.mag) for smp in clean.samples()]
    t, a = np.array(rows)[:, 0], np.array(rows)[:, 1:]
    b = np.array([smp.mag for smp in switched.samples()])
    inside = (t >= 10.0) & (t < 20.0)
    assert 900 <= inside.sum() <= 1100
    np.testing.assert_allclose(b[inside] - a[inside], np.tile(on.mag_switched_gauss, (inside.sum(), 1)), atol=1e-12)
    np.testing.assert_array_equal(b[~inside], a[~inside])
    assert np.array_equal(clean.truth, switched.truth)


def test_hard_iron_shifts_every_magnetometer_reading_by_the_offset():
    sc = SCENARIOS["hard-iron"]
    clean = Simulation(sc.design, sc.wind, replace(sc.truth, mag_hard_iron_gauss=(0.0, 0.0, 0.0)), 30.0, seed=4)
    biased = Simulation(sc.design, sc.wind, sc.truth, 30.0, seed=4)
    a = np.array([smp.mag for smp in clean.samples()])
    b = np.array([smp.mag for smp in biased.samples()])
    # same seed, same noise and motion: the offset is all that differs, in body axes, on the ground and aloft
    np.testing.assert_allclose(b - a, np.tile(sc.truth.mag_hard_iron_gauss, (len(a), 1)), atol=1e-12)
    np.testing.assert_allclose(b.mean(axis=0) - a.mean(axis=0), sc.truth.mag_hard_iron_gauss, atol=1e-12)
    assert np.array_equal(clean.truth, biased.truth)
