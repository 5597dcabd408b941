"""WIND_COV (231) fields from the estimator, as MAVLink defines them (and PX4 does not):
horiz_accuracy = 1-STD accuracy sqrt(P_NN + P_EE); var_horiz = 1-STD variability of the 1 Hz
low-passed wind over the last 60 s (NaN until 60 s are known). Fixed memory: a 60-slot ring."""

from __future__ import annotations

import math

from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import MODE_GROUND

WINDOW_S = 60


class WindCovOutput:
    def __init__(self, imu_rate_hz: float, site_altitude_m: float) -> None:
        dt = 1.0 / imu_rate_hz
        self._alpha = dt / (dt + 1.0 / (2.0 * math.pi * 1.0))  # 1 Hz first-order low-pass
        self._ln = self._le = 0.0
        self._primed = False
        self._ring_n = [0.0] * WINDOW_S
        self._ring_e = [0.0] * WINDOW_S
        self._count = 0
        self._next_slot_us = 0
        self.site_altitude_m = site_altitude_m

    def reset(self) -> None:
        self._primed = False
        self._count = 0
        self._next_slot_us = 0

    def update(self, est: Estimator, t_us: int) -> None:
        """Per filter step: low-pass the wind at 1 Hz and keep one value a second (in flight)."""
        wn, we = est.wind()
        if not self._primed:
            self._ln, self._le, self._primed = wn, we, True
            self._next_slot_us = t_us
        a = self._alpha
        self._ln += a * (wn - self._ln)
        self._le += a * (we - self._le)
        if est.ekf.mode == MODE_GROUND:
            self._count = 0  # the wind is not observed on the ground
            self._next_slot_us = t_us
            return
        if t_us >= self._next_slot_us:
            k = self._count % WINDOW_S
            self._ring_n[k] = self._ln
            self._ring_e[k] = self._le
            self._count += 1
            self._next_slot_us += 1_000_000

    def variability(self) -> float:
        if self._count < WINDOW_S:
            return math.nan
        mn = sum(self._ring_n) / WINDOW_S
        me = sum(self._ring_e) / WINDOW_S
        var = sum((a - mn) ** 2 + (b - me) ** 2 for a, b in zip(self._ring_n, self._ring_e)) / (WINDOW_S - 1)
        return math.sqrt(var)

    def fields(self, est: Estimator) -> tuple:
        """(time_usec, wind_x, wind_y, wind_z, var_horiz, var_vert, wind_alt, horiz_accuracy, vert_accuracy)

        Before the first sensor sample nothing is known: wind, altitude and accuracy are NaN (MAVLink's
        "unknown"), never a zero wind with accuracy 0 (which would claim a perfectly known calm)."""
        if not est.initialised:
            nan = math.nan
            return (max(est.t_last_us, 0), nan, nan, nan, nan, nan, nan, nan, 0.0)
        wn, we = est.wind()
        return (
            max(est.t_last_us, 0),
            wn,
            we,
            math.nan,  # vertical wind is not estimated
            self.variability(),
            math.nan,
            self.site_altitude_m + est.height_m(),
            est.wind_accuracy(),
            0.0,
        )
