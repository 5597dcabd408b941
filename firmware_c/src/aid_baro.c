/* The barometer: zeroing, the barometric height, its row and the height reset
 * (firmware_py/estimator/aid_sources/baro.py). */
#include <string.h>

#include "internal.h"

static bw_real hypsometric_height_m(bw_real p, bw_real p_ref, bw_real t_mean_k)
{
    return (bw_real)BW_R_AIR * t_mean_k / (bw_real)BW_G0 * BW_LOG(p_ref / p);
}

static void fuse_baro(bw_estimator_t *est, bw_real height_m)
{
    bw_ekf_t *e = &est->ekf;
    bw_real pred;
    memset(e->h, 0, sizeof e->h);
    e->h[BW_POS_D] = BW_R(-1.0);
    e->h[BW_BARO_OFF] = BW_R(1.0);
    pred = -(e->x[BW_POS_D] - est->ref_pos_d) + e->x[BW_BARO_OFF];
    bw_ekf_fuse(e, height_m - pred, est->baro_var, &est->baro_status, BW_R(0.0), 1);
}

void bw_reset_height(bw_ekf_t *e, bw_real pos_d, bw_real var)
{
    int j;
    e->x[BW_POS_D] = pos_d + e->x[BW_BARO_OFF];
    e->x[BW_VEL_D] = BW_R(0.0);
    for (j = 0; j < BW_N; j++) {
        e->P[BW_POS_D][j] = e->P[j][BW_POS_D] = BW_R(0.0);
        e->P[BW_VEL_D][j] = e->P[j][BW_VEL_D] = BW_R(0.0);
    }
    e->P[BW_POS_D][BW_POS_D] = var;
    e->P[BW_VEL_D][BW_VEL_D] = BW_R(1.0);
    bw_ekf_reset(e, BW_RESET_HEIGHT);
}

int bw_baro_sample(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c)
{
    bw_real p, tk;
    if (!(pressure_hpa == pressure_hpa && temperature_c == temperature_c && (bw_real)BW_P_MIN_HPA <= pressure_hpa &&
          pressure_hpa <= (bw_real)BW_P_MAX_HPA && (bw_real)BW_T_MIN_C <= temperature_c &&
          temperature_c <= (bw_real)BW_T_MAX_C)) {
        est->counters.rejected += 1;
        return 0;
    }
    p = pressure_hpa * BW_R(100.0);
    tk = temperature_c + BW_R(273.15);
    est->counters.baro_samples += 1;
    est->rho = bw_air_density(p, tk);
    if (est->t_ref_k != est->t_ref_k)
        est->t_ref_k = tk;
    if (est->zeroing) {
        if (!est->initialised)
            return 1;
        if (est->join_height == est->join_height) {
            /* joined in flight: the zero that makes this sample read the height from the tilt */
            bw_real t_ground = tk + (bw_real)BW_LAPSE_K_M * est->join_height;
            est->t_ref_k = t_ground;
            est->p_ref_pa = p * BW_EXP((bw_real)BW_G0 * est->join_height /
                                       ((bw_real)BW_R_AIR * BW_R(0.5) * (t_ground + tk)));
            est->zeroing = 0;
            est->join_height = BW_R(NAN);
        } else if ((double)(t_us - est->t_boot_us) < BW_BARO_ZERO_S * 1e6 || est->zero_n == 0) {
            est->zero_sum += p;
            est->zero_n += 1;
            return 1;
        } else {
            est->p_ref_pa = est->zero_sum / (bw_real)est->zero_n;
            est->zeroing = 0;
        }
    }
    est->height_baro = hypsometric_height_m(p, est->p_ref_pa, BW_R(0.5) * (est->t_ref_k + tk));
    est->baro_pending = 1;
    return 1;
}

void bw_control_baro(bw_estimator_t *est)
{
    if (est->baro_pending && est->height_baro == est->height_baro) {
        bw_status_t *st = &est->baro_status;
        bw_real height = est->height_baro - est->ekf.x[BW_BARO_OFF]; /* its offset taken out (control_baro) */
        if (!(height >= -(bw_real)BW_BARO_PLAUSIBLE_M &&
              height <= est->ekf.m.tether_length_m + est->ekf.m.radius_m + (bw_real)BW_BARO_PLAUSIBLE_M)) {
            est->baro_pending = 0; /* no balloon's on this tether: not fused, never reset to */
            est->counters.rejected += 1;
            return;
        }
        fuse_baro(est, est->height_baro);
        est->baro_pending = 0;
        /* every sample outside the gate counts, the recovery's forced fusions too (control.py) */
        est->baro_outside = st->consecutive_rejects > 0 || st->test_ratio > BW_R(1.0) ? est->baro_outside + 1 : 0;
        if (est->baro_outside >= est->sched.baro_reset) {
            st->consecutive_rejects = 0;
            est->baro_outside = 0;
            if (est->ekf.mode == BW_MODE_TAUT) {
                est->counters.taut_resets += 1;
                bw_enter_taut(est, bw_height_for_taut(est), 1);
            } else {
                est->counters.baro_resets += 1;
                bw_reset_height(&est->ekf, est->ref_pos_d - est->height_baro, est->baro_var);
            }
        }
    }
}
