"""Two flights in one tlog (``cat a.tlog b.tlog``): each is its own log segment, with its own filter and
smoother run, and its own profile leg; nothing of the second is dropped."""

from __future__ import annotations

import subprocess
import sys

import pytest
import xarray as xr

PY = sys.executable


@pytest.mark.slow
def test_two_flights_in_one_tlog_are_two_segments_with_their_own_legs(tmp_path):
    parts = []
    for seed in (1, 2):
        p = tmp_path / f"f{seed}.tlog"
        subprocess.run([PY, "-m", "sim_hil", "--scenario", "profile-fast", "--duration", "150", "--seed", str(seed),
                        "--out", str(p), "--quiet"], check=True, capture_output=True)  # fmt: skip
        parts.append(p.read_bytes())
    both = tmp_path / "both.tlog"
    both.write_bytes(b"".join(parts))
    design = tmp_path / "d.toml"
    design.write_text(subprocess.run([PY, "-m", "sim_hil", "--scenario", "profile-fast", "--print-config"],
                                     check=True, capture_output=True, text=True).stdout)  # fmt: skip
    r = subprocess.run([PY, "-m", "ground_station", "reprocess", str(both), "--out", str(tmp_path / "b.nc"),
                        "--config", str(design)], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    said = r.stdout + r.stderr
    assert "2 log segments" in said and "over 300 s" in said, said
    assert "samples, 300.0 s" in r.stderr, r.stderr  # the log's span: both flights, not the longer one's
    with xr.open_dataset(tmp_path / "b_profile.nc") as prof:
        assert prof.sizes["profile"] == 2  # one leg per flight
        starts = prof["leg_start"].values
        assert (starts[1] - starts[0]).astype("timedelta64[s]").astype(int) >= 140  # the second flight's own
        assert all(int(n) > 0 for n in prof["row_size"].values)
