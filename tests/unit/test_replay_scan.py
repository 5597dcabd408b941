"""firmware_py/replay.py, balloon-fw's tlog replay through the C scanner (firmware_c/host/tlog.c), against
the ordinary path (``wire.tlog_messages`` + ``Firmware.handle``, fastmav's and pymavlink's decoding): on the
frozen flights' tlogs, on them with records lost, repeated, swapped and restarted, and with their bytes
corrupted, cut and mixed with garbage, the same output frames (bytes and times), the same summary and the
same link counts (frames, bad frames, garbage bytes, per-sender sequence counters) come out."""

from __future__ import annotations

import gzip
import random
from pathlib import Path

import pytest

from balloon_core.config import Design
from balloon_core.wire import TLOG_HEADER, LinkStats, frame_length, tlog_messages
from firmware_py.app import Firmware, OutputConfig
from firmware_py.estimator.state import FilterConfig
from firmware_py.replay import replay_tlog, scanner
from tests.helpers.damage import damaged

DATA = Path(__file__).resolve().parents[1] / "data"
TLOGS = ["golden/paper-reference.tlog.gz", "golden/join-in-flight.tlog.gz", "golden/reduced-balloon.tlog.gz"]

SCAN = scanner()
pytestmark = pytest.mark.skipif(SCAN is None, reason="no C core or no fastcrc: no scanner")


class Sink:
    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []

    def send_at(self, frame: bytes, t_us: int) -> None:
        self.frames.append((t_us, bytes(frame)))


def stats_tuple(st: LinkStats) -> tuple:
    senders = {k: (s.received, s.lost, s.reordered, s.duplicates, s.restarts) for k, s in st.senders.items()}
    return (st.bytes, st.frames, st.bad_frames, st.garbage_bytes, st.lost, st.truncated, senders)


def replay(path: Path, how: str, chunk: int = 1 << 20, outputs: OutputConfig | None = None) -> tuple:
    sink = Sink()
    fw = Firmware(Design(), FilterConfig(core="c"), sink, outputs=outputs)
    fw.use_batches()
    if how == "scan":
        assert replay_tlog(fw, str(path), SCAN, chunk=chunk)
    else:  # the ordinary path: fastmav + pymavlink ("fast"), or pymavlink alone
        for m in tlog_messages(str(path), fw.stats, chunk=chunk, fast=how == "fast"):
            fw.handle(m)
    fw.flush()
    return sink.frames, fw.summary(), stats_tuple(fw.stats), fw.samples_in


def same_three_ways(path: Path, chunk: int = 1 << 20) -> tuple:
    ref = replay(path, "pymavlink", chunk)
    assert replay(path, "fast", chunk) == ref
    assert replay(path, "scan", chunk) == ref
    return ref


def records(data: bytes) -> list[bytes]:
    out, i = [], 0
    while i + TLOG_HEADER < len(data):
        ln = frame_length(data, i + TLOG_HEADER)
        out.append(data[i : i + TLOG_HEADER + ln])
        i += TLOG_HEADER + ln
    return out


def flight(name: str) -> bytes:
    return gzip.decompress((DATA / name).read_bytes())


@pytest.mark.parametrize("name", TLOGS)
def test_recorded_flights_replay_alike(name, tmp_path):
    p = tmp_path / "f.tlog"
    p.write_bytes(flight(name))
    frames, _, st, samples = same_three_ways(p)
    assert len(frames) > 1000 and samples > 5000 and st[1] > 5000
    calls = []  # the scanner took the sensor frames itself: a call for each output, not each frame

    def counted(*args):
        calls.append(1)
        return SCAN(*args)

    fw = Firmware(Design(), FilterConfig(core="c"), Sink())
    fw.use_batches()
    replay_tlog(fw, str(p), counted)
    assert len(calls) < st[1] / 5


def test_wind_after_each_wind_cov_replays_alike(tmp_path):
    """``[outputs] qgc_direction = "from"`` (WIND after every WIND_COV: all outputs packed in Python)."""
    p = tmp_path / "f.tlog"
    p.write_bytes(flight(TLOGS[0]))
    ref = replay(p, "pymavlink", outputs=OutputConfig("from"))
    assert replay(p, "scan", outputs=OutputConfig("from")) == ref
    assert sum(1 for _, f in ref[0] if f[7] == 168) > 1000  # WIND after each WIND_COV


@pytest.mark.parametrize("seed", range(4))
def test_lost_repeated_swapped_and_restarted_records_replay_alike(seed, tmp_path):
    rng = random.Random(seed)
    recs = records(flight(TLOGS[seed % len(TLOGS)]))
    out = []
    for k, r in enumerate(recs):
        u = rng.random()
        if u < 0.01:  # lost
            continue
        if u < 0.015 and out:  # swapped with the one before (a late packet)
            out.insert(len(out) - 1, r)
            continue
        out.append(r)
        if u > 0.995:  # repeated
            out.append(r)
        if k == len(recs) // 2 and seed % 2:  # the sender restarts: its first minute again
            out.extend(recs[:6000])
    p = tmp_path / "lossy.tlog"
    p.write_bytes(b"".join(out))
    _, summary, st, _ = same_three_ways(p, chunk=1 << 14)
    assert st[4] > 0 and "duplicated" in summary


@pytest.mark.parametrize("seed", range(6))
def test_corrupted_and_garbage_bytes_replay_alike(seed, tmp_path):
    rng = random.Random(seed)
    data = damaged(flight(TLOGS[seed % len(TLOGS)]), rng, flips=200, inserts=40, drops=20)
    p = tmp_path / "bad.tlog"
    p.write_bytes(bytes(data))
    _, _, st, _ = same_three_ways(p, chunk=rng.choice((4096, 1 << 20)))
    assert st[2] > 0 and st[3] > 0  # bad frames and garbage were met


def test_garbage_only_and_empty_files(tmp_path):
    rng = random.Random(3)
    for k, data in enumerate((b"", bytes(5), bytes(rng.randrange(256) for _ in range(5000)),
                              bytes(rng.choice((0xFD, 0xFE, 0)) for _ in range(3000)))):  # fmt: skip
        p = tmp_path / f"g{k}.tlog"
        p.write_bytes(data)
        same_three_ways(p, chunk=1024)


def test_fast_packer_packs_as_pymavlink():
    """balloon_core.wire.FastPacker (the firmware's WIND_COV) against pymavlink's pack: the same bytes and
    the same sequence, zeros (cut off the payload's end), NaN, infinities and subnormals included."""
    import math

    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from balloon_core.wire import FastPacker, pack

    fast = FastPacker(mavlink.MAVLink_wind_cov_message)
    a, b = (mavlink.MAVLink(None, srcSystem=1, srcComponent=1) for _ in range(2))
    rng = random.Random(1)
    for _ in range(3000):
        f = [rng.choice((0.0, -0.0, math.nan, math.inf, rng.uniform(-50, 50), 1e-40)) for _ in range(8)]
        t = rng.choice((0, 1, 2**40, rng.randrange(2**63)))
        assert fast(b, t, *f) == pack(a, a.wind_cov_encode(t, *f))
    assert (a.seq, a.total_packets_sent) == (b.seq, b.total_packets_sent)


@pytest.mark.parametrize("seed", [None, 0, 1, 2])
def test_every_fast_message_replays_alike(seed, tmp_path):
    """tests/unit/test_fastmav.py's records of every message fastmav decodes (MAVLink 2 and 1, signed,
    zero-truncated, with extensions; and others), whole and corrupted: the scanner's verdict on each
    frame (its table of CRC_EXTRA and sizes) is fastmav's and pymavlink's."""
    from tests.unit.test_fastmav import every_message_tlog

    data = bytearray(every_message_tlog())
    if seed is not None:
        rng = random.Random(seed)
        for _ in range(80):
            k = rng.randrange(len(data))
            data[k] ^= 1 << rng.randrange(8)
    p = tmp_path / "all.tlog"
    p.write_bytes(bytes(data))
    _, _, st, samples = same_three_ways(p, chunk=2048)
    assert samples > 0 and st[1] > 1000
