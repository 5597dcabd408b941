"""``plot_product``: one figure of a reprocessed flight, readable at a glance.

Panels: wind speed and direction over time (smoothed with its ±1-sigma band, the causal estimate beside it,
the estimator's mode shaded), Welch spectra of the along-wind and cross-wind components of both estimates
(0.05 Hz marked), and a wind rose (meteorological: bars point where the wind blows FROM)."""

from __future__ import annotations

import os

import numpy as np

from balloon_core.score import direction_from_deg, psd
from postflight.averages import product_averages, speed_direction_sigma
from postflight.product import FLAG_WIND_UNKNOWN, WindProduct

MODE_STYLE = ((0, "ground", "#d8c3a5"), (1, "free ascent", "#c6dbef"), (2, "taut", "#d9f0d3"))
ROSE_SECTORS = 16
BAND_HZ = 0.05  # the scoring band of the estimator (docs/estimator.md)


def _runs(x: np.ndarray) -> list[tuple[int, int, int]]:
    """(value, first index, last index + 1) of each run of equal values."""
    if len(x) == 0:
        return []
    cut = np.flatnonzero(x[1:] != x[:-1]) + 1
    starts, ends = np.r_[0, cut], np.r_[cut, len(x)]
    return [(int(x[a]), int(a), int(b)) for a, b in zip(starts, ends)]


def _longest_finite_run(ok: np.ndarray) -> slice:
    best, start = (0, 0), None
    for i, v in enumerate(np.r_[ok, False]):
        if v and start is None:
            start = i
        elif not v and start is not None:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    return slice(*best)


def _time_axis(p: WindProduct):
    """(sensor seconds -> plot x, x label): UTC datetimes when known, else time since boot."""
    t = np.asarray(p.time_s, float)
    utc = p.utc_start_s
    if utc is not None:
        return lambda s: np.round((np.asarray(s) + utc) * 1e3).astype("int64").astype("datetime64[ms]"), "time (UTC)"
    if len(t) and t[-1] - t[0] > 1800:
        return lambda s: np.asarray(s) / 60.0, "time since boot [min] (no UTC in the log)"
    return lambda s: np.asarray(s, float), "time since boot [s] (no UTC in the log)"


def _ten_minute_means(ax, p: WindProduct, to_x, key: str, shift=None) -> None:
    """The WMO 10-min means (the ``*_avg_10min`` product) as black steps."""
    a = product_averages(p, 600.0)
    first = True
    for t0, t1, v in zip(a["time_start_s"], a["time_end_s"], a[key]):
        if np.isfinite(v):
            t0, t1 = max(t0, p.time_s[0]), min(t1, p.time_s[-1])
            v = shift(v) if shift else v
            ax.plot(to_x([t0, t1]), [v, v], color="k", lw=1.6, label="10-min mean (WMO)" if first else None)
            first = False


def _circular_mean_deg(d: np.ndarray) -> float:
    r = np.radians(d[np.isfinite(d)])
    return float(np.degrees(np.arctan2(np.mean(np.sin(r)), np.mean(np.cos(r)))) % 360.0) if len(r) else 0.0


def _around(d: np.ndarray, centre: float) -> np.ndarray:
    """Directions moved by whole turns into centre ± 180 deg, so a series near north does not jump 0 <-> 360."""
    return (d - centre + 180.0) % 360.0 - 180.0 + centre


def plot_product(product: WindProduct, path: str, title: str | None = None) -> None:
    """Draw the product to ``path`` (PNG, or any format matplotlib writes from the extension)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from matplotlib.ticker import FuncFormatter

    p = product
    to_x, xlabel = _time_axis(p)
    x = to_x(p.time_s)
    n, e = np.asarray(p.wind_n, float), np.asarray(p.wind_e, float)
    cn, ce = np.asarray(p.causal_n, float), np.asarray(p.causal_e, float)
    speed, c_speed = np.hypot(n, e), np.hypot(cn, ce)
    sig_s, sig_d = speed_direction_sigma(n, e, p.sigma_n, p.sigma_e)
    dirs, c_dirs = direction_from_deg(n, e), direction_from_deg(cn, ce)
    known = (np.asarray(p.flags).astype(np.int64) & FLAG_WIND_UNKNOWN) == 0
    good = known & np.isfinite(speed)

    fig = plt.figure(figsize=(13, 10), layout="constrained")
    gs = fig.add_gridspec(3, 3, height_ratios=[1.0, 1.0, 1.1])
    ax_s = fig.add_subplot(gs[0, :])
    ax_d = fig.add_subplot(gs[1, :], sharex=ax_s)
    ax_p = fig.add_subplot(gs[2, :2])
    ax_r = fig.add_subplot(gs[2, 2], projection="polar")

    # modes shaded behind both time panels
    modes = np.asarray(p.mode)
    edges = np.r_[x, x[-1:]] if len(x) else x
    for ax in (ax_s, ax_d):
        for m, a, b in _runs(modes):
            colour = dict((k, c) for k, _, c in MODE_STYLE).get(m, "0.9")
            ax.axvspan(edges[a], edges[min(b, len(x) - 1)], color=colour, lw=0, zorder=0)
    mode_patches = [Patch(color=c, label=f"mode: {name}") for k, name, c in MODE_STYLE if np.any(modes == k)]

    # speed; where the flags say the wind is unknown, the estimate is drawn grey
    k = lambda a: np.where(known, a, np.nan)  # noqa: E731
    ax_s.fill_between(x, k(speed - sig_s), k(speed + sig_s), color="C0", alpha=0.25, lw=0, label="smoothed ±1σ")
    ax_s.plot(x, k(c_speed), color="C1", lw=0.7, alpha=0.8, label="causal (real-time)")
    ax_s.plot(x, k(speed), color="C0", lw=1.0, label="smoothed (zero-lag)")
    if not known.all():
        ax_s.plot(x, np.where(known, np.nan, speed), color="0.55", lw=0.7, label="smoothed, flagged wind unknown")
    _ten_minute_means(ax_s, p, to_x, "scalar_mean_wind_speed")
    ax_s.set_ylabel("wind speed [m/s]")
    shown = good if good.any() else np.isfinite(speed)
    top = np.nanpercentile(np.r_[speed[shown], c_speed[shown]], 99.5) if shown.any() else 1.0
    ax_s.set_ylim(0, 1.25 * top + 0.1)
    h, _ = ax_s.get_legend_handles_labels()
    ax_s.legend(handles=h + mode_patches, loc="upper left", fontsize=8, ncol=3, framealpha=0.9)
    ax_s.grid(alpha=0.3)
    ax_s.tick_params(labelbottom=False)

    # direction, kept continuous around its circular mean
    centre = _circular_mean_deg(dirs[shown])
    d, cd = _around(dirs, centre), _around(c_dirs, centre)
    ax_d.fill_between(x, k(d - sig_d), k(d + sig_d), color="C0", alpha=0.25, lw=0, label="smoothed ±1σ")
    ax_d.plot(x, k(cd), color="C1", lw=0.7, alpha=0.8, label="causal (real-time)")
    ax_d.plot(x, k(d), color="C0", lw=1.0, label="smoothed (zero-lag)")
    if not known.all():
        ax_d.plot(x, np.where(known, np.nan, d), color="0.55", lw=0.7, label="smoothed, flagged wind unknown")
    _ten_minute_means(ax_d, p, to_x, "vector_mean_wind_from_direction", lambda v: _around(v, centre))
    if shown.any():
        lo, hi = np.nanpercentile(np.r_[d[shown], cd[shown]], [0.5, 99.5])
        pad = max(10.0, 0.15 * (hi - lo))
        ax_d.set_ylim(lo - pad, hi + pad)
    ax_d.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v % 360:.0f}°"))
    ax_d.set_ylabel("wind from [deg, clockwise from N]")
    ax_d.set_xlabel(xlabel)
    ax_d.legend(loc="upper left", fontsize=8, ncol=3, framealpha=0.9)
    ax_d.grid(alpha=0.3)

    # spectra of along- and cross-wind components, longest stretch where both estimates are known
    ok = good & np.isfinite(c_speed)
    run = _longest_finite_run(ok)
    t = np.asarray(p.time_s, float)[run]
    if len(t) >= 64:
        fs = 1.0 / float(np.median(np.diff(t)))
        mn, me = np.mean(n[run]), np.mean(e[run])
        mag = np.hypot(mn, me) or 1.0
        un, ue = mn / mag, me / mag
        for wn, we, label, colour in ((cn, ce, "causal", "C1"), (n, e, "smoothed", "C0")):  # smoothed on top
            along = wn[run] * un + we[run] * ue
            cross = -wn[run] * ue + we[run] * un
            for comp, ls, name in ((along, "-", "along-wind"), (cross, "--", "cross-wind")):
                f, pxx = psd(comp, fs)
                ax_p.loglog(f[1:], pxx[1:], ls=ls, color=colour, lw=1.0, label=f"{label}, {name}")
        lo, hi = ax_p.get_ylim()
        ax_p.set_ylim(max(lo, hi * 1e-9), hi)  # ten decades at most: a filter's numerical floor is not data
        ax_p.axvline(BAND_HZ, ls=":", color="k", lw=1.0)
        ax_p.annotate(f"{BAND_HZ} Hz", (BAND_HZ, 0.97), xycoords=("data", "axes fraction"), ha="left", va="top",
                      fontsize=8, xytext=(3, 0), textcoords="offset points")  # fmt: skip
        ax_p.legend(loc="upper right", fontsize=8, ncol=2)
        ax_p.set_title(f"Welch spectra over {t[-1] - t[0]:.0f} s (longest stretch with a known wind)", fontsize=9)
    else:
        ax_p.text(0.5, 0.5, "too little known wind for a spectrum", ha="center", va="center",
                  transform=ax_p.transAxes)  # fmt: skip
    ax_p.set_xlabel("frequency [Hz]")
    ax_p.set_ylabel("PSD [(m/s)²/Hz]")
    ax_p.grid(alpha=0.3, which="both")

    _wind_rose(ax_r, dirs[good], speed[good])
    when = (np.datetime_as_string(x[0], unit="s") + " UTC") if p.utc_start_s is not None and len(x) else "sensor time"
    src = p.attrs.get("source_log", "")
    span = float(p.time_s[-1] - p.time_s[0]) if len(x) else 0.0
    speed_text = f"mean speed {np.mean(speed[good]):.2f} m/s" if good.any() else "wind unknown throughout (flags)"
    fig.suptitle(title or f"{src + ': ' if src else ''}wind from the tethered balloon, {when}, {span:.0f} s, "
                 f"{speed_text}", fontsize=11)  # fmt: skip
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _wind_rose(ax, dirs: np.ndarray, speed: np.ndarray) -> None:
    import matplotlib
    from matplotlib.ticker import FuncFormatter

    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_title("wind rose (from), % of time", fontsize=9)
    if len(dirs) == 0:
        ax.text(0.5, 0.5, "no known wind", ha="center", va="center", transform=ax.transAxes)
        ax.set_yticks([])
        return
    width = 2 * np.pi / ROSE_SECTORS
    sector = np.floor(((dirs + 180.0 / ROSE_SECTORS) % 360.0) / (360.0 / ROSE_SECTORS)).astype(int) % ROSE_SECTORS
    top = float(np.nanmax(speed))
    step = max(0.5, float(np.ceil(top / 5 / 0.5) * 0.5))  # about 5 classes of a round width
    edges = np.arange(np.floor(float(np.nanmin(speed)) / step) * step, top + step, step)  # classes that occur
    cmap = matplotlib.colormaps["viridis"]
    bottom = np.zeros(ROSE_SECTORS)
    theta = np.arange(ROSE_SECTORS) * width
    for i in range(len(edges) - 1):
        sel = (speed >= edges[i]) & (speed < edges[i + 1] if i < len(edges) - 2 else speed <= edges[i + 1])
        pct = np.bincount(sector[sel], minlength=ROSE_SECTORS) * 100.0 / len(dirs)
        ax.bar(theta, pct, width=width * 0.95, bottom=bottom, color=cmap(i / max(1, len(edges) - 2)),
               edgecolor="white", lw=0.3, label=f"{edges[i]:g}–{edges[i + 1]:g} m/s")  # fmt: skip
        bottom += pct
    ax.set_xticks(np.radians(np.arange(0, 360, 45)), ["N", "NE", "E", "SE", "S", "SW", "W", "NW"])
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.0f}%"))
    ax.tick_params(axis="y", labelsize=7)
    ax.set_rlabel_position((float(np.argmax(bottom)) + ROSE_SECTORS / 2 + 0.5) * 360.0 / ROSE_SECTORS)  # opposite
    ax.legend(loc="upper left", bbox_to_anchor=(1.05, 1.0), fontsize=7, title="speed", title_fontsize=7)
