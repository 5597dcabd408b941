"""What the stated accuracy says in the first minutes on the tether, flight by flight (a diagnosis tool).

    python tools/entry_windows.py                                   # every scenario of bench_accuracy, 9 directions
    python tools/entry_windows.py --seeds 2 --duration 300          # seeds 1 and 2, 300 s flights
    python tools/entry_windows.py --scenarios steady-8 gusty-6 --directions 4
    python tools/entry_windows.py --join-at 200 --duration 500 --start 260   # a restart 200 s into each flight

Flies each scenario of ``benchmarks.bench_accuracy`` (its default list, or ``--scenarios``) from ``--directions``
directions 360/N apart (``NAME@DEG``) with seeds 1..``--seeds`` on the study engine's core (``benchmarks.common.fly``)
and scores the wind against the truth in windows after the first taut entry (0-10, 10-30, 30-90, 90-180 s), which
``bench_accuracy`` (from 120 s) and ``bench_envelope`` (its scored part) leave out, and from ``--start`` s of the
flight, as the stop's check scores: error / stated accuracy (RMS over RMS) and the share of estimates beyond 3 x their
stated accuracy. Prints, per window, how many flights have more than 5 % and 20 % of their estimates beyond 3 sigma,
the error / accuracy percentiles, and the worst flights. ``--join-at S``: the firmware starts S s into each flight (a
restart in flight, ``control._join_in_flight``): its entry is the join, and each flight's line says when the join was
confirmed (``control._confirm``)."""

from __future__ import annotations

import argparse
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from benchmarks.bench_accuracy import DEFAULT_SCENARIOS, directions, lookup  # noqa: E402
from benchmarks.common import fly  # noqa: E402
from firmware_py.estimator.params import JOIN_IN_FLIGHT_US  # noqa: E402
from firmware_py.estimator.state import MODE_TAUT  # noqa: E402

WINDOWS_S = ((0.0, 10.0), (10.0, 30.0), (30.0, 90.0), (90.0, 180.0))  # after the first taut entry
SHARES = (0.05, 0.2)  # a flight counted where more than this share of its estimates is beyond 3 sigma
JOIN_S = JOIN_IN_FLIGHT_US * 1e-6  # a first sample later than this after the sender's boot joins in flight


def judge(err: np.ndarray, acc: np.ndarray) -> tuple[float, float] | None:
    """Error / stated accuracy (RMS over RMS) and the share beyond 3 sigma; None for fewer than 10 estimates."""
    if len(err) < 10:
        return None
    return float(np.sqrt(np.mean(err**2) / np.mean(acc**2))), float(np.mean(~(err <= 3.0 * acc)))


def one(job: tuple[str, int, float, float, float]) -> dict:
    """One flight: the estimate's error and stated accuracy in each window (None where it was not flown)."""
    name, seed, duration_s, start_s, join_s = job
    rows, truth, _ = fly(name, duration_s, seed, lookup(name), join_s)
    rows = rows[np.isfinite(rows[:, 3])]  # the firmware's (from the join)
    t = rows[:, 0]
    err = np.hypot(rows[:, 1] - np.interp(t, truth["time_s"], truth["wind_n"]),
                   rows[:, 2] - np.interp(t, truth["time_s"], truth["wind_e"]))  # fmt: skip
    acc = rows[:, 3]
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT)
    entry = t[taut[0]] if len(taut) else math.inf
    out = {"name": name, "seed": seed, "from start": judge(err[t >= start_s], acc[t >= start_s])}
    if join_s > 0.0:  # when the join was confirmed, from its first sample
        confirmed = np.flatnonzero(rows[:, 11] == 0.0)
        out["confirmed"] = t[confirmed[0]] - t[0] if len(confirmed) else None
    for a, b in WINDOWS_S:
        w = (t >= entry + a) & (t < entry + b)
        out[f"{a:g}-{b:g} s after the entry"] = judge(err[w], acc[w])
    return out


def report(flights: list[dict], start_s: float) -> str:
    lines = []
    if any("confirmed" in f for f in flights):
        never = [f for f in flights if f["confirmed"] is None]
        seconds = np.array([f["confirmed"] for f in flights if f["confirmed"] is not None])
        when = f" (p50 {np.median(seconds):.0f} s, worst {seconds.max():.0f} s after the join)" if len(seconds) else ""
        lines.append(f"joins confirmed: {len(seconds)} of {len(flights)}{when}; never: "
                     + (", ".join(f"{f['name']} seed {f['seed']}" for f in never) or "none"))  # fmt: skip
    for key in [f"{a:g}-{b:g} s after the entry" for a, b in WINDOWS_S] + ["from start"]:
        got = [(f[key], f) for f in flights if f[key] is not None]
        if not got:
            continue
        ratio = np.array([g[0][0] for g in got])
        share = np.array([g[0][1] for g in got])
        counts = ", ".join(f"{int(np.sum(share > s))} more than {100 * s:g} %" for s in SHARES)
        label = f"from {start_s:g} s of the flight" if key == "from start" else key
        p50, p90 = np.median(ratio), np.percentile(ratio, 90)
        lines.append(f"{label}: {len(got)} flights; beyond 3 sigma: {counts}; error/accuracy p50 {p50:.2f}, "
                     f"p90 {p90:.2f}, worst {ratio.max():.2f}")  # fmt: skip
        worst = sorted(got, key=lambda g: (-g[0][1], -g[0][0]))[:5]  # by the share, then by error / accuracy
        lines.append("  worst: " + "; ".join(f"{f['name']} seed {f['seed']} {100 * r[1]:.0f} % (err/acc {r[0]:.2f})"
                                             for r, f in worst))  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog="entry_windows", description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(DEFAULT_SCENARIOS), metavar="NAME")
    ap.add_argument("--directions", type=int, default=9, help="directions 360/N apart (default 9)")
    ap.add_argument("--seeds", type=int, default=2, help="seeds 1..N (default 2)")
    ap.add_argument("--duration", type=float, default=300.0, help="flight length, s (default 300)")
    ap.add_argument("--start", type=float, default=60.0, help="the whole flight scored from here, s (default 60)")
    ap.add_argument("--join-at", type=float, default=0.0, metavar="S",
                    help="the firmware starts S s into each flight: a restart in flight (default 0: from the boot)")
    ap.add_argument("--jobs", type=int, default=2)
    try:
        return run(ap.parse_args(argv))
    except userargs.UserError as e:
        return userargs.fail(ap.prog, e)


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.directions <= 360 or args.seeds < 1 or args.jobs < 1:
        raise userargs.UserError("--directions 1-360, --seeds and --jobs at least 1")
    if not (math.isfinite(args.duration) and 30.0 <= args.duration <= 86400.0):
        raise userargs.UserError(f"--duration {args.duration}: give 30 to 86400 s")
    if not (math.isfinite(args.start) and 0.0 <= args.start < args.duration):
        raise userargs.UserError(f"--start {args.start}: give 0 up to the flight's duration")
    if not (math.isfinite(args.join_at) and (args.join_at == 0.0 or JOIN_S < args.join_at <= args.start)):
        raise userargs.UserError(f"--join-at {args.join_at}: give 0, or more than {JOIN_S:g} s (sooner the firmware "
                                 "starts as after a boot) up to --start")  # fmt: skip
    names = directions(args.scenarios, args.directions)
    unknown = [n for n in names if lookup(n) is None]
    if unknown:
        raise userargs.UserError(f"unknown scenario {unknown[0]!r} (balloon-sim --list-scenarios)")
    jobs = [(n, s, args.duration, args.start, args.join_at) for n in names for s in range(1, args.seeds + 1)]
    with Pool(args.jobs) as pool:
        flights = pool.map(one, jobs)
    print(report(flights, args.start))
    return 0


if __name__ == "__main__":
    sys.exit(main())
