"""Simulator speed: simulated seconds per wall second of a paper-reference run with sensors, MAVLink
packets (tlog framing into memory) and the truth table.

    .venv/bin/python -m benchmarks.bench_sim [--duration 600]
    .venv/bin/python -m benchmarks.bench_sim --memory 600 3600 10800 [86400]
    .venv/bin/python -m benchmarks.bench_sim --memory 86400 604800 --partial 600

``--memory D...``: peak resident memory of a whole balloon-sim run (wind, physics, sensors, tlog
packets and the truth CSV, both written to /dev/null) of each duration, each in a fresh process.
``--partial S``: only the first S simulated seconds of each (set up for the whole duration: the wind
of the whole flight is prepared; the run's memory is flat after the first truth chunk and wind block).
"""

from __future__ import annotations

import argparse
import io
import math
import os
import resource
import subprocess
import sys
import time

from balloon_core.wire import TlogWriter
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation, TruthCsvWriter


def measure(duration_s: float, seed: int = 1, packets: bool = True) -> float:
    sc = SCENARIOS["paper-reference"]
    t0 = time.perf_counter()
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, seed)
    if packets:
        enc, w = SensorPacketEncoder(), TlogWriter(io.BytesIO())
        for s in sim.samples():
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)
    else:
        sim.run()
    return time.perf_counter() - t0


def flight_to_null(duration_s: float, seed: int = 1, partial_s: float | None = None) -> tuple[int, float]:
    """What ``balloon-sim --out F.tlog --truth T.csv`` does, into /dev/null: (peak RSS in MB, wall s)."""
    sc = SCENARIOS["paper-reference"]
    t0 = time.perf_counter()
    truth = TruthCsvWriter(os.devnull)
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, seed, keep_truth=False, truth_sink=truth)
    enc = SensorPacketEncoder()
    with open(os.devnull, "wb") as fh:
        w = TlogWriter(fh)
        stop_us = math.inf if partial_s is None else partial_s * 1e6
        for s in sim.samples():
            if s.time_usec > stop_us:
                break
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)
    sim.flush_truth()
    truth.close()
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024, time.perf_counter() - t0


def memory(durations: list[float], partial_s: float | None = None) -> None:
    print(f"{'flight':>10s} {'simulated':>10s} {'peak RSS MB':>12s} {'wall s':>8s}")
    for d in durations:
        code = f"from benchmarks.bench_sim import flight_to_null; print(*flight_to_null({d!r}, 1, {partial_s!r}))"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
        rss, wall = out.split()
        done = d if partial_s is None else min(d, partial_s)
        print(f"{d / 3600:9.2f}h {done / 3600:9.2f}h {int(rss):12d} {float(wall):8.1f}", flush=True)
    print("target: a 24 h flight under 500 MB, flat in the duration")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--memory", type=float, nargs="+", metavar="SECONDS", help="peak memory of runs this long")
    ap.add_argument("--partial", type=float, metavar="SECONDS", help="with --memory: simulate only this much")
    args = ap.parse_args()
    if args.memory:
        memory(args.memory, args.partial)
        return
    print(f"{'run':34s} {'sim s':>7s} {'wall s':>7s} {'x real':>7s} {'1 h flight':>10s}")
    for label, packets in (("physics + sensors + truth", False), ("... + MAVLink packets (tlog)", True)):
        wall = measure(args.duration, packets=packets)
        x = args.duration / wall
        print(f"{label:34s} {args.duration:7.0f} {wall:7.2f} {x:7.0f} {3600.0 / x:9.1f}s")
    print("target: 1 h flight in <= 60 s (>= 60x real time) on one core")


if __name__ == "__main__":
    main()
