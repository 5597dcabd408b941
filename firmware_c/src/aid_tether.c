/* The tether when taut: its placement, the radius, radial-rate and alignment rows, the taut
 * re-placement and the rope's shape (firmware_py/estimator/aid_sources/tether.py). */
#include <string.h>

#include "internal.h"

void bw_enter_taut(bw_estimator_t *est, bw_real height_m, int from_tilt)
{
    bw_ekf_t *e = &est->ekf;
    bw_real rho = est->rho;
    static const int reset_rows[10] = {BW_POS_N, BW_POS_E, BW_POS_D, BW_VEL_N, BW_VEL_E,
                                       BW_VEL_D, BW_WIND_N, BW_WIND_E, BW_WRATE_N, BW_WRATE_E};
    const bw_model_t *m = &e->m;
    bw_real *x = e->x, r[9];
    bw_real ell = e->rope_chord_m + m->radius_m;
    bw_real cos_t = BW_MIN(BW_MAX(height_m / ell, BW_R(0.05)), BW_R(1.0));
    bw_real sin_t = BW_SQRT(BW_R(1.0) - cos_t * cos_t);
    bw_real pn = x[BW_POS_N], pe = x[BW_POS_E], wn = x[BW_WIND_N], we = x[BW_WIND_E];
    bw_real horiz = BW_HYPOT(pn, pe), zn, ze, lean, wind, an, ae, lift, drag, k, speed, ev[3];
    int i, j;
    bw_rotation(e->q, r);
    zn = r[2], ze = r[5]; /* horizontal part of the body's down axis: it leans towards the anchor */
    lean = BW_HYPOT(zn, ze);
    wind = BW_HYPOT(wn, we);
    if (from_tilt && lean > (bw_real)BW_TAUT_LEAN_MIN_SIN)
        an = -zn / lean, ae = -ze / lean;
    else if (horiz > (bw_real)BW_TAUT_AZIMUTH_MIN_M)
        an = pn / horiz, ae = pe / horiz;
    else if (wind > BW_R(1e-3))
        an = wn / wind, ae = we / wind;
    else
        an = ae = BW_R(0.0);
    /* the wind's speed from the static balance along that azimuth, drag = (N_b - W) tan(theta) */
    lift = bw_lift_n(m, rho) - e->rope_weight_n;
    drag = BW_MAX(lift, BW_R(0.0)) * sin_t / cos_t;
    k = BW_MAX(x[BW_DRAG], BW_R(0.2));
    speed = drag > BW_R(0.0) ? BW_SQRT(drag / (k * rho * m->half_cd_area_m2)) : BW_R(0.0);
    x[BW_WIND_N] = speed * an, x[BW_WIND_E] = speed * ae;
    x[BW_WRATE_N] = x[BW_WRATE_E] = BW_R(0.0);
    x[BW_VEL_N] = x[BW_VEL_E] = x[BW_VEL_D] = BW_R(0.0);
    ev[0] = sin_t * an, ev[1] = sin_t * ae, ev[2] = -cos_t;
    for (i = 0; i < 3; i++)
        x[BW_POS_N + i] = ell * ev[i];
    for (i = 0; i < 10; i++)
        for (j = 0; j < BW_N; j++)
            e->P[reset_rows[i]][j] = e->P[j][reset_rows[i]] = BW_R(0.0);
    for (i = 0; i < 3; i++) {
        e->P[BW_POS_N + i][BW_POS_N + i] = (bw_real)(BW_TAUT_POS_SIGMA_M * BW_TAUT_POS_SIGMA_M);
        e->P[BW_VEL_N + i][BW_VEL_N + i] = (bw_real)(BW_TAUT_VEL_SIGMA_MPS * BW_TAUT_VEL_SIGMA_MPS);
    }
    e->P[BW_WIND_N][BW_WIND_N] = e->P[BW_WIND_E][BW_WIND_E] = (bw_real)(BW_TAUT_WIND_SIGMA_MPS * BW_TAUT_WIND_SIGMA_MPS);
    e->P[BW_WRATE_N][BW_WRATE_N] = e->P[BW_WRATE_E][BW_WRATE_E] = e->sigma_rate * e->sigma_rate;
    bw_ekf_reset(e, BW_RESET_TAUT);
    est->wind_taut_mps = BW_HYPOT(x[BW_WIND_N], x[BW_WIND_E]); /* the wind the placement put (the settling's scale) */
}


/* tether.py lean_variance: the attitude's variance along a horizontal component (cn, ce) of the body's down axis */
bw_real bw_lean_variance(const bw_ekf_t *e, bw_real cn, bw_real ce, bw_real zn, bw_real ze, bw_real zd)
{
    bw_real g[3];
    bw_lean_jacobian(cn, ce, BW_R(0.0), zn, ze, zd, g);
    return bw_attitude_variance(e, g[0], g[1], g[2]);
}

/* tether.py field_axis_row: the alignment's attitude column about the magnetic field's axis */
static void field_axis_row(const bw_real g[3], const bw_real *field, bw_real weight, bw_real out[3])
{
    const bw_real b2 = field[0] * field[0] + field[1] * field[1] + field[2] * field[2];
    bw_real s;
    if (!(b2 > BW_R(0.0)))
        return;
    s = weight * (g[0] * field[0] + g[1] * field[1] + g[2] * field[2]) / b2;
    out[0] = s * field[0], out[1] = s * field[1], out[2] = s * field[2];
}

static void fuse_taut(bw_estimator_t *est, bw_real along_var, bw_real cross_var)
{
    bw_ekf_t *e = &est->ekf;
    const bw_real *x = e->x;
    const bw_real pn = x[0], pe = x[1], pd = x[2], vn = x[3], ve = x[4], vd = x[5];
    const bw_forces_t *f = &e->forces;
    bw_real qn = pn + f->attach_ned[0], qe = pe + f->attach_ned[1], qd = pd + f->attach_ned[2];
    bw_real dist = BW_SQRT(qn * qn + qe * qe + qd * qd), ev[3], vr, v[3];
    int i, cc, j, ncol;
    if (dist < BW_R(1.0))
        return;
    ev[0] = qn / dist, ev[1] = qe / dist, ev[2] = qd / dist;
    memset(e->h, 0, sizeof e->h);
    for (i = 0; i < 3; i++)
        e->h[BW_POS_N + i] = ev[i];
    bw_ekf_fuse(e, e->rope_chord_m - dist, e->m.radial_var, &est->taut_status[0],
                (bw_real)BW_UNGATED, 1);
    memset(e->h, 0, sizeof e->h);
    vr = vn * ev[0] + ve * ev[1] + vd * ev[2];
    v[0] = vn, v[1] = ve, v[2] = vd;
    for (i = 0; i < 3; i++) {
        e->h[BW_VEL_N + i] = ev[i];
        e->h[BW_POS_N + i] = (v[i] - vr * ev[i]) / dist; /* d(v . e)/dp */
    }
    bw_ekf_fuse(e, e->rope_rate_mps - vr, e->m.radial_rate_var, &est->taut_status[1], /* the winch's reel (0: none) */
                (bw_real)BW_UNGATED, 1);
    if (!f->taut)
        return;
    {
        const bw_real s[BW_NCOL] = {pn, pe, pd, vn, ve, vd, x[12], x[13], x[14], x[15], x[16]};
        bw_real n[BW_ROPE_DIRECTION_SIZE], r[9], zn, ze, zd, horiz, lean, an, ae, c[2][3], var[2], share, n_d;
        bw_real misfit, att_gain;
        if (e->m.rope_drag_m2 > BW_R(0.0)) /* the paper's rod carries rope drag */
            bw_rope_direction(s, f->params, n);
        else
            bw_rope_direction_plain(s, f->params, n);
        bw_rotation(e->q, r);
        zn = r[2], ze = r[5], zd = r[8]; /* body down axis in NED */
        /* the azimuth: the balloon's lean, in calm air the state's (both parameters; tether.py fuse_taut) */
        lean = BW_HYPOT(zn, ze), horiz = BW_HYPOT(pn, pe);
        if (lean > (bw_real)BW_TAUT_LEAN_MIN_SIN)
            an = -zn / lean, ae = -ze / lean;
        else if (horiz > BW_R(1e-3))
            an = pn / horiz, ae = pe / horiz;
        else
            an = BW_R(1.0), ae = BW_R(0.0);
        /* along: in the lean's vertical plane, tangent to the body's axis (the lean's angle itself), its nominal
         * allowance over cos^2(lean); cross: horizontal across it (tether.py fuse_taut) */
        c[0][0] = an * zd, c[0][1] = ae * zd, c[0][2] = lean, c[1][0] = -ae, c[1][1] = an, c[1][2] = BW_R(0.0);
        n_d = BW_SQRT(BW_MAX(BW_R(1.0) - n[0] * n[0] - n[1] * n[1],
                             (bw_real)BW_ALIGN_PULL_DOWN_MIN * (bw_real)BW_ALIGN_PULL_DOWN_MIN));
        {
            const bw_real cz = BW_MAX(zd, (bw_real)BW_LEAN_COS_MIN);
            var[0] = BW_MAX(along_var, est->align_var / (cz * cz)), var[1] = cross_var;
        }
        ncol = BW_NCOL - (e->learn_drag ? 0 : 1);
        misfit = bw_accel_misfit(est->consistency.nis[BW_ACCEL]);
        share = (bw_real)BW_ALIGN_FIELD_AXIS_SHARE * (BW_R(1.0) - misfit);
        /* where the force model does not explain the accelerometer the alignment's misfit is correlated too: the
         * attitude takes no more of the cross component's gain than a correlated misfit allows (its noise stops at a
         * rocking balloon's), the along one's all of it (tether.py control_tether) */
        att_gain = BW_R(1.0) - misfit * (BW_R(1.0) - BW_MIN(BW_R(1.0), BW_SQRT((bw_real)est->sched.taut_every * e->dt
                                                                               / (bw_real)BW_ALIGN_MODEL_CORR_S)));
        for (cc = 0; cc < 2; cc++) {
            /* the attitude (tether.py fuse_taut): a column about the magnetic field's axis, weighed by how well
             * the models fit; the rest a parameter whose variance (c . d z / d att P_att (..)^T less the
             * column's) is noise */
            const bw_real cn = c[cc][0], ce = c[cc][1], cd = c[cc][2];
            /* c . d n / d x: d n_d / d x = -(n_n dn_n + n_e dn_e) / n_d */
            const bw_real kn = cn - cd * n[0] / n_d, ke = ce - cd * n[1] / n_d;
            bw_real g[3], hb[3] = {BW_R(0.0), BW_R(0.0), BW_R(0.0)}, var_att;
            bw_lean_jacobian(cn, ce, cd, zn, ze, zd, g);
            if (var[cc] > BW_R(0.0))
                field_axis_row(g, est->field_ned, share * est->align_var / var[cc], hb);
            var_att = BW_MAX(BW_R(0.0), bw_attitude_variance(e, g[0], g[1], g[2]) -
                                            bw_attitude_variance(e, hb[0], hb[1], hb[2]));
            memset(e->h, 0, sizeof e->h);
            for (j = 0; j < ncol; j++)
                e->h[BW_MODEL_COLS[j]] = -(kn * n[2 + j] + ke * n[2 + BW_NCOL + j]); /* residual c . (z - n(x)) */
            e->h[BW_ATT_N] = hb[0], e->h[BW_ATT_E] = hb[1], e->h[BW_ATT_D] = hb[2];
            bw_ekf_fuse_gain(e, cn * (n[0] - zn) + ce * (n[1] - ze) + cd * (n_d - zd), var[cc] + var_att,
                             &est->taut_status[2 + cc], BW_R(0.0), 0, cc ? att_gain : BW_R(1.0));
        }
    }
}

static void update_rope_shape(bw_estimator_t *est)
{
    bw_ekf_t *e = &est->ekf;
    const bw_model_t *m = &e->m;
    const bw_real *x = e->x, rho = est->rho, alpha = est->sched.rope_shape_alpha;
    bw_real un = x[BW_WIND_N] - x[BW_VEL_N], ue = x[BW_WIND_E] - x[BW_VEL_E], ud = -x[BW_VEL_D];
    bw_real kd = x[BW_DRAG] * rho * m->half_cd_area_m2 * BW_SQRT(un * un + ue * ue + ud * ud);
    bw_real lift = bw_lift_n(m, rho);
    bw_real fn = -kd * un, fe = -kd * ue, fd = -kd * ud + lift, ch[3], chord, weight;
    bw_real length = m->tether_length_m;
    bw_rope_chord(fn, fe, fd, length, m->lam_g, BW_R(0.5) * rho * m->rope_cn_d_m,
                  x[BW_WIND_N], x[BW_WIND_E], ch);
    chord = BW_SQRT(ch[0] * ch[0] + ch[1] * ch[1] + ch[2] * ch[2]);
    if (!(chord > BW_R(0.5) * length))
        return; /* no rope shape under this pull (lift gone): keep the last */
    weight = bw_effective_rod(fn, fe, fd, ch[0], ch[1], ch[2], m->rope_weight_n);
    e->rope_chord_m += alpha * (chord - e->rope_chord_m);
    if (weight == weight)
        e->rope_weight_n += alpha * (weight - e->rope_weight_n);
}

void bw_control_tether(bw_estimator_t *est)
{
    bw_ekf_t *e = &est->ekf;
    if (e->mode == BW_MODE_TAUT && e->taut_phase == 0) {
        bw_status_t *an = &est->taut_status[2], *ae = &est->taut_status[3];
        /* each alignment component's noise follows its recent innovations: the lean's their spread about
         * their mean (a persistent misfit is a lean that is off), the azimuth's no more than a rocking
         * balloon's (tether.py control_tether) */
        bw_real *mean2 = est->align_innov2, along_var, cross_var;
        if (est->catenary)
            update_rope_shape(est);
        along_var = BW_MAX(est->align_var, mean2[0] - est->align_mean * est->align_mean);
        cross_var = BW_MAX(est->align_var, BW_MIN(mean2[1], (bw_real)BW_ALIGN_CROSS_VAR_MAX));
        fuse_taut(est, along_var, cross_var);
        if (an->time_test_us == e->time_us) {
            mean2[0] += est->a_align_innov * (an->innov * an->innov - mean2[0]);
            mean2[1] += est->a_align_innov * (ae->innov * ae->innov - mean2[1]);
            est->align_mean += est->a_align_innov * (an->innov - est->align_mean);
            /* the body's tilt (its down axis, bw_rotation's third column alone) and the lean the model disagrees
             * with (consistency.c) */
            const bw_real *q = e->q;
            const bw_real zn = BW_R(2.0) * (q[1] * q[3] + q[0] * q[2]), ze = BW_R(2.0) * (q[2] * q[3] - q[0] * q[1]);
            const bw_real zd = q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3];
            bw_consistency_add_lean(&est->consistency, BW_ATAN2(BW_HYPOT(zn, ze), zd), an->innov, est->a_taut);
        }
        if (BW_MAX(an->consecutive_rejects, ae->consecutive_rejects) >= est->sched.align_reset) {
            est->counters.taut_resets += 1;
            an->consecutive_rejects = ae->consecutive_rejects = 0;
            bw_enter_taut(est, bw_height_for_taut(est), 1);
        }
    }
}
