"""ISA troposphere and the hypsometric equation, shared by the simulator (truth) and the firmware.

Pure functions of plain floats so that the firmware can call them per sample without allocation.
"""

from __future__ import annotations

import math

G0 = 9.80665  # standard gravity, m/s^2
R_AIR = 287.05  # specific gas constant of dry air, J/(kg K)
LAPSE_K_M = 0.0065  # ISA tropospheric lapse rate, K/m
ISA_EXP = G0 / (R_AIR * LAPSE_K_M)  # 5.2559
P0_PA = 101325.0
T0_K = 288.15
SECONDS_PER_HOUR = 3600.0
# the ground conditions a site may have ([site] ground_pressure_hpa, ground_temperature_c in SCHEMA);
# ground_conditions refuses weather that drifts outside them
GROUND_PRESSURE_RANGE_PA = (30000.0, 110000.0)
GROUND_TEMPERATURE_RANGE_K = (273.15 - 80.0, 273.15 + 60.0)


def isa_temperature_k(height_m: float, ground_temperature_k: float) -> float:
    """Air temperature at ``height_m`` above a site whose ground temperature is given (ISA lapse)."""
    return ground_temperature_k - LAPSE_K_M * height_m


def ground_conditions(
    base_pressure_pa: float, base_temperature_k: float, drift_hpa_h: float, drift_k_h: float, time_s: float
) -> tuple[float, float]:
    """(pressure Pa, temperature K) at the ground at ``time_s`` after boot, when the weather changes
    them linearly from their boot values (``[truth] pressure_drift_hpa_h``, ``temperature_drift_k_h``).
    A ValueError when the drift takes them outside what a site may have (GROUND_*_RANGE)."""
    p = base_pressure_pa + drift_hpa_h * 100.0 * time_s / SECONDS_PER_HOUR
    t = base_temperature_k + drift_k_h * time_s / SECONDS_PER_HOUR
    p_lo, p_hi = GROUND_PRESSURE_RANGE_PA
    t_lo, t_hi = GROUND_TEMPERATURE_RANGE_K
    if not (p_lo <= p <= p_hi and t_lo <= t <= t_hi):
        raise ValueError(
            f"the weather drift takes the ground to {p / 100.0:.1f} hPa, {t - 273.15:.1f} C at t = {time_s:.0f} s, "
            f"outside what [site] allows ({p_lo / 100.0:g}-{p_hi / 100.0:g} hPa, {t_lo - 273.15:g} to "
            f"{t_hi - 273.15:g} C): a shorter flight or a smaller [truth] pressure_drift_hpa_h / temperature_drift_k_h"
        )
    return p, t


def isa_pressure_pa(height_m: float, ground_pressure_pa: float, ground_temperature_k: float) -> float:
    """ISA pressure at ``height_m`` above a site (barometric formula with constant lapse rate)."""
    return ground_pressure_pa * (1.0 - LAPSE_K_M * height_m / ground_temperature_k) ** ISA_EXP


def air_density(pressure_pa: float, temperature_k: float) -> float:
    """Ideal-gas dry-air density rho = p / (R T), kg/m^3 (docs/model.md: 1.204 at 1013.25 hPa, 20 C)."""
    return pressure_pa / (R_AIR * temperature_k)


def hypsometric_height_m(pressure_pa: float, ref_pressure_pa: float, mean_temperature_k: float) -> float:
    """Height above the reference level from the hypsometric equation h = (R T_mean / g) ln(p_ref / p)."""
    return R_AIR * mean_temperature_k / G0 * math.log(ref_pressure_pa / pressure_pa)
