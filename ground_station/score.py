"""Scores of a wind estimate against the simulator's truth (the firmware issue's metrics).

- band RMSE: horizontal-vector RMS error after both series are low-passed below ``band_hz``
  (zero-phase FFT filter on a common 10 Hz grid), from ``start_s`` on;
- mean speed error (% of the true mean speed) and mean direction error (deg), of the mean vectors;
- accuracy consistency: mean reported horiz_accuracy / actual RMS error of the raw estimate;
- gain |estimate / truth| at given frequencies (multisine wind).
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
    mean_accuracy_mps: float
    accuracy_ratio: float  # reported / actual
    true_speed_mps: float
    est_speed_mps: float
    duration_s: float

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


def on_grid(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s):
    t0 = max(start_s, t_est[0], t_true[0])
    t1 = min(t_est[-1], t_true[-1])
    if t1 - t0 < 10.0:
        raise ValueError(f"not enough overlap after {start_s} s to score ({t1 - t0:.1f} s)")
    grid = np.arange(t0, t1, 1.0 / GRID_HZ)
    ip = lambda t, y: np.interp(grid, t, y)  # noqa: E731
    return grid, ip(t_est, est_n), ip(t_est, est_e), ip(t_est, acc), ip(t_true, true_n), ip(t_true, true_e)


def score(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s: float = 120.0, band_hz: float = 0.05) -> Score:
    grid, en, ee, ac, tn, te = on_grid(t_est, est_n, est_e, acc, t_true, true_n, true_e, start_s)
    raw = np.sqrt(np.mean((en - tn) ** 2 + (ee - te) ** 2))
    fen, fee = lowpass(en, GRID_HZ, band_hz), lowpass(ee, GRID_HZ, band_hz)
    ftn, fte = lowpass(tn, GRID_HZ, band_hz), lowpass(te, GRID_HZ, band_hz)
    band = np.sqrt(np.mean((fen - ftn) ** 2 + (fee - fte) ** 2))
    ms_true = math.hypot(tn.mean(), te.mean())
    ms_est = math.hypot(en.mean(), ee.mean())
    d_true = math.degrees(math.atan2(te.mean(), tn.mean()))
    d_est = math.degrees(math.atan2(ee.mean(), en.mean()))
    ddir = (d_est - d_true + 180.0) % 360.0 - 180.0
    mean_acc = float(np.sqrt(np.mean(ac**2)))
    return Score(
        band_rmse_mps=float(band),
        raw_rmse_mps=float(raw),
        speed_error_pct=100.0 * (ms_est - ms_true) / max(ms_true, 1e-6),
        direction_error_deg=ddir,
        mean_accuracy_mps=mean_acc,
        accuracy_ratio=mean_acc / max(float(raw), 1e-9),
        true_speed_mps=ms_true,
        est_speed_mps=ms_est,
        duration_s=float(grid[-1] - grid[0]),
    )


def gains(t_est, est_n, est_e, t_true, true_n, true_e, freqs_hz, start_s: float = 120.0) -> dict[float, float]:
    """|estimate / truth| of the along-wind component at each frequency (single-bin DFT over a whole
    number of periods of the lowest frequency that fits)."""
    grid, en, ee, _, tn, te = on_grid(t_est, est_n, est_e, est_n * 0, t_true, true_n, true_e, start_s)
    mean_dir = np.array([tn.mean(), te.mean()])
    mean_dir /= np.linalg.norm(mean_dir) + 1e-12
    e_u = en * mean_dir[0] + ee * mean_dir[1]
    t_u = tn * mean_dir[0] + te * mean_dir[1]
    out = {}
    for f in freqs_hz:
        n_per = max(1, int((grid[-1] - grid[0]) * f))
        m = int(round(n_per / f * GRID_HZ))
        tt = grid[:m] - grid[0]
        ph = np.exp(-2j * math.pi * f * tt)
        ge = np.sum((e_u[:m] - e_u[:m].mean()) * ph)
        gt = np.sum((t_u[:m] - t_u[:m].mean()) * ph)
        out[f] = float(abs(ge) / max(abs(gt), 1e-12))
    return out
