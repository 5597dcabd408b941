"""The sweep's tables: one row per case (cases.parquet and cases.csv, the same rows) and the summary
over seeds (summary.csv: per sweep point, each chosen metric's mean and worst seed)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from balloon_core.atomic import Products
from study.metrics import METRICS, rule_of, worst
from study.spec import Case, Spec

ALWAYS = ("slack_frac", "lift_margin_n", "wall_time_s")  # in every summary (the maps mark slack points)


def axis_value(case: Case, axis: str, base: str) -> Any:
    if axis == "scenario":
        return case.point.get("scenario", base)
    s, _, k = axis.split("+")[0].strip().partition(".")
    return case.sections[s][k]


def case_rows(spec: Spec, cases: list[Case], results: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per case, in the spec's order; the metric columns are the same in every row."""
    extra = sorted({k for r in results.values() for k in r if k.startswith("h_err_") and k not in METRICS},
                   key=lambda k: (k.split("_")[2], float(k.split("_")[3][:-2])))  # fmt: skip
    metric_cols = [m for m in METRICS if m != "wall_time_s"] + extra + ["wall_time_s"]
    out = []
    for c in cases:
        r = results.get(c.key, {"status": "missing", "error": "not run"})
        row: dict[str, Any] = {"key": c.key, "sweep": c.sweep}
        for a in spec.axis_names:
            row[a] = axis_value(c, a, spec.base)
        row.update(seed=c.seed, duration_s=c.duration_s, start_s=c.start_s, status=r.get("status", "failed"),
                   error=r.get("error", ""))  # fmt: skip
        for m in metric_cols:
            v = r.get(m)
            row[m] = float(v) if isinstance(v, (int, float)) and v is not None else math.nan
        out.append(row)
    return out


def summary_rows(spec: Spec, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per sweep and point (the seeds pooled): counts, then ``<metric>_mean`` and ``<metric>_worst``."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        sweep_axes = next(sw for sw in spec.sweeps if sw.name == r["sweep"]).axes
        gk = (r["sweep"], *((a.name, r[a.name]) for a in sweep_axes))
        groups.setdefault(gk, []).append(r)
    out = []
    for gk, rs in groups.items():
        ok = [r for r in rs if r["status"] == "ok"]
        s: dict[str, Any] = {"sweep": gk[0]}
        for a in spec.axis_names:
            s[a] = rs[0][a]
        s.update(seeds=len(rs), failed=len(rs) - len(ok))
        for m in dict.fromkeys((*spec.metrics, *ALWAYS)):
            vals = [r[m] for r in ok if math.isfinite(r[m])]
            s[f"{m}_mean"] = float(np.mean(vals)) if vals else math.nan
            s[f"{m}_worst"] = worst(rule_of(m), vals)
        out.append(s)
    return out


def table(rows: list[dict[str, Any]]) -> pa.Table:
    cols = list(rows[0]) if rows else []
    data = {}
    for c in cols:
        vals = [r.get(c) for r in rows]
        if all(isinstance(v, str) for v in vals):
            data[c] = pa.array(vals, pa.string())
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
            data[c] = pa.array([float(v) for v in vals], pa.float64()) if c != "seed" else pa.array(vals, pa.int64())
        else:  # a mixed column (an axis over strings and numbers): text
            data[c] = pa.array([str(v) for v in vals], pa.string())
    return pa.table(data)


def write(out_dir: Path, spec: Spec, cases: list[Case], results: dict[str, dict[str, Any]]):
    rows = case_rows(spec, cases, results)
    summ = summary_rows(spec, rows)
    t = table(rows)
    with Products() as products:  # under temporary names, renamed when all three are written
        pq.write_table(t, products.path(str(out_dir / "cases.parquet")))
        pacsv.write_csv(t, products.path(str(out_dir / "cases.csv")))
        pacsv.write_csv(table(summ), products.path(str(out_dir / "summary.csv")))
        products.commit()
    return rows, summ


def format_summary(spec: Spec, summ: list[dict[str, Any]], metrics: tuple[str, ...] | None = None) -> list[str]:
    """Plain text tables of the summary, one per sweep (mean, and [worst seed] with several seeds)."""
    metrics = metrics or spec.metrics
    out = []
    for sw in spec.sweeps:
        axes = [a.name for a in sw.axes if len(a.values) > 1] or [a.name for a in sw.axes]
        head = [*axes, "n", *metrics]
        body = []
        for s in summ:
            if s["sweep"] != sw.name:
                continue
            cells = [*(fmt_value(s[a]) for a in axes), f"{s['seeds'] - s['failed']}/{s['seeds']}"]
            for m in metrics:
                mean, w = s[f"{m}_mean"], s[f"{m}_worst"]
                if not math.isfinite(mean):
                    cells.append("-")
                else:
                    cells.append(f"{mean:.3g}" + (f" [{w:.3g}]" if s["seeds"] - s["failed"] > 1 else ""))
            body.append(cells)
        widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
        out += [f"sweep {sw.name}:", md_line(head, widths), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
        out += [md_line(b, widths) for b in body]
    return out


def md_line(cells: list, widths: list[int]) -> str:
    return "| " + " | ".join(str(c).ljust(w) for c, w in zip(cells, widths)) + " |"


def fmt_value(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)
