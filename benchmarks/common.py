"""Shared by the benchmarks: fly a scenario through the simulator and the firmware in one process
(the same Estimator object the program runs, fed sample by sample) and score it."""

from __future__ import annotations

import numpy as np

from firmware_py.control import Estimator
from ground_station.score import Score, response, score
from sim_hil.dynamics import euler_from_quat
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation


def fly(name: str, duration_s: float, seed: int, scenario=None):
    sc = scenario or SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, seed)
    est = Estimator(sc.design, sc.filter)
    rows = np.zeros((sim.n_imu, 7))
    for i, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        wn, we = est.wind()
        rows[i] = (s.time_usec * 1e-6, wn, we, est.ekf.wind_accuracy(), *euler_from_quat(*est.ekf.q.tolist()))
    truth = {c: sim.truth[:, k] for k, c in enumerate(TRUTH_COLUMNS)}
    return rows, truth, est


def attitude_errors(rows, truth, start_s: float = 120.0) -> tuple[float, float]:
    """RMS tilt error (roll and pitch combined) and RMS heading error of the on-board orientation, deg."""
    late = rows[:, 0] >= start_s
    d = np.degrees(rows[late, 4:7]) - np.column_stack([truth[c][late] for c in ("roll_deg", "pitch_deg", "yaw_deg")])
    d = (d + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def score_flight(rows, truth, start_s: float = 120.0) -> Score:
    return score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
                 start_s=start_s)  # fmt: skip


def response_flight(rows, truth, freqs, start_s: float = 120.0, extra_hz=()) -> dict[float, dict[str, complex | None]]:
    """Along/cross transfer function of the flight's estimate (``ground_station.score.response``)."""
    return response(rows[:, 0], rows[:, 1], rows[:, 2], truth["time_s"], truth["wind_n"], truth["wind_e"], freqs,
                    start_s=start_s, extra_hz=extra_hz)  # fmt: skip
