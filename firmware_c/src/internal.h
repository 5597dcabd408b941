/* The core's internal interface: one header for the modules of src/ (each the C twin of the
 * firmware_py/estimator module of the same name). */
#ifndef BW_INTERNAL_H
#define BW_INTERNAL_H

#include "bw_core.h"
#include "generated.h"
#include "params.h"

/* Python's max(a, b) / min(a, b): the first unless the second is strictly larger / smaller (NaN-exact) */
#define BW_MAX(a, b) ((b) > (a) ? (b) : (a))
#define BW_MIN(a, b) ((b) < (a) ? (b) : (a))
#define BW_PI BW_R(3.14159265358979323846)
/* a function kept out of its caller (its frame off the caller's stack; GCC and Clang, elsewhere a hint lost) */
#if defined(__GNUC__)
#define BW_NOINLINE __attribute__((noinline))
#else
#define BW_NOINLINE
#endif
#define BW_DEG BW_R(0.017453292519943295)
#define BW_G0 9.80665
#define BW_R_AIR 287.05
#define BW_LAPSE_K_M 0.0065

/* the states the balloon model's Jacobians are taken over (state.py MODEL_COLUMNS) */
extern const int BW_MODEL_COLS[BW_NCOL];

/* balloon_core: rotation.py, atmosphere.py */
void bw_rotation(const bw_real q[4], bw_real r[9]);
/* accel.py horizontal_ned: a body-frame vector's north and east parts (r: R; the accelerometer's rows and a join's
 * confirmation) */
static inline void bw_horizontal_ned(const bw_real r[9], bw_real x, bw_real y, bw_real z, bw_real *n, bw_real *e)
{
    *n = r[0] * x + r[1] * y + r[2] * z;
    *e = r[3] * x + r[4] * y + r[5] * z;
}
bw_real bw_air_density(bw_real pressure_pa, bw_real temperature_k);
double bw_site_air_density(const bw_config_t *c);
double bw_round_half_even(double v);

/* tuning.py */
void bw_wind_process(double mean_mps, double ti, double diameter_m, double *tau_s, double *q_rate, double *q_walk);
double bw_kaimal_window_share(double window_s, double mean_mps);

/* model.py */
/* BalloonModel.lift_n: the balloon's own net lift in air of density rho (the rope not counted) */
static inline bw_real bw_lift_n(const bw_model_t *m, bw_real rho)
{
    return (rho * m->volume_m3 - m->mass_kg) * (bw_real)BW_G0;
}
void bw_accelerations(const bw_model_t *m, bw_real rho, const bw_real s[BW_NCOL], int taut, bw_forces_t *out);

/* catenary.py */
void bw_rope_chord(bw_real fn, bw_real fe, bw_real fd, bw_real length_m, bw_real weight_n_m, bw_real drag_kg_m2,
                   bw_real wn, bw_real we, bw_real chord[3]);
double bw_calm_weight_share(double lift_n, double rope_weight_n);
bw_real bw_anchored_rope_spread(bw_real weight_n_m, bw_real span_m, bw_real height_m);
bw_real bw_effective_rod(bw_real fn, bw_real fe, bw_real fd, bw_real cn, bw_real ce, bw_real cd, bw_real rope_weight_n);

/* ekf.py */
void bw_ekf_init(bw_ekf_t *e, const bw_config_t *c);
void bw_ekf_initialise(bw_ekf_t *e, const bw_config_t *c, const bw_real q[4], bw_real pos_d);
void bw_ekf_reset(bw_ekf_t *e, int kind);
void bw_ekf_predict(bw_ekf_t *e, bw_real gx, bw_real gy, bw_real gz, bw_real rho);
void bw_ekf_adapt_wind_noise(bw_ekf_t *e, bw_real mean_speed_mps, bw_real excess);
void bw_ekf_inflate(bw_ekf_t *e, bw_real steps);
bw_real bw_gap_attitude_var(const bw_real *last, bw_real gx, bw_real gy, bw_real gz, bw_real held_s, int lost);
void bw_ekf_inflate_attitude(bw_ekf_t *e, bw_real var);
void bw_ekf_begin_update(bw_ekf_t *e);
bw_real bw_lean_variance(const bw_ekf_t *e, bw_real cn, bw_real ce, bw_real zn, bw_real ze, bw_real zd);
/* ekf.py fuse: a scalar row; the attitude's rows of the gain take att_gain of it (the alignment's, aid_tether.c) */
int bw_ekf_fuse_gain(bw_ekf_t *e, bw_real innov, bw_real r, bw_status_t *st, bw_real gate, int recover,
                     bw_real att_gain);
static inline int bw_ekf_fuse(bw_ekf_t *e, bw_real innov, bw_real r, bw_status_t *st, bw_real gate, int recover)
{
    return bw_ekf_fuse_gain(e, innov, r, st, gate, recover, BW_R(1.0));
}
int bw_ekf_fuse3(bw_ekf_t *e, bw_real i0, bw_real i1, bw_real i2, bw_real r, bw_status_t st[3],
                 bw_real r2_extra, bw_real tilt_gain, bw_real heading_gain, const bw_real axis[3], bw_real axis_var);
int bw_ekf_end_update(bw_ekf_t *e);
void bw_ekf_fix_covariance(bw_ekf_t *e);
bw_real bw_ekf_wind_accuracy(const bw_ekf_t *e);
bw_real bw_ekf_cap_information(bw_ekf_t *e, int i, bw_real prior, bw_real prior_var, bw_real data_var_min, int kind,
                               bw_real conflict_sigma, bw_real *data);
bw_real bw_weighed_variance(bw_real prior_var, bw_real data_var, bw_real d, bw_real conflict_sigma);
void bw_ekf_weigh_information(bw_ekf_t *e, int i, bw_real prior, bw_real prior_var, bw_real data, bw_real data_var,
                              bw_real walked_var, int kind, bw_real conflict_sigma);
void bw_status_init(bw_status_t *st, int32_t recover_after);

/* consistency.py */
void bw_consistency_reset(bw_consistency_t *m);
void bw_consistency_add_clipped(bw_consistency_t *m, int source, bw_real nis, bw_real alpha, bw_real clip);
void bw_consistency_add(bw_consistency_t *m, int source, bw_real nis, bw_real alpha);
bw_real bw_balance_nis(const bw_consistency_t *m);
void bw_consistency_evaluate(bw_consistency_t *m);
bw_real bw_heading_misfit_variance(const bw_consistency_t *m);
void bw_consistency_add_lean(bw_consistency_t *m, bw_real tilt, bw_real misfit, bw_real alpha);
bw_real bw_lean_misfit_wind(bw_real speed, bw_real tilt, bw_real misfit);
bw_real bw_placement_settling_wind(bw_real seconds, bw_real speed);
bw_real bw_gyro_heading_wind(bw_real speed, bw_real gyro_bias_rad_s, bw_real seconds);
bw_real bw_field_variance(const bw_ekf_t *e, const bw_real field_ned[3]);
bw_real bw_attitude_variance(const bw_ekf_t *e, bw_real g0, bw_real g1, bw_real g2);
/* consistency.py lean_jacobian: c . d z / d att = z x c, the body's down axis z along a component c = (cn, ce, cd)
 * (horizontal where cd = 0) */
static inline void bw_lean_jacobian(bw_real cn, bw_real ce, bw_real cd, bw_real zn, bw_real ze, bw_real zd,
                                    bw_real g[3])
{
    g[0] = ze * cd - ce * zd, g[1] = cn * zd - zn * cd, g[2] = ce * zn - cn * ze;
}
bw_real bw_correlated_weight(bw_real nis, bw_real dt_s, bw_real corr_s);
bw_real bw_field_attitude_extra(bw_real extra, bw_real v_pred, bw_real v_accel, bw_real v_aids, bw_real v_end,
                                bw_real w_accel, bw_real w_align);
bw_real bw_lean_tilt_variance(bw_real cross_var, bw_real extra, const bw_real field_ned[3], bw_real zn, bw_real ze,
                              bw_real zd);
bw_real bw_systematic_variance(bw_real speed_mps, bw_real drag_scale, bw_real drag_scale_var, bw_real lean_wind_mps);
bw_real bw_bias_tilt_rad(bw_real hbias_var);
bw_real bw_lean_bias_rad(bw_real walk_mps2_rt_s, bw_real seconds);
bw_real bw_lean_bias_wind(bw_real wind_n, bw_real wind_e, bw_real lift_n, bw_real drag_per_speed2,
                          bw_real lean_bias_rad, const bw_real field_ned[3], bw_real cross_tilt_var,
                          bw_real held_bias_rad, bw_real mount_rad);
/* inline: on the step's path */
/* consistency.py accel_misfit: the accelerometer's windowed NIS from BW_FLAG_NIS (0) to twice that (1) */
static inline bw_real bw_accel_misfit(bw_real nis)
{
    return BW_MIN(BW_R(1.0), BW_MAX(BW_R(0.0), nis / (bw_real)BW_FLAG_NIS - BW_R(1.0)));
}

/* consistency.py field_tilt_reading: the horizontal innovation (NED) read as a rotation about the field's axis */
static inline bw_real bw_field_tilt_reading(bw_real innov_n, bw_real innov_e, const bw_real field_ned[3])
{
    const bw_real bh2 = field_ned[0] * field_ned[0] + field_ned[1] * field_ned[1];
    if (!(bh2 > BW_R(0.0)))
        return BW_R(0.0);
    return (innov_e * field_ned[0] - innov_n * field_ned[1]) * BW_SQRT(bh2 + field_ned[2] * field_ned[2]) /
           ((bw_real)BW_G0 * bh2);
}

/* consistency.py Consistency.add_slow_tilt: low-passed over BW_SLOW_INNOV_S, its square over the window */
static inline void bw_consistency_add_slow_tilt(bw_consistency_t *m, bw_real reading, bw_real alpha)
{
    m->slow_tilt += alpha * (bw_real)(BW_CONSISTENCY_S / BW_SLOW_INNOV_S) * (reading - m->slow_tilt);
    m->slow_tilt_var += alpha * (m->slow_tilt * m->slow_tilt - m->slow_tilt_var);
}

/* aid sources */
bw_real bw_accel_nominal_var(const bw_estimator_t *est);
void bw_control_accel(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az);
int bw_baro_sample(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c);
void bw_control_baro(bw_estimator_t *est);
void bw_reset_height(bw_ekf_t *e, bw_real pos_d, bw_real var);
void bw_control_mag(bw_estimator_t *est, bw_real ax, bw_real ay, bw_real az, bw_real mx, bw_real my, bw_real mz);
void bw_control_tether(bw_estimator_t *est);
void bw_enter_taut(bw_estimator_t *est, bw_real height_m, int from_tilt);

/* aid_sources/winch.py, aid_sources/ground_ref.py */
void bw_init_winch(bw_estimator_t *est);
void bw_control_winch(bw_estimator_t *est);
void bw_init_ground_ref(bw_estimator_t *est);

/* control.py */
bw_real bw_height_for_taut(const bw_estimator_t *est);

#endif
