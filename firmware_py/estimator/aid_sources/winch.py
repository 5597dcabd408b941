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

from firmware_py.estimator.params import (
    WINCH_HEIGHT_TOL_M,
    WINCH_LENGTH_MARGIN_M,
    WINCH_LENGTH_MIN_M,
    WINCH_REJECT_HEIGHT,
    WINCH_REJECT_LENGTH,
    WINCH_REJECT_SPEED,
    WINCH_SPEED_MAX_MPS,
    WINCH_TIMEOUT_S,
)

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def init_winch(est: Estimator) -> None:
    """No winch heard yet: the design's length (the model as built)."""
    est.winch_samples = 0  # WINCH_STATUS used
    est.winch_rejected = 0  # ... rejected as implausible (winch_plausible)
    est.winch_reject_reason = 0  # why the last one was (WINCH_REJECT_*; 0: none yet)
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


def winch_plausible(est: Estimator, line_length_m: float, speed_mps: float) -> int:
    """0 if a WINCH_STATUS is plausible, else why not (WINCH_REJECT_*): the line length finite, within
    [WINCH_LENGTH_MIN_M, the design's tether length (the rope on the drum) + WINCH_LENGTH_MARGIN_M] and
    not shorter than the balloon's barometric height less WINCH_HEIGHT_TOL_M (no height yet: not checked);
    the reel speed finite and within WINCH_SPEED_MAX_MPS."""
    drum_m = est.design.tether.length_m
    if not (math.isfinite(line_length_m) and WINCH_LENGTH_MIN_M <= line_length_m <= drum_m + WINCH_LENGTH_MARGIN_M):
        return WINCH_REJECT_LENGTH
    if line_length_m < est.height_baro - WINCH_HEIGHT_TOL_M:  # (NaN before the barometer's zero: False)
        return WINCH_REJECT_HEIGHT
    if not (math.isfinite(speed_mps) and abs(speed_mps) <= WINCH_SPEED_MAX_MPS):
        return WINCH_REJECT_SPEED
    return 0


def winch_sample(est: Estimator, t_us: int, line_length_m: float, speed_mps: float, tension_n: float) -> bool:
    """A WINCH_STATUS (``t_us`` on the sensor clock: when it arrived); an implausible one
    (``winch_plausible``) is rejected and counted."""
    why = winch_plausible(est, line_length_m, speed_mps)
    if why:
        est.winch_rejected += 1
        est.winch_reject_reason = why
        return False
    est.winch_samples += 1
    est.winch_t_us = t_us
    est.winch_tension_n = tension_n if math.isfinite(tension_n) and tension_n >= 0.0 else math.nan
    set_line_length(est, line_length_m)
    rope = est.ekf.rope
    rope.rate_mps = speed_mps * rope.chord_m / line_length_m
    return True


# why a WINCH_STATUS was rejected, in words (the summary, when the winch is ignored wholesale)
REJECT_WORDS = {
    WINCH_REJECT_LENGTH: "line length not plausible (not finite, under 1 m or beyond [tether] length_m, the rope "
                         "on the drum)",
    WINCH_REJECT_HEIGHT: "line length shorter than the balloon's barometric height",
    WINCH_REJECT_SPEED: "reel speed not plausible (not finite or beyond a winch's)",
}  # fmt: skip


def counts_text(what: str, ignored: str, used: int, rejected: int, reason: int, words: dict[int, str]) -> str:
    """``winch: 12 used, 3 rejected``; a source rejected wholesale says why: ``winch: 0 used, 120
    rejected (WINCH_STATUS ignored: line length not plausible ...)``."""
    text = f"{what}: {used} used, {rejected} rejected"
    if rejected and not used:
        text += f" ({ignored} ignored: {words.get(reason, 'not plausible')})"
    return text


def winch_counts(est: Estimator) -> str:
    """What the estimator made of the WINCH_STATUS it was given (either core: the same counters)."""
    return counts_text("winch", "WINCH_STATUS", est.winch_samples, est.winch_rejected, est.winch_reject_reason,
                       REJECT_WORDS)  # fmt: skip


def control_winch(est: Estimator) -> None:
    """A winch that falls silent while it reels: stop expecting the reel's motion."""
    rope = est.ekf.rope
    if rope.rate_mps != 0.0 and est.t_last_us - est.winch_t_us > WINCH_TIMEOUT_S * 1e6:
        rope.rate_mps = 0.0
