"""postflight.level: the IMU's mounting from the payload hung still (balloon-gs level), on synthetic samples: the
mounting read back through rotation.imu_mount's own convention, and what the design's keys cannot take refused."""

from __future__ import annotations

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from balloon_core.rotation import body_to_imu, imu_mount
from balloon_core.samples import ImuSample
from postflight.level import format_level, level_of


def hung(roll: float, pitch: float, n: int = 500, noise: float = 0.01, seed: int = 1) -> list[ImuSample]:
    """A still payload's IMU samples at 100 Hz: gravity's reaction up the balloon's axis, in the IMU's axes."""
    m = imu_mount(roll, pitch) or (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    f = body_to_imu(m, 0.0, 0.0, -G0)
    rng = np.random.default_rng(seed)
    return [ImuSample(10_000 * k, *(f + noise * rng.standard_normal(3)), 0.0, 0.0, 0.0) for k in range(n)]


@pytest.mark.parametrize(("roll", "pitch"), [(0.0, 0.0), (2.0, -1.0), (-7.5, 9.0)])
def test_the_mounting_read_back(roll, pitch):
    lv = level_of(hung(roll, pitch))
    assert lv.roll_deg == pytest.approx(roll, abs=0.01) and lv.pitch_deg == pytest.approx(pitch, abs=0.01)
    assert lv.samples == 500 and lv.sigma_deg < 0.01
    if roll == 0.0:  # a mounting of none prints none, not "-0.000", whatever the noise's sign
        for seed in range(1, 6):
            assert "-0.000" not in format_level(level_of(hung(roll, pitch, seed=seed)), "hang.tlog")


def test_what_the_design_cannot_take_or_a_payload_upside_down_is_refused():
    with pytest.raises(ValueError, match="beyond the design"):
        level_of(hung(0.0, 15.0))
    upside = [s._replace(az=-s.az) for s in hung(0.0, 0.0)]
    with pytest.raises(ValueError, match="does not point down"):
        level_of(upside)
