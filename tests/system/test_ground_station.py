"""Ground station: WIND_COV from any vehicle, direction convention, CSV round trip, report errors."""

import io
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.score import direction_from_deg
from balloon_core.wire import pack
from ground_station.listen import GroundStation
from ground_station.wind import read_records


def px4_wind(seq_mav, t_us, n, e):
    return pack(seq_mav, seq_mav.wind_cov_encode(t_us, n, e, 0.0, 0.5, 0.1, 120.0, 0.0, 0.0))


def test_direction_is_where_the_wind_comes_from():
    assert direction_from_deg(0.0, 3.0) == pytest.approx(270.0)  # blowing east: from the west
    assert direction_from_deg(-2.0, 0.0) == pytest.approx(0.0)  # blowing south: from the north
    assert direction_from_deg(1.0, -1.0) == pytest.approx(135.0)


def test_any_vehicle_csv_and_losses(tmp_path):
    from balloon_core.wire import Decoder

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
    dec.feed(b"\xfd\x09\x00\x00\x07\x2a\x01\xe7\x00\x00" + b"\x00" * 11, datagram=True)  # a corrupt WIND_COV
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


def _two_balloons(gs, now):
    from balloon_core.wire import Decoder

    dec = Decoder(gs.stats)
    for sysid, mode in ((3, 2), (12, 1)):
        mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        frames = [pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0,
                                                 mode, 4)),
                  pack(mav, mav.sys_status_encode(15, 15, 15, 0, 0xFFFF, -1, -1, 125, 0, 9, 2, 0, 0))]  # fmt: skip
        frames += [px4_wind(mav, 5_000_000 + 100_000 * i, 2.0 * sysid / 3, 1.0) for i in range(5)]
        for f in frames:
            for m in dec.feed(f):
                gs.handle(m, now)


@pytest.mark.parametrize("width", [80, 120, 200])
def test_live_view_fits_the_width_and_marks_stale(width):
    from rich.console import Console

    gs = GroundStation(out=io.StringIO())
    _two_balloons(gs, 100.0)
    for now, stale in ((100.5, False), (103.0, True)):
        con = Console(width=width, record=True, file=io.StringIO(), force_terminal=True)
        con.print(gs.view(now, width))
        lines = con.export_text().splitlines()
        assert all(len(ln) <= width for ln in lines) and len(lines) <= 24
        rows = [ln for ln in lines if ln.split() and ln.split()[0] in ("3", "12")]
        assert len(rows) == 2
        assert all(("STALE" in r) == stale for r in rows)
        assert "taut" in rows[0] and "free" in rows[1] and "1.2" in rows[0]  # mode, input loss 1.25 %
    plain = gs.status_lines(103.0)
    assert len(plain) == 2 and all("STALE" in ln and "resets 2" in ln for ln in plain)
    assert not any("STALE" in ln for ln in gs.status_lines(100.5))


def _balloon_says(gs, dec, mav, now, health, text=None, severity=mavlink.MAV_SEVERITY_WARNING):
    """One second of a balloon-fw: HEARTBEAT, SYS_STATUS with these health bits, a WIND_COV, a STATUSTEXT."""
    present = 15 | mavlink.MAV_SYS_STATUS_AHRS
    frames = [pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, 2, 4)),
              pack(mav, mav.sys_status_encode(present, present, health, 0, 0xFFFF, -1, -1, 0, 0, 0, 0, 0, 0)),
              px4_wind(mav, 5_000_000, 2.0, 1.0)]  # fmt: skip
    if text is not None:
        frames.append(pack(mav, mav.statustext_encode(severity, text.encode())))
    for f in frames:
        for m in dec.feed(f):
            gs.handle(m, now)


@pytest.mark.parametrize("width", [80, 120, 200])
def test_live_view_shows_the_balloons_misfit_and_its_message(width):
    from rich.console import Console

    from balloon_core.wire import Decoder

    def view(now):
        con = Console(width=width, record=True, file=io.StringIO(), force_terminal=True)
        con.print(gs.view(now, width))
        lines = con.export_text().splitlines()
        assert all(len(ln) <= width for ln in lines) and len(lines) <= 24
        rows = [ln for ln in lines if ln.split() and ln.split()[0] == "3"]
        assert len(rows) == 1
        return rows[0], [ln for ln in lines if ln.startswith("sys 3: ")]

    gs = GroundStation(out=io.StringIO())
    dec, mav = Decoder(gs.stats), mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    healthy = 15 | mavlink.MAV_SYS_STATUS_AHRS
    _balloon_says(gs, dec, mav, 100.0, healthy)
    row, said = view(100.5)
    assert "OK" in row and "MISFIT" not in row and said == []
    # accelerometer and tether model flagged: health bits 3D_ACCEL and AHRS cleared, and the warning
    text = "wind uncertain: misfit accel,align (acc x2.8)"
    flagged = healthy & ~(mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mavlink.MAV_SYS_STATUS_AHRS)
    _balloon_says(gs, dec, mav, 101.0, flagged, text)
    v = gs.vehicles[3]
    assert v.misfit() == ["accel", "model"] and v.warning_active()
    row, said = view(101.5)
    assert "MISFIT" in row and "OK" not in row
    assert said == [f"sys 3: {text} (WARNING, 0 s ago)"]  # 72 characters: fits 80
    plain = gs.status_lines(101.5)[0]
    assert "MISFIT accel,model" in plain and f"said: {text} (WARNING, 0 s ago)" in plain
    # the wind stops: STALE says more than MISFIT; the message stays, with its age
    row, said = view(105.0)
    assert "STALE" in row and said == [f"sys 3: {text} (WARNING, 4 s ago)"]
    # cleared: healthy again, the all-clear is the last message, no warning active
    _balloon_says(gs, dec, mav, 110.0, healthy, "wind model consistent again", mavlink.MAV_SEVERITY_INFO)
    row, said = view(110.5)
    assert "OK" in row and "MISFIT" not in row and not gs.vehicles[3].warning_active()
    assert said == ["sys 3: wind model consistent again (INFO, 0 s ago)"]


def test_an_unhealthy_sensor_of_another_vehicle_is_not_a_misfit():
    from balloon_core.wire import Decoder

    gs = GroundStation(out=io.StringIO())
    px4 = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    dec = Decoder(gs.stats)
    for f in (pack(px4, px4.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4)),
              pack(px4, px4.sys_status_encode(15, 15, 13, 0, 0xFFFF, -1, -1, 0, 0, 0, 0, 0, 0)),
              px4_wind(px4, 1_000_000, 1.0, 1.0)):  # fmt: skip
        for m in dec.feed(f):
            gs.handle(m, 0.0)
    assert gs.vehicles[42].misfit() == [] and "MISFIT" not in gs.status_line(0.5)


def test_only_true_duplicates_are_dropped_not_a_sequence_cycle_later():
    """A HEARTBEAT that does not change comes back byte for byte once the 8-bit sequence wraps (every 256 frames of its
    sender: 16 s at balloon-fw's 16 frames a second). Not a duplicate; the same frame twice (two links) is."""
    from balloon_core.wire import Decoder

    gs = GroundStation(out=io.StringIO())
    dec = Decoder(gs.stats)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    other = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
    hb = [pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, 2, 4))
          for _ in range(600)]  # fmt: skip
    assert hb[0] == hb[256] == hb[512]  # the same bytes, a cycle apart
    taken = 0
    for i, f in enumerate(hb):
        frames = [f, px4_wind(other, 1000 * i, 1.0, 1.0)]  # another sender's traffic in between
        if i % 100 == 7:
            frames.append(f)  # a true duplicate: the same frame again at once (a second link)
        for frame in frames:
            for m in dec.feed(frame):
                taken += gs.handle(m, 0.0) and m.get_srcSystem() == 1
    assert taken == 600 and gs.duplicates == 6
    assert gs.stats.lost == 0


def _recording(tmp_path):
    """A PX4 vehicle's WIND_COV at 10 Hz for 20 s (3 m/s from 135°), one frame lost, as a tlog (record times 0.1 s
    apart) and as the raw bytes of the same frames."""
    from balloon_core.wire import TlogWriter

    px4 = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    frames = [(0, pack(px4, px4.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4)))]
    frames += [(100_000 * i, pack(px4, px4.wind_cov_encode(100_000 * i, 2.1213, -2.1213, 0.0, 0.5, 0.1, 120.0, 0.4,
                                                           0.0))) for i in range(200)]  # fmt: skip
    del frames[51]  # lost on the way
    tlog, raw = tmp_path / "flight.tlog", tmp_path / "capture.raw"
    with open(tlog, "wb") as fh:
        w = TlogWriter(fh)
        for t, f in frames:
            w.write(t, f)
    raw.write_bytes(b"".join(f for _, f in frames))
    return tlog, raw


def test_listen_reads_a_recorded_link_as_it_came(tmp_path):
    """``balloon-gs listen FILE``: a .tlog or a raw capture through the station at once, logged to CSV as a live
    run logs it (each WIND_COV once, the loss counted), the view at the recording's end; ``--duration`` keeps the
    recording's first seconds; the ground reference needs a live link (exit 2, one line); the input is untouched."""
    import subprocess
    import sys

    tlog, raw = _recording(tmp_path)
    before = tlog.read_bytes()
    for src, name in ((tlog, "a.csv"), (raw, "b.csv")):
        r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(src), "--csv", str(tmp_path / name)],
                           capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert "from 135.0 deg" in r.stdout and "199 WIND_COV from 1 system" in r.stderr and "1 lost" in r.stderr
        recs = read_records(str(tmp_path / name))
        assert len(recs) == 199 and {x.sysid for x in recs} == {42}
        assert [x.time_usec for x in recs][:51] == [100_000 * i for i in range(52) if i != 50]
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(tlog), "--duration", "5",
                        "--csv", str(tmp_path / "c.csv")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and len(read_records(str(tmp_path / "c.csv"))) == 50  # 0-5 s, the one at 5.0 s lost
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(tlog), "--ground-pressure", str(raw)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "live link" in r.stderr
    for opt in ("--csv", "--tlog"):  # the recording is an input: no log may overwrite it
        r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(tlog), opt, str(tlog)],
                           capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 2 and "input" in r.stderr
    assert tlog.read_bytes() == before


def test_report_without_a_truth_summarises_the_estimate(tmp_path):
    """A real flight has no truth: ``balloon-gs report FILE`` says what the estimate says of itself (the mean wind,
    where it comes from, the accuracy it stated) and draws it; too little after ``--start`` is a user error."""
    import subprocess
    import sys

    tlog, _ = _recording(tmp_path)
    plot = tmp_path / "w.png"
    r = subprocess.run([sys.executable, "-m", "ground_station", "report", str(tlog), "--start", "5",
                        "--plot", str(plot)], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "mean wind 3.00 m/s from 135.0 deg" in r.stdout and "horiz_accuracy 0.40 m/s" in r.stdout
    assert plot.stat().st_size > 10_000
    r = subprocess.run([sys.executable, "-m", "ground_station", "report", str(tlog), "--start", "30"],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "--start" in r.stderr


def test_a_recording_of_two_balloons_is_heard_on_one_clock_and_logged_with_its_times(tmp_path):
    """A raw capture of two balloons booted 5000 s apart (the second heard from half-way): ``--duration 60`` keeps the
    recording's first minute of both; a tlog read again is logged with its own record times, not the reading's."""
    import subprocess
    import sys

    from balloon_core.wire import LinkStats, tlog_messages

    one, two = (mavlink.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 2))
    raw = bytearray()
    for i in range(1000):  # 100 s at 10 Hz
        raw += pack(one, one.wind_cov_encode(100_000 * i, 3.0, -2.0, 0.0, 0.2, 0.0, 100.0, 0.3, 0.0))
        if i >= 500:
            raw += pack(two, two.wind_cov_encode(5_000_000_000 + 100_000 * i, 1.0, 1.0, 0.0, 0.2, 0.0, 100.0, 0.3, 0.0))
    (tmp_path / "two.raw").write_bytes(bytes(raw))
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(tmp_path / "two.raw"), "--duration", "60",
                        "--csv", str(tmp_path / "two.csv")], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    by_sys = [x.sysid for x in read_records(str(tmp_path / "two.csv"))]
    assert by_sys.count(1) == 601 and by_sys.count(2) == 101  # 0-60 s of the first, 50-60 s of the second
    tlog, _ = _recording(tmp_path)
    out = tmp_path / "o.tlog"
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(tlog), "--tlog", str(out)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    t_in, t_out = ([m._timestamp for m in tlog_messages(str(p), LinkStats())] for p in (tlog, out))
    assert t_out == t_in and t_out[-1] - t_out[0] == pytest.approx(19.9)


def _damage_stamp(tlog, k: int) -> bytes:
    """The tlog with the top byte of record ``k``'s 8-byte time set to 0x10 (1.15e12 s ahead; its frame whole), and
    a frame of a message id the dialect lacks (a CRC no one can check) after it; the original bytes."""
    from balloon_core.wire import frame_length

    data = bytearray(tlog.read_bytes())
    i = n = 0
    while n < k:
        i += 8 + frame_length(data, i + 8)
        n += 1
    data[i] = 0x10
    frame = bytearray(data[i + 8 : i + 8 + frame_length(data, i + 8)])
    frame[7:10] = (12345).to_bytes(3, "little")  # WIND_COV's bytes under an id no dialect has
    end = i + 8 + len(frame)
    data[end:end] = bytes(1) + data[i + 1 : i + 8] + bytes(frame)  # the damaged record's time as it was (top byte 0)
    return bytes(data)


def test_plausible_record_times_judges_a_time_by_the_records_around_it():
    """A tlog record's time has no CRC: one far from the clock is damaged unless the records after it run on from it
    (a recording resumed after a pause); the first of a file is judged by those after it too."""
    from balloon_core.wire import LinkStats, plausible_record_times

    def judged(times):
        stats = LinkStats()
        out = [t for _, t in plausible_record_times(((k, t) for k, t in enumerate(times)), stats)]
        return out, stats.bad_stamps

    run = [0.1 * k for k in range(30)]
    assert judged(run) == (run, 0)
    assert judged(run[:10] + [1.15e12] + run[10:]) == (run[:10] + [None] + run[10:], 1)  # ahead, then back
    assert judged(run[:10] + [-5e8] + run[10:]) == (run[:10] + [None] + run[10:], 1)  # far behind
    for jump in (2147.48, 16.78, -2147.48):  # bit 7 of byte 4 or bit 0 of byte 4 of its 8: under an hour off
        assert judged(run[:10] + [run[10] + jump] + run[11:]) == (run[:10] + [None] + run[11:], 1), jump
    assert judged([1.15e12] + run) == ([run[0]] + run, 1)  # the first one: the first plausible time, counted
    assert judged([1.15e12, -5e8] + run) == ([run[0]] * 2 + run, 2)
    assert judged([1.15e12]) == ([1.15e12], 0)  # alone: nothing to judge it by
    assert judged(run + [1.15e12]) == (run + [None], 1)  # the last one, with nothing after it to confirm it
    resumed = run + [7200.0 + t for t in run]  # two hours' pause: confirmed by what follows
    assert judged(resumed) == (resumed, 0)
    paused = run + [60.0 + t for t in run]  # a minute's pause: the same
    assert judged(paused) == (paused, 0)
    assert judged([5.0]) == ([5.0], 0)


def test_listen_a_damaged_record_time_is_counted_and_does_not_move_the_clock(tmp_path):
    """One tlog record whose 8-byte time was damaged (1.15e12 s ahead, its frame whole) moved the recording's clock
    for good: ``--duration 10`` cut the rest silently after 6 s, the --tlog log was stamped in the year 38000, the
    view said STALE for 1e12 s. Now it is counted in the summary and does not move the clock; a frame of an unknown
    message id (its CRC unchecked) is not copied into the --tlog log (pymavlink could not read it back)."""
    import subprocess
    import sys

    from balloon_core.wire import LinkStats, frame_length, tlog_messages
    from ground_station import cli

    tlog, _ = _recording(tmp_path)
    ok_csv, csv, out = tmp_path / "ok.csv", tmp_path / "w.csv", tmp_path / "o.tlog"
    assert cli.main(["listen", str(tlog), "--duration", "10", "--csv", str(ok_csv)]) == 0
    damaged = tmp_path / "damaged.tlog"
    damaged.write_bytes(_damage_stamp(tlog, 60))  # the record at 5.9 s
    before = damaged.read_bytes()
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(damaged), "--duration", "10", "--csv",
                        str(csv), "--tlog", str(out)], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "1 record time damaged (not used)" in r.stderr, r.stderr
    assert "1 frame of an unknown message id not logged" in r.stderr, r.stderr
    assert "STALE" not in r.stdout and "t=   10.0s" in r.stdout, r.stdout
    assert [r.time_usec for r in read_records(str(csv))] == [r.time_usec for r in read_records(str(ok_csv))]
    logged = list(tlog_messages(str(out), LinkStats()))
    assert not any(m.get_type().startswith("UNKNOWN") for m in logged)
    stamps = [m._timestamp for m in logged]
    assert max(stamps) - min(stamps) == pytest.approx(10.0)  # the recording's 0-10 s, none in the far future
    assert damaged.read_bytes() == before
    near, at = bytearray(tlog.read_bytes()), 0  # bit 7 of byte 4 of the record at 5.9 s: 2147 s ahead, under an hour
    for _ in range(60):
        at += 8 + frame_length(near, at + 8)
    near[at + 4] ^= 0x80
    damaged.write_bytes(bytes(near))
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(damaged), "--duration", "10", "--csv",
                        str(csv)], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and "1 record time damaged (not used)" in r.stderr, r.stderr
    assert "STALE" not in r.stdout and "t=   10.0s" in r.stdout, r.stdout
    assert [r.time_usec for r in read_records(str(csv))] == [r.time_usec for r in read_records(str(ok_csv))]


def test_listen_a_damaged_time_on_the_first_record_takes_the_first_plausible_one(tmp_path):
    """A damaged time on a tlog's first record was read as None: the --tlog log stamped it with the reading's wall
    clock (now, the recording's other records a year before) and ``web`` put it at the recording's end. Now it takes
    the first plausible time (the records after it tell it) and is counted."""
    import subprocess
    import sys

    from balloon_core.wire import LinkStats, tlog_messages
    from ground_station.listen import recording

    tlog, _ = _recording(tmp_path)
    damaged, out = tmp_path / "damaged.tlog", tmp_path / "o.tlog"
    damaged.write_bytes(b"\x10" + tlog.read_bytes()[1:])  # the first record's top byte: 1.15e12 s ahead
    stats = LinkStats()
    times = [t for _, t in recording(str(damaged), stats)]
    assert stats.bad_stamps == 1 and None not in times and times[0] == times[1] == min(times)
    assert max(times) - min(times) == pytest.approx(19.9)
    r = subprocess.run([sys.executable, "-m", "ground_station", "listen", str(damaged), "--tlog", str(out)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0 and "1 record time damaged (not used)" in r.stderr, r.stderr
    stamps = [m._timestamp for m in tlog_messages(str(out), LinkStats())]
    assert min(stamps) == times[0] and max(stamps) - min(stamps) == pytest.approx(19.9), stamps[:3]


def test_listen_duration_on_a_recording_without_wind_refuses_it(tmp_path, capfd):
    """``listen FILE --duration 10`` on a heartbeat-only tlog exited 0 with a header-only --csv (the refusal was left
    to a file read whole). Now a cut with no WIND_COV reads the rest for one: none, exit 2, one line, no log; a
    recording whose WIND_COV start after the cut is still taken."""
    from balloon_core.wire import TlogWriter
    from ground_station import cli

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)

    def tlog(name: str, wind_from_s: float | None):
        path = tmp_path / name
        with open(path, "wb") as fh:
            w = TlogWriter(fh)
            for k in range(30):  # 30 s at 1 Hz
                w.write(1_000_000 * k, pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON,
                                                                      mavlink.MAV_AUTOPILOT_GENERIC, 0, 2, 4)))
                if wind_from_s is not None and k >= wind_from_s:
                    w.write(1_000_000 * k, pack(mav, mav.wind_cov_encode(1_000_000 * k, 1.0, 2.0, 0.0, 0.5, 0.1,
                                                                         100.0, 0.4, 0.0)))  # fmt: skip
        return path

    hb = tlog("hb.tlog", None)
    capfd.readouterr()
    code = cli.main(["listen", str(hb), "--duration", "10", "--csv", str(tmp_path / "w.csv")])
    got = capfd.readouterr()
    assert code == 2 and len(got.err.strip().splitlines()) == 1 and got.out == "", got
    assert "30 MAVLink frames but no WIND_COV" in got.err, got.err
    assert not (tmp_path / "w.csv").exists()
    late = tlog("late.tlog", 20.0)
    assert cli.main(["listen", str(late), "--duration", "10", "--csv", str(tmp_path / "w.csv")]) == 0
    assert read_records(str(tmp_path / "w.csv")) == []


@pytest.mark.parametrize("what", ["empty", "noise", "png", "no wind"])
def test_listen_and_web_refuse_a_file_that_is_no_recording_of_wind(tmp_path, capfd, what):
    """``listen FILE`` took an empty file, random bytes or a picture with exit 0 ("0 WIND_COV") and left a
    header-only --csv; ``balloon-fw`` and ``balloon-replay`` refuse them. Now listen and web refuse them alike: exit
    2, one line, no output file, the file untouched."""
    import random

    from ground_station import cli

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    data = {"empty": b"", "noise": random.Random(1).randbytes(20_000),
            "png": b"\x89PNG\r\n\x1a\n" + random.Random(2).randbytes(5_000),
            "no wind": b"".join(pack(mav, mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON,
                                                               mavlink.MAV_AUTOPILOT_GENERIC, 0, 2, 4))
                                for _ in range(20))}[what]  # fmt: skip
    path = tmp_path / "input.raw"
    path.write_bytes(data)
    capfd.readouterr()
    code = cli.main(["listen", str(path), "--csv", str(tmp_path / "w.csv"), "--tlog", str(tmp_path / "g.tlog")])
    got = capfd.readouterr()
    assert code == 2 and len(got.err.strip().splitlines()) == 1 and got.out == "", got
    assert str(path) in got.err and ("no MAVLink frame" in got.err or "no WIND_COV" in got.err), got.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["input.raw"]  # no log, no temporary file
    if what in ("empty", "no wind"):
        pytest.importorskip("aiohttp")
        assert cli.main(["web", str(path), "--bind", "127.0.0.1:0"]) == 2
        err = capfd.readouterr().err
        assert len(err.strip().splitlines()) == 1 and str(path) in err, err
    assert path.read_bytes() == data
