"""Cached simulated sensor streams for the firmware tests (simulated once per test session)."""

from __future__ import annotations

import functools

import numpy as np

from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation


@functools.lru_cache(maxsize=4)
def stream(name: str = "paper-reference", duration_s: float = 300.0, seed: int = 11):
    """(samples, truth dict) of one flight."""
    sc = SCENARIOS[name]
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, seed)
    samples = list(sim.samples())
    return samples, {c: sim.truth[:, k].copy() for k, c in enumerate(TRUTH_COLUMNS)}


def feed(est, samples, record: bool = False, each=None):
    """The samples into the estimator; ``record``: its wind and accuracy after each, as rows (t, n, e, accuracy);
    ``each(sample)``: called after each sample is taken."""
    rows = []
    for s in samples:
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if each is not None:
            each(s)
        if record:
            wn, we = est.wind()
            rows.append((s.time_usec * 1e-6, wn, we, est.wind_accuracy()))
    return np.array(rows) if record else None
