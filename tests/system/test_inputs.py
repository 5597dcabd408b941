"""Real flight data in: the ArduPilot message conversions, the IMU rate from the stream and the
averaging to the filter's step, the log readers on real PX4 logs and a DataFlash log, the estimator on
logs that are not a balloon, and a live ArduPilot-style link that has to be asked for its streams."""

from __future__ import annotations

import functools
import hashlib
import math
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design
from balloon_core.samples import BaroSample, ImuSample, MavlinkSampler
from balloon_core.wire import Decoder, LinkStats
from firmware_py.app import Firmware
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import FilterConfig
from firmware_py.streams import (
    InputPipeline,
    Resampler,
    StreamRequester,
    decide_rate,
    estimator_steps,
    feed,
    measure_rate_hz,
)
from postflight.logs import read_flight
from tests.helpers.flights import stream

DATA = Path(__file__).parents[1] / "data"
PY = sys.executable
G0 = 9.80665


def msg(encoder_name: str, *fields, sysid: int = 1, compid: int = 1):
    """A decoded message as the firmware gets it from the wire."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    frame = getattr(mav, encoder_name)(*fields).pack(mav)
    return mavlink.MAVLink(None).parse_char(frame)


# ------------------------------------------------------------------------ ArduPilot unit conversions


def test_scaled_imu_units_against_known_values():
    s = MavlinkSampler()
    (imu,) = s.convert(msg("scaled_imu_encode", 1234, 0, 500, -1000, 1000, -500, 250, 500, -250, 400))
    assert imu.t_us == 1_234_000  # time_boot_ms -> us
    assert (imu.ax, imu.ay, imu.az) == pytest.approx((0.0, 0.5 * G0, -G0), abs=1e-12)  # milli-g, specific force
    assert imu.az == pytest.approx(-9.80665, abs=1e-12)  # level at rest: zacc = -1000 mG
    assert (imu.gx, imu.gy, imu.gz) == pytest.approx((1.0, -0.5, 0.25))  # mrad/s
    assert (imu.mx, imu.my, imu.mz) == pytest.approx((0.5, -0.25, 0.4))  # mgauss


@pytest.mark.parametrize("name", ["scaled_imu2_encode", "scaled_imu3_encode"])
def test_second_and_third_imu_have_the_same_units(name):
    (imu,) = MavlinkSampler().convert(msg(name, 20, 0, 0, -1000, 1000, 0, 0, 500, 0, 0))
    assert imu.az == pytest.approx(-G0) and imu.gx == pytest.approx(1.0) and imu.mx == pytest.approx(0.5)
    assert math.isnan(imu.mz) is False and imu.t_us == 20_000


def test_scaled_pressure_units():
    s = MavlinkSampler()
    (b,) = s.convert(msg("scaled_pressure2_encode", 5000, 1013.25, 0.0, 2150))
    assert b == BaroSample(5_000_000, pytest.approx(1013.25), pytest.approx(21.5))  # hPa, cdegC
    s2 = MavlinkSampler()
    (b,) = s2.convert(msg("scaled_pressure_encode", 10, 950.5, 0.0, -1234))
    assert b.pressure_hpa == pytest.approx(950.5) and b.temperature_c == pytest.approx(-12.34) and b.t_us == 10_000


def test_no_magnetometer_and_repeated_readings_are_not_samples():
    s = MavlinkSampler()
    (a,) = s.convert(msg("scaled_imu2_encode", 10, 0, 0, -1000, 0, 0, 0, 0, 0, 0))
    assert math.isnan(a.mx)  # all zero: the autopilot has no compass
    (b,) = s.convert(msg("scaled_imu2_encode", 20, 0, 0, -1000, 0, 0, 0, 200, 10, 400))
    (c,) = s.convert(msg("scaled_imu2_encode", 30, 0, 0, -1000, 0, 0, 0, 200, 10, 400))
    assert b.mx == pytest.approx(0.2) and math.isnan(c.mx)  # the same reading repeated: not a new sample


def test_one_imu_and_one_barometer_instance_the_others_counted():
    s = MavlinkSampler()
    assert len(s.convert(msg("scaled_imu2_encode", 10, 0, 0, -1000, 0, 0, 0, 1, 1, 1))) == 1
    assert s.convert(msg("scaled_imu_encode", 10, 0, 0, -1000, 0, 0, 0, 1, 1, 1)) == ()
    assert s.convert(msg("scaled_imu3_encode", 10, 0, 0, -1000, 0, 0, 0, 1, 1, 1)) == ()
    assert len(s.convert(msg("scaled_pressure2_encode", 10, 1000.0, 0.0, 2000))) == 1
    assert s.convert(msg("scaled_pressure_encode", 10, 1000.0, 0.0, 2000)) == ()
    assert s.convert(msg("scaled_imu2_encode", 10, 0, 0, -1000, 0, 0, 0, 1, 1, 1, sysid=2)) == ()  # another vehicle
    assert s.ignored == 4
    assert s.convert(msg("heartbeat_encode", 2, 3, 0, 0, 0)) is None  # not a sensor message


def test_nan_and_out_of_range_messages_are_rejected_by_the_estimator():
    est = Estimator(Design())
    for m in (
        msg("scaled_imu_encode", 10, 0, 0, -32000, 0, 0, 0, 300, 0, 400),  # 32 g: out of range
        msg("scaled_pressure_encode", 10, float("nan"), 0.0, 2000),
        msg("scaled_pressure_encode", 20, 5000.0, 0.0, 2000),  # 5000 hPa
        msg("highres_imu_encode", 10, 0, 0, -9.8, 0, 0, 0, 0.2, 0, 0.4, 1000.0, 0, 0, 20.0, 0x1C0, 0),  # no acc/gyro
    ):
        for sample in MavlinkSampler().convert(m):
            feed(est, sample)
    assert est.counters.rejected == 4 and not est.initialised


# ------------------------------------------------------------------------ the rate and the averaging


def test_rate_measured_robustly():
    t = [i * 4000 for i in range(500)]
    assert measure_rate_hz(t) == pytest.approx(250.0)
    lossy = [x for i, x in enumerate(t) if i % 7 != 3] + t[10:20] + [t[5]]  # lost, duplicated, late
    assert measure_rate_hz(lossy) == pytest.approx(250.0)
    assert measure_rate_hz([5]) is None


def test_filter_rate_decision():
    def rate(*args):
        d = decide_rate(*args)
        return d.filter_hz, d.resample, d.warning

    assert rate(250.0, 100.0, False) == (100.0, True, None)  # faster: averaged down
    assert rate(103.0, 100.0, False) == (100.0, False, None)  # within 10 %: as it comes
    assert rate(50.0, 100.0, False) == (50.0, False, None)  # slower: the filter follows
    d = decide_rate(50.0, 100.0, True)  # explicit: kept, and warned
    assert d.filter_hz == 100.0 and not d.resample and "50.0 Hz" in d.warning and "\n" not in d.warning
    assert decide_rate(104.0, 100.0, True).warning is None
    assert rate(None, 100.0, False) == (100.0, False, None)


def imu(t_us, ax=0.0, mag=math.nan):
    return ImuSample(t_us, ax, 0.0, -9.8, 0.0, 0.0, 0.0, mag, mag, mag)


def test_resampler_averages_each_step_and_keeps_gaps():
    r = Resampler(100.0)
    out = []
    times = [i * 4000 for i in range(10)] + [i * 4000 for i in range(50, 60)]  # 250 Hz, a 160 ms dropout
    for t in times:
        out += r.push(imu(t, ax=t * 1e-6, mag=0.3 if t == 8000 else math.nan))
    out += r.flush()
    t_out = [s.t_us for s in out]
    assert t_out[:5] == [0, 10_000, 20_000, 30_000, 40_000]  # centres of the -5..5, 5..15, ... ms bins
    assert out[0].ax == pytest.approx(0.002) and out[2].ax == pytest.approx(0.020)  # means of 0, 4 and 16, 20, 24
    assert out[1].mx == pytest.approx(0.3) and math.isnan(out[0].mx)
    assert t_out[5] - t_out[4] == 160_000  # the dropout stays a dropout
    assert all(b > a for a, b in zip(t_out, t_out[1:]))
    # a duplicate and a late sample are dropped and counted; a reboot starts the bins again
    assert r.push(imu(2_236_000)) == [] and r.push(imu(2_236_000)) == [] and r.duplicates == 1
    assert r.push(imu(2_100_000)) == [] and r.reordered == 1
    rebooted = r.push(imu(1000))
    assert [s.t_us for s in rebooted] == [2_240_000] and r.flush()[0].t_us == 1000
    assert r.push(BaroSample(5, 1000.0, 20.0)) == [BaroSample(5, 1000.0, 20.0)]


def test_pipeline_holds_two_seconds_then_releases_at_the_filter_rate():
    p = InputPipeline(FilterConfig())
    out = []
    for i in range(1000):  # 4 s at 250 Hz
        out += p.push(imu(i * 4000))
        if i < 500:
            assert not p.decided
    assert p.decided and p.cfg.imu_rate_hz == 100.0 and p.decision.resample
    out += p.flush()
    assert len(out) == pytest.approx(400, abs=2)
    slow = InputPipeline(FilterConfig())  # 50 Hz: waits to see if it speeds up, then follows it
    for i in range(400):
        slow.push(imu(i * 20_000))
    assert slow.decided and slow.cfg.imu_rate_hz == 50.0 and not slow.decision.resample


def test_firmware_averages_a_fast_stream_and_says_so():
    """200 Hz HIGHRES_IMU into the default 100 Hz filter: one step per 10 ms, the same wind."""
    samples, truth = stream("paper-reference", 60.0, 12)
    fast = []
    for a, b in zip(samples, samples[1:]):  # 200 Hz: each sample and the midpoint to the next
        fast.append(a)
        mid = [(x + y) / 2 for x, y in zip(a.accel + a.gyro + a.mag, b.accel + b.gyro + b.mag)]
        fast.append(type(a)(a.time_usec + 5000, tuple(mid[:3]), tuple(mid[3:6]), tuple(mid[6:]), None))
    fw = Firmware(Design())
    for s in fast:
        for m in ([s.baro] if s.baro else []):
            fw.push(BaroSample(s.time_usec, *m))
        fw.push(ImuSample(s.time_usec, *s.accel, *s.gyro, *s.mag))
    fw.flush()
    assert fw.est.cfg.imu_rate_hz == 100.0 and fw.pipe.decision.resample
    assert fw.est.counters.imu_samples == pytest.approx(6000, abs=2) and fw.est.counters.jitter == 0
    assert "(IMU stream 200.0 Hz, averaged)" in fw.summary()
    wn, we = fw.est.wind()
    assert math.hypot(wn - truth["wind_n"][-1], we - truth["wind_e"][-1]) < 1.0


@pytest.fixture(scope="module")
def sim_tlog(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    tlog = d / "s.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--duration", "30", "--seed", "2", "--out", str(tlog)], check=True,
                   capture_output=True)  # fmt: skip
    return tlog


def test_explicit_rate_that_the_stream_contradicts_is_one_warning(sim_tlog, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[filter]\nimu_rate_hz = 50.0\n")
    r = subprocess.run([PY, "-m", "firmware_py", "--in", str(sim_tlog), "--config", str(cfg)], capture_output=True,
                       text=True)  # fmt: skip
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 2, r.stderr
    assert "imu_rate_hz = 50" in lines[0] and "100.0 Hz" in lines[0]
    assert "filter at 50 Hz (IMU stream 100.0 Hz, averaged)" in lines[1]
    r = subprocess.run([PY, "-m", "firmware_py", "--in", str(sim_tlog)], capture_output=True, text=True)
    assert r.returncode == 0 and len(r.stderr.strip().splitlines()) == 1 and "filter at 100 Hz" in r.stderr


def test_tlog_reprocessing_sees_what_the_firmware_saw(sim_tlog):
    """read_flight + estimator_steps give the live firmware's estimate bit for bit."""
    from firmware_py.cli import replay_file

    fw = Firmware(Design())
    replay_file(fw, str(sim_tlog))
    flight = read_flight(str(sim_tlog))
    assert flight.meta.format == "tlog" and flight.meta.has_baro and flight.meta.imu_rate_hz == pytest.approx(100.0)
    assert flight.meta.sensors == {"imu": "HIGHRES_IMU", "baro": "HIGHRES_IMU", "mag": "HIGHRES_IMU"}
    last = None
    for est, _, advanced in estimator_steps(Design(), FilterConfig(), flight.samples()):
        if advanced:
            last = est
    assert last.counters.as_dict() == fw.est.counters.as_dict()
    assert last.wind() == fw.est.wind() and last.ekf.wind_accuracy() == fw.est.ekf.wind_accuracy()


# ------------------------------------------------------------------------------------ the log readers


def test_real_px4_flight_without_barometer():
    f = read_flight(str(DATA / "pyulog-sample.ulg"))
    m = f.meta
    assert m.format == "ulog" and m.n_imu == 17070 and m.imu_rate_hz == pytest.approx(250.0)
    assert not m.has_baro and m.n_baro == 0 and any("no barometer" in n for n in m.notes)
    assert m.has_mag and m.sensors["mag"] == "sensor_combined.magnetometer_ga" and 6000 < m.n_mag < 7000
    assert m.utc_start_s is None and m.duration_s == pytest.approx(68.9, abs=0.1)
    assert m.sha256 == hashlib.sha256((DATA / "pyulog-sample.ulg").read_bytes()).hexdigest()
    assert np.all(np.diff(f.t_us) >= 0)
    acc = f.values[f.kind == 0, :3]
    assert np.median(acc[:, 2]) == pytest.approx(-9.6, abs=0.1)  # specific force, FRD


def test_px4_sitl_log_with_air_data():
    f = read_flight(str(DATA / "pyulog-sample_px4_events.ulg"))
    m = f.meta
    assert m.n_imu == 7783 and m.imu_rate_hz == pytest.approx(250.0)
    assert m.has_baro and m.n_baro == 623 and m.sensors == {"imu": "sensor_combined", "mag": "vehicle_magnetometer",
                                                           "baro": "vehicle_air_data"}  # fmt: skip
    baro = f.values[f.kind == 1, :2]
    assert np.all((baro[:, 0] > 900) & (baro[:, 0] < 1100)) and np.all(np.abs(baro[:, 1]) < 60)  # hPa, degC
    assert m.utc_start_s == pytest.approx(0.0, abs=1.0) and m.utc_source == "gps"  # SITL's clock is UNIX time
    assert np.all(np.diff(f.t_us) >= 0)
    assert sum(1 for _ in f.samples()) == len(f) == 7783 + 623


def test_real_px4_log_with_dropouts():
    f = read_flight(str(DATA / "pyulog-sample_log_small.ulg"))
    m = f.meta
    assert m.n_imu == 1298 and m.has_baro and m.n_baro == 120
    assert m.utc_start_s is not None and 1.6e9 < m.utc_start_s < 1.7e9  # April 2021
    t = f.t_us[f.kind == 0]
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) > 50_000  # dropouts kept


def test_dataflash_log_units_and_metadata():
    f = read_flight(str(DATA / "balloon-sim.bin"))
    m = f.meta
    assert m.format == "dataflash" and m.imu_rate_hz == pytest.approx(200.0)
    assert m.n_imu == 18000 - 60 and m.n_baro == 1800 and m.n_mag == 4500 - 15  # the 0.3 s IMU dropout
    assert m.utc_start_s == pytest.approx(1_780_293_600.0, abs=1e-3) and m.utc_source == "gps"
    imu = f.values[f.kind == 0]
    assert np.median(imu[:500, 2]) == pytest.approx(-G0, abs=0.05)  # at rest, m/s^2
    assert 0.3 < np.nanmedian(np.linalg.norm(imu[:, 6:9], axis=1)) < 0.7  # mGauss -> gauss
    baro = f.values[f.kind == 1, :2]
    assert baro[0, 0] == pytest.approx(1013.25, abs=2.0) and 10.0 < baro[0, 1] < 30.0  # Pa -> hPa, cdegC -> degC


def test_dataflash_units_are_checked(tmp_path):
    raw = (DATA / "balloon-sim.bin").read_bytes()
    bad = raw.replace(b"rad/s", b"furl/")  # the gyro's unit label says something unknown
    p = tmp_path / "bad-unit.bin"
    p.write_bytes(bad)
    with pytest.raises(ValueError, match="GyrX.*furl"):
        read_flight(str(p))


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("missing.ulg", None, "no such file"),
        ("empty.bin", b"", "empty"),
        ("junk.ulg", b"this is not a log" * 100, "not a readable PX4 ULog"),
        ("junk.bin", b"\x00\x01" * 1000, "no MAVLink"),  # not DataFlash by its bytes: read as a raw capture
        ("junk-df.bin", b"\xa3\x95\x80" + b"\x00\x01" * 1000, "DataFlash"),
        ("junk.raw", bytes(range(256)) * 10, "no MAVLink"),
        ("hb.tlog", None, "no IMU"),
    ],
)
def test_unreadable_flights_are_clear_errors(tmp_path, name, content, match):
    p = tmp_path / name
    if name == "hb.tlog":
        mav = mavlink.MAVLink(None)
        p.write_bytes(b"\x00" * 8 + mav.heartbeat_encode(2, 3, 0, 0, 0).pack(mav))
    elif content is not None:
        p.write_bytes(content)
    with pytest.raises(ValueError, match=match) as exc:
        read_flight(str(p))
    assert "\n" not in str(exc.value)


# ------------------------------------------------------------------------ the estimator on the logs


@functools.lru_cache(maxsize=2)
def run_estimator(path: Path):
    rows, est = [], None
    for est, s, advanced in estimator_steps(Design(), FilterConfig(), read_flight(str(path)).samples()):
        if advanced:
            wn, we = est.wind()
            rows.append((s.t_us * 1e-6, wn, we, est.wind_accuracy(), est.height_m()))
    return np.array(rows), est


def test_dataflash_balloon_flight_gives_the_wind():
    rows, est = run_estimator(DATA / "balloon-sim.bin")
    truth = np.loadtxt(DATA / "balloon-sim-truth.csv", delimiter=",", skiprows=1)
    assert est.cfg.imu_rate_hz == 100.0 and est.counters.jitter == 0 and est.counters.gaps == 1  # the dropout
    late = rows[:, 0] > 60.0
    wn = np.interp(rows[late, 0], truth[:, 0], truth[:, 1])
    we = np.interp(rows[late, 0], truth[:, 0], truth[:, 2])
    err = np.hypot(rows[late, 1] - wn, rows[late, 2] - we)
    assert np.sqrt(np.mean(err**2)) < 0.5 and np.all(rows[late, 3] < 0.5)
    assert np.all(rows[late, 4] > 80.0)  # on its 100 m tether, from the barometer


def honest(rows) -> np.ndarray:
    """Where the reported accuracy says the wind is not known: the estimate lies within 2 sigma of
    calm, i.e. it cannot be told from no wind at all (a wind the filter claims to know is > 2 sigma)."""
    return np.hypot(rows[:, 1], rows[:, 2]) <= 2.0 * rows[:, 3]


def test_sitl_drone_log_no_crash_finite_and_honest():
    rows, est = run_estimator(DATA / "pyulog-sample_px4_events.ulg")
    assert len(rows) > 3000 and np.all(np.isfinite(rows))
    assert np.all(honest(rows)), rows[~honest(rows)][:3]


@pytest.mark.parametrize("name", ["pyulog-sample.ulg", "pyulog-sample_log_small.ulg"])
def test_real_drone_logs_no_crash_and_finite(name):
    rows, est = run_estimator(DATA / name)
    assert len(rows) > 600 and np.all(np.isfinite(rows)) and est.counters.numeric_resets == 0


@pytest.mark.parametrize("name", ["pyulog-sample.ulg", "pyulog-sample_log_small.ulg"])
def test_real_drone_logs_honest_accuracy(name):
    """A log that starts long after boot joins "in flight" as a taut balloon; a drone resting on the
    ground never shows the sustained motion of a balloon in wind, so the join stays unconfirmed and the
    reported accuracy says the wind is not known (control.py, CONFIRM_*)."""
    rows, est = run_estimator(DATA / name)
    assert est.unconfirmed
    assert np.all(honest(rows))


# ------------------------------------------------------------------------ live ArduPilot-style link


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FakeArduPilot(threading.Thread):
    """An ArduPilot-like peer: HEARTBEAT at 1 Hz, SCALED_IMU2 + SCALED_PRESSURE from the simulator at 2 Hz
    until asked for more; answers SET_MESSAGE_INTERVAL with COMMAND_ACK (``ack``: a MAV_RESULT, or None
    for never) and obeys it, and obeys REQUEST_DATA_STREAM. Sensor time runs with the wall clock (the
    balloon rests on the ground station) until the IMU stream has been sped up, then ``speed`` x faster."""

    def __init__(self, fw_port: int, ack: int | None, speed: float = 5.0) -> None:
        super().__init__(daemon=True)
        self.samples, _ = stream("paper-reference", 120.0, 13)
        self.fw = ("127.0.0.1", fw_port)
        self.ack, self.speed = ack, speed
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.002)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.every = {mavlink.MAVLINK_MSG_ID_SCALED_IMU2: 50, mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: 50}
        self.commands: list[tuple[int, int, float]] = []
        self.data_streams: list[tuple[int, int, int]] = []
        self.stop = threading.Event()
        self.sent = 0

    def send(self, m) -> None:
        self.sock.sendto(m.pack(self.mav), self.fw)
        self.mav.seq = (self.mav.seq + 1) % 256

    def run(self) -> None:
        dec = Decoder(LinkStats())
        last = time.monotonic()
        k, next_hb, sensor_s, wall_s = 0, 0.0, 0.0, 0.0
        while not self.stop.is_set() and k < len(self.samples):
            now = time.monotonic()
            fast = self.every[mavlink.MAVLINK_MSG_ID_SCALED_IMU2] < 50  # asked: run the flight faster than life
            sensor_s += (now - last) * (self.speed if fast else 1.0)
            wall_s += now - last
            last = now
            if wall_s >= next_hb:
                self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                    0, 0, mavlink.MAV_STATE_STANDBY))  # fmt: skip
                next_hb += 1.0
            while k < min(len(self.samples), int(sensor_s * 100)):
                self._sample(k)
                k += 1
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, OSError):
                continue
            for m in dec.feed(data):
                self._command(m)
        self.sock.close()

    def _sample(self, k: int) -> None:
        s = self.samples[k]
        ms = s.time_usec // 1000
        if k % self.every[mavlink.MAVLINK_MSG_ID_SCALED_IMU2] == 0:
            acc = [round(v / G0 * 1000) for v in s.accel]
            gyro = [round(v * 1000) for v in s.gyro]
            mag = [round(v * 1000) for v in s.mag]
            self.send(self.mav.scaled_imu2_encode(ms, *acc, *gyro, *mag))
            self.sent += 1
        if k % self.every[mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE] == 0:
            hpa, temp = self.samples[k - k % 5].baro or (1013.25, 20.0)
            self.send(self.mav.scaled_pressure_encode(ms, hpa, 0.0, round(temp * 100)))

    def _command(self, m) -> None:
        if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.commands.append((int(m.param1), int(m.param2), m.confirmation))
            if self.ack is None:
                return
            self.send(self.mav.command_ack_encode(m.command, self.ack, 0, 0, m.get_srcSystem(), m.get_srcComponent()))
            if self.ack == mavlink.MAV_RESULT_ACCEPTED and int(m.param1) in self.every:
                self.every[int(m.param1)] = max(1, round(m.param2 / 10_000))
        elif m.get_type() == "REQUEST_DATA_STREAM":
            self.data_streams.append((m.req_stream_id, m.req_message_rate, m.start_stop))
            if m.req_stream_id == mavlink.MAV_DATA_STREAM_RAW_SENSORS and m.start_stop:
                for mid in self.every:
                    self.every[mid] = max(1, round(100 / m.req_message_rate))


def run_live_fw(ack: int | None, seconds: float, until_s: float):
    """balloon-fw live against a FakeArduPilot; its WIND_COV until one is stamped ``until_s`` (sensor time)."""
    p_in, p_out = free_port(), free_port()
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.bind(("127.0.0.1", p_out))
    out.settimeout(0.1)
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{p_in}", "--out",
                           f"udpout:127.0.0.1:{p_out}"], stderr=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(1.0)
    peer = FakeArduPilot(p_in, ack)
    peer.start()
    dec = Decoder(LinkStats())
    wind = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            data = out.recv(65536)
        except (TimeoutError, OSError):
            continue
        wind += [m for m in dec.feed(data) if m.get_type() == "WIND_COV"]
        if wind and wind[-1].time_usec > until_s * 1e6:
            break
    peer.stop.set()
    peer.join(5)
    fw.send_signal(signal.SIGINT)
    fw.wait(10)
    out.close()
    return peer, wind, fw.stderr.read(), fw.returncode


@pytest.mark.network
def test_live_ardupilot_link_is_asked_for_its_streams():
    peer, wind, summary, rc = run_live_fw(mavlink.MAV_RESULT_ACCEPTED, 25.0, 60.0)
    assert rc == 130, summary  # stopped by Ctrl-C (SIGINT): interrupted
    asked = {mid: interval for mid, interval, _ in peer.commands}
    assert asked == {mavlink.MAVLINK_MSG_ID_SCALED_IMU2: 10_000, mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: 50_000}
    assert not peer.data_streams
    assert "2 SET_MESSAGE_INTERVAL (2 accepted, 0 refused, 0 unanswered), 0 REQUEST_DATA_STREAM" in summary
    assert "filter at 100 Hz (IMU stream 100.0 Hz)" in summary
    assert len(wind) > 100, summary
    last = wind[-1]
    assert last.time_usec > 60_000_000 and math.isfinite(last.wind_x) and math.isfinite(last.wind_y)
    truth = stream("paper-reference", 120.0, 13)[1]
    t = np.array([m.time_usec * 1e-6 for m in wind])
    late = t > t[-1] - 10.0
    wn = np.interp(t[late], truth["time_s"], truth["wind_n"])
    we = np.interp(t[late], truth["time_s"], truth["wind_e"])
    err = np.hypot([m.wind_x for m in np.array(wind)[late]] - wn, [m.wind_y for m in np.array(wind)[late]] - we)
    assert np.sqrt(np.mean(err**2)) < 1.0, summary  # against the simulator's wind over the last 10 s
    assert 0.0 < last.horiz_accuracy < 2.0


@pytest.mark.network
def test_live_link_falls_back_to_request_data_stream_when_never_acknowledged():
    peer, wind, summary, rc = run_live_fw(None, 20.0, 20.0)
    assert rc == 130, summary
    assert len(peer.commands) == 6 and [c for _, _, c in peer.commands[:4:2]] == [0, 1]  # 3 tries each, confirmation
    assert peer.data_streams and peer.data_streams[0] == (mavlink.MAV_DATA_STREAM_RAW_SENSORS, 100, 1)
    assert re.search(r"6 SET_MESSAGE_INTERVAL \(0 accepted, 0 refused, 2 unanswered\), [1-3] REQUEST_DATA_STREAM",
                     summary), summary  # fmt: skip
    assert len(wind) > 50 and math.isfinite(wind[-1].wind_x) and math.isfinite(wind[-1].horiz_accuracy)


class _Clock:
    def __init__(self):
        self.t = 0.0


def test_stream_requester_refused_goes_to_the_fallback_and_ignores_our_simulator():
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sampler = MavlinkSampler()
    req = StreamRequester(mav, sampler, 100.0)
    req.on_message(msg("heartbeat_encode", mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0), 0.0)
    assert req.poll(5.0) == [] and not req.pending()  # our simulator: never asked
    req.on_message(msg("heartbeat_encode", mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0,
                       sysid=3), 10.0)  # fmt: skip
    assert req.pending() and req.poll(10.5) == []  # watching its streams for a second first
    frames = req.poll(11.1)
    parsed = [mavlink.MAVLink(None).parse_char(f) for f in frames]
    assert [(p.command, int(p.param1), int(p.param2), p.target_system) for p in parsed] == [
        (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 10_000, 3)]  # PX4: carries baro
    req.on_message(msg("command_ack_encode", mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_RESULT_DENIED, 0, 0,
                       1, 1, sysid=3), 11.2)  # fmt: skip
    frames = req.poll(11.3)
    p = mavlink.MAVLink(None).parse_char(frames[0])
    assert p.get_type() == "REQUEST_DATA_STREAM" and p.req_stream_id == mavlink.MAV_DATA_STREAM_RAW_SENSORS
    assert req.refused == 1 and req.data_stream_sent == 1 and req.poll(12.0) == []  # 2 s between fallbacks
    assert len(req.poll(13.4)) == 1 and len(req.poll(15.5)) == 1 and req.poll(30.0) == []  # 3 tries, then quiet
    assert not req.pending()
