"""Small edges of the programs' user errors (exit 2, one line, no traceback): the lockstep harness and
balloon-sil with no C compiler (the advice fits the program: balloon-sil has no --core option), and
``balloon-sim --ground-csv`` for a design that makes no ground reference."""

from __future__ import annotations

from pathlib import Path

import pytest

import firmware_c.build as build
from firmware_py import lockstep
from sil import cli as sil_cli
from sim_hil import cli as sim_cli


@pytest.fixture
def no_compiler(monkeypatch, tmp_path: Path):
    """No C compiler and no C core built yet."""
    empty = tmp_path / "no-build"
    empty.mkdir()
    monkeypatch.setattr(build, "_build_dirs", lambda: [empty])
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(build.shutil, "which", lambda _name: None)


def one_line(code: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def tlog(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("edges")
    assert sim_cli.main(["--duration", "2", "--quiet", "--out", str(d / "s.tlog")]) == 0
    return d / "s.tlog"


def test_lockstep_without_a_compiler_is_one_line(no_compiler, tlog: Path, capsys):
    code = lockstep.main([str(tlog)])
    line = one_line(code, capsys.readouterr().err)
    assert line.startswith("lockstep: error: ") and "C compiler" in line and "--core" not in line


def test_lockstep_with_a_cc_that_is_not_there_is_one_line(no_compiler, tlog: Path, monkeypatch, capsys):
    monkeypatch.setenv("CC", "/no/such/cc")
    line = one_line(lockstep.main([str(tlog), "--float32"]), capsys.readouterr().err)
    assert "/no/such/cc" in line


def test_sil_without_a_compiler_does_not_advise_an_option_it_lacks(no_compiler, tmp_path: Path, capsys):
    out = tmp_path / "out"
    line = one_line(sil_cli.main(["--duration", "30", "--outdir", str(out)]), capsys.readouterr().err)
    assert "C compiler" in line and "--core" not in line and 'core = "py"' in line
    assert not out.exists() or not list(out.iterdir())  # nothing started, nothing written


def test_sil_has_no_core_option(capsys):
    with pytest.raises(SystemExit):
        sil_cli.main(["--help"])
    assert "--core" not in capsys.readouterr().out


def test_sim_ground_csv_without_a_ground_reference_is_a_user_error(tmp_path: Path, capsys):
    g = tmp_path / "g.csv"
    line = one_line(sim_cli.main(["--duration", "2", "--ground-csv", str(g), "--out", str(tmp_path / "s.tlog")]),
                    capsys.readouterr().err)  # fmt: skip
    assert "--ground-csv" in line and "ground_baro_hz" in line
    assert list(tmp_path.iterdir()) == []  # neither the CSV nor the tlog
    cfg = tmp_path / "g.toml"
    cfg.write_text("[truth]\nground_baro_hz = 1.0\n")
    assert sim_cli.main(["--duration", "3", "--config", str(cfg), "--ground-csv", str(g), "--quiet"]) == 0
    rows = g.read_text().splitlines()
    assert rows[0] == "time_s,pressure_hpa,temperature_c" and len(rows) >= 3
