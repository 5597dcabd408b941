"""The ground reference's CSV (balloon_core/groundref.py): read whole for reprocessing, tailed by the
live ground station and sent up as SCALED_PRESSURE from its system; merged into a flight by time; the
estimator's barometer zero following it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from balloon_core.config import Design
from balloon_core.groundref import read_ground_csv, scan_ground_csv, write_ground_csv
from balloon_core.samples import GroundBaroSample, MavlinkSampler
from balloon_core.wire import Decoder, LinkStats
from firmware_py.estimator.control import Estimator
from ground_station.listen import GroundStation
from postflight.flight import KIND_BARO, KIND_GROUND, KIND_IMU, N_VALUES, Flight


def test_csv_round_trip_and_errors(tmp_path):
    p = tmp_path / "g.csv"
    write_ground_csv(str(p), [1.0, 2.0], [1013.2, 1013.1], [18.0, math.nan])
    g = read_ground_csv(str(p))
    assert g.time_column == "time_s" and g.time_s == [1.0, 2.0] and g.pressure_hpa == [1013.2, 1013.1]
    assert g.temperature_c[0] == 18.0 and math.isnan(g.temperature_c[1])
    (tmp_path / "u.csv").write_text("time_unix_s,pressure_hpa,wind\n1700000000.5,990.0,x\n")
    u = read_ground_csv(str(tmp_path / "u.csv"))
    assert u.time_column == "time_unix_s" and math.isnan(u.temperature_c[0])
    (tmp_path / "bad.csv").write_text("t,p\n1,2\n")
    with pytest.raises(ValueError, match="time_s"):
        read_ground_csv(str(tmp_path / "bad.csv"))
    (tmp_path / "bad2.csv").write_text("time_s,pressure_hpa\n1,ten\n")
    with pytest.raises(ValueError, match="line 2"):
        read_ground_csv(str(tmp_path / "bad2.csv"))
    (tmp_path / "back.csv").write_text("time_unix_s,pressure_hpa\n1767225600.5,990.0\n1767225599.2,990.0\n")
    with pytest.raises(ValueError, match=r"\(reading 2: 1767225599\.2 s after 1767225600\.5 s\)"):
        scan_ground_csv(str(tmp_path / "back.csv"))


def test_listen_sends_the_newest_reading_once_from_its_system(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("time_s,pressure_hpa,temperature_c\n1,1013.20,18.5\n")
    gs = GroundStation(ground_pressure=str(p), sysid=250)
    frame = gs.ground_reference()
    assert gs.ground_reference() is None  # nothing new
    with open(p, "a") as fh:
        fh.write("2,1013.10,18.4\n")
    second = gs.ground_reference()
    (m,) = Decoder(LinkStats()).feed(frame)
    assert m.get_type() == "SCALED_PRESSURE" and m.get_srcSystem() == 250
    (s,) = MavlinkSampler(ground_sysid=250).convert(m)
    assert type(s) is GroundBaroSample and s.pressure_hpa == pytest.approx(1013.2) and s.temperature_c == 18.5
    (m2,) = Decoder(LinkStats()).feed(second)
    assert m2.press_abs == pytest.approx(1013.1)
    gs.close()


def test_ground_readings_merge_into_a_flight_by_time():
    kind = np.array([KIND_BARO, KIND_IMU, KIND_IMU, KIND_GROUND], np.int8)
    t = np.array([0, 0, 10_000, 10_000], np.int64)
    f = Flight(kind, t, np.zeros((4, N_VALUES)), meta=None)
    g = f.with_ground(np.array([5_000, 20_000]), np.array([1000.0, 1001.0]), np.array([10.0, math.nan]))
    assert list(g.kind) == [KIND_BARO, KIND_IMU, KIND_GROUND, KIND_IMU, KIND_GROUND]  # the log's own replaced
    assert list(g.t_us) == [0, 0, 5_000, 10_000, 20_000]
    grounds = [s for s in g.samples() if type(s) is GroundBaroSample]
    assert [s.pressure_hpa for s in grounds] == [1000.0, 1001.0]


def test_barometer_zero_follows_the_ground_and_an_offset_cancels():
    """After the zero, p_ref moves by the ground's relative change; a ground barometer reading 0.5 hPa
    high throughout changes nothing (only its change enters)."""
    est = Estimator(Design())
    est.on_ground_baro(0, 1013.75, 20.0)  # before the zero: low-passed, not applied
    est.on_imu(0, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    for k in range(1, 150):
        t = k * 10_000
        if k % 5 == 0:
            est.on_baro(t, 1013.25, 20.0)
        est.on_imu(t, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0.2, 0.0, 0.45)
    assert not est._zeroing and est.p_ref_pa == pytest.approx(101325.0)
    est.on_ground_baro(est.t_last_us, 1013.75, 20.0)
    assert est.p_ref_pa == pytest.approx(101325.0)  # the first reference after the zero fixes p_g0
    t = est.t_last_us
    for k in range(1, 200):  # the ground falls 1 hPa: p_ref follows (low-passed over 10 s)
        est.on_ground_baro(t + k * 1_000_000, 1012.75, 20.0)
    assert est.p_ref_pa == pytest.approx(101325.0 * 1012.75 / 1013.75, abs=0.5)
