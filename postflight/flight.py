"""A flight read from a log: the samples as arrays and what the log says about itself (``FlightMeta``),
and the helpers every log reader shares (postflight/ulog.py, dataflash.py, mavlink_log.py)."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
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
    values: np.ndarray  # float64 (n, 9): IMU ax..gz, mx..mz (NaN: no new magnetometer); baro hPa, degC
    meta: FlightMeta

    def __len__(self) -> int:
        return len(self.t_us)

    def samples(self) -> Iterator[Sample | GroundSample]:
        """The samples in order, converted a chunk at a time (no list of the whole flight)."""
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

    @property
    def has_winch(self) -> bool:
        return bool(np.any(self.kind == KIND_WINCH))

    def with_ground(self, t_us: np.ndarray, hpa: np.ndarray, temp_c: np.ndarray) -> Flight:
        """This flight with a ground reference (e.g. ``--ground-pressure`` CSV) merged in by time (after
        the flight's own samples of the same time); the flight's own ground reference is dropped."""
        own = self.kind != KIND_GROUND
        n = len(t_us)
        kind = np.concatenate([self.kind[own], np.full(n, KIND_GROUND, np.int8)])
        t = np.concatenate([self.t_us[own], np.asarray(t_us, np.int64)])
        vals = np.full((n, N_VALUES), np.nan)
        vals[:, 0], vals[:, 1] = hpa, temp_c
        values = np.concatenate([self.values[own], vals])
        order = np.argsort(t, kind="stable")
        return Flight(kind[order], t[order], values[order], self.meta)


# ------------------------------------------------------------------------------------------ helpers


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


def build_flight(path: str, fmt: str, imu_t, imu, baro_t, baro, sensors, notes, utc=None) -> Flight:
    if len(imu_t) == 0:
        raise ValueError(f"{path}: no IMU samples in this {fmt} file")
    kind, t, values = merge_streams(np.asarray(imu_t), np.asarray(imu), np.asarray(baro_t), np.asarray(baro))
    n_mag = int(np.count_nonzero(np.isfinite(imu[:, 6])))
    meta = FlightMeta(
        source=os.path.basename(path), sha256=sha256_of(path), format=fmt, has_imu=True, has_mag=n_mag > 0,
        has_baro=len(baro_t) > 0, imu_rate_hz=first_rate_hz(np.asarray(imu_t)), n_imu=len(imu_t),
        n_baro=len(baro_t), n_mag=n_mag, duration_s=float(t.max() - t.min()) * 1e-6,
        utc_start_s=utc[0] if utc else None, utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    return Flight(kind, t, values, meta)


def attach_mag(imu_t: np.ndarray, imu: np.ndarray, mag_t: np.ndarray, mag: np.ndarray) -> None:
    """Each magnetometer reading goes with the first IMU sample at or after its time."""
    idx = np.searchsorted(imu_t, mag_t, side="left")
    ok = idx < len(imu_t)
    imu[idx[ok], 6:9] = mag[ok]
