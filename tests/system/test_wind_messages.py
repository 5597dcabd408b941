"""Every ground station shows the wind (docs/protocol.md, "WIND", "ESTIMATOR_STATUS"): balloon-fw sends
ArduPilot's WIND (168) beside WIND_COV, ESTIMATOR_STATUS (230) for the filter's health, and clears its
sensors' SYS_STATUS health when they fall silent; the ground station shows SENSORS LOST and an unknown
wind as —; MAVProxy decodes WIND from the firmware's output."""

from __future__ import annotations

import io
import math
import os
import shutil
import socket
import subprocess
import sys
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design
from balloon_core.wire import LinkStats, pack, tlog_messages
from firmware_py.app import SENSOR_BITS, Firmware, estimator_flags, wind_fields
from firmware_py.estimator.consistency import FLAG_NIS, SOURCES
from firmware_py.estimator.state import MODE_FREE, MODE_GROUND, MODE_TAUT
from ground_station.listen import GroundStation

PY = sys.executable
GYRO = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
GOOD = mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_HORIZ
ACCEL = 1 << SOURCES.index("accel")


def _round_trip(wind_n: float, wind_e: float):
    """WIND of this air velocity, packed and decoded by pymavlink's ardupilotmega dialect."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = pack(mav, mav.wind_encode(*wind_fields(wind_n, wind_e)))
    return mavlink.MAVLink(None).decode(bytearray(frame))


@pytest.mark.parametrize("wind_n,wind_e,direction", [(-3.0, 0.0, 0.0), (0.0, -3.0, 90.0), (3.0, 0.0, 180.0),
                                                     (0.0, 3.0, 270.0), (-2.0, -2.0, 45.0)])  # fmt: skip
def test_wind_direction_is_where_it_comes_from(wind_n, wind_e, direction):
    """An air velocity toward the south is a wind from the north (0°); toward the east, from the west (270°)."""
    m = _round_trip(wind_n, wind_e)
    assert m.get_type() == "WIND" and m.get_msgId() == 168
    assert m.direction == pytest.approx(direction, abs=1e-4)
    assert m.speed == pytest.approx(math.hypot(wind_n, wind_e), rel=1e-6) and math.isnan(m.speed_z)


@given(st.floats(-40, 40), st.floats(-40, 40))
def test_wind_round_trip_gives_back_wind_cov_components(wind_n, wind_e):
    """From WIND's direction and speed alone, WIND_COV's wind_x (north) and wind_y (east) come back."""
    m = _round_trip(wind_n, wind_e)
    assert 0.0 <= m.direction < 360.0
    rad = math.radians(m.direction)
    assert -m.speed * math.cos(rad) == pytest.approx(wind_n, abs=1e-4 + 1e-6 * abs(m.speed))
    assert -m.speed * math.sin(rad) == pytest.approx(wind_e, abs=1e-4 + 1e-6 * abs(m.speed))


def test_estimator_flags_mapping():
    assert estimator_flags(False, False, MODE_TAUT, 0, True) == 0  # nothing before the first sample
    good = estimator_flags(True, False, MODE_TAUT, 0, True)
    assert good & GOOD == GOOD and good & mavlink.ESTIMATOR_POS_HORIZ_REL and good & mavlink.ESTIMATOR_POS_VERT_AGL
    assert not good & (mavlink.ESTIMATOR_ACCEL_ERROR | mavlink.ESTIMATOR_CONST_POS_MODE | mavlink.ESTIMATOR_GPS_GLITCH)
    ground = estimator_flags(True, False, MODE_GROUND, 0, False)
    assert ground & mavlink.ESTIMATOR_CONST_POS_MODE and not ground & mavlink.ESTIMATOR_VELOCITY_HORIZ
    assert not estimator_flags(True, False, MODE_FREE, 0, True) & mavlink.ESTIMATOR_POS_HORIZ_REL  # no rope yet
    misfit = estimator_flags(True, False, MODE_TAUT, ACCEL, True)
    assert misfit & mavlink.ESTIMATOR_ACCEL_ERROR and not misfit & mavlink.ESTIMATOR_VELOCITY_HORIZ
    silent = estimator_flags(True, True, MODE_TAUT, 0, True)
    assert silent & ~mavlink.ESTIMATOR_CONST_POS_MODE == 0  # silent: nothing is good


class Sink:
    """What the firmware sends, decoded (sensor time s, message)."""

    def __init__(self) -> None:
        self.sent: list[tuple[float, object]] = []
        self.mav = mavlink.MAVLink(None)

    def send_at(self, frame: bytes, t_us: int) -> None:
        self.sent.append((t_us * 1e-6, self.mav.decode(bytearray(frame))))

    def of(self, kind: str) -> list[tuple[float, object]]:
        return [(t, m) for t, m in self.sent if m.get_type() == kind]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 60 s paper-reference flight (sensor tlog), and the firmware's output on it, in process."""
    d = tmp_path_factory.mktemp("wind")
    tlog = d / "sensors.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--scenario", "paper-reference", "--duration", "60", "--seed", "2",
                    "--out", str(tlog), "--quiet"], check=True, capture_output=True)  # fmt: skip
    sink = Sink()
    fw = Firmware(Design(), sink=sink)
    for m in tlog_messages(str(tlog), fw.stats):
        fw.handle(m)
    fw.flush()
    return tlog, fw, sink


@pytest.mark.slow
def test_firmware_sends_wind_and_estimator_status_at_1_hz(flight):
    _, fw, sink = flight
    winds, covs, status = sink.of("WIND"), sink.of("WIND_COV"), sink.of("ESTIMATOR_STATUS")
    assert len(winds) == len(status) == pytest.approx(60, abs=1) and len(covs) == pytest.approx(600, abs=2)
    assert all(b - a == pytest.approx(1.0, abs=0.011) for (a, _), (b, _) in zip(winds, winds[1:]))
    kinds = [m.get_type() for _, m in sink.sent]  # each WIND just before a WIND_COV: a reader of both keeps WIND_COV's
    assert all(kinds[i + 1] == "WIND_COV" for i, k in enumerate(kinds) if k == "WIND")
    for t, w in winds:  # the same estimate as the WIND_COV sent at the same time
        cov = [m for tc, m in covs if tc == t]
        assert cov, t
        n, e = cov[-1].wind_x, cov[-1].wind_y
        rad = math.radians(w.direction)
        assert w.speed == pytest.approx(math.hypot(n, e), abs=1e-5)
        assert -w.speed * math.cos(rad) == pytest.approx(n, abs=1e-4)
        assert -w.speed * math.sin(rad) == pytest.approx(e, abs=1e-4)
    # at rest on the ground station first, then in flight on the rope with the wind known
    assert status[0][1].flags & mavlink.ESTIMATOR_CONST_POS_MODE
    assert not status[0][1].flags & mavlink.ESTIMATOR_VELOCITY_HORIZ
    late = [m for t, m in status if t > 45.0]
    assert late and all(m.flags & mavlink.ESTIMATOR_POS_HORIZ_REL for m in late)
    assert any(m.flags & mavlink.ESTIMATOR_VELOCITY_HORIZ for m in late)
    last = status[-1][1]
    assert last.pos_horiz_accuracy > 0.0 and last.pos_vert_accuracy > 0.0
    assert all(m.onboard_control_sensors_health & GYRO for _, m in sink.of("SYS_STATUS"))


def test_qgc_direction_from_sends_wind_after_every_wind_cov(flight):
    """``[outputs] qgc_direction = "from"``: WIND follows every WIND_COV, so a ground station that holds the
    last of the two (QGroundControl) holds where the wind comes FROM; the WIND_COV stream is unchanged."""
    from firmware_py.app import OutputConfig

    tlog, _, base = flight
    sink = Sink()
    fw = Firmware(Design(), sink=sink, outputs=OutputConfig.from_dict({"qgc_direction": "from"}))
    for m in tlog_messages(str(tlog), fw.stats):
        fw.handle(m)
    fw.flush()
    kinds = [m.get_type() for _, m in sink.sent]
    covs = [i for i, k in enumerate(kinds) if k == "WIND_COV"]
    assert len(covs) == len(base.of("WIND_COV")) and len(sink.of("WIND")) == pytest.approx(len(covs), abs=5)
    late = [i for i in covs if sink.sent[i][0] > 10.0]
    assert late and all(kinds[i + 1] == "WIND" for i in late if i + 1 < len(kinds))
    for i in late[:50]:  # the same estimate: WIND's FROM is WIND_COV's air velocity turned by 180 deg
        cov, w = sink.sent[i][1], sink.sent[i + 1][1]
        rad = math.radians(w.direction)
        assert -w.speed * math.cos(rad) == pytest.approx(cov.wind_x, abs=1e-4)
        assert -w.speed * math.sin(rad) == pytest.approx(cov.wind_y, abs=1e-4)
    assert [m.wind_x for _, m in sink.of("WIND_COV")] == [m.wind_x for _, m in base.of("WIND_COV")]
    from balloon_core.config import ConfigError

    with pytest.raises(ConfigError):
        OutputConfig.from_dict({"qgc_direction": "north"})


@pytest.mark.slow
def test_silent_sensors_are_told_and_the_ground_station_shows_them(flight):
    tlog, _, _ = flight
    sink = Sink()
    fw = Firmware(Design(), sink=sink)
    msgs = list(tlog_messages(str(tlog), LinkStats()))
    head = [m for m in msgs if getattr(m, "time_usec", 0) <= 50_000_000]
    for m in head:
        fw.handle(m)
    gs = GroundStation(out=io.StringIO())
    for _, m in sink.sent:
        gs.handle(m, 100.0)
    assert "SENSORS LOST" not in gs.status_line(100.0) and not gs.vehicles[1].sensors_lost()
    n = len(sink.sent)
    for k in range(30):  # 3 s of silence: the firmware keeps talking (balloon-fw's live loop calls coast)
        fw.coast(1000.0 + 0.1 * k)
    told = [m for _, m in sink.sent[n:]]
    sys_status = [m for m in told if m.get_type() == "SYS_STATUS"]
    assert len(sys_status) == 3
    for m in sys_status:
        assert m.onboard_control_sensors_present == SENSOR_BITS
        assert not m.onboard_control_sensors_health & GYRO  # the gyro: only silence clears it
    es = [m for m in told if m.get_type() == "ESTIMATOR_STATUS"]
    assert es and all(not m.flags & GOOD for m in es)
    nis = fw.est.consistency.nis  # the ratios: the monitor's windowed NIS over its flag threshold
    for field, source in (("vel_ratio", "accel"), ("pos_horiz_ratio", "align"), ("pos_vert_ratio", "baro"),
                          ("mag_ratio", "mag"), ("hagl_ratio", "radius")):  # fmt: skip
        assert getattr(es[-1], field) == pytest.approx(nis[SOURCES.index(source)] / FLAG_NIS, rel=1e-5, abs=1e-7)
    assert es[-1].tas_ratio == pytest.approx(max(nis) / FLAG_NIS, rel=1e-5) and max(nis) > 0.0
    for m in told:
        gs.handle(m, 103.0)
    v = gs.vehicles[1]
    assert v.sensors_lost() and v.misfit() == []
    assert "SENSORS LOST" in gs.status_line(103.0)
    from rich.console import Console

    con = Console(width=80, record=True, file=io.StringIO(), force_terminal=True)
    con.print(gs.view(103.0, 80))
    row = next(ln for ln in con.export_text().splitlines() if ln.split() and ln.split()[0] == "1")
    assert "SENSORS LOST" in row and "OK" not in row
    # the sensors are back: healthy again
    for m in msgs[len(head) : len(head) + 300]:
        fw.handle(m)
    last = [m for _, m in sink.sent if m.get_type() == "SYS_STATUS"][-1]
    assert last.onboard_control_sensors_health & GYRO


def test_a_wind_not_known_is_shown_as_a_dash():
    """Before the first estimate (NaN) and while the accuracy is as large as the wind could be."""
    from rich.console import Console

    from balloon_core.wire import Decoder

    gs = GroundStation(out=io.StringIO())
    dec = Decoder(gs.stats)
    mav = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    hb = pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 3))

    def row(wind_n, wind_e, acc, width=80):
        for f in (hb, pack(mav, mav.wind_cov_encode(1_000_000, wind_n, wind_e, math.nan, math.nan, math.nan, 0.0,
                                                    acc, 0.0))):  # fmt: skip
            for m in dec.feed(f):
                gs.handle(m, 10.0)
        con = Console(width=width, record=True, file=io.StringIO(), force_terminal=True)
        con.print(gs.view(10.0, width))
        line = next(ln for ln in con.export_text().splitlines() if ln.split() and ln.split()[0] == "4")
        return line.split(), gs.status_line(10.0)

    for wind in ((math.nan, math.nan, math.nan), (0.0, 0.0, 3.5), (1.0, 1.0, 2.0)):
        cells, plain = row(*wind)
        assert cells[1:3] == ["—", "—"] and "0.00" not in cells and "180" not in cells, cells
        assert "wind — (not known)" in plain
    cells, plain = row(-3.0, 0.0, 0.2)  # known: 3 m/s from the north
    assert cells[1:3] == ["3.00", "000"] and "from   0.0 deg" in plain
    cells, _ = row(-3.0, 0.0, 0.0)  # PX4's accuracy 0 is no claim: known
    assert cells[1] == "3.00"


# ---------------------------------------------------------------- MAVProxy


def _mavproxy() -> str | None:
    here = os.path.join(os.path.dirname(PY), "mavproxy.py")
    return here if os.path.exists(here) else shutil.which("mavproxy.py")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.network
@pytest.mark.skipif(_mavproxy() is None, reason="MAVProxy is not installed (pip install MAVProxy: the test extra)")
def _status_flags(seen: list[str]) -> list[int]:
    """The ESTIMATOR_STATUS flags MAVProxy printed."""
    return [int(ln.split("flags : ")[1].split(",")[0]) for ln in seen if "ESTIMATOR_STATUS {" in ln]


def _horizontal(seen: list[str]) -> bool:
    return any(f & mavlink.ESTIMATOR_VELOCITY_HORIZ for f in _status_flags(seen))


def test_mavproxy_shows_the_firmwares_wind(flight, tmp_path):
    """MAVProxy, headless, with the firmware's output as its master: ``status WIND`` prints the wind,
    ``status ESTIMATOR_STATUS`` the filter's health."""
    tlog, fw, sink = flight
    port = _free_port()
    proc = subprocess.Popen([PY, _mavproxy(), f"--master=udpin:127.0.0.1:{port}", "--non-interactive",
                             "--cmd=repeat add 1 status WIND; repeat add 1 status ESTIMATOR_STATUS",
                             f"--state-basedir={tmp_path}"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 60.0
        seen = []
        # until MAVProxy has printed a WIND and a taut flight's status (one printed on the ground or in a misfit's
        # seconds has no horizontal velocity: which second it prints is the replay's timing, not the firmware's)
        while time.monotonic() < deadline and not (any("WIND {" in ln for ln in seen) and _horizontal(seen)):
            # the firmware replays the flight into MAVProxy's port (again, until MAVProxy has bound it)
            subprocess.run([PY, "-m", "firmware_py", "--in", str(tlog), "--out", f"udpout:127.0.0.1:{port}",
                            "--quiet"], check=True, capture_output=True)  # fmt: skip
            time.sleep(2.0)
            os.set_blocking(proc.stdout.fileno(), False)
            seen += (proc.stdout.read() or "").splitlines()
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    lines = [ln for ln in seen if "WIND {" in ln]
    assert lines, "\n".join(seen[-20:])
    text = lines[-1]
    direction = float(text.split("direction : ")[1].split(",")[0])
    speed = float(text.split("speed : ")[1].split(",")[0])
    # MAVProxy prints the WIND it last received while the firmware may still be sending: the printed wind is
    # one the firmware sent (its float32 fields, as MAVProxy shows them), not necessarily the very last
    sent = [(m.direction, m.speed) for _, m in sink.of("WIND")]
    assert any(abs(direction - d) <= 1e-3 and speed == pytest.approx(s) for d, s in sent), (direction, speed)
    assert "speed_z : nan" in text
    printed = _status_flags(seen)
    # as for WIND: each status MAVProxy printed is one the firmware sent, from wherever in the replayed flight it
    # was (on the ground or in a misfit's seconds: no horizontal velocity); the taut flight's show one
    assert set(printed) <= {m.flags for _, m in sink.of("ESTIMATOR_STATUS")}, printed
    assert any(f & mavlink.ESTIMATOR_VELOCITY_HORIZ for f in printed), printed
