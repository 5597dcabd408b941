"""balloon-fw as a program: tlog and raw replay, WIND_COV fields, HIL_SENSOR input, bad bytes."""

import math
import os
import random
import re
import subprocess
import sys

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import LinkStats, tlog_messages


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("fw")
    tlog = d / "sensors.tlog"
    subprocess.run([sys.executable, "-m", "sim_hil", "--duration", "150", "--seed", "5", "--out", str(tlog),
                    "--truth", str(d / "truth.csv")], check=True, capture_output=True)  # fmt: skip
    return d, tlog


def run_fw(*args):
    """The program as a user runs it off a terminal; the periodic status lines (every 10 s when not on a
    terminal) are left out so that a slow machine does not change what stderr holds."""
    env = {**os.environ, "BALLOON_STATUS_INTERVAL_S": "1e9"}
    return subprocess.run([sys.executable, "-m", "firmware_py", *map(str, args)], capture_output=True, text=True,
                          env=env)  # fmt: skip


def read(tlog, kind):
    conn = mavutil.mavlink_connection(str(tlog))
    out = []
    while (m := conn.recv_match(type=kind)) is not None:
        out.append(m)
    return out


@pytest.mark.slow
def test_tlog_replay_emits_wind_cov_and_heartbeat(flight):
    d, tlog = flight
    out = d / "fw.tlog"
    r = run_fw("--in", tlog, "--out", out)
    assert r.returncode == 0, r.stderr
    assert "15000 IMU samples" in r.stderr and "mode switches" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    wc = read(out, "WIND_COV")
    assert len(wc) == pytest.approx(1500, abs=2)  # 10 Hz
    hb = read(out, "HEARTBEAT")
    assert len(hb) == pytest.approx(150, abs=2)
    assert hb[0].type == mavlink.MAV_TYPE_FREE_BALLOON
    t = np.array([m.time_usec for m in wc])
    assert np.all(np.diff(t) == 100_000) and t[-1] == 149_990_000 - 90_000
    last = wc[-1]
    assert math.isnan(last.wind_z) and last.vert_accuracy == 0.0
    assert math.hypot(last.wind_x, last.wind_y) == pytest.approx(3.0, abs=1.0)
    assert 0.05 < last.horiz_accuracy < 2.0
    assert 80.0 < last.wind_alt < 100.0
    assert math.isnan(wc[500].var_horiz) and 0.0 < last.var_horiz < 2.0  # known after 60 s in flight
    assert wc[0].get_srcSystem() == 1 and wc[0].get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1


def frames(tlog):
    stats = LinkStats()
    return [bytes(m.get_msgbuf()) for m in tlog_messages(str(tlog), stats)]


@pytest.mark.slow
def test_raw_capture_with_garbage_and_corrupt_frames(flight):
    """Line noise, bit errors and frames cut short in a raw capture: every intact frame is taken (a start byte in the
    noise does not swallow the frames after it, as pymavlink's own parser lets it), each corrupted whole frame is a
    bad frame, and the noise is counted as garbage (a frame cut short, which nothing tells from noise, with it)."""
    d, tlog = flight
    rng = random.Random(3)
    blob = bytearray()
    corrupted = intact_imu = noise = 0
    for f in frames(tlog):
        if rng.random() < 0.01:
            n = rng.randrange(1, 40)
            blob += bytes(rng.randrange(256) for _ in range(n))  # line noise
            noise += n
        f = bytearray(f)
        whole, clean = True, True
        if rng.random() < 0.01 and len(f) > 20:
            f[rng.randrange(10, len(f) - 2)] ^= 0x5A  # bit errors: CRC fails
            clean = False
        if rng.random() < 0.002:
            f = f[: len(f) // 2]  # truncated frame
            whole = False
        corrupted += whole and not clean
        intact_imu += whole and clean and f[7:10] == bytes((105, 0, 0))  # HIGHRES_IMU's message id
        blob += f
    raw = d / "capture.raw"
    raw.write_bytes(bytes(blob))
    out = d / "raw.tlog"
    r = run_fw("--in", raw, "--out", out)
    assert r.returncode == 0, r.stderr
    count = {k: int(re.search(rf"(\d+) {k}", r.stderr).group(1))
             for k in ("IMU samples", "bad frames", "garbage bytes")}  # fmt: skip
    assert count["IMU samples"] == intact_imu > 0 and " 0 rejected" in r.stderr
    assert count["bad frames"] >= corrupted > 0 and count["garbage bytes"] >= noise > 0
    last = read(out, "WIND_COV")[-1]
    assert math.hypot(last.wind_x, last.wind_y) == pytest.approx(3.0, abs=1.0)


@pytest.mark.slow
def test_hil_sensor_input(flight):
    d, tlog = flight
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    blob = bytearray()
    for m in tlog_messages(str(tlog), LinkStats()):
        if m.get_type() == "HIGHRES_IMU":
            blob += mav.hil_sensor_encode(
                m.time_usec, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, m.xmag, m.ymag, m.zmag,
                m.abs_pressure, 0.0, 0.0, m.temperature, m.fields_updated, 0,
            ).pack(mav)  # fmt: skip
    raw = d / "hil.raw"
    raw.write_bytes(bytes(blob))
    out = d / "hil.tlog"
    r = run_fw("--in", raw, "--out", out)
    assert r.returncode == 0 and "15000 IMU samples" in r.stderr
    last = read(out, "WIND_COV")[-1]
    assert math.hypot(last.wind_x, last.wind_y) == pytest.approx(3.0, abs=1.0)


def test_bad_config_is_a_clear_error(tmp_path, flight):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[filter]\nwind_walk = 3\n")
    r = run_fw("--in", flight[1], "--config", cfg)
    assert r.returncode == 2 and "wind_walk" in r.stderr
    cfg.write_text("[balloon]\nradius_m = -1.0\n")
    r = run_fw("--in", flight[1], "--config", cfg)
    assert r.returncode == 2 and "radius_m" in r.stderr


def test_config_file_shared_with_the_simulator(tmp_path):
    cfg = tmp_path / "design.toml"
    cfg.write_text("[balloon]\nradius_m = 1.15\n[wind]\nkind = 'steady'\n[truth]\nrelease_s = 3.0\n"
                   "[filter]\nturbulence_intensity = 0.12\n")  # fmt: skip
    tlog = tmp_path / "s.tlog"
    subprocess.run([sys.executable, "-m", "sim_hil", "--config", str(cfg), "--duration", "60", "--out", str(tlog)],
                   check=True, capture_output=True)  # fmt: skip
    r = run_fw("--in", tlog, "--out", tmp_path / "o.tlog", "--config", cfg)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["firmware_py", "--in", "no-such-capture.tlog"],
        ["firmware_py", "--in", "/dev/ttyNOPE0:57600"],
        ["ground_station", "listen", "/dev/ttyNOPE0:57600", "--duration", "1"],
        ["sim_hil", "--duration", "1", "--out", "udpout:no.such.host.invalid:1"],
        ["sim_hil.replay", "no-such.tlog", "--out", "udpout:127.0.0.1:9"],
    ],
)
def test_bad_endpoints_are_clear_errors(argv):
    r = subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
