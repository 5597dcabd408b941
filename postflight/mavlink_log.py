"""A telemetry log (``.tlog``) or a raw MAVLink capture into a ``Flight``."""

from __future__ import annotations

import array
import ctypes as C
import os
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from balloon_core import fastmav
from balloon_core.samples import (
    GROUND_SYSID,
    BaroSample,
    GroundBaroSample,
    GroundSample,
    ImuSample,
    MavlinkSampler,
    Sample,
    WinchSample,
)
from balloon_core.wire import Decoder, LinkStats, capture_messages
from postflight.flight import (
    KIND_BARO,
    KIND_GROUND,
    KIND_IMU,
    KIND_WINCH,
    Flight,
    FlightMeta,
    first_rate_hz,
    imu_losses,
    loss_notes,
    segment_note,
    sensor_span_s,
    sha256_of,
)


class SampleRows(NamedTuple):
    """Sensor samples in arrival order as arrays (what the C tlog scanner takes): ``kind`` 0 an IMU sample
    (``v``: ax ay az gx gy gz mx my mz), 1 a barometer's (``v[:, 0:2]``: hPa, degC)."""

    t: np.ndarray  # int64
    kind: np.ndarray  # int32
    v: np.ndarray  # (n, 9) float64

    def samples(self) -> Iterator[Sample]:
        for t, k, v in zip(self.t.tolist(), self.kind.tolist(), self.v.tolist()):
            yield ImuSample(t, *v) if k == 0 else BaroSample(t, v[0], v[1])


def mavlink_samples(
    path: str, stats: LinkStats | None = None, on_other=None, ground_sysid: int = GROUND_SYSID
) -> Iterator[Sample | GroundSample]:
    """The sensor samples of a capture in arrival order, through the live firmware's converter
    (MavlinkSampler), streamed from the file; ``on_other(msg)`` sees every other message. The winch's and
    the ground reference's samples keep their place (their arrival); their time is the newest sensor
    sample's, as the firmware stamps them."""
    for item in mavlink_blocks(path, stats, on_other, ground_sysid):
        if type(item) is SampleRows:
            yield from item.samples()
        else:
            yield item


def mavlink_blocks(
    path: str, stats: LinkStats | None = None, on_other=None, ground_sysid: int = GROUND_SYSID
) -> Iterator[SampleRows | Sample | GroundSample]:
    """``mavlink_samples`` with runs of the common sensor frames as ``SampleRows``: a tlog through the C
    core's scanner (firmware_c/host/tlog.c, as the firmware's file replay reads it: ``_scan_tlog``) where
    the C core can be built and fastmav decodes, else one sample at a time."""
    stats = stats if stats is not None else LinkStats()
    if path.endswith(".tlog"):
        from firmware_py.replay import scanner

        scan = scanner()
        if scan is not None:
            yield from _scan_tlog(path, stats, on_other, ground_sysid, scan)
            return
    yield from _samples_of(path, stats, on_other, ground_sysid)


def _converted(m, sampler: MavlinkSampler, on_other, last_t: int) -> tuple[list, int]:
    """A message's samples (``on_other`` gets one that is not a sensor's), the winch's and the ground reference's
    at the last IMU sample's time (they carry no sensor clock of their own), and that time after them."""
    out = sampler.convert(m)
    if out is None:
        if on_other is not None:
            on_other(m, sampler)
        return [], last_t
    stamped = []
    for smp in out:
        if type(smp) is WinchSample or type(smp) is GroundBaroSample:
            stamped.append(smp._replace(t_us=last_t))
            continue
        if type(smp) is ImuSample:
            last_t = smp.t_us
        stamped.append(smp)
    return stamped, last_t


def _samples_of(path: str, stats: LinkStats, on_other, ground_sysid: int) -> Iterator[Sample | GroundSample]:
    sampler = MavlinkSampler(ground_sysid)
    last_t = 0
    msgs = capture_messages(path, stats, fast=True)  # the sensor messages by fastmav: the same, faster
    try:
        for m in msgs:
            stamped, last_t = _converted(m, sampler, on_other, last_t)
            yield from stamped
    finally:
        msgs.close()
    if on_other is not None:
        on_other(None, sampler)


ROWS = 4096  # samples the scanner hands over at most at once


class _Reader:
    """The scanner's arrays for a reading (no firmware): the converter's and the link's state copied into
    them before a scan when Python changed it (``dirty``) and back after it (firmware_py/replay.py _Lane,
    without the firmware's block, clock and outputs: the scanner is told no output is ever due)."""

    def __init__(self, sampler: MavlinkSampler, stats: LinkStats) -> None:
        from firmware_py.replay import MAX_SENDERS, Q_SIZE, S_SENDERS

        self.sampler, self.stats = sampler, stats
        self.S = np.zeros(S_SENDERS + Q_SIZE * MAX_SENDERS, np.int64)
        self.D = np.zeros(10)  # the last thermometer reading, then MavlinkSampler.last_readings
        self.t = np.zeros(ROWS + 2, np.int64)
        self.kind = np.zeros(ROWS + 2, np.int32)
        self.v = np.zeros((ROWS + 2, 9))
        self.recent = np.zeros(ROWS + 2, np.int64)
        self.ptrs = [self.S.ctypes.data, self.D.ctypes.data, self.t.ctypes.data, self.kind.ctypes.data,
                     self.v.ctypes.data, self.recent.ctypes.data, None, None, None, None, None, None, None]  # fmt: skip
        self.senders: list = []
        self.prev = -1  # the newest IMU time: an IMU sample not after it is Python's (the scanner's rule)
        self.dirty = True

    def load(self, i: int, n: int, eof: bool) -> None:
        from firmware_py import replay as R

        S = self.S
        if not self.dirty:
            S[R.S_I], S[R.S_N], S[R.S_EOF], S[R.S_LEN] = i, n, eof, 0
            return
        self.dirty = False
        s = self.sampler
        self.senders = []
        if s.imu_key is None or s.imu_key[0] != fastmav.mavlink.MAVLINK_MSG_ID_HIGHRES_IMU:
            S[: R.S_SENDERS] = 0
            S[R.S_I], S[R.S_N], S[R.S_EOF] = i, n, eof
            return
        v = [0] * R.S_SENDERS
        v[R.S_I], v[R.S_N], v[R.S_EOF], v[R.S_LANE] = i, n, eof, 1
        R.sampler_to_scanner(s, v, self.D)
        never = 1 << 62
        v[R.S_PREV], v[R.S_BLOCK_T], v[R.S_DT] = self.prev, -never, 10_000
        v[R.S_NEXT_WIND] = v[R.S_NEXT_HB] = never
        v[R.S_LEN], v[R.S_BATCH] = 0, ROWS
        self.senders = R.senders_to_scanner(self.stats, v)
        S[: len(v)] = v

    def store(self) -> None:
        from firmware_py import replay as R

        S, st = self.S, self.stats
        v = S[: R.S_SENDERS].tolist()
        st.bytes += v[R.S_BYTES]
        st.frames += v[R.S_FRAMES]
        st.garbage_bytes += v[R.S_GARBAGE]
        st.bad_frames += v[R.S_BAD]
        if v[R.S_TRUNC]:
            st.truncated = True
        if not v[R.S_LANE] or not v[R.S_FRAMES]:
            return
        R.sampler_from_scanner(self.sampler, v, self.D)
        self.prev = v[R.S_PREV]
        R.senders_from_scanner(self.senders, S)

    def rows(self) -> SampleRows | None:
        """The samples the scanner took since the last call (None: none)."""
        from firmware_py.replay import S_ROWS

        n = int(self.S[S_ROWS])
        if not n:
            return None
        self.S[S_ROWS] = 0
        return SampleRows(self.t[:n].copy(), self.kind[:n].copy(), self.v[:n].copy())


def _scan_tlog(path: str, stats: LinkStats, on_other, ground_sysid: int, scan) -> Iterator:
    """``_samples_of`` a tlog through the C scanner (``bw_tlog_scan``): the records framed and checked as
    ``wire.tlog_messages`` does, the chosen IMU's HIGHRES_IMU and the balloon's SCALED_PRESSURE (each the
    next packet of its sender) taken into rows as ``LinkStats.sequence`` and ``MavlinkSampler.convert`` take
    them; every other frame decoded and converted here, in file order."""
    from firmware_py import replay as R

    sampler = MavlinkSampler(ground_sysid)
    dec = Decoder(stats, fast=True)
    rd = _Reader(sampler, stats)
    S, ptrs = rd.S, rd.ptrs
    fn = None
    last_t = 0
    with open(path, "rb") as fh:
        buf, i, eof = b"", 0, False
        while True:
            rd.load(i, len(buf), eof)
            if fn is None:
                from firmware_py.core_c import load

                lib = load("double")[0]
                fn = lib.bw_tlog_scan
                fn.argtypes = [C.c_char_p] + [C.c_void_p] * 13
                fn.restype = C.c_int
            r = fn(buf, *ptrs)
            rd.store()
            i = int(S[R.S_I])
            rows = rd.rows()
            if rows is not None:
                imu = np.flatnonzero(rows.kind == 0)
                if len(imu):
                    last_t = int(rows.t[imu[-1]])
                yield rows
            if r == R.R_MORE:
                if eof:
                    break
                more = fh.read(R.CHUNK)
                buf, i, eof = buf[i:] + more, 0, not more
                continue
            if r == R.R_END:
                break
            if r == R.R_FRAME:
                j, i = int(S[R.S_J]), int(S[R.S_END])
                m = dec.decode_frame(buf[j:i])
                rd.dirty = True
                if m is None:
                    continue
                stamped, last_t = _converted(m, sampler, on_other, last_t)
                rd.prev = max(rd.prev, last_t)
                yield from stamped
    if on_other is not None:
        on_other(None, sampler)


def read_mavlink(path: str, ground_sysid: int = GROUND_SYSID) -> Flight:
    """A telemetry log or raw capture, through the live firmware's converter (MavlinkSampler): the same
    messages, instances and units. UTC from SYSTEM_TIME (time_unix_usec against time_boot_ms).

    One pass over the file finds what it holds (kinds and times of the samples, 9 bytes a sample); the
    values are read again, streamed, when ``Flight.samples()`` is iterated: memory holds no flight."""
    stats = LinkStats()
    kinds = array.array("b")
    times = array.array("q")
    n_mag = 0
    found: dict = {"utc": None, "sampler": None}

    def other(m, sampler) -> None:
        if m is None:
            found["sampler"] = sampler
        elif found["utc"] is None and m.get_type() == "SYSTEM_TIME" and m.time_unix_usec > 10**15:
            found["utc"] = ((m.time_unix_usec - m.time_boot_ms * 1000) * 1e-6, "SYSTEM_TIME")

    fmt = "tlog" if path.endswith(".tlog") else "raw"
    for s in mavlink_blocks(path, stats, other, ground_sysid):
        if type(s) is SampleRows:
            kinds.frombytes(np.where(s.kind == 0, KIND_IMU, KIND_BARO).astype(np.int8).tobytes())
            times.frombytes(s.t.tobytes())
            n_mag += int(np.count_nonzero((s.kind == 0) & ~np.isnan(s.v[:, 6])))
            continue
        if type(s) is ImuSample:
            kinds.append(KIND_IMU)
            n_mag += s.mx == s.mx
        elif type(s) is WinchSample:
            kinds.append(KIND_WINCH)
        elif type(s) is GroundBaroSample:
            kinds.append(KIND_GROUND)
        else:
            kinds.append(KIND_BARO)
        times.append(s.t_us)
    if stats.frames == 0:
        raise ValueError(f"{path}: no MAVLink in this file")
    # (on the arrays' own memory: a day's log holds 86 MB of them, no copy)
    kind = np.frombuffer(kinds, np.int8) if len(kinds) else np.zeros(0, np.int8)
    t = np.frombuffer(times, np.int64) if len(times) else np.zeros(0, np.int64)
    del kinds, times
    imu = kind == KIND_IMU
    if not imu.any():
        raise ValueError(f"{path}: no IMU messages (HIGHRES_IMU, HIL_SENSOR, SCALED_IMU*) in this file")
    sampler, utc = found["sampler"], found["utc"]
    sensors: dict[str, str] = {}
    if sampler.imu_key is not None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        sensors = {"imu": mavlink.mavlink_map[sampler.imu_key[0]].msgname}
        if sampler.embedded_baro:
            sensors["baro"] = sensors["imu"]
        elif sampler.baro_key is not None:
            sensors["baro"] = mavlink.mavlink_map[sampler.baro_key[0]].msgname
    if n_mag:
        sensors["mag"] = sensors["imu"]
    notes = [f"{sampler.ignored} messages from other sensor instances ignored"] if sampler.ignored else []
    n_baro = int(np.count_nonzero(kind == KIND_BARO))
    if sampler.ground_messages:
        notes.append(f"{sampler.ground_messages} messages from the ground (WINCH_STATUS, ground reference)")
    sensor = (kind == KIND_IMU) | (kind == KIND_BARO)
    imu_t = t[imu]
    meta = FlightMeta(
        source=os.path.basename(path), sha256=sha256_of(path), format=fmt, has_imu=True, has_mag=n_mag > 0,
        has_baro=n_baro > 0, imu_rate_hz=first_rate_hz(imu_t), n_imu=int(imu.sum()), n_baro=n_baro,
        n_mag=int(n_mag), duration_s=sensor_span_s(t if sensor.all() else t[sensor]),
        utc_start_s=utc[0] if utc else None, utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
        bad_frames=stats.bad_frames, truncated=stats.truncated,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    meta.imu_missing, meta.gaps, meta.clock_breaks = imu_losses(imu_t, meta.imu_rate_hz)
    meta.notes.extend(loss_notes(meta) + [n for n in (segment_note(meta),) if n])
    return Flight(kind, t, None, meta, stream=lambda: mavlink_samples(path, ground_sysid=ground_sysid),
                  block_stream=lambda: mavlink_blocks(path, ground_sysid=ground_sysid))  # fmt: skip
