"""The barometer: zeroing, the barometric height, its row and the height reset."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from balloon_core.atmosphere import G0, LAPSE_K_M, R_AIR, air_density, hypsometric_height_m
from firmware_py.estimator.aid_sources.tether import enter_taut
from firmware_py.estimator.ekf import RESET_HEIGHT, FusionStatus, WindEkf
from firmware_py.estimator.params import BARO_PLAUSIBLE_M, BARO_ZERO_S, P_MAX_HPA, P_MIN_HPA, T_MAX_C, T_MIN_C
from firmware_py.estimator.state import (
    BARO_OFF,
    MODE_TAUT,
    POS_D,
    VEL_D,
)

if TYPE_CHECKING:
    from firmware_py.estimator.control import Estimator


def fuse_baro(ekf: WindEkf, height_m: float, ref_pos_d: float, var: float, status: FusionStatus) -> None:
    """Barometric height above the reference (hypsometric, computed by the caller): the true height
    plus the barometer's offset (the weather since the zero)."""
    ekf.h.fill(0.0)
    ekf.h[POS_D] = -1.0
    ekf.h[BARO_OFF] = 1.0
    pred = -(float(ekf.x[POS_D]) - ref_pos_d) + float(ekf.x[BARO_OFF])
    ekf.fuse(height_m - pred, var, status)


def reset_height(ekf: WindEkf, pos_d: float, var: float) -> None:
    """Put the height where the barometer says (PX4's height reset): the model that contradicted it
    persistently (a bump taken for a release, a climb that did not happen) gives way to the sensor."""
    ekf.x[POS_D] = pos_d + float(ekf.x[BARO_OFF])
    ekf.x[VEL_D] = 0.0
    P = ekf.P
    for i in (POS_D, VEL_D):
        P[i, :] = 0.0
        P[:, i] = 0.0
    P[POS_D, POS_D] = var
    P[VEL_D, VEL_D] = 1.0
    ekf.reset(RESET_HEIGHT)


def baro_sample(est: Estimator, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
    """A barometer + thermometer sample: air density, the barometer's zero (the first second after the
    boot unless the config gives the ground pressure; after a join in flight the zero that makes this
    sample read the height from the tilt), and the height to fuse at the next IMU step."""
    if not (
        math.isfinite(pressure_hpa) and math.isfinite(temperature_c)
        and P_MIN_HPA <= pressure_hpa <= P_MAX_HPA and T_MIN_C <= temperature_c <= T_MAX_C
    ):  # fmt: skip
        est.counters.rejected += 1
        return False
    p = pressure_hpa * 100.0
    tk = temperature_c + 273.15
    est.counters.baro_samples += 1
    est.rho = air_density(p, tk)
    if math.isnan(est.t_ref_k):
        est.t_ref_k = tk
    if est._zeroing:
        if not est.initialised:
            return True
        if math.isfinite(est._join_height):
            # joined in flight: the zero that makes this sample read the height from the tilt
            t_ground = tk + LAPSE_K_M * est._join_height
            est.t_ref_k = t_ground
            est.p_ref_pa = p * math.exp(G0 * est._join_height / (R_AIR * 0.5 * (t_ground + tk)))
            est._zeroing = False
            est._join_height = math.nan
        elif t_us - est.t_boot_us < BARO_ZERO_S * 1e6 or est._zero_n == 0:
            est._zero_sum += p
            est._zero_n += 1
            return True
        else:
            est.p_ref_pa = est._zero_sum / est._zero_n
            est._zeroing = False
    est.height_baro = hypsometric_height_m(p, est.p_ref_pa, 0.5 * (est.t_ref_k + tk))
    est._baro_pending = True
    return True


def control_baro(est: Estimator) -> None:
    """Fuse a new barometric height at the step after it arrived; outside the gate for ``BARO_RESET_S``
    the height model is off and the sensor wins: a height reset, or on the taut tether a re-placement on
    the rope's sphere at the barometric height, its azimuth from the lean (``enter_taut``). The streak
    counts every sample outside the gate, the recovery's forced fusions too (``WindEkf.fuse``: they
    clear the status's run of rejections every ``recover_after_s``, and the reset never came while the
    taut rows held the state where the barometer could not walk it back)."""
    if est._baro_pending and not math.isnan(est.height_baro):
        ekf = est.ekf
        st = est.baro_status
        height = est.height_baro - float(ekf.x[BARO_OFF])  # the height the barometer tells, its offset taken out
        reach = est.model.tether_length_m + est.model.radius_m + BARO_PLAUSIBLE_M
        if not -BARO_PLAUSIBLE_M <= height <= reach:  # no balloon's on this tether: not fused, never reset to
            est._baro_pending = False
            est.counters.rejected += 1
            return
        fuse_baro(ekf, est.height_baro, est.ref_pos_d, est.baro_var, st)
        est._baro_pending = False
        outside = st.consecutive_rejects > 0 or st.test_ratio > 1.0
        est.baro_outside = est.baro_outside + 1 if outside else 0
        if est.baro_outside >= est.schedule.baro_reset:
            st.consecutive_rejects = est.baro_outside = 0
            if ekf.mode == MODE_TAUT:
                est.counters.taut_resets += 1
                enter_taut(est, est._height_for_taut(), from_tilt=True)
            else:
                est.counters.baro_resets += 1
                reset_height(ekf, est.ref_pos_d - est.height_baro, est.baro_var)
