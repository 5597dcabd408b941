"""The simulator's HIGHRES_IMU frames, packed without pymavlink's message objects (sim_hil/packets.py
``_frame``), are the bytes pymavlink packs: header, trailing zeros cut, CRC with the message's extra,
the sequence number running on."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack
from sim_hil.packets import HIGHRES_ACC_GYRO_MAG, SensorPacketEncoder
from sim_hil.simulator import SensorSample


def test_highres_imu_frames_are_pymavlinks():
    enc = SensorPacketEncoder()
    ref = mavlink.MAVLink(None, srcSystem=enc.mav.srcSystem, srcComponent=enc.mav.srcComponent)
    for i in range(600):  # the sequence wraps; a heartbeat a second, a barometer sample every fifth
        t = 10_000 * i
        a = (0.1 * i, -0.0, 9.81 if i % 3 else 0.0)
        g = (1e-7 * i, 0.0, -1e30 if i == 7 else 0.5)
        m = (0.2, math.nan if i == 11 else 0.0, 0.0)
        baro = (1001.5 - 0.01 * i, 15.0) if i % 5 == 0 else None
        frames = enc.encode(SensorSample(t, a, g, m, baro))
        hr = [f for f in frames if f[7] | f[8] << 8 | f[9] << 16 == mavlink.MAVLINK_MSG_ID_HIGHRES_IMU]
        assert len(hr) == 1
        ref.seq = hr[0][4]
        hpa, temp = enc._last_baro
        upd = HIGHRES_ACC_GYRO_MAG | (0x1200 if baro else 0)
        want = pack(ref, ref.highres_imu_encode(t, *a, *g, *m, hpa, 0.0, 0.0, temp, upd, 0))
        assert hr[0] == want
    assert enc.mav.seq == (600 + 6 + 120) % 256  # one a frame: IMU samples, heartbeats, barometer samples
