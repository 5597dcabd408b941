"""What the stated wind accuracy is made of, flight by flight of the envelope benchmark (a diagnosis tool).

    python tools/accuracy_terms.py 23 17 --quick          # flights of the --quick sample, 300 s
    python tools/accuracy_terms.py 0 4 8 --duration 600    # flights of the full sample
    python tools/accuracy_terms.py 83 --sample-seed 21      # a flight of a held-out sample
    python tools/accuracy_terms.py 103 --set truth.accel_bias_mps2=0 --set truth.accel_bias_walk_mps2_rt_s=0
                                                           # the same flight, its world changed (TOML values)
    python tools/accuracy_terms.py --scenario field-gusty-6 --seed 2 --set filter.init_drag=0.001
                                                           # a named scenario (balloon-sim --list-scenarios)

Flies each flight of ``benchmarks.bench_envelope``'s sample on the Python core (the C core is held equal to it) and
prints, over the scored part (from 120 s), the RMS wind error against the truth, the mean vector's speed and
direction errors, the drag scale learnt beside the
one flown (the truth's C_d over the design's) and the RMS of each term of the reported accuracy
(``Estimator.wind_accuracy``): the covariance's, the drag scale's and the tilt's systematic terms, the consistency
monitor's mean factor and its windowed NIS per source (the accelerometer's also per body axis, the mean of its
samples'); how far the barometer offset state walked in its worst 20 s against its own stated 1-sigma (the rope
model's disagreement with the barometer, which no single innovation shows); the accelerometer's misfit along the
rope against the truth's acceleration there and the rope's tension (mean and spread); and the attitude's RMS error
about the magnetic field's axis (which the magnetometer cannot see) against its stated 1-sigma, with its correlation
with the wind's error across the mean wind, and the balloon's own position and velocity errors across it."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from balloon_core.rotation import quat_from_euler, rotation, rotation_error  # noqa: E402
from balloon_core.score import score  # noqa: E402
from benchmarks.bench_envelope import SEED, sample, sections_of  # noqa: E402
from firmware_py.estimator.consistency import NIS_CLIP, SOURCES, lean_misfit_wind, systematic_variance  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from firmware_py.estimator.state import ATT_D, ATT_N, BARO_OFF, DRAG, MODE_TAUT, POS_E, POS_N, VEL_E, VEL_N  # noqa: E402
from sim_hil.scenarios import SCENARIOS  # noqa: E402
from sim_hil.simulator import TRUTH_COLUMNS, Simulation  # noqa: E402
from study.spec import build, scenario_sections  # noqa: E402

START_S = 120.0
MIN_SCORED_S = 30.0  # the least a flight is scored over (balloon_core.score needs some)
MAX_DURATION_S = 86400.0
WALK_WINDOW_S = 20.0


def override(sections: dict, setting: str) -> None:
    """``SECTION.KEY=VALUE`` into the flight's sections, in place, the value as a design file writes it (TOML: a
    number, true/false, an array; a bare word is taken as text); ValueError naming what is wrong for a section or key
    the flight does not have (``build`` judges the value)."""
    name, sep, text = setting.partition("=")
    section, dot, key = name.strip().partition(".")
    if not (sep and dot and section in sections and key in sections[section]):
        known = ", ".join(sorted(sections[section])) if section in sections else ", ".join(sorted(sections))
        raise ValueError(f"--set {setting!r}: not SECTION.KEY=VALUE of the flight's ({known})")
    text = text.strip()
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        value = text
    sections[section][key] = float(value) if isinstance(value, int) and not isinstance(value, bool) else value


def world(point: dict, settings: tuple[str, ...] = ()) -> dict:
    """The flight's sections with ``settings`` (``SECTION.KEY=VALUE``) applied: an envelope flight's, or a named
    scenario's (``point["scenario"]``)."""
    sections = scenario_sections(SCENARIOS[point["scenario"]]) if "scenario" in point else sections_of(point)
    for setting in settings:
        override(sections, setting)
    return sections


def terms(point: dict, duration_s: float, settings: tuple[str, ...] = ()) -> dict[str, float]:
    design, wind, truth_cfg, filt = build(world(point, settings))
    sim = Simulation(design, wind, truth_cfg, duration_s, point["seed"])
    est = Estimator(design, dataclasses.replace(filt, core="py"))
    every = int(round(sim.n_imu / duration_s / 10.0))  # 10 Hz rows
    rows, att, along = [], [], []
    for i, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if i % every:
            continue
        ekf = est.ekf
        wn, we = est.wind()
        speed, k, kv = math.hypot(wn, we), float(ekf.x[DRAG]), float(ekf.P[DRAG, DRAG])
        lean, c = est.lean_wind_mps(), est.consistency
        misfit = lean_misfit_wind(speed, c.lean_tilt, c.lean_misfit) if ekf.mode == MODE_TAUT else 0.0
        rows.append((s.time_usec * 1e-6, wn, we, est.wind_accuracy(), ekf.wind_accuracy() ** 2,
                     systematic_variance(speed, k, kv, 0.0), lean**2, est.consistency.inflation, float(ekf.x[BARO_OFF]),
                     float(ekf.P[BARO_OFF, BARO_OFF]), k, *est.consistency.nis,
                     *(min(v, 3.0 * NIS_CLIP) for v in est._accel_axis_nis),
                     misfit))  # fmt: skip
        att.append(
            (
                *ekf.q.tolist(),
                *est.field_ned,
                *ekf.P[ATT_N : ATT_D + 1, ATT_N : ATT_D + 1].ravel(),
                est.field_extra_variance(),
                est.consistency.slow_tilt,
                *ekf.x[POS_N : POS_E + 1].tolist(),
                *ekf.x[VEL_N : VEL_E + 1].tolist(),
            )
        )
        rb = rotation(*ekf.q.tolist())
        along.append((est.accel_status[2].innov, rb[2], rb[5], rb[8]))  # the body's z misfit; its axis, NED
    r = np.array(rows)
    truth = {c: sim.truth[:, j] for j, c in enumerate(TRUTH_COLUMNS)}
    late = r[:, 0] >= START_S
    tn = np.interp(r[late, 0], truth["time_s"], truth["wind_n"])
    te = np.interp(r[late, 0], truth["time_s"], truth["wind_e"])
    err = np.hypot(r[late, 1] - tn, r[late, 2] - te)
    rms = lambda x: float(np.sqrt(np.mean(x)))  # noqa: E731 - of a squared series
    out = {"error": rms(err**2), "mean_vector_error": math.hypot(r[late, 1].mean() - tn.mean(),
                                                                  r[late, 2].mean() - te.mean()),
           "accuracy": rms(r[late, 3] ** 2), "P": rms(r[late, 4]), "drag": rms(r[late, 5]),
           "tilt": rms(r[late, 6]), "inflation": float(r[late, 7].mean()), "misfit": rms(r[late, -1] ** 2)}  # fmt: skip
    n = int(round(WALK_WINDOW_S * 10.0))
    off, sd = r[late, 8], np.sqrt(r[late, 9])
    out["offset_walk_m"] = float(np.max(np.abs(off[n:] - off[:-n]))) if len(off) > n else math.nan
    out["offset_sigma_m"] = float(np.mean(sd))
    out["drag_scale"] = float(r[late, 10].mean())
    sc = score(r[:, 0], r[:, 1], r[:, 2], r[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"], start_s=START_S)
    out["speed_error_pct"], out["direction_error_deg"] = sc.speed_error_pct, sc.direction_error_deg
    for j, name in enumerate(SOURCES):
        out[f"nis_{name}"] = float(r[late, 11 + j].mean())
    # the accelerometer's per body axis (z along the rope), the mean of each sample's (the monitor clips their mean at
    # NIS_CLIP, so each at three times that)
    for j, axis in enumerate("xyz"):
        out[f"nis_accel_{axis}"] = float(r[late, 11 + len(SOURCES) + j].mean())
    out.update(about_field(np.array(att)[late], r[late], truth, tn, te))
    out.update(along_the_rope(np.array(along)[late], r[late, 0], truth))
    return out


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's correlation of two series, NaN where either is constant."""
    return float(np.corrcoef(a, b)[0, 1]) if np.std(a) > 0.0 and np.std(b) > 0.0 else math.nan


def about_field(att: np.ndarray, r: np.ndarray, truth: dict, tn: np.ndarray, te: np.ndarray) -> dict[str, float]:
    """The attitude's error about the magnetic field's axis (true = (I + [d x]) estimate, d . b), RMS in deg, its
    stated 1-sigma (sqrt(b' P_att b), and with what P does not hold there: consistency.field_attitude_extra and
    consistency.heading_misfit_variance), the accelerometer's slow innovation read as that rotation (RMS in deg, its
    correlation with the error) and the correlation of the error with the wind's error across the mean wind (m/s); the
    balloon's position and velocity errors across the mean wind (RMS) and the velocity's correlation with the wind's."""
    eb, sb, sx = [], [], []
    for row, (t, *_rest) in zip(att, r):
        ri = [float(np.interp(t, truth["time_s"], truth[c])) for c in ("roll_deg", "pitch_deg", "yaw_deg")]
        d = np.array(rotation_error(quat_from_euler(*np.radians(ri)), tuple(row[:4])))
        b = np.array(row[4:7]) / np.linalg.norm(row[4:7])
        eb.append(float(d @ b))
        sb.append(float(b @ row[7:16].reshape(3, 3) @ b))
        sx.append(sb[-1] + float(row[16]))
    ang = math.atan2(te.mean(), tn.mean())

    def across(dn: np.ndarray, de: np.ndarray) -> np.ndarray:  # a north-east error's part across the mean wind
        return -dn * math.sin(ang) + de * math.cos(ang)

    cross = across(r[:, 1] - tn, r[:, 2] - te)
    eb_a, slow = np.array(eb), att[:, 17]
    corr, slow_corr = correlation(eb_a, cross), correlation(eb_a, slow)
    # the balloon's own position and velocity across the mean wind: a wind error that is the velocity's leaves the
    # drag as it was (the air relative to the balloon), and only the tether's pull across tells the position
    t = r[:, 0]
    at = lambda c: np.interp(t, truth["time_s"], truth[c])  # noqa: E731
    pos_cross = across(att[:, 18] - at("pos_n"), att[:, 19] - at("pos_e"))
    vel_cross = across(att[:, 20] - at("vel_n"), att[:, 21] - at("vel_e"))
    return {"cross_position_error_m": float(np.sqrt(np.mean(pos_cross**2))),
            "cross_velocity_error_mps": float(np.sqrt(np.mean(vel_cross**2))),
            "cross_velocity_corr": correlation(vel_cross, cross),
            "about_field_deg": math.degrees(math.sqrt(np.mean(eb_a**2))),
            "slow_innovation_deg": math.degrees(math.sqrt(np.mean(slow**2))), "slow_innovation_corr": slow_corr,
            "about_field_sigma_deg": math.degrees(math.sqrt(np.mean(sb))),
            "about_field_stated_deg": math.degrees(math.sqrt(np.mean(sx))),
            "cross_error": float(np.sqrt(np.mean(cross**2))), "about_field_cross_corr": corr}  # fmt: skip


def along_the_rope(along: np.ndarray, t: np.ndarray, truth: dict) -> dict[str, float]:
    """The accelerometer's misfit along the body's z (the rope's axis) against the truth's acceleration along that
    axis (its correlation: the balloon moving along its rope, which the taut model holds still) and the mean and
    spread of the truth's rope tension at the balloon, N."""
    acc = [np.interp(t, truth["time_s"], np.gradient(truth[c], truth["time_s"])) for c in ("vel_n", "vel_e", "vel_d")]
    a_along = along[:, 1] * acc[0] + along[:, 2] * acc[1] + along[:, 3] * acc[2]
    return {"accel_z_along_corr": correlation(along[:, 0], a_along),
            "tension_mean_n": float(np.mean(np.interp(t, truth["time_s"], truth["tension_n"]))),
            "tension_sd_n": float(np.std(np.interp(t, truth["time_s"], truth["tension_n"])))}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("flights", type=int, nargs="*", help="flight numbers of the envelope's sample")
    ap.add_argument(
        "--scenario",
        action="append",
        default=[],
        metavar="NAME",
        help="a named scenario instead (repeatable, each flown once; its seed --seed, default 1)",
    )
    ap.add_argument("--seed", type=int, default=1, help="the scenarios' seed")
    ap.add_argument("--quick", action="store_true", help="the --quick sample (64 flights) and 300 s")
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds (default 300 quick, else 600)")
    ap.add_argument("--sample-seed", type=userargs.seed, default=SEED,
                    help="the envelope sample's seed (bench_envelope --sample-seed; default its fixed sample)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="change one thing of every flight's world or design (repeatable), e.g. sensors.gyro_dps=0.1",
    )
    a = ap.parse_args(argv)
    sampled = sample(64 if a.quick else 200, a.sample_seed)
    duration = a.duration if a.duration is not None else (300.0 if a.quick else 600.0)
    if not START_S + MIN_SCORED_S <= duration <= MAX_DURATION_S:  # NaN too
        print(f"accuracy_terms: --duration {duration:g}: {START_S + MIN_SCORED_S:g}-{MAX_DURATION_S:g} s (scored from "
              f"{START_S:g} s)", file=sys.stderr)  # fmt: skip
        return 2
    if a.seed < 0 or (a.seed != 1 and not a.scenario):
        print(f"accuracy_terms: --seed {a.seed}: a scenario's seed, 0 or more (an envelope flight has its own)",
              file=sys.stderr)  # fmt: skip
        return 2
    for f in a.flights:
        if not 0 <= f < len(sampled):
            print(f"accuracy_terms: no flight {f} in a sample of {len(sampled)}", file=sys.stderr)
            return 2
    for name in a.scenario:
        if name not in SCENARIOS:
            print(f"accuracy_terms: unknown scenario {name!r} (balloon-sim --list-scenarios)", file=sys.stderr)
            return 2
    if not (a.flights or a.scenario):
        print("accuracy_terms: name a flight or a --scenario", file=sys.stderr)
        return 2
    points: dict = {f: sampled[f] for f in a.flights}
    points.update({name: {"scenario": name, "seed": a.seed, "wind_kind": SCENARIOS[name].wind.kind}
                   for name in a.scenario})  # fmt: skip
    worlds = {}
    for f in points:  # every change judged before the first flight flies: a bad one is a user error
        try:
            worlds[f] = world(points[f], tuple(a.set))
            build(worlds[f])
        except (ValueError, TypeError) as e:  # ConfigError is a ValueError
            print(f"accuracy_terms: flight {f}: {str(e).splitlines()[0] if str(e) else type(e).__name__}",
                  file=sys.stderr)  # fmt: skip
            return 2
    if a.set:
        print("changed: " + ", ".join(a.set))
    print("| flight | wind | rope | error | speed error | direction error | drag scale (truth's C_d / design's) "
          "| accuracy "
          "| = sqrt((sqrt(P^2 + drag^2 + tilt^2) x inflation)^2 + lean misfit^2) | error/accuracy "
          "| worst 20 s offset walk / its sigma | NIS " + " ".join(SOURCES) + " | accel NIS body x y z "
          "| attitude about the field: RMS error (the truth's turn from the estimate) / P's / stated, deg "
          "| the accelerometer's slow innovation as that rotation: RMS, deg (its correlation with the error: positive "
          "where the attitude followed a misfit, negative where the accelerometer sees the error) "
          "| its correlation with the cross-wind error (RMS) "
          "| the balloon's position error across the wind, RMS; its velocity's (its correlation with the wind's) "
          "| accel z misfit: its correlation with the truth's acceleration along the rope; "
          "the tension at the balloon, mean and SD |")  # fmt: skip
    print("|---|---|---|---:|---:|---:|---:|---:|---|---:|---:|---|---|---:|---:|---:|---:|---:|")
    for f in points:
        p, w = points[f], worlds[f]
        t = terms(p, duration, tuple(a.set))
        nis = " ".join(f"{t['nis_' + s]:.2f}" for s in SOURCES)
        # the flight as flown: the sample's names, or with --set (or a scenario) the sections' (the wind's kind and
        # IEC class)
        named = a.set or "scenario" in p
        kind = " ".join(str(w["wind"][k]) for k in ("kind", "iec_class") if w["wind"][k]) if named else p["wind_kind"]
        print(f"| {f} | {kind} {w['wind']['mean_mps']:.1f} m/s | {w['truth']['rope_model']} | "
              f"{t['error']:.3f} | "
              f"{t['speed_error_pct']:+.1f} % | {t['direction_error_deg']:+.1f} deg | "
              f"{t['drag_scale']:.3f} ({w['truth']['drag_coefficient_scale']:.3f}) | {t['accuracy']:.3f} | "
              f"sqrt((sqrt({t['P']:.3f}^2 + {t['drag']:.3f}^2 + {t['tilt']:.3f}^2) x {t['inflation']:.2f})^2 + "
              f"{t['misfit']:.3f}^2) | {t['error'] / t['accuracy']:.2f} | "
              f"{t['offset_walk_m']:.1f} m / {t['offset_sigma_m']:.2f} m | {nis} | "
              f"{t['nis_accel_x']:.2f} {t['nis_accel_y']:.2f} {t['nis_accel_z']:.2f} | "
              f"{t['about_field_deg']:.2f} / {t['about_field_sigma_deg']:.2f} / {t['about_field_stated_deg']:.2f} | "
              f"{t['slow_innovation_deg']:.2f} ({t['slow_innovation_corr']:+.2f}) | "
              f"{t['about_field_cross_corr']:+.2f} ({t['cross_error']:.2f} m/s) | "
              f"{t['cross_position_error_m']:.2f} m; {t['cross_velocity_error_mps']:.2f} m/s "
              f"({t['cross_velocity_corr']:+.2f}) | "
              f"{t['accel_z_along_corr']:+.2f}; {t['tension_mean_n']:.1f} ± {t['tension_sd_n']:.1f} N |",
              flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
