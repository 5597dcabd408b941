import signal

import pytest

from balloon_core.config import Design
from sim_hil.dynamics import BalloonPhysics, TruthConfig


@pytest.fixture
def ref_physics() -> BalloonPhysics:
    return BalloonPhysics.from_design(Design(), TruthConfig(rope_model="paper", rope_drag=False))


@pytest.fixture(autouse=True)
def keep_signal_handlers():
    """The programs install SIGINT/SIGTERM handlers (balloon_core.userargs.stop_flag): every test gets
    pytest's own back."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, h in saved.items():
        signal.signal(s, h)
