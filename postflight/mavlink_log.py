"""A telemetry log (``.tlog``) or a raw MAVLink capture into a ``Flight``."""

from __future__ import annotations

import array
import math
import os

import numpy as np

from balloon_core.samples import GROUND_SYSID, BaroSample, GroundBaroSample, ImuSample, MavlinkSampler, WinchSample
from balloon_core.wire import LinkStats, capture_messages
from postflight.flight import (
    KIND_BARO,
    KIND_GROUND,
    KIND_IMU,
    KIND_WINCH,
    N_VALUES,
    Flight,
    FlightMeta,
    first_rate_hz,
    sha256_of,
)


def read_mavlink(path: str, ground_sysid: int = GROUND_SYSID) -> Flight:
    """A telemetry log or raw capture, through the live firmware's converter (MavlinkSampler): the same
    messages, instances and units. UTC from SYSTEM_TIME (time_unix_usec against time_boot_ms). The
    winch's and the ground reference's samples keep their place in the log (their arrival); their time is
    the newest sensor sample's, as the firmware stamps them."""
    stats = LinkStats()
    sampler = MavlinkSampler(ground_sysid)
    last_t = 0
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
                    last_t = s.t_us
                elif type(s) is BaroSample:
                    kinds.append(KIND_BARO)
                    vals.extend((s.pressure_hpa, s.temperature_c) + (math.nan,) * (N_VALUES - 2))
                elif type(s) is WinchSample:
                    kinds.append(KIND_WINCH)
                    vals.extend((s.line_length_m, s.speed_mps, s.tension_n, float(s.status)) + (math.nan,) * 5)
                    times.append(last_t)
                    continue
                elif type(s) is GroundBaroSample:
                    kinds.append(KIND_GROUND)
                    vals.extend((s.pressure_hpa, s.temperature_c) + (math.nan,) * (N_VALUES - 2))
                    times.append(last_t)
                    continue
                times.append(s.t_us)
    finally:
        msgs.close()
    if stats.frames == 0:
        raise ValueError(f"{path}: no MAVLink in this file")
    kind = np.frombuffer(kinds, np.int8).copy() if len(kinds) else np.zeros(0, np.int8)
    t = np.frombuffer(times, np.int64).copy() if len(times) else np.zeros(0, np.int64)
    values = np.frombuffer(vals, np.float64).reshape(-1, N_VALUES).copy() if len(vals) else np.zeros((0, N_VALUES))
    imu = kind == KIND_IMU
    sensor = (kind == KIND_IMU) | (kind == KIND_BARO)
    if not imu.any():
        raise ValueError(f"{path}: no IMU messages (HIGHRES_IMU, HIL_SENSOR, SCALED_IMU*) in this file")
    sensors: dict[str, str] = {}
    if sampler.imu_key is not None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

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
    n_baro = int(np.count_nonzero(kind == KIND_BARO))
    if sampler.ground_messages:
        notes.append(f"{sampler.ground_messages} messages from the ground (WINCH_STATUS, ground reference)")
    meta = FlightMeta(
        source=os.path.basename(path), sha256=sha256_of(path), format=fmt, has_imu=True, has_mag=n_mag > 0,
        has_baro=n_baro > 0, imu_rate_hz=first_rate_hz(t[imu]), n_imu=int(imu.sum()), n_baro=n_baro,
        n_mag=n_mag, duration_s=float(t[sensor].max() - t[sensor].min()) * 1e-6, utc_start_s=utc[0] if utc else None,
        utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    return Flight(kind, t, values, meta)
