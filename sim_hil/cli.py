"""``balloon-sim``: the HIL simulator's command line (CONTRACT.md)."""

from __future__ import annotations

import argparse
import sys
import time

from firmware_py.config import ConfigError
from firmware_py.mavio import TlogWriter
from firmware_py.progress import Progress
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS, WIND_CHOICES, resolve
from sim_hil.simulator import Simulation, write_truth_csv


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="balloon-sim", description="Tethered-balloon HIL simulator")
    p.add_argument("--scenario", default="paper-reference", help="named scenario (see --list-scenarios)")
    p.add_argument("--duration", type=float, default=600.0, help="simulated seconds")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", help="FILE.tlog or a raw FILE (as fast as possible), or a UDP endpoint / serial "
                   "port (paced: --speed, --lockstep)")
    p.add_argument("--truth", help="truth CSV, one row per IMU sample")
    p.add_argument("--config", help="TOML design file (overrides the scenario)")
    p.add_argument("--wind", choices=sorted(WIND_CHOICES), help="override the scenario's wind model")
    p.add_argument("--speed", type=float, default=1.0,
                   help="UDP/serial output: N x real time (0: as fast as possible)")
    p.add_argument("--lockstep", action="store_true",
                   help="do not run ahead of the firmware's WIND_COV time (lossless fast runs)")
    p.add_argument("--lockstep-window", type=float, default=0.5, help="seconds the simulator may lead")
    p.add_argument("--quiet", action="store_true", help="no progress bar / status lines (the final line stays)")
    p.add_argument("--list-scenarios", action="store_true")
    p.add_argument("--print-config", action="store_true",
                   help="print the scenario (with --config applied) as a design TOML and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.list_scenarios:
        for name, sc in SCENARIOS.items():
            print(f"{name:20s} {sc.description}")
        return 0
    try:
        sc = resolve(args.scenario, args.config, args.wind)
    except ConfigError as exc:
        print(f"balloon-sim: {exc}", file=sys.stderr)
        return 2
    if args.print_config:
        print(sc.to_toml(), end="")
        return 0
    if args.duration <= 0:
        print("balloon-sim: --duration must be > 0", file=sys.stderr)
        return 2
    sim = Simulation(sc.design, sc.wind, sc.truth, args.duration, args.seed)
    enc = SensorPacketEncoder()
    t0 = time.perf_counter()
    n = 0
    out = args.out
    bar = Progress("balloon-sim", total=args.duration, unit="s simulated", quiet=args.quiet)
    try:
        if out and (out.startswith(("udpin:", "udpout:")) or out.startswith("/dev/") or "://" in out):
            from sim_hil.link import stream_udp  # network edge, only when asked for

            try:
                n = stream_udp(sim, enc, out, args, bar)
            except ValueError as exc:
                bar.close()
                print(f"balloon-sim: {exc}", file=sys.stderr)
                return 2
        elif out:
            with open(out, "wb") as fh:
                tlog = out.endswith(".tlog")
                w = TlogWriter(fh)
                for s in sim.samples():
                    for frame in enc.encode(s):
                        if tlog:
                            w.write(s.time_usec, frame)
                        else:
                            fh.write(frame)  # raw bytes, as a serial capture holds them
                    n += 1
                    bar.done = s.time_usec * 1e-6
        else:
            for s in sim.samples():
                n += 1
                bar.done = s.time_usec * 1e-6
    finally:
        bar.close()
    if args.truth:
        write_truth_csv(args.truth, sim.truth[:n])
    wall = time.perf_counter() - t0
    print(
        f"balloon-sim: {sc.name} seed {args.seed}: {n} IMU samples, {args.duration:.0f} s simulated "
        f"in {wall:.1f} s ({args.duration / max(wall, 1e-9):.0f}x real time)",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
