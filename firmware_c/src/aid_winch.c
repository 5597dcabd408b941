/* The winch and the ground reference (firmware_py/estimator/aid_sources/winch.py, ground_ref.py):
 * WINCH_STATUS's paid-out length is the tether's length while it changes, the reel's speed the rate the
 * chord grows at; the ground station's barometer moves the balloon barometer's zero with the weather. */
#include "internal.h"

void bw_init_winch(bw_estimator_t *est)
{
    est->winch_samples = 0;
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

int bw_on_winch(bw_estimator_t *est, int64_t t_us, bw_real line_length_m, bw_real speed_mps, bw_real tension_n)
{
    bw_ekf_t *e = &est->ekf;
    bw_real speed;
    if (!(line_length_m == line_length_m && (bw_real)BW_WINCH_LENGTH_MIN_M <= line_length_m &&
          line_length_m <= (bw_real)BW_WINCH_LENGTH_MAX_M))
        return 0;
    est->winch_samples += 1;
    est->winch_t_us = t_us;
    est->winch_tension_n = isfinite(tension_n) && tension_n >= BW_R(0.0)
                               ? tension_n : BW_R(NAN);
    set_line_length(e, line_length_m);
    speed = speed_mps == speed_mps && BW_FABS(speed_mps) <= (bw_real)BW_WINCH_SPEED_MAX_MPS ? speed_mps : BW_R(0.0);
    e->rope_rate_mps = speed * e->rope_chord_m / line_length_m;
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
    est->ground_t_us = -1;
    est->ground_p_pa = est->ground_p0_pa = est->p_ref0_pa = BW_R(NAN);
}

int bw_on_ground_baro(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c)
{
    bw_real p;
    if (!(pressure_hpa == pressure_hpa && (bw_real)BW_P_MIN_HPA <= pressure_hpa && pressure_hpa <= (bw_real)BW_P_MAX_HPA))
        return 0;
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
    if (temperature_c == temperature_c && (bw_real)BW_T_MIN_C <= temperature_c && temperature_c <= (bw_real)BW_T_MAX_C)
        est->t_ref_k = temperature_c + BW_R(273.15);
    if (!isfinite(est->ground_p0_pa)) {
        est->ground_p0_pa = est->ground_p_pa;
        est->p_ref0_pa = est->p_ref_pa;
    }
    est->p_ref_pa = est->p_ref0_pa * est->ground_p_pa / est->ground_p0_pa;
    return 1;
}
