"""Post-flight reprocessing: the smoother against the causal filter, and what a long flight costs.

    .venv/bin/python -m benchmarks.bench_reprocess [--seeds 5] [--duration 600] [--jobs 2]
        [--scenarios NAME ...] [--hours 1] [--tlog FILE] [--skip-accuracy] [--skip-speed]

Accuracy (in one process per flight: simulator -> the same samples the programs see -> forward filter +
backward smoother), per scenario, mean over seeds and [worst seed], metrics after 120 s as in
bench_accuracy: band skill against the constant true mean, error / reported accuracy, and on the multisine
winds |H - 1| along and across at 0.01-0.1 Hz with the phase. Targets of the smoothed wind (marked '!'
where the worst seed misses): |H - 1| <= 0.15 at f <= 0.05 Hz and <= 0.3 at 0.1 Hz, band skill >= 0.9,
error / accuracy within 0.7-1.4.

Speed and memory: ``balloon-sim`` writes an N-hour tlog of paper-reference (or ``--tlog FILE``: that
flight, N hours long), then ``balloon-gs reprocess`` turns it into NetCDF as a separate process: wall time
and its peak resident memory (targets: 1 h <= 10 s and <= 300 MB, 24 h <= 4 min and <= 500 MB).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from multiprocessing import Pool

import numpy as np

from balloon_core.samples import BaroSample, ImuSample
from balloon_core.score import response, score
from postflight.reprocess import reprocess
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation

START_S = 120.0
FREQS_HZ = (0.01, 0.02, 0.05, 0.1)
H_MAX = {0.01: 0.15, 0.02: 0.15, 0.05: 0.15, 0.1: 0.3}
SKILL_MIN = 0.9
RATIO_RANGE = (0.7, 1.4)


def one(job) -> dict:
    name, seed, duration = job
    sc = SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, duration, seed)

    def samples():
        for s in sim.samples():
            if s.baro:
                yield BaroSample(s.time_usec, *s.baro)
            yield ImuSample(s.time_usec, *s.accel, *s.gyro, *s.mag)

    t0 = time.perf_counter()
    p = reprocess(samples(), sc.design, sc.filter)
    truth = {c: sim.truth[:, k] for k, c in enumerate(TRUTH_COLUMNS)}
    args = (truth["time_s"], truth["wind_n"], truth["wind_e"])
    out = {"scenario": name, "seed": seed, "elapsed_s": time.perf_counter() - t0}
    multisine = sc.wind.kind == "multisine"
    for label, wn, we, sn, se in (("causal", p.causal_n, p.causal_e, p.causal_sigma_n, p.causal_sigma_e),
                                  ("smoothed", p.wind_n, p.wind_e, p.sigma_n, p.sigma_e)):  # fmt: skip
        s = score(p.time_s, wn, we, np.hypot(sn, se), *args, start_s=START_S)
        r = {"skill": s.band_skill, "ratio": s.error_ratio, "speed": s.speed_error_pct}
        if multisine:
            r["H"] = response(p.time_s, wn, we, *args, FREQS_HZ, start_s=START_S)
        out[label] = r
    return out


def _cell(values: list[float], worst, fmt: str, miss: bool) -> str:
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return "-"
    return f"{format(float(np.mean(v)), fmt)} [{format(worst(v), fmt)}]" + ("!" if miss else "")


def _worst_ratio(v: list[float]) -> float:
    return max(v, key=lambda x: abs(math.log(x)))


def accuracy_table(results: list[dict], names: list[str]) -> list[str]:
    lines = [f"{'scenario':<18s} {'estimate':<9s} {'band skill':>16s} {'err/acc':>16s} {'speed %':>16s}"]
    for n in names:
        rs = [r for r in results if r["scenario"] == n]
        for label in ("causal", "smoothed"):
            sk = [r[label]["skill"] for r in rs]
            ra = [r[label]["ratio"] for r in rs]
            sp = [r[label]["speed"] for r in rs]
            judge = label == "smoothed"
            ratio_miss = judge and not all(RATIO_RANGE[0] <= x <= RATIO_RANGE[1] for x in ra)
            lines.append(
                f"{n:<18s} {label:<9s} {_cell(sk, min, '.3f', judge and min(sk) < SKILL_MIN):>16s} "
                f"{_cell(ra, _worst_ratio, '.2f', ratio_miss):>16s} "
                f"{_cell(sp, lambda v: max(v, key=abs), '+.2f', False):>16s}"
            )
    multi = [n for n in names if "H" in next(r for r in results if r["scenario"] == n)["causal"]]
    if multi:
        lines.append("")
        lines.append("|H - 1| (phase deg), mean over seeds [worst]; along / across")
        lines.append(f"{'scenario':<18s} {'estimate':<9s} " + " ".join(f"{f:>22g} Hz" for f in FREQS_HZ))
        for n in multi:
            rs = [r for r in results if r["scenario"] == n]
            for label in ("causal", "smoothed"):
                cells = []
                for f in FREQS_HZ:
                    parts = []
                    for axis in ("along", "cross"):
                        hs = [r[label]["H"][f][axis] for r in rs if r[label]["H"][f][axis] is not None]
                        if not hs:
                            parts.append("-")
                            continue
                        err = [abs(h - 1) for h in hs]
                        ph = float(np.degrees(np.angle(np.mean(hs))))
                        miss = label == "smoothed" and max(err) > H_MAX[f]
                        parts.append(f"{np.mean(err):.2f}[{max(err):.2f}]{'!' if miss else ''}({ph:+.0f})")
                    cells.append(" / ".join(parts).rjust(25))
                lines.append(f"{n:<18s} {label:<9s} " + " ".join(cells))
    return lines


def speed_and_memory(hours: float, given: str | None = None) -> list[str]:
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        tlog = given or os.path.join(tmp, "flight.tlog")
        t0 = time.perf_counter()
        if given is None:
            subprocess.run([py, "-m", "sim_hil", "--scenario", "paper-reference", "--duration", str(hours * 3600),
                            "--seed", "1", "--out", tlog, "--quiet"], check=True, capture_output=True)  # fmt: skip
        t_sim = time.perf_counter() - t0
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0 = time.perf_counter()
        subprocess.run([py, "-m", "ground_station", "reprocess", tlog, "--out", os.path.join(tmp, "wind.nc"),
                        "--quiet"], check=True, stdout=subprocess.DEVNULL)  # fmt: skip
        wall = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        size = os.path.getsize(tlog) / 1e6
    mem = f"{peak / 1024:.0f} MB" if peak > before else f"<= {peak / 1024:.0f} MB (the simulator's peak)"
    return [
        f"{'flight':>8s} {'tlog':>9s} {'reprocess wall':>15s} {'x real time':>12s} {'peak memory':>12s}",
        f"{hours:>6g} h {size:>6.0f} MB {wall:>13.1f} s {hours * 3600 / wall:>11.0f}x {mem:>12s}",
        "(targets: 1 h <= 10 s and <= 300 MB; 24 h <= 4 min and <= 500 MB; "
        + (f"the simulator took {t_sim:.0f} s to write the tlog)" if given is None else f"{os.path.basename(given)})"),
    ]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0, help="flight length for the accuracy part [s]")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenarios", nargs="+", default=["multisine-2d", "paper-reference"], metavar="NAME")
    ap.add_argument("--hours", type=float, default=1.0, help="flight length for the speed/memory part [h]")
    ap.add_argument("--tlog", help="the speed/memory part on this flight (its length: --hours) instead of a "
                    "simulated paper-reference one")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args(argv)
    if not args.skip_accuracy:
        jobs = [(n, s, args.duration) for n in args.scenarios for s in range(1, args.seeds + 1)]
        with Pool(max(1, args.jobs)) as pool:
            results = list(pool.imap_unordered(one, jobs))
        results.sort(key=lambda r: (args.scenarios.index(r["scenario"]), r["seed"]))
        print(f"{args.seeds} seeds x {args.duration:.0f} s, metrics after {START_S:.0f} s "
              f"(targets of the smoothed wind: skill >= {SKILL_MIN}, err/acc {RATIO_RANGE[0]}-{RATIO_RANGE[1]}, "
              "|H-1| <= 0.15 up to 0.05 Hz and <= 0.3 at 0.1 Hz; '!' = the worst seed misses)")  # fmt: skip
        for line in accuracy_table(results, args.scenarios):
            print(line)
    if not args.skip_speed:
        if not args.skip_accuracy:
            print()
        for line in speed_and_memory(args.hours, args.tlog):
            print(line)


if __name__ == "__main__":
    main()
