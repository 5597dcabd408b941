"""The live view in a real terminal: ``balloon-gs listen`` in a tmux pane at 80x24 and 200x50, two
balloons (system ids) feeding WIND_COV, HEARTBEAT and SYS_STATUS over loopback UDP. Every line fits the
width, the key fields show, and STALE appears once the feed stops. Skipped when tmux is missing.

``BALLOON_SAVE_CAPTURES=docs`` saves the captures as docs/live-<W>x<H>.txt."""

from __future__ import annotations

import math
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
import uuid

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack

PY = sys.executable
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TMUX = shutil.which("tmux")
TEXT = "wind uncertain: model misfit accel (accuracy x1.4)"  # balloon-fw's STATUSTEXT, 50 characters
pytestmark = [pytest.mark.terminal, pytest.mark.skipif(TMUX is None, reason="tmux is not installed")]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Feed(threading.Thread):
    """Two balloons, sysid 1 (taut, 1 reset, 0.5 % input loss, its accelerometer flagged by the consistency
    monitor: health bit cleared and a STATUSTEXT) and sysid 7 (free), 10 Hz WIND_COV with 1 Hz HEARTBEAT +
    SYS_STATUS; sysid 7 drops one WIND_COV in 20 on the way (the ground station counts it)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.stop = threading.Event()

    def run(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        mavs = {1: mavlink.MAVLink(None, srcSystem=1, srcComponent=1),
                7: mavlink.MAVLink(None, srcSystem=7, srcComponent=1)}  # fmt: skip
        k = 0
        while not self.stop.is_set():
            t_us = 200_000_000 + k * 100_000
            for sysid, mav in mavs.items():
                frames = []
                if k % 10 == 0:
                    mode = 2 if sysid == 1 else 1
                    hb = mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, mode, 4)
                    one = sysid == 1
                    sensors = 15 | mavlink.MAV_SYS_STATUS_AHRS
                    health = sensors & ~mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL if one else sensors
                    st = mav.sys_status_encode(sensors, sensors, health, 0, 0xFFFF, -1, -1, 50 if one else 0, 0, 3,
                                               int(one), 0, 0)  # fmt: skip
                    frames += [pack(mav, hb), pack(mav, st)]
                    if one and k == 0:
                        frames.append(pack(mav, mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, TEXT.encode())))
                n, e = (3.0 + 0.3 * math.sin(k / 20), -1.0) if sysid == 1 else (-2.0, 4.0 + 0.5 * math.cos(k / 15))
                frames.append(pack(mav, mav.wind_cov_encode(t_us, n, e, math.nan, 0.42, 0.0, 112.0, 0.31, 0.0)))
                if sysid == 7 and k % 20 == 5:
                    frames.pop()  # lost on the way
                for f in frames:
                    sock.sendto(f, ("127.0.0.1", self.port))
            k += 1
            time.sleep(0.1)
        sock.close()


def tmux(sock: str, *args: str) -> str:
    return subprocess.run([TMUX, "-L", sock, *args], check=True, capture_output=True, text=True).stdout


def capture(sock: str) -> list[str]:
    # -J joins wrapped lines: a line too long for the pane comes back longer than the width
    return tmux(sock, "capture-pane", "-p", "-J", "-t", "gs").rstrip("\n").split("\n")


def listening(sock: str, timeout_s: float = 30.0) -> None:
    """Until the ground station draws its header (its socket is bound before): the balloon's one STATUSTEXT,
    sent first, must not go to a port nobody listens on yet, however slowly the program starts."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if any(ln.startswith("balloon-gs") for ln in capture(sock)):
            return
        time.sleep(0.1)
    raise AssertionError("the ground station never drew its view")


@pytest.mark.parametrize("width,height", [(80, 24), (200, 50)])
def test_listen_view_fits_and_marks_stale(width, height):
    port = free_port()
    sock = f"balloon-test-{uuid.uuid4().hex[:8]}"
    cmd = f"cd {ROOT} && exec {PY} -m ground_station listen udpin:127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMUX")}
    subprocess.run([TMUX, "-L", sock, "-f", "/dev/null", "new-session", "-d", "-s", "gs", "-x", str(width),
                    "-y", str(height), cmd], check=True, env=env)  # fmt: skip
    feed = Feed(port)
    try:
        listening(sock)
        feed.start()
        time.sleep(3.5)
        live = capture(sock)
        feed.stop.set()
        feed.join()
        time.sleep(3.0)
        stale = capture(sock)
    finally:
        feed.stop.set()
        subprocess.run([TMUX, "-L", sock, "kill-server"], capture_output=True)
    save = os.environ.get("BALLOON_SAVE_CAPTURES")
    if save:
        with open(os.path.join(ROOT, save, f"live-{width}x{height}.txt"), "w") as fh:
            fh.write("\n".join(live).rstrip() + "\n\n" + "\n".join(stale).rstrip() + "\n")
    text = "\n".join(live)
    assert all(len(line) <= width for line in live + stale), max(live + stale, key=len)
    assert len(live) <= height
    rows = {int(ln.split()[0]): ln for ln in live if ln.split() and ln.split()[0] in ("1", "7")}
    assert set(rows) == {1, 7}, text
    assert "taut" in rows[1] and "free" in rows[7] and "MISFIT" in rows[1] and "OK" in rows[7]
    said = [ln for ln in live if ln.startswith("sys 1: ")]
    assert len(said) == 1 and said[0].startswith(f"sys 1: {TEXT} (WARNING, "), text  # the balloon's message
    assert not any(ln.startswith("sys 7: ") for ln in live)
    assert 3.1 < float(rows[1].split()[1 if width < 110 else 2]) < 3.5  # |(3 + 0.3 sin, -1)| m/s
    assert "0.31" in rows[1]  # accuracy
    assert "0.5" in rows[1]  # the balloon's own input loss, %
    for word in ("mode", "lost", "STALE"):
        assert word in text, word  # the header names the columns; the footer explains STALE
    words = rows[7].split()
    assert int(words[words.index("OK") - 1].rstrip("s")) <= 2  # heartbeat age
    srows = [ln for ln in stale if ln.split() and ln.split()[0] in ("1", "7")]
    assert len(srows) == 2 and all("STALE" in ln for ln in srows), "\n".join(stale)
    assert any(ln.startswith(f"sys 1: {TEXT}") for ln in stale)  # the message stays
    if width >= 200:
        assert 2.6 < float(rows[1].split()[4]) < 3.4 and "0.42" in rows[1]  # N component, variability: wide only
        assert any(c in rows[1] for c in "▁▂▃▄▅▆▇█")  # the sparkline


@pytest.mark.slow
@pytest.mark.network
def test_sil_header_stays_above_the_live_view(tmp_path):
    """Under balloon-sil on a terminal: sil's own header (with the ports) first, then the ground station's
    live view drawn in place below it, once (no copy of a first frame left above the table)."""
    sock = f"balloon-test-{uuid.uuid4().hex[:8]}"
    cmd = f"cd {ROOT} && {PY} -m sil --duration 40 --speed 10 --outdir {tmp_path}; sleep 60"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TMUX")}
    subprocess.run([TMUX, "-L", sock, "-f", "/dev/null", "new-session", "-d", "-s", "gs", "-x", "100", "-y", "30",
                    cmd], check=True, env=env)  # fmt: skip
    try:
        time.sleep(6.0)  # the view has been redrawn many times by now
        screen = capture(sock)
    finally:
        subprocess.run([TMUX, "-L", sock, "kill-server"], capture_output=True)
    text = "\n".join(screen)
    assert screen[0].startswith("balloon-sil: paper-reference, 40 s at 10x") and "-> fw -> udp:" in screen[0], text
    assert sum(ln.startswith("balloon-gs ") for ln in screen) == 1, text
    assert sum(ln.split()[:2] == ["sys", "wind"] for ln in screen if ln.split()) == 1, text
