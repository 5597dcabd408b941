"""A program whose optional extra is missing says which to install: one line, exit 2, nothing written."""

import subprocess
import sys

import pytest

HIDE = "import sys\nfor m in {mods!r}: sys.modules[m] = None\n"


def run_hidden(mods, module, args, tmp_path):
    code = HIDE.format(mods=mods) + f"from {module} import main\nsys.exit(main({args!r}))\n"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60)


@pytest.mark.parametrize("hidden", [("xarray",), ("pyulog", "netCDF4")])
def test_reprocess_without_postflight_names_the_extra(tmp_path, hidden):
    flight = tmp_path / "f.tlog"
    flight.write_bytes(b"\0" * 64)
    r = run_hidden(hidden, "ground_station.cli", ["reprocess", str(flight), "--out", "x.nc"], tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "balloon-wind[postflight]" in r.stderr and "Traceback" not in r.stderr
    assert all(m in r.stderr for m in hidden)
    assert not (tmp_path / "x.nc").exists()


def test_study_without_dask_names_the_extra(tmp_path):
    r = run_hidden(("distributed",), "study.cli", ["--paper", "--out", "o"], tmp_path)
    assert r.returncode == 2 and "balloon-wind[study]" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "o").exists()


def test_with_the_extras_installed_nothing_is_asked(tmp_path):
    from balloon_core.userargs import require_extra

    require_extra("postflight")
    require_extra("study")
