"""Shared by the benchmarks: fly a scenario through the simulator and the firmware in one process
(the same Estimator object the program runs, fed sample by sample: ``study.case``) and score it."""

from __future__ import annotations

from balloon_core.score import Score, response, score
from sim_hil.scenarios import SCENARIOS
from study.case import attitude_errors  # noqa: F401 - re-exported for the benchmarks
from study.case import fly as fly_design


def fly(name: str, duration_s: float, seed: int, scenario=None, join_s: float = 0.0):
    """A named scenario (or ``scenario``) through ``study.case.fly`` (the firmware joining the flight at ``join_s``
    where > 0): rows, truth by column, the estimator."""
    sc = scenario or SCENARIOS[name]
    return fly_design(sc.design, sc.wind, sc.truth, sc.filter, duration_s, seed, join_s)


def score_flight(rows, truth, start_s: float = 120.0) -> Score:
    return score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
                 start_s=start_s)  # fmt: skip


def response_flight(rows, truth, freqs, start_s: float = 120.0, extra_hz=()) -> dict[float, dict[str, complex | None]]:
    """Along/cross transfer function of the flight's estimate (``balloon_core.score.response``)."""
    return response(rows[:, 0], rows[:, 1], rows[:, 2], truth["time_s"], truth["wind_n"], truth["wind_e"], freqs,
                    start_s=start_s, extra_hz=extra_hz)  # fmt: skip
