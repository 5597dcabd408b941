"""PX4 ULog (``.ulg``, pyulog) into a ``Flight``."""

from __future__ import annotations

import contextlib
import io

import numpy as np

from postflight import flight as flight_module
from postflight.flight import (
    INT32_MAX,
    N_VALUES,
    Flight,
    WatchedFile,
    attach_mag,
    build_flight,
    describe_error,
)

ULOG_TOPICS = ["sensor_combined", "vehicle_magnetometer", "sensor_mag", "vehicle_air_data", "sensor_baro",
               "vehicle_gps_position", "sensor_gps"]  # fmt: skip


def read_ulog(path: str, stall_s: float | None = None) -> Flight:
    """PX4 ULog: ``sensor_combined`` (accelerometer m/s^2 and gyro rad/s, FRD); the magnetometer from
    ``vehicle_magnetometer`` (gauss), else ``sensor_mag``, else the old ``sensor_combined.magnetometer_ga``;
    the barometer from ``vehicle_air_data`` (baro_pressure_pa, baro_temp_celcius), else ``sensor_baro``
    (Pa, or hPa in old logs); UTC from ``vehicle_gps_position`` / ``sensor_gps`` ``time_utc_usec``.

    pyulog reads through a ``WatchedFile``: on some damaged files pyulog 1.3.0 seeks back to where it was,
    forever (docs/decisions.md); after ``stall_s`` without progress the file reads as ended, and what was
    read before is used, with a note (nothing usable: the ValueError says why)."""
    from pyulog import ULog

    fh = WatchedFile(path, flight_module.STALL_S if stall_s is None else stall_s)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            u = ULog(fh, ULOG_TOPICS)
    except Exception as exc:  # pyulog raises many kinds on a bad file  # noqa: BLE001
        raise ValueError(f"{path}: not a readable PX4 ULog: {describe_error(exc)}") from exc
    finally:
        fh.close()
    stalled = fh.note()
    topics = {(d.name, d.multi_id): d.data for d in u.data_list}
    sensors: dict[str, str] = {}
    notes: list[str] = [stalled] if stalled else []
    sc = topics.get(("sensor_combined", 0))
    if sc is None or len(sc["timestamp"]) == 0:
        why = f"; {stalled}" if stalled else ""
        raise ValueError(f"{path}: no sensor_combined (accelerometer and gyro) in this ULog{why}")
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
        attach_mag(imu_t, imu, mag_t, mag)
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
    # pyulog flags a damaged stretch (an unknown message type, a message that does not parse) without counting:
    # at least one bad message, skipped; then it searches for the next sync marker, to the file's end if none
    bad = 1 if getattr(u, "file_corruption", False) else 0
    unread = None
    if bad and getattr(u, "_has_sync", True) is False:
        unread = "pyulog found a damaged stretch and no sync marker after it: the rest of the file is unread"
    elif bad:
        notes.append("pyulog found a damaged stretch in the file (a message it could not parse) and skipped it")
    cut = stalled is None and unread is None and fh.ended_inside()  # the file ends inside a message
    flight = build_flight(path, "ulog", imu_t, imu, baro_t, baro, sensors, notes, _ulog_utc(topics), bad_frames=bad,
                          truncated=cut, unread=unread)  # fmt: skip
    flight.meta.truncated = flight.meta.truncated or stalled is not None
    return flight


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
