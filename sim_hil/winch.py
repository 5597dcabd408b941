"""The winch at the anchor (docs/model.md, "The winch"): a schedule of paid-out lengths, the rope paid
out and in along it, and the winch's own report (WINCH_STATUS at ``status_hz`` from its component,
MAV_COMP_ID_WINCH) with a load cell's tension.

The schedule is a list of (time, length) corners joined by straight lines: the length at any time and
the reel's speed (the slope) follow from it, held at the last corner after it. Before the first corner
the first length holds. A slope beyond ``max_speed_mps`` is refused: the winch cannot reel that fast.
Pure functions over plain floats; the rope's response to a changing length is sim_hil/rope.py's
(``LumpedRope.at_length``: the segments share the paid-out length)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from balloon_core.atmosphere import G0
from balloon_core.config import build_section, check_winch_schedule

WINCH_STATUS_HEALTHY = 1  # MAV_WINCH_STATUS_FLAG: HEALTHY
WINCH_STATUS_MOVING = 4  # MOVING
WINCH_STATUS_CLUTCH_ENGAGED = 8


@dataclass(frozen=True)
class WinchConfig:
    """The [winch] section: the schedule and the winch's report. No corners: no winch (the design's
    length throughout, no WINCH_STATUS)."""

    times_s: tuple[float, ...] = ()
    lengths_m: tuple[float, ...] = ()
    max_speed_mps: float = 1.0
    status_hz: float = 10.0
    tension_noise_kg: float = 0.05  # 1-sigma white noise of the load cell
    tension_measured: bool = True  # False: the winch has no load cell (tension NaN)

    def __post_init__(self) -> None:
        check_winch_schedule(self.times_s, self.lengths_m, self.max_speed_mps)  # as every program checks it

    @property
    def enabled(self) -> bool:
        return len(self.times_s) > 0

    @classmethod
    def from_dict(cls, values: dict) -> WinchConfig:
        values = {k: tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else v for k, v in values.items()}
        return build_section(cls, "winch", values)


def line_length_m(cfg: WinchConfig, time_s: float) -> tuple[float, float]:
    """(paid-out length m, reel speed m/s: positive paying out) at ``time_s`` along the schedule."""
    t, lengths = cfg.times_s, cfg.lengths_m
    if time_s <= t[0]:
        return lengths[0], 0.0
    if time_s >= t[-1]:
        return lengths[-1], 0.0
    i = bisect.bisect_right(t, time_s)
    speed = (lengths[i] - lengths[i - 1]) / (t[i] - t[i - 1])
    return lengths[i - 1] + speed * (time_s - t[i - 1]), speed


def status_flags(speed_mps: float) -> int:
    """WINCH_STATUS ``status``: healthy, clutch engaged, moving while it reels."""
    moving = WINCH_STATUS_MOVING if speed_mps != 0.0 else 0
    return WINCH_STATUS_HEALTHY | WINCH_STATUS_CLUTCH_ENGAGED | moving


def load_cell_kg(tension_n: float, noise: float, cfg: WinchConfig) -> float:
    """The load cell's reading (kg, as WINCH_STATUS carries it) of the pull at the anchor; NaN without one."""
    if not cfg.tension_measured:
        return math.nan
    return max(0.0, tension_n / G0 + cfg.tension_noise_kg * noise)
