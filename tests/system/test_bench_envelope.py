"""benchmarks.bench_envelope: the fixed-seed sample (reproducible, covering, every balloon lifts its
tether with 20 % spare), what reaches the firmware, the extra metrics, the summary's verdicts, one
short real flight through the envelope's case function. Light: a few seconds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from balloon_core.config import lift_balance
from benchmarks import bench_envelope as be
from firmware_py.estimator.state import FilterConfig
from study.case import lift_margin
from study.spec import build
from tests.helpers.cli import run_main


def test_sample_is_fixed_and_covers_the_ranges():
    a, b = be.sample(64), be.sample(64)
    assert a == b
    assert be.sample(64, seed=1) != a
    df = pd.DataFrame(a)
    assert df["from_deg"].between(0, 360).all() and df["mean_mps"].between(1, 8).all()
    assert df["tether_m"].between(50, 150).all() and df["pressure_drift_hpa_h"].between(-3, 3).all()
    assert df["bias_scale"].between(0, 1).all() and (df["radius_m"] <= be.MAX_RADIUS_M).all()
    for col, cats in (("wind_kind", be.WIND_KINDS), ("rope_model", be.ROPES), ("sensor_grade", tuple(be.GRADES))):
        assert set(df[col]) == set(cats)
    # low discrepancy: every quarter of every continuous range holds close to a quarter of the points
    u = be.halton(64, len(be.DIMS))
    for j in range(u.shape[1]):
        counts = np.histogram(u[:, j], bins=4, range=(0, 1))[0]
        assert counts.min() >= 13, (j, counts)


def test_every_design_lifts_its_tether_with_spare_and_the_firmware_gets_only_the_design():
    for p in be.sample(40):
        design, wind, truth, filt = build(be.sections_of(p))
        buoy, skin, gas, rope, _ = lift_balance(design)
        assert buoy >= 1.2 * (skin + gas + rope) - 1e-9
        assert design.balloon.radius_m == p["radius_m"] and design.tether.length_m == p["tether_m"]
        assert filt == FilterConfig()  # truth-only settings never reach the filter
        assert truth.rope_model == p["rope_model"] and truth.pressure_drift_hpa_h == p["pressure_drift_hpa_h"]
    r = be.min_radius(100.0)
    assert 0.9 < r < 1.0


def test_a_measured_drag_coefficient_is_drawn_and_told_with_its_own_sigma(capsys):
    # the default: the truth's C_d within 2.5 x 10 % of the design's, and the filter's prior is that 10 %
    assert FilterConfig().init_drag == be.CD_SIGMA
    wide = pd.DataFrame(be.sample(64))
    assert (wide["cd_scale"] - 1.0).abs().max() > 0.15 and "cd_sigma" not in wide
    # measured to 2 %: the same points, the C_d drawn with 2 % and the filter told so, nothing else changed
    narrow = be.sample(64, cd_sigma=0.02)
    assert all(abs(p["cd_scale"] - 1.0) <= 0.05 + 1e-9 for p in narrow)
    for p, q in zip(narrow, be.sample(64)):
        _, _, truth, filt = build(be.sections_of(p))
        assert filt == FilterConfig(init_drag=0.02) and truth.drag_coefficient_scale == p["cd_scale"]
        assert {k: v for k, v in p.items() if k not in ("cd_scale", "cd_sigma")} == {
            k: v for k, v in q.items() if k != "cd_scale"
        }
    # the widest sigma allowed draws no C_d the simulator refuses ([truth] drag_coefficient_scale >= 0.1)
    assert min(p["cd_scale"] for p in be.sample(200, cd_sigma=be.CD_SIGMA_RANGE[1])) >= 0.1
    assert be.main(["--cd-sigma", "0", "--out", "/nonexistent/never-written"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--cd-sigma must be between" in err


def test_a_balloon_that_turns_is_the_same_points_in_a_world_where_it_turns(capsys):
    """--yaw-moment: the same points, the truth's balloon a weak vane ([truth] yaw_moment_coefficient) and nothing
    told to the filter; out of its range (or not a number) one line and exit 2."""
    for p, q in zip(be.sample(64, yaw_moment=0.01), be.sample(64)):
        assert {k: v for k, v in p.items() if k != "yaw_moment"} == q and p["yaw_moment"] == 0.01
        d1, w1, t1, f1 = build(be.sections_of(p))
        d0, w0, t0, f0 = build(be.sections_of(q))
        assert (d1, w1, f1) == (d0, w0, f0) and t0.yaw_moment_coefficient == 0.0
        assert t1 == dataclasses.replace(t0, yaw_moment_coefficient=0.01)
    for bad in ("-0.01", "0.6", "nan"):
        assert be.main(["--yaw-moment", bad, "--out", "/nonexistent/never-written"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--yaw-moment must be between" in err, err


def test_a_stress_beyond_the_envelope_moves_only_the_mean_wind(capsys):
    """--max-wind: the same points, the mean wind from 1 m/s to the new upper end (in proportion: the point at
    u = 0.5 of the dimension sits half way), everything else as the envelope's; out of its range one line and exit 2."""
    base, strong = be.sample(64), be.sample(64, max_wind_mps=15.0)
    assert max(p["mean_mps"] for p in strong) > 14.0 and min(p["mean_mps"] for p in strong) >= 1.0
    for p, q in zip(base, strong):
        assert math.isclose(q["mean_mps"] - 1.0, (p["mean_mps"] - 1.0) * 14.0 / 7.0, abs_tol=0.005)
        assert {k: v for k, v in p.items() if k != "mean_mps"} == {k: v for k, v in q.items() if k != "mean_mps"}
    assert be.sample(64, max_wind_mps=be.MAX_WIND_MPS) == base
    for bad in ("1", "40", "nan"):
        assert be.main(["--max-wind", bad, "--out", "/nonexistent/never-written"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--max-wind must be between" in err


def test_a_held_out_sample_is_another_draw_of_the_same_envelope(tmp_path, capsys):
    """--sample-seed: other points (none of the fixed sample's), by the same rules (the ranges, the lift's spare), the
    summary saying which sample it is; a seed that is not one is one line and exit 2."""
    fixed, held = be.sample(64), be.sample(64, seed=7)
    assert not {tuple(sorted(p.items())) for p in fixed} & {tuple(sorted(p.items())) for p in held}
    df = pd.DataFrame(held)
    assert df["from_deg"].between(0, 360).all() and df["mean_mps"].between(1, 8).all()
    assert df["tether_m"].between(50, 150).all() and set(df["wind_kind"]) == set(be.WIND_KINDS)
    for p in held[:10]:
        design, _, _, _ = build(be.sections_of(p))
        buoy, skin, gas, rope, _ = lift_balance(design)
        assert buoy >= 1.2 * (skin + gas + rope) - 1e-9
    for bad in ("-1", "seven"):
        code, err = run_main(be.main, ["--sample-seed", bad, "--out", str(tmp_path / "never")], capsys)
        assert code == 2 and err.count("\n") == 1 and "--sample-seed" in err and "Traceback" not in err
    assert not (tmp_path / "never").exists()
    out = tmp_path / "held"
    assert be.main(["--out", str(out), "--serial", "--flights", "1", "--duration", "150", "--start", "60",
                    "--sample-seed", "7"]) == 0  # fmt: skip
    capsys.readouterr()
    head = (out / "envelope_summary.md").read_text().splitlines()[0]
    assert "sample seed 7" in head
    assert pd.read_csv(out / "envelope.csv")["from_deg"].iloc[0] == be.sample(1, seed=7)[0]["from_deg"]


def test_its_out_is_judged_before_any_flight_and_its_products_appear_whole(tmp_path, capsys):
    """--out that is a file, under one, or holding a directory where a product goes: one line, exit 2, before any
    flight is flown; a bad count one line too. A run writes every product under its final name only at the end (no
    temporary left), and exits 0 whatever its targets say (they are in the summary)."""
    (tmp_path / "afile").write_text("mine")
    (tmp_path / "held" / "envelope_summary.md").mkdir(parents=True)
    (tmp_path / "held2").mkdir()
    (tmp_path / "held2" / "parts").write_text("mine")
    for argv, word in (
        (["--out", str(tmp_path / "afile")], "not a directory"),
        (["--out", str(tmp_path / "afile" / "sub")], "does not exist"),
        (["--out", str(tmp_path / "held")], "is a directory"),
        (["--out", str(tmp_path / "held2")], "finished flights"),
        (["--flights", "abc"], "--flights"),
        (["--flights", "1", "--duration", "100", "--start", "120"], "--start"),
    ):
        code, err = run_main(be.main, [*argv, "--serial"], capsys)
        assert code == 2 and err.count("\n") == 1 and word in err and "Traceback" not in err, (argv, err)
    assert (tmp_path / "afile").read_text() == "mine" and not (tmp_path / "held" / "parts").exists()
    out = tmp_path / "run"
    assert be.main(["--out", str(out), "--serial", "--flights", "1", "--duration", "150", "--start", "60"]) == 0
    capsys.readouterr()
    assert {p.name for p in out.iterdir()} == {*be.PRODUCTS, "parts"}


def test_extra_metrics_on_a_known_error():
    t = np.arange(0.0, 300.0, 0.01)
    rows = np.column_stack([t, np.full_like(t, 3.0), np.full_like(t, 0.4), np.full_like(t, 0.1)])
    truth = {"time_s": t, "wind_n": np.full_like(t, 3.0), "wind_e": np.zeros_like(t)}

    class Est:
        class counters:  # noqa: N801
            taut_resets = 1
            field_jumps = 0

    m = be.extra_metrics(rows, truth, Est, 120.0, 300.0)
    assert math.isclose(m["worst_60s_dir_err_deg"], math.degrees(math.atan2(0.4, 3.0)), rel_tol=1e-9)
    assert m["beyond_3sigma"] == 1.0  # 0.4 m/s off with 0.1 stated
    # its direction: 7.6 deg off where 0.1 m/s stated across a 3.03 m/s mean says 1.3 deg
    sigma = math.degrees(math.atan2(0.1 / math.sqrt(2.0), math.hypot(3.0, 0.4)))
    assert math.isclose(m["worst_60s_dir_sigma_deg"], sigma, rel_tol=1e-9)
    assert math.isclose(m["worst_60s_dir_z"], 0.4 / (0.1 / math.sqrt(2.0)), rel_tol=1e-9)  # 0.4 m/s off the ray
    assert m["share_60s_dir_beyond_3sigma"] == 1.0
    assert m["replacements_per_h"] == 12.0
    assert sum(m[f"cal_n_{b}"] for b in range(len(be.CAL_EDGES) - 1)) == 1800


def test_the_seconds_after_the_taut_entry_are_judged_apart():
    """The ENTRY_WINDOW_S after the first taut sample (the rows' mode column), which the scored part leaves out: a wind
    0.4 m/s off for the first 10 s there at 0.1 stated, right afterwards, reads a third of the window beyond 3 sigma;
    the SETTLED_WINDOW_S after it, right, none, or 6 s of it off, a tenth; a flight never taut, or taut only at its
    end, has nothing to judge there."""
    from firmware_py.estimator.state import MODE_FREE, MODE_TAUT

    t = np.arange(0.0, 120.0, 0.01)
    entry = 20.0
    off = np.where((t >= entry) & (t < entry + 10.0), 0.4, 0.0)
    mode = np.where(t >= entry, MODE_TAUT, MODE_FREE)
    rows = np.column_stack([t, 3.0 + off, np.zeros_like(t), np.full_like(t, 0.1), np.zeros((len(t), 6)), mode])
    truth = {"time_s": t, "wind_n": np.full_like(t, 3.0), "wind_e": np.zeros_like(t)}
    m = be.entry_metrics(rows, truth)
    assert m["entry_beyond_3sigma"] == pytest.approx(10.0 / be.ENTRY_WINDOW_S, abs=0.01)
    assert m["entry_err_acc"] == pytest.approx(math.sqrt(10.0 / be.ENTRY_WINDOW_S) * 4.0, rel=0.02)
    assert m["settled_beyond_3sigma"] == 0.0 and m["settled_err_acc"] == 0.0  # the minute after it: right
    off2 = off + np.where((t >= entry + be.ENTRY_WINDOW_S) & (t < entry + be.ENTRY_WINDOW_S + 6.0), 0.4, 0.0)
    rows2 = rows.copy()
    rows2[:, 1] = 3.0 + off2
    assert be.entry_metrics(rows2, truth)["settled_beyond_3sigma"] == pytest.approx(6.0 / be.SETTLED_WINDOW_S, abs=0.01)
    never = rows.copy()
    never[:, 10] = MODE_FREE
    late = rows.copy()
    late[:, 10] = np.where(t >= 115.0, MODE_TAUT, MODE_FREE)
    for r in (never, late):
        assert all(math.isnan(v) for v in be.entry_metrics(r, truth).values())


def test_a_calm_minute_is_judged_by_its_vectors():
    """A minute of gusts whose mean is 0.1 m/s from the south where the estimate says 0.5 m/s from the north, stated
    to 0.8 m/s: 180 deg off, but its mean is 0.6 m/s from the truth's, within a sigma; 1.5 m/s from the north at
    0.3 m/s is 3.5 sigma from any southerly wind."""
    t = np.arange(0.0, 200.0, 0.01)
    truth = {"time_s": t, "wind_n": np.full_like(t, 0.1), "wind_e": np.zeros_like(t)}

    class Est:
        class counters:  # noqa: N801
            taut_resets = 0
            field_jumps = 0

    for speed, stated, z in ((0.5, 0.8, 0.5 / (0.8 / math.sqrt(2.0))), (1.5, 0.3, 1.5 / (0.3 / math.sqrt(2.0)))):
        rows = np.column_stack([t, np.full_like(t, -speed), np.zeros_like(t), np.full_like(t, stated)])
        m = be.extra_metrics(rows, truth, Est, 60.0, 200.0)
        assert math.isclose(m["worst_60s_dir_err_deg"], 180.0, abs_tol=1e-9)
        assert math.isclose(m["worst_60s_dir_z"], z, rel_tol=1e-9)
        assert m["share_60s_dir_beyond_3sigma"] == (1.0 if z > 3.0 else 0.0)


def test_summary_verdicts():
    n = 20
    df = pd.DataFrame({
        "status": ["ok"] * n, "speed_err_pct": [1.0] * n, "dir_err_deg": [0.5] * (n - 1) + [9.0],
        "worst_60s_dir_err_deg": [2.0] * n, "err_acc": [1.0] * n, "beyond_3sigma": [0.0] * n,
        "replacements_per_h": [0.0] * n, "taut_resets": [0.0] * n, "band_skill": [0.8] * n,
        "wind_kind": ["kaimal"] * n,
    })  # fmt: skip
    df.attrs["duration_s"] = 600.0
    text, targets = be.summary(df)
    verdict = {t.split(" (")[0]: ok for t, ok in targets}
    assert verdict["|dir| <= 3 deg in 95 % of flights"] and not verdict["|dir| <= 8 deg in all"]
    assert (
        verdict["|speed| <= 4 % in 95 % of flights"] and verdict["band skill >= 0.6 on fluctuating winds, every flight"]
    )
    assert "| |direction error| deg |" in text and "FAIL" in text
    assert "by where the wind comes from" not in text  # no directions in this table


def test_the_summary_splits_the_flights_by_where_the_wind_comes_from():
    """Four flights per 90 deg sector centred on N, E, S, W (315 deg is north, 314.9 west, 45 east): the
    southern sector's band skill and direction misses show in its own counts, not spread over all."""
    deg = [0.0, 44.9, 315.0, 330.0, 45.0, 90.0, 120.0, 134.9, 135.0, 180.0, 200.0, 224.9, 225.0, 270.0, 300.0, 314.9]
    south = [8, 9, 10, 11]
    n = len(deg)
    df = pd.DataFrame({
        "status": ["ok"] * n, "from_deg": deg, "speed_err_pct": [1.0] * n,
        "dir_err_deg": [5.0 if i in (9, 10) else 0.5 for i in range(n)], "worst_60s_dir_err_deg": [2.0] * n,
        "err_acc": [1.6 if i in south else 0.8 for i in range(n)], "beyond_3sigma": [0.0] * n,
        "replacements_per_h": [0.0] * n, "taut_resets": [0.0] * n,
        "band_skill": [0.3 if i in (8, 9, 10) else (float("nan") if i == 11 else 0.8) for i in range(n)],
        "wind_kind": ["steady" if i == 11 else "multisine" for i in range(n)],
    })  # fmt: skip
    df.attrs["duration_s"] = 600.0
    line = next(ln for ln in be.summary(df)[0].splitlines() if ln.startswith("by where the wind comes from"))
    assert "from N (4): band skill at its bar 100 %, |dir| <= 3 deg 100 %, err/acc p50 0.80" in line
    assert "from E (4): band skill at its bar 100 %" in line and "from W (4): band skill at its bar 100 %" in line
    # the steady one has no band skill to count: 0 of the three fluctuating flights; two of four off in direction
    assert "from S (4): band skill at its bar 0 %, |dir| <= 3 deg 50 %, err/acc p50 1.60" in line


def test_the_summary_says_what_to_expect_by_the_mean_wind():
    """Two flights in light air (1-2 m/s), one of them 10 deg off and 5 % beyond 3 sigma at err/acc 1.5, and three in
    a fresh wind (6 m/s): each band's row has its own flights' errors, and a band without flights has no row."""
    n = 5
    df = pd.DataFrame({
        "status": ["ok"] * n, "mean_mps": [1.2, 1.8, 6.0, 6.0, 7.9], "speed_err_pct": [-3.0, 1.0, 2.0, -4.0, 6.0],
        "dir_err_deg": [-10.0, 2.0, 0.1, 0.2, -0.3], "worst_60s_dir_err_deg": [12.0, 3.0, 1.0, 1.0, 1.0],
        "err_acc": [1.5, 0.5, 0.6, 0.7, 0.8], "beyond_3sigma": [0.05, 0.0, 0.0, 0.0, 0.01],
        "raw_rmse_mps": [0.4, 0.2, 0.1, 0.3, 0.2], "replacements_per_h": [0.0] * n, "taut_resets": [0.0] * n,
        "band_skill": [0.1, float("nan"), 0.9, 0.7, 0.8], "wind_kind": ["gusts", "steady", "kaimal", "kaimal", "gusts"],
    })  # fmt: skip
    df.attrs["duration_s"] = 600.0
    lines = be.summary(df)[0].splitlines()
    light = next(ln for ln in lines if ln.startswith("| 1-2 m/s |"))
    fresh = next(ln for ln in lines if ln.startswith("| 4 m/s and more |"))
    assert not any(ln.startswith("| 2-4 m/s |") for ln in lines)
    assert light == "| 1-2 m/s | 2 | 6 / 9.6 / 10 | 2 / 2.9 / 3 | 0.3 | 1.00 | 50 % | 5 % | 0.10 |", light
    assert fresh == "| 4 m/s and more | 3 | 0.2 / 0.29 / 0.3 | 4 / 5.8 / 6 | 0.2 | 0.70 | 100 % | 1 % | 0.80 |", fresh


def test_a_balloon_near_its_lift_limit_is_held_to_the_lower_skill_bar():
    """The issue's bar: band skill >= 0.6 on fluctuating winds, >= 0.4 for a balloon within 30 % of its lift limit
    (buoyancy < 1.3 x what it carries). Balloons sized by the lift balance for 20 %, 29 %, 31 % and 100 % spare on a
    100 m tether, their rows' lift margin from the study's own metric: the first two at 0.4. In a summary a marginal
    balloon at 0.5 passes where a roomy one fails, 0.35 fails both, whatever steady or unscored flights come first;
    a row without a lift margin is held to 0.6."""
    frac = []
    for spare in (0.2, 0.29, 0.31, 1.0):
        secs = be.sections_of(be.sample(1)[0])
        secs["tether"]["length_m"] = 100.0
        secs["balloon"]["radius_m"] = be.min_radius(100.0, spare=spare)
        frac.append(lift_margin(build(secs)[0])[1])
    assert be.skill_bar(pd.DataFrame({"lift_margin_frac": frac})).tolist() == [0.4, 0.4, 0.6, 0.6]
    assert be.skill_bar(pd.DataFrame({"band_skill": [0.5]})).tolist() == [0.6]
    marginal, roomy = frac[0], frac[3]

    def verdict(skill, margin):
        skill, margin = [0.1, float("nan"), *skill], [roomy, roomy, *margin]  # a steady flight, an unscored one
        n = len(skill)
        df = pd.DataFrame({
            "status": ["ok"] * n, "speed_err_pct": [1.0] * n, "dir_err_deg": [0.5] * n,
            "worst_60s_dir_err_deg": [2.0] * n, "err_acc": [1.0] * n, "beyond_3sigma": [0.0] * n,
            "replacements_per_h": [0.0] * n, "taut_resets": [0.0] * n, "band_skill": skill,
            "wind_kind": ["steady", *["gusts"] * (n - 1)], "lift_margin_frac": margin,
        })  # fmt: skip
        df.attrs["duration_s"] = 600.0
        (text, ok), = [t for t in be.summary(df)[1] if t[0].startswith("band skill")]
        return ok, text

    ok, text = verdict([0.8, 0.5], [roomy, marginal])
    assert ok and "1 flights; 100.0 %, worst 0.50)" in text
    assert not verdict([0.8, 0.5], [roomy, roomy])[0]
    assert not verdict([0.8, 0.35], [roomy, marginal])[0]


def test_the_speed_error_the_drag_scale_alone_makes():
    # F ~ C_d U^2: a truth with 21 % more drag than the filter's reads 10 % fast, 21 % less drag ~9 % slow
    assert np.allclose(be.drag_share_pct([1.21, 1.0, 1.0], [1.0, 1.21, 1.0]), [10.0, -100.0 / 11.0, 0.0])
    n = 10
    df = pd.DataFrame({
        "status": ["ok"] * n, "speed_err_pct": [1.0] * (n - 3) + [10.5, -9.0, -9.0], "dir_err_deg": [0.5] * n,
        "worst_60s_dir_err_deg": [2.0] * n, "err_acc": [1.0] * n, "beyond_3sigma": [0.0] * n,
        "replacements_per_h": [0.0] * n, "taut_resets": [0.0] * n, "band_skill": [0.8] * n,
        "wind_kind": ["kaimal"] * n,
        # the eighth's miss is its drag scale (the truth's C_d 21 % above the filter's: +10 %); the ninth's is not (no
        # share), nor the tenth's (a share of +10 % against an error of -9 %: the other sign)
        "cd_scale": [1.0] * (n - 3) + [1.21, 1.0, 1.21], "drag_scale": [1.0] * n,
        "drag_scale_sigma": [0.21] * (n - 3) + [0.21, 0.1, 0.21],
    })  # fmt: skip
    df.attrs["duration_s"] = 600.0
    text, _ = be.summary(df)
    assert "3 of 10 flights beyond 4 %, 1 of them with at least half the error" in text
    # taken out: the eighth is 0.45 % off; the tenth (-9 % less +10 %) is 17 % off
    assert "with that share taken out 80.0 % of flights are within 4 %" in text
    # the drag scale's error over its 1-sigma: 0 in eight flights, 1 in two
    assert "p50 0.00, p95 1.00" in text
    # rows without a drag scale (an older part) are left out, not counted as misses
    df.loc[0, "drag_scale"] = np.nan
    assert "3 of 9 flights beyond 4 %" in be.summary(df)[0]


def test_one_short_flight_through_the_envelope_case():
    c = be.cases(be.sample(3), 100.0, 20.0)[1]
    row = be.envelope_case(c.payload())
    assert row["status"] == "ok", row["error"]
    assert 0.5 < row["drag_scale"] < 1.5 and 0.0 < row["drag_scale_sigma"] < 2.0 * be.CD_SIGMA
    for k in ("dir_err_deg", "err_acc", "worst_60s_dir_err_deg", "beyond_3sigma", "replacements_per_h", "resets"):
        assert math.isfinite(row[k]), k
    assert row["accuracy_factor"] >= 1.0  # the monitor's factor never shrinks the stated accuracy


def test_what_the_err_acc_band_asks():
    """One factor on every stated accuracy fixes a flight set that is uniformly cautious (all at 0.5: 100 % within
    0.75-1.33 at a factor 0.38-0.67), not one whose ratios spread by factors of four (0.25, 1, 4: at most a third)."""
    line = be.ratio_spread(pd.DataFrame({"err_acc": [0.5] * 12}))
    assert "spreads by 0.00" in line and "at most 100.0 % within it" in line
    factor = float(line.rsplit("x ", 1)[1].rstrip(")"))
    assert 0.5 / 1.33 <= factor <= 0.5 / 0.75
    line = be.ratio_spread(pd.DataFrame({"err_acc": [0.25, 1.0, 4.0] * 4 + [float("nan")]}))
    assert "at most 33.3 % within it" in line and "needs about 0.17" in line
    assert be.ratio_spread(pd.DataFrame({"err_acc": [1.0]})) == ""


def test_what_the_over_caution_is_made_of():
    """The flights below the err/acc band whose monitor's factor is at least FACTOR_SHOWN are named by the source that
    set it, with what err/acc would be without it; a flight cautious for another reason (its factor 1) is counted
    below the band only, and a set without the columns (an older part) says nothing."""
    df = pd.DataFrame({
        "err_acc": [0.2, 0.25, 0.3, 0.5, 1.0, 1.1],
        "accuracy_factor": [4.0, 3.0, 1.6, 1.0, 1.0, 2.0],
        "factor_source": [0.0, 0.0, 5.0, np.nan, np.nan, 5.0],
    })  # fmt: skip
    line = be.caution_causes(df)
    assert "4 of 6 flights below err/acc 0.75" in line
    assert "in 3 of them the consistency monitor's factor is at least 1.25" in line
    assert "set most by: accel 2, force 1" in line
    # without the factor: 0.8, 0.75, 0.48 (p50 0.75); so within the band: 0.8, 0.75, 1.0, 1.1 of six
    assert "without the factor (times its RMS, about) 0.75" in line and "66.7 %" in line
    assert be.caution_causes(df.drop(columns=["factor_source"])) == ""
    calm = pd.DataFrame({"err_acc": [1.0], "accuracy_factor": [1.0], "factor_source": [np.nan]})
    assert be.caution_causes(calm) == ""
