"""balloon_core/fastmav.py, the firmware's small decoder, against pymavlink (balloon_core/wire.py with
``fast=False``): on the frozen flights' tlogs, on a tlog of every message it decodes (MAVLink 2 and 1,
signed, zero-truncated, with extensions), and on those bytes corrupted, cut and mixed with garbage,
the same messages (type, header, every field) come out, and the same counts (frames, bad frames,
garbage bytes, lost, per-sender sequence counters)."""

from __future__ import annotations

import gzip
import math
import random
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core import fastmav
from balloon_core.wire import TLOG_HEADER, LinkStats, pack, tlog_messages
from tests.helpers.damage import damaged

DATA = Path(__file__).resolve().parents[1] / "data"
TLOGS = ["golden/paper-reference.tlog.gz", "golden/join-in-flight.tlog.gz", "golden/reduced-balloon.tlog.gz"]

pytestmark = pytest.mark.skipif(not fastmav.TABLE, reason="no fastcrc: no fast path")


def fields(m) -> tuple:
    d = m.to_dict()
    d.pop("mavpackettype")
    vals = tuple(sorted((k, "nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in d.items()))
    return (m.get_type(), m.get_msgId(), m.get_srcSystem(), m.get_srcComponent(), m.get_seq(), vals)


def stats_tuple(st: LinkStats) -> tuple:
    senders = {k: (s.received, s.lost, s.reordered, s.duplicates, s.restarts) for k, s in st.senders.items()}
    return (st.bytes, st.frames, st.bad_frames, st.garbage_bytes, st.lost, st.truncated, senders)


def both(path: Path) -> tuple[list, list]:
    out = []
    for fast in (False, True):
        st = LinkStats()
        msgs = [fields(m) for m in tlog_messages(str(path), st, chunk=4096, fast=fast)]
        out.append((msgs, stats_tuple(st)))
    return out[0], out[1]


def every_message_tlog() -> bytes:
    """Records of each message fastmav decodes, and others, in MAVLink 2 (signed or not) and 1."""
    rng = random.Random(5)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_IMU)
    signed = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    signed.signing.secret_key = bytes(range(32))
    signed.signing.sign_outgoing = True
    signed.signing.link_id = 0
    signed.signing.timestamp = 1
    out = bytearray()
    for i in range(300):
        t = 1_000_000 + 10_000 * i
        f = [rng.uniform(-20, 20) for _ in range(13)]
        msgs = [
            mav.highres_imu_encode(t, *f[:9], 1000.0 + f[9], 0.0, 0.0, 20.0, 0x1FFF if i % 3 else 0x1FF, 0),
            mav.hil_sensor_encode(t, *f[:9], 1000.0, 0.0, 0.0, 20.0, 0x1FFF, i % 2),
            mav.scaled_imu_encode(t // 1000, *(rng.randint(-30000, 30000) for _ in range(9)), rng.randint(-300, 300)),
            mav.scaled_imu2_encode(t // 1000, *(rng.randint(-30000, 30000) for _ in range(9)), 0),
            mav.scaled_imu3_encode(t // 1000, *(0 for _ in range(9)), 0),  # all zeros: cut to one byte
            mav.scaled_pressure_encode(t // 1000, 1001.5 + f[0], 0.0, 2150, 0),
            mav.scaled_pressure2_encode(t // 1000, 1002.5, f[1], -100, 7),
            mav.scaled_pressure3_encode(t // 1000, 0.0, 0.0, 0, 0),
            mav.winch_status_encode(t, 100.0 + f[2], 0.1, math.nan, math.nan, math.nan, 0, 3),
            mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4),
            mav.wind_cov_encode(t, *f[:8]),
        ]
        for k, msg in enumerate(msgs):
            if k == 3 and i % 4 == 0:
                frame = msg.pack(signed)
                signed.seq = (signed.seq + 1) % 256
            elif k == 5 and i % 5 == 0:
                frame = msg.pack(mav, force_mavlink1=True)
                mav.seq = (mav.seq + 1) % 256
            else:
                frame = pack(mav, msg)
            out += struct.pack(">Q", t) + frame
    return bytes(out)


@pytest.mark.parametrize("name", TLOGS)
def test_recorded_flights_decode_as_pymavlink(name, tmp_path):
    p = tmp_path / "f.tlog"
    p.write_bytes(gzip.decompress((DATA / name).read_bytes()))
    (ref_msgs, ref_st), (fast_msgs, fast_st) = both(p)
    assert fast_msgs == ref_msgs and fast_st == ref_st
    assert len(ref_msgs) > 1000


def test_every_message_and_framing_decodes_as_pymavlink(tmp_path):
    p = tmp_path / "all.tlog"
    data = every_message_tlog()
    p.write_bytes(data)
    (ref_msgs, ref_st), (fast_msgs, fast_st) = both(p)
    assert fast_msgs == ref_msgs and fast_st == ref_st
    types = {m[0] for m in ref_msgs}
    assert {"HIGHRES_IMU", "HIL_SENSOR", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "SCALED_PRESSURE",
            "SCALED_PRESSURE2", "SCALED_PRESSURE3", "WINCH_STATUS", "HEARTBEAT", "WIND_COV"} <= types  # fmt: skip
    # the fast path took them: v1, signed and truncated frames included
    decoded = 0
    i = 0
    while i + TLOG_HEADER < len(data):
        j = i + TLOG_HEADER
        ln = (12 + data[j + 1] + (13 if data[j + 2] & 1 else 0)) if data[j] == 0xFD else 8 + data[j + 1]
        decoded += fastmav.decode(data[j : j + ln]) is not None
        i = j + ln
    assert decoded == 9 * 300


@pytest.mark.parametrize("seed", range(6))
def test_corrupted_and_garbage_bytes_decode_as_pymavlink(seed, tmp_path):
    rng = random.Random(seed)
    data = damaged(every_message_tlog(), rng, flips=60, inserts=10, drops=5)
    p = tmp_path / "bad.tlog"
    p.write_bytes(data)
    (ref_msgs, ref_st), (fast_msgs, fast_st) = both(p)
    assert fast_msgs == ref_msgs and fast_st == ref_st
    assert ref_st[2] > 0  # bad frames were met


def test_pure_garbage_and_single_frames():
    rng = random.Random(1)
    for _ in range(2000):
        frame = bytes(rng.choice((0xFD, 0xFE)) if k == 0 else rng.randrange(256) for k in range(rng.randrange(0, 60)))
        m = fastmav.decode(frame)
        if m is None:
            continue
        ref = mavlink.MAVLink(None).decode(bytearray(frame))  # what fastmav took, pymavlink takes alike
        assert fields(m) == fields(ref)
