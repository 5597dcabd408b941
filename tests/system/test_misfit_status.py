"""The model misfit says why (docs/protocol.md, "Model misfit"): when the consistency monitor flags an aid
source, balloon-fw sends a STATUSTEXT, clears the source's SYS_STATUS health bit, says so in its status line
and summary; the ground station shows it; the post-flight NetCDF carries the flags and the accuracy factor.

A real misfit: ``field-gusty-6`` (6 m/s class-B turbulence on the real rope), 120 s, seed 1, flags the
accelerometer from 6.7 s and the tether's alignment from 20.2 s. A scripted one (the monitor replaced by a
schedule of flags) checks the rate limit, the clear, the restart and each source's health bit."""

from __future__ import annotations

import io
import math
import re
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design
from balloon_core.wire import TLOG_EPOCH_US, LinkStats, tlog_messages
from firmware_py import app
from firmware_py.app import CONSISTENT_TEXT, RESTARTED_TEXT, SENSOR_BITS, TEXT_MAX, Firmware
from firmware_py.estimator import control
from firmware_py.estimator.consistency import ACCEL as ACCEL_SOURCE
from firmware_py.estimator.consistency import FLAG_NIS, FLAG_NIS_CLEAR, SOURCES, Consistency, stated_nis
from firmware_py.estimator.state import FilterConfig
from ground_station.listen import GroundStation

PY = sys.executable
ACCEL = mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
MAG = mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
BARO = mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
AHRS = mavlink.MAV_SYS_STATUS_AHRS
BIT = {name: 1 << i for i, name in enumerate(SOURCES)}


@pytest.fixture(scope="module")
def gusty(tmp_path_factory):
    """The simulated flight, balloon-fw's replay of it (its tlog and summary)."""
    d = tmp_path_factory.mktemp("misfit")
    tlog, out = d / "sensors.tlog", d / "fw.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--scenario", "field-gusty-6", "--duration", "120", "--seed", "1",
                    "--out", str(tlog), "--quiet"], check=True, capture_output=True)  # fmt: skip
    r = subprocess.run([PY, "-m", "firmware_py", "--in", str(tlog), "--out", str(out), "--quiet"], capture_output=True,
                       text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    return d, tlog, out, r.stderr


def fw_messages(path):
    """(sensor time s, message) of what the firmware sent (its tlog stamps records with the sensor clock)."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (m := conn.recv_match()) is not None:
        out.append((round(m._timestamp * 1e6 - TLOG_EPOCH_US) * 1e-6, m))
    return out


def health_flags(st) -> int:
    """The consistency flags a SYS_STATUS tells, as far as its bits can (AHRS: align, radius or force, as align)."""
    bad = st.onboard_control_sensors_present & ~st.onboard_control_sensors_health
    flags = 0
    for name, bit in (("accel", ACCEL), ("baro", BARO), ("mag", MAG), ("align", AHRS)):
        if bad & bit:
            flags |= BIT[name]
    return flags


# ---------------------------------------------------------------- a real misfit, end to end


def told_flags(text: str) -> int:
    """The flags a misfit STATUSTEXT names (0 for the all-clear), as SYS_STATUS can tell them."""
    m = re.search(r"misfit ([a-z,]+)", text)
    return 0 if m is None else as_health(sum(BIT[n] for n in m.group(1).split(",")))


def as_health(flags: int) -> int:
    """Flags as SYS_STATUS tells them: align, radius and force share the AHRS bit (shown as align)."""
    tether = flags & (BIT["align"] | BIT["radius"] | BIT["force"])
    return flags & (BIT["accel"] | BIT["baro"] | BIT["mag"]) | (BIT["align"] if tether else 0)


@pytest.mark.slow
def test_a_gusty_flight_tells_its_misfit(gusty):
    d, _, out, stderr = gusty
    msgs = fw_messages(out)
    texts = [(t, m) for t, m in msgs if m.get_type() == "STATUSTEXT"]
    assert texts, "field-gusty-6 was expected to flag the accelerometer"
    t1, m1 = texts[0]
    assert m1.severity == mavlink.MAV_SEVERITY_WARNING and "accel" in m1.text and 5.0 < t1 < 30.0, texts
    assert m1.text.startswith("wind uncertain: model misfit accel")
    for _, m in texts:
        assert len(m.text) <= TEXT_MAX
        if m.severity == mavlink.MAV_SEVERITY_WARNING:
            # a flagged source's NIS is above FLAG_NIS_CLEAR, the accelerometer's stated as (1 + NIS) / 2
            least = math.sqrt(stated_nis(ACCEL_SOURCE, FLAG_NIS_CLEAR))
            assert float(re.search(r"x(\d\.\d)\)?$", m.text).group(1)) >= round(least, 1), m.text
        else:
            assert (m.severity, m.text) == (mavlink.MAV_SEVERITY_INFO, CONSISTENT_TEXT)
    assert all(b - a >= 1.0 - 1e-9 for (a, _), (b, _) in zip(texts, texts[1:]))  # at most one a second
    # SYS_STATUS: all present and enabled, healthy but for what the last STATUSTEXT named (a change is
    # told at most a second later); the gyro stays healthy whatever happens
    status = [(t, m) for t, m in msgs if m.get_type() == "SYS_STATUS"]
    assert len(status) == pytest.approx(120, abs=2)
    told = [(t, told_flags(m.text)) for t, m in texts]
    for t, st in status:
        assert st.onboard_control_sensors_present == st.onboard_control_sensors_enabled == SENSOR_BITS
        assert st.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
        last = [f for tt, f in told if tt <= t]
        expect = last[-1] if last else 0
        soon = any(t < tt <= t + 1.0 for tt, _ in told)
        assert health_flags(st) == expect or soon, (t, hex(st.onboard_control_sensors_health), told)
    assert health_flags(status[-1][1]) & BIT["accel"]  # this flight stays flagged to its end
    # the summary says why, and for how long
    summary = stderr.strip().splitlines()[-1]
    m = re.search(r", model misfit: accel (\d+) % of flight time", summary)
    assert m and int(m.group(1)) >= 50, summary


@pytest.mark.slow
def test_the_ground_station_shows_the_misfit(gusty):
    from rich.console import Console

    _, _, out, _ = gusty
    gs = GroundStation(out=io.StringIO())
    for m in tlog_messages(str(out), LinkStats()):
        gs.handle(m, 100.0)
    v = gs.vehicles[1]
    # the accelerometer's misfit (the alignment's noise follows the rocking, which P then holds: it is
    # flagged only beyond that, docs/estimator.md)
    assert v.misfit() == ["accel"] and v.warning_active()
    for width in (80, 120, 200):
        con = Console(width=width, record=True, file=io.StringIO(), force_terminal=True)
        con.print(gs.view(100.0, width))
        lines = con.export_text().splitlines()
        assert all(len(ln) <= width for ln in lines) and len(lines) <= 24
        row = next(ln for ln in lines if ln.split() and ln.split()[0] == "1")
        assert "MISFIT" in row
        said = [ln for ln in lines if ln.startswith("sys 1: ")]
        assert len(said) == 1 and "misfit accel" in said[0] and "WARNING" in said[0], lines
    plain = gs.status_lines(100.0)
    assert "MISFIT accel" in plain[0]
    assert re.search(r"said: wind uncertain: (model )?misfit accel", plain[0]), plain[0]


@pytest.mark.slow
def test_the_product_carries_the_flags_the_firmware_told(gusty):
    d, tlog, out, _ = gusty
    nc = d / "wind.nc"
    r = subprocess.run([PY, "-m", "ground_station", "reprocess", str(tlog), "--out", str(nc), "--quiet"],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    with xr.open_dataset(nc) as ds:
        t = ds["time_since_boot"].values
        cf = ds["consistency_flags_causal"]
        inf = ds["accuracy_inflation_causal"]
        assert cf.dtype == np.int8 and cf.attrs["standard_name"] == "status_flag"
        assert list(cf.attrs["flag_masks"]) == [1 << i for i in range(len(SOURCES))]
        assert cf.attrs["flag_meanings"].split() == [f"{n}_misfit" for n in SOURCES]
        assert inf.attrs["units"] == "1"
        flags, factor = cf.values.astype(int), inf.values.astype(float)
        assert "flags" in ds and "eastward_wind_causal_uncertainty" in ds  # the existing ones stay
        causal = np.hypot(ds["northward_wind_causal_uncertainty"].values, ds["eastward_wind_causal_uncertainty"].values)
    # the causal uncertainty is the accuracy WIND_COV said in flight, the monitor's factor (and the lean's misfit) in it
    said = [(t_, m.horiz_accuracy) for t_, m in fw_messages(out) if m.get_type() == "WIND_COV"]
    k = np.clip(np.searchsorted(t, [t_ for t_, _ in said]), 0, len(t) - 1)
    same = np.abs(t[k] - np.array([t_ for t_, _ in said])) < 1e-3
    assert same.sum() > 0.9 * len(said) and np.any(factor[k[same]] > 1.5)
    np.testing.assert_allclose(causal[k[same]], np.array([a for _, a in said])[same], rtol=1e-3)
    # an unflagged time has every windowed NIS at most FLAG_NIS, so a factor at most its root; a flagged one a NIS
    # above FLAG_NIS_CLEAR, stated at least as the accelerometer's (1 + NIS) / 2 (consistency.stated_nis)
    assert np.all(factor >= 1.0 - 1e-6)
    assert np.all(factor[flags == 0] <= math.sqrt(FLAG_NIS) * (1 + 1e-6))
    assert np.all(factor[flags != 0] > math.sqrt(stated_nis(ACCEL_SOURCE, FLAG_NIS_CLEAR)) * (1 - 1e-6))
    assert np.any(flags & BIT["accel"])
    # the same as the firmware said in flight: its first STATUSTEXT when the first flag came up, and its
    # SYS_STATUS health (the reprocessing runs the firmware's estimator on the same samples)
    first = t[np.argmax(flags != 0)]
    texts = [t_ for t_, m in fw_messages(out) if m.get_type() == "STATUSTEXT"]
    assert first == pytest.approx(texts[0], abs=0.1)
    status = [(t_, m) for t_, m in fw_messages(out) if m.get_type() == "SYS_STATUS"]
    agree = 0
    for t_, st in status:
        k = int(np.searchsorted(t, t_ + 1e-6)) - 1  # the grid point at or just before the message
        agree += as_health(int(flags[k])) == health_flags(st)
    changes = int(np.count_nonzero(np.diff(flags)))
    assert agree >= len(status) - changes  # a change between the grid point and the message: one per change


# ---------------------------------------------------------------- a scripted misfit


class Scripted(Consistency):
    """The consistency monitor replaced by a schedule: (first call, flags) in the filter steps it judges."""

    __slots__ = ("calls",)
    schedule: tuple[tuple[int, int], ...] = ()

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def evaluate(self) -> None:
        flags = 0
        for start, f in self.schedule:
            if self.calls >= start:
                flags = f
        self.calls += 1
        if flags != self.flags:
            self.flag_changes += 1
        self.flags = flags
        self.inflation = 2.0 if flags else 1.0


class Sink:
    def __init__(self) -> None:
        self.sent: list[tuple[float, object]] = []
        self.mav = mavlink.MAVLink(None)

    def send_at(self, frame: bytes, t_us: int) -> None:
        for b in frame:
            m = self.mav.parse_char(bytes([b]))
            if m is not None:
                self.sent.append((t_us * 1e-6, m))

    def of(self, kind: str) -> list[tuple[float, object]]:
        return [(t, m) for t, m in self.sent if m.get_type() == kind]


def replay(fw: Firmware, path, until_s: float) -> None:
    for m in tlog_messages(str(path), fw.stats):
        if getattr(m, "time_usec", 0) > until_s * 1e6:
            break
        fw.handle(m)


@pytest.fixture
def scripted(monkeypatch):
    def make(schedule):
        monkeypatch.setattr(Scripted, "schedule", schedule)
        monkeypatch.setattr(control, "Consistency", Scripted)
        sink = Sink()
        return Firmware(Design(), FilterConfig(core="py"), sink=sink), sink  # the Python core: its monitor scripted

    return make


@pytest.mark.slow
def test_statustext_is_rate_limited_and_says_when_the_model_is_consistent_again(gusty, scripted):
    a, m, al, r, b = BIT["accel"], BIT["mag"], BIT["align"], BIT["radius"], BIT["baro"]
    schedule = ((1000, a), (1030, 0), (1060, a | m), (3000, al | r | b), (5000, 0))
    fw, sink = scripted(schedule)
    replay(fw, gusty[1], 75.0)
    assert isinstance(fw.est.consistency, Scripted) and fw.est.consistency.calls > 5500
    texts = sink.of("STATUSTEXT")
    got = [(m.severity, m.text) for _, m in texts]
    assert got == [
        (mavlink.MAV_SEVERITY_WARNING, "wind uncertain: model misfit accel (accuracy x2.0)"),
        (mavlink.MAV_SEVERITY_WARNING, "wind uncertain: misfit accel,mag (acc x2.0)"),
        (mavlink.MAV_SEVERITY_WARNING, "wind uncertain: misfit align,radius,baro x2.0"),
        (mavlink.MAV_SEVERITY_INFO, CONSISTENT_TEXT),
    ], got
    times = [t for t, _ in texts]
    # the flap at 10.0-10.3 s after the first flag is not told; the change at 10.6 s waits for the second
    assert times[1] - times[0] == pytest.approx(1.0, abs=1e-6)
    assert times[2] - times[0] == pytest.approx(20.0, abs=0.02) and times[3] - times[2] == pytest.approx(20.0, abs=0.02)
    # SYS_STATUS: each source's health bit; present and enabled never change
    status = sink.of("SYS_STATUS")
    seen = set()
    for t, st in status:
        assert st.onboard_control_sensors_present == st.onboard_control_sensors_enabled == SENSOR_BITS
        health = st.onboard_control_sensors_health
        if times[1] + 0.01 < t < times[2] - 0.01:
            assert health == SENSOR_BITS & ~(ACCEL | MAG)
            seen.add("accel,mag")
        elif times[2] + 0.01 < t < times[3] - 0.01:
            assert health == SENSOR_BITS & ~(AHRS | BARO)
            seen.add("align,radius,baro")
        elif t < times[0] - 0.01 or t > times[3] + 0.01:
            assert health == SENSOR_BITS
            seen.add("healthy")
    assert seen == {"accel,mag", "align,radius,baro", "healthy"}
    # the steps in flight with each source flagged: exactly the schedule's
    assert fw.misfit_steps == [30 + 1940, 2000, 2000, 2000, 1940, 0]
    pct = [round(100 * s / fw.flight_steps) for s in fw.misfit_steps]
    assert f", model misfit: accel {pct[0]} % of flight time, align {pct[1]} %, radius {pct[2]} %, " \
           f"baro {pct[3]} %, mag {pct[4]} %" in fw.summary()  # fmt: skip
    assert fw.texts_sent == 4
    # the live status line
    assert "misfit" not in fw.status()
    fw.est.consistency.flags = a | al
    assert fw.status().endswith(", misfit accel,align")


@pytest.mark.slow
def test_a_reboot_restarts_the_check_and_says_so(gusty, scripted):
    fw, sink = scripted(((1000, BIT["accel"]),))
    replay(fw, gusty[1], 30.0)
    replay(fw, gusty[1], 30.0)  # the sensors rebooted: time goes back
    assert fw.est.counters.time_resets == 1
    got = [(m.severity, m.text) for _, m in sink.of("STATUSTEXT")]
    warn = (mavlink.MAV_SEVERITY_WARNING, "wind uncertain: model misfit accel (accuracy x2.0)")
    assert got == [warn, (mavlink.MAV_SEVERITY_INFO, RESTARTED_TEXT), warn], got


def test_a_flight_never_flagged_is_consistent(scripted):
    fw, _ = scripted(())
    assert fw.summary().endswith(", model not judged (never in flight)")
    fw.flight_steps = 1000
    assert fw.summary().endswith(", model consistent")
    fw.misfit_steps[SOURCES.index("mag")] = 4
    assert fw.summary().endswith(", model misfit: mag <1 % of flight time")


def test_misfit_text_fits_statustext():
    every = list(SOURCES)
    for k in range(1, len(every) + 1):
        text = app.misfit_text(every[:k], 4.99)
        assert len(text) <= TEXT_MAX and "x5.0" in text and ",".join(every[:k]) in text, text
    assert app.misfit_health(BIT["align"] | BIT["radius"]) == AHRS
    assert app.misfit_health(BIT["accel"] | BIT["baro"] | BIT["mag"]) == ACCEL | BARO | MAG
