"""Simulator speed: simulated seconds per wall second of a paper-reference run with sensors, MAVLink
packets (tlog framing into memory) and the truth table.

    .venv/bin/python -m benchmarks.bench_sim [--duration 600]
"""

from __future__ import annotations

import argparse
import io
import time

from firmware_py.mavio import TlogWriter
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=600.0)
    args = ap.parse_args()
    print(f"{'run':34s} {'sim s':>7s} {'wall s':>7s} {'x real':>7s} {'1 h flight':>10s}")
    for label, packets in (("physics + sensors + truth", False), ("... + MAVLink packets (tlog)", True)):
        wall = measure(args.duration, packets=packets)
        x = args.duration / wall
        print(f"{label:34s} {args.duration:7.0f} {wall:7.2f} {x:7.0f} {3600.0 / x:9.1f}s")
    print("target: 1 h flight in <= 60 s (>= 60x real time) on one core")


if __name__ == "__main__":
    main()
