"""balloon-study throughput: cases per hour with 1 and 2 Dask workers, the scaling, and the serial
overhead per case (scheduling, moving the payload and the metrics back, storing the part).

    .venv/bin/python -m benchmarks.bench_study [--duration 60] [--cases 4] [--noop 200]

The sweeps use ``--duration`` s cases (paper-reference, distinct seeds) so that the benchmark stays
short; one 600 s case is also timed in-process, and cases per hour for a 600 s case are the measured
throughput scaled by the ratio of the two case times (the per-case overhead is a fixed cost, so this
is conservative). Overhead per case = (sweep wall time - sum of the cases' own times / workers) / cases
(scheduling, results, storing, and the idle tail of the last case), as a share of the benchmark's case
and of a 600 s case; ``--noop`` tasks that return a metrics-sized dict give the bare round trip per task.
"""

from __future__ import annotations

import argparse
import importlib
import pickle
import statistics
import tempfile
import time
import tomllib
from pathlib import Path

from study import engine
from study.case import run_case
from study.spec import parse_spec

HOUR_S = 3600.0


def cases(duration_s: float, n: int, first_seed: int = 1):
    text = (f"[study]\nbase = \"paper-reference\"\nseeds = {list(range(first_seed, first_seed + n))}\n"
            f"duration_s = {duration_s}\nstart_s = {min(120.0, duration_s / 3)}\n")  # fmt: skip
    return parse_spec(tomllib.loads(text)).cases()


def noop(payload):
    return {"key": payload["key"], "status": "ok", "error": "", **{f"m{i}": float(i) for i in range(24)}}


def sweep(workers: int, cs) -> dict:
    with engine.dask_client(workers=workers) as client, tempfile.TemporaryDirectory() as tmp:
        client.run(importlib.import_module, "study.case")  # workers up, imports done (a one-time cost)
        rows, st = engine.run(cs, engine.Store(Path(tmp)), client, progress=False)
    assert st.failed == 0, [r["error"] for r in rows.values() if r["status"] != "ok"]
    mean_case = st.case_s / st.computed
    overhead = (st.wall_s - st.case_s / workers) / st.computed
    return {"workers": workers, "cases": st.computed, "wall_s": st.wall_s, "mean_case_s": mean_case,
            "per_hour": HOUR_S * st.computed / st.wall_s, "overhead_s": overhead,
            "overhead_frac": overhead / mean_case}  # fmt: skip


def noop_round_trip(n: int, workers: int = 2) -> tuple[float, int]:
    """Seconds per trivial task through the same engine (submit window, as_completed, store), bytes back."""
    cs = cases(60.0, n, first_seed=1000)
    with engine.dask_client(workers=workers) as client, tempfile.TemporaryDirectory() as tmp:
        client.run(importlib.import_module, "study.case")
        t0 = time.perf_counter()
        engine.run(cs, engine.Store(Path(tmp)), client, case_fn=noop, progress=False)
        dt = time.perf_counter() - t0
    return dt / n, len(pickle.dumps(noop(cs[0].payload())))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per benchmark case")
    ap.add_argument("--cases", type=int, default=4, help="cases per worker count")
    ap.add_argument("--noop", type=int, default=200, help="trivial tasks for the bare per-task overhead")
    args = ap.parse_args(argv)

    short = cases(args.duration, 1)[0]
    t_short = statistics.median(run_case(short.payload())["wall_time_s"] for _ in range(2))
    long_ = cases(600.0, 1)[0]
    row600 = run_case(long_.payload())
    t600 = row600["wall_time_s"]
    result_bytes = len(pickle.dumps(row600))
    scale = t_short / t600
    one = sweep(1, cases(args.duration, args.cases, first_seed=1))
    two = sweep(2, cases(args.duration, 2 * args.cases, first_seed=101))
    per_task, noop_bytes = noop_round_trip(args.noop)

    print(f"balloon-study throughput: paper-reference cases of {args.duration:g} s simulated "
          f"(in-process {t_short:.2f} s each); one 600 s case in-process {t600:.1f} s")  # fmt: skip
    print(f"{'workers':>7s} {'cases':>5s} {'wall s':>7s} {'case s':>7s} {'cases/h':>8s} {'cases/h @600 s':>15s} "
          f"{'overhead/case':>17s} {'of a 600 s case':>16s}")  # fmt: skip
    for r in (one, two):
        print(f"{r['workers']:7d} {r['cases']:5d} {r['wall_s']:7.1f} {r['mean_case_s']:7.2f} {r['per_hour']:8.0f} "
              f"{r['per_hour'] * scale:15.0f} {r['overhead_s'] * 1e3:6.0f} ms = {100 * r['overhead_frac']:4.1f} % "
              f"{100 * r['overhead_s'] / t600:15.2f} %")  # fmt: skip
    print(f"scaling 1 -> 2 workers: x{two['per_hour'] / one['per_hour']:.2f} (ideal x2; 2 cores shared with "
          "whatever else runs)")  # fmt: skip
    print(f"bare Dask round trip per task ({args.noop} no-op tasks, 2 workers): {per_task * 1e3:.1f} ms "
          f"= {100 * per_task / t600:.3f} % of a 600 s case; metrics dict back: {result_bytes} bytes "
          f"(no-op {noop_bytes})")  # fmt: skip


if __name__ == "__main__":
    main()
