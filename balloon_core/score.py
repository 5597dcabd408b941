"""Scores of a wind estimate against the simulator's truth, judged the way its users would judge it.

- band RMSE: horizontal-vector RMS error after both series are low-passed below ``band_hz``
  (zero-phase FFT filter on a common 10 Hz grid), from ``start_s`` on;
- band skill: 1 - band RMSE / band RMSE of a constant equal to the true mean over the same window
  (1 = perfect, 0 = no better than knowing the mean; NaN when the truth does not fluctuate in the band);
- mean speed error (% of the true mean speed) and mean direction error (deg), of the mean vectors;
- error ratio: actual raw RMS error / RMS of the reported horiz_accuracy (honest = 1, > 1 = overconfident);
- ``response``: complex transfer function H = estimate / truth per frequency, along the true mean wind
  and across it, by a least-squares sinusoid fit (multisine wind): gain |H|, phase arg H, error |H - 1|.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GRID_HZ = 10.0


@dataclass(frozen=True)
class Score:
    band_rmse_mps: float
    raw_rmse_mps: float
    speed_error_pct: float
    direction_error_deg: float
    mean_accuracy_mps: float  # RMS of the reported horiz_accuracy
    error_ratio: float  # actual raw RMS error / RMS reported accuracy: honest = 1, > 1 = overconfident
    band_skill: float  # 1 - band RMSE / band RMSE of the constant true mean; NaN if the truth is steady in the band
    true_speed_mps: float
    est_speed_mps: float
    duration_s: float
    accuracy_not_finite: int = 0  # estimates scored whose accuracy is not a finite number: left out of its statistics
    beyond_3sigma: float = math.nan  # the share of estimates (on the grid) whose error is beyond 3 x their accuracy

    def as_row(self) -> dict:
        return {k: round(v, 3) if isinstance(v, float) else v for k, v in self.__dict__.items()}


def lowpass(x: np.ndarray, fs: float, cutoff_hz: float) -> np.ndarray:
    """Zero-phase low-pass: FFT with a raised-cosine roll-off from 0.8 to 1.2 x cutoff, after removing
    the linear trend (so the series' ends do not ring)."""
    n = len(x)
    t = np.arange(n)
    coef = np.polyfit(t, x, 1)
    trend = np.polyval(coef, t)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    lo, hi = 0.8 * cutoff_hz, 1.2 * cutoff_hz
    gain = np.clip((hi - f) / (hi - lo), 0.0, 1.0)
    gain = 0.5 - 0.5 * np.cos(math.pi * gain)
    return np.fft.irfft(np.fft.rfft(x - trend) * gain, n=n) + trend


MIN_BAND_STD_MPS = 0.02  # below this the truth does not fluctuate in the band: skill is meaningless


def on_grid(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s):
    """Both series on a common 10 Hz grid from ``start_s`` on (estimate samples that are not finite dropped; an
    accuracy that is not finite is left out of the accuracy's series alone, NaN throughout where none is)."""
    t_est, est_n, est_e, acc = (np.asarray(x, dtype=float) for x in (t_est, est_n, est_e, acc))
    ok = np.isfinite(t_est) & np.isfinite(est_n) & np.isfinite(est_e)
    t_est, est_n, est_e, acc = t_est[ok], est_n[ok], est_e[ok], acc[ok]
    if len(t_est) < 2:
        raise ValueError("fewer than 2 finite estimate samples to score")
    t0 = max(start_s, t_est[0], t_true[0])
    t1 = min(t_est[-1], t_true[-1])
    if t1 - t0 < 10.0:
        end = min(t_est[-1], t_true[-1])
        who = "the estimates end" if t_est[-1] <= t_true[-1] else "the truth ends"
        hint = max(0.0, float(max(t_est[0], t_true[0])), end - 20.0)
        raise ValueError(
            f"too little to score from {start_s:g} s: {who} at {end:.1f} s and the score needs 10 s "
            f"after its start (score from earlier: --start {hint:.0f})"
        )
    grid = np.arange(t0, t1, 1.0 / GRID_HZ)
    ip = lambda t, y: np.interp(grid, t, y)  # noqa: E731
    fa = np.isfinite(acc) & (t_est >= t0) & (t_est <= t1)
    ac = ip(t_est[np.isfinite(acc)], acc[np.isfinite(acc)]) if fa.any() else np.full(len(grid), np.nan)
    return grid, ip(t_est, est_n), ip(t_est, est_e), ac, ip(t_true, true_n), ip(t_true, true_e)


def score(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s: float = 120.0, band_hz: float = 0.05) -> Score:
    grid, en, ee, ac, tn, te = on_grid(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s)
    raw = np.sqrt(np.mean((en - tn) ** 2 + (ee - te) ** 2))
    fen, fee = lowpass(en, GRID_HZ, band_hz), lowpass(ee, GRID_HZ, band_hz)
    ftn, fte = lowpass(tn, GRID_HZ, band_hz), lowpass(te, GRID_HZ, band_hz)
    band = np.sqrt(np.mean((fen - ftn) ** 2 + (fee - fte) ** 2))
    band_const = np.sqrt(np.mean((ftn - tn.mean()) ** 2 + (fte - te.mean()) ** 2))
    skill = 1.0 - band / band_const if band_const >= MIN_BAND_STD_MPS else math.nan
    ms_true = math.hypot(tn.mean(), te.mean())
    ms_est = math.hypot(en.mean(), ee.mean())
    d_true = math.degrees(math.atan2(te.mean(), tn.mean()))
    d_est = math.degrees(math.atan2(ee.mean(), en.mean()))
    ddir = (d_est - d_true + 180.0) % 360.0 - 180.0
    mean_acc = float(np.sqrt(np.mean(ac**2)))
    stated = np.isfinite(ac)
    beyond = float(np.mean(np.hypot(en - tn, ee - te)[stated] > 3.0 * ac[stated])) if stated.any() else math.nan
    t_est, acc = np.asarray(t_est, float), np.asarray(acc, float)
    scored = np.isfinite(t_est) & np.isfinite(est_n) & np.isfinite(est_e) & (t_est >= grid[0]) & (t_est <= grid[-1])
    return Score(
        band_rmse_mps=float(band),
        raw_rmse_mps=float(raw),
        speed_error_pct=100.0 * (ms_est - ms_true) / max(ms_true, 1e-6),
        direction_error_deg=ddir,
        mean_accuracy_mps=mean_acc,
        error_ratio=float(raw) / mean_acc if mean_acc > 0.0 else math.inf if mean_acc == 0.0 else math.nan,
        band_skill=float(skill),
        true_speed_mps=ms_true,
        est_speed_mps=ms_est,
        duration_s=float(grid[-1] - grid[0]),
        accuracy_not_finite=int(np.count_nonzero(scored & ~np.isfinite(acc))),
        beyond_3sigma=beyond,
    )


MIN_AMPLITUDE_MPS = 0.02  # an axis whose true amplitude at a frequency is below this is not driven there


def sinusoid_fit(t: np.ndarray, ys: np.ndarray, freqs_hz) -> np.ndarray:
    """Complex amplitudes (a - i b for a cos + b sin, so a delay reads as a negative phase) of every
    column of ``ys`` at each frequency, one least-squares fit of all the frequencies' cos/sin together
    with a constant and a linear trend. Returns shape (len(freqs_hz), ys.shape[1])."""
    tt = t - t[0]
    cols = [np.ones_like(tt), tt / max(tt[-1], 1e-9)]
    for f in freqs_hz:
        cols += [np.cos(2.0 * math.pi * f * tt), np.sin(2.0 * math.pi * f * tt)]
    c = np.linalg.lstsq(np.column_stack(cols), ys, rcond=None)[0]
    return c[2::2] - 1j * c[3::2]


def response(t_est, est_n, est_e, t_true, true_n, true_e, freqs_hz, start_s: float = 120.0,
             extra_hz=()) -> dict[float, dict[str, complex | None]]:  # fmt: skip
    """Transfer function H = estimate / truth at each frequency, for the along-wind component
    (projected on the true mean direction over the window) and the cross-wind one (its perpendicular,
    90 deg to the right), by a least-squares fit of cos/sin at all ``freqs_hz`` plus a constant and a
    linear trend, from ``start_s`` on. ``extra_hz``: other frequencies the truth is known to hold (the
    multisine's lines), fitted alongside so they do not leak into the reported ones, not reported
    (those with less than one period in the window are left to the constant and the trend).
    ``{f: {"along": H, "cross": H}}``; an axis whose true amplitude at f is below ``MIN_AMPLITUDE_MPS``
    is not driven there and gets None. Gain |H|, phase arg H (negative = lag), complex error |H - 1|:
    ``describe(H)``."""
    freqs = [float(f) for f in freqs_hz]
    extra = [float(f) for f in extra_hz if all(abs(float(f) - g) > 1e-9 for g in freqs)]
    grid, en, ee, _, tn, te = on_grid(t_est, est_n, est_e, np.zeros(len(t_est)), t_true, true_n, true_e, start_s)
    extra = [f for f in extra if f * (grid[-1] - grid[0]) >= 1.0]  # slower ones: left to the constant + trend
    d = np.array([tn.mean(), te.mean()])
    norm = float(np.linalg.norm(d))
    if norm < 1e-6:
        raise ValueError("no mean wind to define the along-wind direction")
    d /= norm
    axes = {"along": d, "cross": np.array([-d[1], d[0]])}
    ys = np.column_stack([v[0] * n + v[1] * e for v in axes.values() for n, e in ((en, ee), (tn, te))])
    z = sinusoid_fit(grid, ys, freqs + extra)
    out: dict[float, dict[str, complex | None]] = {}
    for k, f in enumerate(freqs):
        out[f] = {}
        for j, ax in enumerate(axes):
            ze, zt = z[k, 2 * j], z[k, 2 * j + 1]
            out[f][ax] = complex(ze / zt) if abs(zt) >= MIN_AMPLITUDE_MPS else None
    return out


def describe(h: complex | None) -> tuple[float, float, float]:
    """(gain |H|, phase deg, |H - 1|) of a transfer function value; NaNs for None."""
    if h is None:
        return math.nan, math.nan, math.nan
    return abs(h), math.degrees(math.atan2(h.imag, h.real)), abs(h - 1.0)


def psd(x: np.ndarray, fs: float, segment_s: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD (Hann, 50 % overlap), one-sided, (m/s)^2/Hz."""
    n = min(len(x), int(segment_s * fs))
    step = n // 2
    win = np.hanning(n)
    scale = 2.0 / (fs * np.sum(win**2))
    acc = None
    k = 0
    for i in range(0, len(x) - n + 1, step):
        seg = x[i : i + n] - np.mean(x[i : i + n])
        p = np.abs(np.fft.rfft(seg * win)) ** 2 * scale
        acc = p if acc is None else acc + p
        k += 1
    return np.fft.rfftfreq(n, 1.0 / fs), acc / max(k, 1)


def direction_from_deg(wind_n, wind_e):
    """Meteorological direction the wind blows FROM, degrees clockwise from north, in [0, 360)
    (scalars or arrays). The one definition every program, product and plot uses."""
    return np.degrees(np.arctan2(-np.asarray(wind_e, float), -np.asarray(wind_n, float))) % 360.0


UNKNOWN_SIGMA_MPS = 1.0  # a horizontal 1-sigma above max(this, half the speed): the wind is not known


def wind_unknown(speed_mps, sigma_mps):
    """Is a wind of this horizontal speed with this 1-sigma accuracy not known at all (the error could
    be as large as the wind)? Scalars or arrays; a NaN accuracy or speed is unknown too. The one rule
    the products (flag ``wind_unknown``), the firmware's ESTIMATOR_STATUS and the live view use."""
    speed, sigma = np.asarray(speed_mps, float), np.asarray(sigma_mps, float)
    return ~(sigma <= np.maximum(UNKNOWN_SIGMA_MPS, 0.5 * speed))
