"""balloon-fw's file replay hands the C core blocks of samples (``Firmware.use_batches``,
firmware_c/host/batch.c): its output is the output of one call a sample, byte for byte, and so are its
counters, on the frozen flights (a restart in flight, the hostile serial capture) and on a stream made
to need every exit of a block: a 200 Hz stream averaged down, duplicates, late samples, a reboot,
rejected samples; in float32 and float64."""

from __future__ import annotations

import dataclasses
import gzip
import math
from pathlib import Path

import pytest

from balloon_core.config import Design
from balloon_core.wire import TlogWriter, capture_messages
from firmware_py.app import Firmware
from firmware_py.estimator.state import FilterConfig
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden"


class Recorder:
    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []

    def send_at(self, data: bytes, t_us: int) -> None:
        self.frames.append((t_us, data))


def replay(path: str, float32: bool, batches: bool) -> tuple[list, str, tuple]:
    sink = Recorder()
    fw = Firmware(Design(), FilterConfig(core="c", float32=float32), sink=sink)
    if batches:
        fw.use_batches()
    for m in capture_messages(path, fw.stats, fast=True):
        fw.handle(m)
    fw.flush()
    return sink.frames, fw.summary(), (fw.flight_steps, tuple(fw.misfit_steps), fw.texts_sent, fw.imu_missing)


def hostile_stream(path: Path) -> None:
    """200 Hz (averaged to the filter's 100 Hz) with duplicates, late samples, a reboot at 40 s and
    rejected samples."""
    sc = SCENARIOS["paper-reference"]
    samples = list(Simulation(sc.design, sc.wind, sc.truth, 70.0, 3, imu_hz=200.0).samples())
    out = []
    for i, s in enumerate(samples):
        if s.time_usec >= 40_000_000:  # the sender reboots: its clock starts again
            s = dataclasses.replace(s, time_usec=s.time_usec - 39_000_000)
        if i % 997 == 5:
            s = dataclasses.replace(s, accel=(math.nan, 0.0, 0.0))
        out.append(s)
        if i % 503 == 7:
            out.append(s)  # a duplicate
    for k in range(1000, len(out) - 3, 1733):  # late samples
        out[k], out[k + 2] = out[k + 2], out[k]
    enc = SensorPacketEncoder()
    with open(path, "wb") as fh:
        w = TlogWriter(fh)
        for s in out:
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)


@pytest.mark.parametrize("float32", [False, True])
@pytest.mark.parametrize("name", ["join-in-flight.tlog", "reduced-balloon.tlog", "hostile.raw", "made"])
def test_batches_give_the_same_bytes_and_counts(name, float32, tmp_path):
    path = tmp_path / name
    if name == "made":
        path = tmp_path / "made.tlog"
        hostile_stream(path)
    else:
        path.write_bytes(gzip.decompress((GOLDEN / f"{name}.gz").read_bytes()))
    one = replay(str(path), float32, batches=False)
    blocks = replay(str(path), float32, batches=True)
    assert len(one[0]) > 100
    assert blocks == one
    if name == "made":
        assert "1 reboot" in one[1] and "averaged" in one[1]
