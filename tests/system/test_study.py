"""balloon-study: a tiny sweep on a 2-worker LocalCluster equals the serial run; resume runs only the
rest; a killed worker's case is rescheduled; a raising case is a failed row; a bad SPEC is exit 2 with
one line; a real `dask scheduler` + `dask worker` on loopback runs the sweep through --scheduler."""

from __future__ import annotations

import functools
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import pyarrow.parquet as pq
import pytest

import study.case
from study import engine
from study.case import run_case
from study.cli import main, paper_spec_text
from study.spec import parse_spec

pytestmark = [pytest.mark.dask, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
TINY = """
[study]
base = "paper-reference"
seeds = 1
duration_s = 40.0
start_s = 10.0
[axes]
"balloon.radius_m" = [0.95, 1.1]
"wind.mean_mps" = [2.0, 4.0]
"""
cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the test's case functions travel to workers


def tiny_spec(text: str = TINY):
    import tomllib

    return parse_spec(tomllib.loads(text))


def numbers(row: dict) -> dict:
    """Everything a case computed, without its wall time (NaN made comparable)."""
    return {k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items() if k != "wall_time_s"}


@pytest.fixture(scope="module")
def serial():
    cases = tiny_spec().cases()
    return {c.key: run_case(c.payload()) for c in cases}


@pytest.fixture(scope="module")
def client():
    with engine.dask_client(workers=2) as c:
        yield c


def test_tiny_sweep_on_two_workers_equals_the_serial_run(client, serial, tmp_path):
    cases = tiny_spec().cases()
    assert len(cases) == 4 and len({c.key for c in cases}) == 4
    rows, stats = engine.run(cases, engine.Store(tmp_path / "parts"), client, progress=False)
    assert stats.workers == 2 and stats.computed == 4 and stats.failed == 0
    assert {k: numbers(r) for k, r in rows.items()} == {k: numbers(r) for k, r in serial.items()}
    r = rows[cases[0].key]
    assert r["status"] == "ok" and math.isfinite(r["band_skill"]) and r["band_skill"] <= 1.0
    assert r["lift_margin_n"] > 0 and r["wall_time_s"] > 0 and 0.0 < r["blowdown_deg"] < 90.0
    assert len(list((tmp_path / "parts").glob("*.json"))) == 4
    # only metrics come back: plain numbers and short strings, no series
    assert all(isinstance(v, (float, str)) for row in rows.values() for v in row.values())
    assert all(len(json.dumps(row)) < 2000 for row in rows.values())


def test_resume_computes_only_the_rest_and_a_repeat_nothing(client, serial, tmp_path):
    cases = tiny_spec().cases()
    store = engine.Store(tmp_path / "parts")
    for c in cases[:3]:  # an earlier run that stopped after three cases
        store.put(serial[c.key])
    rows, stats = engine.run(cases, store, client, progress=False)
    assert (stats.reused, stats.computed) == (3, 1) and stats.computed_keys == [cases[3].key]
    assert numbers(rows[cases[3].key]) == numbers(serial[cases[3].key])
    _, again = engine.run(cases, store, client, progress=False)
    assert (again.reused, again.computed) == (4, 0)


def killing_case(payload, marker: str):
    """The first case to get here kills its own worker process (once: the marker file); Dask reschedules."""
    marker = Path(marker)
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return run_case(payload)
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_worker_killed_mid_sweep_still_completes(client, serial, tmp_path):
    marker = tmp_path / "killed"
    cases = tiny_spec().cases()
    rows, stats = engine.run(
        cases,
        engine.Store(tmp_path / "parts"),
        client,
        case_fn=functools.partial(killing_case, marker=str(marker)),
        progress=False,
    )
    assert marker.exists()  # a worker did die
    assert stats.failed == 0 and stats.computed == 4
    assert {k: numbers(r) for k, r in rows.items()} == {k: numbers(r) for k, r in serial.items()}


def test_a_case_that_raises_is_a_failed_row_and_the_sweep_goes_on(tmp_path, capsys, monkeypatch):
    spec = tmp_path / "s.toml"
    spec.write_text(TINY.replace('"wind.mean_mps" = [2.0, 4.0]', '"wind.mean_mps" = [3.0]'))
    # every design passes the up-front checks; one case then fails while it flies (as a numerical
    # blow-up would): in this process (--workers 0) the flight of the 0.95 m balloon raises
    real_fly = study.case.fly

    def fly(design, *args):
        if design.balloon.radius_m == 0.95:
            raise FloatingPointError("avionics_offset_m: the truth integration diverged")
        return real_fly(design, *args)

    monkeypatch.setattr(study.case, "fly", fly)
    assert main([str(spec), "--out", str(tmp_path / "o"), "--workers", "0", "--quiet"]) == 0
    rows = pq.read_table(tmp_path / "o" / "cases.parquet").to_pylist()
    by_r = {r["balloon.radius_m"]: r for r in rows}
    assert by_r[0.95]["status"] == "failed" and "avionics_offset_m" in by_r[0.95]["error"]
    assert math.isnan(by_r[0.95]["band_skill"])
    assert by_r[1.1]["status"] == "ok" and math.isfinite(by_r[1.1]["band_skill"])
    csv_lines = (tmp_path / "o" / "cases.csv").read_text().splitlines()
    assert len(csv_lines) == 1 + len(rows)
    summary = (tmp_path / "o" / "summary.csv").read_text().splitlines()
    assert len(summary) == 3 and "band_skill_mean" in summary[0] and "band_skill_worst" in summary[0]
    assert "1 failed" in capsys.readouterr().out
    assert (tmp_path / "o" / "plots" / "main-balloon.radius_m.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    "text, words",
    [
        ('[axes]\n"balloon.radius_mm" = [1.0]\n', "unknown key 'balloon.radius_mm'"),
        ('[axes]\n"balloon.radius_m" = []\n', "is empty"),
        ('[axes]\n"balloon.radius_m" = [1.0, "big"]\n', "must be a finite number"),
        ('[study]\nbase = "no-such"\n', "unknown scenario 'no-such'"),
        ('[axes]\nscenario = ["paper-reference", "no-such"]\n', "unknown scenario 'no-such'"),
        ("[study]\nsedes = 3\n", "unknown key 'sedes'"),
        ('[axes]\n"balloon.radius_m" = [1.0, -1.0]\n', "radius_m must be a number in [0.05, 20]"),
        ('[axes]\n"tether.length_m" = {start = 50, stop = 300}\n', "needs start, stop and num"),
    ],
)
def test_a_bad_spec_is_exit_2_with_one_line(tmp_path, capsys, text, words):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    assert main([str(spec), "--out", str(tmp_path / "o"), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and words in err and "Traceback" not in err


def test_a_bad_command_line_is_exit_2_with_one_line_before_any_case(tmp_path, capsys):
    """A scheduler address that is none, a flight length no flight can have, an empty --out, and a --out whose
    plots or parts are files: one line, exit 2, and nothing computed or written."""
    spec = tmp_path / "tiny.toml"
    spec.write_text('[study]\nduration_s = 150.0\nstart_s = 60.0\n[axes]\n"balloon.radius_m" = [1.0]\n')
    out = tmp_path / "o"
    (tmp_path / "held").mkdir()
    (tmp_path / "held" / "plots").write_text("mine")
    (tmp_path / "held2").mkdir()
    (tmp_path / "held2" / "parts").write_text("mine")
    for argv, word in (
        (["--out", str(out), "--scheduler", "bogus"], "HOST:PORT"),
        (["--out", str(out), "--workers", "0", "--duration", "nan"], "--duration"),
        (["--out", str(out), "--workers", "0", "--duration", "1e12"], "7 days"),
        (["--out", "", "--workers", "0"], "empty"),
        (["--out", str(tmp_path / "held"), "--workers", "0"], "plots"),
        (["--out", str(tmp_path / "held2"), "--workers", "0"], "parts"),
    ):
        assert main([str(spec), *argv]) == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and word in err and "Traceback" not in err, (argv, err)
    assert not out.exists() and sorted(p.name for p in (tmp_path / "held").iterdir()) == ["plots"]
    spec.write_text('[study]\nduration_s = 1e12\n[axes]\n"balloon.radius_m" = [1.0]\n')
    assert main([str(spec), "--out", str(out), "--workers", "0"]) == 2
    assert "7 days" in capsys.readouterr().err


def test_a_bad_spec_from_the_command_line_is_exit_2_without_traceback(tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text('[axes]\n"sensors.gyro_dps" = [1.0, "0.1"]\n')
    p = subprocess.run([sys.executable, "-m", "study", str(spec), "--out", str(tmp_path / "o")], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "sensors.gyro_dps" in p.stderr


def test_the_shipped_specs_parse_and_the_paper_file_is_the_packaged_one():
    assert (ROOT / "examples" / "paper-study.toml").read_text() == paper_spec_text()
    import tomllib

    q = parse_spec(tomllib.loads((ROOT / "examples" / "quick-study.toml").read_text()))
    assert len(q.cases()) == 4 and q.duration_s == 120.0 and len(q.seeds) == 1
    p = parse_spec(tomllib.loads(paper_spec_text()))
    assert len(p.seeds) >= 5 and {sw.name for sw in p.sweeps} >= {"paper", "tether-radius", "wind-radius"}


def test_a_real_dask_scheduler_and_worker_on_loopback(serial, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    sched_file = tmp_path / "scheduler.json"
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(sched_file)], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))  # fmt: skip
        deadline = time.monotonic() + 30
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
             "--nworkers", "1", "--no-dashboard"], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))  # fmt: skip
        spec = tmp_path / "tiny.toml"
        spec.write_text(TINY)
        out = tmp_path / "o"
        p = subprocess.run([sys.executable, "-m", "study", str(spec), "--out", str(out), "--scheduler", address,
                            "--no-plots"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
        assert p.returncode == 0, p.stderr[-2000:]
        assert "4 computed, 0 reused, 0 failed" in p.stdout
        rows = {r["key"]: r for r in pq.read_table(out / "cases.parquet").to_pylist()}
        for key, want in serial.items():
            assert rows[key]["band_skill"] == want["band_skill"] and rows[key]["blowdown_deg"] == want["blowdown_deg"]
    finally:
        for pr in reversed(procs):
            pr.terminate()
        for pr in procs:
            try:
                pr.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pr.kill()
