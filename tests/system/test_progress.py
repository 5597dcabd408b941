
"""Progress and status: a bar on a terminal, periodic lines in a pipe, nothing with --quiet; the
programs' use of it (balloon-sim, balloon-fw replay and live)."""

from __future__ import annotations

import io
import os
import re
import signal
import socket
import subprocess
import sys
import time

import pytest

from balloon_core.progress import INTERVAL_ENV, Progress, RateMeter, fmt_duration

PY = sys.executable


def test_lines_when_not_a_terminal():
    out = io.StringIO()
    with Progress("job", total=10.0, unit="s simulated", stream=out, interval_s=0.1, terminal=False) as p:
        p.update(5.0, "half way")
        time.sleep(0.35)
        p.log("a line that stays")
    text = out.getvalue()
    assert p.mode == "lines"
    lines = text.splitlines()
    status = [ln for ln in lines if ln.startswith("job:")]
    assert len(status) >= 2 and "a line that stays" in lines
    assert re.match(r"job:\s+50 % \(5/10 s simulated\), 0 s elapsed, ~0 s left \| half way", status[0])


def test_quiet_writes_nothing():
    out = io.StringIO()
    with Progress("job", total=10.0, stream=out, interval_s=0.05, quiet=True) as p:
        p.update(3.0, "x")
        p.log("dropped")
        time.sleep(0.15)
    assert p.mode == "quiet" and out.getvalue() == ""


def test_bar_on_a_terminal():
    out = io.StringIO()
    with Progress("job", total=4.0, unit="flights", stream=out, terminal=True) as p:
        p.update(1.0, "flying")
        time.sleep(0.4)
        p.log("[1/4] done")
        p.update(4.0, "finished")
    text = out.getvalue()
    assert p.mode == "bar"
    assert "\x1b[" in text and "job" in text and "100%" in text and "finished" in text and "[1/4] done" in text


def test_no_total_is_a_status():
    out = io.StringIO()
    with Progress("fw", stream=out, interval_s=0.1, terminal=False) as p:
        p.update(1234, "mode taut")
        time.sleep(0.25)
    assert re.search(r"^fw: 0 s, 1234 \| mode taut$", out.getvalue(), re.M)


def test_helpers():
    assert fmt_duration(42.4) == "42 s" and fmt_duration(185) == "3 min 05 s" and fmt_duration(3720) == "1 h 02 min"
    r = RateMeter(5.0)
    r.rate(0.0, 0)
    assert abs(r.rate(2.0, 200) - 100.0) < 1e-9


@pytest.mark.slow
def test_sim_status_lines_and_quiet(tmp_path):
    # a status line every millisecond: the simulator's 120 s take longer than that on any machine, however fast
    # (at 0.3 s, a machine that simulates them in 0.2 s printed none)
    env = {**os.environ, INTERVAL_ENV: "0.001"}
    out = tmp_path / "s.tlog"
    r = subprocess.run([PY, "-m", "sim_hil", "--duration", "120", "--out", str(out)], capture_output=True,
                       text=True, env=env, check=True)  # fmt: skip
    lines = r.stderr.strip().splitlines()
    assert any(re.match(r"balloon-sim:\s+\d+ % \(\d+/120 s simulated\)", ln) for ln in lines[:-1]), lines
    assert "IMU samples" in lines[-1]
    q = subprocess.run([PY, "-m", "sim_hil", "--duration", "120", "--out", str(out), "--quiet"], capture_output=True,
                       text=True, env=env, check=True)  # fmt: skip
    assert len(q.stderr.strip().splitlines()) == 1
    # a status line every millisecond: the replay takes longer than that on any machine, however fast
    fast = {**env, INTERVAL_ENV: "0.001"}
    f = subprocess.run([PY, "-m", "firmware_py", "--in", str(out)], capture_output=True, text=True, env=fast,
                       check=True)  # fmt: skip
    flines = f.stderr.strip().splitlines()
    pattern = r"balloon-fw:\s+\d+ % \([\d.]+/[\d.]+ MB\).*\| \d+ lost .*, mode \w+, wind"
    assert any(re.match(pattern, ln) for ln in flines[:-1]), flines
    assert "12000 IMU samples" in flines[-1] and "input packets 0 lost" in flines[-1]


@pytest.mark.network
def test_firmware_live_status_line(tmp_path):
    cap = tmp_path / "s.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--duration", "40", "--out", str(cap), "--quiet"], check=True)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, INTERVAL_ENV: "0.5"}
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{port}"], stderr=subprocess.PIPE,
                          text=True, env=env)  # fmt: skip
    time.sleep(0.6)
    subprocess.run([PY, "-m", "sim_hil.replay", str(cap), "--out", f"udpout:127.0.0.1:{port}", "--speed", "10",
                    "--lockstep", "--quiet"], check=True, capture_output=True, timeout=30)  # fmt: skip
    fw.send_signal(signal.SIGINT)
    fw.wait(10)
    lines = fw.stderr.read().strip().splitlines()
    assert lines[-1].startswith("balloon-fw: interrupted (Ctrl-C)") and fw.returncode == 130
    lines = lines[:-1]  # the summary, before the line that says it was interrupted
    live = [ln for ln in lines[:-1] if "msg/s" in ln]
    assert live, lines
    m = re.search(r"in (\d+) msg/s \((\d+) IMU/s\), (\d+) lost \([\d.]+ %\), (\d+) IMU missing, (\d+) long gaps, "
                  r"mode (\w+), wind ([\d.]+) m/s from \d+ deg ±([\d.]+)", "\n".join(live))  # fmt: skip
    assert m, live
    assert any(int(x) > 100 for x in re.findall(r"\((\d+) IMU/s\)", "\n".join(live)))  # 10x: ~1000 IMU/s
    assert "taut" in "\n".join(live) and "4000 IMU samples" in lines[-1]
