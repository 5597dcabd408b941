/* balloon-wind: the wind estimator's C99 core (docs/porting.md).
 *
 * The same filter as firmware_py/estimator (the readable reference), line for line: input checks, the
 * fixed-step clock, modes, every aid source with its status, resets, the consistency monitor and the
 * WIND_COV fields. Static memory only (the caller owns one bw_estimator_t), no recursion, bounded work
 * per sample, libm's sqrt/sin/cos/atan2/exp/log only. No MAVLink: the caller decodes HIGHRES_IMU and
 * SCALED_PRESSURE and encodes WIND_COV.
 *
 * Units: SI unless the name says otherwise; time in microseconds of the sensor's clock (time_usec);
 * frames NED (origin at the anchor) and body FRD.
 *
 *   bw_config_t cfg; bw_config_default(&cfg);  (then set the design's values)
 *   static bw_estimator_t est; bw_init(&est, &cfg);
 *   per IMU sample:   bw_on_imu(&est, t_us, ax, ay, az, gx, gy, gz, mx, my, mz);  (NAN field: no magnetometer)
 *   per baro sample:  bw_on_baro(&est, t_us, pressure_hpa, temperature_c);
 *   when a WIND_COV is due: bw_wind_cov(&est, &fields);
 */
#ifndef BW_CORE_H
#define BW_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "bw_real.h"

#define BW_N 19       /* states: pos (3), vel (3), attitude error (3), gyro bias (3), wind (2), wind rate (2), drag scale, baro offset, z accel bias */
#define BW_NCOL 11    /* the balloon model's Jacobian columns: pos, vel, wind, wind rate, drag scale */

/* The design and the [filter] tuning, as numbers (the Python binding fills it from the design file). */
typedef struct {
    /* the balloon model (firmware_py/estimator/model.py BalloonModel) */
    double radius_m, volume_m3, mass_kg;
    double half_cd_area_m2;      /* 1/2 Cd pi r^2 */
    double tether_length_m;      /* anchor to the attachment point */
    double rope_kg_m;            /* rope mass per metre */
    double rope_drag_m2;         /* the balloon's share of a straight rope's drag, 1/4 Cn d L (paper's rod; 0 for the catenary) */
    double rope_cn_d_m;          /* Cn d of the rope */
    /* [sensors], 1-sigma */
    double accel_mps2, baro_m, gyro_dps, mag_gauss;
    /* [site] */
    double mag_declination_deg;
    double ground_pressure_hpa;  /* NAN: the barometer is zeroed at boot */
    double altitude_amsl_m;
    /* [filter] (firmware_py/estimator/state.py FilterConfig) */
    double imu_rate_hz;
    double accel_process_mps2, expected_wind_mps, turbulence_intensity, drag_walk_rt_s, baro_walk_m_rt_s;
    double accel_bias_walk_mps2_rt_s, gyro_bias_walk_dps_rt_s;
    double accel_model_mps2, accel_taut_mps2, accel_static_mps2, align_rad, radial_m, radial_rate_mps;
    double rope_catenary;        /* 1: rope_model "catenary" (the rope's real shape); 0: "paper" (Eq. 5); a double: the config is 46 doubles */
    double gate_sigma, recover_after_s;
    double init_wind_mps, init_drag, init_accel_bias_mps2, init_gyro_bias_dps, init_tilt_deg, init_yaw_deg;
    double taut_margin_m, mode_dwell_s, release_accel_mps2, release_height_m, max_gap_s;
    /* [sensors], the IMU's mounting (last: a positional initialiser of the fields before them stays as it was) */
    double imu_alignment_deg;    /* how well the IMU's axes are known against the tether's axis, deg */
    double imu_roll_deg, imu_pitch_deg; /* the IMU's axes against the balloon's, measured: readings turned back */
} bw_config_t;

/* One aid source's last test (PX4's estimator_aid_source status). */
typedef struct {
    bw_real innov, innov_var, test_ratio;
    int32_t fused, rejected, consecutive_rejects;
    int32_t recover_after;        /* consecutive rejections before a forced fusion (0: the filter's) */
    int64_t time_last_fuse_us;    /* filter time of the last fusion, -1 never */
    int64_t time_test_us;         /* filter time of the last innovation test */
} bw_status_t;

typedef struct {
    /* 32 bits, unsigned (they wrap, never overflow): 497 days of samples at 100 Hz (the RAM's budget, docs/porting.md) */
    uint32_t imu_samples, baro_samples, rejected, duplicates, reordered, jitter, gaps, long_gaps, time_resets,
        numeric_resets, taut_resets, mode_switches, baro_resets, false_releases, field_jumps;
} bw_counters_t;

/* the balloon model at one state (model.py Forces) */
typedef struct {
    bw_real an, ae, ad;           /* model acceleration, NED, m/s^2 */
    bw_real ja[3 * BW_NCOL];      /* d a / d x, row-major */
    bw_real jpull[BW_NCOL];       /* d (tension / m_eff) / d x (taut) */
    bw_real tension_n, m_eff_kg;
    int32_t taut;
    bw_real params[10];           /* the generated functions' parameters at this step */
    bw_real attach_ned[3];        /* input: attachment point relative to the centre, NED */
    bw_real rope_weight_n;        /* input: weight the taut rod carries (catenary.py W_eff), NAN: Eq. 5 */
} bw_forces_t;

/* what the step uses of the configuration, in the core's real type (no double on the step's path) */
typedef struct {
    bw_real radius_m, volume_m3, mass_kg, half_cd_area_m2, tether_length_m, rope_kg_m, rope_drag_m2, rope_cn_d_m;
    bw_real lam_g;               /* rope weight per metre, N/m */
    bw_real rope_weight_n;       /* the whole rope's weight, N */
    bw_real turbulence_intensity, release_height_m, release_accel_mps2, taut_margin_m, imu_rate_hz;
    bw_real gate_sigma, gate2, radial_var, radial_rate_var;
} bw_model_t;

typedef struct {
    /* the filter (ekf.py WindEkf) */
    bw_model_t m;
    bw_real x[BW_N];
    bw_real q[4];                 /* nominal attitude, body FRD -> NED, scalar first */
    bw_real P[BW_N][BW_N];
    bw_real T[BW_N][BW_N];        /* scratch: F P (F itself is generated row by row: ekf.c f_row) */
    bw_real h[BW_N], dx[BW_N], ph[BW_N];
    bw_real H3[3][BW_N], pht[BW_N][3];
    bw_real var_max[BW_N];
    bw_real q_flight[BW_N];      /* process noise per step in flight (diagonal) */
    bw_real q_ground[BW_N], qd_ground[BW_N];  /* on the ground: for a gap (inflate), per step (predict, follows the wind) */
    bw_real dt, rate_decay, q_rate0, u0, q_walk_step;
    bw_real wp_tau_s, wp_q_rate, wp_q_walk, sigma_rate;
    bw_forces_t forces;
    bw_real rope_chord_m, rope_weight_n;      /* catenary.py RopeShape */
    bw_real rope_rate_mps;       /* the chord's rate while a winch reels (0: none) */
    uint8_t mode, learn_drag, drag_correlated; /* one byte each: the RAM (docs/porting.md) */
    uint8_t field_window;        /* the estimator's (aid_mag.c learn_field_in_flight), in this struct's hole */
    int32_t recover_after;
    bw_real field_heading_var;   /* the estimator's (aid_mag.c, control.c: the heading's variance a body-fixed
                                  * magnetometer offset may hold unseen, rad^2), in this struct's hole */
    int64_t time_us;
    int64_t time_taut_us;        /* the filter's time of the last taut placement (RESET_TAUT), -1 never */
    int32_t taut_phase, noise_phase;   /* step % taut_every, step % wind_noise_every */
    int32_t reset_counts[4];
    int32_t reset_count;
    bw_real field_att_extra;     /* the attitude's variance about the field's axis that P does not hold (consistency.c) */
} bw_ekf_t;

typedef struct {
    bw_real nis[6];
    int32_t flags;
    bw_real inflation;
    int32_t flag_changes;
    bw_real slow_tilt, slow_tilt_var;  /* the accelerometer's slow innovation as a tilt about the field, its mean square */
    bw_real balance_n, balance_e, balance_var; /* the velocity's updates, their mean; that mean's variance if consistent */
    bw_real lean_tilt, lean_misfit; /* the body's taut tilt and the alignment's along innovation, their means */
} bw_consistency_t;

typedef struct {
    int32_t taut_every, align_reset, baro_reset, baro_recover, mag_recover, field_learn, field_flight,
        wind_noise_every, release_confirm, release_height, turbulence_from, turbulence_to;
    bw_real rope_shape_alpha;
} bw_schedule_t;

/* WIND_COV's fields (outputs.py), MAVLink units; NAN for unknown */
typedef struct {
    int64_t time_usec;
    float wind_x, wind_y, wind_z, var_horiz, var_vert, wind_alt, horiz_accuracy, vert_accuracy;
} bw_wind_cov_t;

typedef struct {
    bw_real alpha;                /* 1 Hz low-pass weight per step */
    bw_real ln, le;
    int32_t primed;
    bw_real ring_n[60], ring_e[60];
    int64_t count, next_slot_us;
    double site_altitude_m;
} bw_windcov_out_t;

typedef struct {
    bw_ekf_t ekf;
    bw_forces_t probe;
    bw_schedule_t sched;
    const bw_config_t *cfg;      /* the caller's (in flash on the target): it must outlive the estimator */
    bw_counters_t counters;
    bw_consistency_t consistency;
    bw_status_t accel_status[3], baro_status, heading_status, mag_status[3], taut_status[4];
    bw_windcov_out_t out;
    /* noise */
    bw_real accel_var, accel_static_var, accel_taut_var, vertical_gust_var, align_var, baro_var,
        mag_sigma, mag_var, declination;
    uint8_t catenary, mount;     /* the rope's real shape; an IMU mounting declared (cfg imu_roll/pitch_deg) */
    /* the times of control.py as step counts (n >= ceil(t * rate)) and the monitor's weights, set at init */
    int32_t n_dwell, n_learn_drag, n_false_release, n_taut_pull, n_confirm;
    bw_real a_accel, a_taut, a_baro, a_confirm;
    int64_t dt_us;
    int32_t max_gap_steps;
    /* clock and control (control.py _init_clock) */
    uint8_t initialised, joined, unconfirmed, was_slack; /* flags, one byte each (the RAM's budget) */
    int64_t t_filter_us, t_last_us, t_boot_us, step;
    bw_real last_gyro[3];
    int32_t release_count, field_n;
    bw_real field_sum[6];
    bw_real field_strength[2];   /* |m|^2 on the taut tether, its short and long means (aid_mag.c watch_field) */
    bw_real acc_mean[3], acc_var;
    int32_t confirm_count;
    bw_real field_ned[3];
    int32_t dwell;
    bw_real accel_innov2, innov_alpha, mean_speed, speed_alpha, speed_var;
    int32_t slack, pulling;
    int32_t height_above;
    bw_real accel_var_excess;
    bw_real align_innov2[2], align_mean, a_align_innov; /* the alignment's noise, along and cross; the along
                                                       * innovation's mean (aid_tether.c) */
    bw_real drag_prior[2];        /* the drag scale and its variance when a free ascent starts to learn it */
    /* the drag scale the last ascent's data told, the variance it claimed (0: none to weigh again), its climb */
    bw_real ascent_data, ascent_var, ascent_climb;
    bw_real turbulence[3]; /* the taut wind speed at the window's start, departures from it summed, squared */
    /* barometer (control.py _init_baro) */
    bw_real p_ref_pa;
    int32_t zeroing;
    bw_real ref_pos_d, t_ref_k, zero_sum;
    int32_t zero_n;
    bw_real join_height, rho, height_baro;
    int32_t baro_pending, baro_outside; /* a sample to fuse; samples in a row outside the gate (aid_baro.c) */
    /* the winch (aid_sources/winch.py) and the ground reference (aid_sources/ground_ref.py) */
    bw_real winch_tension_n;
    bw_real accel_radial_innov2; /* the accelerometer's innovations along the tether's radius, their mean square
                                  * (aid_accel.c; in the hole before the int64s) */
    int64_t winch_samples, winch_t_us;
    bw_real accel_hbias[2];      /* the accelerometer's body x, y biases walked since the field was learnt
                                  * (aid_accel.c) */
    int64_t ground_samples, ground_t_us;
    bw_real ground_p_pa, ground_p0_pa, p_ref0_pa;
    bw_real accel_hbias_var;     /* the followed horizontal bias's error variance (aid_accel.c) */
    bw_real level_mean[2], level_var; /* the specific force in NED, north and east: its mean, its variance about it
                                       * per axis (aid_accel.c level rows; level_var 0: nothing followed yet) */
    bw_real wind_taut_mps;       /* the wind's speed the last taut placement put (aid_tether.c bw_enter_taut; in the
                                  * hole before the int64s) */
    /* implausible WINCH_STATUS and ground references, rejected and counted; why the last one was */
    int64_t winch_rejected, ground_rejected;
    int32_t winch_reject_reason, ground_reject_reason;
} bw_estimator_t;

/* the defaults of the design file and of [filter] (the paper's reference balloon) */
void bw_config_default(bw_config_t *cfg);
/* 0 on success, -1 if the configuration cannot describe a balloon (non-positive rate, radius, mass) */
int bw_init(bw_estimator_t *est, const bw_config_t *cfg);
/* one IMU sample: specific force FRD m/s^2, rates rad/s, field gauss (NAN if none); 1 when the filter advanced */
int bw_on_imu(bw_estimator_t *est, int64_t t_us, bw_real ax, bw_real ay, bw_real az, bw_real gx, bw_real gy,
              bw_real gz, bw_real mx, bw_real my, bw_real mz);
/* one barometer + thermometer sample, hPa and degrees C; 1 if accepted */
int bw_on_baro(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c);
/* WINCH_STATUS: the paid-out line (m) is the tether's length from now on, the reel's speed (m/s, paying
 * out positive) the chord's rate, the pull at the anchor (N, NAN: not measured) kept; t_us on the sensor
 * clock (the newest IMU sample's when it arrived). 1 if accepted */
int bw_on_winch(bw_estimator_t *est, int64_t t_us, bw_real line_length_m, bw_real speed_mps, bw_real tension_n);
/* the ground reference (the ground station's barometer, hPa, and thermometer, degrees C or NAN): the
 * barometer's zero follows the ground's pressure; t_us on the sensor clock. 1 if accepted */
int bw_on_ground_baro(bw_estimator_t *est, int64_t t_us, bw_real pressure_hpa, bw_real temperature_c);
/* no sensor data for this long: grow the covariance (the state stays) */
void bw_coast(bw_estimator_t *est, bw_real seconds);
/* forget everything (the sender rebooted) */
void bw_reset(bw_estimator_t *est);
/* per filter step, for WIND_COV's variability (the caller calls it after bw_on_imu returned 1) */
void bw_output_update(bw_estimator_t *est, int64_t t_us);
void bw_output_reset(bw_estimator_t *est);
/* WIND_COV's fields now */
void bw_wind_cov(const bw_estimator_t *est, bw_wind_cov_t *out);
/* the reported horizontal wind accuracy, m/s (P, what P cannot hold, the consistency factor) */
bw_real bw_wind_accuracy(const bw_estimator_t *est);
size_t bw_sizeof_estimator(void);

#endif
