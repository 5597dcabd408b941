"""A ground station's requests, answered as by any vehicle (firmware_py/gcs.py): QGroundControl, Mission Planner and
MAVProxy ask on connect for the vehicle's version (MAV_CMD_REQUEST_MESSAGE AUTOPILOT_VERSION), its missions
(MISSION_REQUEST_LIST) and ping it; a vehicle that stays silent makes them retry and time out. The requests come back
on the firmware's output link, which it reads too."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from firmware_py import gcs

PY = sys.executable


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_every_request_gets_its_answer():
    """In process: each command its COMMAND_ACK (ACCEPTED with the message asked for, UNSUPPORTED for what a balloon
    does not do), no mission of any type, a ping and a time sync answered; a command for another vehicle, or a
    message that asks nothing, not at all."""
    us = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    them = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    def replies(msg) -> list:
        dm = mavlink.MAVLink(None).decode(bytearray(msg.pack(them)))
        return [mavlink.MAVLink(None).decode(bytearray(f)) for f in gcs.answer(us, dm)]

    version_id = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
    ack, version = replies(them.command_long_encode(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, version_id, 0, 0, 0, 0,
                                                    0, 0))  # fmt: skip
    assert ack.get_type() == "COMMAND_ACK" and ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (255, 190)
    assert version.get_type() == "AUTOPILOT_VERSION" and version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    (ack,) = replies(them.command_long_encode(1, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0))
    assert ack.command == 31000 and ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    assert replies(them.command_long_encode(7, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0)) == []  # another vehicle's
    for kind in (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_FENCE, mavlink.MAV_MISSION_TYPE_RALLY):
        (count,) = replies(them.mission_request_list_encode(1, 1, kind))
        assert count.get_type() == "MISSION_COUNT" and count.count == 0 and count.mission_type == kind
    (ping,) = replies(them.ping_encode(123, 7, 0, 0))
    assert (ping.time_usec, ping.seq, ping.target_system) == (123, 7, 255)
    (sync,) = replies(them.timesync_encode(0, 4242))
    assert sync.ts1 == 4242 and sync.tc1 > 0
    assert replies(them.heartbeat_encode(6, 8, 0, 0, 4)) == []


@pytest.mark.network
def test_a_ground_station_on_the_output_link_is_answered():
    """balloon-fw live (no sensors yet: it heartbeats all the same): a ground station at its --out endpoint hears the
    heartbeat, asks, and gets its answers back on that link."""
    fw_in, gcs_port = free_port(), free_port()
    station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    station.bind(("127.0.0.1", gcs_port))
    station.settimeout(0.2)
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{fw_in}", "--out",
                           f"udpout:127.0.0.1:{gcs_port}", "--duration", "8", "--quiet"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    them = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    parser = mavlink.MAVLink(None)
    got: dict[str, object] = {}
    vehicle = None
    try:
        t_end = time.monotonic() + 7.0
        while time.monotonic() < t_end and not {"COMMAND_ACK", "AUTOPILOT_VERSION", "MISSION_COUNT"} <= got.keys():
            try:
                data, addr = station.recvfrom(65536)
            except TimeoutError:
                continue
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT" and vehicle is None:
                    vehicle = addr
                    for req in (them.command_long_encode(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                         mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0),
                                them.mission_request_list_encode(1, 1, 0)):  # fmt: skip
                        station.sendto(req.pack(them), vehicle)
                got.setdefault(m.get_type(), m)
    finally:
        fw.wait(timeout=30)
        station.close()
    assert vehicle is not None, "no HEARTBEAT from the firmware"
    assert got["COMMAND_ACK"].result == mavlink.MAV_RESULT_ACCEPTED
    assert "AUTOPILOT_VERSION" in got and got["MISSION_COUNT"].count == 0
    assert fw.returncode == 0 and "Traceback" not in fw.stderr.read()
