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
