"""``balloon-gs``: listen (live view + logs), web (the same in a browser), report (score + plot), reprocess
(post-flight products) and level (the IMU's mounting from the payload hung still)."""

from __future__ import annotations

import math
import os
import sys

from balloon_core import userargs
from balloon_core.atomic import Products

PROG = "balloon-gs"
DEFAULT_BIND = ("127.0.0.1", 8000)


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog=PROG, description="WIND_COV ground station")
    sub = ap.add_subparsers(dest="cmd", required=True)
    li = sub.add_parser("listen", help="live view of WIND_COV from a UDP endpoint or a serial port, or a recorded "
                        "link's (a .tlog or a raw capture) at once")  # fmt: skip
    li.add_argument("endpoint", type=userargs.source, help="udpin:0.0.0.0:14550, udpout:HOST:PORT, "
                    "/dev/ttyUSB0:57600, or FILE (a .tlog or a raw capture)")  # fmt: skip
    li.add_argument("--csv", type=userargs.output_path, help="log every WIND_COV to this CSV")
    li.add_argument("--tlog", type=userargs.output_path, help="log every received frame to this tlog")
    li.add_argument("--duration", type=userargs.duration, help="stop after this many seconds")
    li.add_argument("--ground-pressure", type=userargs.input_file, metavar="CSV",
                    help="send the newest reading of this ground-barometer CSV (a logger appends to it) up the "
                         "link each second as the ground reference")  # fmt: skip
    li.add_argument("--ground-sysid", type=userargs.sysid, default=255, help="this ground station's MAVLink system id "
                    "([site] ground_sysid of the firmware's design file)")  # fmt: skip
    we = sub.add_parser("web", help="the ground station in a browser: live WIND_COV of every balloon, or a product")
    we.add_argument("endpoint", nargs="*", type=userargs.source, help="as for listen; one or more (or none with "
                    "--product); a recording's last state is shown as it ended")  # fmt: skip
    we.add_argument("--bind", type=userargs.bind, default=DEFAULT_BIND, metavar="HOST:PORT",
                    help=f"serve the page here (default {DEFAULT_BIND[0]}:{DEFAULT_BIND[1]}: this machine only)")
    we.add_argument("--product", type=userargs.input_file, metavar="FILE.nc",
                    help="also show this balloon-gs reprocess product (and its <stem>_profile.nc)")
    rp = sub.add_parser("report", help="score a WIND_COV log against a truth CSV and plot it (without a truth: "
                        "summarise and plot the estimate alone)")  # fmt: skip
    rp.add_argument(
        "file",
        type=userargs.input_file,
        help="ground-station CSV, .tlog or raw capture holding WIND_COV, or a reprocess .nc",
    )
    rp.add_argument("--truth", type=userargs.input_file, help="balloon-sim --truth CSV (none: a real flight)")
    rp.add_argument("--plot", type=userargs.plot_path, help="write the Fig. 6-style figure here (PNG)")
    rp.add_argument("--start", type=userargs.start_time, default=120.0, help="score from this time since boot [s]")
    rp.add_argument("--sysid", type=userargs.sysid,
                    help="the balloon's MAVLink system id, where the log holds WIND_COV from more than one")
    rr = sub.add_parser("reprocess", help="post-flight: filter + smoother over a whole flight log -> NetCDF (CF-1.8)")
    rr.add_argument("flight", type=userargs.input_file, help="a .tlog, raw capture, PX4 .ulg or ArduPilot .bin")
    rr.add_argument("--out", required=True, type=userargs.output_path, help="the NetCDF product (FILE.nc)")
    rr.add_argument("--config", type=userargs.input_file, help="TOML design file (the one the firmware flew with)")
    rr.add_argument("--plot", type=userargs.output_path, help="also draw the product here (PNG)")
    rr.add_argument("--quiet", action="store_true", help="no progress bar / status lines (the final lines stay)")
    rr.add_argument("--ground-pressure", type=userargs.input_file, metavar="CSV",
                    help="the ground reference's readings (time_s or time_unix_s, pressure_hpa, temperature_c): "
                         "height as a difference of two barometers")  # fmt: skip
    lv = sub.add_parser("level", help="the IMU's mounting against the balloon's axis from a recording of the payload "
                        "hung still from its tether attachment: the design's [sensors] imu_roll_deg, imu_pitch_deg")
    lv.add_argument("flight", type=userargs.input_file, help="a .tlog, raw capture, PX4 .ulg or ArduPilot .bin")
    lv.add_argument("--from", dest="start", type=userargs.start_time, default=0.0,
                    help="from this time since the recording's first IMU sample [s]")  # fmt: skip
    lv.add_argument("--to", dest="stop", type=userargs.duration, help="to this time since its first IMU sample [s]")
    args = ap.parse_args(argv)
    prog = f"{PROG} {args.cmd}"
    try:  # the one rule for output options (an input, another output, unwritable), before any work
        userargs.check_outputs(*_files(args))
    except userargs.UserError as exc:
        return userargs.fail(prog, exc)
    if args.cmd == "reprocess":
        try:
            from postflight.reprocess import run_reprocess

            return run_reprocess(args, argv)
        except (ValueError, OSError, userargs.UserError) as exc:
            return userargs.fail(f"{PROG} reprocess", exc)
        except KeyboardInterrupt:
            print(f"{PROG} reprocess: interrupted; nothing written", file=sys.stderr)
            return 130
    if args.cmd == "web":
        return _web(args)
    if args.cmd == "level":
        from postflight.level import format_level, level_of
        from postflight.logs import read_flight

        try:
            print(format_level(level_of(read_flight(args.flight).samples(), args.start, args.stop or math.inf),
                               args.flight))  # fmt: skip
        except (ValueError, OSError) as exc:
            return userargs.fail(prog, exc)
        return 0
    if args.cmd == "listen":
        from ground_station.listen import GroundStation, listen, read_file

        recorded = os.path.isfile(args.endpoint)
        if recorded and args.ground_pressure:
            return userargs.fail(PROG, f"--ground-pressure goes up a live link; {args.endpoint} is a recording")
        stop = userargs.stop_flag()
        with Products() as products:  # the logs under temporary names, renamed when listening stops
            try:
                gs = GroundStation(args.csv and products.path(args.csv), args.tlog and products.path(args.tlog),
                                   ground_pressure=args.ground_pressure, sysid=args.ground_sysid)  # fmt: skip
                gs.csv_path, gs.tlog_path = args.csv, args.tlog  # what the view names
            except OSError as exc:
                return userargs.fail(PROG, exc)
            try:
                (read_file if recorded else listen)(args.endpoint, gs, stop, args.duration)
            except (ValueError, OSError) as exc:
                gs.close()
                return userargs.fail(PROG, exc)
            gs.close()
            products.commit()  # a live log is whole however listening stopped (Ctrl-C, SIGTERM, --duration)
        print(gs.summary(), file=sys.stderr)
        if stop.interrupted:  # Ctrl-C (not --duration, not SIGTERM): the run did not finish
            print(f"{PROG}: interrupted (Ctrl-C) on {args.endpoint}", file=sys.stderr)
            return 130
        return 0
    from ground_station.report import format_score, report

    notes: list[str] = []  # what of the log was left out (the earlier boots of a log of several)
    try:
        with Products() as products:
            s = report(args.file, args.truth, args.plot and products.path(args.plot), args.start, args.sysid, notes)
            products.commit()
    except (ValueError, OSError, userargs.UserError) as exc:  # the notes say what of the log it was about
        return userargs.fail(f"{PROG} report", f"{exc} (note: {'; '.join(notes)})" if notes else exc)
    for note in notes:
        print(f"{PROG} report: note: {note}", file=sys.stderr)
    print(format_score(s))
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def _web(args) -> int:
    prog = f"{PROG} web"
    if not args.endpoint and args.product is None:
        return userargs.fail(prog, "give one or more ENDPOINTs to listen to, or --product FILE.nc")
    try:
        userargs.require_extra("web")
    except userargs.UserError as exc:
        return userargs.fail(prog, exc)
    from ground_station.web.server import run

    host, port = args.bind
    stop = userargs.stop_flag()
    try:
        gs = run(args.endpoint, host, port, args.product, stop)
    except (ValueError, OSError, userargs.UserError) as exc:
        return userargs.fail(prog, exc)
    print(gs.summary(), file=sys.stderr)
    if stop.interrupted:  # as listen: Ctrl-C (not SIGTERM) says the run did not finish
        print(f"{prog}: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    return 0


def _files(args) -> tuple[dict[str, str | None], dict[str, str | None]]:
    """(inputs, outputs) of a ``balloon-gs`` command, by the names the user gave them."""
    if args.cmd == "web":  # read-only: it writes nothing
        return {"--product": args.product}, {}
    if args.cmd == "listen":
        recorded = args.endpoint if os.path.isfile(args.endpoint) else None  # a recording is an input too
        ins = {"ENDPOINT": recorded, "--ground-pressure": args.ground_pressure}
        return ins, {"--csv": args.csv, "--tlog": args.tlog}
    if args.cmd == "report":
        return {"file": args.file, "--truth": args.truth}, {"--plot": args.plot}
    if args.cmd == "level":  # read-only: it prints
        return {"FLIGHT": args.flight}, {}
    from postflight.netcdf import product_paths

    ins = {"FLIGHT": args.flight, "--config": args.config, "--ground-pressure": args.ground_pressure}
    return ins, product_paths(args.out, args.plot)


if __name__ == "__main__":
    sys.exit(main())
