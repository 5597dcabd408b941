"""Named state indices and the filter's tuning (the [filter] config section).

Error-state EKF: position, velocity, wind and the drag scale are total states; the attitude is a
nominal quaternion with a 3-element rotation-vector error (NED frame) in the covariance; the gyro
bias turns the gyro into the angular-rate estimate (gyro - bias).
"""

from __future__ import annotations

from dataclasses import dataclass

from balloon_core.config import build_section
from firmware_py.estimator.generated import COLUMNS

POS_N, POS_E, POS_D = 0, 1, 2  # m, NED from the anchor, the balloon's centre
VEL_N, VEL_E, VEL_D = 3, 4, 5  # m/s NED (body velocity U^B of paper Eq. 8 is R^T v)
ATT_N, ATT_E, ATT_D = 6, 7, 8  # rad, attitude error rotation vector (true = (I + [d x]) estimate)
GB_X, GB_Y, GB_Z = 9, 10, 11  # rad/s gyro bias, body FRD (angular rate Omega = gyro - bias)
WIND_N, WIND_E = 12, 13  # m/s air velocity, horizontal (the paper's wind is horizontal)
WRATE_N, WRATE_E = 14, 15  # m/s^2 rate of change of the wind (its push on the balloon: Froude-Krylov)
DRAG = 16  # drag scale: multiplies 1/2 rho Cd pi r^2 (Cd is uncertain in the drag crisis)
BARO_OFF = 17  # m: barometric height minus true height (the weather moves the barometer, metres an hour)
ABIAS_Z = 18  # m/s^2: accelerometer bias along body z (with the local gravity's departure from G0)
N_STATES = 19
STATE_NAMES = (
    "pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d", "att_n", "att_e", "att_d",
    "gbias_x", "gbias_y", "gbias_z", "wind_n", "wind_e", "wrate_n", "wrate_e", "drag_scale", "baro_offset",
    "abias_z",
)  # fmt: skip
# the states the balloon model's Jacobians are taken over, in the generator's order (generated.COLUMNS)
MODEL_COLUMNS = tuple(STATE_NAMES.index(name) for name in COLUMNS)

# operating modes
MODE_GROUND, MODE_FREE, MODE_TAUT = 0, 1, 2
MODE_NAMES = ("ground", "free", "taut")


@dataclass(frozen=True)
class FilterConfig:
    """Tuning ([filter] section). Noise figures are 1-sigma; *_rt_s are per sqrt(second)."""

    imu_rate_hz: float = 100.0
    float32: bool = False
    # which core runs the filter: "c" the C99 core (firmware_c/, the firmware as flashed; float32 or
    # double as ``float32`` says), "py" this Python reference; they agree step by step (docs/porting.md)
    core: str = "c"
    # process noise
    accel_process_mps2: float = 0.05  # unmodelled force per unit mass between two samples (docs/estimator.md)
    # the wind the filter expects (its process noise is derived from this spectrum: tuning.py)
    expected_wind_mps: float = 3.0
    turbulence_intensity: float = 0.2  # sigma_u / U the filter expects (docs/estimator.md: chosen by NEES)
    # the drag scale's random walk: the balloon's drag changes with time through its gas (a few per cent of its
    # volume lost or heated by the sun over hours, the area with it): 0.0005 per sqrt(s) is 3 % in an hour, 8.5 %
    # in eight; on the taut tether nothing measures the scale, so this is the growth of its stated uncertainty
    # (0.002 grew it by 12 % an hour, 34 % over a field day, where the physics had not changed)
    drag_walk_rt_s: float = 0.0005
    # the barometer's offset walk: the weather moves the ground pressure 1-3 hPa in 3 h (8 m per hPa);
    # 0.1 m/sqrt(s) is 6 m in an hour as a random walk and follows a 2 hPa/h front within metres
    baro_walk_m_rt_s: float = 0.1
    accel_bias_walk_mps2_rt_s: float = 0.001  # body-z accelerometer bias random walk (MEMS: 0.0005-0.002)
    # the gyro bias walks with the temperature (a MEMS gyro's 0.015 deg/s per K, 10 K in an hour of sun and shade:
    # 0.15 deg/s, 0.0025 per sqrt(s)); a looser walk let the yaw follow the force model's misfit (about the
    # magnetic field's axis only the accelerometer holds it: docs/estimator.md, "The whole envelope"), and a
    # truth whose bias walks 2.5 times faster than this is still better followed than with the old 0.005
    gyro_bias_walk_dps_rt_s: float = 0.0025
    # measurement model errors added to the sensor noise of [sensors]
    accel_model_mps2: float = 0.15  # specific-force model error in free ascent
    accel_taut_mps2: float = 0.1  # specific-force model error on the taut tether (rope waves, rocking)
    accel_static_mps2: float = 0.3  # accelerations of the quasi-static balloon (ground, taut)
    align_rad: float = 0.01  # balloon-to-rope-force alignment error (rotational oscillation)
    radial_m: float = 0.3  # tether length + stretch uncertainty when taut
    radial_rate_mps: float = 0.15
    # the taut rope: "catenary" = its real shape (catenary.py: sag, its weight shared with the anchor,
    # its drag); "paper" = Eq. (5), straight with its whole weight on the balloon
    rope_model: str = "catenary"
    # rope cross-flow drag coefficient (Hoerner: 1.1 for a round rope); 0 = no rope drag (the paper)
    rope_normal_cd: float = 1.1
    # gates (innovation test in sigmas)
    gate_sigma: float = 5.0
    recover_after_s: float = 1.0  # a fusion rejected this long is taken again, noise inflated to the gate
    # initial uncertainty
    init_wind_mps: float = 6.0
    init_drag: float = 0.1
    init_accel_bias_mps2: float = 0.05  # body z: turn-on bias and the local gravity (9.78-9.83 m/s^2)
    init_gyro_bias_dps: float = 0.5
    init_tilt_deg: float = 3.0
    init_yaw_deg: float = 10.0
    # mode logic
    taut_margin_m: float = 1.5  # enter taut when the distance reaches length - margin
    mode_dwell_s: float = 1.0
    release_accel_mps2: float = 1.5  # |f| - g that signals the release
    release_height_m: float = 3.0
    max_gap_s: float = 0.5  # predict through gaps up to this, then flag and re-anchor

    @classmethod
    def from_dict(cls, values: dict) -> FilterConfig:
        return build_section(cls, "filter", values)
