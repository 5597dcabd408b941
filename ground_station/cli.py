"""``balloon-gs``: listen (live view + logs) and report (score + plot)."""

from __future__ import annotations

import argparse
import signal
import sys


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="balloon-gs", description="WIND_COV ground station")
    sub = ap.add_subparsers(dest="cmd", required=True)
    li = sub.add_parser("listen", help="live view of WIND_COV from a UDP endpoint or a serial port")
    li.add_argument("endpoint", help="udpin:0.0.0.0:14550, udpout:HOST:PORT, /dev/ttyUSB0:57600 ...")
    li.add_argument("--csv", help="log every WIND_COV to this CSV")
    li.add_argument("--tlog", help="log every received frame to this tlog")
    li.add_argument("--duration", type=float, help="stop after this many seconds")
    rp = sub.add_parser("report", help="score a WIND_COV log against a truth CSV and plot it")
    rp.add_argument("file", help="ground-station CSV, .tlog or raw capture holding WIND_COV")
    rp.add_argument("--truth", required=True, help="balloon-sim --truth CSV")
    rp.add_argument("--plot", help="write the Fig. 6-style figure here (PNG)")
    rp.add_argument("--start", type=float, default=120.0, help="score from this time since boot [s]")
    args = ap.parse_args(argv)
    if args.cmd == "listen":
        from ground_station.listen import GroundStation, listen

        stopping: list[int] = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stopping.append(1))
        gs = GroundStation(args.csv, args.tlog)
        try:
            listen(args.endpoint, gs, lambda: bool(stopping), args.duration)
        except ValueError as exc:
            print(f"balloon-gs: {exc}", file=sys.stderr)
            return 2
        finally:
            gs.close()
            print(gs.summary(), file=sys.stderr)
        return 0
    from ground_station.report import format_score, report

    try:
        s = report(args.file, args.truth, args.plot, args.start)
    except (ValueError, OSError) as exc:
        print(f"balloon-gs report: {exc}", file=sys.stderr)
        return 2
    print(format_score(s))
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
