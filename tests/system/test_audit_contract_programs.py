"""Contract checks of the programs found wanting by an audit (docs/usage.md, "Errors and exit codes"; CONTRACT.md,
"Outputs never touch inputs"): each test here failed before its fix."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from benchmarks import bench_envelope
from firmware_py import cli as fw_cli
from ground_station import cli as gs_cli
from sil import cli as sil_cli
from sim_hil import cli as sim_cli
from study import cli as study_cli
from tests.helpers.cli import run_main

# a directory in which not even root can make a file, though os.access says root may (sysfs)
UNWRITABLE = "/sys/kernel"
needs_sysfs = pytest.mark.skipif(not os.path.isdir(UNWRITABLE), reason="no /sys/kernel (sysfs) here")


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("flight")
    assert sim_cli.main(["--duration", "3", "--out", str(d / "f.tlog"), "--quiet"]) == 0
    return d / "f.tlog"


def one_line_naming(err: str, option: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and option in lines[0], err


@needs_sysfs
@pytest.mark.parametrize("case", ["sim", "fw", "reprocess", "report", "listen", "sil", "sil-new", "study",
                                  "study-new", "bench", "bench-new"])  # fmt: skip
def test_an_output_where_no_file_can_be_made_is_exit_2_naming_it_before_any_work(case, flight, tmp_path, capsys,
                                                                                 monkeypatch):
    """An output in a directory where no file can be made (sysfs; a read-only mount) is exit 2 with one line naming
    the option, before any work, even for root (for whom os.access says yes): it was a traceback (balloon-sil,
    balloon-study, bench_envelope) or an error after the whole reprocess naming no option."""
    u = UNWRITABLE
    spec = str(Path(__file__).parents[2] / "examples" / "quick-study.toml")
    mains = {"sim": (sim_cli.main, ["--duration", "3", "--quiet", "--out", f"{u}/x.tlog"], "--out"),
             "fw": (fw_cli.main, ["--in", str(flight), "--quiet", "--out", f"{u}/x.tlog"], "--out"),
             "reprocess": (gs_cli.main, ["reprocess", str(flight), "--quiet", "--out", f"{u}/p.nc"], "--out"),
             "report": (gs_cli.main, ["report", str(flight), "--truth", str(flight), "--plot", f"{u}/p.png"],
                        "--plot"),
             "listen": (gs_cli.main, ["listen", "udpin:127.0.0.1:1", "--duration", "0.1", "--csv", f"{u}/w.csv"],
                        "--csv"),
             "sil": (sil_cli.main, ["--duration", "30", "--outdir", u], "--outdir"),
             "sil-new": (sil_cli.main, ["--duration", "30", "--outdir", f"{u}/new"], "--outdir"),
             "study": (study_cli.main, [spec, "--workers", "0", "--no-plots", "--quiet", "--out", u], "--out"),
             "study-new": (study_cli.main, [spec, "--workers", "0", "--no-plots", "--quiet", "--out", f"{u}/new"],
                           "--out"),
             "bench": (bench_envelope.main, ["--serial", "--flights", "1", "--duration", "150", "--out", u], "--out"),
             "bench-new": (bench_envelope.main, ["--serial", "--flights", "1", "--duration", "150", "--out",
                                                 f"{u}/new"], "--out")}  # fmt: skip
    main, argv, option = mains[case]
    monkeypatch.chdir(tmp_path)
    code, err = run_main(main, argv, capsys)
    assert code == 2, err
    one_line_naming(err, option)
    assert not list(tmp_path.iterdir())  # no work done, nothing made


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a shell starts a background job: `prog & kill -INT $!`


def _interrupted_once(p: subprocess.Popen, ready, within_s: float) -> str:
    """SIGINT to ``p`` once ``ready()`` (it must be within ``within_s`` and while ``p`` runs); its stderr."""
    try:
        end = time.monotonic() + within_s
        while not ready():
            assert p.poll() is None and time.monotonic() < end, p.communicate()
            time.sleep(0.05)
        p.send_signal(signal.SIGINT)
        return p.communicate(timeout=60)[1]
    finally:
        p.kill()


@pytest.mark.slow
def test_ctrl_c_stops_a_file_simulation_started_in_the_background(tmp_path: Path):
    """SIGINT to a file run of balloon-sim started with SIGINT ignored (a shell's background job): exit 130, nothing
    under a final name, as the paced run and balloon-fw do; it ran to its end (exit 0, products written)."""
    finals = [tmp_path / "long.tlog", tmp_path / "long.csv"]
    p = subprocess.Popen([sys.executable, "-m", "sim_hil", "--duration", "7200", "--quiet", "--out", str(finals[0]),
                          "--truth", str(finals[1])], stderr=subprocess.PIPE, text=True,
                         preexec_fn=_ignore_sigint)  # fmt: skip
    err = _interrupted_once(p, lambda: any(f.stat().st_size > 0 for f in tmp_path.glob(".long.part-*")), 60.0)
    assert p.returncode == 130, err
    assert "Traceback" not in err
    assert not list(tmp_path.iterdir())


def _interrupted_after_first_case(argv: list[str], out: Path, ignore: bool) -> tuple[int, str]:
    """Run ``python -m ...argv`` until its first finished case is in ``out/parts``, then SIGINT it."""
    p = subprocess.Popen([sys.executable, "-m", *argv], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                         cwd=Path(__file__).parents[2], preexec_fn=_ignore_sigint if ignore else None)  # fmt: skip
    err = _interrupted_once(p, lambda: bool(list(out.glob("parts/*"))), 120.0)
    return p.returncode, err


@pytest.mark.slow
@pytest.mark.parametrize("ignore", [False, True], ids=["foreground", "background"])
def test_ctrl_c_stops_the_envelope_benchmark(ignore, tmp_path: Path):
    """bench_envelope on Ctrl-C: exit 130 with one line, no traceback, no product (it was a KeyboardInterrupt
    traceback, exit -SIGINT; started in the background it ran to its end)."""
    out = tmp_path / "env"
    code, err = _interrupted_after_first_case(["benchmarks.bench_envelope", "--serial", "--flights", "30",
                                               "--duration", "300", "--out", str(out)], out, ignore)  # fmt: skip
    assert code == 130, err
    assert "Traceback" not in err and "interrupted" in err.strip().splitlines()[-1], err
    assert sorted(x.name for x in out.iterdir()) == ["parts"]


@pytest.mark.slow
def test_ctrl_c_stops_a_study_started_in_the_background(tmp_path: Path):
    out = tmp_path / "st"
    spec = str(Path(__file__).parents[2] / "examples" / "quick-study.toml")
    code, err = _interrupted_after_first_case(["study", spec, "--out", str(out), "--workers", "0", "--duration",
                                               "3000", "--no-plots"], out, True)  # fmt: skip
    assert code == 130, err
    assert "Traceback" not in err
    assert sorted(x.name for x in out.iterdir()) == ["parts"]


@pytest.mark.parametrize("argv, words", [
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with"),
    (["--serial", "--workers", "2"], "not allowed with"),
    (["--workers", "100000"], "--workers must be"),
    pytest.param(["--scheduler", "tcp://127.0.0.1:1"], "no Dask scheduler", marks=pytest.mark.slow),
])  # fmt: skip
def test_bench_envelope_refuses_a_bad_cluster_before_any_work(argv, words, tmp_path: Path, capsys):
    """``[--workers N | --scheduler tcp://HOST:PORT]``: both, a cluster of 100 000 local processes, or an address
    where no scheduler answers are exit 2 with one line, nothing made (they were accepted, started 100 000
    workers, or ended in a traceback after making --out)."""
    out = tmp_path / "env"
    code, err = run_main(bench_envelope.main, ["--flights", "1", "--duration", "150", "--out", str(out), *argv],
                         capsys)  # fmt: skip
    assert code == 2, err
    one_line_naming(err, words)
    assert not out.exists()


def test_listen_refuses_a_duration_beyond_a_week_as_balloon_fw_does(capsys):
    """``balloon-gs listen --duration 1e300`` listened for ever (it was any positive number); balloon-fw's --duration
    is at most 7 days, exit 2 beyond."""
    for main, argv in ((gs_cli.main, ["listen", "udpin:127.0.0.1:9", "--duration", "1e300"]),
                       (fw_cli.main, ["--in", "udpin:127.0.0.1:9", "--duration", "1e300"])):  # fmt: skip
        code, err = run_main(main, argv, capsys)
        assert code == 2, err
        one_line_naming(err, "--duration")


def test_a_ctrl_c_the_program_has_not_handled_yet_is_one_line(capsys, monkeypatch):
    """A Ctrl-C after the imports but before the program's own handler (its options parsing, its --help printing:
    `sil --help` interrupted in argparse's import of textwrap) was Python's traceback: one line and exit 130."""
    import types

    from balloon_core.entry import run

    def interrupted() -> int:
        raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "fake_program", types.SimpleNamespace(main=interrupted))
    assert run("balloon-fake", "fake_program:main") == 130
    err = capsys.readouterr().err
    assert err.strip() == "balloon-fake: interrupted (Ctrl-C)", err


@pytest.mark.parametrize("module", ["sim_hil", "firmware_py", "ground_station", "sil", "study"])
def test_ctrl_c_while_a_program_is_still_starting_is_one_line(module: str):
    """A Ctrl-C in a program's first fraction of a second, while its modules import (numpy, pymavlink), was Python's
    KeyboardInterrupt traceback: now one line and exit 130 (balloon_core.entry). Before Python's own handler is in
    place the signal ends it as a signal; after the imports, --help has answered (0)."""
    p = subprocess.Popen([sys.executable, "-m", module, "--help"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, cwd=Path(__file__).parents[2])  # fmt: skip
    time.sleep(0.08)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert "Traceback" not in err, err
    assert p.returncode in (130, -signal.SIGINT, 0), err
    if p.returncode == 130:
        # while importing (balloon_core.entry) or already in the program's own handler: which is the machine's timing
        assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err
