"""Plots of a sweep: each swept axis against each metric with the seed spread (every seed a dot, the mean
a line, the min-max range a band); for a two-axis grid sweep, a map of the first metric with the points
where the tether went slack (or the lift is negative) marked."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from balloon_core.atomic import Products
from study.spec import Spec

MAX_LINES = 6  # more combinations of the other axes than this: pooled into one line
SLACK_MARK = 0.05  # a point whose mean slack fraction exceeds this is marked on the maps
COLOUR_RANGE = {"band_skill": (0.0, 1.0)}  # a skill below 0 (worse than the mean) is all one colour


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def axis_plots(spec: Spec, rows: list[dict[str, Any]], out: Path) -> list[Path]:
    plt = _plt()
    made = []
    for sw in spec.sweeps:
        rs = [r for r in rows if r["sweep"] == sw.name and r["status"] == "ok"]
        if not rs:
            continue
        for ax_def in sw.axes:
            if len(ax_def.values) < 2:
                continue
            a = ax_def.name
            values = list(ax_def.values)
            numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)

            def xs_of(v, values=values, numeric=numeric) -> float:
                return float(v) if numeric else float(values.index(v))

            n = len(spec.metrics)
            cols = min(3, n)
            nrows = math.ceil(n / cols)
            fig, axs = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.0 * nrows), squeeze=False)
            others = [b.name for b in sw.axes if b.name != a]
            groups: dict[tuple, list] = {}
            for r in rs:
                groups.setdefault(tuple(r[o] for o in others), []).append(r)
            if len(groups) > MAX_LINES:  # too many lines to tell apart: pool the other axes
                groups = {(): rs}
            for k, m in enumerate(spec.metrics):
                ax = axs[k // cols][k % cols]
                ax.set_title(m, fontsize=9)
                ax.grid(alpha=0.3)
                drawn = False
                for gkey, grs in groups.items():
                    x = np.array([xs_of(r[a]) for r in grs])
                    y = np.array([r[m] for r in grs])
                    ok = np.isfinite(y)
                    if not ok.any():
                        continue
                    drawn = True
                    label = ", ".join(f"{o} {fmt(v)}" for o, v in zip(others, gkey)) if gkey else "mean"
                    ux = sorted(set(x[ok].tolist()))
                    grouped = [y[ok][x[ok] == u] for u in ux]
                    (line,) = ax.plot(ux, [g.mean() for g in grouped], "-o", ms=3, label=label)
                    ax.fill_between(ux, [g.min() for g in grouped], [g.max() for g in grouped], alpha=0.15,
                                    color=line.get_color())  # fmt: skip
                    ax.plot(x[ok], y[ok], ".", color=line.get_color(), ms=3)
                if not drawn:
                    ax.text(0.5, 0.5, "not defined here", ha="center", va="center", transform=ax.transAxes)
                if not numeric:
                    ax.set_xticks(range(len(values)), [str(v) for v in values], rotation=30, ha="right", fontsize=7)
                else:
                    ax.set_xlabel(a, fontsize=8)
                if k == 0 and drawn and len(groups) > 1:
                    ax.legend(fontsize=6)
            for k in range(n, nrows * cols):
                axs[k // cols][k % cols].axis("off")
            pooled = f" ({', '.join(others)} pooled)" if others and len(groups) == 1 else ""
            fig.suptitle(f"{sw.name}: metrics against {a}{pooled}; mean line, seed range band, seeds as dots; "
                         f"{len(spec.seeds)} seed(s), {spec.duration_s:g} s", fontsize=10)  # fmt: skip
            fig.tight_layout()
            path = out / f"{sw.name}-{safe(a)}.png"
            with Products() as products:
                fig.savefig(products.path(str(path)), dpi=90)
                products.commit()
            plt.close(fig)
            made.append(path)
    return made


def maps(spec: Spec, summ: list[dict[str, Any]], out: Path) -> list[Path]:
    """For each two-axis grid sweep: the first metric's mean over the grid, slack points hatched."""
    plt = _plt()
    made = []
    metric = spec.metrics[0]
    for sw in spec.sweeps:
        if len(sw.axes) != 2 or sw.combine != "grid" or min(len(a.values) for a in sw.axes) < 2:
            continue
        (ax_a, ax_b) = sw.axes
        ss = [s for s in summ if s["sweep"] == sw.name]
        grid = np.full((len(ax_b.values), len(ax_a.values)), np.nan)
        mark = np.full(grid.shape, "", dtype=object)
        for s in ss:
            i, j = ax_b.values.index(s[ax_b.name]), ax_a.values.index(s[ax_a.name])
            grid[i, j] = s[f"{metric}_mean"]
            sl = s.get("slack_frac_mean", math.nan)
            lift = s.get("lift_margin_n_mean", math.nan)
            if s.get("seeds", 0) and s.get("failed", 0) == s["seeds"]:
                mark[i, j] = "failed"  # e.g. a design that cannot lift its tether (the row's error says)
            elif math.isfinite(lift) and lift <= 0.0:
                mark[i, j] = "no lift"
            elif math.isfinite(sl) and sl > SLACK_MARK:
                mark[i, j] = f"slack {sl:.0%}"
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        lo, hi = COLOUR_RANGE.get(metric, (None, None))
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", vmin=lo, vmax=hi)
        fig.colorbar(im, ax=ax, label=f"{metric} (mean over seeds)" + (" (colours clipped)" if lo is not None else ""))
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                txt = "-" if not math.isfinite(grid[i, j]) else f"{grid[i, j]:.2f}"
                ax.text(j, i, txt + (f"\n{mark[i, j]}" if mark[i, j] else ""), ha="center", va="center", fontsize=7,
                        color="r" if mark[i, j] else "w")  # fmt: skip
                if mark[i, j]:
                    ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, hatch="//", ec="r", lw=0))
        ax.set_xticks(range(len(ax_a.values)), [fmt(v) for v in ax_a.values])
        ax.set_yticks(range(len(ax_b.values)), [fmt(v) for v in ax_b.values])
        ax.set_xlabel(ax_a.name)
        ax.set_ylabel(ax_b.name)
        ax.set_title(f"{sw.name}: {metric}; red hatch: slack > {SLACK_MARK:.0%} of the time, no spare lift, or failed",
                     fontsize=9)  # fmt: skip
        fig.tight_layout()
        path = out / f"{sw.name}-map-{metric}.png"
        with Products() as products:
            fig.savefig(products.path(str(path)), dpi=90)
            products.commit()
        plt.close(fig)
        made.append(path)
    return made


def fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in name)


def write_plots(spec: Spec, rows, summ, out_dir: Path) -> list[Path]:
    out = out_dir / "plots"
    out.mkdir(parents=True, exist_ok=True)
    return axis_plots(spec, rows, out) + maps(spec, summ, out)
