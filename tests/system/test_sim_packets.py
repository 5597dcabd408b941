"""Sensors and MAVLink packets: decode with pymavlink, rest specific force, barometric altitude."""

import math
import subprocess
import sys

import numpy as np
import pytest
from pymavlink import mavutil

from balloon_core.atmosphere import G0, hypsometric_height_m
from ground_station.report import read_truth_csv
from sim_hil.simulator import TRUTH_COLUMNS


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    tlog, truth = d / "f.tlog", d / "f.csv"
    cmd = [sys.executable, "-m", "sim_hil", "--scenario", "paper-reference", "--duration", "90", "--seed", "3",
           "--out", str(tlog), "--truth", str(truth)]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True)
    return tlog, truth


def decode(tlog):
    conn = mavutil.mavlink_connection(str(tlog))
    msgs = {"HIGHRES_IMU": [], "SCALED_PRESSURE": [], "HEARTBEAT": []}
    while (m := conn.recv_match()) is not None:
        if m.get_type() in msgs:
            msgs[m.get_type()].append(m)
    return msgs


def test_packet_rates_and_types(flight):
    msgs = decode(flight[0])
    assert len(msgs["HIGHRES_IMU"]) == 9000
    assert len(msgs["SCALED_PRESSURE"]) == 1800
    assert len(msgs["HEARTBEAT"]) == 90
    hb = msgs["HEARTBEAT"][0]
    assert hb.type == mavutil.mavlink.MAV_TYPE_FREE_BALLOON
    t = np.array([m.time_usec for m in msgs["HIGHRES_IMU"]])
    assert np.all(np.diff(t) == 10_000)
    assert msgs["HIGHRES_IMU"][0].get_srcSystem() == 1


def test_at_rest_specific_force_is_minus_g_and_baro_bits(flight):
    imu = decode(flight[0])["HIGHRES_IMU"]
    rest = [m for m in imu if m.time_usec < 4_000_000]
    acc = np.array([[m.xacc, m.yacc, m.zacc] for m in rest])
    assert acc[:, 2].mean() == pytest.approx(-G0, abs=0.005)
    assert np.abs(acc[:, :2].mean(axis=0)).max() < 0.005
    assert acc[:, 2].std() == pytest.approx(0.01, rel=0.1)  # Table 2: 0.01 m/s^2
    with_baro = [m for m in imu if m.fields_updated & 0x200]
    assert len(with_baro) == len(imu) // 5
    assert all(m.fields_updated & 0x1FF == 0x1FF for m in imu)


def test_baro_altitude_tracks_truth(flight):
    msgs = decode(flight[0])
    truth = read_truth_csv(str(flight[1]))
    sp = msgs["SCALED_PRESSURE"]
    t = np.array([m.time_boot_ms / 1000.0 for m in sp])
    p = np.array([m.press_abs for m in sp]) * 100.0
    temp = np.array([m.temperature / 100.0 for m in sp]) + 273.15
    p0 = p[t < 1.0].mean()
    t0 = temp[t < 1.0].mean()
    alt = np.array([hypsometric_height_m(pi, p0, 0.5 * (t0 + ti)) for pi, ti in zip(p, temp, strict=True)])
    true_alt = np.interp(t, truth["time_s"], truth["height_m"]) - 1.0  # boot: centre 1 m above anchor
    err = alt - true_alt
    assert abs(err.mean()) < 0.3
    assert err.std() == pytest.approx(1.0, rel=0.15)  # Table 2: 1 m
    assert true_alt.max() > 80.0


def test_truth_csv_columns(flight):
    with open(flight[1]) as fh:
        header = fh.readline().strip().split(",")
    assert tuple(header) == TRUTH_COLUMNS
    truth = read_truth_csv(str(flight[1]))
    assert len(truth["time_s"]) == 9000
    assert truth["tether_taut"][-1] == 1.0


def test_magnetometer_gives_heading(flight):
    imu = decode(flight[0])["HIGHRES_IMU"]
    rest = [m for m in imu if m.time_usec < 4_000_000]
    mx = np.mean([m.xmag for m in rest])
    my = np.mean([m.ymag for m in rest])
    assert math.degrees(math.atan2(-my, mx)) == pytest.approx(30.0, abs=1.0)  # initial yaw


def test_cli_lists_scenarios_and_rejects_bad_input(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sim_hil", "--list-scenarios"], capture_output=True, text=True)
    for name in ("paper-reference", "reduced-balloon", "increased-balloon", "better-accel", "better-baro",
                 "better-gyro-rate", "better-orientation", "realistic-mems"):  # fmt: skip
        assert name in out.stdout
    bad = subprocess.run([sys.executable, "-m", "sim_hil", "--scenario", "nope", "--duration", "1"],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 2 and "unknown scenario" in bad.stderr
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[balloon]\nradius_mm = 3\n")
    bad = subprocess.run([sys.executable, "-m", "sim_hil", "--config", str(cfg), "--duration", "1"],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 2 and "radius_mm" in bad.stderr


def test_config_file_changes_the_design(tmp_path):
    cfg = tmp_path / "big.toml"
    cfg.write_text("[balloon]\nradius_m = 1.15\n[wind]\nkind = 'steady'\nmean_mps = 4.0\n[truth]\nrelease_s = 2.0\n")
    from sim_hil.scenarios import resolve

    sc = resolve("paper-reference", str(cfg))
    assert sc.design.balloon.radius_m == 1.15
    assert sc.wind.kind == "steady" and sc.wind.mean_mps == 4.0
    assert sc.truth.release_s == 2.0
    assert sc.design.tether.length_m == 100.0


def test_a_design_file_alone_flies_the_real_world(tmp_path):
    """A design file's default truth is the real world (the lumped rope with its own drag, vertical air): a run that
    gives a design file and names no scenario flies it (field-rope with the file's sections), where it flew the
    paper's reference case with the paper's rope; one that names neither flies the paper's reference case, and a
    named scenario keeps its own world under the file."""
    import tomllib

    cfg = tmp_path / "d.toml"
    cfg.write_text("[balloon]\nradius_m = 1.1\n")

    def printed(*args: str) -> dict:
        out = subprocess.run([sys.executable, "-m", "sim_hil", *args, "--print-config"], capture_output=True,
                             text=True, check=True)  # fmt: skip
        return tomllib.loads(out.stdout)

    alone = printed("--config", str(cfg))
    assert alone["truth"]["rope_model"] == "lumped" and alone["truth"]["rope_drag"] is True
    assert alone["wind"]["vertical"] is True and alone["balloon"]["radius_m"] == 1.1
    assert printed()["truth"]["rope_model"] == "paper"
    named = printed("--scenario", "paper-reference", "--config", str(cfg))
    assert named["truth"]["rope_model"] == "paper" and named["balloon"]["radius_m"] == 1.1


@pytest.mark.parametrize("name", ["rope-drag", "realistic-mems", "multisine"])
def test_scenario_design_file_round_trips_through_both_programs(name, tmp_path):
    from firmware_py.cli import load_config
    from sim_hil.scenarios import SCENARIOS, resolve

    out = subprocess.run([sys.executable, "-m", "sim_hil", "--scenario", name, "--print-config"],
                         capture_output=True, text=True, check=True)  # fmt: skip
    path = tmp_path / "design.toml"
    path.write_text(out.stdout)
    sc = SCENARIOS[name]
    again = resolve("paper-reference", str(path))
    assert (again.design, again.wind, again.truth, again.filter) == (sc.design, sc.wind, sc.truth, sc.filter)
    design, fcfg, _ = load_config(str(path))
    assert design == sc.design and fcfg == sc.filter
