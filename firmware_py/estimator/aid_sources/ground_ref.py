"""The ground reference (docs/estimator.md, "The ground reference"): the ground station's own barometer
(and thermometer) at the anchor, sent up the link. The balloon's barometric height is then a
difference of two barometers, immune to the weather.

The barometer's zero ``p_ref`` (the pressure at the anchor) follows the ground's pressure: once the
zero is taken (the first second after the boot, the config's ground pressure, or a join in flight),
p_ref = p_ref0 * p_g / p_g0, with p_g the ground reference low-passed over ``GROUND_REF_S`` and p_g0,
p_ref0 the two at the first reference after the zero. Only the ground's change since then enters: an
offset between the two barometers cancels. The weather that moves the whole column's pressure (the
``BARO_OFF`` state's walk) then stays out of the height; the state remains for what is left. The ground
thermometer (when finite) is the layer's bottom temperature of the hypsometric height (``t_ref_k``).
Without a reference nothing here runs."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from firmware_py.estimator.params import GROUND_REF_S, P_MAX_HPA, P_MIN_HPA, T_MAX_C, T_MIN_C

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def init_ground_ref(est: Estimator) -> None:
    """No ground reference yet (and after a reboot: the zero is taken again)."""
    est.ground_samples = 0
    est.ground_t_us = -1  # the sensor clock when the last reference arrived (-1: never)
    est.ground_p_pa = math.nan  # low-passed ground pressure
    est.ground_p0_pa = math.nan  # ... at the first reference after the zero
    est.p_ref0_pa = math.nan  # the barometer's zero then


def ground_baro_sample(est: Estimator, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
    """A ground reference (``t_us`` on the sensor clock: when it arrived): low-pass its pressure, move
    the barometer's zero with it once the zero is taken."""
    if not (math.isfinite(pressure_hpa) and P_MIN_HPA <= pressure_hpa <= P_MAX_HPA):
        return False
    p = pressure_hpa * 100.0
    if est.ground_t_us < 0 or t_us < est.ground_t_us:
        est.ground_p_pa = p
    else:
        alpha = min(1.0, (t_us - est.ground_t_us) * 1e-6 / GROUND_REF_S)
        est.ground_p_pa += alpha * (p - est.ground_p_pa)
    est.ground_t_us = t_us
    est.ground_samples += 1
    if est._zeroing or not math.isfinite(est.p_ref_pa):
        return True  # the zero is not taken yet
    if math.isfinite(temperature_c) and T_MIN_C <= temperature_c <= T_MAX_C:
        est.t_ref_k = temperature_c + 273.15
    if not math.isfinite(est.ground_p0_pa):
        est.ground_p0_pa = est.ground_p_pa
        est.p_ref0_pa = est.p_ref_pa
    est.p_ref_pa = est.p_ref0_pa * est.ground_p_pa / est.ground_p0_pa
    return True
