"""The one rule for every output option of every program (docs/usage.md, "Errors and exit codes"):
an output that is an input of the same run (the same path, through a symlink, through a hardlink), another
output of the same run, or that cannot be written (under /proc, in a missing directory) is exit 2 with
ONE line naming the option, before any work: the inputs stay byte for byte as they were and nothing new
appears in the directory. And products appear under their final names only when complete: a run that
fails or is stopped (SIGTERM) leaves neither a final name nor a temporary one.

(``balloon-replay --out`` takes only a link, never a file: it has no file output to walk.)"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from firmware_py import cli as fw_cli
from ground_station import cli as gs_cli
from sil import cli as sil_cli
from sim_hil import cli as sim_cli
from study import cli as study_cli
from tests.helpers.cli import run_main

MAINS: dict[str, Callable[[list[str]], int]] = {
    "balloon-sim": sim_cli.main,
    "balloon-fw": fw_cli.main,
    "balloon-gs": gs_cli.main,
    "balloon-sil": sil_cli.main,
    "balloon-study": study_cli.main,
}


@dataclass(frozen=True)
class Option:
    """One output option: ``argv(d, value)`` is a whole command line of ``prog`` with ``value`` given to
    ``option``; ``inputs`` the input files it reads (names in ``d``), ``other`` another output option of
    the same run (``argv`` then takes its value too)."""

    prog: str
    option: str
    argv: Callable[..., list[str]]
    inputs: tuple[str, ...]
    other: str | None = None
    ext: str = ""


def sim(d: Path, opt: str, value: str, other: str | None = None, other_value: str | None = None) -> list[str]:
    argv = ["--duration", "2", "--config", str(d / "design.toml"), opt, value]
    return argv + ([other, other_value] if other else [])


def fw(d: Path, opt: str, value: str, *_: object) -> list[str]:
    return ["--in", str(d / "flight.tlog"), "--config", str(d / "design.toml"), "--quiet", opt, value]


def listen(d: Path, opt: str, value: str, other: str | None = None, other_value: str | None = None) -> list[str]:
    argv = ["listen", "udpin:127.0.0.1:1", "--duration", "0.1", "--ground-pressure", str(d / "ground.csv"), opt, value]
    return argv + ([other, other_value] if other else [])


def report(d: Path, opt: str, value: str, *_: object) -> list[str]:
    return ["report", str(d / "wind.csv"), "--truth", str(d / "truth.csv"), opt, value]


def reprocess(d: Path, opt: str, value: str, other: str | None = None, other_value: str | None = None) -> list[str]:
    argv = ["reprocess", str(d / "flight.tlog"), "--config", str(d / "design.toml"), "--quiet",
            "--ground-pressure", str(d / "ground.csv")]  # fmt: skip
    argv += [opt, value] + ([other, other_value] if other else [])
    if "--out" not in argv:
        argv += ["--out", str(d / "product.nc")]
    return argv


def sil(d: Path, opt: str, value: str, *_: object) -> list[str]:
    return ["--duration", "30", "--config", str(d / "design.toml"), opt, value]


def study(d: Path, opt: str, value: str, *_: object) -> list[str]:
    return [str(d / "spec.toml"), "--workers", "0", opt, value]


OPTIONS = [
    Option("balloon-sim", "--out", sim, ("design.toml",), "--truth", ext=".tlog"),
    Option("balloon-sim", "--truth", sim, ("design.toml",), "--ground-csv", ext=".csv"),
    Option("balloon-sim", "--ground-csv", sim, ("design.toml",), "--out", ext=".csv"),
    Option("balloon-fw", "--out", fw, ("flight.tlog", "design.toml"), ext=".tlog"),
    Option("balloon-gs", "--csv", listen, ("ground.csv",), "--tlog", ext=".csv"),
    Option("balloon-gs", "--tlog", listen, ("ground.csv",), "--csv", ext=".tlog"),
    Option("balloon-gs", "--plot", report, ("wind.csv", "truth.csv"), ext=".png"),
    Option("balloon-gs", "--out", reprocess, ("flight.tlog", "design.toml", "ground.csv"), "--plot", ext=".nc"),
    Option("balloon-gs", "--plot", reprocess, ("flight.tlog", "design.toml", "ground.csv"), "--out", ext=".png"),
]
IDS = [f"{o.prog}-{o.argv.__name__}-{o.option}" for o in OPTIONS]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("rule-inputs")
    (d / "design.toml").write_text("[truth]\nground_baro_hz = 1.0\n")
    assert sim_cli.main(["--duration", "3", "--quiet", "--out", str(d / "flight.tlog"),
                         "--truth", str(d / "truth.csv")]) == 0  # fmt: skip
    (d / "ground.csv").write_text("time_s,pressure_hpa,temperature_c\n0.0,1013.2,15.0\n1.0,1013.2,15.0\n")
    rows = ["time_usec,sysid,compid,wind_x,wind_y"] + [f"{i * 100000},1,1,0.1,3" for i in range(50)]
    (d / "wind.csv").write_text("\n".join(rows) + "\n")
    (d / "spec.toml").write_text('[study]\nduration_s = 60\n')
    return d


def run(prog: str, argv: list[str], capsys) -> tuple[int, str]:
    return run_main(MAINS[prog], argv, capsys)


def snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def check_refused(o: Option, d: Path, argv: list[str], capsys) -> str:
    """Exit 2, one line naming the option, no traceback; inputs unchanged, nothing new in ``d``."""
    before = snapshot(d)
    code, err = run(o.prog, argv, capsys)
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"{o.prog}") and ": error: " in lines[0], err
    assert o.option in lines[0], f"the line does not name {o.option}: {err}"
    after = snapshot(d)
    assert set(after) == set(before), f"new or removed files: {set(after) ^ set(before)}"
    for name in o.inputs:
        assert after[name] == before[name], f"{name} changed"
    return lines[0]


@pytest.fixture
def workdir(inputs: Path, tmp_path: Path) -> Path:
    """A copy of the inputs in a fresh directory (the links are made beside them)."""
    for p in inputs.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    return tmp_path


def link(target: Path, name: Path, how: str) -> str:
    """``target`` under ``name`` (``how``: same path, symlink, hardlink); the path to give the program."""
    if how == "same path":
        return str(target)
    if how == "symlink":
        name.symlink_to(target)
    else:
        os.link(target, name)
    return str(name)


@pytest.mark.parametrize("o", OPTIONS, ids=IDS)
@pytest.mark.parametrize("how", ["same path", "symlink", "hardlink"])
def test_an_output_that_is_an_input_is_refused(o: Option, how: str, workdir: Path, capsys):
    d = workdir
    for name in o.inputs:
        value = link(d / name, d / f"link-to-{name}{o.ext}", how)
        line = check_refused(o, d, o.argv(d, o.option, value), capsys)
        assert os.path.basename(value) in line and name in line


def _reprocess(d: Path, *extra: str) -> list[str]:
    return ["reprocess", str(d / "flight.tlog"), "--out", str(d / "w.nc"), *extra]


# what a program derives from an output option (a stem, a directory) is an output too: (program, the option,
# the derived file's name, which input file it is made to be, the command line)
DERIVED = {
    "reprocess-averages-csv": ("balloon-gs", "--out", "w_avg_1s.csv", "ground.csv",
                               lambda d, f: _reprocess(d, "--ground-pressure", f)),
    "reprocess-profile": ("balloon-gs", "--out", "w_profile.nc", "design.toml",
                          lambda d, f: _reprocess(d, "--config", f)),
    "reprocess-plot-profile": ("balloon-gs", "--plot", "p_profile.png", "design.toml",
                               lambda d, f: _reprocess(d, "--config", f, "--plot", str(d / "p.png"))),
    "sil-design": ("balloon-sil", "--outdir", "field-rope-seed1-design.toml", "design.toml",  # a design file alone
                   lambda d, f: ["--config", f, "--outdir", str(d)]),
    "study-cases": ("balloon-study", "--out", "cases.csv", "spec.toml", lambda d, f: [f, "--out", str(d)]),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(DERIVED))
@pytest.mark.parametrize("how", ["same path", "symlink", "hardlink"])
def test_a_derived_output_that_is_an_input_is_refused(case: str, how: str, workdir: Path, capsys):
    """reprocess writes ``<stem>_avg_1s.csv`` beside ``--out``: never over the user's CSV (nor the design
    file, nor anything the run reads); sil and study write fixed names in their directory. The input is
    at the derived name itself, or the derived name is a link to the input the run is given."""
    prog, option, derived, source, argv = DERIVED[case]
    d = workdir
    if how == "same path":
        (d / derived).write_bytes((d / source).read_bytes())
        given = derived
    else:
        link(d / source, d / derived, how)
        given = source
    o = Option(prog, option, lambda *_: [], (given,))
    line = check_refused(o, d, argv(d, str(d / given)), capsys)
    assert derived in line


@pytest.mark.parametrize("o", [o for o in OPTIONS if o.other], ids=[i for i, o in zip(IDS, OPTIONS) if o.other])
def test_an_output_that_is_another_output_is_refused(o: Option, workdir: Path, capsys):
    same = str(workdir / f"both{o.ext}")
    line = check_refused(o, workdir, o.argv(workdir, o.option, same, o.other, same), capsys)
    assert "also the output" in line


@pytest.mark.parametrize("o", OPTIONS, ids=IDS)
@pytest.mark.parametrize("where", ["/proc/x", "/no/such/dir/x"])
def test_an_output_that_cannot_be_written_is_refused_at_once(o: Option, where: str, workdir: Path, capsys):
    t0 = time.perf_counter()
    check_refused(o, workdir, o.argv(workdir, o.option, where + o.ext), capsys)
    assert not os.path.exists(where + o.ext)
    assert time.perf_counter() - t0 < 5.0  # before any work (reprocess, a flight, a study)


@pytest.mark.parametrize("prog,option", [("balloon-sil", "--outdir"), ("balloon-study", "--out")])
@pytest.mark.parametrize("where", ["/proc/x", "/no/such/dir/x"])
def test_an_output_directory_that_cannot_be_written_is_refused(prog: str, option: str, where: str, workdir, capsys):
    o = Option(prog, option, sil if prog == "balloon-sil" else study, ("design.toml", "spec.toml"))
    check_refused(o, workdir, o.argv(workdir, option, where), capsys)


def test_the_derived_profile_and_averages_are_not_each_other(workdir: Path, capsys):
    """``--plot x_avg_1s.png`` next to ``--out x.nc`` is fine; ``--plot`` naming a derived product is not."""
    o = next(o for o in OPTIONS if o.argv is reprocess and o.option == "--plot")
    line = check_refused(o, workdir, reprocess(workdir, "--out", str(workdir / "w.nc"), "--plot",
                                               str(workdir / "w_avg_1s.csv")), capsys)  # fmt: skip
    assert "avg_1s" in line


# ---------------------------------------------------------------- no partial product under a final name


def no_leftovers(d: Path, finals: list[Path]) -> None:
    assert not [f for f in finals if f.exists()], "a final name appeared"
    assert not list(d.glob(".*.part-*")), f"temporary files left: {list(d.glob('.*.part-*'))}"


def test_a_diverging_simulation_leaves_no_output(tmp_path: Path, capsys):
    cfg = tmp_path / "stiff.toml"
    cfg.write_text("[tether]\nlength_m = 1\n[truth]\ntether_ea_n = 1e9\nground_baro_hz = 1.0\n")
    finals = [tmp_path / "d.tlog", tmp_path / "d.csv", tmp_path / "g.csv"]  # the paper's rope (a rod) diverges
    code, err = run("balloon-sim", ["--scenario", "paper-reference", "--config", str(cfg), "--duration", "60",
                                    "--out", str(finals[0]),
                                    "--truth", str(finals[1]), "--ground-csv", str(finals[2])], capsys)  # fmt: skip
    assert code == 2 and "diverged" in err
    no_leftovers(tmp_path, finals)


def test_a_failing_firmware_replay_leaves_no_output(tmp_path: Path, capsys):
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(bytes(range(256)) * 40)
    code, err = run("balloon-fw", ["--in", str(junk), "--out", str(tmp_path / "w.tlog"), "--quiet"], capsys)
    assert code == 2, err
    no_leftovers(tmp_path, [tmp_path / "w.tlog"])


def _wait_for(pred: Callable[[], bool], proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while not pred():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "timed out"
        time.sleep(0.05)


def test_sigterm_mid_simulation_leaves_no_output(tmp_path: Path):
    """A long file run stopped by SIGTERM once its temporary files exist: exit 130, neither they nor a
    final name remain."""
    cfg = tmp_path / "g.toml"
    cfg.write_text("[truth]\nground_baro_hz = 1.0\n")
    finals = [tmp_path / "long.tlog", tmp_path / "long.csv", tmp_path / "ground.csv"]
    p = subprocess.Popen([sys.executable, "-m", "sim_hil", "--duration", "7200", "--quiet", "--config", str(cfg),
                          "--out", str(finals[0]), "--truth", str(finals[1]), "--ground-csv", str(finals[2])],
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _wait_for(lambda: any(f.stat().st_size > 0 for f in tmp_path.glob(".long.part-*")), p)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert "Traceback" not in err
    no_leftovers(tmp_path, finals)


def _sigint_ignored() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a shell starts a background job: `prog & kill -INT $!`


@pytest.mark.parametrize("sig, background", [(signal.SIGTERM, False), (signal.SIGINT, True)],
                         ids=["sigterm", "ctrl-c-in-the-background"])  # fmt: skip
def test_a_signal_mid_reprocess_leaves_no_output(sig, background, inputs: Path, tmp_path: Path):
    """SIGTERM, or Ctrl-C to a run started as a shell starts a background job (SIGINT ignored; it ran to its end,
    exit 0, products written): exit 130, nothing under a final name."""
    flight = tmp_path / "flight.tlog"
    assert sim_cli.main(["--duration", "120" if not background else "300", "--quiet", "--out", str(flight)]) == 0
    finals = [tmp_path / "w.nc", tmp_path / "w_avg_1s.csv", tmp_path / "w_avg_1s.nc"]
    p = subprocess.Popen([sys.executable, "-m", "ground_station", "reprocess", str(flight), "--out", str(finals[0])],
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=_sigint_ignored if background else None)  # fmt: skip
    try:
        line = p.stderr.readline()  # the reader has opened the flight: the run is under way
        assert "balloon-gs reprocess" in line, line
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        p.kill()
    assert p.returncode == 130, line + err
    no_leftovers(tmp_path, finals)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["flight.tlog"]
