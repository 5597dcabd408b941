"""One case in one process: the simulator and the estimator (the same ``Estimator`` the firmware program
runs, fed sample by sample; no files, no sockets), then the metrics. Only a dict of numbers leaves."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from balloon_core.config import Design, lift_balance
from balloon_core.rotation import euler_from_quat
from balloon_core.score import response, score
from firmware_py.core_c import new_core
from firmware_py.estimator.consistency import stated_nis
from firmware_py.estimator.state import ATT_E, ATT_N, DRAG, FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.simulator import TRUTH_COLUMNS, Simulation
from sim_hil.wind import WindConfig
from study.metrics import FACTOR_SHOWN, H_BAND_HZ, h_column


def fly(design: Design, wind: WindConfig, truth: TruthConfig, filt: FilterConfig, duration_s: float, seed: int,
        join_s: float = 0.0):
    """Rows (time s, wind N, wind E, horiz accuracy, roll, pitch, yaw rad, the stated tilt's 1-sigma rad, the
    consistency monitor's factor on the accuracy, the index in ``SOURCES`` of the source whose windowed NIS set it or
    -1 where it is 1, the filter's mode, 1 while a join in flight is unconfirmed) per IMU sample, the truth table by
    column, and the estimator (its counters). ``join_s`` > 0: the firmware starts that far into the flight (a restart
    in flight: it joins the balloon on its tether), its rows before then NaN but their time."""
    sim = Simulation(design, wind, truth, duration_s, seed)
    est, _ = new_core(design, filt)
    rows = np.zeros((sim.n_imu, 12))
    ekf = est.ekf  # its P is updated in place
    mon = est.consistency
    for i, s in enumerate(sim.samples()):
        if s.time_usec < join_s * 1e6:
            rows[i] = np.nan
            rows[i, 0] = s.time_usec * 1e-6
            continue
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        wn, we = est.wind()
        factor = mon.inflation
        source = -1.0
        if factor > 1.0:
            stated = [stated_nis(k, v) for k, v in enumerate(mon.nis)]
            source = float(stated.index(max(stated)))
        rows[i] = (s.time_usec * 1e-6, wn, we, est.wind_accuracy(), *euler_from_quat(*ekf.q.tolist()),
                   math.sqrt(ekf.P[ATT_N, ATT_N] + ekf.P[ATT_E, ATT_E]), factor, source, ekf.mode,
                   est.unconfirmed)  # fmt: skip
    truth_cols = {c: sim.truth[:, k] for k, c in enumerate(TRUTH_COLUMNS)}
    return rows, truth_cols, est


def attitude_errors(rows, truth, start_s: float = 120.0) -> tuple[float, float]:
    """RMS tilt error (roll and pitch combined) and RMS heading error of the on-board orientation, deg."""
    late = rows[:, 0] >= start_s
    d = np.degrees(rows[late, 4:7]) - np.column_stack([truth[c][late] for c in ("roll_deg", "pitch_deg", "yaw_deg")])
    d = (d + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def lift_margin(design: Design) -> tuple[float, float]:
    """Net free lift at the ground (N) with the whole rope aloft, and as a fraction of the buoyancy, in the air the
    simulator flies in (config.lift_balance)."""
    buoyancy, *_, net = lift_balance(design)
    return net, net / buoyancy


def wind_lines_hz(wind: WindConfig) -> tuple[float, ...]:
    return tuple(sorted(float(f) for f in wind.multisine_hz)) if wind.kind == "multisine" else ()


def metrics(design: Design, wind: WindConfig, rows, truth, est, start_s: float) -> dict[str, float]:
    t = rows[:, 0]
    sc = score(t, rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
               start_s=start_s)  # fmt: skip
    out: dict[str, float] = {
        "band_skill": sc.band_skill, "band_rmse_mps": sc.band_rmse_mps, "raw_rmse_mps": sc.raw_rmse_mps,
        "speed_error_pct": sc.speed_error_pct, "direction_error_deg": sc.direction_error_deg,
        "error_ratio": sc.error_ratio, "accuracy_mps": sc.mean_accuracy_mps,
    }  # fmt: skip
    out["h_err_max"] = math.nan
    lines = wind_lines_hz(wind)
    if lines:
        window = t[-1] - start_s
        shown = [f for f in lines if f * window >= 2.0]
        h = response(t, rows[:, 1], rows[:, 2], truth["time_s"], truth["wind_n"], truth["wind_e"], shown,
                     start_s=start_s, extra_hz=lines)  # fmt: skip
        band = []
        for f in shown:
            for ax in ("along", "cross"):
                v = h[f][ax]
                out[h_column(ax, f)] = abs(v - 1.0) if v is not None else math.nan
                if v is not None and f <= H_BAND_HZ + 1e-12:
                    band.append(abs(v - 1.0))
        out["h_err_max"] = max(band) if band else math.nan
    out["lift_margin_n"], out["lift_margin_frac"] = lift_margin(design)
    late = truth["time_s"] >= start_s
    horiz = np.hypot(truth["pos_n"][late], truth["pos_e"][late])
    up = -truth["pos_d"][late]
    out["blowdown_deg"] = float(np.degrees(np.mean(np.arctan2(horiz, up))))
    out["height_m"] = float(np.mean(up))
    out["slack_frac"] = float(np.mean(truth["tether_taut"][late] < 0.5))
    c = est.counters
    out["mode_switches"] = float(c.mode_switches)
    out["resets"] = float(c.taut_resets + c.numeric_resets + c.time_resets + c.baro_resets)
    out["tilt_err_deg"], out["yaw_err_deg"] = attitude_errors(rows, truth, start_s)
    # the stated tilt (RMS of the filter's own 1-sigma): the tilt's error over it says whether the attitude is honest
    out["tilt_sigma_deg"] = (
        float(np.degrees(np.sqrt(np.mean(rows[t >= start_s, 7] ** 2)))) if rows.shape[1] > 7 else math.nan
    )
    # the consistency monitor's factor on the stated accuracy (RMS) and the source that set it most of the time it was
    # above FACTOR_SHOWN (its index in SOURCES; NaN: it never was): what an over-cautious flight's caution is made of
    scored = rows[t >= start_s] if rows.shape[1] > 9 else np.zeros((0, 10))
    out["accuracy_factor"] = float(np.sqrt(np.mean(scored[:, 8] ** 2))) if len(scored) else math.nan
    shown = scored[scored[:, 8] >= FACTOR_SHOWN, 9].astype(int)
    shown = shown[shown >= 0]
    out["factor_source"] = float(np.bincount(shown).argmax()) if len(shown) else math.nan
    # the drag scale the flight ended with and its 1-sigma: against the truth's C_d, the speed error it alone makes
    out["drag_scale"] = float(est.ekf.x[DRAG])
    out["drag_scale_sigma"] = math.sqrt(max(0.0, float(est.ekf.P[DRAG, DRAG])))
    return {k: float(v) for k, v in out.items()}


def run_case(payload: dict[str, Any]) -> dict[str, Any]:
    """A worker's whole job for one case: never raises; a failure is a row with its error text."""
    from study.spec import build  # here, so that a worker imports only what it runs

    t0 = time.perf_counter()
    row: dict[str, Any] = {"key": payload["key"], "status": "ok", "error": ""}
    try:
        design, wind, truth_cfg, filt = build(payload["sections"])
        rows, truth, est = fly(design, wind, truth_cfg, filt, payload["duration_s"], payload["seed"])
        row.update(metrics(design, wind, rows, truth, est, payload["start_s"]))
    except Exception as e:  # one broken case must not stop the sweep
        row["status"], row["error"] = "failed", f"{type(e).__name__}: {e}"
    row["wall_time_s"] = time.perf_counter() - t0
    return row
