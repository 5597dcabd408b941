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

from firmware_py.estimator.params import (
    GROUND_P_MAX_HPA,
    GROUND_P_MIN_HPA,
    GROUND_REF_S,
    GROUND_REJECT_PRESSURE,
    GROUND_REJECT_TEMPERATURE,
    GROUND_T_MAX_C,
    GROUND_T_MIN_C,
)

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def init_ground_ref(est: Estimator) -> None:
    """No ground reference yet (and after a reboot: the zero is taken again)."""
    est.ground_samples = 0  # references used
    est.ground_rejected = 0  # ... rejected as implausible (ground_plausible)
    est.ground_reject_reason = 0  # why the last one was (GROUND_REJECT_*; 0: none yet)
    est.ground_t_us = -1  # the sensor clock when the last reference arrived (-1: never)
    est.ground_p_pa = math.nan  # low-passed ground pressure
    est.ground_p0_pa = math.nan  # ... at the first reference after the zero
    est.p_ref0_pa = math.nan  # the barometer's zero then


def ground_plausible(pressure_hpa: float, temperature_c: float) -> int:
    """0 if a ground reference is a ground station's weather, else why not (GROUND_REJECT_*): the
    pressure finite and within [GROUND_P_MIN_HPA, GROUND_P_MAX_HPA], the temperature NaN (not measured)
    or within [GROUND_T_MIN_C, GROUND_T_MAX_C]."""
    if not (math.isfinite(pressure_hpa) and GROUND_P_MIN_HPA <= pressure_hpa <= GROUND_P_MAX_HPA):
        return GROUND_REJECT_PRESSURE
    if not (math.isnan(temperature_c) or GROUND_T_MIN_C <= temperature_c <= GROUND_T_MAX_C):
        return GROUND_REJECT_TEMPERATURE
    return 0


# why a ground reference was rejected, in words (the summary, when the reference is ignored wholesale)
REJECT_WORDS = {
    GROUND_REJECT_PRESSURE: f"pressure not plausible (outside {GROUND_P_MIN_HPA:g}-{GROUND_P_MAX_HPA:g} hPa)",
    GROUND_REJECT_TEMPERATURE: f"temperature not plausible (outside {GROUND_T_MIN_C:g} to {GROUND_T_MAX_C:g} C)",
}


def ground_counts(est: Estimator) -> str:
    """What the estimator made of the ground reference it was given (either core: the same counters)."""
    from firmware_py.estimator.aid_sources.winch import counts_text

    return counts_text("ground reference", "ground reference", est.ground_samples, est.ground_rejected,
                       est.ground_reject_reason, REJECT_WORDS)  # fmt: skip


def ground_baro_sample(est: Estimator, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
    """A ground reference (``t_us`` on the sensor clock: when it arrived): low-pass its pressure, move
    the barometer's zero with it once the zero is taken. An implausible one is rejected and counted."""
    why = ground_plausible(pressure_hpa, temperature_c)
    if why:
        est.ground_rejected += 1
        est.ground_reject_reason = why
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
    if math.isfinite(temperature_c):
        est.t_ref_k = temperature_c + 273.15
    if not math.isfinite(est.ground_p0_pa):
        est.ground_p0_pa = est.ground_p_pa
        est.p_ref0_pa = est.p_ref_pa
    est.p_ref_pa = est.p_ref0_pa * est.ground_p_pa / est.ground_p0_pa
    return True
