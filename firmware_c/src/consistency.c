/* Is the model explaining the data? (firmware_py/estimator/consistency.py) */
#include "internal.h"

void bw_consistency_reset(bw_consistency_t *m)
{
    int i;
    for (i = 0; i < BW_N_SOURCES; i++)
        m->nis[i] = BW_R(0.0);
    m->flags = 0;
    m->inflation = BW_R(1.0);
    m->slow_tilt = m->slow_tilt_var = BW_R(0.0);
    m->balance_n = m->balance_e = m->balance_var = BW_R(0.0);
    m->lean_tilt = m->lean_misfit = BW_R(0.0);
}

/* consistency.py heading_misfit_variance: the attitude's variance about the field's axis that the accelerometer's
 * slow misfit shows */
bw_real bw_heading_misfit_variance(const bw_consistency_t *m)
{
    return (bw_real)BW_HEADING_MISFIT_RATIO * (bw_real)BW_HEADING_MISFIT_RATIO * m->slow_tilt_var;
}

void bw_consistency_add_clipped(bw_consistency_t *m, int source, bw_real nis, bw_real alpha, bw_real clip)
{
    if (nis == nis)
        m->nis[source] += alpha * (BW_MIN(nis, clip) - m->nis[source]);
}

void bw_consistency_add(bw_consistency_t *m, int source, bw_real nis, bw_real alpha)
{
    bw_consistency_add_clipped(m, source, nis, alpha, (bw_real)BW_NIS_CLIP);
}

/* consistency.py balance_nis: the window's mean update of the velocity over the variance a consistent filter's
 * would have (Consistency.add_balance) */
bw_real bw_balance_nis(const bw_consistency_t *m)
{
    if (!(m->balance_var > BW_R(0.0)))
        return BW_R(0.0);
    return (m->balance_n * m->balance_n + m->balance_e * m->balance_e) / m->balance_var;
}

/* consistency.py Consistency.add_lean: the body's taut tilt and the alignment's along innovation, their means over
 * the window (the tilt's from its first sample, the misfit's from zero; a NaN not taken) */
void bw_consistency_add_lean(bw_consistency_t *m, bw_real tilt, bw_real misfit, bw_real alpha)
{
    if (!(tilt == tilt && misfit == misfit)) /* an innovation not evaluated (NaN) is not taken */
        return;
    m->lean_tilt = m->lean_tilt == BW_R(0.0) ? tilt : m->lean_tilt + alpha * (tilt - m->lean_tilt);
    m->lean_misfit += alpha * (misfit - m->lean_misfit);
}

/* consistency.py gyro_heading_wind: the wind error of a heading the gyro alone has held for seconds */
bw_real bw_gyro_heading_wind(bw_real speed, bw_real gyro_bias_rad_s, bw_real seconds)
{
    bw_real theta = BW_MIN(BW_MAX(gyro_bias_rad_s * seconds, BW_R(0.0)), (bw_real)BW_PI);
    return BW_R(2.0) * speed * BW_SIN(BW_R(0.5) * theta);
}

/* consistency.py placement_settling_wind: the wind error still to settle seconds after a taut placement, the
 * placement's 1-sigma and the wind's own speed in quadrature, falling by e every ENTRY_SETTLE_S; 0 before one */
bw_real bw_placement_settling_wind(bw_real seconds, bw_real speed)
{
    if (!(seconds >= BW_R(0.0)))
        return BW_R(0.0);
    return BW_HYPOT((bw_real)BW_TAUT_WIND_SIGMA_MPS, speed) * BW_EXP(-seconds / (bw_real)BW_ENTRY_SETTLE_S);
}

/* consistency.py lean_misfit_wind: the wind error of a lean the body and the taut model disagree on, persistently
 * (the two leans' tangents tell two winds, |w|^2 ~ tan), each lean at most the pull's steepest, bounded by the
 * wind's own speed or 0.5 m/s */
bw_real bw_lean_misfit_wind(bw_real speed, bw_real tilt, bw_real misfit)
{
    const bw_real bound = BW_MAX(speed, BW_R(0.5)), c = (bw_real)BW_ALIGN_PULL_DOWN_MIN;
    const bw_real top = BW_ATAN2(BW_SQRT(BW_R(1.0) - c * c), c), lean = tilt - misfit;
    bw_real a, b, ratio;
    if (!(tilt > BW_R(0.0) && lean > BW_R(0.0)))
        return bound;
    a = BW_MIN(tilt, top), b = BW_MIN(lean, top);
    ratio = BW_SIN(a) * BW_COS(b) / (BW_COS(a) * BW_SIN(b));
    return BW_MIN(speed * BW_FABS(BW_R(1.0) - BW_SQRT(ratio)), bound);
}

void bw_consistency_evaluate(bw_consistency_t *m)
{
    int32_t flags = 0;
    bw_real worst = BW_R(1.0), v;
    int i;
    for (i = 0; i < BW_N_SOURCES; i++) {
        if (m->nis[i] > (bw_real)BW_FLAG_NIS || ((m->flags >> i & 1) && m->nis[i] > (bw_real)BW_FLAG_NIS_CLEAR))
            flags |= 1 << i; /* set above FLAG_NIS, cleared below FLAG_NIS_CLEAR (consistency.py evaluate) */
        /* the accelerometer's as (1 + NIS) / 2: a slow gain's error (consistency.py) */
        v = i == BW_ACCEL ? BW_R(0.5) * (BW_R(1.0) + m->nis[i]) : m->nis[i];
        if (v > worst)
            worst = v;
    }
    if (flags != m->flags)
        m->flag_changes += 1;
    m->flags = flags;
    m->inflation = BW_SQRT(worst);
}

/* control.py _field_variance (consistency.py field_variance on the unit field): the attitude's variance about the
 * field's axis in P, 0 while the field is unknown */
bw_real bw_field_variance(const bw_ekf_t *e, const bw_real field_ned[3])
{
    bw_real b = BW_SQRT(field_ned[0] * field_ned[0] + field_ned[1] * field_ned[1] + field_ned[2] * field_ned[2]), bn,
            be, bd;
    if (!(b > BW_R(0.0)))
        return BW_R(0.0);
    bn = field_ned[0] / b, be = field_ned[1] / b, bd = field_ned[2] / b;
    return bw_attitude_variance(e, bn, be, bd);
}

/* consistency.py attitude_variance: g^T P_att g */
bw_real bw_attitude_variance(const bw_ekf_t *e, bw_real g0, bw_real g1, bw_real g2)
{
    return g0 * (g0 * e->P[BW_ATT_N][BW_ATT_N] +
                 BW_R(2.0) * (g1 * e->P[BW_ATT_N][BW_ATT_E] + g2 * e->P[BW_ATT_N][BW_ATT_D])) +
           g1 * (g1 * e->P[BW_ATT_E][BW_ATT_E] + BW_R(2.0) * g2 * e->P[BW_ATT_E][BW_ATT_D]) +
           g2 * g2 * e->P[BW_ATT_D][BW_ATT_D];
}

/* consistency.py correlated_weight: the share of a fusion's information that counts, its misfit correlated */
bw_real bw_correlated_weight(bw_real nis, bw_real dt_s, bw_real corr_s)
{
    return nis * corr_s <= dt_s ? BW_R(1.0) : dt_s / (nis * corr_s);
}

/* consistency.py field_attitude_extra: one step of the attitude's variance about the field's axis that P does not
 * hold, each fusion's information counted with its weight */
bw_real bw_field_attitude_extra(bw_real extra, bw_real v_pred, bw_real v_accel, bw_real v_aids, bw_real v_end,
                                bw_real w_accel, bw_real w_align)
{
    const bw_real v0[3] = {v_pred, v_accel, v_aids}, v1[3] = {v_accel, v_aids, v_end}, w[3] = {w_accel, BW_R(1.0), w_align};
    bw_real s = v_pred + extra, inv;
    int i;
    for (i = 0; i < 3; i++) {
        inv = (v0[i] > BW_R(0.0) && v1[i] > BW_R(0.0) && s > BW_R(0.0))
                  ? BW_R(1.0) / s + w[i] * (BW_R(1.0) / v1[i] - BW_R(1.0) / v0[i]) : BW_R(0.0);
        if (inv > BW_R(0.0))
            s = BW_R(1.0) / inv;
    }
    return isfinite(s) ? BW_MAX(BW_R(0.0), s - v_end) : BW_R(0.0);
}

/* consistency.py lean_tilt_variance: the tilt variance across the lean that bw_lean_bias_wind takes, from P's
 * displacement variance across it and what P does not hold about the field's axis (across, and a quarter along),
 * over cos^2(lean) */
bw_real bw_lean_tilt_variance(bw_real cross_var, bw_real extra, const bw_real field_ned[3], bw_real zn, bw_real ze,
                              bw_real zd)
{
    const bw_real lean = BW_SQRT(zn * zn + ze * ze);
    bw_real cn, ce, b, across, along, c, g[3];
    if (!(lean > BW_R(0.0)))
        return cross_var;
    cn = ze / lean, ce = -zn / lean;
    b = BW_SQRT(field_ned[0] * field_ned[0] + field_ned[1] * field_ned[1] + field_ned[2] * field_ned[2]);
    if (b > BW_R(0.0)) {
        bw_lean_jacobian(cn, ce, BW_R(0.0), zn, ze, zd, g);
        across = (g[0] * field_ned[0] + g[1] * field_ned[1] + g[2] * field_ned[2]) / b;
        along = zd * (cn * field_ned[0] + ce * field_ned[1]) / b;
        cross_var += extra * (across * across + BW_R(0.25) * along * along);
    }
    c = BW_MAX(zd, (bw_real)BW_LEAN_COS_MIN);
    return cross_var / (c * c);
}

bw_real bw_systematic_variance(bw_real speed_mps, bw_real drag_scale, bw_real drag_scale_var, bw_real lean_wind_mps)
{
    bw_real k = BW_MAX(drag_scale, BW_R(1e-3));
    bw_real rel_k = BW_R(0.5) * BW_SQRT(drag_scale_var) / k;
    return speed_mps * speed_mps * rel_k * rel_k + lean_wind_mps * lean_wind_mps;
}

/* consistency.py bias_tilt_rad: the tilt's systematic error of a horizontal bias of variance hbias_var read as a
 * tilt, beside the turn-on term */
bw_real bw_bias_tilt_rad(bw_real hbias_var)
{
    return BW_SQRT((bw_real)(BW_LEAN_BIAS_RAD * BW_LEAN_BIAS_RAD) +
                   BW_MAX(hbias_var, BW_R(0.0)) / (bw_real)(BW_G0 * BW_G0));
}

/* consistency.py lean_bias_rad: the turn-on term and the horizontal bias's walk since the boot (the declared random
 * walk) read as a tilt */
bw_real bw_lean_bias_rad(bw_real walk_mps2_rt_s, bw_real seconds)
{
    return bw_bias_tilt_rad(walk_mps2_rt_s * walk_mps2_rt_s * BW_MAX(seconds, BW_R(0.0)));
}

/* consistency.py lean_bias_wind: the wind error of a tilt error on the taut balloon, with the field's geometry
 * (the rotation about the field's axis that only the accelerometer holds turns the lean's azimuth) */
bw_real bw_lean_bias_wind(bw_real wind_n, bw_real wind_e, bw_real lift_n, bw_real drag_per_speed2,
                          bw_real lean_bias_rad, const bw_real field_ned[3], bw_real cross_tilt_var,
                          bw_real held_bias_rad, bw_real mount_rad)
{
    bw_real speed = BW_SQRT(wind_n * wind_n + wind_e * wind_e), about = BW_R(1.0), across = BW_R(0.0), bh, t, cos_a, v;
    if (!(drag_per_speed2 > BW_R(0.0) && lift_n > BW_R(0.0)))
        return BW_R(0.0);
    bh = BW_SQRT(field_ned[0] * field_ned[0] + field_ned[1] * field_ned[1]);
    if (bh > BW_R(0.0) && speed > BW_R(0.0)) { /* false while the field is unknown (NaN) */
        t = field_ned[2] / bh * drag_per_speed2 * speed * speed / lift_n;
        cos_a = (wind_n * field_ned[0] + wind_e * field_ned[1]) / (speed * bh);
        about = (t + cos_a) * (t + cos_a), across = BW_MAX(BW_R(0.0), BW_R(1.0) - cos_a * cos_a);
    }
    v = lift_n *
        BW_SQRT(lean_bias_rad * lean_bias_rad * (about + BW_R(0.25)) + held_bias_rad * held_bias_rad * across +
                cross_tilt_var + BW_R(1.25) * mount_rad * mount_rad) /
        (drag_per_speed2 * BW_MAX(speed, BW_R(1e-3)));
    return BW_MIN(v, BW_MAX(speed, BW_R(0.5)));
}
