"""Wind averages by the WMO conventions (WMO-No. 8, Guide to Instruments and Methods of Observation,
Vol. I, Ch. 5 "Measurement of surface wind"): pure functions over numpy arrays.

Per averaging period (aligned to whole multiples of the period on the clock, as WMO reports are):
- scalar mean speed: mean of the sample speeds;
- vector mean: the mean of the velocity vectors, its speed and meteorological direction (from);
- standard deviations (population): of the speed, of the eastward (u) and northward (v) components, and of
  the direction by the Yamartino (1984) one-pass method;
- gust: the highest 3-s running mean of the speed whose window lies wholly inside the period (NaN when
  the period is shorter than the gust window);
- turbulence intensity: std of the speed / scalar mean speed.

Winds here are the air's velocity TOWARD north/east (``wind_n``, ``wind_e``) as the estimator gives them;
directions are where the wind blows FROM, degrees clockwise from north.
"""

from __future__ import annotations

import math

import numpy as np

from balloon_core.score import direction_from_deg
from postflight.product import FLAG_WIND_UNKNOWN, WindProduct

GUST_WINDOW_S = 3.0  # WMO: gusts are 3-s running means
YAMARTINO_K = 2.0 / math.sqrt(3.0) - 1.0  # 0.1547


def speed_direction_sigma(wind_n: np.ndarray, wind_e: np.ndarray, sigma_n: np.ndarray,
                          sigma_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """1-sigma of the speed (m/s) and of the direction (deg) by linear propagation of independent N/E errors.

    speed s = |(n, e)|:      sigma_s^2 = (n^2 sigma_n^2 + e^2 sigma_e^2) / s^2
    direction atan2(-e, -n): sigma_d^2 = (e^2 sigma_n^2 + n^2 sigma_e^2) / s^4   (rad^2)
    Low-speed guard: the direction's sigma is capped at 180 deg (unknown; also at s = 0), and at s = 0 the
    speed's sigma is max(sigma_n, sigma_e)."""
    n, e = np.asarray(wind_n, float), np.asarray(wind_e, float)
    sn2, se2 = np.asarray(sigma_n, float) ** 2, np.asarray(sigma_e, float) ** 2
    s2 = n * n + e * e
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_s = np.where(s2 > 0, np.sqrt((n * n * sn2 + e * e * se2) / s2), np.sqrt(np.maximum(sn2, se2)))
        sig_d = np.degrees(np.sqrt(e * e * sn2 + n * n * se2) / s2)
    sig_d = np.where(s2 > 0, np.minimum(sig_d, 180.0), 180.0)
    sig_d = np.where(np.isfinite(s2 + sn2 + se2), sig_d, np.nan)
    return sig_s, sig_d


def yamartino_std_deg(sin_mean: np.ndarray, cos_mean: np.ndarray) -> np.ndarray:
    """Yamartino (1984) direction standard deviation from the mean sine and cosine of the directions, deg."""
    eps = np.sqrt(np.clip(1.0 - (np.asarray(sin_mean) ** 2 + np.asarray(cos_mean) ** 2), 0.0, 1.0))
    return np.degrees(np.arcsin(eps) * (1.0 + YAMARTINO_K * eps**3))


# key, units, long_name, CF standard_name ("" none), cell_methods over time
AVERAGE_FIELDS: tuple[tuple[str, str, str, str, str], ...] = (
    ("n_samples", "1", "number of valid samples in the period", "", ""),
    ("valid_fraction", "1", "valid samples / samples the period would hold", "", ""),
    ("eastward_wind", "m s-1", "vector mean eastward wind (u)", "eastward_wind", "time: mean"),
    ("northward_wind", "m s-1", "vector mean northward wind (v)", "northward_wind", "time: mean"),
    ("scalar_mean_wind_speed", "m s-1", "scalar mean wind speed (mean of the sample speeds)", "wind_speed",
     "time: mean"),
    ("vector_mean_wind_speed", "m s-1", "speed of the vector mean wind", "", ""),
    ("vector_mean_wind_from_direction", "degree", "direction of the vector mean wind (from, clockwise from north)",
     "wind_from_direction", "time: mean"),
    ("wind_speed_std", "m s-1", "standard deviation of the wind speed", "", "time: standard_deviation"),
    ("eastward_wind_std", "m s-1", "standard deviation of the eastward wind (u)", "", "time: standard_deviation"),
    ("northward_wind_std", "m s-1", "standard deviation of the northward wind (v)", "", "time: standard_deviation"),
    ("wind_from_direction_std", "degree", "standard deviation of the wind direction (Yamartino method)", "",
     "time: standard_deviation"),
    ("wind_speed_of_gust", "m s-1", "gust: highest 3-s running mean of the wind speed in the period",
     "wind_speed_of_gust", "time: maximum"),
    ("turbulence_intensity", "1", "turbulence intensity: std of the speed / scalar mean speed", "", ""),
)  # fmt: skip


def wind_averages(time_s: np.ndarray, wind_n: np.ndarray, wind_e: np.ndarray, period_s: float, *,
                  clock_offset_s: float = 0.0, gust_window_s: float = GUST_WINDOW_S, min_fraction: float = 0.5,
                  calm_mps: float = 0.1) -> dict[str, np.ndarray]:  # fmt: skip
    """WMO averages of a sampled wind over periods of ``period_s``.

    ``time_s`` increasing sample times, uniformly sampled apart from gaps; periods are aligned on
    ``time_s + clock_offset_s`` (pass the UNIX time of ``time_s == 0`` to align 10-min periods to UTC).
    NaN samples are left out; a period with less than ``min_fraction`` of its samples valid gets NaN
    statistics (its counts are still given). Turbulence intensity is NaN below ``calm_mps`` mean speed.
    Returns columns: ``time_start_s``, ``time_end_s`` (on the ``time_s`` clock) and every key of
    ``AVERAGE_FIELDS``; one row per period that holds any sample."""
    t = np.asarray(time_s, float)
    n = np.asarray(wind_n, float)
    e = np.asarray(wind_e, float)
    if t.ndim != 1 or t.shape != n.shape or t.shape != e.shape:
        raise ValueError("time_s, wind_n and wind_e must be 1-D arrays of the same length")
    if period_s <= 0:
        raise ValueError("period_s must be > 0")
    keys = ["time_start_s", "time_end_s", *(f[0] for f in AVERAGE_FIELDS)]
    if len(t) == 0:
        return {k: np.zeros(0) for k in keys}
    if np.any(np.diff(t) <= 0):
        raise ValueError("time_s must be strictly increasing")
    dt = float(np.median(np.diff(t))) if len(t) > 1 else period_s
    k = np.floor((t + clock_offset_s) / period_s + 1e-9).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])  # k is non-decreasing: periods are contiguous runs
    group = np.cumsum(np.r_[True, k[1:] != k[:-1]]) - 1
    valid = np.isfinite(n) & np.isfinite(e) & np.isfinite(t)
    nv = np.add.reduceat(valid.astype(float), starts)
    with np.errstate(divide="ignore", invalid="ignore"):

        def mean(x: np.ndarray, mask: np.ndarray = valid) -> np.ndarray:
            return np.add.reduceat(np.where(mask, x, 0.0), starts) / np.add.reduceat(mask.astype(float), starts)

        def std(x: np.ndarray, m: np.ndarray) -> np.ndarray:
            d = np.where(valid, x - m[group], 0.0)
            return np.sqrt(np.add.reduceat(d * d, starts) / nv)

        speed = np.hypot(n, e)
        u_m, v_m, s_m = mean(e), mean(n), mean(speed)
        moving = valid & (speed > 0)  # a calm sample has no direction
        d_rad = np.arctan2(-e, -n)
        sin_m, cos_m = mean(np.sin(d_rad), moving), mean(np.cos(d_rad), moving)
        vec_speed = np.hypot(u_m, v_m)
        out = {
            "time_start_s": k[starts] * period_s - clock_offset_s,
            "time_end_s": (k[starts] + 1) * period_s - clock_offset_s,
            "n_samples": nv.astype(np.int32),
            "valid_fraction": np.minimum(nv * dt / period_s, 1.0),
            "eastward_wind": u_m,
            "northward_wind": v_m,
            "scalar_mean_wind_speed": s_m,
            "vector_mean_wind_speed": vec_speed,
            "vector_mean_wind_from_direction": np.where(vec_speed > 0, direction_from_deg(v_m, u_m), np.nan),
            "wind_speed_std": std(speed, s_m),
            "eastward_wind_std": std(e, u_m),
            "northward_wind_std": std(n, v_m),
            "wind_from_direction_std": yamartino_std_deg(sin_m, cos_m),
            "wind_speed_of_gust": _gust(t, speed, valid, k, starts, dt, gust_window_s),
            "turbulence_intensity": np.where(s_m >= calm_mps, std(speed, s_m) / s_m, np.nan),
        }
    poor = out["valid_fraction"] < min_fraction
    for f in AVERAGE_FIELDS[2:]:
        out[f[0]] = np.where(poor, np.nan, out[f[0]])
    return out


def _gust(t: np.ndarray, speed: np.ndarray, valid: np.ndarray, k: np.ndarray, starts: np.ndarray, dt: float,
          window_s: float) -> np.ndarray:  # fmt: skip
    """Highest running mean of ``speed`` over ``window_s`` whose samples are all valid, gap-free and in one
    period; NaN for a period without such a window."""
    w = max(1, int(round(window_s / dt)))
    out = np.full(len(starts), np.nan)
    if len(t) < w:
        return out
    c = np.r_[0.0, np.cumsum(np.where(valid, speed, 0.0))]
    cv = np.r_[0, np.cumsum(valid)]
    i = np.arange(len(t) - w + 1)
    j = i + w - 1
    run = (c[j + 1] - c[i]) / w
    ok = (cv[j + 1] - cv[i] == w) & (k[i] == k[j]) & (t[j] - t[i] <= (w - 1) * dt * 1.5 + 1e-9)
    vals = np.full(len(t), -np.inf)
    vals[i] = np.where(ok, run, -np.inf)
    best = np.maximum.reduceat(vals, starts)
    out[np.isfinite(best)] = best[np.isfinite(best)]
    return out


def product_averages(product: WindProduct, period_s: float) -> dict[str, np.ndarray]:
    """WMO averages of the smoothed wind; samples flagged wind_unknown are left out."""
    unknown = (np.asarray(product.flags).astype(np.int64) & FLAG_WIND_UNKNOWN) != 0
    n = np.where(unknown, np.nan, product.wind_n)
    e = np.where(unknown, np.nan, product.wind_e)
    offset = product.utc_start_s if product.utc_start_s is not None else 0.0
    return wind_averages(product.time_s, n, e, period_s, clock_offset_s=offset)
