"""``balloon-fw --in SOURCE --out SINK [--config FILE.toml]`` (docs/usage.md)."""

from __future__ import annotations

import os
import signal
import sys
import time

from firmware_py import userargs
from firmware_py.app import Firmware
from firmware_py.config import ConfigError, design_from_dict, load_toml
from firmware_py.mavio import Decoder, open_link, open_sink, raw_messages, tlog_messages
from firmware_py.state import FilterConfig


def load_config(path: str | None):
    if path is None:
        from firmware_py.config import Design

        return Design(), FilterConfig()
    data = load_toml(path)
    return design_from_dict(data), FilterConfig.from_dict(data.get("filter", {}))


def replay_file(fw: Firmware, path: str) -> None:
    """Every message of a capture; a file without a single MAVLink frame in it is a UserError."""
    _replay(fw, path)
    if fw.stats.frames == 0:
        raise userargs.UserError(f"no MAVLink frame in {path}")


def _replay(fw: Firmware, path: str) -> None:
    if path.endswith(".tlog"):
        for m in tlog_messages(path, fw.stats):
            fw.handle(m)
    else:
        with open(path, "rb") as fh:
            for m in raw_messages(fh, fw.stats):
                fw.handle(m)


def run_live(fw: Firmware, spec: str, stop) -> None:
    """Until stopped: decode what arrives; keep the 1 Hz heartbeat and the WIND_COV stream going on
    the wall clock when the sensors fall silent (accuracy then reflects the silence)."""
    link = open_link(spec)
    fw.sinks.append(link)  # like any vehicle, it also talks back on the link its sensors come from
    dec = Decoder(fw.stats)
    last_rx = time.monotonic()
    last_emit = 0.0
    try:
        while not stop():
            data = link.recv(0.05)
            now = time.monotonic()
            if data:
                last_rx = now
                for m in dec.feed(data):
                    fw.handle(m)
            elif now - last_rx > 0.5 and now - last_emit > 0.1:
                fw.coast(now)
                last_emit = now
    finally:
        link.close()


def main(argv: list[str] | None = None) -> int:
    prog = "balloon-fw"
    ap = userargs.Parser(prog=prog, description="Tethered-balloon wind EKF firmware")
    ap.add_argument("--in", dest="source", required=True, type=userargs.source,
                    help=".tlog, raw capture, udpin:/udpout:, serial port")  # fmt: skip
    ap.add_argument("--out", dest="sink", type=userargs.tlog_sink,
                    help="udpout:HOST:PORT or FILE.tlog for WIND_COV + HEARTBEAT")  # fmt: skip
    ap.add_argument("--config", type=userargs.input_file, help="TOML design file (the same one balloon-sim reads)")
    args = ap.parse_args(argv)
    try:
        design, fcfg = load_config(args.config)
    except ConfigError as exc:
        return userargs.fail(prog, exc)
    try:
        sink = open_sink(args.sink) if args.sink else None
    except (ValueError, OSError) as exc:
        return userargs.fail(prog, exc)
    fw = Firmware(design, fcfg, sink)
    stopping = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopping.append(1))
    try:
        if os.path.isfile(args.source):
            replay_file(fw, args.source)
        else:
            run_live(fw, args.source, lambda: bool(stopping))
    except (ValueError, OSError, userargs.UserError) as exc:
        if sink is not None:
            sink.close()
        return userargs.fail(prog, exc)
    if sink is not None:
        sink.close()
    print(fw.summary(), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
