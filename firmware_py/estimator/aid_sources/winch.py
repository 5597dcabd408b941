"""The winch (docs/estimator.md, "The winch"): WINCH_STATUS's paid-out length is the tether's length
while it changes; the reel's speed is the rate the chord grows at.

A new length L replaces the design's in the model (``BalloonModel.tether_length_m``: the free ascent's
airborne rope, the taut rope's weight and shape) and scales the rope's shape with it (``RopeShape``:
the chord, the weight the rod carries and the calm share, all in proportion L_new / L_old: the sag's
share of the length stays, and the slow shape update corrects the rest). The taut radial-rate row then
expects the radial velocity the reel gives, ``RopeShape.rate_mps`` (the speed times chord / L), instead
of zero; a winch silent for ``WINCH_TIMEOUT_S`` stops (rate 0, the last length holds). Without
WINCH_STATUS nothing here runs: the design's length holds.

The winch's tension (the pull at the anchor) is kept (``Estimator.winch_tension_n``) for the record;
the filter does not fuse it (docs/estimator.md says why and what it could do)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from firmware_py.estimator.params import WINCH_LENGTH_MAX_M, WINCH_LENGTH_MIN_M, WINCH_SPEED_MAX_MPS, WINCH_TIMEOUT_S

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def init_winch(est: Estimator) -> None:
    """No winch heard yet: the design's length (the model as built)."""
    est.winch_samples = 0
    est.winch_t_us = -1  # the sensor clock when the last WINCH_STATUS arrived (-1: never)
    est.winch_tension_n = math.nan  # the pull at the anchor, N (NaN: not measured)


def set_line_length(est: Estimator, length_m: float) -> None:
    """The tether's length is now ``length_m``: the model's length and the rope's shape in proportion."""
    m = est.model
    old = m.tether_length_m
    if length_m == old:
        return
    scale = length_m / old
    est.model = est.ekf.model = replace(m, tether_length_m=length_m, rope_drag_m2=m.rope_drag_m2 * scale)
    rope = est.ekf.rope
    rope.chord_m *= scale
    rope.weight_n *= scale
    rope.calm_weight_n *= scale


def winch_sample(est: Estimator, t_us: int, line_length_m: float, speed_mps: float, tension_n: float) -> bool:
    """A WINCH_STATUS (``t_us`` on the sensor clock: when it arrived). A length outside
    [WINCH_LENGTH_MIN_M, WINCH_LENGTH_MAX_M] or not finite is rejected; a speed that is not finite or
    beyond WINCH_SPEED_MAX_MPS counts as 0."""
    if not (math.isfinite(line_length_m) and WINCH_LENGTH_MIN_M <= line_length_m <= WINCH_LENGTH_MAX_M):
        return False
    est.winch_samples += 1
    est.winch_t_us = t_us
    est.winch_tension_n = tension_n if math.isfinite(tension_n) and tension_n >= 0.0 else math.nan
    set_line_length(est, line_length_m)
    rope = est.ekf.rope
    speed = speed_mps if math.isfinite(speed_mps) and abs(speed_mps) <= WINCH_SPEED_MAX_MPS else 0.0
    rope.rate_mps = speed * rope.chord_m / line_length_m
    return True


def control_winch(est: Estimator) -> None:
    """A winch that falls silent while it reels: stop expecting the reel's motion."""
    rope = est.ekf.rope
    if rope.rate_mps != 0.0 and est.t_last_us - est.winch_t_us > WINCH_TIMEOUT_S * 1e6:
        rope.rate_mps = 0.0
