"""The IMU's mounting against the balloon's axis, from a recording of the payload hung still from its tether
attachment (``balloon-gs level``): what the design's ``[sensors] imu_roll_deg`` and ``imu_pitch_deg`` declare.

Hung still, the tether's pull (through the attachment and the centre: the balloon's axis) is vertical and the
accelerometer reads gravity's reaction along that axis, in its own axes: ``f = M (0, 0, -g)`` with ``M`` the
body-to-IMU matrix of ``balloon_core.rotation.imu_mount``, so ``pitch = atan2(f_x, -f_z)`` and ``roll =
atan2(-f_y, sqrt(f_x^2 + f_z^2))``. The accelerometer's own turn-on bias is in the reading and is measured with the
mounting: the flight's tilt has the same (what stays is the bias's wander since, which the filter states). The
payload must hang still: a swing or a turn is not the axis, and the spread of the samples' tilt says whether it did."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from balloon_core.atmosphere import G0
from balloon_core.config import SCHEMA
from balloon_core.samples import ImuSample

LEVEL_MIN_SAMPLES = 100  # a second of a 100 Hz IMU at least
LEVEL_STILL_DEG = 0.5  # the samples' tilt may spread this much (1-sigma) about its mean: more is a payload that swings
LEVEL_GRAVITY_SHARE = 0.05  # the mean specific force within this share of g: more is a payload accelerating
LEVEL_MAX_DEG = SCHEMA["sensors"]["imu_roll_deg"].hi  # what the design's keys take


@dataclass(frozen=True)
class Level:
    roll_deg: float  # [sensors] imu_roll_deg
    pitch_deg: float  # [sensors] imu_pitch_deg
    sigma_deg: float  # the mean's own 1-sigma per axis (the samples' spread over sqrt(n))
    spread_deg: float  # the samples' tilt about the mean, 1-sigma
    samples: int
    seconds: float


def level_of(samples: Iterable[ImuSample], start_s: float = 0.0, stop_s: float = math.inf) -> Level:
    """The mounting from the IMU samples between ``start_s`` and ``stop_s`` (s of the sensor's clock since its first
    sample). ValueError (one line) where there are too few or the payload was not still."""
    t0, rows = None, []
    for s in samples:
        if not isinstance(s, ImuSample):
            continue
        t0 = s.t_us if t0 is None else t0
        t = (s.t_us - t0) * 1e-6
        if start_s <= t <= stop_s and all(math.isfinite(v) for v in (s.ax, s.ay, s.az)):
            rows.append((t, s.ax, s.ay, s.az))
    if len(rows) < LEVEL_MIN_SAMPLES:
        span = f"from {start_s:g} s" if math.isinf(stop_s) else f"between {start_s:g} and {stop_s:g} s"
        raise ValueError(f"{len(rows)} IMU samples {span}: at least {LEVEL_MIN_SAMPLES} are needed")
    a = np.array(rows)
    f = a[:, 1:4].mean(axis=0)
    if abs(float(np.linalg.norm(f)) - G0) > LEVEL_GRAVITY_SHARE * G0:
        raise ValueError(f"the mean specific force is {np.linalg.norm(f):.2f} m/s^2, not gravity's {G0:.2f}: "
                         "the payload was not hanging still")  # fmt: skip
    if not f[2] < 0.0:
        raise ValueError("the accelerometer's z does not point down the hung payload (its z reads +g): not a mounting "
                         "a degree or two askew")  # fmt: skip
    pitch = np.degrees(np.arctan2(a[:, 1], -a[:, 3]))
    roll = np.degrees(np.arctan2(-a[:, 2], np.hypot(a[:, 1], a[:, 3])))
    spread = float(math.sqrt(0.5 * (np.var(pitch) + np.var(roll))))
    if spread > LEVEL_STILL_DEG:
        raise ValueError(f"the tilt spread {spread:.2f} deg (1-sigma) about its mean, over {LEVEL_STILL_DEG:g}: the "
                         "payload was not hanging still (it swung or turned; give --from/--to around a still stretch)")
    # as printed, to a thousandth of a degree (+ 0.0: no "-0.000")
    pitch_deg = round(math.degrees(math.atan2(f[0], -f[2])), 3) + 0.0
    roll_deg = round(math.degrees(math.atan2(-f[1], math.hypot(f[0], f[2]))), 3) + 0.0
    if max(abs(roll_deg), abs(pitch_deg)) > LEVEL_MAX_DEG:
        raise ValueError(f"the IMU is rolled {roll_deg:.1f} and pitched {pitch_deg:.1f} deg against the hung axis, "
                         f"beyond the design's +-{LEVEL_MAX_DEG:g}: a board that far askew is mounted wrong, or "
                         "the payload did not hang from its tether attachment")  # fmt: skip
    return Level(roll_deg, pitch_deg, spread / math.sqrt(len(a)), spread, len(a), float(a[-1, 0] - a[0, 0]))


def format_level(lv: Level, path: str) -> str:
    """The lines a user pastes into the design file, and what they rest on."""
    return (f"# {path}: the payload hung still for {lv.seconds:.1f} s ({lv.samples} IMU samples, its tilt "
            f"{lv.spread_deg:.3f} deg about the mean, the mean's own 1-sigma {lv.sigma_deg:.4f} deg)\n"
            f"[sensors]\nimu_roll_deg = {lv.roll_deg:.3f}\nimu_pitch_deg = {lv.pitch_deg:.3f}")
