"""``balloon-replay FILE --out ENDPOINT [--speed N] [--lockstep]``: play a capture into a UDP endpoint or
a serial port at the recorded timing (or N times faster; 0 = as fast as possible). Serial log replay
without hardware. A .tlog is paced by its record timestamps; a raw capture by the time fields of the
messages inside it (HIGHRES_IMU / HIL_SENSOR time_usec, SCALED_PRESSURE time_boot_ms), and its bytes
are sent exactly as captured, garbage included.

Lockstep (the default with --speed 0): like balloon-sim --lockstep, a sample is sent only once the
firmware's WIND_COV says it has digested the samples up to half a second before it, so nothing is
dropped however fast. The last line says what the firmware reported it lost (its SYS_STATUS), or
that nothing came back to say.

A recorded wind: a firmware output log (a .tlog of WIND_COV, WIND, ESTIMATOR_STATUS, HEARTBEAT, ... and no
sensor sample) is played as it was recorded, every record at its time (or N times faster), to any MAVLink
endpoint: a past flight shown in MAVProxy, QGroundControl or balloon-gs. There is no firmware to wait for:
no lockstep."""

from __future__ import annotations

import argparse
import os
import struct
import sys
import time
from dataclasses import dataclass

from balloon_core import userargs
from balloon_core.progress import Progress
from balloon_core.wire import (
    MAGIC_V2,
    MAX_FRAME,
    TLOG_HEADER,
    Decoder,
    LinkStats,
    capture_messages,
    frame_length,
    frame_msgid,
    mavlink,
    message_time_us,
    next_magic,
    open_link,
    plausible_record_times,
)
from sim_hil.link import Lockstep

IMU_MSG_IDS = {105, 107}  # HIGHRES_IMU, HIL_SENSOR: time_usec (uint64) is the first payload field
IMU_MS_MSG_IDS = {26}  # SCALED_IMU: time_boot_ms (uint32) is the first payload field
SLEEP_SLICE_S = 0.1  # a wait for a record's time is cut into sleeps this long: Ctrl-C and SIGTERM stop it at once


def imu_time_us(frame: bytes) -> int | None:
    """The sample time of an IMU frame (HIGHRES_IMU, HIL_SENSOR, SCALED_IMU), else None; read from the
    frame's header and first payload field, without decoding it."""
    msgid = frame_msgid(frame) if len(frame) >= 8 else None
    if msgid is None:
        return None
    payload = frame[10 : 10 + frame[1]] if frame[0] == MAGIC_V2 else frame[6 : 6 + frame[1]]
    if msgid in IMU_MSG_IDS:
        return struct.unpack("<Q", (bytes(payload[:8]) + bytes(8))[:8])[0]  # MAVLink 2 trims trailing zeros
    if msgid in IMU_MS_MSG_IDS:
        return struct.unpack("<I", (bytes(payload[:4]) + bytes(4))[:4])[0] * 1000
    return None


def paced_tlog_records(path: str, stats: LinkStats):
    """``tlog_records`` with a record time that is not plausible against its neighbours (a damaged 8-byte header: no
    CRC covers it) as None, counted in ``stats.bad_stamps`` (``wire.plausible_record_times``): not paced on."""
    pairs = plausible_record_times(((rec, rec[0] * 1e-6) for rec in tlog_records(path)), stats)
    for (ts, t_imu, frame), t in pairs:
        yield (None if t is None else ts), t_imu, frame


def wait_until(deadline: float, stop) -> None:
    """Sleep until ``time.monotonic()`` reaches ``deadline`` or ``stop()`` says so, in slices of ``SLEEP_SLICE_S``:
    however far ahead a record's time lies, a signal stops the wait within a slice."""
    while not stop():
        ahead = deadline - time.monotonic()
        if ahead <= 0.001:
            return
        time.sleep(min(ahead, SLEEP_SLICE_S))


def tlog_records(path: str):
    """(record timestamp us, IMU sample time us or None, frame bytes) of each record."""
    with open(path, "rb") as fh:
        buf = fh.read()
    i = 0
    while i + TLOG_HEADER < len(buf):
        ln = frame_length(buf, i + TLOG_HEADER)
        if ln == 0:
            i += 1
            continue
        (ts,) = struct.unpack(">Q", buf[i : i + TLOG_HEADER])
        frame = buf[i + TLOG_HEADER : i + TLOG_HEADER + ln]
        yield ts, imu_time_us(frame), frame
        i += TLOG_HEADER + ln


def raw_chunks(path: str, chunk: int = 65536):
    """(time us or None, IMU sample time us or None, bytes) of a raw capture, one piece per MAVLink frame and
    one per run of bytes between frames (garbage, a frame cut short), so that the byte stream is sent exactly
    as captured while a datagram link (UDP) still carries whole frames, each in its own datagram, as a
    receiver that parses every datagram on its own needs. A frame is timed by its own time field."""
    dec = Decoder(LinkStats())
    known = mavlink.mavlink_map
    with open(path, "rb") as fh:
        buf, i, eof = b"", 0, False
        garbage_from = 0
        while True:
            if not eof and len(buf) - i < MAX_FRAME:
                if i > garbage_from:  # no frame starts before i: send the bytes so far (memory stays bounded)
                    yield None, None, buf[garbage_from:i]
                    garbage_from = i
                more = fh.read(chunk)
                buf, garbage_from, i, eof = buf[garbage_from:] + more, 0, i - garbage_from, not more
                continue
            if i >= len(buf):
                break
            ln = frame_length(buf, i)
            if ln == 0 or i + ln > len(buf):
                i = next_magic(buf, i + 1) if ln == 0 else i + 1
                continue
            frame = buf[i : i + ln]
            m = dec.decode_frame(frame) if frame_msgid(frame) in known else None
            if m is None:  # a CRC error or a message no receiver knows (pymavlink's parser skips it alike)
                i += 1  # a garbage byte
                continue
            if i > garbage_from:
                yield None, None, buf[garbage_from:i]
            t = message_time_us(m)
            yield t, imu_time_us(frame), frame
            i += ln
            garbage_from = i
        if len(buf) > garbage_from:
            yield None, None, buf[garbage_from:]


@dataclass
class ReplayResult:
    bytes_sent: int = 0
    imu_sent: int = 0
    lockstep: bool = False
    timeouts: int = 0
    acknowledged: bool = False  # the firmware caught up with the last sample and reported after it
    fw_lost: int | None = None  # the firmware's own count of packets it lost (SYS_STATUS), if it said
    fw_long_gaps: int = 0
    fw_imu_missing: int = 0
    fw_time_s: float = -1.0  # the newest sample time the firmware's WIND_COV acknowledged
    sent_time_s: float = -1.0  # the newest sample time sent
    interrupted: bool = False
    records_sent: int = 0  # tlog records, or a raw capture's frames and runs of bytes between them, sent
    bad_stamps: int = 0  # tlog records whose time is not plausible (a damaged header): sent, not paced on

    def stamps_note(self) -> str:
        """``, 1 record time damaged (sent, not paced on)``, or nothing."""
        n = self.bad_stamps
        return f", {n} record time{'' if n == 1 else 's'} damaged (sent, not paced on)" if n else ""

    def final_line(self, out: str, speed: float) -> str:
        head = f"balloon-replay: {self.imu_sent} IMU samples ({self.bytes_sent} bytes) sent to {out}"
        if self.lockstep:
            head += " in lockstep"
            if self.timeouts:
                head += f", LOST SYNC {self.timeouts} times (the firmware fell silent for 2 s)"
        else:
            head += " flat out" if speed == 0 else f" at {speed:g}x"
        if self.interrupted:
            head += ", interrupted"
        head += self.stamps_note()
        if self.fw_lost is None:
            if self.lockstep or speed == 0:
                return head + "; nothing came back to say what arrived: losses unknown"
            return head + "; no receiver report: losses unknown"
        tail = ""
        if not self.acknowledged and not self.interrupted and self.fw_time_s < self.sent_time_s - 0.2:
            tail = f"; its estimate stops at {self.fw_time_s:.1f} s, the samples sent at {self.sent_time_s:.1f} s"
        if self.fw_lost or self.fw_long_gaps or self.fw_imu_missing or tail:
            counts = f"{self.fw_lost} packets lost, {self.fw_imu_missing} IMU samples missing"
            return head + f"; DATA LOST: the firmware counted {counts}, {self.fw_long_gaps} long gaps{tail}"
        return head + ("; the firmware counted 0 packets lost" if self.acknowledged
                       else "; the firmware counted 0 lost but did not confirm the end")  # fmt: skip


def replay(path: str, out: str, speed: float, stop=lambda: False, lockstep: bool = False, window_s: float = 0.5,
           timeout_s: float = 2.0, progress: Progress | None = None) -> ReplayResult:  # fmt: skip
    link = open_link(out)
    ls = Lockstep(link, window_s, timeout_s)
    stamps = LinkStats()
    items = paced_tlog_records(path, stamps) if path.endswith(".tlog") else raw_chunks(path)
    res = ReplayResult(lockstep=lockstep)
    t_first = None
    wall0 = time.monotonic()
    try:
        for k, (t, t_imu, data) in enumerate(items):
            if stop():
                res.interrupted = True
                break
            if t is not None and speed > 0:
                if t_first is None:
                    t_first = t
                wait_until(wall0 + (t - t_first) * 1e-6 / speed, stop)
                if stop():
                    res.interrupted = True
                    break
            if t_imu is not None:
                if lockstep:
                    ls.wait_for(t_imu)
                else:
                    ls.note_sent(t_imu)
                res.imu_sent += 1
            if not lockstep and k % 100 == 0:
                ls.poll(0.0)  # drain what comes back (and keep the firmware's SYS_STATUS)
            link.send(data)
            res.bytes_sent += len(data)
            res.records_sent += 1
            if progress is not None:
                progress.done = res.bytes_sent / 1e6
        if not res.interrupted and (lockstep or ls.fw_status is not None):
            res.acknowledged = ls.finish(timeout_s + 1.5)
    finally:
        link.close()
    res.bad_stamps = stamps.bad_stamps
    res.timeouts = ls.timeouts
    res.fw_lost = ls.firmware_lost()
    res.fw_time_s, res.sent_time_s = ls.fw_time_us * 1e-6, ls.sent_us * 1e-6
    if ls.fw_status is not None:
        res.fw_long_gaps = int(ls.fw_status.errors_count3)
        res.fw_imu_missing = int(ls.fw_status.errors_count4)
    return res


def first_sample(path: str) -> tuple[int, bool, bool]:
    """(MAVLink frames read, whether a sensor sample came, whether a WIND_COV came) up to the first sensor
    sample (IMU or barometer) of a capture, without reading further."""
    from balloon_core.samples import MavlinkSampler

    stats, sampler = LinkStats(), MavlinkSampler()
    msgs = capture_messages(path, stats)
    wind = False
    try:
        for m in msgs:
            if sampler.convert(m):
                return stats.frames, True, wind
            wind = wind or m.get_type() == "WIND_COV"
    finally:
        msgs.close()
    return stats.frames, False, wind


def main(argv: list[str] | None = None) -> int:
    prog = "balloon-replay"
    ap = userargs.Parser(prog=prog, description=" ".join(__doc__.split("\n\n")[0].replace("``", "").split()))
    ap.add_argument("file", type=userargs.input_file, help=".tlog or raw capture")
    ap.add_argument("--out", required=True, type=userargs.link, help="udpout:HOST:PORT, udpin:..., or a serial port")
    ap.add_argument("--speed", type=userargs.speed, default=1.0, help="N x recorded timing; 0 = as fast as possible")
    ap.add_argument(
        "--lockstep",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="send only as fast as the firmware's WIND_COV acknowledges (default: on with --speed 0)",
    )
    ap.add_argument(
        "--lockstep-window", type=userargs.positive_float, default=0.5, help="seconds the replay may lead the firmware"
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar / status lines (the final line stays)")
    args = ap.parse_args(argv)
    lockstep = args.lockstep if args.lockstep is not None else args.speed == 0
    try:  # the one rule for output options (--out is a link: a serial device is never the capture itself)
        userargs.check_outputs({"file": args.file}, {"--out": args.out})
    except userargs.UserError as exc:
        return userargs.fail(prog, exc)
    try:
        frames, sample, wind = first_sample(args.file)
        if frames == 0:
            return userargs.fail(prog, f"{args.file}: no MAVLink frame in this file (not a capture of a MAVLink link?)")
        recorded_wind = not sample and wind and args.file.endswith(".tlog")
        if not sample and not recorded_wind:
            return userargs.fail(prog, f"{args.file}: {frames} MAVLink frames but no sensor sample (IMU or barometer)"
                                 + (" and no WIND_COV" if not wind else " (a recorded wind replays from a .tlog)"))
        if recorded_wind and args.lockstep:
            return userargs.fail(prog, f"{args.file} is a recorded wind (no sensor sample): --lockstep has no "
                                 "firmware to wait for")  # fmt: skip
    except OSError as exc:
        return userargs.fail(prog, exc)
    if recorded_wind:
        lockstep = False
    stop = userargs.stop_flag()
    try:
        size = os.path.getsize(args.file)
    except OSError as exc:
        return userargs.fail(prog, exc)
    bar = Progress(prog, total=size / 1e6, unit="MB", quiet=args.quiet)
    try:
        res = replay(args.file, args.out, args.speed, stop, lockstep, args.lockstep_window,
                     progress=bar)  # fmt: skip
    except (OSError, ValueError) as exc:
        bar.close()
        return userargs.fail(prog, exc)
    bar.close()
    if recorded_wind:
        pace = "flat out" if args.speed == 0 else f"at {args.speed:g}x"
        print(f"{prog}: a recorded wind, {res.records_sent} records ({res.bytes_sent} bytes) sent to {args.out} {pace}"
              + (", interrupted" if res.interrupted else "") + res.stamps_note(), file=sys.stderr)  # fmt: skip
    else:
        print(res.final_line(args.out, args.speed), file=sys.stderr)
    return 130 if res.interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
