"""Every user error of every program: exit 2, exactly one line on stderr, no traceback (docs/usage.md).

Run in-process (``main(argv)``) for speed; a few cases through ``python -m`` prove the console path.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from balloon_core.config import SCHEMA, SIM_DEFAULTS, BalloonConfig, SensorsConfig, SiteConfig, TetherConfig
from balloon_core.wire import frame_length
from firmware_py import cli as fw_cli
from firmware_py.app import OutputConfig
from firmware_py.estimator.state import FilterConfig
from ground_station import cli as gs_cli
from ground_station.wind import CSV_COLUMNS
from sil import cli as sil_cli
from sim_hil import cli as sim_cli
from sim_hil import replay as replay_cli
from sim_hil.dynamics import TruthConfig
from sim_hil.winch import WinchConfig
from sim_hil.wind import WindConfig
from tests.helpers.cli import run_main

MAINS = {"sim": sim_cli.main, "fw": fw_cli.main, "gs": gs_cli.main, "sil": sil_cli.main, "replay": replay_cli.main}
NOWHERE = "/no/such/dir"



@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Small inputs: a capture with MAVLink in it, an empty file, random bytes, CSVs good and bad."""
    d = tmp_path_factory.mktemp("inputs")
    tlog = d / "s.tlog"
    assert sim_cli.main(["--duration", "3", "--out", str(tlog), "--truth", str(d / "truth.csv")]) == 0
    first = tlog.read_bytes()[:8]
    first += tlog.read_bytes()[8 : 8 + frame_length(tlog.read_bytes(), 8)]
    (d / "one.tlog").write_bytes(first)  # one record: replays in no time at any speed
    (d / "empty.raw").write_bytes(b"")
    (d / "random.raw").write_bytes(bytes((i * 7919 + (i >> 3) * 104729) % 251 for i in range(100_000)))
    (d / "empty.csv").write_text("")
    (d / "header-only.csv").write_text("time_s,wind_n,wind_e\n")
    (d / "no-wind.csv").write_text("time_s,pos_n\n0,1\n1,2\n2,3\n")
    (d / "bad-wind.csv").write_text("time_s,wind_n,wind_e\n0,1,0\n1,abc,0\n2,1,0\n")
    rows = [",".join(CSV_COLUMNS)] + [f"{i * 100000},1,1,0.1,3,0,0.3,0,100,0.2,0,3,270" for i in range(50)]
    (d / "wind.csv").write_text("\n".join(rows) + "\n")
    return d


def toml(d, name: str, text: str) -> str:
    p = d / name
    p.write_text(text)
    return str(p)


def run(prog: str, argv: list[str], capsys) -> tuple[int, str]:
    return run_main(MAINS[prog], argv, capsys)


CONFIGS = {
    "imu_rate_zero": ("[filter]\nimu_rate_hz = 0\n", "imu_rate_hz"),
    "imu_rate_negative": ("[filter]\nimu_rate_hz = -100\n", "imu_rate_hz"),
    "gate_sigma_negative": ("[filter]\ngate_sigma = -1\n", "gate_sigma"),
    "float32_string": ('[filter]\nfloat32 = "yes"\n', "float32"),
    "radius_boolean": ("[balloon]\nradius_m = true\n", "radius_m"),
    "physics_hz_zero": ("[truth]\nphysics_hz = 0\n", "physics_hz"),
    "physics_hz_not_multiple": ("[truth]\nphysics_hz = 250\n", "physics_hz"),
    "no_spare_lift": ("[balloon]\nradius_m = 0.3\n", "net lift"),
    "wind_hurricane": ('[wind]\nkind = "hurricane"\n', "hurricane"),
    "unknown_key": ("[tether]\nlength_ft = 300\n", "length_ft"),
    "unknown_section": ("[engine]\nthrust = 1\n", "engine"),
    "not_toml": ("[balloon\nradius_m = 1\n", "TOML"),
    "nan": ("[sensors]\nbaro_m = nan\n", "baro_m"),
}


def cases(d) -> list[tuple[str, str, list[str], str]]:
    """(program, error class, argv, a word the message must hold)."""
    s, truth, wind = str(d / "s.tlog"), str(d / "truth.csv"), str(d / "wind.csv")
    out = []
    for port in ("99999", "0", "x"):
        ep = f"udpout:127.0.0.1:{port}"
        out += [("sim", "port", ["--duration", "1", "--out", ep], "port"),
                ("fw", "port", ["--in", f"udpin:0.0.0.0:{port}"], "port"),
                ("gs", "port", ["listen", f"udpin:0.0.0.0:{port}", "--duration", "1"], "port"),
                ("replay", "port", [s, "--out", ep], "port")]  # fmt: skip
    out += [
        ("sim", "output path", ["--duration", "1", "--out", f"{NOWHERE}/a.tlog"], NOWHERE),
        ("sim", "output path", ["--duration", "1", "--truth", f"{NOWHERE}/t.csv"], NOWHERE),
        ("sim", "output path", ["--duration", "1", "--truth", str(d)], "directory"),
        ("fw", "output path", ["--in", s, "--out", f"{NOWHERE}/o.tlog"], NOWHERE),
        ("gs", "output path", ["listen", "udpin:127.0.0.1:14599", "--csv", f"{NOWHERE}/w.csv"], NOWHERE),
        ("gs", "output path", ["listen", "udpin:127.0.0.1:14599", "--tlog", f"{NOWHERE}/w.tlog"], NOWHERE),
        ("gs", "output path", ["report", wind, "--truth", truth, "--plot", f"{NOWHERE}/p.png"], NOWHERE),
        ("sil", "output path", ["--outdir", f"{NOWHERE}/out"], NOWHERE),
    ]
    for bad in ("nan", "inf", "-1", "0", "1e9", "ten"):
        out += [("sim", "number", ["--duration", bad], "--duration"),
                ("sil", "number", ["--duration", bad], "--duration")]  # fmt: skip
    for bad in ("-1", "4294967296", "1.5"):
        out += [("sim", "number", ["--seed", bad], "--seed"), ("sil", "number", ["--seed", bad], "--seed")]
    out += [
        ("sim", "number", ["--speed", "-2", "--duration", "1"], "--speed"),
        ("sil", "number", ["--speed", "0"], "--speed"),
        ("gs", "number", ["listen", "udpin:127.0.0.1:14599", "--duration", "nan"], "--duration"),
        ("gs", "number", ["report", wind, "--truth", truth, "--start", "inf"], "--start"),
        ("replay", "number", [s, "--out", "udpout:127.0.0.1:14599", "--speed", "-1"], "--speed"),
        ("gs", "report input", ["report", truth, "--truth", wind], "WIND_COV CSV"),  # arguments swapped
        ("gs", "report input", ["report", wind, "--truth", str(d / "empty.csv")], "empty"),
        ("gs", "report input", ["report", wind, "--truth", str(d / "header-only.csv")], "fewer than 2 rows"),
        ("gs", "report input", ["report", wind, "--truth", str(d / "no-wind.csv")], "wind_n"),
        ("gs", "report input", ["report", wind, "--truth", str(d / "bad-wind.csv")], "not numbers"),
        ("gs", "report input", ["report", str(d / "nope.csv"), "--truth", truth], "no such file"),
        ("gs", "report input", ["report", s], "WIND_COV"),  # a sensor log: no wind to report (no truth needed)
    ]
    for name in ("empty.raw", "random.raw"):
        f = str(d / name)
        out += [("fw", "input file", ["--in", f], "no MAVLink frame"),
                ("replay", "input file", [f, "--out", "udpout:127.0.0.1:14599"], "no MAVLink frame")]  # fmt: skip
    out += [("fw", "input file", ["--in", str(d / "nope.tlog")], "no such file")]
    sil_out = str(d / "sil")
    for key, (text, word) in CONFIGS.items():
        cfg = toml(d, f"{key}.toml", text)
        out += [("sim", f"config {key}", ["--duration", "1", "--config", cfg], word),
                ("fw", f"config {key}", ["--in", s, "--config", cfg], word),
                ("sil", f"config {key}", ["--duration", "1", "--config", cfg, "--outdir", sil_out], word)]  # fmt: skip
    out += [("sim", "config missing", ["--config", str(d / "nope.toml")], "nope.toml"),
            ("sim", "scenario", ["--scenario", "paper-referense"], "unknown scenario")]  # fmt: skip
    # a name that ends in a separator is a directory: refused before the run, not when it is renamed at the end
    out += [("sim", "output path", ["--duration", "1", "--truth", str(d / "t.csv") + "/"], "names a directory"),
            ("gs", "output path", ["listen", "udpin:127.0.0.1:14599", "--csv", str(d / "w.csv") + "/"],
             "names a directory"),
            ("gs", "output path", ["report", wind, "--truth", truth, "--plot", str(d / "p.png") + "/"],
             "names a directory"),
            ("gs", "output path", ["report", wind, "--truth", truth, "--plot", str(d / "noext")], ".png")]  # fmt: skip
    for bad in ("0", "256", "-1", "x"):  # a ground station's MAVLink system id: 1..255
        out += [("gs", "number", ["listen", "udpin:127.0.0.1:14599", "--ground-sysid", bad], "--ground-sysid")]
    return out


def test_every_user_error_is_one_line_and_exit_2(files, capsys):
    failures = []
    table = cases(files)
    for prog, what, argv, word in table:
        code, err = run(prog, argv, capsys)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        ok = code == 2 and len(lines) == 1 and "Traceback" not in err and word in err and err.startswith("balloon-")
        if not ok:
            failures.append(f"{prog} {what} {argv}: exit {code}, stderr {err!r}")
    assert not failures, "\n".join(failures)
    assert len(table) > 80


@pytest.mark.parametrize(
    "argv, word",
    [
        (["sim_hil", "--duration", "nan"], "--duration"),
        (["firmware_py", "--in", "udpin:0.0.0.0:99999"], "port"),
        (["ground_station", "report", "missing-wind.csv", "--truth", "x.csv"], "no such file"),
    ],
)
def test_console_path(argv, word):
    r = subprocess.run([sys.executable, "-m", *argv], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and word in r.stderr and "Traceback" not in r.stderr


def test_one_verdict_for_one_file(files, capsys):
    """balloon-fw checks the simulator's sections too: the same file is refused by both, for the same key."""
    for key, (text, _) in CONFIGS.items():
        cfg = toml(files, f"v-{key}.toml", text)
        (_, e_sim), (_, e_fw) = (run(p, a, capsys) for p, a in (
            ("sim", ["--duration", "1", "--config", cfg]), ("fw", ["--in", str(files / "s.tlog"), "--config", cfg])))
        assert e_sim.split("error: ", 1)[1] == e_fw.split("error: ", 1)[1], key


def test_schema_names_every_key_the_programs_read():
    classes = {"balloon": BalloonConfig, "tether": TetherConfig, "site": SiteConfig, "sensors": SensorsConfig,
               "wind": WindConfig, "truth": TruthConfig, "filter": FilterConfig, "winch": WinchConfig,
               "outputs": OutputConfig}  # fmt: skip
    assert set(SCHEMA) == set(classes)
    for name, cls in classes.items():
        assert set(SCHEMA[name]) == {f.name for f in dataclasses.fields(cls)}, name
    assert SIM_DEFAULTS == {"wind.sample_hz": WindConfig().sample_hz, "wind.multisine_hz": WindConfig().multisine_hz,
                            "truth.avionics_kg": TruthConfig().avionics_kg,
                            "truth.physics_hz": TruthConfig().physics_hz}  # fmt: skip


def test_clean_run_still_works(files, capsys):
    cfg = toml(files, "ok.toml", "[balloon]\nradius_m = 0.95\n[filter]\nfloat32 = true\n[truth]\nphysics_hz = 400\n")
    assert run("sim", ["--duration", "1", "--config", cfg], capsys)[0] == 0
    assert run("fw", ["--in", str(files / "s.tlog"), "--config", cfg], capsys)[0] == 0


# ---------------------------------------------------------------- property: exit 0 or 2, never a traceback

ANY_NUMBER_TEXT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(2**40), 2**40).map(str),
    st.sampled_from(["", "nan", "-inf", "1e999", "0x10", "3,5", "--", "ten", " 1", "1e9"]),
    st.text(max_size=6),
)
TOML_VALUES = st.one_of(
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(-5.0, 500.0),
    st.sampled_from(["vdh", "steady", "multisine", "paper", "reynolds", "both", "", "A", "yes"]),
    st.lists(st.floats(-1.0, 30.0), max_size=4),
)
KEYS = [(sec, key) for sec, keys in SCHEMA.items() for key in keys]


def toml_literal(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, list):
        return "[" + ", ".join(toml_literal(x) for x in v) + "]"
    if isinstance(v, float) and v != v:
        return "nan"
    if isinstance(v, float) and v in (float("inf"), float("-inf")):
        return "inf" if v > 0 else "-inf"
    return repr(v)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(duration=ANY_NUMBER_TEXT, seed=ANY_NUMBER_TEXT,
       entries=st.lists(st.tuples(st.sampled_from(KEYS), TOML_VALUES), max_size=3))  # fmt: skip
@pytest.mark.slow
def test_random_arguments_and_config_never_crash(files, capsys, duration, seed, entries):
    sections: dict[str, dict[str, object]] = {}
    for (sec, key), val in entries:
        sections.setdefault(sec, {})[key] = val
    text = "".join(f"[{sec}]\n" + "".join(f"{k} = {toml_literal(v)}\n" for k, v in kv.items())
                   for sec, kv in sections.items())  # fmt: skip
    cfg = toml(files, "h.toml", text)
    # --print-config: every argument and the file checked, no flight (a valid duration may be a day)
    argv = ["--duration", duration, "--seed", seed, "--config", cfg, "--scenario", "steady", "--print-config"]
    code, err = run("sim", argv, capsys)
    assert code in (0, 2) and "Traceback" not in err
    code_sim, err_sim = run("sim", ["--duration", "0.2", "--config", cfg, "--scenario", "steady"], capsys)
    code_fw, err_fw = run("fw", ["--in", str(files / "s.tlog"), "--config", cfg], capsys)
    assert code_sim in (0, 2) and code_fw in (0, 2), (err_sim, err_fw)
    assert code_sim == code_fw, (text, err_sim, err_fw)
    if code_sim == 2:
        assert len(err_sim.strip().splitlines()) == 1 and len(err_fw.strip().splitlines()) == 1


@pytest.mark.slow
@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=ANY_NUMBER_TEXT, which=st.sampled_from(["replay --speed", "gs --start", "gs --duration", "sil"]))
def test_random_numbers_to_the_other_programs(files, capsys, value, which):
    """Whatever number (or not) a person types: exit 0 or 2 and one line, never a traceback, never a hang
    (a speed of 1e-300 would pace a replay for ever: speeds are 0 or 0.01 .. 10000)."""
    tlog, truth, wind = str(files / "one.tlog"), str(files / "truth.csv"), str(files / "wind.csv")
    argv = {
        "replay --speed": ("replay", [tlog, "--out", "udpout:127.0.0.1:9", "--speed", value]),
        "gs --start": ("gs", ["report", wind, "--truth", truth, "--start", value]),
        "gs --duration": ("gs", ["listen", "udpin:127.0.0.1:0x", "--duration", value]),
        # an argument error, or a config error before any child starts (the file is refused)
        "sil": ("sil", ["--duration", value, "--seed", value, "--config", toml(files, "bad.toml", "[x]\n")]),
    }[which]
    code, err = run(*argv, capsys)
    if which == "replay --speed" and code == 0:
        assert float(value) == 0.0 or 0.01 <= float(value) <= 10000.0
    assert code in (0, 2) and "Traceback" not in err
    if code == 2:
        assert len(err.strip().splitlines()) == 1


def in_range(rule):
    """Values anywhere in a key's range (its edges included)."""
    if rule.kind == "bool":
        return st.booleans()
    if rule.kind == "str":
        return st.sampled_from(rule.choices)
    if rule.kind == "numbers":
        return st.lists(st.floats(max(rule.lo, 1e-3), min(rule.hi, 5.0)), min_size=rule.length or 1,
                        max_size=rule.length or 4)  # fmt: skip
    return st.floats(rule.lo, rule.hi, exclude_min=rule.lo_open)


IN_RANGE = st.sampled_from(KEYS).flatmap(lambda sk: st.tuples(st.just(sk), in_range(SCHEMA[sk[0]][sk[1]])))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(entries=st.lists(IN_RANGE, min_size=1, max_size=8),
       scenario=st.sampled_from(["steady", "paper-reference", "multisine-2d", "com-offset", "drag-crisis"]))
@pytest.mark.slow
def test_values_anywhere_in_their_ranges_run_or_are_refused_clearly(files, capsys, entries, scenario):
    """The ranges hold what the programs can run: a flight past the release (6 s) and the firmware on a
    capture, or a one-line refusal (a balloon that cannot lift, a design too stiff for the physics step)."""
    sections: dict[str, dict[str, object]] = {}
    for (sec, key), val in entries:
        sections.setdefault(sec, {})[key] = val
    text = "".join(f"[{sec}]\n" + "".join(f"{k} = {toml_literal(v)}\n" for k, v in kv.items())
                   for sec, kv in sections.items())  # fmt: skip
    cfg = toml(files, "r.toml", text)
    for prog, argv in (("sim", ["--duration", "6", "--config", cfg, "--scenario", scenario]),
                       ("fw", ["--in", str(files / "s.tlog"), "--config", cfg])):  # fmt: skip
        code, err = run(prog, argv, capsys)
        assert code in (0, 2) and "Traceback" not in err, (text, err)
        if code == 2:
            assert len(err.strip().splitlines()) == 1, err


def test_a_file_under_dev_is_a_file(tmp_path, capsys):
    """Only a character device (or a name directly in /dev) is a serial port: a file in a memory file system under
    /dev (/dev/shm) keeps every rule of files. Its input is never its output, and it is left byte for byte."""
    shm = Path("/dev/shm")
    if not (shm.is_dir() and os.access(shm, os.W_OK)):
        pytest.skip("no writable /dev/shm here")
    src = shm / f"balloon-wind-test-{os.getpid()}.tlog"
    assert sim_cli.main(["--duration", "2", "--out", str(src), "--truth", str(tmp_path / "t.csv")]) == 0
    try:
        before = src.read_bytes()
        link = tmp_path / "link.tlog"
        link.symlink_to(src)
        for argv in (["--in", str(src), "--out", str(src)], ["--in", str(link), "--out", str(src)],
                     ["--in", str(src), "--out", str(link)]):  # fmt: skip
            code, err = run("fw", argv, capsys)
            assert code == 2 and err.count("\n") == 1 and "is the input" in err, (argv, err)
        assert src.read_bytes() == before and link.is_symlink()
    finally:
        src.unlink()


def test_sil_judges_its_scenario_before_it_makes_its_directory(tmp_path, capsys):
    code, err = run("sil", ["--scenario", "nope", "--outdir", str(tmp_path / "new")], capsys)
    assert code == 2 and err.count("\n") == 1 and "unknown scenario" in err
    assert not (tmp_path / "new").exists()
