"""What a ground station asks of a vehicle, answered (MAVLink's command, mission and ping protocols).

QGroundControl, Mission Planner and MAVProxy ask on connect: the vehicle's version and capabilities
(``MAV_CMD_REQUEST_MESSAGE`` AUTOPILOT_VERSION, ``MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES``), its missions
(MISSION_REQUEST_LIST for each mission type) and its clock (TIMESYNC); they ping. A vehicle that stays silent
makes them retry and time out. Every command gets its COMMAND_ACK (UNSUPPORTED for one the balloon does not
do); a balloon has no mission, fence or rally points (MISSION_COUNT 0); no parameter is settable in flight, so
PARAM_REQUEST_LIST is not answered (the design file holds them). Pure message in, frames out: the firmware sends
them on its links (``Firmware.answer``)."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack

# MAV_PROTOCOL_CAPABILITY: it speaks MAVLink 2 and the mission protocol's int frames (with no items)
CAPABILITIES = mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT


def _for_us(msg, sysid: int) -> bool:
    """Addressed to this vehicle (its system id, or to all: 0)."""
    return getattr(msg, "target_system", 0) in (0, sysid)


def answer(mav: mavlink.MAVLink, msg) -> list[bytes]:
    """The frames that answer ``msg`` (none if it asks nothing of this vehicle), packed by ``mav`` (our ids)."""
    kind = msg.get_type()
    if kind in ("COMMAND_LONG", "COMMAND_INT") and _for_us(msg, mav.srcSystem):
        return _command(mav, msg)
    if kind == "MISSION_REQUEST_LIST" and _for_us(msg, mav.srcSystem):
        return [pack(mav, mav.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), 0,
                                                   msg.mission_type))]  # fmt: skip
    if kind == "TIMESYNC" and msg.tc1 == 0:  # a request: our clock (ns) beside its own
        return [pack(mav, mav.timesync_encode(time.monotonic_ns(), msg.ts1))]
    if kind == "PING" and msg.target_system == 0:  # a request (a reply names its target)
        return [pack(mav, mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))]
    return []


def _command(mav: mavlink.MAVLink, msg) -> list[bytes]:
    cmd = msg.command
    out: list[bytes] = []
    result = mavlink.MAV_RESULT_UNSUPPORTED
    wanted = int(msg.param1) if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE else None
    if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES or wanted == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        out.append(pack(mav, mav.autopilot_version_encode(CAPABILITIES, 0, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8,
                                                          0, 0, 0)))  # fmt: skip
        result = mavlink.MAV_RESULT_ACCEPTED
    ack = mav.command_ack_encode(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
    return [pack(mav, ack), *out]
