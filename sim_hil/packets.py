"""MAVLink 2 sensor packets (pymavlink) and the thin file/UDP writers at the program's edge."""

from __future__ import annotations

import struct
from typing import BinaryIO

from pymavlink.dialects.v20 import common as mavlink

from firmware_py.mavio import pack
from sim_hil.simulator import SensorSample

SIM_SYSID = 1
SIM_COMPID = mavlink.MAV_COMP_ID_IMU
TLOG_EPOCH_US = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z: tlog timestamps = epoch + simulated time
HIGHRES_ACC_GYRO_MAG = 0x1FF
HIGHRES_ABS_PRESSURE = 0x200
HIGHRES_TEMPERATURE = 0x1000


class SensorPacketEncoder:
    """Encodes simulator samples as HIGHRES_IMU (every sample), SCALED_PRESSURE (new baro samples) and
    HEARTBEAT (1 Hz, MAV_TYPE_FREE_BALLOON) frames."""

    def __init__(self, sysid: int = SIM_SYSID, compid: int = SIM_COMPID) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._last_baro = (1013.25, 20.0)
        self._next_heartbeat_us = 0

    def encode(self, s: SensorSample) -> list[bytes]:
        mav = self.mav
        out = []
        if s.time_usec >= self._next_heartbeat_us:
            out.append(pack(mav, mav.heartbeat_encode(
                mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
            )))  # fmt: skip
            self._next_heartbeat_us += 1_000_000
        updated = HIGHRES_ACC_GYRO_MAG
        if s.baro is not None:
            self._last_baro = s.baro
            updated |= HIGHRES_ABS_PRESSURE | HIGHRES_TEMPERATURE
        hpa, temp_c = self._last_baro
        a, g, m = s.accel, s.gyro, s.mag
        out.append(pack(mav, mav.highres_imu_encode(
            s.time_usec, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2], hpa, 0.0, 0.0, temp_c, updated, 0
        )))  # fmt: skip
        if s.baro is not None:
            temp_cdeg = int(round(temp_c * 100.0))
            out.append(pack(mav, mav.scaled_pressure_encode(s.time_usec // 1000, hpa, 0.0, temp_cdeg, 0)))
        return out


class TlogWriter:
    """Telemetry log: each frame preceded by its 8-byte big-endian microsecond timestamp."""

    def __init__(self, fh: BinaryIO, epoch_us: int = TLOG_EPOCH_US) -> None:
        self.fh = fh
        self.epoch_us = epoch_us

    def write(self, time_usec: int, frame: bytes) -> None:
        self.fh.write(struct.pack(">Q", self.epoch_us + time_usec) + frame)
