import pytest

from balloon_core.config import Design
from sim_hil.dynamics import BalloonPhysics, TruthConfig


@pytest.fixture
def ref_physics() -> BalloonPhysics:
    return BalloonPhysics.from_design(Design(), TruthConfig(rope_model="paper", rope_drag=False))
