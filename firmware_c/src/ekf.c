/* The EKF's memory, prediction, sequential fusion and covariance hygiene (firmware_py/estimator/ekf.py).
 * The products skip F's and H's zeros and keep P exactly symmetric: the same arithmetic as the
 * reference's dense matrix products up to the order of the sums. */
#include <string.h>

#include "internal.h"

/* the public struct's reset counts hold every kind the filter knows (a compile-time check, C99) */
typedef char bw_reset_kinds_fit[sizeof(((bw_ekf_t *)0)->reset_counts) / sizeof(int32_t) == BW_N_RESET_KINDS ? 1 : -1];

#define N BW_N

#ifdef BW_HOST_RECORDER
/* the post-flight smoother's recorder (include/bw_recorder.h): host build only, here at ekf.py's calls */
#include "bw_recorder.h"
#define REC(e) (bw_recorder_active != 0 && bw_recorder_active->ekf == (e) ? bw_recorder_active : 0)
#endif

void bw_status_init(bw_status_t *st, int32_t recover_after)
{
    memset(st, 0, sizeof *st);
    st->recover_after = recover_after;
    st->time_last_fuse_us = -1;
    st->time_test_us = -1;
}

void bw_ekf_init(bw_ekf_t *e, const bw_config_t *c)
{
    int i;
    double dt = 1.0 / c->imu_rate_hz, g, qv, qr, tau, q_rate, q_walk, rho0, lift0, rope_w;
    memset(e, 0, sizeof *e);
    e->m.radius_m = (bw_real)c->radius_m, e->m.volume_m3 = (bw_real)c->volume_m3, e->m.mass_kg = (bw_real)c->mass_kg;
    e->m.half_cd_area_m2 = (bw_real)c->half_cd_area_m2, e->m.tether_length_m = (bw_real)c->tether_length_m;
    e->m.rope_kg_m = (bw_real)c->rope_kg_m, e->m.rope_drag_m2 = (bw_real)c->rope_drag_m2;
    e->m.rope_cn_d_m = (bw_real)c->rope_cn_d_m, e->m.lam_g = (bw_real)(c->rope_kg_m * BW_G0);
    e->m.rope_weight_n = (bw_real)(c->rope_kg_m * BW_G0 * c->tether_length_m);
    e->m.turbulence_intensity = (bw_real)c->turbulence_intensity, e->m.release_height_m = (bw_real)c->release_height_m;
    e->m.release_accel_mps2 = (bw_real)c->release_accel_mps2, e->m.taut_margin_m = (bw_real)c->taut_margin_m;
    e->m.imu_rate_hz = (bw_real)c->imu_rate_hz, e->m.gate_sigma = (bw_real)c->gate_sigma;
    e->m.gate2 = (bw_real)(c->gate_sigma * c->gate_sigma), e->m.radial_var = (bw_real)(c->radial_m * c->radial_m);
    e->m.radial_rate_var = (bw_real)(c->radial_rate_mps * c->radial_rate_mps);
    e->dt = (bw_real)dt;
    e->q[0] = BW_R(1.0);
    for (i = 0; i < N; i++) {
        double v = i < 3 ? BW_POS_VAR_MAX_M2 : i < 6 ? BW_VEL_VAR_MAX_M2S2 : i < 9 ? BW_ATT_VAR_MAX_RAD2
                 : i < 12 ? (BW_GYRO_BIAS_SIGMA_MAX_DEG_S * 0.017453292519943295) * (BW_GYRO_BIAS_SIGMA_MAX_DEG_S * 0.017453292519943295)
                 : i < 14 ? BW_WIND_VAR_MAX_M2S2 : i < 16 ? BW_WRATE_VAR_MAX_M2S4 : i == BW_DRAG ? BW_DRAG_VAR_MAX
                 : i == BW_BARO_OFF ? BW_POS_VAR_MAX_M2 : BW_ABIAS_VAR_MAX_M2S4;
        e->var_max[i] = (bw_real)v;
    }
    e->forces.rope_weight_n = BW_R(NAN);
    e->forces.m_eff_kg = BW_R(1.0);
    rho0 = bw_site_air_density(c);
    lift0 = (rho0 * c->volume_m3 - c->mass_kg) * BW_G0;
    rope_w = c->rope_kg_m * BW_G0 * c->tether_length_m;
    e->rope_chord_m = (bw_real)c->tether_length_m;
    e->rope_weight_n = (bw_real)(c->rope_catenary != 0.0 ? bw_calm_weight_share(lift0, rope_w) : rope_w);
    g = c->gyro_dps * 0.017453292519943295;
    qv = c->accel_process_mps2 * c->accel_process_mps2 * dt;
    bw_wind_process(c->expected_wind_mps, c->turbulence_intensity, 2.0 * c->radius_m, &tau, &q_rate, &q_walk);
    e->wp_tau_s = (bw_real)tau;
    e->wp_q_rate = (bw_real)q_rate;
    e->wp_q_walk = (bw_real)q_walk;
    e->sigma_rate = (bw_real)sqrt(0.5 * q_rate * tau);
    e->rate_decay = (bw_real)exp(-dt / tau);
    qr = q_rate * dt;
    for (i = 0; i < 3; i++) {
        double gb = c->gyro_bias_walk_dps_rt_s * 0.017453292519943295;
        e->q_flight[i] = (bw_real)(0.25 * qv * dt * dt);
        e->q_flight[3 + i] = (bw_real)qv;
        e->q_flight[6 + i] = (bw_real)(g * g * dt * dt);
        e->q_flight[9 + i] = (bw_real)(gb * gb * dt);
    }
    e->q_flight[BW_WIND_N] = e->q_flight[BW_WIND_E] = BW_R(0.0);
    e->q_flight[BW_WRATE_N] = e->q_flight[BW_WRATE_E] = (bw_real)qr;
    e->q_flight[BW_DRAG] = (bw_real)(c->drag_walk_rt_s * c->drag_walk_rt_s * dt);
    e->q_flight[BW_BARO_OFF] = (bw_real)(c->baro_walk_m_rt_s * c->baro_walk_m_rt_s * dt);
    e->q_flight[BW_ABIAS_Z] = (bw_real)(c->accel_bias_walk_mps2_rt_s * c->accel_bias_walk_mps2_rt_s * dt);
    for (i = 0; i < N; i++)
        e->q_ground[i] = i < 6 ? (bw_real)BW_GROUND_PROCESS_VAR : i == BW_DRAG ? BW_R(0.0) : e->q_flight[i];
    memcpy(e->qd_ground, e->q_ground, sizeof e->q_ground);
    e->q_rate0 = (bw_real)qr;
    e->u0 = (bw_real)(c->expected_wind_mps > 0.5 ? c->expected_wind_mps : 0.5);
    e->q_walk_step = (bw_real)(q_walk * dt);
    e->mode = BW_MODE_GROUND;
    e->time_taut_us = -1;
    e->drag_correlated = 1;
    e->recover_after = (int32_t)(c->recover_after_s * c->imu_rate_hz);
}

void bw_ekf_reset(bw_ekf_t *e, int kind)
{
    e->reset_counts[kind] += 1;
    e->reset_count += 1;
    if (kind == BW_RESET_TAUT)
        e->time_taut_us = e->time_us;
    if (kind == BW_RESET_INITIALISE) /* the others leave the attitude's block of P as it was */
        e->field_att_extra = BW_R(0.0);
}

void bw_ekf_initialise(bw_ekf_t *e, const bw_config_t *c, const bw_real q[4], bw_real pos_d)
{
    int i;
    double tilt = (c->init_tilt_deg * 0.017453292519943295) * (c->init_tilt_deg * 0.017453292519943295);
    double yaw = c->init_yaw_deg * 0.017453292519943295, gb = c->init_gyro_bias_dps * 0.017453292519943295;
    memset(e->x, 0, sizeof e->x);
    e->x[BW_POS_D] = pos_d;
    e->x[BW_DRAG] = BW_R(1.0);
    for (i = 0; i < 4; i++)
        e->q[i] = q[i];
    memset(e->P, 0, sizeof e->P);
    for (i = 0; i < 3; i++) {
        e->P[i][i] = BW_R(0.01);
        e->P[3 + i][3 + i] = BW_R(1e-4);
        e->P[9 + i][9 + i] = (bw_real)(gb * gb);
    }
    e->P[6][6] = e->P[7][7] = (bw_real)tilt;
    e->P[8][8] = (bw_real)(yaw * yaw);
    e->P[BW_WIND_N][BW_WIND_N] = e->P[BW_WIND_E][BW_WIND_E] = (bw_real)(c->init_wind_mps * c->init_wind_mps);
    e->P[BW_WRATE_N][BW_WRATE_N] = e->P[BW_WRATE_E][BW_WRATE_E] = e->sigma_rate * e->sigma_rate;
    e->P[BW_DRAG][BW_DRAG] = (bw_real)(c->init_drag * c->init_drag);
    e->P[BW_BARO_OFF][BW_BARO_OFF] = (bw_real)BW_VAR_MIN;
    e->P[BW_ABIAS_Z][BW_ABIAS_Z] = (bw_real)(c->init_accel_bias_mps2 * c->init_accel_bias_mps2);
    e->mode = BW_MODE_GROUND;
    bw_ekf_reset(e, BW_RESET_INITIALISE);
}

/* The non-zeros of row i of the transition matrix F (ekf.py predict and _set_static_jacobian): the
 * position integrates the velocity; in flight the velocity follows the model's Jacobian (on the ground it
 * is held at zero); the attitude error is driven by the gyro-bias error through R; the wind integrates
 * its rate, which decays. F is never stored: each row is made when a product needs it. */
static int f_row(const bw_ekf_t *e, const bw_real r[9], int ground, int i, unsigned char cols[BW_NCOL + 1],
                 bw_real vals[BW_NCOL + 1])
{
    const bw_real dt = e->dt;
    int n = 0, j;
    if (i < 3) {
        cols[n] = (unsigned char)i, vals[n++] = BW_R(1.0);
        if (!ground)
            cols[n] = (unsigned char)(3 + i), vals[n++] = dt;
    } else if (i < 6) {
        if (!ground)
            for (j = 0; j < BW_NCOL; j++) {
                int col = BW_MODEL_COLS[j];
                bw_real v = e->forces.ja[BW_NCOL * (i - 3) + j] * dt;
                if (col == i)
                    v += BW_R(1.0);
                if ((col == BW_DRAG && !e->learn_drag) || v == BW_R(0.0))
                    continue; /* a structural zero of the model's Jacobian (the reference adds its 0 x P) */
                cols[n] = (unsigned char)col, vals[n++] = v;
            }
    } else if (i < 9) {
        cols[n] = (unsigned char)i, vals[n++] = BW_R(1.0);
        for (j = 0; j < 3; j++)
            cols[n] = (unsigned char)(9 + j), vals[n++] = -r[3 * (i - 6) + j] * dt;
    } else if (i == BW_WIND_N || i == BW_WIND_E) {
        cols[n] = (unsigned char)i, vals[n++] = BW_R(1.0);
        cols[n] = (unsigned char)(i + 2), vals[n++] = dt;
    } else if (i == BW_WRATE_N || i == BW_WRATE_E) {
        cols[n] = (unsigned char)i, vals[n++] = e->rate_decay;
    } else {
        cols[n] = (unsigned char)i, vals[n++] = BW_R(1.0);
    }
    return n;
}

#ifdef BW_HOST_RECORDER
/* SmootherRecorder.predict: Pi <- F Pi */
static void rec_predict(bw_recorder_t *rc, const bw_ekf_t *e, const bw_real r[9], int ground)
{
    unsigned char cols[BW_NCOL + 1];
    bw_real vals[BW_NCOL + 1];
    int i, j, k, n;
    for (i = 0; i < N; i++) {
        double *t = rc->tmp[i];
        n = f_row(e, r, ground, i, cols, vals);
        for (j = 0; j < N; j++)
            t[j] = 0.0;
        for (k = 0; k < n; k++) {
            const double v = (double)vals[k], *p = rc->Pi[cols[k]];
            for (j = 0; j < N; j++)
                t[j] += v * p[j];
        }
    }
    memcpy(rc->Pi, rc->tmp, sizeof rc->Pi);
}

/* SmootherRecorder.update: a scalar fusion (row h, 1/S, innovation, gain K) */
static void rec_update(bw_recorder_t *rc, const bw_real *h, double s_inv, double innov, const bw_real *kv)
{
    double hp[N];
    int i, j, k;
    for (j = 0; j < N; j++)
        hp[j] = 0.0;
    for (k = 0; k < N; k++)
        if (h[k] != BW_R(0.0)) {
            const double v = (double)h[k], *p = rc->Pi[k];
            for (j = 0; j < N; j++)
                hp[j] += v * p[j];
        }
    for (j = 0; j < N; j++)
        rc->g[j] += hp[j] * (s_inv * innov);
    for (i = 0; i < N; i++) {
        const double a = hp[i] * s_inv, ki = (double)kv[i];
        for (j = 0; j < N; j++) {
            rc->G[i][j] += a * hp[j];
            rc->Pi[i][j] -= ki * hp[j];
        }
    }
}

/* SmootherRecorder.update3: a vector fusion of three rows (H, S^-1, innovations, gain K) */
static void rec_update3(bw_recorder_t *rc, const bw_real H[3][N], const bw_real si[3][3], const bw_real inn[3],
                        const bw_real k3[N][3])
{
    double hp[3][N], s3[3][N], v3[3];
    int a, b, i, j, k;
    for (a = 0; a < 3; a++) {
        for (j = 0; j < N; j++)
            hp[a][j] = 0.0;
        for (k = 0; k < N; k++)
            if (H[a][k] != BW_R(0.0)) {
                const double v = (double)H[a][k], *p = rc->Pi[k];
                for (j = 0; j < N; j++)
                    hp[a][j] += v * p[j];
            }
    }
    for (a = 0; a < 3; a++) {
        v3[a] = 0.0;
        for (b = 0; b < 3; b++)
            v3[a] += (double)si[a][b] * (double)inn[b];
    }
    for (a = 0; a < 3; a++)
        for (j = 0; j < N; j++)
            s3[a][j] = (double)si[a][0] * hp[0][j] + (double)si[a][1] * hp[1][j] + (double)si[a][2] * hp[2][j];
    for (j = 0; j < N; j++)
        rc->g[j] += v3[0] * hp[0][j] + v3[1] * hp[1][j] + v3[2] * hp[2][j];
    for (i = 0; i < N; i++) {
        const double h0 = hp[0][i], h1 = hp[1][i], h2 = hp[2][i];
        const double c0 = (double)k3[i][0], c1 = (double)k3[i][1], c2 = (double)k3[i][2];
        for (j = 0; j < N; j++) {
            rc->G[i][j] += h0 * s3[0][j] + h1 * s3[1][j] + h2 * s3[2][j];
            rc->Pi[i][j] -= c0 * hp[0][j] + c1 * hp[1][j] + c2 * hp[2][j];
        }
    }
}
#endif

/* P <- F P F^T over F's non-zeros; the result written symmetric (both triangles, bit-identical) */
static void propagate_covariance(bw_ekf_t *e, const bw_real r[9], int ground)
{
    unsigned char rc[N][BW_NCOL + 1], *cols;
    int rn[N], i, j, k, n;
    bw_real rv[N][BW_NCOL + 1], acc[N], *vals;
    for (i = 0; i < N; i++) /* F's rows, once */
        rn[i] = f_row(e, r, ground, i, rc[i], rv[i]);
    for (i = 0; i < N; i++) { /* T = F P, a row of T from the rows of P that row i of F takes */
        bw_real *t = e->T[i];
        n = rn[i], cols = rc[i], vals = rv[i];
        if (n == 0) {
            for (j = 0; j < N; j++)
                t[j] = BW_R(0.0);
            continue;
        }
        if (n == 1 && vals[0] == BW_R(1.0)) { /* an identity row: a copy (1 x P, exactly) */
            memcpy(t, e->P[cols[0]], sizeof e->T[i]);
            continue;
        }
        {
            const bw_real v = vals[0], *pr = e->P[cols[0]];
            for (j = 0; j < N; j++)
                t[j] = v * pr[j];
        }
        for (k = 1; k < n; k++) {
            const bw_real v = vals[k], *pr = e->P[cols[k]];
            for (j = 0; j < N; j++)
                t[j] += v * pr[j];
        }
    }
    for (j = 0; j < N; j++) { /* P = T F^T: column j from the columns of T that row j of F takes */
        n = rn[j], cols = rc[j], vals = rv[j];
        if (n == 1 && vals[0] == BW_R(1.0)) {
            const int c = cols[0];
            for (i = 0; i <= j; i++)
                e->P[i][j] = e->P[j][i] = e->T[i][c];
            continue;
        }
        for (i = 0; i <= j; i++)
            acc[i] = BW_R(0.0);
        for (k = 0; k < n; k++) {
            const bw_real v = vals[k];
            const int c = cols[k];
            for (i = 0; i <= j; i++)
                acc[i] += e->T[i][c] * v;
        }
        for (i = 0; i <= j; i++)
            e->P[i][j] = e->P[j][i] = acc[i];
    }
}

void bw_ekf_predict(bw_ekf_t *e, bw_real gx, bw_real gy, bw_real gz, bw_real rho)
{
    bw_real *x = e->x;
    const bw_real dt = e->dt;
    const bw_real pn = x[0], pe = x[1], pd = x[2], vn = x[3], ve = x[4], vd = x[5];
    const bw_real wn = x[12], we = x[13], rn = x[14], re = x[15], k = x[16];
    bw_real q0 = e->q[0], q1 = e->q[1], q2 = e->q[2], q3 = e->q[3], n, r[9];
    bw_real wx = gx - x[BW_GB_X], wy = gy - x[BW_GB_Y], wz = gz - x[BW_GB_Z];
    bw_real ang = BW_SQRT(wx * wx + wy * wy + wz * wz) * dt;
    int ground, i;
    if (ang > BW_R(1e-12)) {
        bw_real s = BW_SIN(BW_R(0.5) * ang) / ang * dt, cc = BW_COS(BW_R(0.5) * ang);
        bw_real ax = wx * s, ay = wy * s, az = wz * s;
        bw_real a0 = q0 * cc - q1 * ax - q2 * ay - q3 * az;
        bw_real a1 = q0 * ax + q1 * cc + q2 * az - q3 * ay;
        bw_real a2 = q0 * ay - q1 * az + q2 * cc + q3 * ax;
        bw_real a3 = q0 * az + q1 * ay - q2 * ax + q3 * cc;
        q0 = a0, q1 = a1, q2 = a2, q3 = a3;
    }
    n = BW_R(1.0) / BW_SQRT(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3);
    e->q[0] = q0 * n, e->q[1] = q1 * n, e->q[2] = q2 * n, e->q[3] = q3 * n;
    bw_rotation(e->q, r);
    ground = e->mode == BW_MODE_GROUND;
    if (ground) {
        x[BW_VEL_N] = x[BW_VEL_E] = x[BW_VEL_D] = BW_R(0.0);
    } else {
        const bw_real s[BW_NCOL] = {pn, pe, pd, vn, ve, vd, wn, we, rn, re, k};
        bw_forces_t *f = &e->forces;
        bw_accelerations(&e->m, rho, s, e->mode == BW_MODE_TAUT, f);
        x[BW_POS_N] = pn + (vn + BW_R(0.5) * f->an * dt) * dt;
        x[BW_POS_E] = pe + (ve + BW_R(0.5) * f->ae * dt) * dt;
        x[BW_POS_D] = pd + (vd + BW_R(0.5) * f->ad * dt) * dt;
        x[BW_VEL_N] = vn + f->an * dt;
        x[BW_VEL_E] = ve + f->ae * dt;
        x[BW_VEL_D] = vd + f->ad * dt;
        if (e->learn_drag) /* d(vel)/d(x) = I + (d a / d x) dt: f_row */
            e->drag_correlated = 1;
    }
    /* the wind: integrated Ornstein-Uhlenbeck (tuning.py) */
    x[BW_WIND_N] = wn + rn * dt;
    x[BW_WIND_E] = we + re * dt;
    x[BW_WRATE_N] = rn * e->rate_decay;
    x[BW_WRATE_E] = re * e->rate_decay;
    propagate_covariance(e, r, ground);
    for (i = 0; i < N; i++)
        e->P[i][i] += ground ? e->qd_ground[i] : e->q_flight[i];
#ifdef BW_HOST_RECORDER
    if (REC(e))
        rec_predict(REC(e), e, r, ground);
#endif
}

void bw_ekf_adapt_wind_noise(bw_ekf_t *e, bw_real mean_speed_mps, bw_real excess)
{
    bw_real u = BW_MIN(BW_MAX(mean_speed_mps, BW_R(0.5)), BW_R(20.0));
    bw_real ratio = u / e->u0;
    bw_real q = e->q_rate0 * BW_POW(ratio, BW_R(14.0) / BW_R(3.0)) * excess;
    bw_real t = e->wp_tau_s / ratio;
    e->q_flight[BW_WRATE_N] = e->q_flight[BW_WRATE_E] = q;
    e->qd_ground[BW_WRATE_N] = e->qd_ground[BW_WRATE_E] = q;
    e->rate_decay = BW_EXP(-e->dt * ratio / e->wp_tau_s);
    e->q_walk_step = q * (t * t);
}

void bw_ekf_inflate(bw_ekf_t *e, bw_real steps)
{
    int i;
    const bw_real *q = e->mode == BW_MODE_GROUND ? e->q_ground : e->q_flight;
    for (i = 0; i < N; i++) {
        bw_real d = (i == BW_WIND_N || i == BW_WIND_E) ? e->q_walk_step * steps : q[i] * steps;
        e->P[i][i] += d;
    }
    bw_ekf_fix_covariance(e);
}

/* ekf.py gap_attitude_var: the attitude's variance (rad^2, each axis) a gap of held_s costs: a rate that changed
 * linearly from the held one to the new one turned the balloon by |dw| held_s / 2 more; beyond max_gap_s (lost) the
 * held rate may be wrong by all of itself. Out of line: inlined into the step it cost the median 40 instructions */
BW_NOINLINE bw_real bw_gap_attitude_var(const bw_real *last, bw_real gx, bw_real gy, bw_real gz, bw_real held_s,
                                        int lost)
{
    const bw_real dx = last[0] - gx, dy = last[1] - gy, dz = last[2] - gz;
    bw_real d2 = BW_R(0.25) * (dx * dx + dy * dy + dz * dz);
    if (lost)
        d2 = BW_MAX(d2, BW_MAX(last[0] * last[0] + last[1] * last[1] + last[2] * last[2], gx * gx + gy * gy + gz * gz));
    return d2 * held_s * held_s;
}

void bw_ekf_inflate_attitude(bw_ekf_t *e, bw_real var)
{
    int i;
    for (i = BW_ATT_N; i <= BW_ATT_D; i++) /* to its bound at most (ekf.py inflate_attitude) */
        e->P[i][i] = BW_MIN(e->P[i][i] + var, e->var_max[i]);
    bw_ekf_fix_covariance(e);
}

void bw_ekf_begin_update(bw_ekf_t *e)
{
    memset(e->dx, 0, sizeof e->dx);
}

int bw_ekf_fuse_gain(bw_ekf_t *e, bw_real innov, bw_real r, bw_status_t *st, bw_real gate, int recover,
                     bw_real att_gain)
{
    int nz[N], nn = 0, i, j, k;
    bw_real hdx = BW_R(0.0), s = BW_R(0.0), ratio, kv[N];
    if (!(gate > BW_R(0.0)))
        gate = e->m.gate_sigma;
    for (i = 0; i < N; i++)
        if (e->h[i] != BW_R(0.0))
            nz[nn++] = i;
    for (k = 0; k < nn; k++)
        hdx += e->h[nz[k]] * e->dx[nz[k]];
    innov -= hdx;
    for (i = 0; i < N; i++) {
        bw_real v = BW_R(0.0);
        for (k = 0; k < nn; k++)
            v += e->P[i][nz[k]] * e->h[nz[k]];
        e->ph[i] = v;
    }
    for (k = 0; k < nn; k++)
        s += e->h[nz[k]] * e->ph[nz[k]];
    s += r;
    st->innov = innov;
    st->innov_var = s;
    st->time_test_us = e->time_us;
    if (!(s > BW_R(0.0) && isfinite(innov))) {
        st->rejected += 1;
        st->consecutive_rejects += 1;
        return 0;
    }
    ratio = innov * innov / (gate * gate * s);
    st->test_ratio = ratio;
    if (ratio > BW_R(1.0)) {
        st->rejected += 1;
        st->consecutive_rejects += 1;
        if (!recover || st->consecutive_rejects < (st->recover_after ? st->recover_after : e->recover_after))
            return 0;
        /* persistently inconsistent: fuse with the noise inflated to put the innovation on the gate */
        s = innov * innov / (gate * gate);
        st->fused -= 1;
    }
    {
        bw_real inv = BW_R(1.0) / s;
        for (i = 0; i < N; i++)
            kv[i] = e->ph[i] * inv;
    }
    for (i = 0; i < N; i++) {
        const bw_real ki = kv[i];
        for (j = i; j < N; j++)
            e->P[i][j] = e->P[j][i] = e->P[i][j] - ki * e->ph[j];
    }
    if (att_gain < BW_R(1.0)) {
        /* K' = D K: P for the gain used (Joseph form) differs from P - K H P only in the attitude's block, by
         * (1 - g)^2 K H P (ekf.py fuse) */
        const bw_real c = (BW_R(1.0) - att_gain) * (BW_R(1.0) - att_gain);
        for (i = BW_ATT_N; i <= BW_ATT_D; i++) {
            for (j = i; j <= BW_ATT_D; j++) {
                bw_real v = c * kv[i] * e->ph[j];
                e->P[i][j] += v;
                if (j != i)
                    e->P[j][i] += v;
            }
        }
        for (i = BW_ATT_N; i <= BW_ATT_D; i++)
            kv[i] *= att_gain;
    }
#ifdef BW_HOST_RECORDER
    if (REC(e))
        rec_update(REC(e), e->h, 1.0 / (double)s, (double)innov, kv);
#endif
    for (i = 0; i < N; i++)
        e->dx[i] += kv[i] * innov;
    st->fused += 1;
    st->consecutive_rejects = 0;
    st->time_last_fuse_us = e->time_us;
    return 1;
}

int bw_ekf_fuse3(bw_ekf_t *e, bw_real i0, bw_real i1, bw_real i2, bw_real r, bw_status_t st[3],
                 bw_real r2_extra, bw_real tilt_gain, bw_real heading_gain, const bw_real axis[3], bw_real axis_var)
{
    int nz[N], nn = 0, i, j, k, a, ok = 1, moved;
    bw_real s[3][3], si[3][3], k3[N][3], hc[3][N], inn[3], var[3], gate2, worst = BW_R(0.0), scale = BW_R(1.0);
    bw_real a00, a01, a02, det, inv;
    for (j = 0; j < N; j++)
        if (e->H3[0][j] != BW_R(0.0) || e->H3[1][j] != BW_R(0.0) || e->H3[2][j] != BW_R(0.0))
            nz[nn++] = j;
    for (k = 0; k < nn && e->dx[nz[k]] == BW_R(0.0); k++) {
    }
    moved = k < nn; /* the first fusion of a step meets dx = 0: H dx is exactly 0 */
    for (a = 0; a < 3; a++) {
        bw_real v = BW_R(0.0);
        for (k = 0; moved && k < nn; k++)
            v += e->H3[a][nz[k]] * e->dx[nz[k]];
        inn[a] = v;
    }
    i0 -= inn[0], i1 -= inn[1], i2 -= inn[2];
    for (k = 0; k < nn; k++)
        hc[0][k] = e->H3[0][nz[k]], hc[1][k] = e->H3[1][nz[k]], hc[2][k] = e->H3[2][nz[k]];
    for (i = 0; i < N; i++) {
        const bw_real *row = e->P[i];
        bw_real v0 = BW_R(0.0), v1 = BW_R(0.0), v2 = BW_R(0.0);
        for (k = 0; k < nn; k++) {
            const bw_real pv = row[nz[k]];
            v0 += pv * hc[0][k];
            v1 += pv * hc[1][k];
            v2 += pv * hc[2][k];
        }
        e->pht[i][0] = v0, e->pht[i][1] = v1, e->pht[i][2] = v2;
    }
    for (a = 0; a < 3; a++)
        for (j = a; j < 3; j++) { /* H P H^T: symmetric, the upper half computed */
            bw_real v = BW_R(0.0);
            for (k = 0; k < nn; k++)
                v += e->H3[a][nz[k]] * e->pht[nz[k]][j];
            s[a][j] = s[j][a] = v;
        }
    s[0][0] += r;
    s[1][1] += r;
    s[2][2] += r + r2_extra;
    s[0][1] = s[1][0] = BW_R(0.5) * (s[0][1] + s[1][0]);
    s[0][2] = s[2][0] = BW_R(0.5) * (s[0][2] + s[2][0]);
    s[1][2] = s[2][1] = BW_R(0.5) * (s[1][2] + s[2][1]);
    if (axis_var > BW_R(0.0)) { /* ekf.py fuse3: axis_var axis axis^T more */
        const bw_real v0 = axis_var * axis[0], v1 = axis_var * axis[1];
        s[0][0] += v0 * axis[0];
        s[1][1] += v1 * axis[1];
        s[2][2] += axis_var * axis[2] * axis[2];
        s[0][1] = s[1][0] = s[0][1] + v0 * axis[1];
        s[0][2] = s[2][0] = s[0][2] + v0 * axis[2];
        s[1][2] = s[2][1] = s[1][2] + v1 * axis[2];
    }
    gate2 = e->m.gate2;
    inn[0] = i0, inn[1] = i1, inn[2] = i2;
    var[0] = s[0][0], var[1] = s[1][1], var[2] = s[2][2];
    for (a = 0; a < 3; a++) {
        st[a].innov = inn[a];
        st[a].innov_var = var[a];
        st[a].time_test_us = e->time_us;
        if (!(var[a] > BW_R(0.0) && isfinite(inn[a]))) {
            ok = 0;
            continue;
        }
        st[a].test_ratio = inn[a] * inn[a] / (gate2 * var[a]);
        worst = BW_MAX(worst, st[a].test_ratio);
    }
    /* cofactor inverse of the symmetric 3x3 */
    a00 = s[1][1] * s[2][2] - s[1][2] * s[1][2];
    a01 = s[0][2] * s[1][2] - s[0][1] * s[2][2];
    a02 = s[0][1] * s[1][2] - s[0][2] * s[1][1];
    det = s[0][0] * a00 + s[0][1] * a01 + s[0][2] * a02;
    if (!ok || !(det > BW_R(0.0) && isfinite(det))) {
        for (a = 0; a < 3; a++) {
            st[a].rejected += 1;
            st[a].consecutive_rejects += 1;
        }
        return 0;
    }
    if (worst > BW_R(1.0)) {
        for (a = 0; a < 3; a++) {
            st[a].rejected += 1;
            st[a].consecutive_rejects += 1;
        }
        if (st[0].consecutive_rejects < (st[0].recover_after ? st[0].recover_after : e->recover_after))
            return 0;
        scale = BW_R(1.0) / worst; /* persistently off: the model, not the sensor; walk back, no jump */
        for (a = 0; a < 3; a++)
            st[a].fused -= 1;
    }
    inv = scale / det;
    si[0][0] = a00 * inv;
    si[0][1] = si[1][0] = a01 * inv;
    si[0][2] = si[2][0] = a02 * inv;
    si[1][1] = (s[0][0] * s[2][2] - s[0][2] * s[0][2]) * inv;
    si[1][2] = si[2][1] = (s[0][1] * s[0][2] - s[0][0] * s[1][2]) * inv;
    si[2][2] = (s[0][0] * s[1][1] - s[0][1] * s[0][1]) * inv;
    for (i = 0; i < N; i++) {
        bw_real d;
        for (a = 0; a < 3; a++)
            k3[i][a] = e->pht[i][0] * si[0][a] + e->pht[i][1] * si[1][a] + e->pht[i][2] * si[2][a];
        d = k3[i][0] * inn[0] + k3[i][1] * inn[1] + k3[i][2] * inn[2];
        e->dx[i] += d;
    }
    /* K' = D K (ekf.py fuse3): the tilt's rows take tilt_gain of the correction, the heading's and the bias's
     * heading_gain (only the tilt's while the heading's gain is whole) */
    if (tilt_gain < BW_R(1.0) || heading_gain < BW_R(1.0))
        for (i = BW_ATT_N; i <= (heading_gain < BW_R(1.0) ? BW_GB_Z : BW_ATT_E); i++)
            e->dx[i] -= (BW_R(1.0) - (i <= BW_ATT_E ? tilt_gain : heading_gain))
                        * (k3[i][0] * inn[0] + k3[i][1] * inn[1] + k3[i][2] * inn[2]);
#ifdef BW_HOST_RECORDER
    if (REC(e)) { /* the gain used: the attitude's and the bias's rows times their gains (ekf.py hands it K') */
        bw_real kr[N][3];
        memcpy(kr, k3, sizeof kr);
        for (i = BW_ATT_N; i <= BW_GB_Z; i++) {
            bw_real g = i >= BW_ATT_D ? heading_gain : tilt_gain;
            kr[i][0] *= g, kr[i][1] *= g, kr[i][2] *= g;
        }
        rec_update3(REC(e), (const bw_real(*)[N])e->H3, (const bw_real(*)[3])si, inn, (const bw_real(*)[3])kr);
    }
#endif
    for (i = 0; i < N; i++) {
        const bw_real k0 = k3[i][0], k1 = k3[i][1], k2 = k3[i][2];
        for (j = i; j < N; j++)
            e->P[i][j] = e->P[j][i] = e->P[i][j] - (k0 * e->pht[j][0] + k1 * e->pht[j][1] + k2 * e->pht[j][2]);
    }
    if (tilt_gain < BW_R(1.0) || heading_gain < BW_R(1.0)) {
        /* P for the gain used (Joseph form) differs from P - K H P only in the attitude and gyro bias block, by
         * (1 - d_i) (1 - d_j) K H P (the tilt's d_i tilt_gain, the heading's and the bias's heading_gain) */
        const bw_real t = BW_R(1.0) - tilt_gain, h = BW_R(1.0) - heading_gain;
        const bw_real c[6] = {t, t, h, h, h, h}; /* 1 - d_i */
        const int last = heading_gain < BW_R(1.0) ? BW_GB_Z : BW_ATT_E; /* the tilt's block alone at full heading */
        for (i = BW_ATT_N; i <= last; i++)
            for (j = i; j <= last; j++) {
                bw_real v = c[i - BW_ATT_N] * c[j - BW_ATT_N]
                            * (k3[i][0] * e->pht[j][0] + k3[i][1] * e->pht[j][1] + k3[i][2] * e->pht[j][2]);
                e->P[i][j] += v;
                if (j != i)
                    e->P[j][i] += v;
            }
    }
    for (a = 0; a < 3; a++) {
        st[a].fused += 1;
        st[a].consecutive_rejects = 0;
        st[a].time_last_fuse_us = e->time_us;
    }
    return 1;
}

static void inhibit(bw_ekf_t *e, int i)
{
    int j;
    bw_real v = e->P[i][i];
    e->dx[i] = BW_R(0.0);
#ifdef BW_HOST_RECORDER
    if (REC(e))
        bw_recorder_broken(REC(e)); /* not a fusion: the smoother's chain is cut here */
#endif
    for (j = 0; j < N; j++)
        e->P[i][j] = e->P[j][i] = BW_R(0.0);
    e->P[i][i] = v;
}

/* ekf.py in_conflict: a prior and a datum d from it more than conflict_sigma (> 0) sigma of their difference apart */
static int in_conflict(bw_real prior_var, bw_real data_var, bw_real d, bw_real conflict_sigma)
{
    return conflict_sigma > BW_R(0.0) && d * d > conflict_sigma * conflict_sigma * (prior_var + data_var);
}

/* ekf.py weighed_variance: a prior weighed with one datum d from it, their combination's variance, or in conflict
 * their equal mixture's */
bw_real bw_weighed_variance(bw_real prior_var, bw_real data_var, bw_real d, bw_real conflict_sigma)
{
    if (in_conflict(prior_var, data_var, d, conflict_sigma))
        return BW_R(0.5) * (prior_var + data_var) + BW_R(0.25) * d * d;
    return BW_R(1.0) / (BW_R(1.0) / prior_var + BW_R(1.0) / data_var);
}

/* ekf.py weigh_information: state i as the prior combined with one measurement data of variance data_var, plus
 * walked_var (its random walk since); correlations cut; a reset of kind. Where conflict_sigma > 0 and the two differ
 * by more than that many sigma of their difference, their equal mixture */
void bw_ekf_weigh_information(bw_ekf_t *e, int i, bw_real prior, bw_real prior_var, bw_real data, bw_real data_var,
                              bw_real walked_var, int kind, bw_real conflict_sigma)
{
    bw_real v, d = data - prior;
    if (!(prior_var > BW_R(0.0) && data_var > BW_R(0.0)))
        return;
    inhibit(e, i);
    v = bw_weighed_variance(prior_var, data_var, d, conflict_sigma);
    if (in_conflict(prior_var, data_var, d, conflict_sigma))
        e->x[i] = prior + BW_R(0.5) * d;
    else
        e->x[i] = v * (prior / prior_var + data / data_var);
    e->P[i][i] = v + walked_var;
    bw_ekf_reset(e, kind);
}

/* ekf.py cap_information: what the data told state i since the prior is worth at most a measurement of
 * variance data_var_min (a model error taken for information is given back; a datum that contradicts its prior
 * beyond conflict_sigma at that weight makes their mixture at once, capped or not); the data's own estimate in *data
 * and the variance it claimed returned (0, 0: it told nothing) */
bw_real bw_ekf_cap_information(bw_ekf_t *e, int i, bw_real prior, bw_real prior_var, bw_real data_var_min, int kind,
                               bw_real conflict_sigma, bw_real *data)
{
    bw_real var = e->P[i][i], info, weight;
    info = var > BW_R(0.0) && prior_var > BW_R(0.0) ? BW_R(1.0) / var - BW_R(1.0) / prior_var : BW_R(0.0);
    *data = BW_R(0.0);
    if (!(info > BW_R(0.0)))
        return BW_R(0.0);
    *data = (e->x[i] / var - prior / prior_var) / info;
    weight = BW_MAX(BW_R(1.0) / info, data_var_min); /* the cap's: what the data claimed, at most data_var_min's */
    if (info > BW_R(1.0) / data_var_min || in_conflict(prior_var, weight, *data - prior, conflict_sigma))
        bw_ekf_weigh_information(e, i, prior, prior_var, *data, weight, BW_R(0.0), kind, conflict_sigma);
    return BW_R(1.0) / info;
}

int bw_ekf_end_update(bw_ekf_t *e)
{
    int i;
    bw_real *x = e->x, sx = BW_R(0.0), sp = BW_R(0.0);
    if (!e->learn_drag && e->drag_correlated) {
        inhibit(e, BW_DRAG);
        e->drag_correlated = 0;
    }
    for (i = 0; i < N; i++)
        x[i] += e->dx[i];
    if (x[BW_ATT_N] != BW_R(0.0) || x[BW_ATT_E] != BW_R(0.0) || x[BW_ATT_D] != BW_R(0.0)) {
        bw_real q0 = e->q[0], q1 = e->q[1], q2 = e->q[2], q3 = e->q[3];
        bw_real hn = BW_R(0.5) * x[BW_ATT_N], he = BW_R(0.5) * x[BW_ATT_E], hd = BW_R(0.5) * x[BW_ATT_D];
        /* q <- dq (x) q with dq = (1, d/2) in NED */
        bw_real a0 = q0 - hn * q1 - he * q2 - hd * q3;
        bw_real a1 = q1 + hn * q0 + he * q3 - hd * q2;
        bw_real a2 = q2 - hn * q3 + he * q0 + hd * q1;
        bw_real a3 = q3 + hn * q2 - he * q1 + hd * q0;
        bw_real n = BW_R(1.0) / BW_SQRT(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3);
        e->q[0] = a0 * n, e->q[1] = a1 * n, e->q[2] = a2 * n, e->q[3] = a3 * n;
        x[BW_ATT_N] = x[BW_ATT_E] = x[BW_ATT_D] = BW_R(0.0);
    }
    if (x[BW_DRAG] < (bw_real)BW_DRAG_SCALE_MIN)
        x[BW_DRAG] = (bw_real)BW_DRAG_SCALE_MIN;
    bw_ekf_fix_covariance(e);
    /* a NaN/inf anywhere in P reaches its diagonal within one prediction */
    for (i = 0; i < N; i++) {
        sx += x[i];
        sp += e->P[i][i];
    }
    return isfinite(sx) && isfinite(sp);
}

void bw_ekf_fix_covariance(bw_ekf_t *e)
{
    int i, j;
    bw_real scale[N], mn;
    /* (the reference symmetrises here: P is kept exactly symmetric, every write sets both triangles) */
    for (i = 0; i < N; i++)
        scale[i] = e->var_max[i] / e->P[i][i];
    mn = scale[0];
    for (i = 1; i < N; i++)
        if (scale[i] < mn || scale[i] != scale[i])
            mn = mn != mn ? mn : scale[i];
    if (mn < BW_R(1.0)) {
        for (i = 0; i < N; i++)
            scale[i] = BW_SQRT(BW_MIN(scale[i], BW_R(1.0)));
        for (i = 0; i < N; i++) {
            for (j = i; j < N; j++)
                e->P[i][j] = e->P[j][i] = e->P[i][j] * scale[i] * scale[j];
            if (e->P[i][i] > e->var_max[i]) /* float rounds d^2 P an ulp past the bound */
                e->P[i][i] = e->var_max[i];
        }
    }
    for (i = 0; i < N; i++)
        if (e->P[i][i] < (bw_real)BW_VAR_MIN)
            e->P[i][i] = (bw_real)BW_VAR_MIN;
}

bw_real bw_ekf_wind_accuracy(const bw_ekf_t *e)
{
    return BW_SQRT(BW_MAX(BW_R(0.0), e->P[BW_WIND_N][BW_WIND_N] + e->P[BW_WIND_E][BW_WIND_E]));
}
