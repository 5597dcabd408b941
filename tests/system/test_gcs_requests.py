"""A ground station's requests, answered as by any vehicle (firmware_py/gcs.py): QGroundControl, Mission Planner and
MAVProxy ask on connect for the vehicle's version (MAV_CMD_REQUEST_MESSAGE AUTOPILOT_VERSION), its missions
(MISSION_REQUEST_LIST) and its parameters (PARAM_REQUEST_LIST: the design, read-only) and ping it; a vehicle that
stays silent makes them retry and time out. The requests come back on the firmware's output link, which it reads
too."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import BalloonConfig, Design, SensorsConfig, SiteConfig, TetherConfig, to_toml
from firmware_py import app, gcs

PY = sys.executable

DOCS = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"
# a design no default shares a value with (a table of the defaults would fail), with a ground pressure
DESIGN = Design(
    BalloonConfig(radius_m=1.3, skin_and_avionics_kg=1.15, gas_density_kg_m3=0.17, drag_coefficient=0.42),
    TetherConfig(length_m=75.0, linear_density_kg_m=0.013),
    SiteConfig(altitude_amsl_m=412.5, mag_declination_deg=-3.25, ground_pressure_hpa=968.4),
    SensorsConfig(accel_mps2=0.03, baro_m=0.7, gyro_dps=0.35, mag_gauss=0.004, thermometer_k=0.3,
                  imu_alignment_deg=0.4, imu_roll_deg=-1.25, imu_pitch_deg=0.75),
)


def design_values(d: Design) -> dict[str, float]:
    """What a ground station must read of design ``d`` (at the firmware's 10 Hz), as the wire's float32."""
    b, t, site, s = d.balloon, d.tether, d.site, d.sensors
    values = {"BAL_RADIUS": b.radius_m, "BAL_MASS": b.skin_and_avionics_kg, "BAL_GAS_RHO": b.gas_density_kg_m3,
              "BAL_CD": b.drag_coefficient, "TETH_LEN": t.length_m, "TETH_RHO_L": t.linear_density_kg_m,
              "SITE_ALT": site.altitude_amsl_m, "SITE_DECL": site.mag_declination_deg,
              "SITE_GND_P": site.ground_pressure_hpa, "SNS_ACC_SD": s.accel_mps2, "SNS_BARO_SD": s.baro_m,
              "SNS_GYRO_SD": s.gyro_dps, "SNS_MAG_SD": s.mag_gauss, "SNS_IMU_ROLL": s.imu_roll_deg,
              "SNS_IMU_PITCH": s.imu_pitch_deg, "SNS_IMU_ALIGN": s.imu_alignment_deg, "WIND_COV_HZ": 10.0}  # fmt: skip
    return {k: float(np.float32(v)) for k, v in values.items() if v is not None}


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


class Frames:
    """A live link's sink (``send``): the frames the firmware sends, decoded."""

    def __init__(self) -> None:
        self.parser = mavlink.MAVLink(None)
        self.msgs: list = []

    def send(self, frame: bytes) -> None:
        self.msgs.append(self.parser.decode(bytearray(frame)))


def test_parameters_are_the_design_read_only():
    """The firmware (in process, a live link's sink) lists the design it was started with as its parameters; each is
    read by name and by index; an unknown name or index gets no PARAM_VALUE; a PARAM_SET is refused with the current
    value and a STATUSTEXT; a request for another system or component is not answered."""
    sink = Frames()
    fw = app.Firmware(DESIGN, sink=sink)
    them = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    def replies(msg) -> list:
        sink.msgs.clear()
        fw.handle(mavlink.MAVLink(None).decode(bytearray(msg.pack(them))))
        return list(sink.msgs)

    want = design_values(DESIGN)
    listed = replies(them.param_request_list_encode(1, 1))
    n = len(listed)
    assert n == len(want) and all(m.get_type() == "PARAM_VALUE" for m in listed)
    assert [m.param_index for m in listed] == list(range(n)) and {m.param_count for m in listed} == {n}
    names = [m.param_id for m in listed]
    assert len(set(names)) == n and all(len(name) <= 16 and name == name.upper() for name in names)
    assert {m.param_id: m.param_value for m in listed} == want
    assert {m.param_type for m in listed} == {mavlink.MAV_PARAM_TYPE_REAL32}  # read alike by every ground station

    def fields(msgs: list) -> list:
        return [(m.param_id, m.param_value, m.param_type, m.param_count, m.param_index) for m in msgs]

    assert fields(replies(them.param_request_list_encode(0, 0))) == fields(listed)  # to all: the same list
    by_name = {m.param_id: m for m in listed}

    (one,) = replies(them.param_request_read_encode(1, 1, b"TETH_LEN", -1))
    assert (one.param_id, one.param_value, one.param_index, one.param_count) == (
        "TETH_LEN", 75.0, by_name["TETH_LEN"].param_index, n)  # fmt: skip
    (one,) = replies(them.param_request_read_encode(1, 1, b"", n - 1))
    assert (one.param_id, one.param_index) == (names[-1], n - 1)
    (one,) = replies(them.param_request_read_encode(1, 0, b"IGNORED_BY_INDEX", 0))
    assert (one.param_id, one.param_index) == (names[0], 0)
    assert replies(them.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1)) == []
    assert replies(them.param_request_read_encode(1, 1, b"", n)) == []
    assert replies(them.param_request_read_encode(1, 1, b"", 32767)) == []

    value, text = replies(them.param_set_encode(1, 1, b"BAL_RADIUS", 9.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert value.get_type() == "PARAM_VALUE" and value.param_id == "BAL_RADIUS"
    assert value.param_value == want["BAL_RADIUS"]  # the current value: refused
    assert (value.param_index, value.param_count) == (by_name["BAL_RADIUS"].param_index, n)
    assert text.get_type() == "STATUSTEXT" and text.severity == mavlink.MAV_SEVERITY_WARNING
    assert "BAL_RADIUS" in text.text and "read-only" in text.text and "design file" in text.text
    (value, _) = replies(them.param_set_encode(0, 0, b"WIND_COV_HZ", 50.0, mavlink.MAV_PARAM_TYPE_INT32))
    assert (value.param_value, value.param_type) == (10.0, mavlink.MAV_PARAM_TYPE_REAL32)
    (text,) = replies(them.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert text.get_type() == "STATUSTEXT" and "NO_SUCH_PARAM" in text.text
    assert replies(them.param_request_read_encode(1, 1, b"BAL_RADIUS", -1))[0].param_value == want["BAL_RADIUS"]

    for target in ((7, 1), (7, 0), (1, 100)):  # another vehicle's, another component's
        assert replies(them.param_request_list_encode(*target)) == []
        assert replies(them.param_request_read_encode(*target, b"BAL_RADIUS", -1)) == []
        assert replies(them.param_set_encode(*target, b"BAL_RADIUS", 9.0, mavlink.MAV_PARAM_TYPE_REAL32)) == []


def test_the_parameter_list_is_fixed_by_the_design():
    """No ground pressure in the design: no SITE_GND_P (the list one shorter, in the same order); the same design the
    same list; every name and its unit in docs/protocol.md; a repeated or too long name refused."""
    with_p = app.parameters(DESIGN, 10.0)
    without = app.parameters(Design(), 10.0)
    assert [p.name for p in without] == [p.name for p in with_p if p.name != "SITE_GND_P"]
    assert {p.name: float(np.float32(p.value)) for p in without} == design_values(Design())
    assert app.parameters(DESIGN, 10.0) == with_p
    docs = DOCS.read_text()
    for name in (p.name for p in with_p):
        assert f"| `{name}` |" in docs, f"{name} not in docs/protocol.md"
    with pytest.raises(ValueError):
        gcs.check_params((gcs.Param("BAL_CD", 1.0), gcs.Param("BAL_CD", 2.0)))
    with pytest.raises(ValueError):
        gcs.Param("A_NAME_LONGER_THAN_16", 1.0)


@pytest.mark.network
def test_a_ground_station_loads_the_parameters_over_the_link(tmp_path):
    """balloon-fw live with a design file: a ground station as MAVProxy is one (pymavlink's mavutil, at the --out
    endpoint) waits for the heartbeat, asks for the parameter list (PARAM_REQUEST_LIST to the heartbeat's system, all
    its components) and gets every one of the design's values over UDP."""
    config = tmp_path / "design.toml"
    config.write_text(to_toml({"balloon": DESIGN.balloon, "tether": DESIGN.tether, "site": DESIGN.site,
                               "sensors": DESIGN.sensors}, "# test_gcs_requests"))  # fmt: skip
    want = design_values(DESIGN)
    fw_in, gcs_port = free_port(), free_port()
    station = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255, source_component=190)
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{fw_in}", "--out",
                           f"udpout:127.0.0.1:{gcs_port}", "--config", str(config), "--duration", "8", "--quiet"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    got: dict[int, object] = {}
    try:
        heartbeat = station.wait_heartbeat(timeout=7.0)
        assert heartbeat is not None, "no HEARTBEAT from the firmware"
        station.param_fetch_all()  # as MAVProxy's "param fetch": to the system heard (1), component 0
        assert station.target_system == heartbeat.get_srcSystem()
        t_end = time.monotonic() + 5.0
        while time.monotonic() < t_end and (not got or len(got) < next(iter(got.values())).param_count):
            m = station.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
            if m is not None:
                got[m.param_index] = m
    finally:
        fw.wait(timeout=30)
        station.close()
    assert sorted(got) == list(range(len(want))) and {m.param_count for m in got.values()} == {len(want)}
    assert {m.param_id: m.param_value for m in got.values()} == want == {k: float(v) for k, v in station.params.items()}
    assert fw.returncode == 0 and "Traceback" not in fw.stderr.read()


def test_a_request_is_answered_on_its_own_link():
    """Live, the firmware talks on two links: the ground station's (--out) and the sensors' (--in), where an autopilot
    may sit with the same system id. A request is answered on the link it came in on only: the autopilot never gets the
    parameter list a ground station asked for, nor the ground station the autopilot's answers."""
    station, autopilot = Frames(), Frames()
    fw = app.Firmware(DESIGN, sink=station)
    fw.sinks.append(autopilot)  # as run_live adds the sensors' link
    them = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    request = mavlink.MAVLink(None).decode(bytearray(them.param_request_list_encode(1, 1).pack(them)))
    fw.handle(request, station)
    assert [m.get_type() for m in station.msgs] == ["PARAM_VALUE"] * len(design_values(DESIGN))
    assert autopilot.msgs == []
    station.msgs.clear()
    ping = mavlink.MAVLink(None).decode(bytearray(them.ping_encode(123, 7, 0, 0).pack(them)))
    fw.handle(ping, autopilot)
    assert station.msgs == [] and [m.get_type() for m in autopilot.msgs] == ["PING"]
