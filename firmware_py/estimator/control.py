"""The logic that decides what to fuse and when (PX4's control.cpp): input validation, the
fixed-step clock with jitter/gap/duplicate/reorder/backwards handling, barometer zeroing, air
density, mode switching (ground -> free ascent <-> taut) with hysteresis, and resets."""

from __future__ import annotations

import math

from balloon_core.atmosphere import G0
from balloon_core.config import Design
from balloon_core.rotation import imu_mount, imu_to_body, quat_from_euler, rotation
from firmware_py.estimator.aid_sources.accel import accel_nominal_var, control_accel, horizontal_ned
from firmware_py.estimator.aid_sources.baro import baro_sample, control_baro, reset_height
from firmware_py.estimator.aid_sources.ground_ref import ground_baro_sample, init_ground_ref
from firmware_py.estimator.aid_sources.magnetometer import control_mag
from firmware_py.estimator.aid_sources.tether import control_tether, enter_taut, lean_variance
from firmware_py.estimator.aid_sources.winch import control_winch, init_winch, winch_sample
from firmware_py.estimator.catenary import anchored_rope_spread
from firmware_py.estimator.consistency import (
    ACCEL,
    ALIGN,
    BARO,
    CONSISTENCY_S,
    MAG,
    RADIUS,
    Consistency,
    bias_tilt_rad,
    correlated_weight,
    field_attitude_extra,
    field_variance,
    gyro_heading_wind,
    heading_misfit_variance,
    lean_bias_rad,
    lean_bias_wind,
    lean_misfit_wind,
    lean_tilt_variance,
    placement_settling_wind,
    systematic_variance,
)
from firmware_py.estimator.ekf import RESET_DRAG, FusionStatus, WindEkf, gap_attitude_var, weighed_variance
from firmware_py.estimator.model import ADDED_MASS_COEFFICIENT, BalloonModel, Forces, accelerations
from firmware_py.estimator.params import (
    ACC_MAX,
    ACCEL_INNOV_S,
    ACCEL_MODEL_CORR_S,
    ALIGN_INNOV_S,
    ASCENT_AIRFLOW_RATIO,
    BALANCE_FROM_S,
    BARO_MODEL_M,
    BARO_NOMINAL_HZ,
    CONFIRM_EXPLAINED,
    CONFIRM_MOTION_MPS2,
    CONFIRM_S,
    CONFIRM_WINDOW_S,
    DRAG_ASCENT_FLOOR,
    DRAG_ASCENT_SIGMA,
    DRAG_CONFLICT_SIGMA,
    DRAG_SCALE_MIN,
    FALSE_RELEASE_S,
    GYRO_MAX,
    HEADING_LOST_S,
    JOIN_IN_FLIGHT_US,
    LEARN_DRAG_AFTER_S,
    LIGHT_AIR_SIGMA_U_MPS,
    MAG_MAX,
    MAG_MODEL_GAUSS,
    MEAN_WIND_S,
    REORDER_WINDOW_US,
    ROPE_WAVE_ACCEL_MPS2,
    ROPE_WAVE_ALIGN_RAD,
    TAUT_PULL_S,
    TURBULENCE_FROM_S,
    TURBULENCE_TO_S,
    VERTICAL_TURBULENCE_RATIO,
    Schedule,
)
from firmware_py.estimator.state import (
    BARO_OFF,
    DRAG,
    MODE_FREE,
    MODE_GROUND,
    MODE_NAMES,
    MODE_TAUT,
    POS_D,
    VEL_D,
    VEL_E,
    VEL_N,
    WIND_E,
    WIND_N,
    FilterConfig,
)
from firmware_py.estimator.tuning import kaimal_window_share


class Counters:
    __slots__ = (
        "imu_samples", "baro_samples", "rejected", "duplicates", "reordered", "jitter", "gaps",
        "long_gaps", "time_resets", "numeric_resets", "taut_resets", "mode_switches", "baro_resets",
        "false_releases", "field_jumps",
    )  # fmt: skip

    def __init__(self) -> None:
        for name in self.__slots__:
            setattr(self, name, 0)

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in self.__slots__}


BALANCE_FROM_US = int(BALANCE_FROM_S * 1e6)  # the force balance's start after a taut placement (as the C core casts)


def count_up(n: int) -> int:
    """A step count one more, held at the largest int32 (the C core's counts: 248 days at 100 Hz)."""
    return n + 1 if n < 2147483647 else n


def _finite3(a: float, b: float, c: float, limit: float) -> bool:
    return (
        math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
        and abs(a) <= limit and abs(b) <= limit and abs(c) <= limit
    )  # fmt: skip


def valid_imu(ax: float, ay: float, az: float, gx: float, gy: float, gz: float) -> bool:
    """The one IMU validity check (the estimator's and the input stage's): finite and within range."""
    return _finite3(ax, ay, az, ACC_MAX) and _finite3(gx, gy, gz, GYRO_MAX)


def quat_from_accel_mag(ax: float, ay: float, az: float, mx: float, my: float, mz: float, dec: float):
    """Attitude of a resting body from gravity (specific force = -g) and the magnetic heading."""
    roll = math.atan2(-ay, -az)
    pitch = math.atan2(ax, math.hypot(ay, az))
    # de-rotate the magnetometer by roll and pitch, then heading
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    bx = mx * cp + my * sr * sp + mz * cr * sp
    by = my * cr - mz * sr
    yaw = math.atan2(-by, bx) + dec if (bx or by) else 0.0
    return quat_from_euler(roll, pitch, yaw)


class Estimator:
    """Raw sensor samples in, wind estimate out. One call per received sample, bounded work."""

    def __init__(self, design: Design, cfg: FilterConfig | None = None) -> None:
        self.design = design
        self._mount = imu_mount(design.sensors.imu_roll_deg, design.sensors.imu_pitch_deg)  # None: on the body's axes
        self.cfg = cfg or FilterConfig()
        self.catenary = self.cfg.rope_model == "catenary"
        # a flexible rope carries its own drag to the anchor along its tension: none of it acts at the
        # balloon (the balloon's pull is its own drag and lift); it bows the rope instead, which the
        # catenary shape holds. The paper's rigid rod shares it half and half (Eq. 5 with drag).
        self.model = BalloonModel.from_design(design, self.cfg.rope_normal_cd, rope_drag_at_balloon=not self.catenary)
        self.ekf = WindEkf(self.model, self.cfg, design.sensors)
        s = design.sensors
        self.accel_var = s.accel_mps2**2 + self.cfg.accel_model_mps2**2
        self.accel_static_var = s.accel_mps2**2 + self.cfg.accel_static_mps2**2
        # a rope with mass moves on its own (waves, its swing) and moves the balloon with it: the rod
        # model's errors grow with the rope's share of the moving mass (docs/estimator.md)
        rope_share = self.model.rope_kg_m * self.model.tether_length_m / (self.model.mass_kg + 1e-9)
        rope_share = rope_share if self.catenary else 0.0
        self.accel_taut_var = s.accel_mps2**2 + self.cfg.accel_taut_mps2**2 + (ROPE_WAVE_ACCEL_MPS2 * rope_share) ** 2
        self.vertical_gust_var = self._vertical_gust_var(self.cfg.expected_wind_mps, self.model.site_rho_kg_m3)
        self.align_var = self.cfg.align_rad**2 + (ROPE_WAVE_ALIGN_RAD * rope_share) ** 2
        self.baro_var = s.baro_m**2 + BARO_MODEL_M**2
        self.mag_sigma = s.mag_gauss
        self.declination = math.radians(design.site.mag_declination_deg)
        self.dt_us = round(1e6 / self.cfg.imu_rate_hz)
        self.max_gap_steps = max(1, round(self.cfg.max_gap_s * self.cfg.imu_rate_hz))
        self.counters = Counters()
        self._probe = Forces()  # scratch for the taut-entry check
        self.accel_status = [FusionStatus(f"accel_{a}") for a in "xyz"]
        self.accel_bias_status = FusionStatus("accel_bias_z")  # the bias in flight (accel.fuse_bias_magnitude)
        self.level_status = FusionStatus("level")  # a tethered balloon does not accelerate (accel.fuse_level)
        self.schedule = sched = Schedule.at(self.cfg.imu_rate_hz, self.cfg.recover_after_s)
        self.baro_status = FusionStatus("baro", sched.baro_recover)
        self.heading_status = FusionStatus("heading", sched.mag_recover)
        self.mag_status = [FusionStatus(f"mag_{a}", sched.mag_recover) for a in "xyz"]
        # the magnetometer's model error: the field's direction is known to ~0.5 deg after the boot
        self.mag_var = self.mag_sigma**2 + MAG_MODEL_GAUSS**2
        self.taut_status = [FusionStatus(n) for n in ("radius", "radial_rate", "align_along", "align_cross")]
        self.consistency = Consistency()
        self._init_clock()
        self._init_baro()
        init_winch(self)

    # ------------------------------------------------------------------ state of the clock / baro

    def _init_clock(self) -> None:
        self.initialised = False
        self.t_filter_us = 0
        self.t_last_us = -1
        self.t_boot_us = 0
        self.step = 0
        self._last_gyro = (0.0, 0.0, 0.0)
        self._release_count = 0
        self._field_n = 0
        self._field_window = 0  # the field learnt again on the tether: 0 armed, 1 summing, 2 done (magnetometer.py)
        self._field_sum = [0.0] * 6
        # the field's strength squared on the taut tether, its means over FIELD_JUMP_SHORT_S and FIELD_JUMP_LONG_S
        # (magnetometer.follow_field_strength; 0: none yet)
        self.field_strength = [0.0, 0.0]
        self._joined = False
        self.wind_taut_mps = 0.0  # the wind's speed the last taut placement put (tether.enter_taut)
        self.unconfirmed = False  # joined in flight and not yet confirmed by the motion (see CONFIRM_*)
        self._acc_mean = [0.0, 0.0, 0.0]
        self._acc_var = 0.0
        self._confirm_count = 0
        self.field_ned = (math.nan, math.nan, math.nan)
        # the heading's variance a body-fixed magnetometer offset may hold unseen, rad^2: set where the field learnt
        # again on the tether replaced the boot's (magnetometer.learn_field_in_flight); 0 while none did
        self.field_heading_var = 0.0
        self._dwell = 0
        self._accel_innov2 = 0.0
        self._accel_radial_innov2 = 0.0  # on the tether, along its radius (accel.radial_noise)
        # the specific force in NED, north and east: its mean, and its variance about it per axis (accel.level_noise)
        self.level_mean = [0.0, 0.0]
        self.level_var = 0.0  # 0: nothing followed yet (accel.level_noise starts it)
        self._accel_axis_nis = [0.0, 0.0, 0.0]  # the last flying step's NIS per axis (accel.control_accel)
        self._innov_alpha = 1.0 / (ACCEL_INNOV_S * self.cfg.imu_rate_hz)
        self._mean_speed = self.cfg.expected_wind_mps  # the filter's own mean wind (60 s), for its noise
        self._speed_alpha = 1.0 / (MEAN_WIND_S * self.cfg.imu_rate_hz)
        # the turbulence the filter sees: its wind speed's variance about that mean (60 s)
        self._speed_var = (self.cfg.turbulence_intensity * self.cfg.expected_wind_mps) ** 2
        self._slack = 0
        self._pulling = 0
        self._was_slack = False
        self._height_above = 0
        self._accel_var_excess = 0.0
        # the accelerometer's body x and y biases walked since the field was learnt (accel.follow_horizontal_bias)
        self.accel_hbias = [0.0, 0.0]
        self.accel_hbias_var = 0.0  # its error variance, (m/s^2)^2 (accel.horizontal_bias_variance)
        self._align_innov2 = [0.0, 0.0]  # along, cross (aid_sources/tether.py)
        self._align_mean = 0.0  # the along innovations' running mean (their spread is the noise)
        self._drag_prior = (1.0, 0.0)  # the drag scale and its variance when a free ascent starts to learn it
        # the drag scale the last ascent's data told, the variance it claimed (0: nothing to weigh again, and a spell of
        # learning may start), its climb m/s
        self._ascent_data, self._ascent_var, self._ascent_climb = 0.0, 0.0, 0.0
        # the taut wind speed at the measuring window's start, its departures from it summed, and squared
        self._turbulence = [0.0, 0.0, 0.0]
        self._align_alpha = self.schedule.taut_every / (ALIGN_INNOV_S * self.cfg.imu_rate_hz)
        self._taut_alpha = self.schedule.taut_every / (CONSISTENCY_S * self.cfg.imu_rate_hz)
        self._step_alpha = 1.0 / (CONSISTENCY_S * self.cfg.imu_rate_hz)  # one filter step of the monitor's window
        self.consistency.reset()

    def _init_baro(self) -> None:
        gp = self.design.site.ground_pressure_hpa
        self.p_ref_pa = gp * 100.0 if gp is not None else math.nan
        self._zeroing = gp is None
        self.ref_pos_d = 0.0 if gp is not None else -self.model.radius_m
        self.t_ref_k = math.nan
        self._zero_sum = 0.0
        self._zero_n = 0
        self._join_height = math.nan
        self.rho = self.model.site_rho_kg_m3  # the site's air until the barometer reads it (aid_sources/baro.py)
        self.height_baro = math.nan
        self._baro_pending = False
        self.baro_outside = 0  # barometer samples in a row outside the gate (aid_sources.baro.control_baro)
        init_ground_ref(self)

    def reset(self) -> None:
        """Forget everything (time went backwards: the vehicle rebooted)."""
        self._init_clock()
        self._init_baro()
        self.ekf.mode = MODE_GROUND

    # ------------------------------------------------------------------ inputs

    def on_baro(self, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
        """A barometer + thermometer sample (aid_sources/baro.py): zeroed during the first second unless
        the config gives the ground pressure; fused at the next IMU step."""
        return baro_sample(self, t_us, pressure_hpa, temperature_c)

    def on_winch(self, t_us: int, line_length_m: float, speed_mps: float, tension_n: float) -> bool:
        """A WINCH_STATUS (aid_sources/winch.py): the paid-out length is the tether's length from now on,
        the reel's speed the chord's rate; ``t_us`` on the sensor clock (when it arrived)."""
        return winch_sample(self, t_us, line_length_m, speed_mps, tension_n)

    def on_ground_baro(self, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
        """The ground reference's pressure and temperature (aid_sources/ground_ref.py): the barometer's
        zero follows the ground's pressure; ``t_us`` on the sensor clock (when it arrived)."""
        return ground_baro_sample(self, t_us, pressure_hpa, temperature_c)

    def on_imu(
        self, t_us: int, ax: float, ay: float, az: float, gx: float, gy: float, gz: float,
        mx: float = math.nan, my: float = math.nan, mz: float = math.nan,
    ) -> bool:  # fmt: skip
        """One IMU sample: specific force (FRD, m/s^2), rates (rad/s), field (gauss, NaN if none).
        Returns True when the filter advanced."""
        c = self.counters
        if self._mount is not None:  # the IMU's declared mounting: its readings in the balloon's axes (then judged)
            ax, ay, az = imu_to_body(self._mount, ax, ay, az)
            gx, gy, gz = imu_to_body(self._mount, gx, gy, gz)
            mx, my, mz = imu_to_body(self._mount, mx, my, mz)
        if not valid_imu(ax, ay, az, gx, gy, gz):
            c.rejected += 1
            return False
        mag_ok = _finite3(mx, my, mz, MAG_MAX) and (mx != 0.0 or my != 0.0 or mz != 0.0)
        if not self.initialised:
            # a start needs the field and the balloon's bottom down: gravity's reaction up the body's z (FRD: level at
            # rest az = -9.81; a tethered balloon never leans past 90 deg). An accelerometer whose sign or mounting is
            # wrong (az = +9.81) would start the filter upside down, and its wind, 140 deg off, would look consistent
            if not (mag_ok and az < 0.0):
                c.rejected += 1
                return False
            self._initialise(t_us, ax, ay, az, mx, my, mz)
            c.imu_samples += 1
            return True
        d = t_us - self.t_last_us
        if d == 0:
            c.duplicates += 1
            return False
        if d < 0:
            if d > -REORDER_WINDOW_US:
                c.reordered += 1
                return False
            airborne = self.ekf.mode != MODE_GROUND  # the balloon stays where it was
            c.time_resets += 1
            self.reset()
            if mag_ok and az < 0.0:  # the new boot's first sample starts the filter again: it is counted
                self._initialise(t_us, ax, ay, az, mx, my, mz, in_flight=airborne)
                c.imu_samples += 1
            return False
        c.imu_samples += 1
        self.t_last_us = t_us
        steps = (t_us - self.t_filter_us + self.dt_us // 2) // self.dt_us
        if steps <= 0:
            c.jitter += 1
        elif steps > 1:
            c.gaps += 1
            # the attitude, predicted on a rate held from before the gap (or not at all beyond max_gap_s), grows by
            # what that rate cannot know: its change across the gap (ekf.gap_attitude_var)
            lost = steps > self.max_gap_steps
            var = gap_attitude_var(self._last_gyro, (gx, gy, gz), (steps - 1) * self.dt_us * 1e-6, lost)
            if lost:
                c.long_gaps += 1
                # predict the last max_gap_s; the covariance grows by the process noise of the rest
                self.ekf.inflate(steps - self.max_gap_steps)
                self.t_filter_us = t_us - self.max_gap_steps * self.dt_us
                steps = self.max_gap_steps
            self.ekf.inflate_attitude(var)
        ekf = self.ekf
        # the tether pulls at the bottom of the sphere: where that is depends on the attitude
        r = rotation(*ekf.q.tolist())
        rad = self.model.radius_m
        ekf.forces.attach_ned = self._probe.attach_ned = (rad * r[2], rad * r[5], rad * r[8])
        if self.catenary:
            ekf.forces.rope_weight_n = self._probe.rope_weight_n = ekf.rope.weight_n
        for i in range(steps):
            g = (gx, gy, gz) if i == steps - 1 else self._last_gyro
            ekf.predict(g[0], g[1], g[2], self.rho)
            self.t_filter_us += self.dt_us
            self.step += 1
        self._last_gyro = (gx, gy, gz)
        ekf.time_us = self.t_filter_us
        vn, ve = float(ekf.x[VEL_N]), float(ekf.x[VEL_E])  # the velocity predicted and its variance (the balance)
        pv, resets = float(ekf.P[VEL_N, VEL_N] + ekf.P[VEL_E, VEL_E]), ekf.reset_count
        ekf.begin_update()
        v_pred = self._field_variance()
        control_accel(self, ax, ay, az)
        v_accel = self._field_variance()
        if self.unconfirmed:
            self._confirm(ax, ay, az)
        control_baro(self)
        control_winch(self)
        if mag_ok:  # the field is learnt in the frame the followed horizontal bias is corrected in (a landing's)
            control_mag(self, ax - self.accel_hbias[0], ay - self.accel_hbias[1], az, mx, my, mz)
        v_aids = self._field_variance()
        control_tether(self)
        if not ekf.end_update():
            c.numeric_resets += 1
            self._reinitialise_in_flight(ax, ay, az, mx, my, mz, mag_ok)
            return True
        if ekf.mode == MODE_TAUT and ekf.reset_count == resets:  # the force balance's monitor (consistency.py)
            # judged from BALANCE_FROM_S after the last taut placement, whose own convergence pulls the velocity
            # before; its mean and that mean's variance from zero then (held there at the tether's rate until)
            mon = self.consistency
            at_rate = self.step % self.schedule.taut_every == 0
            settling = ekf.time_us - ekf.time_taut_us < BALANCE_FROM_US
            mon.add_balance(
                float(ekf.x[VEL_N]) - vn,
                float(ekf.x[VEL_E]) - ve,
                pv - float(ekf.P[VEL_N, VEL_N] + ekf.P[VEL_E, VEL_E]),
                self._step_alpha,
                self._taut_alpha if at_rate and not settling else 0.0,
            )
            if at_rate and settling:
                mon.balance_n = mon.balance_e = mon.balance_var = 0.0
        if ekf.mode != MODE_GROUND:
            # each source's windowed NIS against (about) the noise it was fused with (the accelerometer's is kept
            # against its nominal noise; here the shared excess alone is put back, not the radius's, accel.radial_noise:
            # the NIS reads high on the tether in gusts, and the weight lower, the cautious side), each over its own
            # interval (the alignment's every taut_every steps)
            nominal = accel_nominal_var(self)
            nis_accel = self.consistency.nis[ACCEL] * nominal / (nominal + self._accel_var_excess)
            dt, corr = ekf.dt, ACCEL_MODEL_CORR_S
            ekf.field_att_extra = field_attitude_extra(
                ekf.field_att_extra, v_pred, v_accel, v_aids, self._field_variance(),
                correlated_weight(nis_accel, dt, corr),
                correlated_weight(self.consistency.nis[ALIGN], self.schedule.taut_every * dt, corr),
            )  # fmt: skip
        else:
            ekf.field_att_extra = 0.0
        self._update_mode(ax, ay, az)
        if ekf.mode != MODE_GROUND:
            self._monitor()
        if ekf.mode == MODE_TAUT:
            wn, we = self.wind()
            speed = math.sqrt(wn * wn + we * we)
            dev = speed - self._mean_speed
            self._mean_speed += self._mean_weight(dev) * dev
            self._speed_var += self._speed_alpha * (dev * dev - self._speed_var)
            if self._ascent_var > 0.0:
                self._weigh_ascent(speed)
            if self.step % self.schedule.wind_noise_every == 0:
                self.vertical_gust_var = self._vertical_gust_var(self._mean_speed, self.rho)
                ekf.adapt_wind_noise(self._mean_speed, self._turbulence_excess())
        return True

    def _mean_weight(self, dev: float) -> float:
        """The weight of this taut step's wind speed, ``dev`` above the filter's mean wind (MEAN_WIND_S), in that
        mean, which sizes the wind's process noise (q_rate ~ U^(14/3)). In the first taut spell, until it fills the
        window, a speed above the mean counts as one of the spell's own samples (1 / n): from the design's expected
        wind (3 m/s) a 60 s running mean took two minutes to reach a 10 m/s day, and with the wind's noise a tenth of
        its size the state's swing across a long rope grew (docs/estimator.md, "The swing across the rope"). Below it
        the running mean: in light air the expected wind's larger noise is the cautious side while it meanders (the
        spell's own mean there cost the light-air flights 2 % of their RMS error). A later spell (after the rope went
        slack) keeps the running mean."""
        if dev > 0.0 and not self._was_slack and self._dwell * self._speed_alpha < 1.0:
            return 1.0 / (self._dwell + 1)
        return self._speed_alpha

    def _turbulence_excess(self) -> float:
        """The wind's process noise is sized for sigma_u = TI U (adapt_wind_noise). Light air does not calm
        in proportion: it meanders, sigma_u near 0.3-0.5 m/s at any mean speed. So below
        ``LIGHT_AIR_SIGMA_U_MPS`` the filter's own turbulence, its speed's variance about the 60 s mean, raises
        the noise when larger (a variance ratio >= 1). Never above that: in a strong wind TI U holds, and a
        noise that followed the estimate's own scatter would feed on it. Nor does the force model's misfit raise it
        (the accelerometer's innovations beyond their taut allowance): taken for turbulence, the noisier wind raised
        the model's drag and tension until a balloon blown down ran away (class B gusts of 14.4 m/s on the paper's
        rope read 616 % fast), and let a state swinging across its rope carry the wind with its velocity, so that
        the drag which damps the swing never acted (docs/estimator.md, "The swing across the rope")."""
        expected = self.cfg.turbulence_intensity * max(self._mean_speed, 0.5)
        seen = min(self._speed_var, LIGHT_AIR_SIGMA_U_MPS * LIGHT_AIR_SIGMA_U_MPS)
        return max(1.0, seen / (expected * expected))

    def _weigh_ascent(self, speed: float) -> None:
        """The drag scale a free ascent learnt, weighed again once the taut flight has measured the turbulence.
        The ascent's model leaves out the vertical air: a downdraft w through a climb at v reads as drag,
        dk / k = 2 w / v (F ~ k v^2). Until it is measured the ascent is worth DRAG_ASCENT_SIGMA; from
        TURBULENCE_FROM_S after the taut entry (its settling over) to TURBULENCE_TO_S the wind speed's variance
        measures sigma_u, and the ascent is weighed as a measurement of sqrt(DRAG_ASCENT_FLOOR^2 + (2 sigma_w /
        v)^2), sigma_w = VERTICAL_TURBULENCE_RATIO sigma_u, never more than its data claimed. Still air trusts
        the ascent more, gusts less; once per ascent. Where the ascent and the prior it started from disagree beyond
        DRAG_CONFLICT_SIGMA they do not both hold (a sphere's C_d through its drag crisis: the ascent's airspeed is
        not the tether's) and the scale is their mixture (WindEkf.weigh_information). The wind moves with the drag
        scale, so that the pull the state explains stays (no step in the estimate)."""
        start, end = self.schedule.turbulence_from, self.schedule.turbulence_to
        tb = self._turbulence
        if self._dwell <= start:
            tb[0], tb[1], tb[2] = speed, 0.0, 0.0
            return
        d = speed - tb[0]
        tb[1] += d
        tb[2] += d * d
        if self._dwell < end:
            return
        n = float(end - start)
        share = kaimal_window_share(TURBULENCE_TO_S - TURBULENCE_FROM_S, tb[0] + tb[1] / n)
        sigma_u2 = max(0.0, tb[2] / n - (tb[1] / n) * (tb[1] / n)) / share
        climb = max(self._ascent_climb, 1.0)
        sigma_w2 = VERTICAL_TURBULENCE_RATIO * VERTICAL_TURBULENCE_RATIO * sigma_u2
        var = max(self._ascent_var, DRAG_ASCENT_FLOOR * DRAG_ASCENT_FLOOR + 4.0 * sigma_w2 / (climb * climb))
        ekf = self.ekf
        prior, prior_var = self._drag_prior
        # what the scale's random walk has added since the cap (its variance then: the prior and the data at the
        # weight the cap left it)
        capped = max(self._ascent_var, DRAG_ASCENT_SIGMA * DRAG_ASCENT_SIGMA)  # as the cap weighed it
        walked = max(0.0, float(ekf.P[DRAG, DRAG]) - weighed_variance(prior_var, capped, self._ascent_data - prior,
                                                                      DRAG_CONFLICT_SIGMA))
        k = float(ekf.x[DRAG])
        ekf.weigh_information(DRAG, prior, prior_var, self._ascent_data, var, walked, RESET_DRAG, DRAG_CONFLICT_SIGMA)
        ekf.x[DRAG] = max(float(ekf.x[DRAG]), DRAG_SCALE_MIN)
        self._ascent_var = 0.0
        # the drag the state explains (k |w - v| (w - v), the lean's pull) stays: the relative wind moves with k
        s = math.sqrt(k / float(ekf.x[DRAG]))
        for wi, vi in ((WIND_N, VEL_N), (WIND_E, VEL_E)):
            ekf.x[wi] = ekf.x[vi] + s * (ekf.x[wi] - ekf.x[vi])
            ekf.P[wi, :] *= s
            ekf.P[:, wi] *= s

    def _vertical_gust_var(self, mean_speed_mps: float, rho: float) -> float:
        """The vertical air the model leaves out (its wind is horizontal), as the acceleration it puts
        into the drag: k c U w' / m_eff, with w' of the turbulence the filter expects at the IEC
        proportion sigma_w = 0.5 sigma_u. A vertical gust is then noise on the specific force, not a
        horizontal wind the state must move to explain."""
        m = self.model
        m_eff = m.mass_kg + ADDED_MASS_COEFFICIENT * rho * m.volume_m3
        u = max(mean_speed_mps, 0.5)
        sigma_w = VERTICAL_TURBULENCE_RATIO * self.cfg.turbulence_intensity * u
        a = rho * m.half_cd_area_m2 * u * sigma_w / m_eff
        return a * a

    def _monitor(self) -> None:
        """Feed the consistency monitor (consistency.py) with this step's innovations, each source
        weighted by its own interval over the window."""
        mon = self.consistency
        t = self.ekf.time_us
        # the accelerometer's NIS is added where it is fused (control_accel), whose noise follows its innovations
        taut_alpha = self._taut_alpha
        radius, _, an, ae = self.taut_status
        if an.time_test_us == t and an.innov_var > 0.0 and ae.innov_var > 0.0:
            # against the noise it was fused with: the alignment's noise follows the rocking (aid_sources/tether.py),
            # which P then holds; what the monitor sees is innovations beyond it (the azimuth's bound, and a
            # persistent along misfit: that noise follows only the spread about the mean)
            mon.add(ALIGN, 0.5 * (an.innov**2 / an.innov_var + ae.innov**2 / ae.innov_var), taut_alpha)
        if radius.time_test_us == t and radius.innov_var > 0.0:
            mon.add(RADIUS, radius.innov**2 / radius.innov_var, taut_alpha)
        b = self.baro_status
        if b.time_test_us == t and b.innov_var > 0.0:
            mon.add(BARO, b.innov**2 / b.innov_var, 1.0 / (CONSISTENCY_S * BARO_NOMINAL_HZ))
        mg = self.mag_status
        if mg[0].time_test_us == t and mg[0].innov_var > 0.0:
            nis = sum(s.innov**2 / s.innov_var for s in mg if s.innov_var > 0.0) / 3.0
            mon.add(MAG, nis, self._step_alpha)
        mon.evaluate()

    def coast(self, seconds: float) -> None:
        """No sensor data arrived for a while: grow the covariance by the process noise of the
        elapsed time (the state stays; the gap logic re-anchors the clock when data resumes)."""
        if self.initialised:
            self.ekf.inflate(seconds * self.cfg.imu_rate_hz)

    # ------------------------------------------------------------------ helpers

    def _initialise(
        self, t_us: int, ax: float, ay: float, az: float, mx: float, my: float, mz: float, in_flight: bool = False
    ) -> None:
        """Start the filter at this sample: on the ground, or joined in flight (``_join_in_flight``) when the sender's
        clock says it booted long before us or ``in_flight`` (it rebooted while the filter flew: a real reboot starts
        its clock at zero, and the balloon is still up on its tether)."""
        q = quat_from_accel_mag(ax, ay, az, mx, my, mz, self.declination)
        self.ekf.initialise(q, -self.model.radius_m)
        self.initialised = True
        self.t_boot_us = t_us
        self.t_last_us = t_us
        self.t_filter_us = t_us
        self.ekf.time_us = t_us  # the filter's time from this sample on: a join's placement is at it
        if in_flight or t_us > JOIN_IN_FLIGHT_US:
            self._join_in_flight(q)

    def _join_in_flight(self, q) -> None:
        """The sender booted long before us (a firmware restart in flight): the balloon is up on its
        tether, not on the ground station. Start taut, with the chord angle from the tilt through the
        static balance (tan chord = tan tilt * N_b / (N_b - W)) and, unless the config gives the ground
        pressure, the barometer's zero placed so that its first sample reads that height."""
        m = self.model
        ekf = self.ekf
        zd = q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3]  # cos(tilt)
        tan_tilt = math.sqrt(max(0.0, 1.0 - zd * zd)) / max(zd, 0.1)
        lift = m.lift_n(self.rho)
        spare = lift - (ekf.rope.weight_n if self.catenary else m.rope_weight_n)
        tan_chord = tan_tilt * lift / spare if spare > 0.1 * lift else tan_tilt
        height = (ekf.rope.chord_m + m.radius_m) / math.sqrt(1.0 + tan_chord * tan_chord)
        ekf.mode = MODE_TAUT
        self._joined = True
        self.unconfirmed = True
        self._confirm_count = 0
        self._acc_var = -1.0  # the fluctuation's running mean starts at the next sample
        self.counters.mode_switches += 1
        enter_taut(self, height, from_tilt=True)
        if self._zeroing:
            self._join_height = height - m.radius_m  # above the (unseen) boot position

    def _confirm(self, ax: float, ay: float, az: float) -> None:
        """While a join in flight is unconfirmed: watch the balloon's acceleration across its rope (the specific force
        turned into NED: a sender that only turns reads none) and how much of it the force model explains there;
        confirmed once both have held for CONFIRM_S. Across the rope the taut model's pendulum is what a balloon on its
        tether obeys; along it the rope's breathing and the vertical air move the balloon (``accel.radial_noise``),
        which the model leaves out: judged on all three axes, a real rope in light air with its vertical air (1.2 m/s)
        never confirmed, its accuracy 1.3-1.6 m/s for the rest of the flight where the wind was right to 0.08 m/s
        (docs/estimator.md, "Mode switching and resets", joining in flight)."""
        ekf = self.ekf
        rt, p = ekf.rt, ekf.x  # R^T as the accelerometer's rows took it; the state's position, NED
        fn, fe = horizontal_ned(rt, ax, ay, az)
        fd = float(rt[0, 2]) * ax + float(rt[1, 2]) * ay + float(rt[2, 2]) * az
        m = self._acc_mean
        if self._acc_var < 0.0:
            m[0], m[1], m[2], self._acc_var = fn, fe, fd, 0.0
        # the running mean over CONFIRM_WINDOW_S; until the window fills, the mean of the samples since the placement
        since = ekf.time_us - ekf.time_taut_us
        a = max(1.0 / (since // self.dt_us + 1), 1.0 / (CONFIRM_WINDOW_S * self.cfg.imu_rate_hz))
        dn, de, dd = fn - m[0], fe - m[1], fd - m[2]
        m[0] += a * dn
        m[1] += a * de
        m[2] += a * dd
        # the fluctuation's variance across the rope, per axis, over the same time as the innovations' (ACCEL_INNOV_S):
        # compared with each other they say how much of the motion the model explains, then and there
        pn, pe, pd = float(p[0]), float(p[1]), float(p[2])
        d2 = pn * pn + pe * pe + pd * pd
        f2 = dn * dn + de * de + dd * dd
        innov2 = self._accel_innov2
        if d2 > 1.0:  # the two axes' share of the three's, less the radius's
            along = dn * pn + de * pe + dd * pd
            f2 = 1.5 * (f2 - along * along / d2)
            innov2 = 1.5 * innov2 - 0.5 * self._accel_radial_innov2  # below 0: none across; NaN: not explained
        self._acc_var += self._innov_alpha * (f2 / 3.0 - self._acc_var)
        moving = self._acc_var > CONFIRM_MOTION_MPS2**2
        explained = innov2 < CONFIRM_EXPLAINED * self._acc_var
        # counted once the placement has settled, when the force balance starts to judge the state (BALANCE_FROM_S):
        # a state still swinging from its placement moves with the motion it is to explain (class B gusts from the
        # south: confirmed 21 s after the join, 5-6 m/s off at 1.8 stated for the next 20 s)
        settled = since >= BALANCE_FROM_US
        self._confirm_count = count_up(self._confirm_count) if moving and explained and settled else 0
        if self._confirm_count >= CONFIRM_S * self.cfg.imu_rate_hz:
            self.unconfirmed = False

    def _reinitialise_in_flight(
        self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool
    ) -> None:
        """State went non-finite: restart the covariance, keep what is known from the barometer, and
        take the attitude afresh from this sample's accelerometer (tilt) and magnetometer (heading)."""
        ekf = self.ekf
        h = self.height_baro if math.isfinite(self.height_baro) else 0.0
        if mag_ok:  # the accelerometer corrected by the horizontal bias followed, which is kept (the field's frame)
            q = quat_from_accel_mag(ax - self.accel_hbias[0], ay - self.accel_hbias[1], az, mx, my, mz,
                                    self.declination)  # fmt: skip
        else:  # keep the heading we had if it is still a rotation, else level
            q0, q1, q2, q3 = self.ekf.q.tolist()
            n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            q = (q0 / n, q1 / n, q2 / n, q3 / n) if math.isfinite(n) and n > 0.5 else (1.0, 0.0, 0.0, 0.0)
        ekf.initialise(q, self.ref_pos_d - h)
        ekf.P[0, 0] = ekf.P[1, 1] = 100.0**2
        self._ascent_var = 0.0  # the drag scale starts afresh: no ascent to weigh again
        ekf.mode = MODE_FREE if h > self.cfg.release_height_m else MODE_GROUND

    def _height_for_taut(self) -> float:
        """Height of the balloon's centre above the anchor: barometer if it has one, else the state."""
        if math.isfinite(self.height_baro):
            return self.height_baro - float(self.ekf.x[BARO_OFF]) - self.ref_pos_d
        return -float(self.ekf.x[POS_D])

    def _rope_would_pull(self) -> bool:
        """The tether can only be taut if the balloon pulls on it: the taut model's tension at the
        current state (with lift lost, e.g., the rope stays slack however far out the balloon is).
        Taken with the radial velocity removed, as the rope leaves it once it has snapped taut: at the
        current state a climbing balloon's drag holds its lift, and the rope's pull shows only after the
        snap has stopped the climb (reference balloon: 4 s of a taut truth taken for free ascent, and
        the drag scale learnt from the snap, +2 %, when the pull was taken with the climb rate)."""
        x = self.ekf.x.tolist()
        pn, pe, pd, vn, ve, vd = x[0:6]
        dist = math.sqrt(pn * pn + pe * pe + pd * pd)
        if dist > 0.0:
            vr = (vn * pn + ve * pe + vd * pd) / (dist * dist)
            vn, ve, vd = vn - vr * pn, ve - vr * pe, vd - vr * pd
        f = accelerations(self.model, self.rho, pn, pe, pd, vn, ve, vd, *x[12:17], True, self._probe)
        return f.taut

    def _airflow_from_above(self) -> bool:
        """The climb tells the drag scale through the vertical drag, k c |u| u_z against the net lift, u the air
        relative to the balloon. Its horizontal part enters |u|: where it is no larger than the vertical speed
        (ASCENT_AIRFLOW_RATIO; a climb's, or a sinking balloon's, whose drag tells it as well) the vertical flow rules
        the drag; just after a release in a wind the balloon sits in the whole of it, and the vertical drag turns on a
        horizontal wind the state has only begun to learn (from rest, where the drag's linearisation is flat in the
        wind, it takes the first acceleration overconfidently)."""
        x = self.ekf.x
        un, ue, vd = float(x[WIND_N] - x[VEL_N]), float(x[WIND_E] - x[VEL_E]), float(x[VEL_D])
        return un * un + ue * ue <= ASCENT_AIRFLOW_RATIO * ASCENT_AIRFLOW_RATIO * vd * vd

    def _rope_load_known(self) -> bool:
        """The climb tells the drag scale only as well as the rope's pull on the balloon is known: the
        airborne rope hanging straight down (the free model) and fed from the anchor (a catenary from
        it, ``anchored_rope_spread``) differ by less than DRAG_ASCENT_SIGMA of the lift that drives the
        climb. Early in the ascent, or straight above the anchor, they agree; blown downwind on a long
        rope they do not, and the climb's slowing may be the rope's."""
        m = self.model
        x = self.ekf.x
        pn, pe, pd = float(x[0]), float(x[1]), float(x[2])
        lam_g = m.rope_kg_m * G0
        height = min(max(-pd - m.radius_m, 0.0), m.tether_length_m)
        net_lift = m.lift_n(self.rho) - lam_g * height
        spread = anchored_rope_spread(lam_g, math.hypot(pn, pe), height)
        return spread < DRAG_ASCENT_SIGMA * net_lift

    def _switch(self, mode: int) -> None:
        self.ekf.mode = mode
        self.counters.mode_switches += 1
        self._dwell = 0
        if mode == MODE_FREE:  # a free flight of its own (a release, a slack rope): its ascent may learn the drag
            # again, and an earlier one's capped data that await their weighing stay as the cap left them
            self._ascent_var = 0.0

    def _update_mode(self, ax: float, ay: float, az: float) -> None:
        ekf = self.ekf
        cfg = self.cfg
        self._dwell = count_up(self._dwell)
        dwell_ok = self._dwell >= cfg.mode_dwell_s * cfg.imu_rate_hz
        # a spell of learning starts where the air flows past the balloon from above and no earlier spell of this free
        # flight awaits its weighing (one that starts again on the edge of the rope's load learns that load for drag),
        # and goes on while the rope's pull is known
        learning = (
            ekf.mode == MODE_FREE
            and self._dwell >= LEARN_DRAG_AFTER_S * cfg.imu_rate_hz
            and (ekf.learn_drag or (self._ascent_var == 0.0 and self._airflow_from_above()))
            and self._rope_load_known()
        )
        if learning:
            self._ascent_climb = -float(ekf.x[VEL_D])
        if learning != ekf.learn_drag:
            if learning:
                self._drag_prior = (float(ekf.x[DRAG]), float(ekf.P[DRAG, DRAG]))
            else:
                self._ascent_data, self._ascent_var = ekf.cap_information(
                    DRAG, *self._drag_prior, DRAG_ASCENT_SIGMA**2, RESET_DRAG, DRAG_CONFLICT_SIGMA
                )
        ekf.learn_drag = learning
        if ekf.mode == MODE_GROUND:
            lifted = abs(math.sqrt(ax * ax + ay * ay + az * az) - G0) > cfg.release_accel_mps2
            self._release_count = self._release_count + 1 if lifted else 0
            high = math.isfinite(self.height_baro) and self.height_baro > cfg.release_height_m
            self._height_above = count_up(self._height_above) if high else 0
            sched = self.schedule
            if self._release_count >= sched.release_confirm or self._height_above >= sched.release_height:
                self._switch(MODE_FREE)
            return
        x = ekf.x
        pn, pe, pd = float(x[0]), float(x[1]), float(x[2])
        dist = math.sqrt(pn * pn + pe * pe + pd * pd)
        length = ekf.rope.chord_m + self.model.radius_m
        if ekf.mode == MODE_FREE:
            low = math.isfinite(self.height_baro) and self.height_baro < cfg.release_height_m
            if low and self._dwell >= FALSE_RELEASE_S * cfg.imu_rate_hz:
                # still at the ground station 3 s after the "release": a bump, not a release
                self.counters.false_releases += 1
                self._switch(MODE_GROUND)
                reset_height(ekf, self.ref_pos_d - self.height_baro, self.baro_var)
                return
            stalled = -pd > 0.5 * length and -float(x[VEL_D]) < 0.3
            near = dist >= length - cfg.taut_margin_m or stalled
            self._pulling = count_up(self._pulling) if near and self._rope_would_pull() else 0
            # back to taut after the rope went slack: only once it has pulled for a while (no flapping)
            need = TAUT_PULL_S * cfg.imu_rate_hz if self._was_slack else 1
            if dwell_ok and self._pulling >= need:
                self._switch(MODE_TAUT)
                enter_taut(self, self._height_for_taut())
                self.consistency.lean_tilt = self.consistency.lean_misfit = 0.0  # a new taut stretch's own lean
        else:
            self._slack = 0 if ekf.forces.taut else count_up(self._slack)
            if dwell_ok and self._slack >= cfg.mode_dwell_s * cfg.imu_rate_hz:
                self._switch(MODE_FREE)
                self._was_slack = True

    # ------------------------------------------------------------------ outputs

    @property
    def mode_name(self) -> str:
        return MODE_NAMES[self.ekf.mode]

    def wind_accuracy(self) -> float:
        """The horizontal wind's 1-sigma accuracy to report (WIND_COV horiz_accuracy): the filter's
        P_NN + P_EE with what P does not hold (consistency.systematic_variance), times the consistency
        monitor's factor (>= 1: the model does not explain the data); taut, with the wind of the lean the body and
        the model disagree on (consistency.lean_misfit_wind) and what the last taut placement has still to settle
        (consistency.placement_settling_wind) in quadrature; while a join in flight is
        unconfirmed at least sqrt(|w|^2 + 1); with the gyro's heading alone (consistency.gyro_heading_wind) and the
        heading a magnetometer offset may turn unseen (``field_heading_var``) in quadrature."""
        ekf = self.ekf
        wn, we = self.wind()
        speed = math.sqrt(wn * wn + we * we)
        sys_var = 0.0
        if ekf.mode != MODE_GROUND:
            sys_var = systematic_variance(speed, float(ekf.x[DRAG]), float(ekf.P[DRAG, DRAG]), self.lean_wind_mps())
        acc = math.sqrt(ekf.wind_accuracy() ** 2 + sys_var) * self.consistency.inflation
        if ekf.mode == MODE_TAUT:  # the lean the body and the model disagree on: not scaled by the monitor's factor,
            # which measures the same misfit (consistency.lean_misfit_wind)
            c = self.consistency
            acc = math.hypot(acc, lean_misfit_wind(speed, c.lean_tilt, c.lean_misfit))
            if ekf.time_taut_us >= 0:  # the snap still settling (consistency.placement_settling_wind)
                since = (ekf.time_us - ekf.time_taut_us) * 1e-6  # the scale: the placement's wind or the swing's
                acc = math.hypot(acc, placement_settling_wind(since, max(speed, self.wind_taut_mps)))
        if self.unconfirmed:
            acc = max(acc, math.sqrt(wn * wn + we * we + 1.0))
        if ekf.mode != MODE_GROUND:  # no magnetometer for HEADING_LOST_S: the heading is the gyro's alone since then
            last = max(self.mag_status[0].time_last_fuse_us, self.heading_status.time_last_fuse_us, self.t_boot_us)
            seconds = (ekf.time_us - last) * 1e-6
            if seconds > HEADING_LOST_S:
                acc = math.hypot(acc, gyro_heading_wind(speed, math.radians(self.cfg.init_gyro_bias_dps), seconds))
        if self.field_heading_var > 0.0:  # a magnetometer offset turned with the balloon: its unseen part turns it
            acc = math.hypot(acc, speed * math.sqrt(self.field_heading_var))
        return acc

    def _field_variance(self) -> float:
        """The attitude's variance about the magnetic field's axis in P, rad^2; 0 while the field is unknown."""
        return field_variance(self.ekf.P, *self.field_ned)

    def field_extra_variance(self) -> float:
        """The attitude's variance about the magnetic field's axis that P does not hold, rad^2: the larger of what is
        counted (consistency.field_attitude_extra) and what is seen (consistency.heading_misfit_variance), two
        estimates of one error (their sum counted it twice)."""
        return max(self.ekf.field_att_extra, heading_misfit_variance(self.consistency.slow_tilt_var))

    def lean_wind_mps(self) -> float:
        """The wind error of the tilt's systematic error (with the horizontal accelerometer bias's wander since the
        boot, consistency.lean_bias_rad) and of the attitude's variance across the lean (P's and what
        P does not hold about the field's axis, the larger of what is counted and what is seen:
        consistency.field_attitude_extra, consistency.heading_misfit_variance; consistency.lean_tilt_variance) on the
        taut tether
        (consistency.lean_bias_wind), m/s; 0 off it."""
        ekf = self.ekf
        if ekf.mode != MODE_TAUT:
            return 0.0
        m = self.model
        wn, we = self.wind()
        r = rotation(*ekf.q.tolist())
        zn, ze, zd = r[2], r[5], r[8]  # the body's down axis, along the rope
        lean = math.hypot(zn, ze)
        cross_var = lean_variance(ekf.P, ze / lean, -zn / lean, zn, ze, zd) if lean > 0.0 else 0.0  # across the lean
        extra = self.field_extra_variance()
        tilt_var = lean_tilt_variance(cross_var, extra, self.field_ned, zn, ze, zd)
        bias = lean_bias_rad(self.cfg.accel_bias_walk_mps2_rt_s, 1e-6 * (ekf.time_us - self.t_boot_us))
        return lean_bias_wind(wn, we, m.lift_n(self.rho), float(ekf.x[DRAG]) * self.rho * m.half_cd_area_m2, bias,
                              self.field_ned, tilt_var, bias_tilt_rad(self.accel_hbias_var),
                              math.radians(self.design.sensors.imu_alignment_deg))  # fmt: skip

    def wind(self) -> tuple[float, float]:
        return float(self.ekf.x[WIND_N]), float(self.ekf.x[WIND_E])

    def height_m(self) -> float:
        """Estimated height of the balloon's centre above the anchor."""
        return -float(self.ekf.x[POS_D])
