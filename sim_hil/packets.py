"""MAVLink 2 sensor packets (pymavlink): HIGHRES_IMU, SCALED_PRESSURE and HEARTBEAT frames from the
balloon's sensors; WINCH_STATUS from the winch (its own component) and the ground reference's
SCALED_PRESSURE from the ground station's system, when the simulation has them."""

from __future__ import annotations

import math
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack
from sim_hil.simulator import SensorSample

SIM_SYSID = 1
SIM_COMPID = mavlink.MAV_COMP_ID_IMU
HIGHRES_ACC_GYRO_MAG = 0x1FF
HIGHRES_ABS_PRESSURE = 0x200
HIGHRES_TEMPERATURE = 0x1000
GROUND_SYSID = 255  # the ground station's system ([site] ground_sysid's default)
GROUND_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER
WINCH_SYSID = GROUND_SYSID  # the winch stands at the ground station: a component of its system
WINCH_COMPID = mavlink.MAV_COMP_ID_WINCH
_HEADER_V2 = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_HIGHRES = mavlink.MAVLink_highres_imu_message


def _frame(mav: mavlink.MAVLink, msg_id: int, crc_extra: int, payload: bytes) -> bytes:
    """The frame ``pack(mav, msg)`` makes of a message with this payload (pymavlink's ``_pack``: MAVLink 2,
    trailing zeros cut, unsigned), without building the message object: the per-sample HIGHRES_IMU."""
    plen = len(payload)
    while plen > 1 and payload[plen - 1] == 0:
        plen -= 1
    buf = _HEADER_V2.pack(253, plen, 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, msg_id & 0xFFFF, msg_id >> 16)
    buf += payload[:plen]
    crc = mavlink.x25crc(buf[1:])
    crc.accumulate(bytes((crc_extra,)))
    mav.seq = (mav.seq + 1) % 256
    mav.total_packets_sent += 1
    return buf + _CRC.pack(crc.crc)


class SensorPacketEncoder:
    """Encodes simulator samples as HIGHRES_IMU (every sample), SCALED_PRESSURE (new baro samples) and
    HEARTBEAT (1 Hz, MAV_TYPE_FREE_BALLOON) frames."""

    def __init__(self, sysid: int = SIM_SYSID, compid: int = SIM_COMPID, ground_sysid: int = GROUND_SYSID) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.winch_mav = mavlink.MAVLink(None, srcSystem=WINCH_SYSID, srcComponent=WINCH_COMPID)
        self.ground_mav = mavlink.MAVLink(None, srcSystem=ground_sysid, srcComponent=GROUND_COMPID)
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
        if mav.signing.sign_outgoing:  # never in the simulator: pymavlink's whole path
            out.append(pack(mav, mav.highres_imu_encode(
                s.time_usec, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2], hpa, 0.0, 0.0, temp_c, updated, 0
            )))  # fmt: skip
        else:
            out.append(_frame(mav, _HIGHRES.id, _HIGHRES.crc_extra, _HIGHRES.unpacker.pack(
                s.time_usec, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2], hpa, 0.0, 0.0, temp_c, updated, 0
            )))  # fmt: skip
        if s.baro is not None:
            temp_cdeg = int(round(temp_c * 100.0))
            out.append(pack(mav, mav.scaled_pressure_encode(s.time_usec // 1000, hpa, 0.0, temp_cdeg, 0)))
        if s.winch is not None:
            length, speed, kg, status = s.winch
            w = self.winch_mav
            out.append(pack(w, w.winch_status_encode(s.time_usec, length, speed, kg, math.nan, math.nan, 0, status)))
        if s.ground is not None:
            g = self.ground_mav
            ghpa, gtemp = s.ground
            out.append(pack(g, g.scaled_pressure_encode(s.time_usec // 1000, ghpa, 0.0, int(round(gtemp * 100.0)), 0)))
        return out
