"""The one sample interface: every input (live MAVLink, tlogs, raw captures, PX4 ULog, ArduPilot
DataFlash) is turned into these samples before it reaches the estimator, so the live firmware and the
post-flight reprocessing see exactly the same thing.

Units are the estimator's: specific force in body FRD (m/s^2, level and at rest z = -9.81), body rates
(rad/s), magnetic field (gauss, NaN when the sample holds no new magnetometer reading), pressure
(hPa), temperature (degC). ``t_us`` is the sensor's own clock (microseconds since its boot)."""

from __future__ import annotations

import math
from typing import NamedTuple

from firmware_py.control import Estimator


class ImuSample(NamedTuple):
    t_us: int
    ax: float
    ay: float
    az: float
    gx: float
    gy: float
    gz: float
    mx: float = math.nan
    my: float = math.nan
    mz: float = math.nan


class BaroSample(NamedTuple):
    t_us: int
    pressure_hpa: float
    temperature_c: float


Sample = ImuSample | BaroSample


def feed(est: Estimator, s: Sample) -> bool:
    """Hand one sample to the estimator. Returns True when the filter advanced (an IMU step)."""
    if type(s) is ImuSample:
        return est.on_imu(s.t_us, s.ax, s.ay, s.az, s.gx, s.gy, s.gz, s.mx, s.my, s.mz)
    est.on_baro(s.t_us, s.pressure_hpa, s.temperature_c)
    return False
