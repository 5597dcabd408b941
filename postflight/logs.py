"""Flight files in, estimator samples out: the edge adapters for post-flight reprocessing.

``read_flight(path)`` reads a PX4 ULog (``.ulg``, pyulog), an ArduPilot DataFlash log (``.bin``,
pymavlink's DFReader), a telemetry log (``.tlog``) or a raw MAVLink capture (anything else), chosen by
extension and then by the file's first bytes, into a ``Flight``: the samples as numpy arrays (in time
order for logs; in arrival order for MAVLink, whose reordering and reboots the estimator handles as the
live firmware does) and what the log says about itself (``FlightMeta``). ``Flight.samples()`` iterates
them as ``balloon_core.samples`` ImuSample / BaroSample, the interface every input goes through;
``firmware_py.streams.estimator_steps`` runs them through the live firmware's input pipeline into an
Estimator. A file that cannot be read, or that holds no IMU samples, is a ValueError with one clear line.
"""

from __future__ import annotations

import array
import contextlib
import hashlib
import io
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from balloon_core.samples import BaroSample, ImuSample, MavlinkSampler, Sample
from balloon_core.wire import LinkStats, capture_messages
from firmware_py.streams import RATE_WINDOW_S, measure_rate_hz

KIND_IMU, KIND_BARO = 0, 1
N_VALUES = 9  # IMU: ax ay az gx gy gz mx my mz; barometer: hPa degC (then NaN)
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
    kind: np.ndarray  # int8, KIND_IMU / KIND_BARO
    t_us: np.ndarray  # int64, the sensor's clock (us since its boot)
    values: np.ndarray  # float64 (n, 9): IMU ax..gz, mx..mz (NaN: no new magnetometer); baro hPa, degC
    meta: FlightMeta

    def __len__(self) -> int:
        return len(self.t_us)

    def samples(self) -> Iterator[Sample]:
        """The samples in order, converted a chunk at a time (no list of the whole flight)."""
        for a in range(0, len(self.t_us), CHUNK):
            kinds = self.kind[a : a + CHUNK].tolist()
            times = self.t_us[a : a + CHUNK].tolist()
            vals = self.values[a : a + CHUNK].tolist()
            for k, t, v in zip(kinds, times, vals):
                if k == KIND_IMU:
                    yield ImuSample(t, *v)
                else:
                    yield BaroSample(t, v[0], v[1])


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
    t = np.sort(t_us[: 20_000])
    return measure_rate_hz(t[t <= t[0] + RATE_WINDOW_S * 1e6].tolist())


def _merge(imu_t: np.ndarray, imu: np.ndarray, baro_t: np.ndarray, baro: np.ndarray):
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


def _build(path: str, fmt: str, imu_t, imu, baro_t, baro, sensors, notes, utc=None) -> Flight:
    if len(imu_t) == 0:
        raise ValueError(f"{path}: no IMU samples in this {fmt} file")
    kind, t, values = _merge(np.asarray(imu_t), np.asarray(imu), np.asarray(baro_t), np.asarray(baro))
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


def _attach_mag(imu_t: np.ndarray, imu: np.ndarray, mag_t: np.ndarray, mag: np.ndarray) -> None:
    """Each magnetometer reading goes with the first IMU sample at or after its time."""
    idx = np.searchsorted(imu_t, mag_t, side="left")
    ok = idx < len(imu_t)
    imu[idx[ok], 6:9] = mag[ok]


# --------------------------------------------------------------------------------------------- ULog

ULOG_TOPICS = ["sensor_combined", "vehicle_magnetometer", "sensor_mag", "vehicle_air_data", "sensor_baro",
               "vehicle_gps_position", "sensor_gps"]  # fmt: skip


def read_ulog(path: str) -> Flight:
    """PX4 ULog: ``sensor_combined`` (accelerometer m/s^2 and gyro rad/s, FRD); the magnetometer from
    ``vehicle_magnetometer`` (gauss), else ``sensor_mag``, else the old ``sensor_combined.magnetometer_ga``;
    the barometer from ``vehicle_air_data`` (baro_pressure_pa, baro_temp_celcius), else ``sensor_baro``
    (Pa, or hPa in old logs); UTC from ``vehicle_gps_position`` / ``sensor_gps`` ``time_utc_usec``."""
    from pyulog import ULog

    try:
        with contextlib.redirect_stdout(io.StringIO()):
            u = ULog(path, ULOG_TOPICS)
    except Exception as exc:  # pyulog raises many kinds on a bad file  # noqa: BLE001
        raise ValueError(f"{path}: not a readable PX4 ULog ({exc})") from exc
    topics = {(d.name, d.multi_id): d.data for d in u.data_list}
    sensors: dict[str, str] = {}
    notes: list[str] = []
    sc = topics.get(("sensor_combined", 0))
    if sc is None or len(sc["timestamp"]) == 0:
        raise ValueError(f"{path}: no sensor_combined (accelerometer and gyro) in this ULog")
    sensors["imu"] = "sensor_combined"
    imu_t = sc["timestamp"].astype(np.int64)
    imu = np.full((len(imu_t), N_VALUES), np.nan)
    for i in range(3):
        imu[:, i] = sc[f"accelerometer_m_s2[{i}]"]
        imu[:, 3 + i] = sc[f"gyro_rad[{i}]"]
    order = np.argsort(imu_t, kind="stable")
    imu_t, imu = imu_t[order], imu[order]
    mag_t, mag = _ulog_mag(topics, sensors)
    if mag_t is not None:
        _attach_mag(imu_t, imu, mag_t, mag)
    elif "magnetometer_ga[0]" in sc:  # old PX4: the magnetometer inside sensor_combined
        rel = sc["magnetometer_timestamp_relative"][order].astype(np.int64)
        valid = rel != INT32_MAX
        tm = imu_t + rel
        new = valid & np.concatenate([[True], tm[1:] != tm[:-1]])
        for i in range(3):
            imu[new, 6 + i] = sc[f"magnetometer_ga[{i}]"][order][new]
        if new.any():
            sensors["mag"] = "sensor_combined.magnetometer_ga"
    baro_t, baro = _ulog_baro(topics, sensors, notes)
    return _build(path, "ulog", imu_t, imu, baro_t, baro, sensors, notes, _ulog_utc(topics))


def _sample_time(d) -> np.ndarray:
    return (d["timestamp_sample"] if "timestamp_sample" in d else d["timestamp"]).astype(np.int64)


def _ulog_mag(topics, sensors):
    d = topics.get(("vehicle_magnetometer", 0))
    if d is not None and len(d["timestamp"]):
        sensors["mag"] = "vehicle_magnetometer"
        return _sample_time(d), np.column_stack([d[f"magnetometer_ga[{i}]"] for i in range(3)])
    d = topics.get(("sensor_mag", 0))
    if d is not None and len(d["timestamp"]):
        sensors["mag"] = "sensor_mag"
        return _sample_time(d), np.column_stack([d["x"], d["y"], d["z"]])
    return None, None


def _ulog_baro(topics, sensors, notes):
    d = topics.get(("vehicle_air_data", 0))
    if d is not None and len(d["timestamp"]) and "baro_pressure_pa" in d:
        sensors["baro"] = "vehicle_air_data"
        return _sample_time(d), np.column_stack([d["baro_pressure_pa"] / 100.0, d["baro_temp_celcius"]])
    d = topics.get(("sensor_baro", 0))
    if d is not None and len(d["timestamp"]):
        sensors["baro"] = "sensor_baro"
        p = d["pressure"].astype(np.float64)
        if np.nanmedian(p) > 2000.0:  # Pa (PX4 >= 1.13); older logs have hPa (mbar)
            p = p / 100.0
        else:
            notes.append("sensor_baro pressure taken as hPa (an old PX4 log)")
        return _sample_time(d), np.column_stack([p, d["temperature"]])
    return np.zeros(0, np.int64), np.zeros((0, 2))


def _ulog_utc(topics) -> tuple[float, str] | None:
    for name in ("vehicle_gps_position", "sensor_gps"):
        d = topics.get((name, 0))
        if d is None or "time_utc_usec" not in d:
            continue
        utc = d["time_utc_usec"].astype(np.int64)
        ok = np.flatnonzero(utc > 1_000_000_000 * 1_000_000)  # after 2001: a real GPS time
        if len(ok):
            k = ok[0]
            return (utc[k] - int(d["timestamp"][k])) * 1e-6, "gps"
    return None


# ---------------------------------------------------------------------------------------- DataFlash

_NP_CODES = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
             "f": "<f4", "d": "<f8", "e": "<f2"}  # fmt: skip
# unit (as DFReader shows it, FMTU multiplier folded in as a prefix) -> factor to the estimator's unit
ACC_UNITS = {"": 1.0, "m/s/s": 1.0, "m/s^2": 1.0}
GYRO_UNITS = {"": 1.0, "rad/s": 1.0, "deg/s": math.pi / 180.0, "mrad/s": 1e-3}
MAG_UNITS = {"": 1e-3, "mGauss": 1e-3, "mG": 1e-3, "Gauss": 1.0, "G": 1.0}  # no FMTU: ArduPilot logs mGauss
PRESS_UNITS = {"": 0.01, "Pa": 0.01, "hPa": 1.0, "mbar": 1.0, "kPa": 10.0}
TEMP_UNITS = {"": 1.0, "degC": 1.0, "cdegC": 0.01}


def _df_records(log, name: str):
    """All records of one DataFlash message type as a numpy structured array (fields by column name,
    DFReader's own scale factors for the c/C/e/E/L types applied later), and its DFFormat."""
    tid = log.name_to_id.get(name)
    if tid is None:
        return None, None
    fmt = log.formats[tid]
    offs = np.asarray(log.offsets[tid], dtype=np.int64)
    if len(offs) == 0:
        return None, fmt
    codes = [s for s in _struct_codes(fmt.msg_struct)]
    dtype = np.dtype([(c, _np_code(code)) for c, code in zip(fmt.columns, codes)])
    size = dtype.itemsize
    if size != fmt.len - 3:
        raise ValueError(f"DataFlash {name}: format length {fmt.len} does not match its fields")
    buf = np.frombuffer(log.data_map, dtype=np.uint8)
    offs = offs[offs + fmt.len <= len(buf)]
    out = np.empty(len(offs), dtype)
    raw = out.view(np.uint8).reshape(len(offs), size)
    cols = np.arange(size)
    for a in range(0, len(offs), 32768):  # gathered in chunks: the index array stays small
        raw[a : a + 32768] = buf[(offs[a : a + 32768] + 3)[:, None] + cols]
    return out, fmt


def _struct_codes(msg_struct: str) -> list[str]:
    out, num = [], ""
    for ch in msg_struct.lstrip("<"):
        if ch.isdigit():
            num += ch
        else:
            out.append(num + ch)
            num = ""
    return out


def _np_code(code: str) -> str:
    if code.endswith("s"):
        return f"S{code[:-1] or 1}"
    return _NP_CODES[code]


def _df_column(recs, fmt, col: str, units: dict[str, float], what: str) -> np.ndarray:
    i = fmt.colhash[col]
    v = recs[col].astype(np.float64)
    if fmt.msg_mults[i] is not None:  # c/C/e/E/L: DFReader's scaling of the stored integer
        v *= fmt.msg_mults[i]
    unit = fmt.get_unit(col)
    if unit not in units:
        raise ValueError(f"DataFlash {what}.{col} is in {unit!r}, not a unit this reader knows")
    return v * units[unit]


def _df_instance(recs, fmt):
    """The first instance logged (field ``I``), as a mask over the records."""
    if "I" not in fmt.colhash or len(recs) == 0:
        return np.ones(len(recs), bool)
    return recs["I"] == recs["I"][0]


def read_dataflash(path: str) -> Flight:
    """ArduPilot DataFlash: IMU (AccX.. m/s^2, GyrX.. rad/s, TimeUS), MAG (MagX.. milligauss), BARO
    (Press Pa, Temp degC), each the first instance logged; units checked against the FMTU/UNIT/MULT
    messages when the log has them; UTC from GPS (GWk, GMS). DFReader's own complaints about a
    damaged log (a line per bad byte) are silenced: the verdict is this function's one ValueError."""
    with _silenced():
        return _read_dataflash(path)


@contextlib.contextmanager
def _silenced():
    """Standard output and error closed to everything, Python and C alike, for the duration."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        with open(os.devnull, "w") as sink, contextlib.redirect_stderr(sink), contextlib.redirect_stdout(sink):
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _read_dataflash(path: str) -> Flight:
    from pymavlink import DFReader

    try:
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            log = DFReader.DFReader_binary(path, zero_time_base=True)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{path}: not a readable ArduPilot DataFlash log ({exc})") from exc
    sensors: dict[str, str] = {}
    notes: list[str] = []
    try:
        imu_r, imu_f = _df_records(log, "IMU")
        if imu_r is None or len(imu_r) == 0:
            raise ValueError(f"{path}: no IMU records in this DataFlash log")
        imu_r = imu_r[_df_instance(imu_r, imu_f)]
        sensors["imu"] = "IMU"
        imu_t = imu_r["TimeUS"].astype(np.int64)
        imu = np.full((len(imu_t), N_VALUES), np.nan)
        for i, a in enumerate("XYZ"):
            imu[:, i] = _df_column(imu_r, imu_f, f"Acc{a}", ACC_UNITS, "IMU")
            imu[:, 3 + i] = _df_column(imu_r, imu_f, f"Gyr{a}", GYRO_UNITS, "IMU")
        order = np.argsort(imu_t, kind="stable")
        imu_t, imu = imu_t[order], imu[order]
        mag_r, mag_f = _df_records(log, "MAG")
        if mag_r is not None and len(mag_r):
            mag_r = mag_r[_df_instance(mag_r, mag_f)]
            mag = np.column_stack([_df_column(mag_r, mag_f, f"Mag{a}", MAG_UNITS, "MAG") for a in "XYZ"])
            _attach_mag(imu_t, imu, mag_r["TimeUS"].astype(np.int64), mag)
            sensors["mag"] = "MAG"
        baro_r, baro_f = _df_records(log, "BARO")
        if baro_r is not None and len(baro_r):
            baro_r = baro_r[_df_instance(baro_r, baro_f)]
            baro_t = baro_r["TimeUS"].astype(np.int64)
            baro = np.column_stack([_df_column(baro_r, baro_f, "Press", PRESS_UNITS, "BARO"),
                                    _df_column(baro_r, baro_f, "Temp", TEMP_UNITS, "BARO")])  # fmt: skip
            sensors["baro"] = "BARO"
        else:
            baro_t, baro = np.zeros(0, np.int64), np.zeros((0, 2))
        utc = _df_utc(log)
    except (KeyError, ValueError) as exc:
        raise ValueError(str(exc) if str(exc).startswith(path) else f"{path}: {exc}") from exc
    finally:
        log.close()
    return _build(path, "dataflash", imu_t, imu, baro_t, baro, sensors, notes, utc)


def _df_utc(log) -> tuple[float, str] | None:
    recs, fmt = _df_records(log, "GPS")
    if recs is None or not {"GWk", "GMS", "TimeUS"} <= set(fmt.colhash):
        return None
    ok = np.flatnonzero(recs["GWk"] > 0)
    if len(ok) == 0:
        return None
    r = recs[ok[0]]
    gps_s = GPS_EPOCH_UNIX_S + int(r["GWk"]) * 604_800 + int(r["GMS"]) * 1e-3 - GPS_LEAP_S
    return gps_s - int(r["TimeUS"]) * 1e-6, "gps"


# ------------------------------------------------------------------------------------ tlog / raw MAVLink


def read_mavlink(path: str) -> Flight:
    """A telemetry log or raw capture, through the live firmware's converter (MavlinkSampler): the same
    messages, instances and units. UTC from SYSTEM_TIME (time_unix_usec against time_boot_ms)."""
    stats = LinkStats()
    sampler = MavlinkSampler()
    kinds = array.array("b")
    times = array.array("q")
    vals = array.array("d")
    utc = None
    fmt = "tlog" if path.endswith(".tlog") else "raw"
    msgs = capture_messages(path, stats)
    try:
        for m in msgs:
            out = sampler.convert(m)
            if out is None:
                if utc is None and m.get_type() == "SYSTEM_TIME" and m.time_unix_usec > 10**15:
                    utc = ((m.time_unix_usec - m.time_boot_ms * 1000) * 1e-6, "SYSTEM_TIME")
                continue
            for s in out:
                if type(s) is ImuSample:
                    kinds.append(KIND_IMU)
                    vals.extend(s[1:])
                else:
                    kinds.append(KIND_BARO)
                    vals.extend((s.pressure_hpa, s.temperature_c) + (math.nan,) * (N_VALUES - 2))
                times.append(s.t_us)
    finally:
        msgs.close()
    if stats.frames == 0:
        raise ValueError(f"{path}: no MAVLink in this file")
    kind = np.frombuffer(kinds, np.int8).copy() if len(kinds) else np.zeros(0, np.int8)
    t = np.frombuffer(times, np.int64).copy() if len(times) else np.zeros(0, np.int64)
    values = np.frombuffer(vals, np.float64).reshape(-1, N_VALUES).copy() if len(vals) else np.zeros((0, N_VALUES))
    imu = kind == KIND_IMU
    if not imu.any():
        raise ValueError(f"{path}: no IMU messages (HIGHRES_IMU, HIL_SENSOR, SCALED_IMU*) in this file")
    sensors: dict[str, str] = {}
    if sampler.imu_key is not None:
        from pymavlink.dialects.v20 import common as mavlink

        sensors = {"imu": mavlink.mavlink_map[sampler.imu_key[0]].msgname}
        if sampler.embedded_baro:
            sensors["baro"] = sensors["imu"]
        elif sampler.baro_key is not None:
            sensors["baro"] = mavlink.mavlink_map[sampler.baro_key[0]].msgname
    n_mag = int(np.count_nonzero(np.isfinite(values[imu, 6])))
    if n_mag:
        sensors["mag"] = sensors["imu"]
    notes = [f"{sampler.ignored} messages from other sensor instances ignored"] if sampler.ignored else []
    if stats.bad_frames:
        notes.append(f"{stats.bad_frames} bad frames skipped")
    n_baro = int(np.count_nonzero(~imu))
    meta = FlightMeta(
        source=os.path.basename(path), sha256=sha256_of(path), format=fmt, has_imu=True, has_mag=n_mag > 0,
        has_baro=n_baro > 0, imu_rate_hz=first_rate_hz(t[imu]), n_imu=int(imu.sum()), n_baro=n_baro,
        n_mag=n_mag, duration_s=float(t.max() - t.min()) * 1e-6, utc_start_s=utc[0] if utc else None,
        utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    return Flight(kind, t, values, meta)


# ------------------------------------------------------------------------------------------ one door


def flight_format(path: str) -> str:
    """"ulog", "dataflash", "tlog" or "raw": by extension, else by the first bytes."""
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ulg":
        return "ulog"
    if ext == ".tlog":
        return "tlog"
    with open(path, "rb") as fh:
        head = fh.read(8)
    if ext == ".bin":  # DataFlash's name, but also a common one for a raw serial capture: the bytes decide
        return "dataflash" if head.startswith(DATAFLASH_MAGIC) else "raw"
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    return "raw"


def read_flight(path: str) -> Flight:
    """Any flight file -> Flight. ValueError (one line, for exit 2) if it is missing, empty, unreadable
    or holds no IMU samples."""
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise ValueError(f"{path}: empty file")
    kind = flight_format(path)
    if kind == "ulog":
        return read_ulog(path)
    if kind == "dataflash":
        return read_dataflash(path)
    return read_mavlink(path)


# ------------------------------------------------------------------------------------------ a look


def main(argv: list[str] | None = None) -> int:
    """``python -m postflight.logs FILE [--estimate]``: what a flight file holds and, with
    --estimate, what the estimator makes of it (ten lines over the flight, then its counters)."""
    import argparse
    import sys

    from balloon_core.config import Design
    from firmware_py.estimator.state import FilterConfig
    from firmware_py.streams import estimator_steps

    ap = argparse.ArgumentParser(prog="python -m postflight.logs", description=main.__doc__)
    ap.add_argument("file")
    ap.add_argument("--estimate", action="store_true", help="run the estimator over it")
    args = ap.parse_args(argv)
    try:
        flight = read_flight(args.file)
    except (ValueError, OSError) as exc:
        print(f"flightlog: {exc}", file=sys.stderr)
        return 2
    m = flight.meta
    print(m.describe())
    print(f"sensors {m.sensors}, utc_start_s {m.utc_start_s} ({m.utc_source}), sha256 {m.sha256}")
    for note in m.notes:
        print(f"note: {note}")
    if not args.estimate:
        return 0
    rows, est = [], None
    for est, s, advanced in estimator_steps(Design(), FilterConfig(), flight.samples(), warn=print):
        if advanced:
            wn, we = est.wind()
            rows.append((s.t_us * 1e-6, wn, we, est.wind_accuracy(), est.ekf.mode, est.height_m()))
    r = np.array(rows)
    print(f"filter at {est.cfg.imu_rate_hz:g} Hz, {len(r)} steps, all finite: {bool(np.all(np.isfinite(r)))}")
    for k in np.linspace(0, len(r) - 1, 10).astype(int):
        t, wn, we, acc, mode, h = r[k]
        print(f"t {t - r[0, 0]:7.1f} s  wind N {wn:6.2f} E {we:6.2f} |{math.hypot(wn, we):5.2f}| m/s  "
              f"accuracy {acc:5.2f} m/s  mode {int(mode)}  height {h:6.1f} m")  # fmt: skip
    print("counters", {k: v for k, v in est.counters.as_dict().items() if v})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
