"""tools/rope_waves.py: the taut model's pull direction at the truth's state against the balloon's axis. In the
paper's world the filter's model is the truth's, so the two agree at every line; on the real rope they agree where
its static shape holds (the slowest lines), and its waves are what the model leaves out above."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from balloon_core.score import sinusoid_fit
from sim_hil.scenarios import SCENARIOS
from tools.rope_waves import fly

pytestmark = pytest.mark.slow  # two 300 s flights on the Python core
LINES = (0.01, 0.02, 0.05, 0.1, 0.2)  # the multisines' lines in a 240 s window


@functools.cache
def flown(scenario: str) -> np.ndarray:
    return fly(scenario, 1)[0]


def ratios(scenario: str, over: int = 2) -> dict[float, complex]:
    """The body axis over the model's pull (``over`` 2) or over the chord (3), line by line."""
    rows = flown(scenario)
    z = sinusoid_fit(rows[:, 0], rows[:, 1:4], LINES)
    return {f: complex(z[k, 0] / z[k, over - 1]) for k, f in enumerate(LINES) if f < 0.15}


def test_the_paper_model_is_the_paper_truth_at_every_line():
    """The paper's rod in truth and filter, the wind from the north-east on both axes (north and east both in play):
    the body axis follows the model's pull within 5 % and 3 deg up to 0.1 Hz (a sign, an axis or a lean mixed up in
    the tool, or a generated model that left the truth's physics, reads far off), while the chord does not (the
    pull is not along it: the rope's weight hangs at the balloon)."""
    sc = SCENARIOS["multisine-2d-ne"]
    assert sc.truth.rope_model == sc.filter.rope_model == "paper" and sc.wind.from_deg % 90.0 != 0.0
    for f, r in ratios("multisine-2d-ne").items():
        assert abs(abs(r) - 1.0) < 0.05 and abs(math.degrees(np.angle(r))) < 3.0, (f, r)
    rows = flown("multisine-2d-ne")
    assert abs(np.mean(rows[:, 3]) - np.mean(rows[:, 1])) > math.radians(5.0)


def test_the_real_ropes_static_shape_holds_and_its_waves_are_left_out():
    """The lumped rope in truth, the catenary in the filter: within 20 % and 10 deg at 0.01-0.02 Hz, but at 0.1 Hz
    the balloon's axis swings with the rope's transverse waves, which no static shape holds (more than twice the
    model's: the real rope's over-read there, docs/estimator.md)."""
    r = ratios("field-rope-multisine")
    for f in (0.01, 0.02):
        assert abs(abs(r[f]) - 1.0) < 0.2 and abs(math.degrees(np.angle(r[f]))) < 10.0, (f, r[f])
    assert abs(r[0.1]) > 2.0
