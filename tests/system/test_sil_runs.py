"""balloon-sil for any run: a short one scores what it can or says it is too short (exit 0); Ctrl-C at the
terminal (SIGINT to the whole process group) says "interrupted" and exits 130, and the simulator does
not claim the whole flight; a dead child's last stderr lines are shown."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest

from balloon_core.atomic import PART
from sil.cli import MIN_SCORED_S, last_lines, score_start

pytestmark = [pytest.mark.network, pytest.mark.slow]

PY = sys.executable


def test_score_start_moves_earlier_for_short_runs():
    assert score_start(600.0, None) == 120.0
    assert score_start(600.0, 300.0) == 300.0
    for d in (40.0, 60.0, 100.0, 140.0):
        s = score_start(d, None)
        assert s is not None and d - s >= MIN_SCORED_S and s >= 0.4 * d
    assert score_start(25.0, None) is None
    assert score_start(100.0, 90.0) is None


def test_last_lines_of_a_dead_child():
    text = "starting\n" + "".join(f"line {i}\n" for i in range(10)) + "ValueError: boom\n"
    shown = last_lines(text)
    assert shown.splitlines()[-1].strip() == "ValueError: boom" and len(shown.splitlines()) == 5
    assert "nothing" in last_lines("")


def sil(tmp_path, *args, **kw):
    return subprocess.Popen([PY, "-m", "sil.cli", "--outdir", str(tmp_path), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)  # fmt: skip


def test_too_short_to_score_is_not_a_failure(tmp_path):
    out, err = sil(tmp_path, "--duration", "20", "--speed", "20").communicate(timeout=60)
    assert "too short to score" in out, out + err
    assert "Traceback" not in err


def test_short_run_is_scored_from_an_earlier_start(tmp_path):
    p = sil(tmp_path, "--duration", "50", "--speed", "25")
    out, err = p.communicate(timeout=90)
    assert p.returncode == 0, out + err
    m = re.search(r"\| (\d+) s scored \(from ([\d.]+) s\)", out)
    assert m and int(m.group(1)) >= MIN_SCORED_S - 1 and float(m.group(2)) < 50


def test_ctrl_c_at_the_terminal_is_interrupted_130(tmp_path):
    p = sil(tmp_path, "--duration", "600", "--speed", "5", start_new_session=True)
    banner = p.stdout.readline()
    assert "sim -> udp" in banner
    # the ground station's log, written under its temporary name until the run ends (balloon_core/atomic.py)
    pattern = f".paper-reference-seed1-wind{PART}*.csv"
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and not any(f.stat().st_size > 0 for f in tmp_path.glob(pattern)):
        time.sleep(0.2)  # the first estimates are written: the simulator is in its paced run
    assert any(tmp_path.glob(pattern)), "no estimate in 60 s"
    os.killpg(p.pid, signal.SIGINT)  # what Ctrl-C does: the whole foreground process group
    out, err = p.communicate(timeout=30)
    assert p.returncode == 130, out + err
    assert "interrupted" in err and "cannot score" not in err
    said = re.search(r"(\d+) s simulated", err)
    assert said and int(said.group(1)) < 600, err
