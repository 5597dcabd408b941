"""``balloon-replay FILE --out ENDPOINT [--speed N]``: play a capture into a UDP endpoint or a serial
port at the recorded timing (or N times faster; 0 = as fast as possible). Serial log replay without
hardware. A .tlog is paced by its record timestamps; a raw capture by the time fields of the
messages inside it (HIGHRES_IMU / HIL_SENSOR time_usec, SCALED_PRESSURE time_boot_ms), and its bytes
are sent exactly as captured, garbage included."""

from __future__ import annotations

import signal
import struct
import sys
import time

from firmware_py import userargs
from firmware_py.mavio import TLOG_HEADER, Decoder, LinkStats, frame_length, open_link, raw_messages, tlog_messages


def tlog_records(path: str):
    """(timestamp us, frame bytes) of each record."""
    with open(path, "rb") as fh:
        buf = fh.read()
    i = 0
    while i + TLOG_HEADER < len(buf):
        ln = frame_length(buf, i + TLOG_HEADER)
        if ln == 0:
            i += 1
            continue
        (ts,) = struct.unpack(">Q", buf[i : i + TLOG_HEADER])
        yield ts, buf[i + TLOG_HEADER : i + TLOG_HEADER + ln]
        i += TLOG_HEADER + ln


def raw_chunks(path: str, chunk: int = 64):
    """(time us or None, bytes) of a raw capture, timed by the messages decoded so far."""
    dec = Decoder(LinkStats())
    with open(path, "rb") as fh:
        data = fh.read()
    for i in range(0, len(data), chunk):
        piece = data[i : i + chunk]
        t = None
        for m in dec.feed(piece):
            if hasattr(m, "time_usec"):
                t = m.time_usec
            elif hasattr(m, "time_boot_ms"):
                t = m.time_boot_ms * 1000
        yield t, piece


def replay(path: str, out: str, speed: float, stop=lambda: False) -> int:
    link = open_link(out)
    items = tlog_records(path) if path.endswith(".tlog") else raw_chunks(path)
    t_first = None
    wall0 = time.monotonic()
    sent = 0
    try:
        for t, data in items:
            if stop():
                break
            if t is not None and speed > 0:
                if t_first is None:
                    t_first = t
                ahead = wall0 + (t - t_first) * 1e-6 / speed - time.monotonic()
                if ahead > 0.001:
                    time.sleep(ahead)
            link.send(data)
            sent += len(data)
    finally:
        link.close()
    return sent


def first_frame(path: str):
    """The first MAVLink message in a capture (None if there is none), without reading it all."""
    stats = LinkStats()
    if path.endswith(".tlog"):
        return next(iter(tlog_messages(path, stats)), None)
    with open(path, "rb") as fh:
        return next(iter(raw_messages(fh, stats)), None)


def main(argv: list[str] | None = None) -> int:
    prog = "balloon-replay"
    ap = userargs.Parser(prog=prog, description=" ".join(__doc__.split("\n\n")[0].replace("``", "").split()))
    ap.add_argument("file", type=userargs.input_file, help=".tlog or raw capture")
    ap.add_argument("--out", required=True, type=userargs.link, help="udpout:HOST:PORT, udpin:..., or a serial port")
    ap.add_argument("--speed", type=userargs.speed, default=1.0,
                    help="N x recorded timing; 0 = as fast as possible")
    args = ap.parse_args(argv)
    try:
        if first_frame(args.file) is None:
            return userargs.fail(prog, f"no MAVLink frame in {args.file}")
    except OSError as exc:
        return userargs.fail(prog, exc)
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopping.append(1))
    try:
        n = replay(args.file, args.out, args.speed, lambda: bool(stopping))
    except (OSError, ValueError) as exc:
        return userargs.fail(prog, exc)
    print(f"balloon-replay: {n} bytes sent to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
