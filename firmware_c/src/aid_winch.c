/* The winch and the ground reference (firmware_py/estimator/aid_sources/winch.py, ground_ref.py):
 * WINCH_STATUS's paid-out length is the tether's length while it changes, the reel's speed the rate the
 * chord grows at; the ground station's barometer moves the balloon barometer's zero with the weather. */
#include "internal.h"

void bw_init_winch(bw_estimator_t *est)
{
    est->winch_samples = 0;
    est->winch_rejected = 0;
    est->winch_reject_reason = 0;
    est->winch_t_us = -1;
    est->winch_tension_n = BW_R(NAN);
}

/* the tether's length is now length_m: the model's length and the rope's shape in proportion */
static void set_line_length(bw_ekf_t *e, bw_real length_m)
{
    bw_model_t *m = &e->m;
    bw_real scale;
    if (length_m == m->tether_length_m)
        return;
    scale = length_m / m->tether_length_m;
    m->tether_length_m = length_m;
    m->rope_drag_m2 = m->rope_drag_m2 * scale;
    m->rope_weight_n = m->lam_g * length_m;
    e->rope_chord_m *= scale;
    e->rope_weight_n *= scale;
}

/* 0 if a WINCH_STATUS is plausible, else why not (BW_WINCH_REJECT_*): the line finite, within [1 m, the
 * design's tether (the rope on the drum) + margin], not shorter than the barometric height less a
 * tolerance (no height yet: not checked); the reel speed finite and within the winch's limit */
static int winch_plausible(const bw_estimator_t *est, bw_real line_length_m, bw_real speed_mps)
{
    bw_real drum_m = (bw_real)est->cfg->tether_length_m;
    if (!(isfinite(line_length_m) && (bw_real)BW_WINCH_LENGTH_MIN_M <= line_length_m &&
          line_length_m <= drum_m + (bw_real)BW_WINCH_LENGTH_MARGIN_M))
        return BW_WINCH_REJECT_LENGTH;
    if (line_length_m < est->height_baro - (bw_real)BW_WINCH_HEIGHT_TOL_M) /* (NAN before the zero: false) */
        return BW_WINCH_REJECT_HEIGHT;
    if (!(isfinite(speed_mps) && BW_FABS(speed_mps) <= (bw_real)BW_WINCH_SPEED_MAX_MPS))
        return BW_WINCH_REJECT_SPEED;
    return 0;
}

int bw_on_winch(bw_estimator_t *est, int64_t t_us, bw_real line_length_m, bw_real speed_mps, bw_real tension_n)
{
    bw_ekf_t *e = &est->ekf;
    int why = winch_plausible(est, line_length_m, speed_mps);
    if (why) {
        est->winch_rejected += 1;
        est->winch_reject_reason = why;
        return 0;
    }
    est->winch_samples += 1;
    est->winch_t_us = t_us;
    est->winch_tension_n = isfinite(tension_n) && tension_n >= BW_R(0.0)
                               ? tension_n : BW_R(NAN);
    set_line_length(e, line_length_m);
    e->rope_rate_mps = speed_mps * e->rope_chord_m / line_length_m;
    return 1;
}

void bw_control_winch(bw_estimator_t *est)
{
    /* a winch that falls silent while it reels: stop expecting the reel's motion */
    if (est->ekf.rope_rate_mps != BW_R(0.0) && est->t_last_us - est->winch_t_us > (int64_t)(BW_WINCH_TIMEOUT_S * 1e6))
        est->ekf.rope_rate_mps = BW_R(0.0);
}

void bw_init_ground_ref(bw_estimator_t *est)
{
    est->ground_samples = 0;
    est->ground_rejected = 0;
    est->ground_reject_reason = 0;
    est->ground_t_us = -1;
    est->ground_p_pa = est->ground_p0_pa = est->p_ref0_pa = BW_R(NAN);
}

/* 0 if a ground reference is a ground station's weather, else why not (BW_GROUND_REJECT_*): the pressure
 * finite and within [300, 1100] hPa, the temperature NAN (not measured) or within [-80, 60] degrees C */
static int ground_plausible(bw_real pressure_hpa, bw_real temperature_c)
{
    if (!(isfinite(pressure_hpa) && (bw_real)BW_GROUND_P_MIN_HPA <= pressure_hpa &&
          pressure_hpa <= (bw_real)BW_GROUND_P_MAX_HPA))
        return BW_GROUND_REJECT_PRESSURE;
    if (!(isnan(temperature_c) || ((bw_real)BW_GROUND_T_MIN_C <= temperature_c && temperature_c <= (bw_real)BW_GROUND_T_MAX_C)))
        return BW_GROUND_REJECT_TEMPERATURE;
    return 0;
}

int bw_on_ground_baro(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c)
{
    bw_real p;
    int why = ground_plausible(pressure_hpa, temperature_c);
    if (why) {
        est->ground_rejected += 1;
        est->ground_reject_reason = why;
        return 0;
    }
    p = pressure_hpa * BW_R(100.0);
    if (est->ground_t_us < 0 || t_us < est->ground_t_us) {
        est->ground_p_pa = p;
    } else {
        bw_real alpha = BW_MIN(BW_R(1.0), (bw_real)(t_us - est->ground_t_us) * BW_R(1e-6) / (bw_real)BW_GROUND_REF_S);
        est->ground_p_pa += alpha * (p - est->ground_p_pa);
    }
    est->ground_t_us = t_us;
    est->ground_samples += 1;
    if (est->zeroing || !isfinite(est->p_ref_pa))
        return 1; /* the zero is not taken yet */
    if (isfinite(temperature_c))
        est->t_ref_k = temperature_c + BW_R(273.15);
    if (!isfinite(est->ground_p0_pa)) {
        est->ground_p0_pa = est->ground_p_pa;
        est->p_ref0_pa = est->p_ref_pa;
    }
    est->p_ref_pa = est->p_ref0_pa * est->ground_p_pa / est->ground_p0_pa;
    return 1;
}
