"""benchmarks.bench_accuracy's tables from made-up flight results: targets marked, steady skill '-',
cross-wind rows only where driven, missing scenarios skipped, JSON written, the worst window named."""

import json

import pytest

from benchmarks import bench_accuracy as ba


def flight(name, seed, skill=0.8, speed=1.0, direction=0.5, ratio=1.0, response=None):
    r = {"scenario": name, "seed": seed, "duration_s": 600.0, "taut_resets": 0, "tilt_err_deg": 0.5,
         "yaw_err_deg": 0.3, "elapsed_s": 1.0,
         "score": {"band_skill": skill, "band_rmse_mps": 0.1, "speed_error_pct": speed,
                   "direction_error_deg": direction, "error_ratio": ratio}}  # fmt: skip
    if response is not None:
        r["response"] = response
    return r


class NoPool:
    """multiprocessing.Pool's part main uses, in this process (a monkeypatched ``one`` is not picklable)."""

    def __init__(self, n):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False

    def imap_unordered(self, fn, jobs):
        return map(fn, jobs)


def row(lines, name, axis=""):
    return next(ln for ln in lines if ln.startswith(f"{name:28s} {axis}"))


def test_summary_marks_the_worst_seed_against_each_target():
    res = [flight("paper-reference", 1), flight("paper-reference", 2, skill=0.6, speed=-3.5, ratio=1.5),
           flight("better-baro", 1), flight("steady", 1, skill=float("nan"), direction=2.5)]  # fmt: skip
    lines = ba.summary_table(["paper-reference", "better-baro", "steady"], res)
    ref = row(lines, "paper-reference")
    assert "0.70 [ 0.60]!" in ref and "2.25 [ 3.50]!" in ref and "1.25 [ 1.50]!" in ref
    assert "!" not in row(lines, "better-baro")
    steady = row(lines, "steady")
    assert steady.split()[1] == "-" and "2.50 [ 2.50]!" in steady


def test_response_table_marks_h_error_and_leaves_undriven_cross_out():
    h = {0.01: {"along": 1.0 + 0.1j, "cross": None}, 0.02: {"along": 0.9 - 0.2j, "cross": None},
         0.05: {"along": 0.5 - 0.5j, "cross": None}, 0.1: {"along": 0.2 - 0.9j, "cross": None}}  # fmt: skip
    lines = ba.response_table(["multisine"], [flight("multisine", 1, response=h)])
    along = row(lines, "multisine", "along")
    cells = along.split("]")
    marks = [c[0] for c in cells[1:]]  # what follows each cell's [worst]
    assert cells[0].endswith("0.10 [0.10") and cells[2].endswith("0.71 [0.71")
    assert marks == [" ", " ", "!", " "]  # 0.05 Hz misses |H-1| <= 0.3; 0.1 Hz has no target
    assert "(not driven)" in row(lines, "multisine", "cross")


def test_unknown_scenarios_are_skipped_and_json_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(ba, "one", lambda job: flight(job[0], job[1]))

    monkeypatch.setattr(ba, "Pool", NoPool)
    out = tmp_path / "r.json"
    ba.main(["--seeds", "2", "--scenarios", "paper-reference", "no-such-scenario", "--json", str(out)])
    cap = capsys.readouterr()
    assert "skipping 'no-such-scenario'" in cap.out and "[2/2] paper-reference" in cap.err
    doc = json.loads(out.read_text())
    assert doc["skipped"] == ["no-such-scenario"] and [r["seed"] for r in doc["results"]] == [1, 2]


def test_a_scenario_flies_from_another_direction_with_its_own_wind():
    """NAME@DEG is the scenario with only the wind's direction changed (the wind in its own axes, the design, the
    truth and the filter as they were); --directions N spreads N of them 360/N apart from the scenario's own."""
    from sim_hil.scenarios import SCENARIOS

    base = SCENARIOS["multisine-2d"]
    assert base.wind.from_deg == 270.0  # the expectations below start there
    turned = ba.lookup("multisine-2d@170")
    assert turned.wind.from_deg == 170.0
    assert turned.wind.multisine_hz == base.wind.multisine_hz and turned.wind.mean_mps == base.wind.mean_mps
    assert (turned.design, turned.truth, turned.filter) == (base.design, base.truth, base.filter)
    assert ba.lookup("multisine-2d@-90").wind.from_deg == 270.0 and ba.lookup("multisine-2d@-1e-20").wind.from_deg == 0
    for bad in ("multisine-2d@north", "multisine-2d@nan", "no-such-scenario@10"):
        assert ba.lookup(bad) is None
    assert ba.directions(["multisine-2d", "nonesuch"], 4) == [
        "multisine-2d@270", "multisine-2d@0", "multisine-2d@90", "multisine-2d@180", "nonesuch"]  # fmt: skip
    assert ba.directions(["multisine-2d"], 16)[:3] == ["multisine-2d@270", "multisine-2d@292.5", "multisine-2d@315"]
    assert ba.directions(["multisine-2d"], 1) == ["multisine-2d"]
    # one flight per direction however it is written
    assert ba.directions(["steady@90", "steady@90.0", "steady@450", "steady@-270"], 1) == ["steady@90"]


def test_directions_fly_each_turned_scenario_once(capsys, monkeypatch):
    flown = []
    monkeypatch.setattr(ba, "one", lambda job: flown.append(job[:2]) or flight(job[0], job[1]))

    monkeypatch.setattr(ba, "Pool", NoPool)
    ba.main(["--seeds", "1", "--scenarios", "steady", "steady@0", "--directions", "4", "--quiet"])
    assert sorted(flown) == sorted([("steady@270", 1), ("steady@0", 1), ("steady@90", 1), ("steady@180", 1)])
    assert "steady@90 " in capsys.readouterr().out


@pytest.mark.parametrize("argv, says", [(["--directions", "0"], "--directions 0"),
                                        (["--directions", "abc"], "invalid int value"),
                                        (["--scenarios", "steady@north"], "'steady@north'"),
                                        (["--window", "100"], "--window 100"),
                                        (["--window", "900"], "--window 900"),
                                        (["--duration", "120"], "give at least 150 s"),
                                        (["--duration", "nan"], "--duration nan")])  # fmt: skip
def test_bad_directions_are_a_user_error(argv, says, capsys):
    with pytest.raises(SystemExit) as e:
        ba.main(argv + (["--scenarios", "steady"] if "--scenarios" not in argv else []))
    err = capsys.readouterr().err
    assert e.value.code == 2 and says in err and err.strip().count("\n") == 0


def test_windows_cover_the_scored_flight_and_leave_a_short_tail_out():
    assert ba.windows(3600.0, 600.0) == [(120.0, 600.0), (600.0, 1200.0), (1200.0, 1800.0), (1800.0, 2400.0),
                                         (2400.0, 3000.0), (3000.0, 3600.0)]  # fmt: skip
    assert ba.windows(14400.0, 3600.0)[0] == (120.0, 3600.0) and ba.windows(14400.0, 3600.0)[-1] == (10800.0, 14400.0)
    assert ba.windows(1000.0, 600.0) == [(120.0, 600.0), (600.0, 1000.0)]  # 400 s: at least half a window
    assert ba.windows(1300.0, 600.0) == [(120.0, 600.0), (600.0, 1200.0)]  # the last 100 s left out


def test_the_window_table_names_the_worst_window_of_any_seed(capsys, monkeypatch):
    def flown(job):
        r = flight(job[0], job[1])
        r["windows"] = [{"start_s": a, "speed_error_pct": 1.0, "direction_error_deg": -0.5, "error_ratio": 1.1}
                        for a, _ in ba.windows(job[2], job[3])]  # fmt: skip
        if job[1] == 2:
            r["windows"][1].update(speed_error_pct=-7.5, error_ratio=0.2)
            r["windows"][2].update(direction_error_deg=12.6, error_ratio=3.5)
        return r

    monkeypatch.setattr(ba, "one", flown)
    monkeypatch.setattr(ba, "Pool", NoPool)
    ba.main(["--seeds", "3", "--scenarios", "field-all", "--duration", "3600", "--window", "600", "--quiet"])
    line = row(capsys.readouterr().out.splitlines()[-2:], "field-all")
    assert "-7.50 (seed 2,   600 s)" in line and "+12.60 (seed 2,  1200 s)" in line
    assert "+0.20 (seed 2,   600 s)" in line  # farther from 1 than 3.5 is: |log 0.2| = 1.61 > |log 3.5| = 1.25


def test_a_window_that_could_not_be_judged_is_the_worst():
    ws = [{"start_s": a, "speed_error_pct": 9.0, "direction_error_deg": 1.0, "error_ratio": 5.0}
          for a in (120.0, 600.0)]  # fmt: skip
    ws[1].update(speed_error_pct=float("nan"), error_ratio=float("inf"))
    r = flight("field-all", 1) | {"windows": ws}
    line = row(ba.window_table(["field-all"], [r]), "field-all")
    assert "nan (seed 1,   600 s)" in line and "inf (seed 1,   600 s)" in line
