"""``balloon-fw --in SOURCE --out SINK [--config FILE.toml]`` (docs/usage.md)."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time

from balloon_core import userargs
from balloon_core.atomic import Products
from balloon_core.config import ConfigError, design_from_dict, load_toml
from balloon_core.progress import Progress, RateMeter
from balloon_core.wire import Decoder, LinkStats, capture_messages, open_link, open_sink
from firmware_c.build import BuildError
from firmware_py.app import Firmware, OutputConfig
from firmware_py.estimator.state import FilterConfig
from firmware_py.replay import replay_tlog, scanner
from firmware_py.streams import StreamRequester


def load_config(path: str | None):
    """(design, [filter], [outputs]) of a design file (the defaults without one)."""
    if path is None:
        from balloon_core.config import Design

        return Design(), FilterConfig(), OutputConfig()
    data = load_toml(path)
    return (design_from_dict(data), FilterConfig.from_dict(data.get("filter", {})),
            OutputConfig.from_dict(data.get("outputs", {})))  # fmt: skip


def rate_is_explicit(path: str | None) -> bool:
    """Does the config set ``[filter] imu_rate_hz`` (else the rate is measured from the stream)?"""
    return path is not None and "imu_rate_hz" in load_toml(path).get("filter", {})


def replay_file(fw: Firmware, path: str, progress: Progress | None = None, stop=None) -> bool:
    """Every message of a capture; a file without a single sensor sample in it (no MAVLink at all, or
    none from an IMU or a barometer) is a UserError. Returns False if ``stop()`` said to stop before the
    end (Ctrl-C)."""
    fw.use_batches()  # a file: the samples to the C core a block at a time (the same outputs)
    done = _replay(fw, path, progress, stop)
    if done and fw.stats.frames == 0:
        raise userargs.UserError(f"{path}: no MAVLink frame in this file (not a capture of a MAVLink link?)")
    if done and fw.samples_in == 0:
        raise userargs.UserError(f"{path}: {fw.stats.frames} MAVLink frames but no sensor sample (IMU or barometer)")
    return done


def _replay(fw: Firmware, path: str, progress: Progress | None, stop) -> bool:
    tlog = path.endswith(".tlog")
    scan = scanner() if tlog and fw._block is not None else None
    if scan is not None:  # the C core's tlog scanner (firmware_py/replay.py: the same messages and counts)
        if not replay_tlog(fw, path, scan, progress, stop):
            return False
        fw.flush()
        return True
    st = fw.stats
    msgs = capture_messages(path, st, fast=True)  # the sensor messages by fastmav (same messages, same counts)
    try:
        for k, m in enumerate(msgs):
            fw.handle(m)
            if k % 1000 == 0 and stop is not None and stop():
                return False
            if progress is not None and k % 1000 == 0:
                # file position: the frames' bytes (+ the tlog's 8-byte record headers) and the garbage
                progress.done = (st.bytes + st.garbage_bytes + (8 * (st.frames + st.bad_frames) if tlog else 0)) / 1e6
                progress.status = fw.status()
    finally:
        msgs.close()  # closes the file
    fw.flush()
    return True


def run_live(fw: Firmware, spec: str, stop, progress: Progress | None = None,
             duration_s: float | None = None) -> bool:  # fmt: skip
    """Until stopped (returns False: Ctrl-C) or for ``duration_s`` of wall-clock time (returns True):
    decode what arrives; keep the 1 Hz heartbeat and the WIND_COV stream going on the wall clock when the
    sensors fall silent (accuracy then reflects the silence). Once a second the status (input rate,
    mode, wind, accuracy, lost) goes to ``progress``."""
    link = open_link(spec)
    fw.sinks.append(link)  # like any vehicle, it also talks back on the link its sensors come from
    # an autopilot on the link that does not stream its sensors fast enough is asked to (streams.py)
    fw.streams = streams = StreamRequester(fw.mav, fw.sampler, fw.est.cfg.imu_rate_hz)
    dec = Decoder(fw.stats)
    # what a ground station sends back on the output link (its requests: firmware_py/gcs.py), read too
    back = {s: Decoder(LinkStats()) for s in fw.sinks if s is not link and hasattr(s, "recv")}
    last_rx = time.monotonic()
    last_emit = 0.0
    next_status = last_rx + 1.0
    frames, imu = RateMeter(), RateMeter()
    frames.rate(last_rx, fw.stats.frames)  # the rates count from here
    imu.rate(last_rx, fw.est.counters.imu_samples)
    end = math.inf if duration_s is None else last_rx + duration_s
    try:
        while not stop():
            data = link.recv(0.05)
            now = time.monotonic()
            if now >= end:
                return True
            if data:
                last_rx = now
                for m in dec.feed(data, link.datagrams):
                    fw.handle(m, link)
                    streams.on_message(m, now)
            elif now - last_rx > 0.5 and now - last_emit > 0.1:
                fw.coast(now)
                last_emit = now
            for sink, gdec in back.items():
                for m in gdec.feed(sink.recv(0.0), sink.datagrams):
                    if not fw.sampler.is_sensor(m):  # the sensors come on --in
                        fw.handle(m, sink)
            for frame in streams.poll(now):
                link.send(frame)
            if progress is not None and now >= next_status:
                next_status = now + 1.0
                silent = f", silent {now - last_rx:.0f} s" if now - last_rx > 2.0 else ""
                progress.update(
                    fw.stats.frames,
                    f"in {frames.rate(now, fw.stats.frames):.0f} msg/s "
                    f"({imu.rate(now, fw.est.counters.imu_samples):.0f} IMU/s){silent}, {fw.status()}",
                )
    finally:
        link.close()
    return False


def main(argv: list[str] | None = None) -> int:
    prog = "balloon-fw"
    ap = userargs.Parser(prog=prog, description="Tethered-balloon wind EKF firmware")
    ap.add_argument("--in", dest="source", required=True, type=userargs.source,
                    help=".tlog, raw capture, udpin:/udpout:, serial port")  # fmt: skip
    ap.add_argument("--out", dest="sink", type=userargs.tlog_sink,
                    help="udpout:HOST:PORT or FILE.tlog for WIND_COV + HEARTBEAT")  # fmt: skip
    ap.add_argument("--config", type=userargs.input_file, help="TOML design file (the same one balloon-sim reads)")
    ap.add_argument("--core", choices=("c", "py"),
                    help="c: the C core, py: the Python reference (default: [filter] core, else c)")  # fmt: skip
    ap.add_argument("--quiet", action="store_true", help="no progress bar / live status (the summary stays)")
    ap.add_argument("--duration", type=userargs.duration,
                    help="a live source: stop after this many seconds (wall clock), exit 0")  # fmt: skip
    args = ap.parse_args(argv)
    try:  # the one rule for output options, before any work
        userargs.check_outputs({"--in": args.source, "--config": args.config}, {"--out": args.sink})
    except userargs.UserError as exc:
        return userargs.fail(prog, exc)
    with Products() as products:  # a tlog under a temporary name, renamed when the run ends well
        return _main(prog, args, products)


def _main(prog: str, args, products: Products) -> int:
    try:
        design, fcfg, outputs = load_config(args.config)
    except ConfigError as exc:
        return userargs.fail(prog, exc)
    if args.core is not None:
        fcfg = dataclasses.replace(fcfg, core=args.core)
    is_file = os.path.isfile(args.source)
    if is_file and args.duration is not None:
        return userargs.fail(prog, f"--duration is for a live source; {args.source} is a file (read to its end)")
    try:
        to_file = args.sink is not None and not userargs.is_link(args.sink)
        sink = open_sink(products.path(args.sink) if to_file else args.sink) if args.sink else None
    except (ValueError, OSError) as exc:
        return userargs.fail(prog, exc)
    try:
        fw = Firmware(design, fcfg, sink, rate_explicit=rate_is_explicit(args.config), outputs=outputs)
    except BuildError as exc:
        if sink is not None:
            sink.close()
        return userargs.fail(prog, f"{exc}; or run the Python core: --core py")
    stop = userargs.stop_flag()
    if is_file:
        bar = Progress("balloon-fw", total=os.path.getsize(args.source) / 1e6, unit="MB", quiet=args.quiet)
    else:
        bar = Progress("balloon-fw", unit="frames", quiet=args.quiet, interval_s=5.0)
    finished = True
    try:
        if is_file:
            finished = replay_file(fw, args.source, bar, stop)
            bar.done = bar.total if finished else bar.done
        else:
            finished = run_live(fw, args.source, stop, bar, args.duration)
    except (ValueError, OSError, userargs.UserError) as exc:
        bar.close()
        if sink is not None:
            sink.close()  # the temporary tlog is removed: no half-written output beside an error
        return userargs.fail(prog, exc)
    bar.close()
    if sink is not None:
        sink.close()
    if finished or not is_file:  # a whole file, or a live run however it was stopped: what came is the log
        products.commit()
    print(fw.summary(), file=sys.stderr)
    if is_file and not finished:
        print(f"{prog}: interrupted before the end of {args.source}", file=sys.stderr)
        return 130
    if not is_file and stop.interrupted:
        print(f"{prog}: interrupted (Ctrl-C) on {args.source}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
