/* What to fuse and when (firmware_py/estimator/control.py): input validation, the fixed-step clock
 * with jitter/gap/duplicate/reorder/backwards handling, barometer zeroing, mode switching with
 * hysteresis, resets, the consistency monitor's feed and the reported accuracy. */
#include <string.h>

#include "internal.h"

static int finite3(bw_real a, bw_real b, bw_real c, bw_real limit)
{
    /* NaN and inf fail the bounds */
    return BW_FABS(a) <= limit && BW_FABS(b) <= limit && BW_FABS(c) <= limit;
}

static int32_t round_count(double v) /* max(1, round(v)), Python's round (half to even) */
{
    double r = bw_round_half_even(v);
    return r < 1.0 ? 1 : (int32_t)r;
}

/* control.py count_up: a step count one more, held at the largest int32 */
static int32_t count_up(int32_t n)
{
    return n < INT32_MAX ? n + 1 : n;
}

static int32_t steps_for(double v) /* the least step count n with n >= v (the config bounds v well below 2^31) */
{
    return (int32_t)ceil(v);
}

static void schedule_at(bw_schedule_t *s, double rate, double recover_after_s)
{
    double taut_hz, a;
    s->taut_every = round_count(BW_TAUT_PERIOD_S * rate);
    taut_hz = rate / s->taut_every;
    s->align_reset = round_count(BW_ALIGN_RESET_S * taut_hz);
    s->baro_reset = round_count(BW_BARO_RESET_S * BW_BARO_NOMINAL_HZ);
    s->baro_recover = (int32_t)(recover_after_s * BW_BARO_NOMINAL_HZ);
    if (s->baro_recover < 1)
        s->baro_recover = 1;
    s->mag_recover = round_count(BW_MAG_RECOVER_S * rate);
    s->field_learn = round_count(BW_FIELD_LEARN_S * rate);
    s->field_flight = round_count(BW_FIELD_FLIGHT_S * rate);
    s->wind_noise_every = round_count(BW_WIND_NOISE_PERIOD_S * rate);
    s->release_confirm = round_count(BW_RELEASE_CONFIRM_S * rate);
    s->release_height = round_count(BW_RELEASE_HEIGHT_S * rate);
    s->turbulence_from = round_count(BW_TURBULENCE_FROM_S * rate);
    s->turbulence_to = round_count(BW_TURBULENCE_TO_S * rate);
    a = 1.0 / (BW_ROPE_SHAPE_S * taut_hz);
    s->rope_shape_alpha = (bw_real)(a < 1.0 ? a : 1.0);
}

static bw_real vertical_gust_var(const bw_estimator_t *est, bw_real mean_speed_mps, bw_real rho)
{
    const bw_model_t *m = &est->ekf.m;
    bw_real m_eff = m->mass_kg + (bw_real)BW_ADDED_MASS_COEFFICIENT * rho * m->volume_m3;
    bw_real u = BW_MAX(mean_speed_mps, BW_R(0.5));
    bw_real sigma_w = (bw_real)BW_VERTICAL_TURBULENCE_RATIO * m->turbulence_intensity * u;
    bw_real a = rho * m->half_cd_area_m2 * u * sigma_w / m_eff;
    return a * a;
}

/* control.py _mean_weight: in the first taut spell, until it fills the window, a speed above the mean counts as one
 * of the spell's own samples */
static bw_real mean_weight(const bw_estimator_t *est, bw_real dev)
{
    if (dev > BW_R(0.0) && !est->was_slack && (bw_real)est->dwell * est->speed_alpha < BW_R(1.0))
        return BW_R(1.0) / (bw_real)(est->dwell + 1);
    return est->speed_alpha;
}

/* control.py _turbulence_excess: below BW_LIGHT_AIR_SIGMA_U_MPS the filter's own turbulence raises the wind's
 * noise when larger than sigma_u = TI U (light air meanders), as a variance ratio >= 1; the force model's misfit
 * does not (taken for turbulence it fed on itself) */
static bw_real turbulence_excess(const bw_estimator_t *est)
{
    bw_real expected = est->ekf.m.turbulence_intensity * BW_MAX(est->mean_speed, BW_R(0.5));
    bw_real seen = BW_MIN(est->speed_var, (bw_real)(BW_LIGHT_AIR_SIGMA_U_MPS * BW_LIGHT_AIR_SIGMA_U_MPS));
    return BW_MAX(BW_R(1.0), seen / (expected * expected));
}

static void init_clock(bw_estimator_t *est)
{
    est->initialised = 0;
    est->t_filter_us = 0;
    est->t_last_us = -1;
    est->t_boot_us = 0;
    est->step = 0;
    est->ekf.taut_phase = est->ekf.noise_phase = 0;
    est->last_gyro[0] = est->last_gyro[1] = est->last_gyro[2] = BW_R(0.0);
    est->release_count = 0;
    est->field_n = 0;
    memset(est->field_sum, 0, sizeof est->field_sum);
    est->field_strength[0] = est->field_strength[1] = BW_R(0.0);
    est->joined = 0;
    est->wind_taut_mps = BW_R(0.0);
    est->unconfirmed = 0;
    est->acc_mean[0] = est->acc_mean[1] = est->acc_mean[2] = BW_R(0.0);
    est->acc_var = BW_R(0.0);
    est->confirm_count = 0;
    est->field_ned[0] = est->field_ned[1] = est->field_ned[2] = BW_R(NAN);
    est->ekf.field_heading_var = BW_R(0.0);
    est->dwell = 0;
    est->accel_innov2 = BW_R(0.0);
    est->innov_alpha = (bw_real)(1.0 / (BW_ACCEL_INNOV_S * est->cfg->imu_rate_hz));
    est->mean_speed = (bw_real)est->cfg->expected_wind_mps;
    est->speed_alpha = (bw_real)(1.0 / (BW_MEAN_WIND_S * est->cfg->imu_rate_hz));
    est->speed_var = (bw_real)(est->cfg->turbulence_intensity * est->cfg->expected_wind_mps
                               * est->cfg->turbulence_intensity * est->cfg->expected_wind_mps);
    est->slack = 0;
    est->pulling = 0;
    est->was_slack = 0;
    est->height_above = 0;
    est->accel_var_excess = BW_R(0.0);
    est->accel_radial_innov2 = BW_R(0.0);
    est->level_mean[0] = est->level_mean[1] = est->level_var = BW_R(0.0);
    est->accel_hbias[0] = est->accel_hbias[1] = BW_R(0.0);
    est->accel_hbias_var = BW_R(0.0);
    est->align_innov2[0] = est->align_innov2[1] = est->align_mean = BW_R(0.0);
    est->drag_prior[0] = BW_R(1.0), est->drag_prior[1] = BW_R(0.0);
    est->ascent_data = est->ascent_var = est->ascent_climb = BW_R(0.0);
    est->turbulence[0] = est->turbulence[1] = est->turbulence[2] = BW_R(0.0);
    bw_consistency_reset(&est->consistency);
}

static void init_baro(bw_estimator_t *est)
{
    double gp = est->cfg->ground_pressure_hpa;
    int known = gp == gp;
    est->p_ref_pa = known ? (bw_real)(gp * 100.0) : BW_R(NAN);
    est->zeroing = !known;
    est->ref_pos_d = known ? BW_R(0.0) : (bw_real)-est->cfg->radius_m;
    est->t_ref_k = BW_R(NAN);
    est->zero_sum = BW_R(0.0);
    est->zero_n = 0;
    est->join_height = BW_R(NAN);
    est->rho = (bw_real)bw_site_air_density(est->cfg); /* the site's air until the barometer reads it (aid_baro.c) */
    est->height_baro = BW_R(NAN);
    est->baro_pending = 0;
    est->baro_outside = 0;
    bw_init_ground_ref(est);
}

size_t bw_sizeof_estimator(void)
{
    return sizeof(bw_estimator_t);
}

void bw_config_default(bw_config_t *c)
{
    const double r = 1.0, volume = 4.0 / 3.0 * 3.141592653589793 * r * r * r;
    memset(c, 0, sizeof *c);
    c->radius_m = r;
    c->volume_m3 = volume;
    c->mass_kg = 1.0 + 0.2 * volume;
    c->half_cd_area_m2 = 0.5 * 0.3 * 3.141592653589793 * r * r;
    c->tether_length_m = 100.0;
    c->rope_kg_m = 0.02;
    c->rope_drag_m2 = 0.0;
    c->rope_cn_d_m = 1.1 * 0.004726260241728836; /* Cn d: a solid nylon rope of 0.02 kg/m is 4.7 mm thick */
    c->accel_mps2 = 0.01, c->baro_m = 1.0, c->gyro_dps = 1.0, c->mag_gauss = 0.005, c->imu_alignment_deg = 0.0;
    c->imu_roll_deg = 0.0, c->imu_pitch_deg = 0.0;
    c->mag_declination_deg = 0.0, c->ground_pressure_hpa = NAN, c->altitude_amsl_m = 0.0;
    c->imu_rate_hz = 100.0, c->accel_process_mps2 = 0.05, c->expected_wind_mps = 3.0, c->turbulence_intensity = 0.2;
    c->drag_walk_rt_s = 0.0005, c->baro_walk_m_rt_s = 0.1, c->accel_bias_walk_mps2_rt_s = 0.001;
    c->gyro_bias_walk_dps_rt_s = 0.0025;
    c->accel_model_mps2 = 0.15, c->accel_taut_mps2 = 0.1, c->accel_static_mps2 = 0.3, c->align_rad = 0.01;
    c->radial_m = 0.3, c->radial_rate_mps = 0.15, c->rope_catenary = 1;
    c->gate_sigma = 5.0, c->recover_after_s = 1.0;
    c->init_wind_mps = 6.0, c->init_drag = 0.1, c->init_accel_bias_mps2 = 0.05, c->init_gyro_bias_dps = 0.5;
    c->init_tilt_deg = 3.0, c->init_yaw_deg = 10.0;
    c->taut_margin_m = 1.5, c->mode_dwell_s = 1.0, c->release_accel_mps2 = 1.5, c->release_height_m = 3.0;
    c->max_gap_s = 0.5;
}

int bw_init(bw_estimator_t *est, const bw_config_t *cfg)
{
    double share, s_acc, dt_us, gap;
    int i;
    if (!(cfg->imu_rate_hz > 0.0 && cfg->radius_m > 0.0 && cfg->mass_kg > 0.0 && cfg->volume_m3 > 0.0))
        return -1;
    memset(est, 0, sizeof *est);
    est->cfg = cfg;
    est->catenary = cfg->rope_catenary != 0.0;
    est->mount = cfg->imu_roll_deg != 0.0 || cfg->imu_pitch_deg != 0.0;
    bw_ekf_init(&est->ekf, cfg);
    s_acc = cfg->accel_mps2 * cfg->accel_mps2;
    est->accel_var = (bw_real)(s_acc + cfg->accel_model_mps2 * cfg->accel_model_mps2);
    est->accel_static_var = (bw_real)(s_acc + cfg->accel_static_mps2 * cfg->accel_static_mps2);
    /* a rope with mass moves on its own and moves the balloon with it: the rod model's errors grow with it */
    share = est->catenary ? cfg->rope_kg_m * cfg->tether_length_m / (cfg->mass_kg + 1e-9) : 0.0;
    est->accel_taut_var = (bw_real)(s_acc + cfg->accel_taut_mps2 * cfg->accel_taut_mps2 +
                                    (BW_ROPE_WAVE_ACCEL_MPS2 * share) * (BW_ROPE_WAVE_ACCEL_MPS2 * share));
    est->vertical_gust_var = vertical_gust_var(est, cfg->expected_wind_mps, (bw_real)bw_site_air_density(cfg));
    est->align_var = (bw_real)(cfg->align_rad * cfg->align_rad + (BW_ROPE_WAVE_ALIGN_RAD * share) * (BW_ROPE_WAVE_ALIGN_RAD * share));
    est->baro_var = (bw_real)(cfg->baro_m * cfg->baro_m + BW_BARO_MODEL_M * BW_BARO_MODEL_M);
    est->mag_sigma = cfg->mag_gauss;
    est->declination = (bw_real)(cfg->mag_declination_deg * 0.017453292519943295);
    dt_us = bw_round_half_even(1e6 / cfg->imu_rate_hz);
    est->dt_us = (int64_t)dt_us;
    gap = bw_round_half_even(cfg->max_gap_s * cfg->imu_rate_hz);
    est->max_gap_steps = gap < 1.0 ? 1 : (int32_t)gap;
    schedule_at(&est->sched, cfg->imu_rate_hz, cfg->recover_after_s);
    est->n_dwell = steps_for(cfg->mode_dwell_s * cfg->imu_rate_hz);
    est->n_learn_drag = steps_for(BW_LEARN_DRAG_AFTER_S * cfg->imu_rate_hz);
    est->n_false_release = steps_for(BW_FALSE_RELEASE_S * cfg->imu_rate_hz);
    est->n_taut_pull = steps_for(BW_TAUT_PULL_S * cfg->imu_rate_hz);
    est->n_confirm = steps_for(BW_CONFIRM_S * cfg->imu_rate_hz);
    est->a_accel = (bw_real)(1.0 / (BW_CONSISTENCY_S * cfg->imu_rate_hz));
    est->a_taut = (bw_real)(est->sched.taut_every / (BW_CONSISTENCY_S * cfg->imu_rate_hz));
    est->a_align_innov = (bw_real)(est->sched.taut_every / (BW_ALIGN_INNOV_S * cfg->imu_rate_hz));
    est->a_baro = (bw_real)(1.0 / (BW_CONSISTENCY_S * BW_BARO_NOMINAL_HZ));
    est->a_confirm = (bw_real)(1.0 / (BW_CONFIRM_WINDOW_S * cfg->imu_rate_hz));
    for (i = 0; i < 3; i++)
        bw_status_init(&est->accel_status[i], 0);
    bw_status_init(&est->baro_status, est->sched.baro_recover);
    bw_status_init(&est->heading_status, est->sched.mag_recover);
    for (i = 0; i < 3; i++)
        bw_status_init(&est->mag_status[i], est->sched.mag_recover);
    est->mag_var = (bw_real)(cfg->mag_gauss * cfg->mag_gauss + BW_MAG_MODEL_GAUSS * BW_MAG_MODEL_GAUSS);
    for (i = 0; i < 4; i++)
        bw_status_init(&est->taut_status[i], 0);
    bw_consistency_reset(&est->consistency);
    est->probe.rope_weight_n = BW_R(NAN);
    est->probe.m_eff_kg = BW_R(1.0);
    {
        double dt = 1.0 / cfg->imu_rate_hz;
        est->out.alpha = (bw_real)(dt / (dt + 1.0 / (2.0 * 3.141592653589793 * 1.0)));
        est->out.site_altitude_m = cfg->altitude_amsl_m;
    }
    init_clock(est);
    init_baro(est);
    bw_init_winch(est);
    return 0;
}

void bw_reset(bw_estimator_t *est)
{
    init_clock(est);
    init_baro(est);
    est->ekf.mode = BW_MODE_GROUND;
}

/* attitude of a resting body from gravity (specific force = -g) and the magnetic heading */
static void quat_from_accel_mag(bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my, bw_real mz, bw_real dec,
                                bw_real q[4])
{
    bw_real roll = BW_ATAN2(-ay, -az), pitch = BW_ATAN2(ax, BW_HYPOT(ay, az));
    bw_real cr = BW_COS(roll), sr = BW_SIN(roll), cp = BW_COS(pitch), sp = BW_SIN(pitch);
    bw_real bx = mx * cp + my * sr * sp + mz * cr * sp, by = my * cr - mz * sr;
    bw_real yaw = (bx != BW_R(0.0) || by != BW_R(0.0)) ? BW_ATAN2(-by, bx) + dec : BW_R(0.0);
    bw_real c1 = BW_COS(roll / 2), s1 = BW_SIN(roll / 2), c2 = BW_COS(pitch / 2), s2 = BW_SIN(pitch / 2);
    bw_real c3 = BW_COS(yaw / 2), s3 = BW_SIN(yaw / 2);
    q[0] = c1 * c2 * c3 + s1 * s2 * s3;
    q[1] = s1 * c2 * c3 - c1 * s2 * s3;
    q[2] = c1 * s2 * c3 + s1 * c2 * s3;
    q[3] = c1 * c2 * s3 - s1 * s2 * c3;
}

static void join_in_flight(bw_estimator_t *est, const bw_real q[4])
{
    bw_ekf_t *e = &est->ekf;
    const bw_model_t *m = &e->m;
    bw_real zd = q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3]; /* cos(tilt) */
    bw_real tan_tilt = BW_SQRT(BW_MAX(BW_R(0.0), BW_R(1.0) - zd * zd)) / BW_MAX(zd, BW_R(0.1));
    bw_real lift = bw_lift_n(m, est->rho);
    bw_real spare = lift - (est->catenary ? e->rope_weight_n : m->rope_weight_n);
    bw_real tan_chord = spare > BW_R(0.1) * lift ? tan_tilt * lift / spare : tan_tilt;
    bw_real height = (e->rope_chord_m + m->radius_m) / BW_SQRT(BW_R(1.0) + tan_chord * tan_chord);
    e->mode = BW_MODE_TAUT;
    est->joined = 1;
    est->unconfirmed = 1;
    est->confirm_count = 0;
    est->acc_var = BW_R(-1.0);
    est->counters.mode_switches += 1;
    bw_enter_taut(est, height, 1);
    if (est->zeroing)
        est->join_height = height - m->radius_m;
}

static void initialise(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my,
                       bw_real mz)
{
    bw_real q[4];
    quat_from_accel_mag(ax, ay, az, mx, my, mz, est->declination, q);
    bw_ekf_initialise(&est->ekf, est->cfg, q, (bw_real)-est->cfg->radius_m);
    est->initialised = 1;
    est->t_boot_us = est->t_last_us = est->t_filter_us = est->ekf.time_us = t_us; /* a join's placement is at it */
    if (t_us > BW_JOIN_IN_FLIGHT_US)
        join_in_flight(est, q);
}

static BW_NOINLINE void confirm(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az)
{
    /* control.py _confirm: the balloon's acceleration across its rope (the specific force turned into NED) and the
     * model's innovations there; along the rope the rope's breathing and the vertical air */
    const bw_ekf_t *e = &est->ekf;
    const bw_real pn = e->x[BW_POS_N], pe = e->x[BW_POS_E], pd = e->x[BW_POS_D];
    bw_real *m = est->acc_mean, r[9], a, fn, fe, fd, dn, de, dd, d2, f2, innov2;
    int64_t since;
    int moving, explained, settled;
    bw_rotation(e->q, r);
    bw_horizontal_ned(r, ax, ay, az, &fn, &fe);
    fd = r[6] * ax + r[7] * ay + r[8] * az;
    if (est->acc_var < BW_R(0.0))
        m[0] = fn, m[1] = fe, m[2] = fd, est->acc_var = BW_R(0.0);
    /* the running mean; until its window fills, the mean of the samples since the placement */
    since = e->time_us - e->time_taut_us;
    a = BW_MAX(BW_R(1.0) / (bw_real)(since / est->dt_us + 1), est->a_confirm);
    dn = fn - m[0], de = fe - m[1], dd = fd - m[2];
    m[0] += a * dn;
    m[1] += a * de;
    m[2] += a * dd;
    d2 = pn * pn + pe * pe + pd * pd;
    f2 = dn * dn + de * de + dd * dd;
    innov2 = est->accel_innov2;
    if (d2 > BW_R(1.0)) { /* per axis across the rope: the two axes' share of the three's, less the radius's */
        const bw_real along = dn * pn + de * pe + dd * pd;
        f2 = BW_R(1.5) * (f2 - along * along / d2);
        innov2 = BW_R(1.5) * innov2 - BW_R(0.5) * est->accel_radial_innov2; /* < 0: none across; NaN: not explained */
    }
    est->acc_var += est->innov_alpha * (f2 / BW_R(3.0) - est->acc_var);
    moving = est->acc_var > (bw_real)(BW_CONFIRM_MOTION_MPS2 * BW_CONFIRM_MOTION_MPS2);
    explained = innov2 < (bw_real)BW_CONFIRM_EXPLAINED * est->acc_var;
    /* counted once the placement has settled, when the force balance starts to judge the state */
    settled = since >= (int64_t)(BW_BALANCE_FROM_S * 1e6);
    est->confirm_count = moving && explained && settled ? count_up(est->confirm_count) : 0;
    if (est->confirm_count >= est->n_confirm)
        est->unconfirmed = 0;
}

static void reinitialise_in_flight(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my,
                                   bw_real mz, int mag_ok)
{
    bw_ekf_t *e = &est->ekf;
    bw_real h = isfinite(est->height_baro) ? est->height_baro : BW_R(0.0);
    bw_real q[4];
    if (mag_ok) { /* the accelerometer corrected by the horizontal bias followed, which is kept (the field's frame) */
        quat_from_accel_mag(ax - est->accel_hbias[0], ay - est->accel_hbias[1], az, mx, my, mz, est->declination, q);
    } else { /* keep the heading we had if it is still a rotation, else level */
        bw_real n = BW_SQRT(e->q[0] * e->q[0] + e->q[1] * e->q[1] + e->q[2] * e->q[2] + e->q[3] * e->q[3]);
        int i;
        if (isfinite(n) && n > BW_R(0.5))
            for (i = 0; i < 4; i++)
                q[i] = e->q[i] / n;
        else
            q[0] = BW_R(1.0), q[1] = q[2] = q[3] = BW_R(0.0);
    }
    bw_ekf_initialise(e, est->cfg, q, est->ref_pos_d - h);
    est->ascent_var = BW_R(0.0); /* the drag scale starts afresh: no ascent to weigh again */
    e->P[0][0] = e->P[1][1] = BW_R(100.0) * BW_R(100.0);
    e->mode = h > e->m.release_height_m ? BW_MODE_FREE : BW_MODE_GROUND;
}

bw_real bw_height_for_taut(const bw_estimator_t *est)
{
    bw_real hb = est->height_baro;
    if (isfinite(hb))
        return hb - est->ekf.x[BW_BARO_OFF] - est->ref_pos_d;
    return -est->ekf.x[BW_POS_D];
}

static int rope_would_pull(bw_estimator_t *est)
{
    const bw_real *x = est->ekf.x;
    bw_real pn = x[0], pe = x[1], pd = x[2], vn = x[3], ve = x[4], vd = x[5];
    bw_real dist = BW_SQRT(pn * pn + pe * pe + pd * pd);
    if (dist > BW_R(0.0)) {
        bw_real vr = (vn * pn + ve * pe + vd * pd) / (dist * dist);
        vn = vn - vr * pn, ve = ve - vr * pe, vd = vd - vr * pd;
    }
    {
        const bw_real s[BW_NCOL] = {pn, pe, pd, vn, ve, vd, x[12], x[13], x[14], x[15], x[16]};
        bw_accelerations(&est->ekf.m, est->rho, s, 1, &est->probe);
    }
    return est->probe.taut;
}

static void switch_mode(bw_estimator_t *est, int mode)
{
    est->ekf.mode = mode;
    est->counters.mode_switches += 1;
    est->dwell = 0;
    if (mode == BW_MODE_FREE) /* a free flight of its own: its ascent may learn again (control.py _switch) */
        est->ascent_var = BW_R(0.0);
}

/* a spell of learning the drag starts only where the air flows past the balloon mostly along its vertical: its
 * horizontal relative wind at most BW_ASCENT_AIRFLOW_RATIO times its vertical speed (Estimator._airflow_from_above) */
static int airflow_from_above(const bw_estimator_t *est)
{
    const bw_real *x = est->ekf.x;
    bw_real un = x[BW_WIND_N] - x[BW_VEL_N], ue = x[BW_WIND_E] - x[BW_VEL_E], vd = x[BW_VEL_D];
    return un * un + ue * ue <= (bw_real)(BW_ASCENT_AIRFLOW_RATIO * BW_ASCENT_AIRFLOW_RATIO) * vd * vd;
}

/* the climb tells the drag scale only while the rope's pull is known (Estimator._rope_load_known) */
static int rope_load_known(const bw_estimator_t *est)
{
    const bw_ekf_t *e = &est->ekf;
    const bw_model_t *m = &e->m;
    bw_real lam_g = m->rope_kg_m * (bw_real)BW_G0;
    bw_real height = BW_MIN(BW_MAX(-e->x[2] - m->radius_m, BW_R(0.0)), m->tether_length_m);
    bw_real net_lift = bw_lift_n(m, est->rho) - lam_g * height;
    bw_real spread = bw_anchored_rope_spread(lam_g, BW_HYPOT(e->x[0], e->x[1]), height);
    return spread < (bw_real)BW_DRAG_ASCENT_SIGMA * net_lift;
}

/* control.py _weigh_ascent: the drag scale a free ascent learnt, weighed again once the taut flight has
 * measured the turbulence (its wind speed's variance from TURBULENCE_FROM_S to TURBULENCE_TO_S after the entry):
 * a measurement of sqrt(DRAG_ASCENT_FLOOR^2 + (2 sigma_w / v_climb)^2), never more than its data claimed */
static void weigh_ascent(bw_estimator_t *est, bw_real speed)
{
    int32_t start = est->sched.turbulence_from, end = est->sched.turbulence_to;
    bw_ekf_t *e = &est->ekf;
    bw_real *tb = est->turbulence, d, n, sigma_u2, sigma_w2, climb, var, prior, prior_var, capped, walked, k, s;
    int i, j;
    if (est->dwell <= start) {
        tb[0] = speed, tb[1] = BW_R(0.0), tb[2] = BW_R(0.0);
        return;
    }
    d = speed - tb[0];
    tb[1] += d;
    tb[2] += d * d;
    if (est->dwell < end)
        return;
    n = (bw_real)(end - start);
    sigma_u2 = BW_MAX(BW_R(0.0), tb[2] / n - (tb[1] / n) * (tb[1] / n))
               / (bw_real)bw_kaimal_window_share(BW_TURBULENCE_TO_S - BW_TURBULENCE_FROM_S, (double)(tb[0] + tb[1] / n));
    climb = BW_MAX(est->ascent_climb, BW_R(1.0));
    sigma_w2 = (bw_real)(BW_VERTICAL_TURBULENCE_RATIO * BW_VERTICAL_TURBULENCE_RATIO) * sigma_u2;
    var = BW_MAX(est->ascent_var,
                 (bw_real)(BW_DRAG_ASCENT_FLOOR * BW_DRAG_ASCENT_FLOOR) + BW_R(4.0) * sigma_w2 / (climb * climb));
    prior = est->drag_prior[0], prior_var = est->drag_prior[1];
    /* what the scale's random walk has added since the cap (its variance then: the prior and the data at the
     * weight the cap left it) */
    capped = BW_MAX(est->ascent_var, (bw_real)(BW_DRAG_ASCENT_SIGMA * BW_DRAG_ASCENT_SIGMA));
    walked = BW_MAX(BW_R(0.0), e->P[BW_DRAG][BW_DRAG] -
                                   bw_weighed_variance(prior_var, capped, est->ascent_data - prior,
                                                       (bw_real)BW_DRAG_CONFLICT_SIGMA)); /* as the cap weighed */
    k = e->x[BW_DRAG];
    bw_ekf_weigh_information(e, BW_DRAG, prior, prior_var, est->ascent_data, var, walked, BW_RESET_DRAG,
                             (bw_real)BW_DRAG_CONFLICT_SIGMA);
    e->x[BW_DRAG] = BW_MAX(e->x[BW_DRAG], (bw_real)BW_DRAG_SCALE_MIN);
    est->ascent_var = BW_R(0.0);
    /* the drag the state explains stays: the relative wind moves with k */
    s = BW_SQRT(k / e->x[BW_DRAG]);
    for (i = 0; i < 2; i++) {
        int w = i ? BW_WIND_E : BW_WIND_N, vel = i ? BW_VEL_E : BW_VEL_N;
        e->x[w] = e->x[vel] + s * (e->x[w] - e->x[vel]);
        for (j = 0; j < BW_N_STATES; j++)
            e->P[w][j] *= s;
        for (j = 0; j < BW_N_STATES; j++)
            e->P[j][w] *= s;
    }
}

static void update_mode(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az)
{
    bw_ekf_t *e = &est->ekf;
    const bw_model_t *cfg = &e->m;
    int dwell_ok;
    bw_real pn, pe, pd, dist, length;
    est->dwell = count_up(est->dwell);
    dwell_ok = est->dwell >= est->n_dwell;
    {
        /* a spell starts where the air flows from above and no earlier spell of this free flight awaits its
         * weighing; it goes on while the rope's pull is known (control.py _update_mode) */
        int learning = e->mode == BW_MODE_FREE && est->dwell >= est->n_learn_drag &&
                       (e->learn_drag || (est->ascent_var == BW_R(0.0) && airflow_from_above(est))) &&
                       rope_load_known(est);
        if (learning)
            est->ascent_climb = -e->x[BW_VEL_D];
        if (learning != e->learn_drag) {
            if (learning)
                est->drag_prior[0] = e->x[BW_DRAG], est->drag_prior[1] = e->P[BW_DRAG][BW_DRAG];
            else
                est->ascent_var = bw_ekf_cap_information(e, BW_DRAG, est->drag_prior[0], est->drag_prior[1],
                                                         (bw_real)(BW_DRAG_ASCENT_SIGMA * BW_DRAG_ASCENT_SIGMA),
                                                         BW_RESET_DRAG, (bw_real)BW_DRAG_CONFLICT_SIGMA,
                                                         &est->ascent_data);
        }
        e->learn_drag = learning;
    }
    if (e->mode == BW_MODE_GROUND) {
        int lifted = BW_FABS(BW_SQRT(ax * ax + ay * ay + az * az) - (bw_real)BW_G0) > cfg->release_accel_mps2;
        bw_real hb = est->height_baro;
        int high = isfinite(hb) && hb > cfg->release_height_m;
        est->release_count = lifted ? est->release_count + 1 : 0;
        est->height_above = high ? count_up(est->height_above) : 0;
        if (est->release_count >= est->sched.release_confirm || est->height_above >= est->sched.release_height)
            switch_mode(est, BW_MODE_FREE);
        return;
    }
    pn = e->x[0], pe = e->x[1], pd = e->x[2];
    dist = BW_SQRT(pn * pn + pe * pe + pd * pd);
    length = e->rope_chord_m + cfg->radius_m;
    if (e->mode == BW_MODE_FREE) {
        bw_real hb = est->height_baro;
        int low = isfinite(hb) && hb < cfg->release_height_m;
        int stalled, near;
        int64_t need;
        if (low && est->dwell >= est->n_false_release) {
            /* still at the ground station 3 s after the "release": a bump, not a release */
            est->counters.false_releases += 1;
            switch_mode(est, BW_MODE_GROUND);
            bw_reset_height(e, est->ref_pos_d - hb, est->baro_var);
            return;
        }
        stalled = -pd > BW_R(0.5) * length && -e->x[BW_VEL_D] < BW_R(0.3);
        near = dist >= length - cfg->taut_margin_m || stalled;
        est->pulling = near && rope_would_pull(est) ? count_up(est->pulling) : 0;
        /* back to taut after the rope went slack: only once it has pulled for a while (no flapping) */
        need = est->was_slack ? est->n_taut_pull : 1;
        if (dwell_ok && est->pulling >= need) {
            switch_mode(est, BW_MODE_TAUT);
            bw_enter_taut(est, bw_height_for_taut(est), 0);
            est->consistency.lean_tilt = est->consistency.lean_misfit = BW_R(0.0); /* a new taut stretch's own lean */
        }
    } else {
        est->slack = e->forces.taut ? 0 : count_up(est->slack);
        if (dwell_ok && est->slack >= est->n_dwell) {
            switch_mode(est, BW_MODE_FREE);
            est->was_slack = 1;
        }
    }
}

static void monitor(bw_estimator_t *est)
{
    bw_consistency_t *mon = &est->consistency;
    const int64_t t = est->ekf.time_us;
    const bw_status_t *radius = &est->taut_status[0], *an = &est->taut_status[2],
                      *ae = &est->taut_status[3], *b = &est->baro_status, *mg = est->mag_status;
    const bw_real taut_alpha = est->a_taut;
    int i;
    /* the accelerometer's NIS is added where it is fused (bw_control_accel) */
    if (an->time_test_us == t && an->innov_var > BW_R(0.0) && ae->innov_var > BW_R(0.0))
        /* against the noise it was fused with (control.py _monitor) */
        bw_consistency_add(mon, BW_ALIGN,
                           BW_R(0.5) * (an->innov * an->innov / an->innov_var + ae->innov * ae->innov / ae->innov_var),
                           taut_alpha);
    if (radius->time_test_us == t && radius->innov_var > BW_R(0.0))
        bw_consistency_add(mon, BW_RADIUS, radius->innov * radius->innov / radius->innov_var, taut_alpha);
    if (b->time_test_us == t && b->innov_var > BW_R(0.0))
        bw_consistency_add(mon, BW_BARO, b->innov * b->innov / b->innov_var,
                           est->a_baro);
    if (mg[0].time_test_us == t && mg[0].innov_var > BW_R(0.0)) {
        bw_real nis = BW_R(0.0);
        for (i = 0; i < 3; i++)
            if (mg[i].innov_var > BW_R(0.0))
                nis += mg[i].innov * mg[i].innov / mg[i].innov_var;
        bw_consistency_add(mon, BW_MAG, nis / BW_R(3.0), est->a_accel);
    }
    bw_consistency_evaluate(mon);
}

int bw_on_baro(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c)
{
    return bw_baro_sample(est, t_us, pressure_hpa, temperature_c);
}

static int on_imu_body(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay, bw_real az, bw_real gx,
                       bw_real gy, bw_real gz, bw_real mx, bw_real my, bw_real mz);

/* An IMU mounted askew, as the design declares it (cfg imu_roll_deg, imu_pitch_deg): its readings turned into the
 * balloon's axes, M^T v with M the body -> IMU matrix of rotation.py imu_mount, then the filter's step (a call of
 * its own, which the compiler makes a tail call: its frame is gone before the step's deepest stack, where a call
 * that returned would add 80 B to it on the Cortex-M4F). */
static BW_NOINLINE int on_imu_mounted(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay,
                                                    bw_real az, bw_real gx, bw_real gy, bw_real gz, bw_real mx,
                                                    bw_real my, bw_real mz)
{
    bw_real roll = (bw_real)est->cfg->imu_roll_deg * (BW_PI / BW_R(180.0));
    bw_real pitch = (bw_real)est->cfg->imu_pitch_deg * (BW_PI / BW_R(180.0));
    bw_real cr = BW_COS(roll), sr = BW_SIN(roll), cp = BW_COS(pitch), sp = BW_SIN(pitch);
    const bw_real m[9] = {cp, sr * sp, -cr * sp, BW_R(0.0), cr, sr, sp, -sr * cp, cr * cp};
    return on_imu_body(est, t_us, m[0] * ax + m[3] * ay + m[6] * az, m[1] * ax + m[4] * ay + m[7] * az,
                       m[2] * ax + m[5] * ay + m[8] * az, m[0] * gx + m[3] * gy + m[6] * gz,
                       m[1] * gx + m[4] * gy + m[7] * gz, m[2] * gx + m[5] * gy + m[8] * gz,
                       m[0] * mx + m[3] * my + m[6] * mz, m[1] * mx + m[4] * my + m[7] * mz,
                       m[2] * mx + m[5] * my + m[8] * mz);
}

int bw_on_imu(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay, bw_real az, bw_real gx, bw_real gy,
              bw_real gz, bw_real mx, bw_real my, bw_real mz)
{
    if (est->mount)
        return on_imu_mounted(est, t_us, ax, ay, az, gx, gy, gz, mx, my, mz);
    return on_imu_body(est, t_us, ax, ay, az, gx, gy, gz, mx, my, mz);
}

static int on_imu_body(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay, bw_real az, bw_real gx,
                       bw_real gy, bw_real gz, bw_real mx, bw_real my, bw_real mz)
{
    bw_counters_t *c = &est->counters;
    bw_ekf_t *e = &est->ekf;
    int mag_ok;
    int64_t d, steps, i;
    bw_real r[9], rad, v_pred, v_accel, v_aids, vn, ve, pv, var;
    int lost;
    int32_t resets;
    if (!(finite3(ax, ay, az, (bw_real)BW_ACC_MAX) && finite3(gx, gy, gz, (bw_real)BW_GYRO_MAX))) {
        c->rejected += 1;
        return 0;
    }
    mag_ok = finite3(mx, my, mz, (bw_real)BW_MAG_MAX) && (mx != BW_R(0.0) || my != BW_R(0.0) || mz != BW_R(0.0));
    if (!est->initialised) {
        if (!(mag_ok && az < BW_R(0.0))) { /* a start needs the field and the bottom down (Estimator.on_imu) */
            c->rejected += 1;
            return 0;
        }
        initialise(est, t_us, ax, ay, az, mx, my, mz);
        c->imu_samples += 1;
        return 1;
    }
    d = t_us - est->t_last_us;
    if (d == 0) {
        c->duplicates += 1;
        return 0;
    }
    if (d < 0) {
        if (d > -BW_REORDER_WINDOW_US) {
            c->reordered += 1;
            return 0;
        }
        steps = e->mode != BW_MODE_GROUND; /* (no local of its own: the stack's budget) */
        c->time_resets += 1;
        bw_reset(est);
        if (mag_ok && az < BW_R(0.0)) { /* the new boot's first sample starts the filter again: it is counted */
            initialise(est, t_us, ax, ay, az, mx, my, mz);
            if (steps && !(t_us > BW_JOIN_IN_FLIGHT_US)) /* it rebooted while flying: the balloon is still up */
                join_in_flight(est, e->q);                /* (Estimator._initialise's in_flight) */
            c->imu_samples += 1;
        }
        return 0;
    }
    c->imu_samples += 1;
    est->t_last_us = t_us;
    d = t_us - est->t_filter_us + est->dt_us / 2;
    steps = d >= 0 ? d / est->dt_us : -((-d + est->dt_us - 1) / est->dt_us); /* Python's floor division */
    if (steps <= 0) {
        c->jitter += 1;
    } else if (steps > 1) {
        c->gaps += 1;
        /* the attitude, predicted on a rate held from before the gap (or not at all beyond max_gap_s), grows by what
         * that rate cannot know: its change across the gap (bw_gap_attitude_var) */
        lost = steps > est->max_gap_steps;
        var = bw_gap_attitude_var(est->last_gyro, gx, gy, gz, (bw_real)((steps - 1) * est->dt_us) * BW_R(1e-6), lost);
        if (lost) {
            c->long_gaps += 1;
            /* predict the last max_gap_s; the covariance grows by the process noise of the rest */
            bw_ekf_inflate(e, (bw_real)(steps - est->max_gap_steps));
            est->t_filter_us = t_us - est->max_gap_steps * est->dt_us;
            steps = est->max_gap_steps;
        }
        bw_ekf_inflate_attitude(e, var);
    }
    /* the tether pulls at the bottom of the sphere: where that is depends on the attitude */
    bw_rotation(e->q, r);
    rad = e->m.radius_m;
    e->forces.attach_ned[0] = est->probe.attach_ned[0] = rad * r[2];
    e->forces.attach_ned[1] = est->probe.attach_ned[1] = rad * r[5];
    e->forces.attach_ned[2] = est->probe.attach_ned[2] = rad * r[8];
    if (est->catenary)
        e->forces.rope_weight_n = est->probe.rope_weight_n = e->rope_weight_n;
    for (i = 0; i < steps; i++) {
        if (i == steps - 1)
            bw_ekf_predict(e, gx, gy, gz, est->rho);
        else
            bw_ekf_predict(e, est->last_gyro[0], est->last_gyro[1], est->last_gyro[2], est->rho);
        est->t_filter_us += est->dt_us;
        est->step += 1;
        if (++e->taut_phase == est->sched.taut_every)
            e->taut_phase = 0;
        if (++e->noise_phase == est->sched.wind_noise_every)
            e->noise_phase = 0;
    }
    est->last_gyro[0] = gx, est->last_gyro[1] = gy, est->last_gyro[2] = gz;
    e->time_us = est->t_filter_us;
    vn = e->x[BW_VEL_N], ve = e->x[BW_VEL_E]; /* the velocity predicted and its variance (the balance) */
    pv = e->P[BW_VEL_N][BW_VEL_N] + e->P[BW_VEL_E][BW_VEL_E], resets = e->reset_count;
    bw_ekf_begin_update(e);
    v_pred = bw_field_variance(e, est->field_ned);
    bw_control_accel(est, ax, ay, az);
    v_accel = bw_field_variance(e, est->field_ned);
    if (est->unconfirmed)
        confirm(est, ax, ay, az);
    bw_control_baro(est);
    bw_control_winch(est);
    if (mag_ok) /* the field is learnt in the frame the followed horizontal bias is corrected in (a landing's) */
        bw_control_mag(est, ax - est->accel_hbias[0], ay - est->accel_hbias[1], az, mx, my, mz);
    v_aids = bw_field_variance(e, est->field_ned);
    bw_control_tether(est);
    if (!bw_ekf_end_update(e)) {
        c->numeric_resets += 1;
        reinitialise_in_flight(est, ax, ay, az, mx, my, mz, mag_ok);
        return 1;
    }
    if (e->mode == BW_MODE_TAUT && e->reset_count == resets) {
        /* consistency.py Consistency.add_balance: the velocity's updates, their mean, and the variance that mean
         * has where each update is white with what it took from P; the force balance's NIS at the tether's rate,
         * from BALANCE_FROM_S after the last taut placement (before, its own convergence pulls the velocity), the
         * mean and its variance from zero then (held there at the tether's rate until) */
        bw_consistency_t *m = &est->consistency;
        const bw_real a = est->a_accel, keep = BW_R(1.0) - a,
                      taken = BW_MAX(pv - (e->P[BW_VEL_N][BW_VEL_N] + e->P[BW_VEL_E][BW_VEL_E]), BW_R(0.0));
        m->balance_n += a * (e->x[BW_VEL_N] - vn - m->balance_n);
        m->balance_e += a * (e->x[BW_VEL_E] - ve - m->balance_e);
        m->balance_var = keep * keep * m->balance_var + a * a * taken;
        if (e->taut_phase == 0) {
            if (e->time_us - e->time_taut_us < (int64_t)(BW_BALANCE_FROM_S * 1e6))
                m->balance_n = m->balance_e = m->balance_var = BW_R(0.0);
            else
                bw_consistency_add_clipped(m, BW_FORCE, bw_balance_nis(m), est->a_taut, (bw_real)BW_FORCE_NIS_CLIP);
        }
    }
    if (e->mode != BW_MODE_GROUND) {
        /* control.py: each source's NIS against the noise it was fused with, over its own interval */
        const bw_real corr = (bw_real)BW_ACCEL_MODEL_CORR_S;
        const bw_real nominal = bw_accel_nominal_var(est);
        const bw_real nis_accel = est->consistency.nis[BW_ACCEL] * nominal / (nominal + est->accel_var_excess);
        e->field_att_extra = bw_field_attitude_extra(
            e->field_att_extra, v_pred, v_accel, v_aids, bw_field_variance(e, est->field_ned),
            bw_correlated_weight(nis_accel, e->dt, corr),
            bw_correlated_weight(est->consistency.nis[BW_ALIGN], (bw_real)est->sched.taut_every * e->dt, corr));
    } else {
        e->field_att_extra = BW_R(0.0);
    }
    update_mode(est, ax, ay, az);
    if (e->mode != BW_MODE_GROUND)
        monitor(est);
    if (e->mode == BW_MODE_TAUT) {
        bw_real wn = e->x[BW_WIND_N], we = e->x[BW_WIND_E];
        bw_real speed = BW_SQRT(wn * wn + we * we), dev = speed - est->mean_speed;
        est->mean_speed += mean_weight(est, dev) * dev;
        est->speed_var += est->speed_alpha * (dev * dev - est->speed_var);
        if (est->ascent_var > BW_R(0.0))
            weigh_ascent(est, speed);
        if (e->noise_phase == 0) {
            est->vertical_gust_var = vertical_gust_var(est, est->mean_speed, est->rho);
            bw_ekf_adapt_wind_noise(e, est->mean_speed, turbulence_excess(est));
        }
    }
    return 1;
}

void bw_coast(bw_estimator_t *est, bw_real seconds)
{
    if (est->initialised)
        bw_ekf_inflate(&est->ekf, seconds * est->ekf.m.imu_rate_hz);
}

bw_real bw_wind_accuracy(const bw_estimator_t *est)
{
    const bw_ekf_t *e = &est->ekf;
    bw_real wn = e->x[BW_WIND_N], we = e->x[BW_WIND_E], speed = BW_SQRT(wn * wn + we * we), sys_var = BW_R(0.0), acc,
            w = bw_ekf_wind_accuracy(e);
    if (e->mode != BW_MODE_GROUND) {
        const bw_model_t *m = &e->m;
        bw_real lean = BW_R(0.0);
        if (e->mode == BW_MODE_TAUT) {
            /* the attitude's variance across the lean, as a tilt, with the larger of what P does not hold about the
             * field's axis counted and seen (control.py lean_wind_mps) */
            bw_real r[9], zn, ze, zd, tilt, extra, cross_var = BW_R(0.0);
            bw_rotation(e->q, r);
            zn = r[2], ze = r[5], zd = r[8];
            tilt = BW_HYPOT(zn, ze);
            if (tilt > BW_R(0.0))
                cross_var = bw_lean_variance(e, ze / tilt, -zn / tilt, zn, ze, zd);
            extra = BW_MAX(e->field_att_extra, bw_heading_misfit_variance(&est->consistency));
            cross_var = bw_lean_tilt_variance(cross_var, extra, est->field_ned, zn, ze, zd);
            lean = bw_lean_bias_wind(wn, we, bw_lift_n(m, est->rho), e->x[BW_DRAG] * est->rho * m->half_cd_area_m2,
                                     bw_lean_bias_rad((bw_real)est->cfg->accel_bias_walk_mps2_rt_s,
                                                      (bw_real)(e->time_us - est->t_boot_us) * BW_R(1e-6)),
                                     est->field_ned, cross_var, bw_bias_tilt_rad(est->accel_hbias_var),
                                     (bw_real)est->cfg->imu_alignment_deg * (BW_PI / BW_R(180.0)));
        }
        sys_var = bw_systematic_variance(speed, e->x[BW_DRAG], e->P[BW_DRAG][BW_DRAG], lean);
    }
    acc = BW_SQRT(w * w + sys_var) * est->consistency.inflation;
    if (e->mode == BW_MODE_TAUT) { /* not scaled by the monitor's factor, which measures the same misfit (control.py) */
        acc = BW_HYPOT(acc, bw_lean_misfit_wind(speed, est->consistency.lean_tilt, est->consistency.lean_misfit));
        if (e->time_taut_us >= 0) /* the snap still settling */
            acc = BW_HYPOT(acc, bw_placement_settling_wind((bw_real)(e->time_us - e->time_taut_us) * BW_R(1e-6),
                                                           BW_MAX(speed, est->wind_taut_mps)));
    }
    if (est->unconfirmed)
        acc = BW_MAX(acc, BW_SQRT(wn * wn + we * we + BW_R(1.0)));
    if (e->mode != BW_MODE_GROUND) { /* no magnetometer for HEADING_LOST_S: the heading is the gyro's alone */
        int64_t last = est->mag_status[0].time_last_fuse_us;
        bw_real seconds;
        last = BW_MAX(BW_MAX(last, est->heading_status.time_last_fuse_us), est->t_boot_us);
        seconds = (bw_real)(e->time_us - last) * BW_R(1e-6);
        if (seconds > (bw_real)BW_HEADING_LOST_S)
            acc = BW_HYPOT(acc, bw_gyro_heading_wind(speed, (bw_real)est->cfg->init_gyro_bias_dps *
                                                                (BW_PI / BW_R(180.0)), seconds));
    }
    if (e->field_heading_var > BW_R(0.0)) /* a magnetometer offset turned with the balloon (aid_mag.c) */
        acc = BW_HYPOT(acc, speed * BW_SQRT(e->field_heading_var));
    return acc;
}
