"""A small MAVLink decoder for the few messages the firmware reads (HIGHRES_IMU, HIL_SENSOR, SCALED_IMU/2/3,
SCALED_PRESSURE/2/3, WINCH_STATUS), beside pymavlink: a replay spends most of its decoding time in
pymavlink's generic message objects, and these are the frames of nearly every record.

``decode(frame)`` takes one whole frame (MAVLink 2 or 1; a signed one's signature skipped, not checked,
as pymavlink does without a key) and returns a light message (``FastMessage``: the fields as attributes,
``get_type``, ``get_msgId``, ``get_srcSystem``, ``get_srcComponent``, ``get_seq``) only when the frame is
one of these messages with a consistent length and a good CRC (with the message's CRC_EXTRA); anything
else is None, and the caller hands the frame to pymavlink, which decodes it or finds it bad by its own
rules. So a frame is never judged here differently from pymavlink (tests/unit/test_fastmav.py: real and
simulated tlogs, corrupted and garbage bytes, the same messages and counts out). Without the ``fastcrc``
package (pymavlink's own accelerator) there is no fast path: everything goes to pymavlink.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

try:
    from fastcrc.crc16 import mcrf4xx
except ImportError:  # pragma: no cover - fastcrc is a dependency
    mcrf4xx = None

MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
HEADER_V2, HEADER_V1 = 10, 6
SIGNATURE = 13
IFLAG_SIGNED = 0x01
CRC_INIT = 0xFFFF
MESSAGES = (
    mavlink.MAVLink_highres_imu_message, mavlink.MAVLink_hil_sensor_message, mavlink.MAVLink_scaled_imu_message,
    mavlink.MAVLink_scaled_imu2_message, mavlink.MAVLink_scaled_imu3_message,
    mavlink.MAVLink_scaled_pressure_message, mavlink.MAVLink_scaled_pressure2_message,
    mavlink.MAVLink_scaled_pressure3_message, mavlink.MAVLink_winch_status_message,
)  # fmt: skip


HEADER_FIELDS = ("_sys", "_comp", "_seq")


class FastMessage:
    """A decoded frame: its fields and ``HEADER_FIELDS`` in the instance's dict (the cheapest attribute
    reads), one subclass per message (``_classes``) with pymavlink's accessors."""

    _type = ""
    _id = -1
    _names: tuple[str, ...] = ()

    def get_type(self) -> str:
        return self._type

    def get_msgId(self) -> int:  # noqa: N802 - pymavlink's name
        return self._id

    def get_srcSystem(self) -> int:  # noqa: N802
        return self._sys

    def get_srcComponent(self) -> int:  # noqa: N802
        return self._comp

    def get_seq(self) -> int:
        return self._seq

    def to_dict(self) -> dict:
        return {"mavpackettype": self._type, **{n: getattr(self, n) for n in self._names}}


def _classes() -> dict[int, tuple]:
    """msg id -> (CRC_EXTRA byte, payload size, struct unpacker, the message's class, its names in wire
    order then ``HEADER_FIELDS``)."""
    out = {}
    for m in MESSAGES:
        assert sum(m.lengths) == len(m.lengths), m.msgname  # no array fields: one value per field
        wire = [""] * len(m.fieldnames)
        for i, name in enumerate(m.fieldnames):  # pymavlink: field i of the declaration is t[orders[i]]
            wire[m.orders[i]] = name
        cls = type(f"Fast_{m.msgname}", (FastMessage,), {"_type": m.msgname, "_id": m.id, "_names": tuple(wire)})
        out[m.id] = (bytes((m.crc_extra,)), m.unpacker.size, m.unpacker.unpack, cls, (*wire, *HEADER_FIELDS))
    return out


TABLE = _classes() if mcrf4xx is not None else {}


def decode(frame: bytes) -> FastMessage | None:
    """One whole frame as a ``FastMessage``, or None: not one of ``MESSAGES``, or not a frame pymavlink
    would decode to one (bad length, bad CRC): let pymavlink have it."""
    n = len(frame)
    if n < 8:
        return None
    magic = frame[0]
    if magic == MAGIC_V2:
        if n < HEADER_V2 + 2:
            return None
        hl = HEADER_V2
        msg_id = frame[7] | frame[8] << 8 | frame[9] << 16
        tail = 2 + (SIGNATURE if frame[2] & IFLAG_SIGNED else 0)
        seq, sysid, compid = frame[4], frame[5], frame[6]
    elif magic == MAGIC_V1:
        hl = HEADER_V1
        msg_id = frame[5]
        tail = 2
        seq, sysid, compid = frame[2], frame[3], frame[4]
    else:
        return None
    spec = TABLE.get(msg_id)
    mlen = frame[1]
    if spec is None or mlen != n - hl - tail:
        return None
    extra, size, unpack, cls, names = spec
    end = n - tail
    if mcrf4xx(extra, mcrf4xx(frame[1:end], CRC_INIT)) != frame[end] | frame[end + 1] << 8:
        return None
    payload = frame[hl:end]
    if mlen < size:  # MAVLink 2 cuts trailing zeros
        payload += bytes(size - mlen)
    elif mlen > size:  # extensions this dialect does not know
        payload = payload[:size]
    m = cls()
    m.__dict__ = dict(zip(names, unpack(payload) + (sysid, compid, seq)))
    return m
