"""One validation of the design file for every program, the same verdict on ``[winch]``
(balloon_core/config.py): a schedule that reels faster than its max_speed_mps, whose times do not
increase, or that reaches beyond ``[tether] length_m`` (the rope on the drum, where the lift is checked)
is refused by balloon-sim, balloon-sil, balloon-fw and reprocess alike; the profile scenarios' drum
holds their longest line, and their lift is checked there."""

from __future__ import annotations

from pathlib import Path

import pytest

from balloon_core.config import design_from_dict, lift_balance, load_toml
from firmware_py import cli as fw_cli
from ground_station import cli as gs_cli
from sil import cli as sil_cli
from sim_hil import cli as sim_cli
from sim_hil.scenarios import SCENARIOS

MAINS = {
    "balloon-sim": lambda d, c: sim_cli.main(["--scenario", "profile-fast", "--duration", "2", "--config", c]),
    "balloon-sil": lambda d, c: sil_cli.main(["--scenario", "profile-fast", "--duration", "30", "--config", c,
                                              "--outdir", str(d / "sil")]),
    "balloon-fw": lambda d, c: fw_cli.main(["--in", str(d / "f.tlog"), "--config", c]),
    "reprocess": lambda d, c: gs_cli.main(["reprocess", str(d / "f.tlog"), "--out", str(d / "w.nc"), "--config", c]),
}  # fmt: skip

BAD = {
    "too fast": ("max_speed_mps = 1.0", "max_speed_mps = 0.5", "faster than max_speed_mps"),
    "times not increasing": ("times_s = [0.0, 60.0,", "times_s = [0.0, 0.0,", "times_s must increase"),
    "beyond the drum": ("length_m = 150.0", "length_m = 100.0", "beyond [tether] length_m"),
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("winch-verdict")
    assert sim_cli.main(["--duration", "2", "--quiet", "--out", str(d / "f.tlog")]) == 0
    (d / "profile.toml").write_text(SCENARIOS["profile-fast"].to_toml())
    return d


@pytest.mark.parametrize("case", sorted(BAD))
def test_every_program_refuses_the_same_schedule(case: str, files: Path, capsys):
    old, new, said = BAD[case]
    text = (files / "profile.toml").read_text()
    assert old in text
    cfg = files / f"{case.replace(' ', '-')}.toml"
    cfg.write_text(text.replace(old, new, 1))
    verdicts = {}
    for prog, main in MAINS.items():
        capsys.readouterr()
        code = main(files, str(cfg))
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and said in err[0], (prog, err)
        verdicts[prog] = err[0].split("error: ", 1)[1]
    assert len(set(verdicts.values())) == 1, verdicts  # word for word the same


@pytest.mark.parametrize("name", [n for n, sc in SCENARIOS.items() if sc.winch.enabled])
def test_a_winch_scenario_flies_within_its_drum_and_lifts_its_longest_line(name: str, tmp_path: Path):
    sc = SCENARIOS[name]
    assert max(sc.winch.lengths_m) <= sc.design.tether.length_m
    assert lift_balance(sc.design)[-1] > 0.0  # at the drum's whole rope, the longest line at most
    path = tmp_path / "s.toml"
    path.write_text(sc.to_toml())
    assert design_from_dict(load_toml(path)) == sc.design  # the file every program reads passes
