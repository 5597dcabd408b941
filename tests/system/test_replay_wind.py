"""balloon-replay plays a recorded wind (a firmware output log: WIND_COV, WIND, ESTIMATOR_STATUS and no sensor
sample) to any MAVLink endpoint, every record at its recorded time or N times faster: a past flight shown live."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import LinkStats, tlog_messages
from sim_hil import replay

PY = sys.executable
pytestmark = pytest.mark.network


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_recorded_wind_replays_to_a_ground_station(tmp_path, capsys):
    sensors, out = tmp_path / "s.tlog", tmp_path / "fw.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--scenario", "paper-reference", "--duration", "20", "--seed", "1",
                    "--out", str(sensors), "--quiet"], check=True, capture_output=True)  # fmt: skip
    subprocess.run([PY, "-m", "firmware_py", "--in", str(sensors), "--out", str(out), "--quiet"], check=True,
                   capture_output=True)  # fmt: skip
    recorded = [m for m in tlog_messages(str(out), LinkStats()) if m.get_type() in ("WIND_COV", "WIND")]
    n_cov = sum(m.get_type() == "WIND_COV" for m in recorded)
    assert n_cov > 150
    port = free_port()
    got: list = []
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(3.0)
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True

    def receive() -> None:
        try:
            while True:
                for m in mav.parse_buffer(sock.recv(65536)) or []:
                    if m.get_type() in ("WIND_COV", "WIND"):
                        got.append(m)
        except OSError:
            pass

    th = threading.Thread(target=receive, daemon=True)
    th.start()
    rc = replay.main([str(out), "--out", f"udpout:127.0.0.1:{port}", "--speed", "10", "--quiet"])
    th.join(5.0)
    sock.close()
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "a recorded wind" in err and f"sent to udpout:127.0.0.1:{port} at 10x" in err
    # every WIND_COV and WIND arrives, the same values in the same order
    assert [(m.get_type(), getattr(m, "wind_x", getattr(m, "direction", None))) for m in got] == [
        (m.get_type(), getattr(m, "wind_x", getattr(m, "direction", None))) for m in recorded
    ]
    # --lockstep has no firmware to wait for: one line, exit 2
    assert replay.main([str(out), "--out", f"udpout:127.0.0.1:{port}", "--lockstep"]) == 2
    assert "no firmware to wait for" in capsys.readouterr().err


def test_a_damaged_record_time_is_not_waited_for(tmp_path, capsys):
    """One record whose 8-byte time was damaged (1.15e12 s ahead, its frame whole): at --speed 100 time.sleep raised
    OverflowError (a traceback); at --speed 10000 the replay slept 3.6 years. Now the record is sent, not paced on,
    and counted in the last line."""
    from tests.system.test_ground_station import _damage_stamp, _recording

    tlog, _ = _recording(tmp_path)
    damaged = tmp_path / "damaged.tlog"
    damaged.write_bytes(_damage_stamp(tlog, 60))
    before = damaged.read_bytes()
    for speed in ("100", "10000"):
        rc = replay.main([str(damaged), "--out", f"udpout:127.0.0.1:{free_port()}", "--speed", speed, "--quiet"])
        err = capsys.readouterr().err
        assert rc == 0 and len(err.strip().splitlines()) == 1, err
        assert "a recorded wind, 201 records" in err and "1 record time damaged (sent, not paced on)" in err, err
    assert damaged.read_bytes() == before


def test_a_long_wait_for_the_next_record_stops_on_a_signal(tmp_path):
    """A recording that resumes two hours later (its records confirm the pause): the replay waits for it, and
    Ctrl-C or SIGTERM ends that wait at once (a single time.sleep ignored both: only SIGKILL stopped it)."""
    import signal
    import time

    from balloon_core.wire import TlogWriter, pack

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    path = tmp_path / "paused.tlog"
    with open(path, "wb") as fh:
        w = TlogWriter(fh)
        for t_us in (0, 100_000, 7_200_000_000, 7_200_100_000, 7_200_200_000):
            w.write(t_us, pack(mav, mav.wind_cov_encode(t_us, 1.0, 2.0, 0.0, 0.5, 0.1, 100.0, 0.4, 0.0)))
    procs = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(20.0)
        port = sock.getsockname()[1]
        p = subprocess.Popen([PY, "-m", "sim_hil.replay", str(path), "--out", f"udpout:127.0.0.1:{port}", "--speed",
                              "1", "--quiet"], stderr=subprocess.PIPE, text=True)  # fmt: skip
        procs.append((sig, sock, p))
    try:
        for _, sock, _ in procs:
            sock.recv(65536)  # the first record came: the replay runs (its handlers are in place)
            sock.recv(65536)  # the second: it now waits two hours for the third
        time.sleep(0.3)
        t0 = time.monotonic()
        for sig, _, p in procs:
            p.send_signal(sig)
        for sig, _, p in procs:
            err = p.communicate(timeout=5)[1]
            assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err, (sig, err)
        assert time.monotonic() - t0 < 3.0
    finally:
        for _, sock, p in procs:
            sock.close()
            if p.poll() is None:
                p.kill()
