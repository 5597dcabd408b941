"""A telemetry log (``.tlog``) or a raw MAVLink capture into a ``Flight``."""

from __future__ import annotations

import array
import os
from collections.abc import Iterator

import numpy as np

from balloon_core.samples import (
    GROUND_SYSID,
    GroundBaroSample,
    GroundSample,
    ImuSample,
    MavlinkSampler,
    Sample,
    WinchSample,
)
from balloon_core.wire import LinkStats, capture_messages
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


def mavlink_samples(
    path: str, stats: LinkStats | None = None, on_other=None, ground_sysid: int = GROUND_SYSID
) -> Iterator[Sample | GroundSample]:
    """The sensor samples of a capture in arrival order, through the live firmware's converter
    (MavlinkSampler), streamed from the file; ``on_other(msg)`` sees every other message. The winch's and
    the ground reference's samples keep their place (their arrival); their time is the newest sensor
    sample's, as the firmware stamps them."""
    stats = stats if stats is not None else LinkStats()
    sampler = MavlinkSampler(ground_sysid)
    last_t = 0
    msgs = capture_messages(path, stats, fast=True)  # the sensor messages by fastmav: the same, faster
    try:
        for m in msgs:
            out = sampler.convert(m)
            if out is None:
                if on_other is not None:
                    on_other(m, sampler)
                continue
            for smp in out:
                if type(smp) is WinchSample or type(smp) is GroundBaroSample:
                    yield smp._replace(t_us=last_t)
                    continue
                if type(smp) is ImuSample:
                    last_t = smp.t_us
                yield smp
    finally:
        msgs.close()
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
    for s in mavlink_samples(path, stats, other, ground_sysid):
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
    kind = np.frombuffer(kinds, np.int8).copy() if len(kinds) else np.zeros(0, np.int8)
    t = np.frombuffer(times, np.int64).copy() if len(times) else np.zeros(0, np.int64)
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
        n_mag=int(n_mag), duration_s=sensor_span_s(t[sensor]),
        utc_start_s=utc[0] if utc else None, utc_source=utc[1] if utc else None, sensors=sensors, notes=notes,
        bad_frames=stats.bad_frames, truncated=stats.truncated,
    )  # fmt: skip
    if not meta.has_baro:
        meta.notes.append("no barometer in the log: height and air data unknown")
    meta.imu_missing, meta.gaps, meta.clock_breaks = imu_losses(imu_t, meta.imu_rate_hz)
    meta.notes.extend(loss_notes(meta) + [n for n in (segment_note(meta),) if n])
    return Flight(kind, t, None, meta, stream=lambda: mavlink_samples(path, ground_sysid=ground_sysid))
