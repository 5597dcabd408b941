"""A flight read from a log: the samples as arrays and what the log says about itself (``FlightMeta``),
and the helpers every log reader shares (postflight/ulog.py, dataflash.py, mavlink_log.py)."""

from __future__ import annotations

import errno
import hashlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from balloon_core.samples import BaroSample, GroundBaroSample, GroundSample, ImuSample, Sample, WinchSample
from firmware_py.streams import RATE_WINDOW_S, measure_rate_hz

KIND_IMU, KIND_BARO, KIND_WINCH, KIND_GROUND = 0, 1, 2, 3
# IMU: ax ay az gx gy gz mx my mz; barometer: hPa degC (then NaN); winch: length m, speed m/s, tension N,
# status; ground reference: hPa degC
N_VALUES = 9
ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_MAGIC = b"\xa3\x95\x80"  # the first record of a DataFlash log: FMT describing FMT
INT32_MAX = 2**31 - 1  # PX4's "no sample" relative timestamp
GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00Z
GPS_LEAP_S = 18  # GPS - UTC since 2017
CHUNK = 4096
STALL_S = 10.0  # a log reader that makes no progress in the file for this long is stopped (WatchedFile)
CLOCK_BACK_US = 1_000_000  # the sensor clock going back by more than this: a reboot (less: reordering)
CLOCK_JUMP_US = 60_000_000  # ... forward by more than this: a damaged stretch or a clock that jumped


@dataclass
class FlightMeta:
    source: str  # the file's name
    sha256: str  # of the file's bytes
    format: str  # "ulog", "dataflash", "tlog", "raw"
    has_imu: bool
    has_mag: bool
    has_baro: bool  # False: the height and the air data are unknown (never 0 m)
    imu_rate_hz: float | None  # measured: median sample interval over the first 2 s
    n_imu: int
    n_baro: int
    n_mag: int
    duration_s: float  # first to last sample on the sensor clock
    utc_start_s: float | None = None  # UNIX time of the sensor clock's zero (t_us == 0), if the log knows it
    utc_source: str | None = None  # where that came from ("gps", "SYSTEM_TIME")
    sensors: dict[str, str] = field(default_factory=dict)  # role -> message/topic it was read from
    notes: list[str] = field(default_factory=list)
    # what the file lost, each counted once (docs/usage.md, "What a damaged log loses")
    bad_frames: int = 0  # corrupt MAVLink frames skipped (a cut-off last frame included)
    truncated: bool = False  # the file ends inside a frame / record, or the reader stopped before its end
    imu_missing: int = 0  # IMU samples missing by their time stamps (at the measured rate)
    gaps: int = 0  # holes in the IMU stream (two or more steps without a sample)
    clock_breaks: int = 0  # the sensor clock going back (a reboot) or jumping: where a new segment starts
    # samples the estimator rejected (IMU or barometer values not numbers or out of range, IMU samples before its
    # first magnetometer reading: its one counter), once reprocessed
    samples_rejected: int = 0
    unread: str | None = None  # why and where a reader stopped before the file's end (the rest unread), if it did

    def describe(self) -> str:
        rate = f"{self.imu_rate_hz:.1f} Hz" if self.imu_rate_hz else "unknown rate"
        baro = f"{self.n_baro} barometer samples" if self.has_baro else "NO barometer (height unknown)"
        mag = f"{self.n_mag} magnetometer samples" if self.has_mag else "NO magnetometer"
        head = f"{self.source} ({self.format}): {self.n_imu} IMU samples at {rate}"
        return f"{head}, {mag}, {baro}, {self.duration_s:.1f} s"


@dataclass
class Flight:
    kind: np.ndarray  # int8, KIND_IMU / KIND_BARO / KIND_WINCH / KIND_GROUND
    t_us: np.ndarray  # int64, the sensor's clock (us since its boot)
    values: np.ndarray | None  # float64 (n, 9): IMU ax..gz, mx..mz (NaN: no new magnetometer); baro hPa, degC
    meta: FlightMeta
    # the samples read again from the file (a MAVLink log: its values are not held in memory); None: ``values``
    stream: Callable[[], Iterator[Sample]] | None = None
    # the same with runs of sensor samples as arrays (mavlink_log.SampleRows: a tlog through the C scanner)
    block_stream: Callable[[], Iterator] | None = None

    def __len__(self) -> int:
        return len(self.t_us) if self.t_us is not None else self._released

    def release(self) -> None:
        """Forget the kinds and times of a flight whose samples are read again from the file (``stream``): a
        day's log holds 86 MB of them, which reprocessing does not need once ``meta`` says what they told.
        ``len()`` stays; ``with_ground`` no longer works."""
        if self.stream is not None and self.t_us is not None:
            self._released = len(self.t_us)
            self.kind = self.t_us = None  # type: ignore[assignment]

    def samples(self) -> Iterator[Sample | GroundSample]:
        """The samples in order, converted a chunk at a time (no list of the whole flight)."""
        if self.stream is not None:
            yield from self.stream()
            return
        for a in range(0, len(self.t_us), CHUNK):
            kinds = self.kind[a : a + CHUNK].tolist()
            times = self.t_us[a : a + CHUNK].tolist()
            vals = self.values[a : a + CHUNK].tolist()
            for k, t, v in zip(kinds, times, vals):
                if k == KIND_IMU:
                    yield ImuSample(t, *v)
                elif k == KIND_BARO:
                    yield BaroSample(t, v[0], v[1])
                elif k == KIND_WINCH:
                    yield WinchSample(t, v[0], v[1], v[2], int(v[3]))
                else:
                    yield GroundBaroSample(t, v[0], v[1])

    def blocks(self) -> Iterator:
        """``samples()``, with runs of sensor samples as ``mavlink_log.SampleRows`` where the reader has them."""
        if self.block_stream is not None:
            yield from self.block_stream()
        else:
            yield from self.samples()

    @property
    def has_winch(self) -> bool:
        return bool(np.any(self.kind == KIND_WINCH))

    def with_ground(self, t_us: np.ndarray, hpa: np.ndarray, temp_c: np.ndarray) -> Flight:
        """This flight with a ground reference (e.g. ``--ground-pressure`` CSV) merged in by time (after
        the flight's own samples of the same time); the flight's own ground reference is dropped."""
        own = self.kind != KIND_GROUND
        n = len(t_us)
        gt = np.asarray(t_us, np.int64)
        kind = np.concatenate([self.kind[own], np.full(n, KIND_GROUND, np.int8)])
        t = np.concatenate([self.t_us[own], gt])
        order = np.argsort(t, kind="stable")
        if self.stream is None:
            vals = np.full((n, N_VALUES), np.nan)
            vals[:, 0], vals[:, 1] = hpa, temp_c
            values = np.concatenate([self.values[own], vals])
            return Flight(kind[order], t[order], values[order], self.meta)
        src, gs = self.stream, sorted(zip(gt.tolist(), np.asarray(hpa, float).tolist(),
                                         np.asarray(temp_c, float).tolist()))  # fmt: skip

        def merged() -> Iterator[Sample | GroundSample]:
            k = 0
            for smp in src():
                if type(smp) is GroundBaroSample:
                    continue  # the flight's own reference is replaced
                while k < len(gs) and gs[k][0] < smp.t_us:
                    yield GroundBaroSample(*gs[k])
                    k += 1
                yield smp
            for g in gs[k:]:
                yield GroundBaroSample(*g)

        return Flight(kind[order], t[order], None, self.meta, stream=merged)


    def with_ground_rows(self, rows: Callable[[], Iterator[tuple[int, float, float]]]) -> Flight:
        """As ``with_ground``, the reference given as ``rows()``: a fresh iterator of (time us, hPa,
        degC) each call, in the order the logger wrote them. A streamed flight merges them as it is read
        (memory flat in the reference's length: nothing of it is held); a flight in arrays takes them in."""
        if self.stream is None:
            got = list(rows())
            cols = [np.array(c) for c in zip(*got)] if got else [np.zeros(0, np.int64), np.zeros(0), np.zeros(0)]
            return self.with_ground(*cols)
        own = self.kind != KIND_GROUND
        src = self.stream

        def merged() -> Iterator[Sample | GroundSample]:
            it = rows()
            nxt = next(it, None)
            for smp in src():
                if type(smp) is GroundBaroSample:
                    continue  # the flight's own reference is replaced
                while nxt is not None and nxt[0] < smp.t_us:
                    yield GroundBaroSample(*nxt)
                    nxt = next(it, None)
                yield smp
            while nxt is not None:
                yield GroundBaroSample(*nxt)
                nxt = next(it, None)

        return Flight(self.kind[own], self.t_us[own], None, self.meta, stream=merged)


# ------------------------------------------------------------------------------------------ helpers


class ReaderStalled(Exception):
    """A log reader made no progress in its file for ``STALL_S`` (a loop in a third-party parser)."""


class WatchedFile:
    """A binary file for a third-party reader (pyulog) with a watchdog: when the furthest position
    read has not advanced for ``stall_s`` seconds, the file reads as ended from then on, so a reader
    that loops (seeks back to where it was, again and again) stops with what it has read."""

    def __init__(self, path: str, stall_s: float = STALL_S) -> None:
        self.fh = open(path, "rb")
        self.size = os.fstat(self.fh.fileno()).st_size
        self.stall_s = stall_s
        self.furthest = 0
        self.stalled_at: int | None = None  # where the reader kept going back to when the watchdog ended the read
        self.last_read = (0, 0)  # (bytes asked, bytes got) of the last read
        self._low = 0  # the lowest position read from since the furthest last advanced
        self._moved = time.monotonic()

    def read(self, n: int = -1) -> bytes:
        if self.stalled_at is not None:
            return b""
        start = self.fh.tell()
        data = self.fh.read(n)
        pos = self.fh.tell()
        now = time.monotonic()
        if pos > self.furthest:
            self.furthest, self._moved, self._low = pos, now, pos
        else:
            self._low = min(self._low, start)
            if now - self._moved > self.stall_s:
                self.stalled_at = self._low
                return b""
        self.last_read = (n, len(data))
        return data

    def ended_inside(self) -> bool:
        """Whether the reader's last read ran into the file's end inside a message: it got part of what it asked
        for, or nothing of a message body (pyulog reads a 3-byte header, then the body; a whole file ends with a
        header read that gets nothing)."""
        asked, got = self.last_read
        return got < asked and (got > 0 or asked != 3)

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.fh.seek(offset, whence)

    def tell(self) -> int:
        return self.fh.tell()

    def close(self) -> None:
        self.fh.close()

    def note(self) -> str | None:
        """The note for the flight's metadata when the watchdog ended the read, else None."""
        if self.stalled_at is None:
            return None
        return (
            f"the reader made no progress in the file for {self.stall_s:g} s (it kept going back to byte "
            f"{self.stalled_at} of {self.size}: a damaged stretch it loops on); the read stopped there"
        )


def describe_error(exc: BaseException) -> str:
    """What a reader's exception means, in words (a bare ``'AccY'`` or ``[Errno 22]`` says nothing)."""
    if isinstance(exc, KeyError):
        return f"a field the reader needs, {exc.args[0]!r}, is missing (a damaged or unexpected log format)"
    if isinstance(exc, OSError) and exc.errno == errno.EINVAL:
        return "a length or position inside the file points outside it (the file is damaged)"
    if isinstance(exc, OSError):
        return f"{exc.strerror or exc} (reading the file)"
    if isinstance(exc, (OverflowError, MemoryError)) or "out of range" in str(exc):
        return f"a value in the file is impossible ({exc}): the file is damaged"
    text = str(exc).strip()
    return f"{text} ({type(exc).__name__})" if text else f"the file is damaged ({type(exc).__name__})"


def sensor_span_s(t_us: np.ndarray) -> float:
    """The time a log's samples span on the sensor clock, s: each segment's first to last sample, summed (the
    clock going back or jumping ahead starts a segment, as ``imu_losses`` cuts them): two flights in one
    file are both counted, not the longer one's span."""
    t = np.asarray(t_us, np.int64)
    if len(t) < 2:
        return 0.0
    brk = _clock_breaks(t)
    return float(sum(int(p.max()) - int(p.min()) for p in np.split(t, brk) if len(p))) * 1e-6


_PIECE = 1 << 20  # the long arrays of a day's log are worked through this many at a time (memory)


def _clock_breaks(t: np.ndarray) -> np.ndarray:
    """Where the clock goes back by more than ``CLOCK_BACK_US`` or jumps ahead by more than ``CLOCK_JUMP_US``
    (the indices of the first sample after each), a piece at a time."""
    out = []
    for a in range(0, len(t) - 1, _PIECE):
        d = np.diff(t[a : a + _PIECE + 1])
        out.append(np.flatnonzero((d < -CLOCK_BACK_US) | (d > CLOCK_JUMP_US)) + 1 + a)
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def imu_losses(imu_t: np.ndarray, rate_hz: float | None) -> tuple[int, int, int]:
    """(IMU samples missing, gaps, clock breaks) from the IMU sample times in file order: at the
    measured rate, a hole of k steps is k - 1 missing samples (a late sample fills its hole, a copy
    counts nothing); the clock going back by more than ``CLOCK_BACK_US`` or forward by more than
    ``CLOCK_JUMP_US`` is a break (the holes are counted within the stretches between breaks)."""
    t = np.asarray(imu_t, np.int64)
    if len(t) < 2 or not rate_hz:
        return 0, 0, 0
    brk = _clock_breaks(t)
    dt = 1e6 / rate_hz
    missing = gaps = 0
    for part in np.split(t, brk):
        ordered = all(bool(np.all(np.diff(part[a : a + _PIECE + 1]) > 0)) for a in range(0, len(part), _PIECE))
        u = part if ordered else np.unique(part)  # in time order, copies once: a late sample sits in its place
        for a in range(0, max(len(u) - 1, 0), _PIECE):
            steps = np.rint(np.diff(u[a : a + _PIECE + 1]) / dt).astype(np.int64)
            holes = steps[steps >= 2]
            missing += int(np.sum(holes - 1))
            gaps += len(holes)
    return missing, gaps, len(brk)


def loss_notes(meta: FlightMeta) -> list[str]:
    """One note per kind of loss the flight file holds (none for a clean file)."""
    out = []
    if meta.bad_frames:
        cut = ", the last one cut off: the file ends inside a frame" if meta.truncated and not meta.unread else ""
        out.append(f"{meta.bad_frames} bad frames skipped{cut}")
    elif meta.truncated and not meta.unread:
        out.append("the file ends inside a record (truncated)")
    if meta.unread:
        out.append(meta.unread)
    if meta.imu_missing:
        out.append(f"{meta.imu_missing} IMU samples missing by their time stamps, in {meta.gaps} gaps")
    return out


def rejected_note(meta: FlightMeta) -> str | None:
    """What the estimator rejected of the flight's samples (``FlightMeta.samples_rejected``), None if none: a note, not
    a loss (its count cannot tell a damaged value from a sample before the first magnetometer reading)."""
    if not meta.samples_rejected:
        return None
    return (f"{meta.samples_rejected} samples rejected by the estimator (values not numbers or out of range, or before "
            "its first magnetometer reading)")  # fmt: skip


def segment_note(meta: FlightMeta) -> str | None:
    """Where the log is cut into segments (the sensor clock went back or jumped), None if nowhere."""
    if not meta.clock_breaks:
        return None
    times = "once" if meta.clock_breaks == 1 else f"{meta.clock_breaks} times"
    return (
        f"the sensor clock goes back (a reboot) or jumps {times}: reprocessed in {meta.clock_breaks + 1} "
        "segments, each its own filter and smoother run"
    )


def sha256_of(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def first_rate_hz(t_us: np.ndarray) -> float | None:
    """The IMU rate as the firmware measures it: median interval over the first 2 s of samples."""
    if len(t_us) < 2:
        return None
    t = np.sort(t_us[:20_000])
    return measure_rate_hz(t[t <= t[0] + RATE_WINDOW_S * 1e6].tolist())


def merge_streams(imu_t: np.ndarray, imu: np.ndarray, baro_t: np.ndarray, baro: np.ndarray):
    """IMU and barometer samples in one time-ordered sequence (a barometer sample before an IMU sample
    of the same time, as HIGHRES_IMU carries them)."""
    n, m = len(imu_t), len(baro_t)
    kind = np.concatenate([np.full(n, KIND_IMU, np.int8), np.full(m, KIND_BARO, np.int8)])
    t = np.concatenate([imu_t.astype(np.int64), baro_t.astype(np.int64)])
    order = np.lexsort((kind == KIND_IMU, t))
    where = np.empty(n + m, np.int64)
    where[order] = np.arange(n + m)  # the row each input sample goes to
    values = np.full((n + m, N_VALUES), np.nan)
    values[where[:n]] = imu
    values[where[n:], :2] = baro
    return kind[order], t[order], values


def build_flight(path: str, fmt: str, imu_t, imu, baro_t, baro, sensors, notes, utc=None, bad_frames: int = 0,
                 truncated: bool = False, unread: str | None = None) -> Flight:
    """``bad_frames``, ``truncated``, ``unread``: what the reader lost of the file (``FlightMeta``)."""
    if len(imu_t) == 0:
        raise ValueError(f"{path}: no IMU samples in this {fmt} file")
    kind, t, values = merge_streams(np.asarray(imu_t), np.asarray(imu), np.asarray(baro_t), np.asarray(baro))
    n_mag = int(np.count_nonzero(np.isfinite(imu[:, 6])))
    meta = FlightMeta(
        source=os.path.basename(path), sha256=sha256_of(path), format=fmt, has_imu=True, has_mag=n_mag > 0,
        has_baro=len(baro_t) > 0, imu_rate_hz=first_rate_hz(np.asarray(imu_t)), n_imu=len(imu_t),
        n_baro=len(baro_t), n_mag=n_mag, duration_s=sensor_span_s(t),
        utc_start_s=utc[0] if utc else None, utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
        bad_frames=bad_frames, truncated=truncated or unread is not None, unread=unread,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    meta.imu_missing, meta.gaps, meta.clock_breaks = imu_losses(np.asarray(imu_t), meta.imu_rate_hz)
    meta.notes.extend(loss_notes(meta) + [n for n in (segment_note(meta),) if n])
    return Flight(kind, t, values, meta)


def attach_mag(imu_t: np.ndarray, imu: np.ndarray, mag_t: np.ndarray, mag: np.ndarray) -> None:
    """Each magnetometer reading goes with the first IMU sample at or after its time."""
    idx = np.searchsorted(imu_t, mag_t, side="left")
    ok = idx < len(imu_t)
    imu[idx[ok], 6:9] = mag[ok]
