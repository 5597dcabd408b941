"""What one case records, and how the summary over seeds picks the worst seed of each metric.

``worst``: "min" (lower is worse), "max" (higher is worse), "abs" (largest magnitude, sign kept),
"ratio" (farthest from 1 in log: over- and under-confidence alike), "mode" (a category: the most common)."""

from __future__ import annotations

import math

import numpy as np

#: name -> (worst rule, description with unit)
METRICS: dict[str, tuple[str, str]] = {
    "band_skill": ("min", "1 - band RMSE / band RMSE of the constant true mean (< 0.05 Hz); 1 perfect, 0 no better"),
    "band_rmse_mps": ("max", "horizontal RMS error of the low-passed (< 0.05 Hz) estimate, m/s"),
    "raw_rmse_mps": ("max", "horizontal RMS error of the raw 10 Hz estimate, m/s"),
    "speed_error_pct": ("abs", "error of the mean wind speed, % of the true mean"),
    "direction_error_deg": ("abs", "error of the mean wind direction, deg"),
    "error_ratio": ("ratio", "actual raw RMS error / RMS reported horiz_accuracy (honest = 1)"),
    "accuracy_mps": ("max", "RMS of the reported horiz_accuracy, m/s"),
    "h_err_max": ("max", "multisine wind: largest |H - 1| along and across at its lines <= 0.05 Hz"),
    "lift_margin_n": ("min", "net free lift at the ground: buoyancy - skin, avionics, gas and the whole rope, N"),
    "lift_margin_frac": ("min", "net free lift / buoyancy"),
    "blowdown_deg": ("max", "mean lean of the anchor-balloon chord from vertical (truth), deg"),
    "height_m": ("min", "mean height of the balloon centre above the anchor (truth), m"),
    "slack_frac": ("max", "fraction of the scored time with the tether slack (truth)"),
    "mode_switches": ("max", "estimator mode switches (ground / free / taut)"),
    "resets": ("max", "estimator resets: taut placements + numeric + time + barometer"),
    "tilt_err_deg": ("max", "RMS roll/pitch error of the on-board orientation, deg"),
    "yaw_err_deg": ("max", "RMS heading error of the on-board orientation, deg"),
    "tilt_sigma_deg": ("max", "RMS of the filter's own 1-sigma tilt (tilt_err_deg over it: honest?), deg"),
    "drag_scale": ("ratio", "the filter's drag scale at the end (its C_d over the design's; 1: the design's)"),
    "drag_scale_sigma": ("max", "the drag scale's 1-sigma at the end (relative)"),
    "accuracy_factor": (
        "max",
        "RMS of the consistency monitor's factor on the stated accuracy (1: the model explains every source)",
    ),
    "factor_source": (
        "mode",
        "the source (index in firmware_py.estimator.consistency.SOURCES) whose windowed NIS set "
        "that factor most of the time it was at least FACTOR_SHOWN; NaN: never",
    ),
    "wall_time_s": ("max", "wall time of the case on its worker, s"),
}
#: the default set summarised and plotted
MAIN = ("band_skill", "band_rmse_mps", "speed_error_pct", "direction_error_deg", "error_ratio", "h_err_max",
        "lift_margin_n", "blowdown_deg", "slack_frac", "resets")  # fmt: skip
#: the consistency monitor's factor counted as setting a flight's caution from here (its NIS 1.56: a quarter more)
FACTOR_SHOWN = 1.25
#: |H - 1| is summarised over lines up to here (the paper's usable band)
H_BAND_HZ = 0.05


def h_column(axis: str, f_hz: float) -> str:
    return f"h_err_{axis}_{f_hz:g}hz"


def worst(rule: str, values) -> float:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not len(v):
        return math.nan
    if rule == "min":
        return float(v.min())
    if rule == "max":
        return float(v.max())
    if rule == "abs":
        return float(v[np.argmax(np.abs(v))])
    if rule == "ratio":
        return float(v[np.argmax(np.abs(np.log(np.clip(v, 1e-9, 1e9))))])
    if rule == "mode":  # a category: the most common value (the smallest of a tie)
        values, counts = np.unique(v, return_counts=True)
        return float(values[np.argmax(counts)])
    raise ValueError(rule)


def rule_of(name: str) -> str:
    if name in METRICS:
        return METRICS[name][0]
    return "max" if name.startswith("h_err_") else "abs"
