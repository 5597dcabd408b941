"""``balloon-sim``: the HIL simulator's command line (docs/usage.md)."""

from __future__ import annotations

import sys
import time

from balloon_core import userargs
from balloon_core.atmosphere import ground_conditions
from balloon_core.atomic import Products, sigterm_raises
from balloon_core.config import ConfigError
from balloon_core.progress import Progress
from balloon_core.wire import TlogWriter
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS, WIND_CHOICES, resolve, scenario_name
from sim_hil.simulator import Simulation, TruthCsvWriter

PROG = "balloon-sim"


def build_parser() -> userargs.Parser:
    p = userargs.Parser(prog=PROG, description="Tethered-balloon HIL simulator")
    p.add_argument("--scenario", help="named scenario (see --list-scenarios; default paper-reference, with --config "
                   "the real world: field-rope with the file's sections)")  # fmt: skip
    p.add_argument("--duration", type=userargs.duration, default=600.0, help="simulated seconds (at most 7 days)")
    p.add_argument("--seed", type=userargs.seed, default=1, help="0 .. 2^32-1")
    p.add_argument("--out", type=userargs.sink, help="FILE.tlog or a raw FILE (as fast as possible), or a UDP "
                   "endpoint / serial port (paced: --speed, --lockstep)")  # fmt: skip
    p.add_argument("--truth", type=userargs.output_path, help="truth CSV, one row per IMU sample")
    p.add_argument("--ground-csv", type=userargs.output_path,
                   help="write the ground reference's readings here ([truth] ground_baro_hz > 0)")  # fmt: skip
    p.add_argument("--config", type=userargs.input_file, help="TOML design file (overrides the scenario)")
    p.add_argument("--wind", choices=sorted(WIND_CHOICES), help="override the scenario's wind model")
    p.add_argument(
        "--speed", type=userargs.speed, default=1.0, help="UDP/serial output: N x real time (0: as fast as possible)"
    )
    p.add_argument(
        "--lockstep", action="store_true", help="do not run ahead of the firmware's WIND_COV time (lossless fast runs)"
    )
    p.add_argument(
        "--lockstep-window", type=userargs.positive_float, default=0.5, help="seconds the simulator may lead"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar / status lines (the final line stays)")
    p.add_argument("--list-scenarios", action="store_true")
    p.add_argument(
        "--print-config",
        action="store_true",
        help="print the scenario (with --config applied) as a design TOML and exit",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:  # the one rule for output options (an input, another output, unwritable), before any work
        userargs.check_outputs({"--config": args.config},
                               {"--out": args.out, "--truth": args.truth, "--ground-csv": args.ground_csv})  # fmt: skip
    except userargs.UserError as exc:
        return userargs.fail(PROG, exc)
    if args.list_scenarios:
        for name, sc in SCENARIOS.items():
            print(f"{name:20s} {sc.description}")
        return 0
    try:
        args.scenario = scenario_name(args.scenario, args.config)
        sc = resolve(args.scenario, args.config, args.wind)
    except ConfigError as exc:
        return userargs.fail(PROG, exc)
    if args.print_config:
        print(sc.to_toml(), end="")
        return 0
    try:  # weather that drifts beyond any site's ground by the end of the flight: refused before it starts
        site, truth = sc.design.site, sc.truth
        ground_conditions(site.ground_pressure_pa, site.ground_temperature_c + 273.15,
                          truth.pressure_drift_hpa_h, truth.temperature_drift_k_h, args.duration)  # fmt: skip
    except ValueError as exc:
        return userargs.fail(PROG, exc)
    if args.ground_csv and sc.truth.ground_baro_hz <= 0.0:
        return userargs.fail(PROG, f"--ground-csv {args.ground_csv}: this design has no ground reference to write "
                             "(set [truth] ground_baro_hz > 0 in the --config file)")  # fmt: skip
    # every file under a temporary name, renamed only when the whole flight is written (balloon_core/atomic.py)
    with Products() as products:
        try:
            if not (args.out and userargs.is_link(args.out)):
                sigterm_raises()  # a file run: SIGTERM ends it like Ctrl-C, its temporary files removed
                userargs.ctrl_c_raises()
            truth_csv = TruthCsvWriter(products.path(args.truth)) if args.truth else None
            code = _run(args, sc, truth_csv, products)
            if code == 0:
                products.commit()
            return code
        except (OSError, ValueError) as exc:
            return userargs.fail(PROG, exc)
        except KeyboardInterrupt:  # Ctrl-C before the paced run took the signal over (or in a file run)
            print(f"{PROG}: interrupted; nothing written", file=sys.stderr)
            return 130


def _run(args, sc, truth_csv: TruthCsvWriter | None, products: Products) -> int:
    sim = Simulation(sc.design, sc.wind, sc.truth, args.duration, args.seed, keep_truth=False, truth_sink=truth_csv,
                     winch=sc.winch)  # fmt: skip
    enc = SensorPacketEncoder(ground_sysid=sc.design.site.ground_sysid)
    t0 = time.perf_counter()
    n = 0
    out = args.out
    bar = Progress(PROG, total=args.duration, unit="s simulated", quiet=args.quiet)
    if args.ground_csv:
        sim = _GroundCsv(sim, products.path(args.ground_csv))
    try:
        if out and userargs.is_link(out):
            from sim_hil.link import stream_udp  # network edge, only when asked for

            n = stream_udp(sim, enc, out, args, bar)
        elif out:
            with products.open(out, "wb") as fh:
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
        sim.flush_truth()
        if isinstance(sim, _GroundCsv):
            sim.close()
        if truth_csv is not None:
            truth_csv.close()
    wall = time.perf_counter() - t0
    simulated = n / sim.imu_hz
    interrupted = n < sim.n_imu
    print(
        f"{PROG}: {sc.name} seed {args.seed}: {n} IMU samples, {simulated:.0f} s simulated "
        f"in {wall:.1f} s ({simulated / max(wall, 1e-9):.0f}x real time)"
        + (f"; interrupted before the {args.duration:.0f} s asked for" if interrupted else ""),
        file=sys.stderr,
    )
    return 130 if interrupted else 0


class _GroundCsv:
    """The simulation with its ground reference's readings also written to a CSV (balloon_core/groundref.py)."""

    def __init__(self, sim: Simulation, path: str) -> None:
        self.sim, self.path, self.rows = sim, path, ([], [], [])

    def __getattr__(self, name: str):
        return getattr(self.sim, name)

    def samples(self):
        for s in self.sim.samples():
            if s.ground is not None:
                for col, v in zip(self.rows, (s.time_usec * 1e-6, *s.ground)):
                    col.append(v)
            yield s

    def close(self) -> None:
        from balloon_core.groundref import write_ground_csv

        write_ground_csv(self.path, *self.rows)


if __name__ == "__main__":
    sys.exit(main())
