"""Ground station: WIND_COV from any vehicle, direction convention, CSV round trip, report errors."""

import io
import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from firmware_py.mavio import pack
from ground_station.listen import GroundStation
from ground_station.wind import direction_from_deg, read_records


def px4_wind(seq_mav, t_us, n, e):
    return pack(seq_mav, seq_mav.wind_cov_encode(t_us, n, e, 0.0, 0.5, 0.1, 120.0, 0.0, 0.0))


def test_direction_is_where_the_wind_comes_from():
    assert direction_from_deg(0.0, 3.0) == pytest.approx(270.0)  # blowing east: from the west
    assert direction_from_deg(-2.0, 0.0) == pytest.approx(0.0)  # blowing south: from the north
    assert direction_from_deg(1.0, -1.0) == pytest.approx(135.0)


def test_any_vehicle_csv_and_losses(tmp_path):
    from firmware_py.mavio import Decoder

    px4 = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)  # a PX4 vehicle, not ours
    hb = pack(px4, px4.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4))
    frames = [hb] + [px4_wind(px4, 1_000_000 + 100_000 * i, 1.0, -1.0) for i in range(20)]
    del frames[5]  # one lost on the way
    csv = tmp_path / "w.csv"
    out = io.StringIO()
    gs = GroundStation(str(csv), str(tmp_path / "g.tlog"), out=out)
    dec = Decoder(gs.stats)
    for f in frames:
        for m in dec.feed(f):
            gs.handle(m, 0.0)
    dec.feed(b"\xfd\x09\x00\x00\x07\x2a\x01\xe7\x00\x00" + b"\x00" * 11)  # a corrupt WIND_COV
    line = gs.status_line(0.0)
    gs.close()
    assert gs.wind_count == 19 and gs.stats.lost == 1 and gs.stats.bad_frames >= 1
    assert "from 135.0 deg" in line and "mode ?" in line
    recs = read_records(str(csv))
    assert len(recs) == 19 and recs[0].sysid == 42
    assert math.hypot(recs[0].wind_x, recs[0].wind_y) == pytest.approx(math.sqrt(2), rel=1e-4)
    assert len(read_records(str(tmp_path / "g.tlog"))) == 19


def test_report_refuses_a_log_without_wind(tmp_path):
    import subprocess
    import sys

    empty = tmp_path / "empty.csv"
    empty.write_text("time_usec,sysid,compid,wind_x,wind_y,wind_z,var_horiz,var_vert,wind_alt,"
                     "horiz_accuracy,vert_accuracy,speed_mps,from_deg\n")  # fmt: skip
    truth = tmp_path / "t.csv"
    truth.write_text("time_s,wind_n,wind_e\n0,0,3\n1,0,3\n")
    r = subprocess.run([sys.executable, "-m", "ground_station", "report", str(empty), "--truth", str(truth)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and "WIND_COV" in r.stderr
