/* The accelerometer: its specific-force rows (paper Eq. 9) and when and how loud to fuse them
 * (firmware_py/estimator/aid_sources/accel.py). */
#include <string.h>

#include "internal.h"

/* tuning.py vertical_air_samples: how many samples of dt_s one independent sample of the vertical air is worth
 * (2 L_w / U over dt_s), at least one */
static bw_real vertical_air_samples(bw_real dt_s, bw_real mean_mps)
{
    const bw_real u = BW_MAX(mean_mps, (bw_real)BW_MIN_WIND_MPS);
    return BW_MAX(BW_R(1.0), BW_R(2.0) * (bw_real)BW_KAIMAL_VERTICAL_LENGTH_M / (u * dt_s));
}

/* accel.py fuse_bias_magnitude: the body-z bias on the tether, from the innovations along the predicted specific
 * force (a tilt moves them across it, along only to second order); its status is the call's own (Python keeps one
 * for diagnosis) */
static void fuse_bias_magnitude(bw_ekf_t *e, bw_real fx, bw_real fy, bw_real fz, const bw_status_t st[3], bw_real var)
{
    bw_status_t bias;
    const bw_real nx = st[0].innov, ny = st[1].innov, nz = st[2].innov;
    const bw_real px = fx - nx, py = fy - ny, pz = fz - nz;
    const bw_real pred = BW_SQRT(px * px + py * py + pz * pz);
    bw_real inv;
    if (!(pred > BW_R(0.5) * (bw_real)BW_G0)) /* no gravity to read the length against */
        return;
    inv = BW_R(1.0) / pred;
    memset(&bias, 0, sizeof bias);
    memset(e->h, 0, sizeof e->h);
    e->h[BW_ABIAS_Z] = pz * inv;
    bw_ekf_fuse(e, (nx * px + ny * py + nz * pz) * inv, var, &bias, BW_R(0.0), 0);
}

/* accel.py fuse_level: a tethered balloon does not accelerate on average, so the horizontal specific force in NED
 * (fn, fe) is gravity's tilt alone, g d_E and -g d_N (d the attitude's error); no force model enters. Its status is
 * the call's own (Python keeps one for diagnosis) */
static void fuse_level(bw_ekf_t *e, bw_real fn, bw_real fe, bw_real var)
{
    bw_status_t level;
    memset(&level, 0, sizeof level);
    memset(e->h, 0, sizeof e->h);
    e->h[BW_ATT_E] = (bw_real)BW_G0;
    bw_ekf_fuse(e, fn, var, &level, (bw_real)BW_UNGATED, 0);
    memset(e->h, 0, sizeof e->h);
    e->h[BW_ATT_N] = -(bw_real)BW_G0;
    bw_ekf_fuse(e, fe, var, &level, (bw_real)BW_UNGATED, 0);
}

/* accel.py follow_horizontal_bias: the body x, y biases walked since the field was learnt, from the horizontal
 * innovation (NED) the accelerometer's fusion left, its share along the field's horizontal direction, back in the body
 * frame (r: R), weight w (interval / BW_ACCEL_HBIAS_S x the share that counts); nothing while the field is unknown or
 * from a step that is not finite: 0 then, and where the guard holds the bias (the step did not follow) */
static int follow_horizontal_bias(bw_real hbias[2], bw_real innov_n, bw_real innov_e, const bw_real field[3],
                                  const bw_real r[9], bw_real w)
{
    const bw_real lim = (bw_real)BW_ACCEL_HBIAS_MAX_MPS2, bn = field[0], be = field[1];
    const bw_real bh2 = bn * bn + be * be;
    bw_real s, vn, ve, b;
    int i, free = 1;
    if (!(bh2 > BW_R(0.0)))
        return 0;
    s = w * (innov_n * bn + innov_e * be) / bh2;
    if (!isfinite(s)) /* a numeric reset's step */
        return 0;
    vn = s * bn, ve = s * be;
    for (i = 0; i < 2; i++) { /* row i of R^T */
        b = hbias[i] + r[i] * vn + r[3 + i] * ve;
        hbias[i] = BW_MAX(-lim, BW_MIN(lim, b));
        free = free && hbias[i] == b;
    }
    return free;
}

static void fuse_accel(bw_estimator_t *est, bw_real fx, bw_real fy, bw_real fz, bw_real var, bw_real var_z_extra,
                       bw_real misfit, bw_real nominal, bw_real radial[3], bw_real radial_var)
{
    bw_ekf_t *e = &est->ekf;
    const bw_forces_t *f = &e->forces;
    int ground = e->mode == BW_MODE_GROUND, i, j;
    bw_real r[9], yn, ye, yd, pred[3], tilt;
    bw_rotation(e->q, r);
    if (ground)
        yn = BW_R(0.0), ye = BW_R(0.0), yd = -(bw_real)BW_G0;
    else
        yn = f->an, ye = f->ae, yd = f->ad - (bw_real)BW_G0;
    /* H3's other columns are zero (the estimator's start and the magnetometer's rows, aid_mag.c, which zero them and
     * write the attitude's alone): these rows set every column they write in one mode and not in the other */
    for (i = 0; i < 3; i++) {
        bw_real cn = r[i], ce = r[3 + i], cd = r[6 + i]; /* row i of R^T */
        pred[i] = cn * yn + ce * ye + cd * yd;
        if (e->mode == BW_MODE_TAUT) /* accel.py fuse_accel: R^T p */
            radial[i] = cn * e->x[BW_POS_N] + ce * e->x[BW_POS_E] + cd * e->x[BW_POS_D];
        /* d/d att: R^T [y x] */
        e->H3[i][BW_ATT_N] = ce * yd - cd * ye;
        e->H3[i][BW_ATT_E] = cd * yn - cn * yd;
        e->H3[i][BW_ATT_D] = cn * ye - ce * yn;
        for (j = 0; j < BW_NCOL; j++) /* d/d (model states): R^T (d a / d x); none on the ground */
            e->H3[i][BW_MODEL_COLS[j]] =
                ground ? BW_R(0.0) : cn * f->ja[j] + ce * f->ja[BW_NCOL + j] + cd * f->ja[2 * BW_NCOL + j];
        e->H3[i][BW_ABIAS_Z] = BW_R(0.0);
    }
    if (!ground && !e->learn_drag)
        e->H3[0][BW_DRAG] = e->H3[1][BW_DRAG] = e->H3[2][BW_DRAG] = BW_R(0.0);
    if (ground) /* learnt at rest, where g is the only force */
        e->H3[2][BW_ABIAS_Z] = BW_R(1.0);
    pred[2] += e->x[BW_ABIAS_Z];
    /* accel.py: in flight the tilt takes only what a correlated model error allows (BW_ACCEL_MODEL_CORR_S), the
     * heading and the gyro bias less in proportion to the misfit, at least BW_ACCEL_HEADING_GAIN_MIN */
    tilt = ground ? BW_R(1.0) : BW_MIN(BW_R(1.0), BW_SQRT(e->dt / (bw_real)BW_ACCEL_MODEL_CORR_S));
    bw_ekf_fuse3(e, fx - pred[0], fy - pred[1], fz - pred[2], var, est->accel_status, var_z_extra, tilt,
                 BW_R(1.0) - misfit * (BW_R(1.0) - (bw_real)BW_ACCEL_HEADING_GAIN_MIN), radial, radial_var);
    if (e->taut_phase == 0) {
        const bw_real step_s = (bw_real)est->sched.taut_every * e->dt;
        const bw_real walk = (bw_real)est->cfg->accel_bias_walk_mps2_rt_s;
        bw_real weight = BW_R(0.0); /* the horizontal bias's loop step, 0 where it did not follow */
        if (!ground) {
            /* accel.py: its slow horizontal innovation, NED, at the tether's rate, with the share that counts
             * (consistency.py slow_innovation_share) */
            const bw_status_t *st = est->accel_status;
            bw_real in, ie, fn, fe, dn, de;
            bw_real share = (BW_R(1.0) - misfit) * BW_SQRT(nominal / var);
            /* accel.py level_noise: the specific force in NED (its biases out), its mean and its variance about it
             * over BW_LEVEL_MEAN_S, per axis; the level rows' noise from it (fuse_level, on the tether) */
            const bw_real a = step_s / (bw_real)BW_LEVEL_MEAN_S;
            bw_horizontal_ned(r, st[0].innov, st[1].innov, st[2].innov, &in, &ie);
            bw_horizontal_ned(r, fx, fy, fz - e->x[BW_ABIAS_Z], &fn, &fe);
            if (est->level_var == BW_R(0.0)) { /* nothing followed yet: from this sample and the nominal noise */
                est->level_mean[0] = fn, est->level_mean[1] = fe;
                est->level_var = nominal;
            }
            est->level_mean[0] += a * (fn - est->level_mean[0]);
            est->level_mean[1] += a * (fe - est->level_mean[1]);
            dn = fn - est->level_mean[0], de = fe - est->level_mean[1];
            est->level_var += a * (BW_R(0.5) * (dn * dn + de * de) - est->level_var);
            bw_consistency_add_slow_tilt(&est->consistency, share * bw_field_tilt_reading(in, ie, est->field_ned),
                                         est->a_taut);
            if (e->mode == BW_MODE_TAUT) {
                const bw_real sensor = (bw_real)est->cfg->accel_mps2;
                const bw_real level_noise =
                    BW_MAX(est->level_var, sensor * sensor) * BW_R(2.0) * (bw_real)BW_LEVEL_CORR_S / step_s;
                bw_real w = isfinite(share) ? share * step_s / (bw_real)BW_ACCEL_HBIAS_S : BW_R(0.0);
                fuse_level(e, fn, fe, level_noise);
                fuse_bias_magnitude(e, fx, fy, fz, st,
                                    var + var_z_extra * vertical_air_samples(step_s, est->mean_speed));
                weight = follow_horizontal_bias(est->accel_hbias, in, ie, est->field_ned, r, w) ? w : BW_R(0.0);
            }
        }
        /* accel.py horizontal_bias_variance: it walks in every mode, the ground's too */
        est->accel_hbias_var = BW_MAX(BW_R(0.0), est->accel_hbias_var + walk * walk * step_s -
                                                     BW_R(2.0) * (bw_real)BW_ACCEL_HBIAS_RESIDUE * weight *
                                                         est->accel_hbias_var);
    }
}

/* accel.py accel_nominal_var: the accelerometer's nominal noise in the filter's mode */
bw_real bw_accel_nominal_var(const bw_estimator_t *est)
{
    const int32_t mode = est->ekf.mode;
    return mode == BW_MODE_GROUND ? est->accel_static_var : mode == BW_MODE_FREE ? est->accel_var : est->accel_taut_var;
}

void bw_control_accel(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az)
{
    const bw_ekf_t *e = &est->ekf;
    const bw_real nominal = bw_accel_nominal_var(est), a = est->innov_alpha;
    const int taut = e->mode == BW_MODE_TAUT;
    const bw_real var = BW_MAX(nominal, est->accel_innov2);
    const bw_real d2 = taut ? e->x[BW_POS_N] * e->x[BW_POS_N] + e->x[BW_POS_E] * e->x[BW_POS_E] +
                                  e->x[BW_POS_D] * e->x[BW_POS_D]
                            : BW_R(0.0);
    /* accel.py radial_noise: the rope's breathing along the radius is more noise there (per unit of |R^T p|^2) */
    const bw_real radial_var = d2 > BW_R(1.0) ? BW_MAX(BW_R(0.0), est->accel_radial_innov2 - var) / d2 : BW_R(0.0);
    bw_real radial[3] = {BW_R(0.0), BW_R(0.0), BW_R(0.0)}, i2, misfit, nis, ex;
    const bw_status_t *st = est->accel_status;
    int i;
    est->accel_var_excess = var - nominal;
    /* accel.py: the windowed NIS from BW_FLAG_NIS to twice that, the model stops explaining the accelerometer */
    misfit = bw_accel_misfit(est->consistency.nis[BW_ACCEL]);
    fuse_accel(est, ax - est->accel_hbias[0], ay - est->accel_hbias[1], az, var,
               e->mode != BW_MODE_GROUND ? est->vertical_gust_var : BW_R(0.0), misfit, nominal, radial, radial_var);
    i2 = st[0].innov * st[0].innov + st[1].innov * st[1].innov + st[2].innov * st[2].innov;
    est->accel_innov2 += a * (i2 / BW_R(3.0) - est->accel_innov2);
    if (d2 > BW_R(1.0)) {
        const bw_real ir = radial[0] * st[0].innov + radial[1] * st[1].innov + radial[2] * st[2].innov;
        est->accel_radial_innov2 += a * (ir * ir / d2 - est->accel_radial_innov2);
    } else if (!taut) {
        est->accel_radial_innov2 = est->accel_innov2;
    }
    if (e->mode != BW_MODE_GROUND) {
        /* the consistency monitor (accel.py control_accel): each axis against the nominal noise */
        ex = var - nominal, nis = BW_R(0.0);
        for (i = 0; i < 3; i++)
            nis += st[i].innov * st[i].innov /
                   BW_MAX(st[i].innov_var - (ex + radial_var * radial[i] * radial[i]), BW_R(1e-12));
        bw_consistency_add(&est->consistency, BW_ACCEL, nis / BW_R(3.0), est->a_accel);
    }
}
