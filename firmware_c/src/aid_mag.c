/* The magnetometer: the earth field learnt on the ground (and again on the tether), the field-vector and heading rows
 * (firmware_py/estimator/aid_sources/magnetometer.py). */
#include <string.h>

#include "internal.h"

static void fuse_heading(bw_estimator_t *est, bw_real mx, bw_real my, bw_real mz)
{
    bw_ekf_t *e = &est->ekf;
    bw_status_t *st = &est->heading_status;
    bw_real r[9], mn, me, md, h2, horiz, innov, var, a;
    bw_rotation(e->q, r);
    mn = r[0] * mx + r[1] * my + r[2] * mz;
    me = r[3] * mx + r[4] * my + r[5] * mz;
    md = r[6] * mx + r[7] * my + r[8] * mz;
    h2 = mn * mn + me * me;
    horiz = BW_SQRT(h2);
    if (horiz < BW_R(1e-3)) {
        st->rejected += 1;
        return;
    }
    innov = est->declination - BW_ATAN2(me, mn);
    a = BW_FMOD(innov + BW_PI, BW_R(2.0) * BW_PI); /* Python's %: the result takes the divisor's sign */
    if (a < BW_R(0.0))
        a += BW_R(2.0) * BW_PI;
    innov = a - BW_PI;
    memset(e->h, 0, sizeof e->h);
    e->h[BW_ATT_N] = -mn * md / h2;
    e->h[BW_ATT_E] = -me * md / h2;
    e->h[BW_ATT_D] = BW_R(1.0);
    var = (est->mag_sigma / horiz) * (est->mag_sigma / horiz) + (BW_R(0.5) * BW_DEG) * (BW_R(0.5) * BW_DEG);
    bw_ekf_fuse(e, innov, var, st, BW_R(0.0), 1);
}

static void fuse_mag_field(bw_estimator_t *est, bw_real mx, bw_real my, bw_real mz)
{
    bw_ekf_t *e = &est->ekf;
    bw_real r[9], pred[3];
    const bw_real bn = est->field_ned[0], be = est->field_ned[1], bd = est->field_ned[2];
    int i;
    bw_rotation(e->q, r);
    for (i = 0; i < 3; i++) {
        bw_real cn = r[i], ce = r[3 + i], cd = r[6 + i];
        int j;
        /* H3's other columns are zero but those the accelerometer's rows write (aid_accel.c) */
        for (j = 0; j < BW_NCOL; j++)
            e->H3[i][BW_MODEL_COLS[j]] = BW_R(0.0);
        e->H3[i][BW_ABIAS_Z] = BW_R(0.0);
        e->H3[i][BW_ATT_N] = ce * bd - cd * be;
        e->H3[i][BW_ATT_E] = cd * bn - cn * bd;
        e->H3[i][BW_ATT_D] = cn * be - ce * bn;
        pred[i] = cn * bn + ce * be + cd * bd;
    }
    bw_ekf_fuse3(e, mx - pred[0], my - pred[1], mz - pred[2], est->mag_var, est->mag_status, BW_R(0.0),
                 BW_R(1.0), BW_R(1.0), NULL, BW_R(0.0));
}

static void learn_field(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my, bw_real mz)
{
    bw_real *s = est->field_sum, fnorm, n, down, horiz, v;
    s[0] += ax, s[1] += ay, s[2] += az, s[3] += mx, s[4] += my, s[5] += mz;
    est->field_n += 1;
    if (est->field_n < est->sched.field_learn)
        return;
    fnorm = BW_SQRT(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
    n = (bw_real)est->field_n;
    down = -(s[0] * s[3] + s[1] * s[4] + s[2] * s[5]) / (fnorm * n); /* at rest the specific force points up */
    v = (s[3] * s[3] + s[4] * s[4] + s[5] * s[5]) / (n * n) - down * down;
    horiz = BW_SQRT(BW_MAX(BW_R(0.0), v));
    est->field_ned[0] = horiz * BW_COS(est->declination);
    est->field_ned[1] = horiz * BW_SIN(est->declination);
    est->field_ned[2] = down;
}

#define FIELD_WINDOW_STATE 7     /* ekf.field_window: its state ... (magnetometer.py) */
#define FIELD_REPLACED_EARLY 16  /* ... and this bit: the first window replaced the field */
#define FIELD_JUMPED 32          /* ... and this one: the magnetometer's own field jumped, a window learns it since */

/* magnetometer.py follow_field_strength: |m|^2, its means over FIELD_JUMP_SHORT_S and FIELD_JUMP_LONG_S at the
 * tether's rate; while a placement settles both the short one */
static void follow_field_strength(bw_estimator_t *est, bw_real mx, bw_real my, bw_real mz, int settling)
{
    bw_real *st = est->field_strength;
    const bw_real m2 = mx * mx + my * my + mz * mz,
                  step_s = (bw_real)(est->sched.taut_every * est->dt_us) * BW_R(1e-6);
    if (st[0] == BW_R(0.0))
        st[0] = m2;
    st[0] += step_s / (bw_real)BW_FIELD_JUMP_SHORT_S * (m2 - st[0]);
    st[1] = settling ? st[0] : st[1] + step_s / (bw_real)BW_FIELD_JUMP_LONG_S * (m2 - st[1]);
}

/* magnetometer.py field_jump: counted, the field vector no longer fused, learnt again from now (learn_field_in_flight);
 * the attitude's variance grown by what the rows may have turned it by before the jump was seen */
static void field_jump(bw_estimator_t *est, bw_real tilt_var)
{
    bw_real *s = est->field_sum;
    est->counters.field_jumps += 1;
    est->ekf.field_window = FIELD_JUMPED;
    s[0] = s[1] = s[2] = s[3] = s[4] = s[5] = BW_R(0.0);
    est->mag_status[0].consecutive_rejects = est->mag_status[1].consecutive_rejects =
        est->mag_status[2].consecutive_rejects = 0;
    if (tilt_var > BW_R(0.0))
        bw_ekf_inflate_attitude(&est->ekf, tilt_var);
}

/* magnetometer.py watch_field: the field's strength off its own mean, or the field vector rejected for
 * FIELD_JUMP_REJECTED_S from a sample it was fused (its run of rejections set back before the rows' recover at the
 * gate): the magnetometer's own field jumped (field_jump); 1 if it did */
static int watch_field(bw_estimator_t *est, bw_real mx, bw_real my, bw_real mz)
{
    const bw_real *st = est->field_strength;
    bw_status_t *status = est->mag_status;
    bw_real jump;
    int rejected = 0, young;
    int64_t unfused;
    const int32_t run = est->sched.mag_recover - est->sched.taut_every;
    if (status[0].consecutive_rejects == 0) {
        follow_field_strength(est, mx, my, mz, 0);
    } else { /* a run that began as the field was fused: a jump once it lasts, the recover held until then */
        unfused = est->ekf.time_us - status[0].time_last_fuse_us;
        young = unfused < (int64_t)(BW_FIELD_JUMP_REJECTED_S * 1e6) + est->sched.taut_every * est->dt_us;
        rejected = young && unfused >= (int64_t)(BW_FIELD_JUMP_REJECTED_S * 1e6);
        if (young && status[0].consecutive_rejects >= (run > 1 ? run : 1))
            status[0].consecutive_rejects = status[1].consecutive_rejects = status[2].consecutive_rejects = 0;
    }
    jump = BW_FABS(BW_SQRT(st[0]) - BW_SQRT(st[1]));
    if (!(jump > (bw_real)BW_FIELD_JUMP_GAUSS || rejected))
        return 0;
    field_jump(est, jump > (bw_real)BW_FIELD_JUMP_GAUSS ? jump * jump / st[0] : BW_R(0.0));
    return 1;
}

/* magnetometer.py learn_field_in_flight: the earth field learnt again on the taut tether twice after a placement
 * (ekf.field_window: 2k armed for window k, 2k + 1 summing the specific force in NED, m . f, |m|^2 and the samples
 * into field_sum, 4 done; and whether the first replaced the field); at the first sample past each window, the field
 * (beyond BW_FIELD_CHANGE_GAUSS of the one held, scaled to the window's samples), the sums then the kept field's */
static void learn_field_in_flight(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my,
                                  bw_real mz)
{
    bw_ekf_t *e = &est->ekf;
    bw_real *s = est->field_sum, r[9], f, c, down, h, h_old, h_new, change2, hx, hy, hz, bn = est->field_ned[0],
            be = est->field_ned[1], bd = est->field_ned[2];
    /* from the later of the taut spell's start and its last placement: a re-placement starts them again; two
     * windows (magnetometer.py FIELD_RELEARN_WINDOWS_US), field_window even armed, odd summing; after a jump of the
     * magnetometer's own field one, at once, timed by its samples, that learns the field's direction too */
    const int64_t placed = e->time_us - e->time_taut_us, spell = (int64_t)est->dwell * est->dt_us;
    const int64_t since = placed < spell ? placed : spell;
    const int k = (e->field_window & FIELD_WINDOW_STATE) / 2, jumped = e->field_window & FIELD_JUMPED,
              rejected = est->mag_status[0].consecutive_rejects > 0; /* (before watch_field holds the recover) */
    int64_t start, length;
    int summing;
    if (since < (int64_t)(BW_FIELD_RELEARN_FROM_S * 1e6)) {
        e->field_window = 0;
        follow_field_strength(est, mx, my, mz, 1);
        return;
    }
    if (jumped) {
        length = (int64_t)(BW_FIELD_RELEARN_S * 1e6);
        summing = s[5] * (bw_real)(est->sched.taut_every * est->dt_us) < (bw_real)length;
    } else {
        if (watch_field(est, mx, my, mz) || k >= 2)
            return;
        start = k == 0 ? (int64_t)(BW_FIELD_RELEARN_FROM_S * 1e6) : (int64_t)(BW_FIELD_RELEARN_AGAIN_FROM_S * 1e6);
        length = k == 0 ? (int64_t)(BW_FIELD_RELEARN_S * 1e6) : (int64_t)(BW_FIELD_FLIGHT_S * 1e6);
        if (since < start)
            return;
        if ((e->field_window & 1) == 0) {
            s[0] = s[1] = s[2] = s[3] = s[4] = s[5] = BW_R(0.0);
            e->field_window += 1;
        }
        summing = since < start + length;
    }
    if (summing) {
        if (rejected) /* a field the rows reject (a burst beside the magnetometer) */
            return;
        bw_rotation(e->q, r);
        hx = jumped ? mx : ax, hy = jumped ? my : ay, hz = jumped ? mz : az; /* after a jump the field's direction */
        s[0] += r[0] * hx + r[1] * hy + r[2] * hz;
        s[1] += r[3] * hx + r[4] * hy + r[5] * hz;
        s[2] += r[6] * ax + r[7] * ay + r[8] * az;
        s[3] += ax * mx + ay * my + az * mz;
        s[4] += mx * mx + my * my + mz * mz;
        s[5] += BW_R(1.0);
        return;
    }
    e->field_window = jumped ? 4 : e->field_window + 1;
    c = s[5];
    f = jumped ? -s[2] : BW_SQRT(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
    if (!(f > BW_R(0.5) * (bw_real)BW_G0 * c)) /* no gravity to read the field's down component against */
        return;
    down = -s[3] / f; /* at rest the specific force points up */
    h = h_old = BW_SQRT(bn * bn + be * be);
    h_new = BW_SQRT(BW_MAX(BW_R(0.0), s[4] / c - BW_R(3.0) * est->mag_sigma * est->mag_sigma - down * down));
    change2 = (h_new - h_old) * (h_new - h_old) + (down - bd) * (down - bd);
    if (jumped) { /* the whole field, its direction through the heading the gyro held; the strength's means */
        est->field_strength[0] = est->field_strength[1] = s[4] / c;
        if (h_new > (bw_real)BW_FIELD_CHANGE_GAUSS) {
            f = BW_ATAN2(s[1], s[0]);
            est->field_ned[0] = h_new * BW_COS(f);
            est->field_ned[1] = h_new * BW_SIN(f);
            est->field_ned[2] = down;
            e->field_heading_var = BW_MIN(e->field_heading_var + e->P[BW_ATT_D][BW_ATT_D],
                                          (bw_real)BW_FIELD_HEADING_VAR_MAX);
            h = h_new, bd = down;
        }
    } else if (h_old > BW_R(0.0) && h_new > (bw_real)BW_FIELD_CHANGE_GAUSS &&
               (change2 > (bw_real)BW_FIELD_CHANGE_GAUSS * (bw_real)BW_FIELD_CHANGE_GAUSS *
                              (bw_real)(int64_t)(BW_FIELD_FLIGHT_S * 1e6) / (bw_real)length || /* a shorter window */
                (e->field_window & FIELD_REPLACED_EARLY))) { /* the second takes the place of the first's */
        est->field_ned[0] = bn * h_new / h_old;
        est->field_ned[1] = be * h_new / h_old;
        est->field_ned[2] = down;
        /* its unseen part across the field's horizontal direction, as large as the part seen (magnetometer.py) */
        e->field_heading_var = BW_MIN(e->field_heading_var + change2 / (h_new * h_new),
                                      (bw_real)BW_FIELD_HEADING_VAR_MAX); /* each replacement adds (magnetometer.py) */
        h = h_new, bd = down;
        if (k == 0)
            e->field_window |= FIELD_REPLACED_EARLY;
    }
    /* the sums learn_field would have taken of the field at rest, level, from as many samples as it had */
    f = (bw_real)est->field_n;
    s[0] = BW_R(0.0), s[1] = BW_R(0.0), s[2] = -(bw_real)BW_G0 * f, s[3] = h * f, s[4] = BW_R(0.0), s[5] = bd * f;
}

void bw_control_mag(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my, bw_real mz)
{
    const bw_ekf_t *e = &est->ekf;
    if (e->mode == BW_MODE_GROUND || (est->joined && est->field_n < est->sched.field_flight))
        learn_field(est, ax, ay, az, mx, my, mz);
    else if (e->mode == BW_MODE_TAUT && !est->joined && est->field_n >= est->sched.field_learn && e->taut_phase == 0)
        learn_field_in_flight(est, ax, ay, az, mx, my, mz);
    if (est->field_n >= est->sched.field_learn && e->mode != BW_MODE_GROUND) {
        if (!(e->field_window & FIELD_JUMPED)) /* a jumped field is learnt again before it is fused */
            fuse_mag_field(est, mx, my, mz);
    } else
        fuse_heading(est, mx, my, mz);
}
