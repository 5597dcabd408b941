"""``balloon-gs level``: the IMU's mounting from a recording of the payload hung still. The simulator's balloon rests
upright on its ground station before the release ([truth] release_s, 5 s), so the first seconds of a flight whose
truth has the IMU askew ([truth] imu_roll_deg, imu_pitch_deg) are that recording: the tool finds the truth's mounting,
in the lines the design takes ([sensors] the same keys); a stretch that is not still, or too short, is a user error
(exit 2, one line)."""

from __future__ import annotations

import subprocess
import sys
import tomllib

import pytest

PY = sys.executable


def hung(tmp_path, roll: float, pitch: float, seconds: float = 6.0) -> str:
    cfg = tmp_path / "askew.toml"
    cfg.write_text(f"[truth]\nimu_roll_deg = {roll}\nimu_pitch_deg = {pitch}\n")
    out = tmp_path / "hang.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--config", str(cfg), "--duration", str(seconds), "--seed", "2", "--out",
                    str(out)], check=True, capture_output=True, timeout=60)  # fmt: skip
    return str(out)


def level(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "ground_station", "level", *args], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(("roll", "pitch"), [(1.5, -0.8), (-2.5, 3.0)])
def test_the_mounting_of_a_payload_hung_still(tmp_path, roll, pitch):
    p = level(hung(tmp_path, roll, pitch), "--to", "4.5")
    assert p.returncode == 0, p.stderr
    sensors = tomllib.loads(p.stdout)["sensors"]  # the lines a design file takes as they are
    assert sensors["imu_roll_deg"] == pytest.approx(roll, abs=0.02)
    assert sensors["imu_pitch_deg"] == pytest.approx(pitch, abs=0.02)


def test_a_payload_that_is_not_still_or_a_stretch_too_short_is_refused(tmp_path):
    path = hung(tmp_path, 1.0, 1.0, 12.0)
    for args, said in (((), "not hanging still"), (("--from", "8"), "not hanging still"),
                       (("--from", "30"), "IMU samples from 30 s"), (("--to", "0.5"), "at least 100")):  # fmt: skip
        p = level(path, *args)
        assert p.returncode == 2 and said in p.stderr and len(p.stderr.strip().splitlines()) == 1, (args, p.stderr)
        assert p.stdout == ""
