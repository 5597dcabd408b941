"""tools/attitude_step.py: an error of the attitude about the magnetic field's axis (which the magnetometer cannot
see) moves the wind across, and the filter takes it back out (the accelerometer holds the tilt that rotation
carries); the tool's difference of two runs is the step's alone; a wrong scenario is a user error."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

from sim_hil.scenarios import SCENARIOS
from tools.attitude_step import step_response

ROOT = Path(__file__).resolve().parents[2]


def test_an_attitude_error_about_the_field_is_recovered_and_the_wind_with_it():
    """A 1 deg step of the attitude about the field in a steady 3 m/s from 200 deg: the wind across follows it a
    little and briefly (0.06-0.07 m/s at 2 s, gone by 10 s: the level rows hold the tilt that rotation carries; before
    them it peaked at 0.51 m/s and took 100 s), about alike either way round (the two within a third of the peak of
    each other), and nothing is left of either."""
    sc = SCENARIOS["field-rope-multisine"]
    sc = dataclasses.replace(sc, wind=dataclasses.replace(sc.wind, kind="steady", from_deg=200.0))
    up, down, none = step_response(sc, (1.0, -1.0, 0.0))
    assert all(abs(a) < 1e-6 and abs(c) < 1e-6 for _, a, c in none)  # the same samples: only the step differs
    peak = max(abs(c) for _, _, c in up + down)
    assert 0.02 < peak < 0.15  # the wind across follows the turned attitude, a little ...
    for (_, a1, c1), (_, a2, c2) in zip(up, down):  # ... either way round about alike (the linear response) ...
        assert abs(c1 + c2) <= 0.45 * peak and abs(a1 + a2) <= 0.45 * peak
    late = [abs(c) for run in (up, down) for t, _, c in run if t >= 10.0]
    assert late and max(late) < 0.3 * peak  # ... and both are taken back out within 10 s: no lock-in


def test_an_unknown_scenario_is_a_user_error():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "attitude_step.py"), "nonesuch"],
                       capture_output=True, text=True, cwd=ROOT)  # fmt: skip
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "invalid choice: 'nonesuch'" in r.stderr
