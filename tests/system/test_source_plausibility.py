"""Input plausibility of the optional sources, with counts (docs/usage.md, "A field day"): a WINCH_STATUS
whose line length is not finite, under 1 m, beyond the drum's rope (+ margin) or shorter than the
balloon's barometric height (less a tolerance), or whose reel speed is not finite or beyond a winch's, is
rejected and counted; so is a ground reference outside 300-1100 hPa or -80 to 60 C. Both cores count
alike; the firmware's summary and the reprocessed product say the counts, and why when a source is
ignored wholesale. The ground CSV is read as a stream (a byte-order mark accepted) and never written."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from balloon_core.samples import BaroSample, GroundBaroSample, ImuSample, WinchSample
from balloon_core.wire import TlogWriter
from firmware_py import cli as fw_cli
from firmware_py.core_c import new_core
from firmware_py.estimator.params import (
    GROUND_REJECT_PRESSURE,
    GROUND_REJECT_TEMPERATURE,
    WINCH_REJECT_HEIGHT,
    WINCH_REJECT_LENGTH,
    WINCH_REJECT_SPEED,
)
from firmware_py.streams import feed, feed_ground
from ground_station import cli as gs_cli
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation

DURATION_S = 40.0


@functools.lru_cache(maxsize=1)
def profile_flight():
    """profile-fast with the ground reference: 40 s at the 30 m line (the balloon near 28 m after ~15 s)."""
    sc = SCENARIOS["profile-fast"]
    truth = dataclasses.replace(sc.truth, ground_baro_hz=1.0)
    sim = Simulation(sc.design, sc.wind, truth, DURATION_S, 3, winch=sc.winch)
    samples = list(sim.samples())
    height = sim.truth[:, TRUTH_COLUMNS.index("height_m")].copy()
    return sc, samples, height


def spoiled(samples, drum_m: float):
    """The flight with implausible winch reports and ground references mixed in; (samples, expected
    rejections {reason: count} of the winch and of the ground)."""
    bad_winch = [(math.nan, 0.0, WINCH_REJECT_LENGTH), (0.5, 0.0, WINCH_REJECT_LENGTH),
                 (drum_m + 20.0, 0.0, WINCH_REJECT_LENGTH), (30.0, math.inf, WINCH_REJECT_SPEED),
                 (30.0, 50.0, WINCH_REJECT_SPEED), (1.5, 0.0, WINCH_REJECT_HEIGHT)]  # fmt: skip
    bad_ground = [(250.0, 15.0, GROUND_REJECT_PRESSURE), (1200.0, 15.0, GROUND_REJECT_PRESSURE),
                  (math.nan, 15.0, GROUND_REJECT_PRESSURE), (1013.0, 70.0, GROUND_REJECT_TEMPERATURE),
                  (1013.0, -90.0, GROUND_REJECT_TEMPERATURE),
                  (1013.0, math.inf, GROUND_REJECT_TEMPERATURE)]  # fmt: skip
    out, exp_w, exp_g = [], {}, {}
    kw = kg = 0
    for s in samples:
        t = s.time_usec * 1e-6
        winch, ground = s.winch, s.ground
        if winch is not None and t > 25.0 and kw < 6 * len(bad_winch) and round(t * 10) % 7 == 0:
            length, speed, why = bad_winch[kw % len(bad_winch)]
            winch = (length, speed, winch[2], winch[3])
            exp_w[why] = exp_w.get(why, 0) + 1
            kw += 1
        if ground is not None and t > 10.0 and kg < len(bad_ground) and round(t) % 2 == 0:
            p, c, why = bad_ground[kg]
            ground = (p, c)
            exp_g[why] = exp_g.get(why, 0) + 1
            kg += 1
        out.append(dataclasses.replace(s, winch=winch, ground=ground))
    return out, exp_w, exp_g


def as_samples(sim_samples):
    for s in sim_samples:
        if s.winch:
            length, speed, kg, status = s.winch
            yield WinchSample(s.time_usec, length, speed, kg * G0, status)
        if s.ground:
            yield GroundBaroSample(s.time_usec, *s.ground)
        if s.baro:
            yield BaroSample(s.time_usec, *s.baro)
        yield ImuSample(s.time_usec, *s.accel, *s.gyro, *s.mag)


def run_core(core: str, design, cfg, samples):
    est, _ = new_core(design, dataclasses.replace(cfg, core=core, float32=False))
    reasons_w, reasons_g = {}, {}
    for s in as_samples(samples):
        if type(s) is WinchSample or type(s) is GroundBaroSample:
            winch = type(s) is WinchSample
            before = est.winch_rejected if winch else est.ground_rejected
            feed_ground(est, s)
            if (est.winch_rejected if winch else est.ground_rejected) > before:
                reasons = reasons_w if winch else reasons_g
                why = est.winch_reject_reason if winch else est.ground_reject_reason
                reasons[why] = reasons.get(why, 0) + 1
        else:
            feed(est, s)
    return est, reasons_w, reasons_g


@pytest.mark.parametrize("core", ["py", "c"])
def test_both_cores_reject_and_count_what_is_not_plausible(core):
    sc, samples, height = profile_flight()
    assert height[int(25.0 * 100) :].min() > 16.5  # a 1.5 m line cannot hold the balloon there
    bad, exp_w, exp_g = spoiled(samples, sc.design.tether.length_m)
    assert set(exp_w) == {WINCH_REJECT_LENGTH, WINCH_REJECT_SPEED, WINCH_REJECT_HEIGHT}
    assert set(exp_g) == {GROUND_REJECT_PRESSURE, GROUND_REJECT_TEMPERATURE}
    n_winch = sum(1 for s in samples if s.winch is not None)
    n_ground = sum(1 for s in samples if s.ground is not None)
    est, got_w, got_g = run_core(core, sc.design, sc.filter, bad)
    assert got_w == exp_w and got_g == exp_g
    assert est.winch_rejected == sum(exp_w.values()) and est.winch_samples == n_winch - est.winch_rejected
    assert est.ground_rejected == sum(exp_g.values()) and est.ground_samples == n_ground - est.ground_rejected
    # the clean flight: everything used
    clean, _, _ = run_core(core, sc.design, sc.filter, samples)
    assert (clean.winch_samples, clean.winch_rejected) == (n_winch, 0)
    assert (clean.ground_samples, clean.ground_rejected) == (n_ground, 0)


def write_tlog(path: Path, samples, ground_sysid: int = 255) -> None:
    enc = SensorPacketEncoder(ground_sysid=ground_sysid)
    with open(path, "wb") as fh:
        w = TlogWriter(fh)
        for s in samples:
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)


def config_of(sc, path: Path) -> str:
    path.write_text(sc.to_toml())
    return str(path)


def test_the_fw_summary_says_what_it_used_and_why_a_source_was_ignored(tmp_path: Path, capsys):
    sc, samples, _ = profile_flight()
    drum = sc.design.tether.length_m
    # every WINCH_STATUS beyond the drum's rope: the winch is ignored wholesale, and the summary says why
    beyond = [dataclasses.replace(s, winch=(drum + 50.0, *s.winch[1:])) if s.winch else s for s in samples]
    n_winch = sum(1 for s in samples if s.winch is not None)
    n_ground = sum(1 for s in samples if s.ground is not None)
    write_tlog(tmp_path / "f.tlog", beyond)
    cfg = config_of(sc, tmp_path / "p.toml")
    assert fw_cli.main(["--in", str(tmp_path / "f.tlog"), "--config", cfg, "--quiet", "--core", "c"]) == 0
    err = capsys.readouterr().err
    assert f"winch: 0 used, {n_winch} rejected (WINCH_STATUS ignored: line length not plausible" in err
    assert f"ground reference: {n_ground} used, 0 rejected" in err


def test_reprocess_counts_a_bom_ground_csv_streams_it_and_never_writes_it(tmp_path: Path, capsys):
    import xarray as xr

    sc, samples, _ = profile_flight()
    no_ground = [dataclasses.replace(s, ground=None) for s in samples]
    write_tlog(tmp_path / "f.tlog", no_ground)
    cfg = config_of(sc, tmp_path / "p.toml")
    rows = [(t, 1013.0 + 0.01 * t, 15.0) for t in np.arange(1.0, DURATION_S, 1.0)]
    bad = {5: (1013.0, 99.0), 9: (50.0, 15.0), 13: (2000.0, 15.0)}  # row index: implausible (hPa, C)
    text = "time_s,pressure_hpa,temperature_c\r\n" + "".join(
        f"{t:.1f},{bad.get(i, (p, c))[0]:.2f},{bad.get(i, (p, c))[1]:.1f}\r\n" for i, (t, p, c) in enumerate(rows))
    # the CSV named as reprocess names its own 1 s averages: refused before any work
    csv_path = tmp_path / "w_avg_1s.csv"
    csv_path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    original = csv_path.read_bytes()
    rc = gs_cli.main(["reprocess", str(tmp_path / "f.tlog"), "--out", str(tmp_path / "w.nc"), "--config", cfg,
                      "--ground-pressure", str(csv_path), "--quiet"])  # fmt: skip
    assert rc == 2 and "--ground-pressure" in capsys.readouterr().err
    assert csv_path.read_bytes() == original
    rc = gs_cli.main(["reprocess", str(tmp_path / "f.tlog"), "--out", str(tmp_path / "x.nc"), "--config", cfg,
                      "--ground-pressure", str(csv_path), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0, err
    assert csv_path.read_bytes() == original  # only read
    with xr.open_dataset(tmp_path / "x.nc", decode_times=False) as ds:
        a = ds.attrs
        # every row after the estimator started reaches it; the implausible ones are rejected
        assert int(a["ground_reference_rejected"]) == len(bad)
        assert len(bad) < int(a["ground_reference_used"]) + len(bad) <= len(rows)
        assert int(a["ground_reference_used"]) >= len(rows) - len(bad) - 2
        n_winch = sum(1 for s in samples if s.winch is not None)
        assert int(a["winch_status_used"]) + int(a["winch_status_rejected"]) <= n_winch
        assert int(a["winch_status_rejected"]) == 0
        line = f"ground reference: {a['ground_reference_used']} used, {len(bad)} rejected"
        assert line in a["optional_sources"] and line in a["source_log_notes"]


def test_the_ground_csv_is_read_as_a_stream(tmp_path: Path):
    """A long reference file: the rows come one at a time (the reader holds none of them)."""
    import tracemalloc

    from balloon_core.groundref import ground_rows

    path = tmp_path / "g.csv"
    with open(path, "w") as fh:
        fh.write("\ufefftime_s,pressure_hpa,temperature_c\n")
        for i in range(50_000):
            fh.write(f"{i}.0,1013.25,\n")
    tracemalloc.start()
    tcol, rows = ground_rows(str(path))
    n, last = 0, None
    for row in rows:
        n, last = n + 1, row
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert tcol == "time_s" and n == 50_000 and last[:2] == (49_999.0, 1013.25) and math.isnan(last[2])
    assert peak < 300_000, peak  # 50 000 rows held as lists would take several MB
