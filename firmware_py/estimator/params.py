"""The estimator's internal tunables, each named once with its unit: input limits, schedules and
timeouts (in seconds, so any IMU rate behaves the same in time), model errors. What a user may set is
the ``[filter]`` section (``state.FilterConfig``); these are the design choices behind it, explained
in docs/estimator.md and docs/decisions.md."""

from __future__ import annotations

import math
from dataclasses import dataclass

ACC_MAX = 160.0  # m/s^2 (16 g)
GYRO_MAX = 35.0  # rad/s (2000 deg/s)
MAG_MAX = 4.0  # gauss
P_MIN_HPA, P_MAX_HPA = 300.0, 1100.0
T_MIN_C, T_MAX_C = -60.0, 85.0
BARO_ZERO_S = 1.0
REORDER_WINDOW_US = 1_000_000
TAUT_PERIOD_S = 0.05  # the taut constraints at 20 Hz
# the taut rod's model errors from the rope's own motion, per unit of rope mass / balloon mass (the
# reference: 2 kg of rope on a 1.84 kg balloon): accelerations and the lean the rod does not predict
ROPE_WAVE_ACCEL_MPS2 = 0.26
VERTICAL_TURBULENCE_RATIO = 0.5  # sigma_w / sigma_u (IEC 61400-1): the vertical air the model leaves out
ROPE_WAVE_ALIGN_RAD = 0.016
# the rope shape (chord, weight on the rod) follows the mean wind, slowly: a fast one feeds the
# wind estimate back into the model (a 0.05 Hz resonance, gain 4 on the real rope)
ROPE_SHAPE_S = 60.0
# the tilt's systematic error (accelerometer bias 1-3 mg, the learnt field's direction): what no averaging
# removes from the lean, so from the wind in calm air, where the lean is a degree (consistency.py)
LEAN_BIAS_RAD = 0.0035
# no magnetometer fused for this long (or since the start): the heading is the gyro's alone, and the wind's direction
# with it (consistency.gyro_heading_wind; a magnetometer fuses at 10-100 Hz)
HEADING_LOST_S = 5.0
# a barometric height (less the offset state) further than this below the anchor or beyond the tether's reach is no
# balloon's on this tether: not fused, no reset to it, counted rejected (a step of 50 hPa read as 400 m of height was
# forced in and re-placed the taut balloon every 2 s, a 24 m/s wind where 3 blew)
BARO_PLAUSIBLE_M = 50.0
# the accelerometer's horizontal bias walked since the field was learnt is followed from its slow innovation over this
# long (aid_sources/accel.py follow_horizontal_bias). About a quarter of a new bias stays in the innovation, so the
# bias is followed over about 1200 s: a walk of 0.001 m/s^2 per sqrt(s) to 0.025 m/s^2 (0.12 unfollowed over four
# hours). Faster it takes more of the force model's slow misfit for a bias: at 120 s the envelope's worst light-air
# multisine (flight 187) read 2 % further off and a steady 7.6 m/s flight 1.3 %, where at 300 s none reads more than
# 1.1 % further off. Within +-ACCEL_HBIAS_MAX_MPS2 (100 mg: beyond any MEMS part's bias in flight, a guard against a
# runaway only)
ACCEL_HBIAS_S = 300.0
ACCEL_HBIAS_MAX_MPS2 = 1.0
# the share of a bias along the field's horizontal direction that stays in the accelerometer's innovation, the loop's
# gain on it (a 0.1 m/s^2 step on body x on field-rope: 0.023 m/s^2 of it stayed; the followed bias closed on it over
# 1000-1400 s at ACCEL_HBIAS_S 300): the followed bias's error variance settles at walk^2 ACCEL_HBIAS_S / (2 x this)
ACCEL_HBIAS_RESIDUE = 0.25
# the attitude's variance across the lean is a displacement of the body's axis, which turns the lean's azimuth by
# itself over sin(lean) (a tilt d turns it by d / tan(lean)): over cos^2(lean) into lean_bias_wind
# (consistency.lean_tilt_variance), the lean taken at most to acos of this (84 deg: at most x100 in variance)
LEAN_COS_MIN = 0.1
# the drag scale learnt in a free ascent is worth at most this (1-sigma, relative): the ascent's model leaves
# out the vertical air and the gusts (a downdraft through the climb reads as drag: +20 % in class B gusts).
# It learns only while the rope's pull is known to this share of the net lift (control._rope_load_known)
DRAG_ASCENT_SIGMA = 0.1
# ... until the taut flight has measured the turbulence (control._weigh_ascent): the wind speed's variance about
# the window's own mean from TURBULENCE_FROM_S after the entry (the entry's settling is over) to TURBULENCE_TO_S,
# when the ascent's drag scale is weighed again as a measurement of 1-sigma DRAG_ASCENT_FLOOR in still air (the
# full envelope's 50 steady flights, tools/ascent_scale.py: 1.8 % RMS, 5.0 % worst, +0.1 % mean with the rope's
# pick-up in the ascent's model, 3.1 %, 7.7 % and +2.5 % without it; the rope's pull in the wind and the added mass
# are models) and
# 2 sigma_w / v_climb with vertical air sigma_w = VERTICAL_TURBULENCE_RATIO sigma_u (F ~ k v^2: dk / k = 2 w / v)
DRAG_ASCENT_FLOOR = 0.02
# ... unless the ascent and its prior (the design's) disagree beyond this many sigma of their difference (a chance
# of 0.3 % where both hold): a sphere's C_d depends on its Reynolds number, and through the drag crisis the ascent's
# airspeed (4-5 m/s) and the tether's differ by half; either may hold, so their mixture is taken
# (WindEkf.weigh_information), at the ascent's cap already (at DRAG_ASCENT_SIGMA, or the ascent's claim where less)
# and again at the weighing
DRAG_CONFLICT_SIGMA = 3.0
TURBULENCE_FROM_S = 60.0
TURBULENCE_TO_S = 120.0
ALIGN_INNOV_S = 5.0  # averaging time of the alignment's innovations that set its noise floor
ALIGN_CROSS_VAR_MAX = 0.05**2  # rad^2: the most a rocking balloon's azimuth departs from its rope's
# the share of the attitude's rotation about the magnetic field's axis that the alignment takes into its row (a column
# about that axis), the rest left to its noise as a parameter's (tether.field_axis_row): the axis only the
# accelerometer's tilt holds otherwise, and blown magnetically north the rope's direction turns with it. Without it a
# south wind's estimate swung across at the balloon's pendulum period (paper-reference from 180 deg: band skill 0.57,
# error/accuracy 2.4); taken whole (1.0) a taut state that is off turned the attitude with it (class B gusts from the
# south); flown from four directions (paper-reference, gusty-6, field-rope-multisine) and on the full envelope, 0.5
# made no flight worse by more than noise where 0.25 and 1.0 did (docs/estimator.md, "The wind from magnetic south")
ALIGN_FIELD_AXIS_SHARE = 0.5
ALIGN_RESET_S = 2.0  # rejected alignment this long re-places the taut state
JOIN_IN_FLIGHT_US = 10_000_000  # a first sample this long after the sender's boot: we restarted in flight
# After a join in flight the balloon hypothesis is unconfirmed: the wind read from the tilt through the
# static balance is only as good as the assumption that this is a balloon on its tether. The motion
# confirms it: a tethered balloon in a real (turbulent) wind accelerates across its rope, and the force
# model explains that acceleration (control._confirm; along the rope the vertical air and the rope's
# breathing, which the model leaves out). Until then the reported accuracy (``wind_accuracy``) is at least
# the wind's own magnitude (and 1 m/s): the estimate cannot be told from calm. The filter runs on unchanged.
CONFIRM_MOTION_MPS2 = 0.03  # RMS of the acceleration's fluctuation across the rope (a resting sensor: noise only)
CONFIRM_EXPLAINED = 0.5  # the model's innovations there below this share of that fluctuation's variance
CONFIRM_S = 20.0  # both, for this long without a break once the placement has settled (BALANCE_FROM_S)
CONFIRM_WINDOW_S = 10.0  # time constant of the acceleration's running mean (NED)
BARO_RESET_S = 2.0  # rejected barometer this long: reset the height to it
BARO_NOMINAL_HZ = 20.0  # the barometer's rate its counts are taken at (its samples are fused as they come)
FALSE_RELEASE_S = 3.0  # free ascent that stays below the release height this long was a bump
BARO_MODEL_M = 0.3  # hypsometric conversion error (temperature profile, lag) added to the sensor's noise
# the drag scale learns from this long after the release: the climb speed state follows the drag scale, and held at
# the design's value for 2 s it lagged the truth's by 8 % (C_d 20 % off) and pulled the ascent's scale back towards
# the design's (the steady flights: 4.2 % RMS, 10.8 % worst)
LEARN_DRAG_AFTER_S = 0.5
# ... and only while the air flows past the balloon mostly from above: the state's horizontal wind relative to it at
# most this times its vertical speed (control._airflow_from_above). Released in a wind, the balloon first sits in the
# whole of it, and the vertical drag k c |u| u_z turns on the horizontal part of |u|, which the state has only begun
# to learn: in Kaimal turbulence a 2 s spell there read the drag scale 24 % low, claimed to 4 % (docs/estimator.md,
# "A held-out sample")
ASCENT_AIRFLOW_RATIO = 1.0
# the magnetometer averaged this long after a restart in flight (no rest on the ground), and on the tether
FIELD_FLIGHT_S = 60.0
# the earth field learnt again on the taut tether from this long after its entry (the rope's catch damped: the mean
# specific force is gravity's), over FIELD_RELEARN_S (aid_sources/magnetometer.learn_field_in_flight): the boot's holds
# at the boot's heading and tilt only, and until it is replaced a hard-iron offset tilted with the balloon pulls the
# attitude (docs/estimator.md, "The field learnt again on the tether")
FIELD_RELEARN_FROM_S = 5.0
FIELD_RELEARN_S = 15.0
# ... and again over FIELD_FLIGHT_S from this long after it, once the released balloon has turned to the wind
FIELD_RELEARN_AGAIN_FROM_S = 30.0
ACCEL_INNOV_S = 2.0  # averaging time of the accelerometer's innovations that set its noise floor
# the specific force's model error (the rope's waves, the drag's lag behind a gust) is correlated over about this
# long, and the accelerometer is fused every sample as if it were white: for the tilt, which the gyro holds and the
# magnetometer also measures, that is its error. The tilt takes sqrt(dt / ACCEL_MODEL_CORR_S) of its gain in flight
# (0.1 at 100 Hz: a correlated error is worth that many fewer independent samples, and a walking state's gain goes as
# 1 / sqrt(R)); the covariance is the one for the gain used (ekf.fuse3, Joseph form). The heading and the gyro bias
# take less in proportion to the accelerometer's windowed NIS from consistency.FLAG_NIS to twice that (aid_sources/
# accel.py), down to ACCEL_HEADING_GAIN_MIN: taut, the accelerometer reads the heading through the lean's azimuth
# (the pull's direction), from the same force model, and about the magnetic field's axis only it holds the attitude;
# at the full gain the paper's rope blown down 65 deg in class B gusts drove the bias 0.16 deg/s in 20 s and the
# attitude 3 deg about the field, where 0.5 was stated, and the wind 1.4 m/s across (the envelope's quick flight 23,
# before the wind's noise stopped following the misfit, control._turbulence_excess). Always at the reduced gain, the
# heading lost what the accelerometer tells of it where the model fits (the real rope's multisine: band skill
# 0.76 -> 0.57), and the bias in light air, where it must be learnt in flight. What the heading's full gain takes from
# a correlated misfit is stated instead: the accuracy carries the attitude's variance about the field's axis with
# the accelerometer's and the alignment's information worth dt / (NIS ACCEL_MODEL_CORR_S) of what they fused, NIS
# against the noise fused (dt / ACCEL_MODEL_CORR_S for a consistent source; consistency.field_attitude_extra)
ACCEL_MODEL_CORR_S = 1.0
# the alignment's misfit (the balloon's rocking, the rope's waves) is correlated over this long where the force model
# has stopped explaining the accelerometer: its along and cross innovations' autocorrelation falls by e in 0.25-0.45 s
# in class B gusts and on the real rope (from 120 s, seed 1; a script, not in a command of the repo). There the
# attitude takes sqrt(interval / this) of the alignment's gain (aid_sources/tether.py control_tether). The attitude's
# extra variance (consistency.field_attitude_extra) keeps counting the alignment's information over
# ACCEL_MODEL_CORR_S: where the model fits, its innovations are the state's own slow error (0.75-0.95 s, the paper's
# multisine)
ALIGN_MODEL_CORR_S = 0.4
# ... but a tethered balloon does not accelerate on average: its velocity is bounded, so the mean of its acceleration
# over T falls as 1 / T, and the mean of its specific force is gravity's, whatever the force model says
# (aid_sources/accel.py fuse_level). The balloon's horizontal acceleration (NED) has no power at zero frequency: over
# 10 s its mean is 0.05-0.13 of its RMS, over 20 s 0.03-0.06, over 60 s 0.01-0.02 (the truth of paper-reference,
# field-rope, field-rope-multisine, reduced-balloon, gusty-6, field-gusty-6; seed 1, after 120 s). Fused as white
# noise of the measured variance times 2 LEVEL_CORR_S / dt, the rows claim sqrt(2 LEVEL_CORR_S / T) of it for the mean
# over T: 0.24 over 10 s, 0.17 over 20 s, 0.10 over 60 s, twice what the truth holds or more at every window from
# 10 s. A wind that changes over tens of seconds moves the balloon metres and accelerates it coherently there: at 0.1
# s the paper's multisine read 0.05 Hz at |H - 1| 0.24 instead of 0.14 (4 seeds); at 1 s the magnetic equator's wind
# along the meridian was lost again (docs/estimator.md, "The level rows"). The variance is the specific force's (NED,
# horizontal, per axis) about its mean over LEVEL_MEAN_S
LEVEL_CORR_S = 0.3
LEVEL_MEAN_S = 10.0
# the least of its gain the heading and the gyro bias take where the accelerometer misfits (above). Not the tilt's
# tenth: the same rows move the position's azimuth about the anchor at the full gain, and a heading that lagged it let
# the pair's rotation about the magnetic field's axis (which the magnetometer cannot see) swing across the rope and
# grow after the taut entry, position, attitude and wind together: 200-300 m tethers in 10 m/s from the south read
# 1-5 m/s RMS off at error/accuracy up to 2.2. At the full gain class B gusts in 10-15 m/s lost band skill (0.06-0.28
# in 9 of 64 stress flights); at half they keep most of it (docs/estimator.md, "The swing across the rope")
ACCEL_HEADING_GAIN_MIN = 0.5
TAUT_PULL_S = 1.0  # after a slack spell the rope must pull this long before the filter is taut again
MEAN_WIND_S = 60.0  # averaging time of the mean wind that scales the wind's process noise
# light air meanders: sigma_u stays near 0.3-0.5 m/s however low the mean wind (low-wind meandering), so where
# TI U is below this the filter's own turbulence (its speed's variance) may raise the wind's noise up to it
LIGHT_AIR_SIGMA_U_MPS = 0.5
WIND_NOISE_PERIOD_S = 1.0  # time between updates of that noise
FIELD_LEARN_S = 1.0  # at least this much magnetometer on the ground (all of the ground time is used)
MAG_MODEL_GAUSS = 0.004  # field direction model error (~0.5 deg of a 0.5 G field: soft iron, anomalies)
# the field learnt again on the tether replaces the boot's only this far from it (twice the field's model error):
# a hard-iron offset turned with the balloon, 0.014-0.016 G in field-turning-hard-iron; the means' own scatter in
# class B gusts and an accelerometer's bias read at the lean, 0.002-0.004 G
FIELD_CHANGE_GAUSS = 2.0 * MAG_MODEL_GAUSS
# the magnetometer's own field may jump in flight: a heater, a radio or a servo switched on a few centimetres from it
# (0.3 A at 5 cm: 0.012 G), which a field learnt at the boot cannot know. Its strength |m| no rotation changes: its
# mean over FIELD_JUMP_SHORT_S leaving its mean over FIELD_JUMP_LONG_S by more than FIELD_JUMP_GAUSS (the field's
# model error; 5 sigma of the short mean's noise at the paper's 0.005 G, sampled at the tether's 20 Hz) is a jump
# (magnetometer.watch_field)
FIELD_JUMP_GAUSS = MAG_MODEL_GAUSS
FIELD_JUMP_SHORT_S = 1.0
FIELD_JUMP_LONG_S = 10.0
# ... or the field vector rejected this long in a row: a burst (a radio's transmission, tenths of a second) is not
# a jump, its samples only rejected
FIELD_JUMP_REJECTED_S = 1.0
# the heading's variance the replaced fields' unseen parts may add up to, rad^2: a heading known to a radian is not
# known (magnetometer.learn_field_in_flight)
FIELD_HEADING_VAR_MAX = 1.0

# the winch (aid_sources/winch.py) and the ground reference (aid_sources/ground_ref.py)
# a WINCH_STATUS is rejected (and counted) when its line length is not finite, below WINCH_LENGTH_MIN_M or
# beyond the design's tether (the rope on the drum) + WINCH_LENGTH_MARGIN_M, shorter than the balloon's
# barometric height less WINCH_HEIGHT_TOL_M, or its reel speed not finite or beyond WINCH_SPEED_MAX_MPS
WINCH_LENGTH_MIN_M = 1.0
WINCH_LENGTH_MARGIN_M = 5.0  # the winch's length counter against the drum's rope
WINCH_HEIGHT_TOL_M = 15.0  # the barometric height's error (weather, noise) the length check allows
WINCH_SPEED_MAX_MPS = 10.0  # a reel speed beyond this is not a winch's
# why the last WINCH_STATUS / ground reference was rejected (the summary says it in words)
WINCH_REJECT_LENGTH, WINCH_REJECT_HEIGHT, WINCH_REJECT_SPEED = 1, 2, 3
GROUND_REJECT_PRESSURE, GROUND_REJECT_TEMPERATURE = 1, 2
# a ground reference outside these is rejected (and counted): a ground station's weather
GROUND_P_MIN_HPA, GROUND_P_MAX_HPA = 300.0, 1100.0
GROUND_T_MIN_C, GROUND_T_MAX_C = -80.0, 60.0
WINCH_TIMEOUT_S = 1.0  # no WINCH_STATUS this long: the reel is taken to have stopped
GROUND_REF_S = 10.0  # low-pass of the ground reference's pressure (its noise; the weather is slower)

MAG_RECOVER_S = 0.1  # the magnetometer and heading: rejected this long, fused again with inflated noise
RELEASE_CONFIRM_S = 0.03  # | |f| - g | above the release threshold this long (3 samples at 100 Hz)
RELEASE_HEIGHT_S = 0.5  # barometric height above the release height this long
# the placement after a taut switch (aid_sources.tether.enter_taut)
UNGATED = 1e6  # a gate in sigmas that never rejects (the radius and radial-rate rows, the level rows)
TAUT_AZIMUTH_MIN_M = 3.0  # horizontal offset of the ascent that fixes the azimuth at the taut switch
TAUT_LEAN_MIN_SIN = math.sin(math.radians(3.0))  # a lean this large gives the azimuth to a few degrees
ALIGN_PULL_DOWN_MIN = 0.05  # the rope's pull on the balloon taken at least this far down (87 deg from vertical)
TAUT_POS_SIGMA_M = 5.0  # after a placement: wide enough for the alignment row to move it where the tilt says
TAUT_VEL_SIGMA_MPS = 1.0  # the balloon still swings after the snap
TAUT_WIND_SIGMA_MPS = 1.5  # the static balance's wind at the snap (the balloon is not yet in balance)
# after a taut placement the stated accuracy falls from TAUT_WIND_SIGMA_MPS and the wind's own speed in quadrature no
# faster than by e in this long
# (consistency.placement_settling_wind): the snap is not the rod's (the balloon climbs on as the rope's sag is taken
# up, or bounces on a stiff one), its rows pull the state for seconds, and P, which takes them as consistent, fell
# from the placement's 1.5 m/s to 0.8 in five. Over the envelope's 200 first entries (a script over the flights of
# python -m benchmarks.bench_envelope, not in a command of the repo) the wind's RMS error was 2.0-2.4 m/s in the first
# 2 s (90 % within 4.1), 0.57 at 7-10 s, 0.25 at 20-30 s: its excess over the settled flight's falls by e in 5-11 s
ENTRY_SETTLE_S = 8.0
# the force balance (consistency.balance_nis) is judged from this long after a taut placement, its mean and that mean's
# variance from zero then: before, the placement's own convergence pulls the velocity, which the settling above states;
# judged from the entry on, a mean that still held the settling flagged every entry for a minute after it had settled
BALANCE_FROM_S = 3.0 * ENTRY_SETTLE_S
# covariance hygiene (ekf.fix_covariance) and the held balloon
VAR_MIN = 1e-9  # floor of every variance
POS_VAR_MAX_M2 = 1e4
VEL_VAR_MAX_M2S2 = 400.0
ATT_VAR_MAX_RAD2 = 0.3
GYRO_BIAS_SIGMA_MAX_DEG_S = 5.0
WIND_VAR_MAX_M2S2 = 100.0
WRATE_VAR_MAX_M2S4 = 4.0
DRAG_VAR_MAX = 1.0
ABIAS_VAR_MAX_M2S4 = 1.0
GROUND_PROCESS_VAR = 1e-8  # position and velocity process noise per step while held on the ground station
DRAG_SCALE_MIN = 0.2  # the drag scale is held above this (a balloon always has drag)


@dataclass(frozen=True)
class Schedule:
    """The times above as counts of the steps (or samples) they are checked at, for one IMU rate."""

    taut_every: int  # steps between taut fusions
    align_reset: int  # rejected alignment fusions before a taut re-placement
    baro_reset: int  # rejected barometer samples before a height reset
    baro_recover: int
    mag_recover: int
    field_learn: int  # magnetometer samples
    field_flight: int
    wind_noise_every: int  # steps
    release_confirm: int
    release_height: int
    turbulence_from: int  # taut steps: the ascent's turbulence window (control._weigh_ascent)
    turbulence_to: int
    rope_shape_alpha: float  # low-pass weight per taut step of the rope shape (ROPE_SHAPE_S)

    @classmethod
    def at(cls, imu_rate_hz: float, recover_after_s: float) -> Schedule:
        taut_every = max(1, round(TAUT_PERIOD_S * imu_rate_hz))
        taut_hz = imu_rate_hz / taut_every
        return cls(
            taut_every=taut_every,
            align_reset=max(1, round(ALIGN_RESET_S * taut_hz)),
            baro_reset=max(1, round(BARO_RESET_S * BARO_NOMINAL_HZ)),
            baro_recover=max(1, int(recover_after_s * BARO_NOMINAL_HZ)),
            mag_recover=max(1, round(MAG_RECOVER_S * imu_rate_hz)),
            field_learn=max(1, round(FIELD_LEARN_S * imu_rate_hz)),
            field_flight=max(1, round(FIELD_FLIGHT_S * imu_rate_hz)),
            wind_noise_every=max(1, round(WIND_NOISE_PERIOD_S * imu_rate_hz)),
            release_confirm=max(1, round(RELEASE_CONFIRM_S * imu_rate_hz)),
            release_height=max(1, round(RELEASE_HEIGHT_S * imu_rate_hz)),
            turbulence_from=max(1, round(TURBULENCE_FROM_S * imu_rate_hz)),
            turbulence_to=max(1, round(TURBULENCE_TO_S * imu_rate_hz)),
            rope_shape_alpha=min(1.0, 1.0 / (ROPE_SHAPE_S * taut_hz)),
        )
