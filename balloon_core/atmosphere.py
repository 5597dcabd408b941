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


def isa_temperature_k(height_m: float, ground_temperature_k: float) -> float:
    """Air temperature at ``height_m`` above a site whose ground temperature is given (ISA lapse)."""
    return ground_temperature_k - LAPSE_K_M * height_m


def isa_pressure_pa(height_m: float, ground_pressure_pa: float, ground_temperature_k: float) -> float:
    """ISA pressure at ``height_m`` above a site (barometric formula with constant lapse rate)."""
    return ground_pressure_pa * (1.0 - LAPSE_K_M * height_m / ground_temperature_k) ** ISA_EXP


def air_density(pressure_pa: float, temperature_k: float) -> float:
    """Ideal-gas dry-air density rho = p / (R T), kg/m^3 (docs/model.md: 1.204 at 1013.25 hPa, 20 C)."""
    return pressure_pa / (R_AIR * temperature_k)


def hypsometric_height_m(pressure_pa: float, ref_pressure_pa: float, mean_temperature_k: float) -> float:
    """Height above the reference level from the hypsometric equation h = (R T_mean / g) ln(p_ref / p)."""
    return R_AIR * mean_temperature_k / G0 * math.log(ref_pressure_pa / pressure_pa)
