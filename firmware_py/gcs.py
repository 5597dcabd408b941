"""What a ground station asks of a vehicle, answered (MAVLink's command, mission, parameter and ping protocols).

QGroundControl, Mission Planner and MAVProxy ask on connect: the vehicle's version and capabilities
(``MAV_CMD_REQUEST_MESSAGE`` AUTOPILOT_VERSION, ``MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES``), its missions
(MISSION_REQUEST_LIST for each mission type), its parameters (PARAM_REQUEST_LIST) and its clock (TIMESYNC); they
ping. A vehicle that stays silent makes them retry and time out. Every command gets its COMMAND_ACK (UNSUPPORTED for
one the balloon does not do); a balloon has no mission, fence or rally points (MISSION_COUNT 0). The parameters are
the design the filter was started with (a table of ``Param`` the firmware builds once, ``firmware_py.app.PARAMETERS``):
PARAM_REQUEST_LIST and PARAM_REQUEST_READ get their PARAM_VALUEs (an unknown name or index none, as the protocol
says "no such parameter"); nothing is settable in flight, so PARAM_SET is refused as the protocol refuses it, with
the current value, and a STATUSTEXT says why. Pure message in, frames out: the firmware sends them on the link the
request came in on (``Firmware.handle``)."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack

# MAV_PROTOCOL_CAPABILITY: it speaks MAVLink 2, the mission protocol's int frames (with no items) and the parameter
# protocol (one of the two encodings must be named; every parameter is a REAL32, which both encode alike)
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)  # fmt: skip
TEXT_MAX = 50  # STATUSTEXT's text field, characters
PARAM_ID_MAX = 16  # PARAM_VALUE's param_id, characters
_PARAM_NAME = re.compile(r"[A-Z][A-Z0-9_]*")
# PARAM_SET's STATUSTEXTs: with a name of 16 characters at most 50
READ_ONLY_TEXT = "{} is read-only: set in design file"
UNKNOWN_TEXT = "unknown parameter {}"
PARAM_REQUESTS = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")


@dataclass(frozen=True)
class Param:
    """One parameter as a ground station reads it: its name (upper case, at most 16 characters) and its value, a
    MAV_PARAM_TYPE_REAL32. Only reals: an integer type's param_value is read two ways for a vehicle that is not
    ArduPilot (QGroundControl reads its bytes, MAVProxy and pymavlink the float: C cast), a real the same by all."""

    name: str
    value: float

    def __post_init__(self) -> None:
        if len(self.name) > PARAM_ID_MAX or not _PARAM_NAME.fullmatch(self.name):
            raise ValueError(f"parameter name {self.name!r}: upper case, digits and _, at most {PARAM_ID_MAX}")


def check_params(params: tuple[Param, ...]) -> tuple[Param, ...]:
    """``params`` as a table (a tuple, the order the indices follow), each name once."""
    params = tuple(params)
    names = [p.name for p in params]
    if len(set(names)) != len(names):
        raise ValueError(f"parameter names repeated: {sorted({n for n in names if names.count(n) > 1})}")
    return params


def _for_us(msg, sysid: int, compid: int | None = None) -> bool:
    """Addressed to this vehicle (its system id, or to all: 0), and with ``compid`` to this component (or all: 0)."""
    if getattr(msg, "target_system", 0) not in (0, sysid):
        return False
    return compid is None or getattr(msg, "target_component", 0) in (0, compid)


def answer(mav: mavlink.MAVLink, msg, params: tuple[Param, ...] = ()) -> list[bytes]:
    """The frames that answer ``msg`` (none if it asks nothing of this vehicle), packed by ``mav`` (our ids);
    ``params``: the vehicle's parameters (``check_params``), fixed for the session."""
    kind = msg.get_type()
    if kind in ("COMMAND_LONG", "COMMAND_INT") and _for_us(msg, mav.srcSystem):
        return _command(mav, msg)
    if kind in PARAM_REQUESTS and _for_us(msg, mav.srcSystem, mav.srcComponent):
        return _param(mav, msg, params)
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


def _param(mav: mavlink.MAVLink, msg, params: tuple[Param, ...]) -> list[bytes]:
    """PARAM_REQUEST_LIST: every parameter; PARAM_REQUEST_READ: the one asked for by index (>= 0) or, with index
    -1, by name (none if there is no such parameter); PARAM_SET: refused, the current value and a STATUSTEXT."""
    kind = msg.get_type()
    if kind == "PARAM_REQUEST_LIST":
        return [_param_value(mav, params, i) for i in range(len(params))]
    name = _name(msg.param_id)
    i = next((i for i, p in enumerate(params) if p.name == name), -1)  # by name: -1 if none is called so
    if kind == "PARAM_REQUEST_READ":
        if msg.param_index >= 0:  # by index (the name ignored)
            i = msg.param_index
        return [_param_value(mav, params, i)] if 0 <= i < len(params) else []
    if i < 0:  # PARAM_SET of no parameter
        return [_text(mav, UNKNOWN_TEXT.format(name))]
    return [_param_value(mav, params, i), _text(mav, READ_ONLY_TEXT.format(params[i].name))]


def _name(param_id) -> str:
    """A param_id as decoded (str, or bytes), printable ASCII (anything else ``?``), at most 16 characters."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", "replace")
    return "".join(c if " " <= c <= "~" else "?" for c in param_id.rstrip("\0"))[:PARAM_ID_MAX]


def _param_value(mav: mavlink.MAVLink, params: tuple[Param, ...], i: int) -> bytes:
    p = params[i]
    return pack(mav, mav.param_value_encode(p.name.encode("ascii"), float(p.value), mavlink.MAV_PARAM_TYPE_REAL32,
                                            len(params), i))  # fmt: skip


def _text(mav: mavlink.MAVLink, text: str) -> bytes:
    """A STATUSTEXT (severity WARNING, one chunk), ASCII, at most ``TEXT_MAX`` characters."""
    return pack(mav, mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, text.encode("ascii", "replace")[:TEXT_MAX]))
