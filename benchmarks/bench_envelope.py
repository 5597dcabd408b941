"""The operating envelope: many flights from a seeded low-discrepancy sample of the conditions a
user may meet, each run through the study engine, scored, summarised against the issue's targets.

    .venv/bin/python -m benchmarks.bench_envelope [--quick] [--flights N] [--out DIR] [--cd-sigma S]
        [--max-wind U] [--sample-seed N] [--serial | --workers N | --scheduler tcp://HOST:PORT]

Sampled per flight (a scrambled Halton sequence, a fixed seed unless ``--sample-seed`` draws a held-out one): wind
direction 0-360 deg, mean speed 1-8 m/s (``--max-wind``: up to another, e.g. a stress beyond the envelope the targets
are set for), wind kind (steady | multisine both axes | VdH + Kaimal with vertical | IEC class B gusts with
vertical), rope model of the truth (lumped | paper), tether 50-150 m, balloon radius from the smallest that lifts its
tether with 20 % spare lift (``balloon_core.config.lift_balance``) up to 1.6 m, weather pressure drift +-3 hPa/h,
wandering gyro/accelerometer biases (0-1 x the field-biases scenario's), sensor grade (Table 2 | MEMS | tactical),
the simulator seed, and the balloon's and the rope's drag coefficients about the design's (a sphere's C_d known to
10 %, ``--cd-sigma``; a rope's C_n to 30 %). The firmware is told only the design (balloon, tether, sensors); everything
else is truth only, its [filter] stays the default (with ``--cd-sigma`` other than 0.1 it is told that 1-sigma:
``[filter] init_drag``).

Per flight (after ``start_s``): the study metrics (``study.case.metrics``) plus the worst 60 s mean
direction error, the share of samples whose horizontal error exceeds 3 x the reported accuracy,
taut re-placements (``counters.taut_resets``) per hour, and binned stated-vs-actual error for the
calibration plot; apart from those, error / stated accuracy and the share beyond 3 sigma in the ENTRY_WINDOW_S after
the first taut entry and in the SETTLED_WINDOW_S after that (before ``start_s``: the entry's settling and the first
minute on a settled tether, not targets). Writes envelope.parquet,
envelope.csv, envelope_summary.md and PNG plots into ``--out``.
Finished flights are stored as parts (``DIR/parts``): a repeated run only computes what is missing. The products
appear under their final names only when all are written. Exit 0 when the run is done (its targets pass or fail in
the summary), 2 a user error (one line, before any flight is flown), as every program of the project.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import os
import shutil
import sys
import time
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from balloon_core import userargs
from balloon_core.config import Design, lift_balance
from balloon_core.score import on_grid, score
from firmware_py.estimator.consistency import SOURCES
from firmware_py.estimator.state import MODE_TAUT
from sim_hil.scenarios import SCENARIOS
from study import engine
from study.cli import max_workers
from study.metrics import FACTOR_SHOWN
from study.spec import Case, case_key, scenario_sections

BASE = "field-rope"  # the real world: lumped rope with its drag, vertical turbulence
SEED = 20261202
MAX_RADIUS_M = 1.6
SPARE_LIFT = 0.20  # buoyancy >= 1.2 x everything it carries (skin and avionics, gas, the whole rope)
WIND_KINDS = ("steady", "multisine", "kaimal", "gusts")
ROPES = ("lumped", "paper")
GRADES = {  # sensor 1-sigma errors the design states (and the simulator draws)
    "table2": {"accel_mps2": 0.01, "baro_m": 1.0, "gyro_dps": 1.0, "mag_gauss": 0.005},
    "mems": {"accel_mps2": 0.014, "baro_m": 0.1, "gyro_dps": 0.07, "mag_gauss": 0.002},
    "tactical": {"accel_mps2": 0.002, "baro_m": 0.1, "gyro_dps": 0.1, "mag_gauss": 0.0005},
}
BIASES = {"gyro_bias_dps": 0.3, "gyro_bias_walk_dps_rt_s": 0.002, "accel_bias_mps2": 0.02,
          "accel_bias_walk_mps2_rt_s": 0.001}  # fmt: skip  # the field-biases scenario's, x bias_scale
DIMS = ("from_deg", "mean_mps", "wind_kind", "rope_model", "radius_u", "tether_m", "pressure_drift_hpa_h",
        "bias_scale", "sensor_grade", "seed", "cd_scale", "rope_cd_scale")  # fmt: skip
#: sampled parameters as they appear in the table (radius_u becomes radius_m)
PARAMS = ("from_deg", "mean_mps", "wind_kind", "rope_model", "radius_m", "tether_m", "pressure_drift_hpa_h",
          "bias_scale", "sensor_grade", "seed", "cd_scale", "rope_cd_scale")  # fmt: skip
# the balloon and the rope flown are not the design's: their drag coefficients are the design's times a factor
# drawn from what a user knows of them (1-sigma, truncated at 2.5 sigma): a sphere's C_d to 10 % (the filter's
# default prior, [filter] init_drag, assumes as much), a rope's cross-flow C_n to 30 %. ``--cd-sigma``: a balloon
# whose C_d was measured (a tow or a wind-tunnel test), the truth's drawn and the filter told with that 1-sigma
CD_SIGMA = 0.10
MAX_WIND_MPS = 8.0  # the mean wind's upper end, the envelope's (--max-wind takes another: a stress beyond it)
MAX_WIND_RANGE = (2.0, 25.0)
YAW_MOMENT_RANGE = (0.0, 0.5)  # [truth] yaw_moment_coefficient: 0 a perfect sphere, 0.01 a weak vane
TURN_RANGE_DEG = (-360.0, 360.0)  # --turn-deg: a front turns the wind by this much ([wind] turn_deg)
TURN_DURATION_S = 60.0  # ... in a minute, halfway through the scored part
CD_SIGMA_RANGE = (0.005, 0.3)  # at 0.3 the 2.5-sigma draw keeps the C_d at 0.25 of the design's (the floor: 0.1)
ROPE_CD_SIGMA = 0.30
WINDOW_S = 60.0
# the per-flight bars (the summary's targets, its by-direction line, the speed misses, the plots)
DIR_TARGET_DEG = 3.0
SPEED_TARGET_PCT = 4.0
SKILL_TARGET = 0.6
RATIO_BAND = (0.75, 1.33)  # err/acc within this ...
RATIO_SHARE = 0.90  # ... in this share of the flights
# ... and for a balloon within 30 % of its lift limit (its buoyancy less than 1.3 x everything it carries: the
# sample's smallest balloons, from SPARE_LIFT up), which leans far over and pulls its rope less taut
MARGINAL_SPARE_LIFT = 0.30
MARGINAL_SKILL_TARGET = 0.4
CAL_EDGES = np.geomspace(0.02, 5.0, 15)  # stated accuracy bins, m/s
# not a target: the first seconds on the tether (the taut entry's settling, before the scored part of the flight)
ENTRY_WINDOW_S = 30.0
SETTLED_WINDOW_S = 60.0  # ... and the minute after it (the first on a settled tether, where a user starts to trust it)
ENVELOPE_VERSION = 6
#: the study's metric names as the envelope's table names them (one row per flight, envelope.csv)
# a flight's length (the wind's realisation depends on it: the same flight is the same only at the same length)
FULL_DURATION_S = 600.0
QUICK_DURATION_S = 300.0
CONTRACT_NAMES = {"speed_error_pct": "speed_err_pct", "direction_error_deg": "dir_err_deg", "error_ratio": "err_acc"}

# ---------------------------------------------------------------- the sample


def _primes(n: int) -> list[int]:
    out, k = [], 2
    while len(out) < n:
        if all(k % p for p in out):
            out.append(k)
        k += 1
    return out


def halton(n: int, d: int, seed: int = SEED) -> np.ndarray:
    """n points of a d-dimensional Halton sequence in [0, 1), scrambled by a fixed-seed random digit
    permutation per base and digit (the radical inverse's digits permuted, as scipy.stats.qmc.Halton's
    scramble does; the low discrepancy is kept, the seed fixes the points). Plain numpy (scipy is not
    a dependency): the same points on every machine."""
    rng = np.random.default_rng(seed)
    out = np.zeros((n, d))
    idx = np.arange(1, n + 1)  # skip 0 (all digits 0)
    for j, b in enumerate(_primes(d)):
        digits = int(math.ceil(math.log(n + 1, b))) + 2
        perms = [rng.permutation(b) for _ in range(digits)]
        i, f, x = idx.copy(), 1.0 / b, np.zeros(n)
        for k in range(digits):
            x += perms[k][i % b] * f
            i //= b
            f /= b
        out[:, j] = x
    return out


def min_radius(tether_m: float, design: Design | None = None, spare: float = SPARE_LIFT) -> float:
    """Smallest radius whose buoyancy carries skin, gas and the whole tether with ``spare`` to spare:
    buoyancy >= (1 + spare) x their weight, by the project's own lift balance (bisection)."""
    d0 = design or Design()

    def ok(r: float) -> bool:
        d = dataclasses.replace(d0, balloon=dataclasses.replace(d0.balloon, radius_m=r),
                                tether=dataclasses.replace(d0.tether, length_m=tether_m))  # fmt: skip
        buoy, skin, gas, rope, _ = lift_balance(d)
        return buoy >= (1.0 + spare) * (skin + gas + rope)

    lo, hi = 0.05, 20.0
    if not ok(hi):
        raise ValueError(f"no radius up to {hi} m lifts a {tether_m} m tether with {spare:.0%} spare")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


def pick(u: float, choices: tuple[str, ...]) -> str:
    return choices[min(int(u * len(choices)), len(choices) - 1)]


def sample(
    n: int, seed: int = SEED, cd_sigma: float = CD_SIGMA, max_wind_mps: float = MAX_WIND_MPS, yaw_moment: float = 0.0,
    turn: tuple[float, float] | None = None,
) -> list[dict[str, Any]]:
    """The n flights' parameters (a dict per flight, in the order of ``PARAMS``); the balloon's C_d drawn with
    1-sigma ``cd_sigma`` (any other than CD_SIGMA is also what the filter is told: ``cd_sigma`` in each dict); the
    mean wind from 1 m/s to ``max_wind_mps`` (the same points: only that dimension's scale moves); a balloon that turns
    as a weak vane where ``yaw_moment`` (its [truth] yaw_moment_coefficient, in each dict) is not 0 (the same
    points); a front where ``turn`` is (degrees, start s): the wind turns by that much in TURN_DURATION_S from the
    start (``turn_deg`` and ``turn_start_s`` in each dict; the same points)."""
    u = halton(n, len(DIMS), seed)
    out = []
    for row in u:
        v = dict(zip(DIMS, row))
        tether = float(50.0 + 100.0 * v["tether_m"])
        r0 = min_radius(tether)
        out.append({
            "from_deg": float(round(360.0 * v["from_deg"], 3)),
            "mean_mps": float(round(1.0 + (max_wind_mps - 1.0) * v["mean_mps"], 3)),
            "wind_kind": pick(v["wind_kind"], WIND_KINDS),
            "rope_model": pick(v["rope_model"], ROPES),
            "radius_m": float(round(r0 + (MAX_RADIUS_M - r0) * v["radius_u"], 4)),
            "tether_m": float(round(tether, 2)),
            "pressure_drift_hpa_h": float(round(-3.0 + 6.0 * v["pressure_drift_hpa_h"], 3)),
            "bias_scale": round(float(v["bias_scale"]), 4),
            "sensor_grade": pick(v["sensor_grade"], tuple(GRADES)),
            "seed": int(v["seed"] * 1_000_000),
            "cd_scale": drawn_scale(v["cd_scale"], cd_sigma),
            "rope_cd_scale": drawn_scale(v["rope_cd_scale"], ROPE_CD_SIGMA),
        })  # fmt: skip
        if cd_sigma != CD_SIGMA:
            out[-1]["cd_sigma"] = cd_sigma
        if yaw_moment:
            out[-1]["yaw_moment"] = yaw_moment
        if turn is not None:
            out[-1]["turn_deg"], out[-1]["turn_start_s"] = turn
    return out


def drawn_scale(u: float, sigma: float) -> float:
    """1 + sigma z, z the standard normal quantile of the sample's u, truncated at 2.5 sigma."""
    z = NormalDist().inv_cdf(min(max(u, 1e-9), 1.0 - 1e-9))
    return float(round(1.0 + sigma * max(-2.5, min(2.5, z)), 4))


def sections_of(p: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Every section of the flight: the base scenario's, then the sampled values. Only balloon, tether
    and sensors reach the firmware (as the design file a user writes); wind and truth are the world."""
    secs = scenario_sections(SCENARIOS[BASE])
    secs["balloon"]["radius_m"] = p["radius_m"]
    secs["tether"]["length_m"] = p["tether_m"]
    secs["sensors"].update(GRADES[p["sensor_grade"]])
    w = secs["wind"]
    w.update({"mean_mps": p["mean_mps"], "from_deg": p["from_deg"], "vertical": True, "iec_class": ""})
    kind = p["wind_kind"]
    if kind == "steady":
        w["kind"] = "steady"
    elif kind == "multisine":
        w.update({"kind": "multisine", "multisine_axes": "both"})
    else:
        w["kind"] = "vdh"
        if kind == "gusts":
            w["iec_class"] = "B"
    t = secs["truth"]
    t["rope_model"] = p["rope_model"]
    t["pressure_drift_hpa_h"] = p["pressure_drift_hpa_h"]
    t["drag_coefficient_scale"] = p.get("cd_scale", 1.0)
    t["rope_normal_cd"] *= p.get("rope_cd_scale", 1.0)
    t.update({k: v * p["bias_scale"] for k, v in BIASES.items()})
    if "cd_sigma" in p:  # a measured C_d: the user writes its 1-sigma into the design's [filter]
        secs["filter"]["init_drag"] = p["cd_sigma"]
    if "yaw_moment" in p:  # the balloon turns (the world's, not the design's)
        t["yaw_moment_coefficient"] = p["yaw_moment"]
    if "turn_deg" in p:  # a front turns the wind
        w.update({"turn_deg": p["turn_deg"], "turn_start_s": p["turn_start_s"], "turn_duration_s": TURN_DURATION_S})
    return secs


def cases(params: list[dict[str, Any]], duration_s: float, start_s: float) -> list[Case]:
    out = []
    for i, p in enumerate(params):
        c = Case("envelope", {"flight": i, **p}, sections_of(p), p["seed"], duration_s, start_s)
        key = hashlib.sha256(f"envelope-v{ENVELOPE_VERSION}-{case_key(c)}".encode()).hexdigest()[:20]
        out.append(dataclasses.replace(c, key=key))
    return out


# ---------------------------------------------------------------- one flight (on a worker)


def extra_metrics(rows, truth, est, start_s: float, duration_s: float) -> dict[str, float]:
    """What study.case.metrics does not give: the worst 60 s mean direction error, the share beyond
    3 sigma, taut re-placements per hour, and the calibration bins (stated vs actual error)."""
    grid, en, ee, ac, tn, te = on_grid(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"],
                                       truth["wind_n"], truth["wind_e"], start_s)  # fmt: skip
    out: dict[str, float] = {}
    n = int(round(WINDOW_S * 10.0))  # the grid is 10 Hz
    if len(grid) >= n:
        c = lambda x: np.concatenate([[0.0], np.cumsum(x)])  # noqa: E731
        mean = lambda cs: (cs[n:] - cs[:-n]) / n  # noqa: E731 - sliding 60 s means, every 0.1 s
        mn, me = mean(c(en)), mean(c(ee))
        d_est = np.degrees(np.arctan2(me, mn))
        d_true = np.degrees(np.arctan2(mean(c(te)), mean(c(tn))))
        d_err = np.abs((d_est - d_true + 180.0) % 360.0 - 180.0)
        out["worst_60s_dir_err_deg"] = float(np.max(d_err))
        # what the flight stated of that direction: the window's mean accuracy (its systematic part does not average
        # out) across the mean vector (half the horizontal variance), as an angle: 90 deg where it exceeds the speed
        axis = mean(c(ac)) / math.sqrt(2.0)
        sigma = np.degrees(np.arctan2(axis, np.hypot(mn, me)))
        # how many of those sigmas the estimate's mean lies from the nearest wind of the truth's direction (the ray
        # from calm): |m| sin(err) up to 90 deg off, |m| beyond. An angle's ratio would read a calm minute's mean,
        # 0.1 m/s in gusts and 180 deg off, beyond 3 sigma where the vectors are within their stated accuracy
        z = np.hypot(mn, me) * np.sin(np.radians(np.minimum(d_err, 90.0))) / np.maximum(axis, 1e-9)
        out["worst_60s_dir_z"] = float(np.max(z))
        out["share_60s_dir_beyond_3sigma"] = float(np.mean(z > 3.0))
        out["worst_60s_dir_sigma_deg"] = float(sigma[int(np.argmax(d_err))])
    else:
        out["worst_60s_dir_err_deg"] = out["worst_60s_dir_z"] = math.nan
        out["share_60s_dir_beyond_3sigma"] = out["worst_60s_dir_sigma_deg"] = math.nan
    err = np.hypot(en - tn, ee - te)
    out["beyond_3sigma"] = float(np.mean(err > 3.0 * ac))
    out.update(entry_metrics(rows, truth))
    out["taut_resets"] = float(est.counters.taut_resets)
    out["field_jumps"] = float(est.counters.field_jumps)
    out["replacements_per_h"] = float(est.counters.taut_resets) / (duration_s / 3600.0)
    k = np.clip(np.digitize(ac, CAL_EDGES) - 1, 0, len(CAL_EDGES) - 2)
    for b in range(len(CAL_EDGES) - 1):
        m = k == b
        out[f"cal_n_{b}"] = float(m.sum())
        out[f"cal_a2_{b}"] = float(np.sum(ac[m] ** 2))
        out[f"cal_e2_{b}"] = float(np.sum(err[m] ** 2))
    return out


def entry_metrics(rows, truth) -> dict[str, float]:
    """The ENTRY_WINDOW_S after the first taut entry (``study.case.fly``'s mode column) and the SETTLED_WINDOW_S after
    that, which the scored part of the flight leaves out (or partly): error / stated accuracy and the share beyond 3
    sigma in each (``entry_*``, ``settled_*``; NaN: never taut, or less than a third of the window flown)."""
    out = {f"{w}_{m}": math.nan for w in ("entry", "settled") for m in ("err_acc", "beyond_3sigma")}
    taut = np.flatnonzero(rows[:, 10] == MODE_TAUT) if rows.shape[1] > 10 else np.zeros(0, int)
    if not len(taut):
        return out
    t0 = rows[taut[0], 0]
    for name, start, length in (("entry", t0, ENTRY_WINDOW_S), ("settled", t0 + ENTRY_WINDOW_S, SETTLED_WINDOW_S)):
        w = rows[(rows[:, 0] >= start) & (rows[:, 0] < start + length)]
        if not len(w) or w[-1, 0] - start < length / 3.0:  # the flight's end: too little to judge
            continue
        sc = score(w[:, 0], w[:, 1], w[:, 2], w[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], start)
        out[f"{name}_err_acc"], out[f"{name}_beyond_3sigma"] = sc.error_ratio, sc.beyond_3sigma
    return out


def envelope_case(payload: dict[str, Any]) -> dict[str, Any]:
    """``study.case.run_case`` with the extra metrics: the same flight (``fly``), the same metrics."""
    from study.case import fly, metrics
    from study.spec import build

    t0 = time.perf_counter()
    row: dict[str, Any] = {"key": payload["key"], "status": "ok", "error": ""}
    try:
        design, wind, truth_cfg, filt = build(payload["sections"])
        rows, truth, est = fly(design, wind, truth_cfg, filt, payload["duration_s"], payload["seed"])
        m = metrics(design, wind, rows, truth, est, payload["start_s"])
        row.update({CONTRACT_NAMES.get(k, k): v for k, v in m.items()})
        row.update(extra_metrics(rows, truth, est, payload["start_s"], payload["duration_s"]))
    except Exception as e:  # one broken flight must not stop the envelope
        row["status"], row["error"] = "failed", f"{type(e).__name__}: {e}"
    row["wall_time_s"] = time.perf_counter() - t0
    return row


# ---------------------------------------------------------------- the summary


def _pct(x, q: float) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if len(x) else math.nan


def summary(df) -> tuple[str, list[tuple[str, bool]]]:
    """The markdown summary table (percentiles and worst) and the targets with pass/fail."""
    ok = df[df["status"] == "ok"]
    cols = {
        "|speed error| %": ok["speed_err_pct"].abs(),
        "|direction error| deg": ok["dir_err_deg"].abs(),
        "worst 60 s mean |dir error| deg": ok["worst_60s_dir_err_deg"],
        "err/acc": ok["err_acc"],
        "share beyond 3 sigma %": 100.0 * ok["beyond_3sigma"],
        "taut re-placements /h": ok["replacements_per_h"],
        "band skill (fluctuating winds)": ok.loc[ok["wind_kind"] != "steady", "band_skill"],
    }
    if "worst_60s_dir_z" in ok:
        # not a target: did the flight say so? (the 60 s means' direction error over the direction's stated 1-sigma)
        cols["worst 60 s mean |dir error| / its stated sigma"] = ok["worst_60s_dir_z"]
        cols["60 s means beyond 3 stated sigma %"] = 100.0 * ok["share_60s_dir_beyond_3sigma"]
    if "tilt_err_deg" in ok and "tilt_sigma_deg" in ok:
        # not a target: the attitude's honesty (RMS tilt error over the filter's own RMS 1-sigma), which decides the
        # wind's in light air (a degree of lean)
        cols["tilt error / stated tilt"] = ok["tilt_err_deg"] / ok["tilt_sigma_deg"]
    lines = ["| metric | p50 | p90 | p95 | worst |", "|---|---:|---:|---:|---:|"]
    for name, s in cols.items():
        worst = s.min() if name.startswith("band skill") else (s.max() if name != "err/acc" else _far(s))
        q = (50, 10, 5) if name.startswith("band skill") else (50, 90, 95)  # skill: low is bad
        lines.append(f"| {name}{' (p10, p5)' if q[1] == 10 else ''} | " + " | ".join(f"{_pct(s, x):.3g}" for x in q)
                     + f" | {worst:.3g} |")  # fmt: skip
    d, sp, r = cols["|direction error| deg"], cols["|speed error| %"], cols["err/acc"]
    n_ok, n_all = len(ok), len(df)
    flown_h = float(df.attrs.get("duration_s", FULL_DURATION_S)) * n_ok / 3600.0
    hours = float(ok["taut_resets"].sum()) / flown_h if n_ok else math.nan
    fluct = ok[ok["wind_kind"] != "steady"]
    scored = np.isfinite(fluct["band_skill"].to_numpy(float))
    skill, bar = fluct["band_skill"].to_numpy(float)[scored], skill_bar(fluct)[scored]
    marginal = int(np.sum(bar < SKILL_TARGET))
    targets = [
        (f"every flight ran ({n_ok}/{n_all})", n_ok == n_all),
        (f"|dir| <= {DIR_TARGET_DEG:g} deg in 95 % of flights ({100 * np.mean(d <= DIR_TARGET_DEG):.1f} %)",
         np.mean(d <= DIR_TARGET_DEG) >= 0.95),
        (f"|dir| <= 8 deg in all (worst {d.max():.2f})", bool(d.max() <= 8.0)),
        (f"no 60 s mean > 12 deg off (worst {cols['worst 60 s mean |dir error| deg'].max():.2f})",
         bool(cols["worst 60 s mean |dir error| deg"].max() <= 12.0)),
        (f"|speed| <= {SPEED_TARGET_PCT:g} % in 95 % of flights ({100 * np.mean(sp <= SPEED_TARGET_PCT):.1f} %)",
         np.mean(sp <= SPEED_TARGET_PCT) >= 0.95),
        (f"err/acc in {RATIO_BAND[0]:g}-{RATIO_BAND[1]:g} in {100 * RATIO_SHARE:.0f} % of flights "
         f"({100 * np.mean((r >= RATIO_BAND[0]) & (r <= RATIO_BAND[1])):.1f} %)",
         np.mean((r >= RATIO_BAND[0]) & (r <= RATIO_BAND[1])) >= RATIO_SHARE),
        (f"err/acc in 0.5-2 in all (range {r.min():.2f}-{r.max():.2f})", bool(r.min() >= 0.5 and r.max() <= 2.0)),
        (f"<= 3 % beyond 3 sigma every flight (worst {cols['share beyond 3 sigma %'].max():.2f} %)",
         bool(cols["share beyond 3 sigma %"].max() <= 3.0)),
        (f"<= 2 taut re-placements per hour over all flights ({hours:.2f} /h; worst flight "
         f"{cols['taut re-placements /h'].max():.1f} /h)", bool(hours <= 2.0)),
        (f"band skill >= {SKILL_TARGET:g} on fluctuating winds, every flight (>= {MARGINAL_SKILL_TARGET:g} within "
         f"{100 * MARGINAL_SPARE_LIFT:.0f} % of the lift limit: {marginal} flights; "
         f"{100 * np.mean(skill >= bar) if len(skill) else math.nan:.1f} %, "
         f"worst {skill.min() if len(skill) else math.nan:.2f})",
         bool((skill >= bar).all()) if len(skill) else False),
    ]  # fmt: skip
    lines += ["", "| target | result |", "|---|---|"]
    lines += [f"| {t} | {'PASS' if p else 'FAIL'} |" for t, p in targets]
    for note in (speed_causes(ok), ratio_spread(ok), caution_causes(ok), entry_note(ok), jumps_note(ok)):
        if note:
            lines += ["", note]
    if "from_deg" in ok:
        lines += ["", by_direction(ok)]
    if "mean_mps" in ok:
        lines += ["", *by_wind(ok)]
    return "\n".join(lines), targets


def skill_bar(ok):
    """Each flight's band-skill bar: SKILL_TARGET, or MARGINAL_SKILL_TARGET for a balloon within
    MARGINAL_SPARE_LIFT of its lift limit. The spare lift from the row's ``lift_margin_frac`` (free lift over
    buoyancy, study.case.lift_margin): buoyancy / carried - 1 = 1 / (1 - frac) - 1 (all flights at
    SKILL_TARGET where the rows do not carry it)."""
    bar = np.full(len(ok), SKILL_TARGET)
    if "lift_margin_frac" in ok:
        frac = ok["lift_margin_frac"].to_numpy(float)
        with np.errstate(divide="ignore", invalid="ignore"):
            spare = 1.0 / (1.0 - frac) - 1.0
        bar[spare < MARGINAL_SPARE_LIFT] = MARGINAL_SKILL_TARGET
    return bar


SECTORS = ("N", "E", "S", "W")  # where the wind comes from: 90 deg sectors centred on these


def jumps_note(ok) -> str:
    """Not a target: the flights whose magnetometer's own field the estimator took to have jumped (none has a current
    switched beside it: each would be a false alarm, the field not fused for 15 s and learnt again)."""
    if "field_jumps" not in ok:
        return ""
    j = ok["field_jumps"].fillna(0.0).to_numpy(float)
    flights = ", ".join(str(int(f)) for f in ok["flight"][j > 0])
    return (f"jumps of the magnetometer's own field (not a target; no flight has one): {int(j.sum())} in "
            f"{int((j > 0).sum())} of {len(ok)} flights" + (f" ({flights})" if flights else ""))


def entry_note(ok) -> str:
    """Not a target: the ENTRY_WINDOW_S after the taut entry and the SETTLED_WINDOW_S after that, before the scored
    part of each flight (or partly). On a real rope the balloon still rises for seconds after the firmware's entry
    (its sag taken up, the rope stretched), which the rigid taut model does not expect (docs/estimator.md, "Mode
    switching and resets"); the minute after it is where a user starts to read the wind."""
    parts = []
    for name, what, length, share in (("entry", "the {:g} s after the taut entry", ENTRY_WINDOW_S, 0.05),
                                      ("settled", "the {:g} s after that", SETTLED_WINDOW_S, 0.03)):  # fmt: skip
        if f"{name}_beyond_3sigma" not in ok:
            continue
        b = ok[f"{name}_beyond_3sigma"].to_numpy(float)
        r = ok[f"{name}_err_acc"].to_numpy(float)
        fin = np.isfinite(b)
        if not fin.any():
            continue
        worst = int(np.nanargmax(b))
        flight = int(ok["flight"].to_numpy()[worst]) if "flight" in ok else worst
        parts.append(
            f"{what.format(length)}: err/acc p50 {_pct(r, 50):.2f}, p90 {_pct(r, 90):.2f}, worst {np.nanmax(r):.2f}; "
            f"{int(np.sum(b[fin] > share))} of {int(fin.sum())} flights more than {100 * share:g} % beyond 3 sigma "
            f"there, the worst {100 * b[worst]:.0f} % (flight {flight})"
        )
    return "; ".join(parts) + " (not targets, not scored above)" if parts else ""


def by_direction(ok) -> str:
    """Not a target: the flights by where the wind comes from, as a user flies one direction. Blown towards magnetic
    north the cross-lean turn of the balloon's axis is nearly one about the field, which only the accelerometer holds
    (docs/estimator.md, "What limits the envelope now"): a target met on average can be missed in one sector."""
    sector = ((ok["from_deg"].to_numpy(float) + 45.0) % 360.0 // 90.0).astype(int)
    fluct = (ok["wind_kind"] != "steady").to_numpy()
    skill = ok["band_skill"].to_numpy(float) >= skill_bar(ok)
    dir_ok = ok["dir_err_deg"].abs().to_numpy(float) <= DIR_TARGET_DEG
    ratio = ok["err_acc"].to_numpy(float)
    parts = []
    for k, name in enumerate(SECTORS):
        m = sector == k
        f = m & fluct
        skill_pct = f"{100 * np.mean(skill[f]):.0f} %" if f.any() else "-"
        dir_pct = f"{100 * np.mean(dir_ok[m]):.0f} %" if m.any() else "-"
        parts.append(f"from {name} ({int(m.sum())}): band skill at its bar {skill_pct}, "
                     f"|dir| <= {DIR_TARGET_DEG:g} deg {dir_pct}, "
                     f"err/acc p50 {_pct(ratio[m], 50):.2f}")  # fmt: skip
    return "by where the wind comes from (not a target): " + "; ".join(parts)


WIND_BANDS_MPS = (1.0, 2.0, 4.0, math.inf)  # light air, moderate, fresh: the lean is a degree, a few, tens


def by_wind(ok) -> list[str]:
    """Not a target: what a user can expect, by the mean wind. In light air the balloon leans a degree or two, and a
    tenth of a degree of tilt (an accelerometer's bias) turns the lean's azimuth by degrees; in a fresh wind the C_d
    the flight could not learn is most of the speed's error. |error| percentiles per band, the RMS error, the
    err/acc median, the share of flights that stated their error (err/acc at most 1.33: the error within its stated
    1-sigma, or a third more) and the most of a flight's estimates beyond 3 sigma."""
    mean = ok["mean_mps"].to_numpy(float)
    fluct = (ok["wind_kind"] != "steady").to_numpy()
    lines = ["what to expect by the mean wind (not a target): |error| p50 / p95 / worst", "",
             "| mean wind | flights | direction, deg | speed, % | RMS error, m/s (p50) | err/acc p50 "
             f"| err/acc <= {RATIO_BAND[1]:g} | beyond 3 sigma, worst flight | band skill p50 (fluctuating) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for lo, hi in zip(WIND_BANDS_MPS[:-1], WIND_BANDS_MPS[1:]):
        m = (mean >= lo) & (mean < hi)
        if not m.any():
            continue
        d = ok["dir_err_deg"].abs().to_numpy(float)[m]
        sp = ok["speed_err_pct"].abs().to_numpy(float)[m]
        r = ok["err_acc"].to_numpy(float)[m]
        rms = ok["raw_rmse_mps"].to_numpy(float)[m] if "raw_rmse_mps" in ok else np.full(int(m.sum()), math.nan)
        skill = ok["band_skill"].to_numpy(float)[m & fluct]
        beyond = ok["beyond_3sigma"].to_numpy(float)[m]
        band = f"{lo:g}-{hi:g} m/s" if math.isfinite(hi) else f"{lo:g} m/s and more"
        trio = lambda x: f"{_pct(x, 50):.2g} / {_pct(x, 95):.2g} / {np.nanmax(x):.2g}"  # noqa: E731
        lines.append(f"| {band} | {int(m.sum())} | {trio(d)} | {trio(sp)} | {_pct(rms, 50):.2g} | {_pct(r, 50):.2f} | "
                     f"{100 * np.mean(r <= RATIO_BAND[1]):.0f} % | {100 * np.nanmax(beyond):.2g} % | "
                     f"{_pct(skill, 50):.2f} |")  # fmt: skip
    return lines


def drag_share_pct(cd_scale, drag_scale):
    """The speed error (%) the drag scale alone makes: the lean is the truth's pull, k_true U^2 (F ~ C_d U^2), and the
    filter reads it with its own k, so its wind is sqrt(k_true / k) of the truth's; the truth's C_d is ``cd_scale``
    times the design's and the filter's ``drag_scale`` times it."""
    return 100.0 * (np.sqrt(np.asarray(cd_scale, float) / np.asarray(drag_scale, float)) - 1.0)


def speed_causes(ok) -> str:
    """Not a target: how much of the speed misses is the C_d the flight could not learn (``drag_share_pct``)."""
    if not {"drag_scale", "drag_scale_sigma", "cd_scale"} <= set(ok.columns):
        return ""
    ok = ok[np.isfinite(ok["drag_scale"]) & (ok["drag_scale_sigma"] > 0.0)]
    if not len(ok):
        return ""
    sp = ok["speed_err_pct"].to_numpy(float)
    share = drag_share_pct(ok["cd_scale"], ok["drag_scale"])
    miss = np.abs(sp) > SPEED_TARGET_PCT
    mostly = miss & (np.sign(share) == np.sign(sp)) & (np.abs(share) >= 0.5 * np.abs(sp))
    rest = np.abs(100.0 * ((1.0 + sp / 100.0) / (1.0 + share / 100.0) - 1.0))  # the error with that share taken out
    z = ((ok["drag_scale"] - ok["cd_scale"]).abs() / ok["drag_scale_sigma"]).to_numpy(float)
    return (
        f"what the speed misses are made of (not a target): {int(miss.sum())} of {len(ok)} flights beyond "
        f"{SPEED_TARGET_PCT:g} %, "
        f"{int(mostly.sum())} of them with at least half the error (same sign) from the drag scale alone (sqrt(truth's "
        f"C_d / the filter's) - 1: the C_d the flight could not learn); with that share taken out "
        f"{100 * np.mean(rest <= SPEED_TARGET_PCT):.1f} % of flights are within {SPEED_TARGET_PCT:g} % "
        f"(p95 {_pct(rest, 95):.3g} %); the drag scale's "
        f"error over its stated 1-sigma: p50 {_pct(z, 50):.2f}, p95 {_pct(z, 95):.2f} (calibrated: 0.67, 1.96)"
    )


def ratio_spread(ok) -> str:
    """Not a target: what the err/acc band asks. The flights' spread of log(err/acc) against what RATIO_SHARE within
    the band needs (a normal spread of at most log(hi) over its two-sided quantile), and the most that one factor on
    every flight's stated accuracy would put within the band: a flight whose error is a systematic draw (its C_d, its
    accelerometer's bias) is off by that draw over its 1-sigma whatever the scale, so the band asks each flight's own
    accuracy."""
    r = ok["err_acc"].to_numpy(float)
    r = r[np.isfinite(r) & (r > 0.0)]
    if len(r) < 2:
        return ""
    lo, hi = RATIO_BAND
    factors = np.geomspace(0.25, 4.0, 481)
    share = [np.mean((r >= lo * f) & (r <= hi * f)) for f in factors]
    best = int(np.argmax(share))
    return (
        f"what the err/acc band asks (not a target): log(err/acc) spreads by {np.std(np.log(r)):.2f} (1-sigma) over "
        f"the flights, where {100 * RATIO_SHARE:.0f} % within {lo:g}-{hi:g} needs about "
        f"{np.log(hi) / NormalDist().inv_cdf(0.5 + RATIO_SHARE / 2.0):.2f}; one factor on every "
        f"stated accuracy would put at most {100 * share[best]:.1f} % within it (x {factors[best]:.2f})"
    )


def caution_causes(ok) -> str:
    """Not a target: what the over-cautious flights' caution is made of. Of the flights below the err/acc band, those
    whose consistency monitor's factor (``accuracy_factor``, RMS) is at least ``FACTOR_SHOWN``, by the source that set
    it most (``factor_source``), and what err/acc would be with the factor taken out (times its RMS: about, the
    factor varies through the flight)."""
    if not {"accuracy_factor", "factor_source"} <= set(ok.columns):
        return ""
    r = ok["err_acc"].to_numpy(float)
    f = ok["accuracy_factor"].to_numpy(float)
    src = ok["factor_source"].to_numpy(float)
    low = np.isfinite(r) & (r < RATIO_BAND[0])
    if not low.any():
        return ""
    factored = low & np.isfinite(f) & (f >= FACTOR_SHOWN)
    names = [SOURCES[int(i)] if np.isfinite(i) and 0 <= i < len(SOURCES) else "?" for i in src[factored]]
    by = ", ".join(f"{n} {names.count(n)}" for n in sorted(set(names), key=lambda n: (-names.count(n), n)))
    without = np.where(factored, r * f, r)
    lo, hi = RATIO_BAND
    return (
        f"what the over-caution is made of (not a target): {int(low.sum())} of {len(ok)} flights below err/acc "
        f"{lo:g}; in {int(factored.sum())} of them the consistency monitor's factor is at least {FACTOR_SHOWN:g} (RMS)"
        + (f", set most by: {by}; their err/acc p50 {_pct(r[factored], 50):.2f}, without the factor (times its RMS, "
           f"about) {_pct(without[factored], 50):.2f}; all flights so within {lo:g}-{hi:g}: "
           f"{100 * np.mean((without >= lo) & (without <= hi)):.1f} %" if factored.any() else "")
    )  # fmt: skip


def _far(s) -> float:
    v = np.asarray(s, float)
    v = v[np.isfinite(v) & (v > 0)]
    return float(v[np.argmax(np.abs(np.log(v)))]) if len(v) else math.nan


def worst_flights(df, k: int = 5) -> str:
    ok = df[df["status"] == "ok"].copy()
    ok["abs_dir"] = ok["dir_err_deg"].abs()
    top = ok.sort_values("abs_dir", ascending=False).head(k)
    cols = ["flight", *PARAMS, "dir_err_deg", "worst_60s_dir_err_deg", "speed_err_pct", "err_acc",
            "beyond_3sigma", "taut_resets", "band_skill", *(["drag_scale"] if "drag_scale" in ok else [])]  # fmt: skip
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in top.iterrows():
        lines.append("| " + " | ".join(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    failed = df[df["status"] != "ok"]
    for _, r in failed.iterrows():
        lines.append(f"\nfailed flight {r['flight']}: {r['error']}")
    return "\n".join(lines)


# ---------------------------------------------------------------- plots


PLOTS = ("direction_error_vs_params.png", "calibration.png", "speed_error_vs_drag_scale.png")


def plots(df, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = df[df["status"] == "ok"]
    y = ok["dir_err_deg"].abs()
    fig, axes = plt.subplots(2, 6, figsize=(21, 7), sharey=True)
    rng = np.random.default_rng(0)
    for ax, p in zip(axes.flat, PARAMS):
        x = ok[p]
        if x.dtype == object:
            cats = sorted(set(x))
            xi = np.array([cats.index(v) for v in x]) + rng.uniform(-0.15, 0.15, len(x))
            ax.scatter(xi, y, s=10)
            ax.set_xticks(range(len(cats)), cats)
        else:
            ax.scatter(x, y, s=10)
        ax.set_xlabel(p)
        ax.grid(alpha=0.3)
        ax.axhline(3.0, color="tab:orange", lw=0.8)
        ax.axhline(8.0, color="tab:red", lw=0.8)
        ax.set_yscale("symlog", linthresh=3.0)
    for ax in axes[:, 0]:
        ax.set_ylabel("|mean direction error| deg")
    fig.suptitle(f"envelope: {len(ok)} flights, |direction error| against each sampled parameter")
    fig.tight_layout()
    p1 = out / "direction_error_vs_params.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    nb = len(CAL_EDGES) - 1
    n = np.array([ok[f"cal_n_{b}"].sum() for b in range(nb)])
    a2 = np.array([ok[f"cal_a2_{b}"].sum() for b in range(nb)])
    e2 = np.array([ok[f"cal_e2_{b}"].sum() for b in range(nb)])
    m = n >= 100
    fig, ax = plt.subplots(figsize=(6, 5.5))
    stated, actual = np.sqrt(a2[m] / n[m]), np.sqrt(e2[m] / n[m])
    ax.loglog(stated, actual, "o-", label="RMS actual error in the bin")
    lim = [CAL_EDGES[0], CAL_EDGES[-1]]
    ax.loglog(lim, lim, "k--", lw=0.8, label="honest (actual = stated)")
    ax.fill_between(lim, [0.75 * v for v in lim], [1.33 * v for v in lim], color="0.85", label="0.75-1.33")
    for s, a, k in zip(stated, actual, n[m]):
        ax.annotate(f"{k / 10 / 3600:.1f} h", (s, a), fontsize=6, xytext=(3, -8), textcoords="offset points")
    ax.set_xlabel("stated horizontal accuracy (RMS in bin), m/s")
    ax.set_ylabel("actual horizontal error (RMS in bin), m/s")
    ax.set_title(f"calibration over {len(ok)} flights (10 Hz samples after start)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    p2 = out / "calibration.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    if "drag_scale" not in ok or not ok["drag_scale"].notna().any():
        return [p1, p2]

    share = drag_share_pct(ok["cd_scale"], ok["drag_scale"])
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    for kind in WIND_KINDS:
        m = (ok["wind_kind"] == kind).to_numpy()
        ax.scatter(share[m], ok["speed_err_pct"][m], s=12, label=kind)
    lim = float(np.nanmax(np.abs(np.concatenate([share, ok["speed_err_pct"].to_numpy()])))) * 1.05
    ax.plot([-lim, lim], [-lim, lim], "k--", lw=0.8, label="all of it the drag scale")
    band = f"|speed error| <= {SPEED_TARGET_PCT:g} %"
    ax.axhspan(-SPEED_TARGET_PCT, SPEED_TARGET_PCT, color="0.88", zorder=0, label=band)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_xlabel("the drag scale's share: sqrt(truth's C_d / the filter's) - 1, %")
    ax.set_ylabel("speed error of the flight's mean wind, %")
    ax.set_title(f"speed error against the C_d the flight could not learn, {len(ok)} flights", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p3 = out / "speed_error_vs_drag_scale.png"
    fig.savefig(p3, dpi=110)
    plt.close(fig)
    return [p1, p2, p3]


# ---------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog="bench_envelope", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"64 flights of {QUICK_DURATION_S:g} s (else 200 of {FULL_DURATION_S:g} s)")  # fmt: skip
    ap.add_argument("--flights", type=userargs.count, help="number of flights (quick: 64, else 200)")
    ap.add_argument("--duration", type=userargs.duration,
                    help=f"seconds per flight (quick: {QUICK_DURATION_S:g}, else {FULL_DURATION_S:g})")  # fmt: skip
    ap.add_argument("--start", type=userargs.start_time, default=120.0, help="scoring starts here, s")
    ap.add_argument("--out", default="out/envelope", help="output directory (default out/envelope)")
    where = ap.add_mutually_exclusive_group()  # [--workers N | --scheduler tcp://HOST:PORT] (or --serial)
    where.add_argument("--serial", action="store_true", help="in this process, no Dask")
    where.add_argument("--workers", type=userargs.count, help="Dask workers (default: one per core; at most 4 per "
                       "core)")  # fmt: skip
    where.add_argument("--scheduler", type=userargs.scheduler_address,
                       help="a running Dask scheduler, tcp://HOST:PORT (instead of local workers)")  # fmt: skip
    ap.add_argument("--cd-sigma", type=float, default=CD_SIGMA,
                    help=f"1-sigma of what the user knows of the balloon's C_d, relative (default {CD_SIGMA:g}: "
                         "a sphere's from the literature; 0.02: measured); the truth's drawn with it, the filter "
                         "told it")  # fmt: skip
    ap.add_argument("--max-wind", type=float, default=MAX_WIND_MPS,
                    help=f"the mean wind's upper end, m/s, {MAX_WIND_RANGE[0]:g}-{MAX_WIND_RANGE[1]:g} (default "
                         f"{MAX_WIND_MPS:g}, the envelope's; above it a stress, its targets shown as they "
                         "are)")  # fmt: skip
    ap.add_argument("--yaw-moment", type=float, default=0.0,
                    help="the balloon's yaw moment coefficient ([truth] yaw_moment_coefficient, "
                         f"{YAW_MOMENT_RANGE[0]:g}-{YAW_MOMENT_RANGE[1]:g}; default 0: a perfect sphere that keeps its "
                         "heading; 0.01: a weak vane that turns downwind once released)")  # fmt: skip
    ap.add_argument("--turn-deg", type=float, default=0.0,
                    help="a front: the wind turns by this much (deg, positive clockwise: veering) in "
                         f"{TURN_DURATION_S:g} s halfway through each flight's scored part, {TURN_RANGE_DEG[0]:g} to "
                         f"{TURN_RANGE_DEG[1]:g} (default 0: no front)")  # fmt: skip
    ap.add_argument("--sample-seed", type=userargs.seed, default=SEED,
                    help=f"the sample's seed (default {SEED}: the fixed sample every run compares on; any other draws "
                         "a fresh set of points, flights no tuning has seen)")  # fmt: skip
    args = ap.parse_args(argv)
    wlo, whi = MAX_WIND_RANGE
    if not wlo <= args.max_wind <= whi:
        print(f"bench_envelope: --max-wind must be between {wlo:g} and {whi:g} m/s, got {args.max_wind:g}",
              file=sys.stderr)  # fmt: skip
        return 2
    lo, hi = CD_SIGMA_RANGE
    if not lo <= args.cd_sigma <= hi:
        print(f"bench_envelope: --cd-sigma must be between {lo:g} and {hi:g}, got {args.cd_sigma:g}", file=sys.stderr)
        return 2
    lo, hi = YAW_MOMENT_RANGE
    if not lo <= args.yaw_moment <= hi:  # NaN too
        return userargs.fail("bench_envelope", f"--yaw-moment must be between {lo:g} and {hi:g}, got "
                             f"{args.yaw_moment:g}")  # fmt: skip
    lo, hi = TURN_RANGE_DEG
    if not lo <= args.turn_deg <= hi:  # NaN too
        return userargs.fail("bench_envelope", f"--turn-deg must be between {lo:g} and {hi:g}, got {args.turn_deg:g}")
    n = args.flights or (64 if args.quick else 200)
    duration = args.duration or (QUICK_DURATION_S if args.quick else FULL_DURATION_S)
    if args.start >= duration:
        print(f"bench_envelope: error: --start {args.start:g} must be before the flight's end ({duration:g} s)",
              file=sys.stderr)  # fmt: skip
        return 2
    most = max_workers()  # balloon-study's: more only time-share the cores
    if args.workers is not None and args.workers > most:
        return userargs.fail("bench_envelope", f"--workers must be 1 .. {most} (4 per core; a bigger cluster is "
                             f"--scheduler), got {args.workers}")  # fmt: skip
    try:
        out = output_directory(args.out)
        if args.scheduler:  # before any work: a scheduler that answers
            try:
                engine.check_scheduler(args.scheduler)
            except engine.NoScheduler as exc:
                raise userargs.UserError(f"no Dask scheduler at {args.scheduler}: {exc}") from None
    except userargs.UserError as exc:
        return userargs.fail("bench_envelope", exc)
    userargs.ctrl_c_raises()  # (also when started in the background)
    try:
        return _run(args, out, n, duration)
    except KeyboardInterrupt:
        print(f"bench_envelope: interrupted; the finished flights are kept in {out / 'parts'}: run the same command "
              "again to resume", file=sys.stderr)  # fmt: skip
        return 130


def _run(args, out: Path, n: int, duration: float) -> int:
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    turn = None
    if args.turn_deg:  # halfway through the scored part
        turn = (args.turn_deg, round(0.5 * (args.start + duration - TURN_DURATION_S), 3))
    params = sample(n, seed=args.sample_seed, cd_sigma=args.cd_sigma, max_wind_mps=args.max_wind,
                    yaw_moment=args.yaw_moment, turn=turn)
    cs = cases(params, duration, args.start)
    store = engine.Store(out / "parts")
    t0 = time.perf_counter()
    if args.serial:
        rows, st = engine.run(cs, store, None, case_fn=envelope_case)
    else:
        with engine.dask_client(workers=args.workers, scheduler=args.scheduler) as client:
            rows, st = engine.run(cs, store, client, case_fn=envelope_case)
    wall = time.perf_counter() - t0
    table = [{"flight": c.point["flight"], **{p: c.point[p] for p in PARAMS}, **rows[c.key]} for c in cs]
    df = pd.DataFrame(table)
    df.attrs["duration_s"] = duration
    part = out / f".part-{os.getpid()}"  # every product here first, then each under its final name
    part.mkdir()
    try:
        written = write_products(df, part, out, n, duration, args, st, wall)
    finally:
        shutil.rmtree(part, ignore_errors=True)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0  # the run is done; its targets pass or fail in the summary


PRODUCTS = ("envelope.parquet", "envelope.csv", "envelope_summary.md", *PLOTS)


def output_directory(path: str) -> Path:
    """``--out``: a directory that exists and can be written, or can be made; none of the products in it a
    directory, and its ``parts`` (the finished flights, reused) not a file. A UserError naming the problem."""
    try:
        userargs.output_dir(path)
    except argparse.ArgumentTypeError as exc:
        raise userargs.UserError(f"--out {exc}") from None
    out = Path(path)
    for name in PRODUCTS:
        if (out / name).is_dir():
            raise userargs.UserError(f"--out {path}: {out / name} is a directory")
    if (out / "parts").exists() and not (out / "parts").is_dir():
        raise userargs.UserError(f"--out {path}: {out / 'parts'} is not a directory (the finished flights go there)")
    return out


def write_products(df, part: Path, out: Path, n: int, duration: float, args, st, wall: float) -> list[Path]:
    """Every product written into ``part``, then moved to its final name in ``out``; the final names."""
    df.to_parquet(part / "envelope.parquet", index=False)
    df.to_csv(part / "envelope.csv", index=False)
    text, _ = summary(df)
    head = (
        f"envelope: {n} flights of {duration:g} s (scored from {args.start:g} s), base {BASE}"
        f"{'' if args.cd_sigma == CD_SIGMA else f', the C_d known to {100 * args.cd_sigma:g} %'}"
        f"{'' if args.max_wind == MAX_WIND_MPS else f', mean wind 1-{args.max_wind:g} m/s'}"
        f"{f', the balloon turns (yaw moment {args.yaw_moment:g})' if args.yaw_moment else ''}"
        f"{f', a front turns the wind {args.turn_deg:g} deg in {TURN_DURATION_S:g} s' if args.turn_deg else ''}"
        f"{'' if args.sample_seed == SEED else f', sample seed {args.sample_seed}'}, "
        f"{'serial' if args.serial else f'{st.workers} Dask workers'}; {st.computed} computed, {st.reused} "
        f"reused, {st.failed} failed; wall {wall:.0f} s (mean flight {st.case_s / max(st.computed, 1):.1f} s)"
    )
    worst = worst_flights(df)
    pngs = plots(df, part)
    doc = f"{head}\n\n{text}\n\nworst flights by |direction error|:\n\n{worst}\n"
    (part / "envelope_summary.md").write_text(doc)
    print(doc)
    written = []
    for p in (part / "envelope.parquet", part / "envelope.csv", part / "envelope_summary.md", *pngs):
        os.replace(p, out / p.name)
        written.append(out / p.name)
    return written


if __name__ == "__main__":
    sys.exit(main())
