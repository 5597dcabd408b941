"""Audit findings for balloon-replay, balloon-gs report and reprocess's log readers: each test fails without
its fix."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack

PY = sys.executable


@pytest.fixture(scope="module")
def raw_capture(tmp_path_factory):
    """A 10 s simulated flight as a raw serial capture (the tlog's frames without their record stamps), with
    some line noise between frames."""
    from sim_hil.replay import tlog_records

    d = tmp_path_factory.mktemp("raw")
    tlog = d / "sensors.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--duration", "10", "--seed", "3", "--out", str(tlog), "--quiet"],
                   check=True, capture_output=True)  # fmt: skip
    frames = [f for _, _, f in tlog_records(str(tlog))]
    clean = d / "sensors.raw"
    clean.write_bytes(b"".join(frames))
    noisy = d / "noisy.raw"
    noise = bytes([0xFD, 0x40, 0x00, 0x13, 0x37, 0x55])  # a false frame start and junk
    noisy.write_bytes(b"".join(f + (noise if k % 7 == 3 else b"") for k, f in enumerate(frames)))
    n_imu = sum(1 for _, t_imu, _ in tlog_records(str(tlog)) if t_imu is not None)
    return clean, noisy, n_imu


def test_raw_capture_is_sent_as_whole_frames_and_exactly_its_bytes(raw_capture):
    """A raw capture's pieces (one a datagram on UDP) are whole frames or runs of garbage between them: 64-byte
    chunks cut frames across datagrams, and a receiver that parses each datagram on its own (balloon-fw,
    balloon-gs) got no sample at all."""
    from sim_hil.replay import raw_chunks

    clean, noisy, n_imu = raw_capture
    for path in (clean, noisy):
        pieces = list(raw_chunks(str(path)))
        assert b"".join(p for _, _, p in pieces) == path.read_bytes()  # exactly as captured, garbage and all
        imu = 0
        for _, t_imu, piece in pieces:
            mav = mavlink.MAVLink(None)
            mav.robust_parsing = True
            msgs = [m for m in mav.parse_buffer(piece) or [] if m.get_type() != "BAD_DATA"]
            if t_imu is not None:
                imu += 1
                assert len(msgs) == 1 and len(msgs[0].get_msgbuf()) == len(piece)
                assert msgs[0].time_usec == t_imu
        assert imu == n_imu


@pytest.mark.network
def test_raw_capture_replayed_over_udp_in_lockstep_reaches_the_firmware_whole(raw_capture):
    from tests.system.test_link_loss import replay_into_firmware

    clean, _, n_imu = raw_capture
    r, fw_summary = replay_into_firmware(clean, "--speed", "0")
    assert r.returncode == 0, r.stderr
    assert int(re.search(r"(\d+) IMU samples", fw_summary).group(1)) == n_imu, fw_summary
    assert " 0 bad frames, 0 garbage bytes" in fw_summary
    last = r.stderr.strip().splitlines()[-1]
    assert f"{n_imu} IMU samples" in last and "the firmware counted 0 packets lost" in last, last


@pytest.fixture(scope="module")
def scored_flight(tmp_path_factory):
    """A 40 s flight: the firmware's WIND_COV log and the simulator's truth."""
    d = tmp_path_factory.mktemp("report")
    cap, truth, wind = d / "sensors.tlog", d / "truth.csv", d / "wind.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--duration", "40", "--seed", "4", "--out", str(cap), "--truth", str(truth),
                    "--quiet"], check=True, capture_output=True)  # fmt: skip
    subprocess.run([PY, "-m", "firmware_py", "--in", str(cap), "--out", str(wind), "--quiet"], check=True,
                   capture_output=True)  # fmt: skip
    return d, wind, truth


def report_run(capsys, *argv) -> tuple[int, str, str]:
    from ground_station.cli import main

    capsys.readouterr()
    try:
        code = main(["report", *map(str, argv)])
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def truth_variant(scored_flight, name: str, edit) -> str:
    d, _, truth = scored_flight
    lines = truth.read_text().splitlines()
    header, rows = edit(lines[0], lines[1:])
    path = d / name
    path.write_text("\n".join([header, *rows]) + "\n")
    return str(path)


def test_report_refuses_a_truth_out_of_time_order(scored_flight, capsys):
    """np.interp needs the truth in time order: shuffled rows scored 0.5 m/s RMSE with exit 0, rows reversed said
    'the truth ends at 0.0 s'."""
    _, wind, _ = scored_flight
    for name, edit in (("shuffled.csv", lambda h, r: (h, r[1::2] + r[0::2])),
                       ("reversed.csv", lambda h, r: (h, r[::-1]))):  # fmt: skip
        code, out, err = report_run(capsys, wind, "--truth", truth_variant(scored_flight, name, edit), "--start", "5")
        assert code == 2 and out == "", out
        assert len(err.strip().splitlines()) == 1 and "time_s goes back" in err and "Traceback" not in err, err


def test_report_says_the_truth_does_not_overlap_the_estimates(scored_flight, capsys):
    """A truth of another time span: 'the estimates end at 39.9 s ... (score from earlier: --start 10000)' was a
    hint that could not work."""
    _, wind, _ = scored_flight

    def shift(h, rows):
        return h, [",".join([f"{float(r.split(',')[0]) + 10000:.6f}", *r.split(",")[1:]]) for r in rows]

    code, out, err = report_run(capsys, wind, "--truth", truth_variant(scored_flight, "shifted.csv", shift))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "do not overlap" in err and "--start" not in err, err


def test_report_reads_a_truth_header_with_spaces_or_a_bom(scored_flight, capsys):
    """The contract writes the header as `time_s, wind_n, wind_e, ...`; a spreadsheet adds a BOM."""
    _, wind, truth = scored_flight
    code, ref, _ = report_run(capsys, wind, "--truth", truth, "--start", "5")
    assert code == 0
    for name, edit in (("spaces.csv", lambda h, r: (h.replace(",", ", "), [x.replace(",", ", ") for x in r])),
                       ("bom.csv", lambda h, r: ("\ufeff" + h, r))):  # fmt: skip
        code, out, err = report_run(capsys, wind, "--truth", truth_variant(scored_flight, name, edit), "--start", "5")
        assert code == 0 and out == ref, err


def test_report_refuses_two_systems_in_one_log(scored_flight, capsys):
    """Two balloons' WIND_COV in one log were merged by time (the later one of each time kept) and scored as one:
    now refused, naming --sysid, which picks one."""
    import struct

    from balloon_core.wire import LinkStats, tlog_messages

    d, wind, truth = scored_flight
    mav2 = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    out = b""
    for m in tlog_messages(str(wind), LinkStats()):
        t = struct.pack(">Q", int(m._timestamp * 1e6)) if hasattr(m, "_timestamp") else bytes(8)
        out += t + bytes(m.get_msgbuf())
        if m.get_type() == "WIND_COV":
            m2 = mavlink.MAVLink_wind_cov_message(
                m.time_usec,
                m.wind_x + 5.0,
                m.wind_y,
                m.wind_z,
                m.var_horiz,
                m.var_vert,
                m.wind_alt,
                m.horiz_accuracy,
                m.vert_accuracy,
            )
            out += t + m2.pack(mav2)
    two = d / "two.tlog"
    two.write_bytes(out)
    code, out_, err = report_run(capsys, two, "--truth", truth, "--start", "5")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "2 systems" in err and "--sysid" in err, err
    # --sysid picks the balloon: its own log's score, and the other's (5 m/s off) far worse
    code, alone, err = report_run(capsys, wind, "--truth", truth, "--start", "5")
    assert code == 0, err
    code, one, err = report_run(capsys, two, "--truth", truth, "--start", "5", "--sysid", "1")
    assert code == 0 and one == alone, err
    code, other, err = report_run(capsys, two, "--truth", truth, "--start", "5", "--sysid", "2")
    assert code == 0 and other != alone, err
    code, _, err = report_run(capsys, two, "--truth", truth, "--start", "5", "--sysid", "9")
    assert code == 2 and "no WIND_COV from system 9" in err, err


DATA = __import__("pathlib").Path(__file__).resolve().parents[1] / "data"


def test_dataflash_reader_tells_a_cut_a_damaged_stretch_and_a_stop(tmp_path):
    """DFReader drops a cut-off last record, skips a damaged stretch and stops at a record of an undefined type,
    all without a word: the flight said 'nothing lost' (a log cut to 18 % of its length, or read to 2 % only)."""
    from postflight.dataflash import read_dataflash

    data = (DATA / "balloon-sim.bin").read_bytes()
    clean = read_dataflash(str(DATA / "balloon-sim.bin")).meta
    assert clean.bad_frames == 0 and not clean.truncated and clean.unread is None
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[:140941])  # inside a record
    m = read_dataflash(str(cut)).meta
    assert m.truncated and m.bad_frames == 0 and any("truncated" in n for n in m.notes), m.notes
    zeroed = tmp_path / "zeroed.bin"
    zeroed.write_bytes(data[:177560] + bytes(4096) + data[177560 + 4096 :])
    m = read_dataflash(str(zeroed)).meta
    assert m.bad_frames == 1 and not m.truncated, m.notes
    stop = bytearray(data)  # a record's type byte damaged into a type no FMT defines, a fifth into the log
    k = stop.index(b"\xa3\x95", len(data) // 5)
    stop[k + 2] = 39
    stopped = tmp_path / "stopped.bin"
    stopped.write_bytes(bytes(stop))
    m = read_dataflash(str(stopped)).meta
    assert m.truncated and m.unread and f"stopped at byte {k} of {len(data)}" in m.unread, m.unread
    assert m.unread in m.notes


def test_ulog_reader_tells_a_cut_and_a_damaged_stretch(tmp_path):
    """pyulog stops quietly at a message cut by the file's end, and flags a damaged stretch only in
    ``file_corruption``: the product said 'nothing lost' of a log whose last 95 % went unread."""
    from postflight.ulog import read_ulog

    for name in ("pyulog-sample_px4_events.ulg", "pyulog-sample_log_small.ulg"):
        clean = read_ulog(str(DATA / name)).meta
        assert clean.bad_frames == 0 and not clean.truncated and clean.unread is None, (name, clean.notes)
    data = (DATA / "pyulog-sample_px4_events.ulg").read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:525446])  # inside a message
    m = read_ulog(str(cut)).meta
    assert m.truncated and m.bad_frames == 0 and any("truncated" in n for n in m.notes), m.notes
    small = (DATA / "pyulog-sample_log_small.ulg").read_bytes()
    zeroed = tmp_path / "zeroed.ulg"
    zeroed.write_bytes(small[:68170] + bytes(4096) + small[68170 + 4096 :])
    m = read_ulog(str(zeroed)).meta
    assert m.bad_frames >= 1 and m.truncated and m.unread and "unread" in m.unread, m.notes


def test_reprocess_of_a_cut_dataflash_log_says_so_in_the_product(tmp_path):
    xr = pytest.importorskip("xarray")
    cut = tmp_path / "cut.bin"
    cut.write_bytes((DATA / "balloon-sim.bin").read_bytes()[:596903])
    out = tmp_path / "w.nc"
    r = subprocess.run([PY, "-m", "ground_station", "reprocess", str(cut), "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "DATA LOST" in r.stderr and "truncated" in r.stderr and "Traceback" not in r.stderr, r.stderr
    with xr.open_dataset(out, decode_times=False) as ds:
        assert ds.attrs["source_log_truncated"] == "yes"
        assert "truncated" in ds.attrs["source_log_losses"]
        assert bool((ds["time"].diff("time") > 0).all())


# ---------------------------------------------------------------- report: logs of two boots, damaged values, messages


def wind_csv(records, path) -> str:
    """A ground-station CSV of these WIND_COV records (as listen --csv writes it, without the loss columns)."""
    from ground_station.wind import CSV_COLUMNS

    path.write_text(",".join(CSV_COLUMNS) + "\n" + "".join(",".join(map(str, r.csv_row())) + "\n" for r in records))
    return str(path)


@pytest.fixture(scope="module")
def products(scored_flight):
    """The flight reprocessed (``one.nc``), and the same log twice end to end (``two.nc``: a second boot)."""
    pytest.importorskip("netCDF4")
    d, _, _ = scored_flight
    sensors = (d / "sensors.tlog").read_bytes()
    (d / "twice.tlog").write_bytes(sensors + sensors)
    for src, out in (("sensors.tlog", "one.nc"), ("twice.tlog", "two.nc")):
        subprocess.run([PY, "-m", "ground_station", "reprocess", str(d / src), "--out", str(d / out), "--quiet"],
                       check=True, capture_output=True)  # fmt: skip
    return d / "one.nc", d / "two.nc"


def test_report_of_two_boots_scores_the_last_and_says_what_it_left_out(scored_flight, products, capsys, tmp_path):
    """A log of two firmware boots (time since boot starting again): keyed by time_usec, the second boot's records
    silently replaced the first's (a tlog, a CSV); a product of both was read unsorted. Now each scores the last boot
    (the same as that flight alone) and says in one line how much of how many earlier boots it left out."""
    import dataclasses

    from ground_station.wind import read_records

    _, wind, truth = scored_flight
    recs = read_records(str(wind))
    first = [dataclasses.replace(r, wind_x=r.wind_x + 5.0) for r in recs]  # another flight's wind
    two_csv = wind_csv(first + recs, tmp_path / "two.csv")
    two_tlog = tmp_path / "two.tlog"
    body = wind.read_bytes()
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    shifted = b"".join(bytes(8) + pack(mav, mavlink.MAVLink_wind_cov_message(r.time_usec, r.wind_x, r.wind_y,
                       r.wind_z, r.var_horiz, r.var_vert, r.wind_alt, r.horiz_accuracy, r.vert_accuracy))
                       for r in first)  # fmt: skip
    two_tlog.write_bytes(shifted + body)
    for two, one, n, what in ((two_tlog, wind, len(recs), "WIND_COV"), (two_csv, wind, len(recs), "WIND_COV"),
                              (products[1], products[0], None, "estimates")):  # fmt: skip
        for extra in ((), ("--truth", truth)):
            code, ref, _ = report_run(capsys, one, *extra, "--start", "5")
            assert code == 0
            code, out, err = report_run(capsys, two, *extra, "--start", "5")
            assert code == 0 and out == ref, (two, err)
            note = err.strip().splitlines()
            assert len(note) == 1 and "holds 2 boots" in note[0] and "earlier boot left out" in note[0], err
            if n is not None:
                assert f"only the last boot's {n} WIND_COV are used; {n} WIND_COV of 1 earlier" in note[0], err
            assert what in note[0]


def test_late_packets_are_no_boot_and_a_short_last_boot_gives_way_to_the_longest(capsys, tmp_path):
    """Two late packets at a log's end (50.0, 50.1 s after 99.9 s), or a burst of four (30.0-30.3 s) after which the
    clock runs on from 50.0 s, were taken for a second boot: the flight was dropped for them, or the log refused. Now
    a boot needs all BOOT_CONFIRM samples after it and no jump back to the old clock; a last boot of fewer than 10
    samples (a reboot as the log ended) gives way to the longest, and the note says so."""
    import numpy as np

    from ground_station.report import boot_starts, read_estimate
    from ground_station.wind import WindRecord

    run = np.round(np.arange(0.0, 100.0, 0.1), 1)
    tail = np.concatenate([run, [50.0, 50.1]])
    burst = np.concatenate([run[:500], [30.0, 30.1, 30.2, 30.3], run[500:]])
    short = np.concatenate([run, run[:5]])
    assert boot_starts(tail) == [0] and boot_starts(burst) == [0]
    assert boot_starts(short) == [0, 1000] and boot_starts(np.concatenate([run, run])) == [0, 1000]

    def log(times, name):
        return wind_csv([WindRecord(round(t * 1e6), 1, 1, 1.0, 2.0, 0.0, 0.25, 0.1, 100.0, 0.5, 0.3) for t in times],
                        tmp_path / name)  # fmt: skip

    for times, name in ((tail, "tail.csv"), (burst, "burst.csv")):
        notes: list[str] = []
        est = read_estimate(log(times, name), None, notes)
        assert notes == [] and est["time_s"][0] == 0.0 and est["time_s"][-1] == pytest.approx(99.9), name
    notes = []
    est = read_estimate(log(short, "short.csv"), None, notes)
    assert len(est["time_s"]) == 1000 and est["time_s"][-1] == pytest.approx(99.9)
    assert len(notes) == 1 and "the last boot holds only 5 WIND_COV (fewer than 10)" in notes[0], notes
    assert "the longest, boot 1's 1000 WIND_COV (WIND_COV 1-1000) are used; 5 WIND_COV" in notes[0], notes
    code, out, err = report_run(capsys, str(tmp_path / "short.csv"), "--start", "5")
    assert code == 0 and "the longest, boot 1's" in err, err
    code, out, err = report_run(capsys, log(np.concatenate([run, run[:20]]), "two.csv"))  # its 2 s before --start
    assert code == 2 and len(err.strip().splitlines()) == 1 and out == "", err
    assert "fewer than 2 known winds" in err and "(note: " in err and "holds 2 boots" in err, err


def test_report_leaves_accuracies_that_are_not_numbers_out_and_counts_them(scored_flight, products, capsys, tmp_path):
    """One NaN horiz_accuracy made the score say "horiz_accuracy nan m/s (actual error / accuracy inf)" with exit 0;
    all of them inf said "inf m/s ... 0.00". Now a non-finite accuracy is left out of the accuracy's statistics and
    counted; with none finite the accuracy cannot be judged: exit 2, one line."""
    import dataclasses

    import netCDF4
    import numpy as np

    from ground_station.wind import read_records

    _, wind, truth = scored_flight
    recs = read_records(str(wind))
    k = next(i for i, r in enumerate(recs) if r.time_usec > 20_000_000)
    one_nan = wind_csv([dataclasses.replace(r, horiz_accuracy=math.nan) if i == k else r for i, r in enumerate(recs)],
                       tmp_path / "nan.csv")  # fmt: skip
    all_inf = wind_csv([dataclasses.replace(r, horiz_accuracy=math.inf) for r in recs], tmp_path / "inf.csv")
    nc = tmp_path / "nan.nc"
    nc.write_bytes(products[0].read_bytes())
    with netCDF4.Dataset(nc, "a") as ds:
        t = ds["time_since_boot"][:]
        u = ds["eastward_wind_uncertainty"][:]
        u[int(np.argmax(t > 20.0))] = np.nan
        ds["eastward_wind_uncertainty"][:] = u
    for path in (one_nan, nc):
        code, out, err = report_run(capsys, path, "--truth", truth, "--start", "5")
        assert code == 0, err
        assert "1 accuracy not finite, left out" in out and "nan" not in out and "inf" not in out, out
    code, out, err = report_run(capsys, all_inf, "--truth", truth, "--start", "5")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "no finite horiz_accuracy" in err and "Traceback" not in err, err


def test_report_says_what_is_wrong_with_a_damaged_csv_or_product(scored_flight, products, capsys, tmp_path):
    """A spreadsheet's BOM read "no column time_usec"; binary garbage gave a codec error without the file's name; a
    CSV cut mid-row "int() argument must be ... not 'NoneType'"; a product whose time runs backward "do not overlap";
    one with no finite wind "fewer than 10 WIND_COV messages". A BOM is now read; the rest say what is wrong."""
    import random

    import netCDF4
    import numpy as np

    from ground_station.wind import read_records

    _, wind, truth = scored_flight
    plain = wind_csv(read_records(str(wind)), tmp_path / "plain.csv")
    text = open(plain, "rb").read()
    code, ref, _ = report_run(capsys, plain, "--truth", truth, "--start", "5")
    assert code == 0
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + text)
    code, out, err = report_run(capsys, bom, "--truth", truth, "--start", "5")
    assert code == 0 and out == ref, err
    garbage = tmp_path / "garbage.csv"
    garbage.write_bytes(random.Random(1).randbytes(5000))
    cut = tmp_path / "cut.csv"
    cut.write_bytes(text[: text.index(b"\n", 20_000) + 20])  # 20 bytes into a row
    line = text[: len(cut.read_bytes())].count(b"\n") + 1
    reversed_nc, nan_nc = tmp_path / "reversed.nc", tmp_path / "nan.nc"
    for path in (reversed_nc, nan_nc):
        path.write_bytes(products[0].read_bytes())
    with netCDF4.Dataset(reversed_nc, "a") as ds:
        ds["time_since_boot"][:] = ds["time_since_boot"][:][::-1]
    with netCDF4.Dataset(nan_nc, "a") as ds:
        ds["eastward_wind"][:] = np.nan
    for path, says in ((garbage, "not a text CSV"), (cut, f"line {line} is incomplete"),
                       (reversed_nc, "time goes back"), (nan_nc, "no finite wind")):  # fmt: skip
        before = path.read_bytes()
        code, out, err = report_run(capsys, path, "--truth", truth, "--start", "5")
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert str(path) in err and says in err and "Traceback" not in err, err
        assert path.read_bytes() == before
