"""EKF core: fixed-size memory, prediction, sequential scalar fusion, covariance hygiene.

Everything the filter touches per sample is allocated here, once. The per-sample path uses numpy
only with ``out=`` arguments and plain Python floats, so a steady-state step creates no numpy array
(tests/unit/test_allocation.py counts numpy's tracemalloc domain). A C port maps each array to a static
buffer and each ``np.*(..., out=)`` call to a loop.
"""

from __future__ import annotations

import math

import numpy as np

from balloon_core.atmosphere import G0
from balloon_core.rotation import rotation
from firmware_py.estimator.catenary import RopeShape, calm_weight_share
from firmware_py.estimator.model import BalloonModel, Forces, accelerations
from firmware_py.estimator.params import (
    ABIAS_VAR_MAX_M2S4,
    ATT_VAR_MAX_RAD2,
    DRAG_SCALE_MIN,
    DRAG_VAR_MAX,
    GROUND_PROCESS_VAR,
    GYRO_BIAS_SIGMA_MAX_DEG_S,
    POS_VAR_MAX_M2,
    VAR_MIN,
    VEL_VAR_MAX_M2S2,
    WIND_VAR_MAX_M2S2,
    WRATE_VAR_MAX_M2S4,
)
from firmware_py.estimator.state import (
    ATT_D,
    ATT_E,
    ATT_N,
    DRAG,
    GB_X,
    GB_Y,
    GB_Z,
    MODE_GROUND,
    MODE_TAUT,
    MODEL_COLUMNS,
    N_STATES,
    POS_D,
    POS_E,
    POS_N,
    VEL_D,
    VEL_E,
    VEL_N,
    WIND_E,
    WIND_N,
    WRATE_E,
    WRATE_N,
    FilterConfig,
)
from firmware_py.estimator.tuning import wind_process

N = N_STATES


def gap_attitude_var(
    last_rate: tuple[float, float, float], rate: tuple[float, float, float], held_s: float, lost: bool
) -> float:
    """What a gap in the IMU's samples costs the attitude (rad², each axis). Across it the prediction holds the rate
    of the sample before (the new one for its last step): a rate that changed linearly from that to the new one turned
    the balloon by ``|Δω| held_s / 2`` more. Beyond ``max_gap_s`` (``lost``) the rate may have swung and back within
    the gap, and the balloon rocks at tens of degrees a second after the rope's catch: the held rate may be wrong by
    all of itself, ``max(|ω|) held_s``."""
    d2 = 0.25 * sum((a - b) * (a - b) for a, b in zip(last_rate, rate, strict=True))
    if lost:
        d2 = max(d2, sum(a * a for a in last_rate), sum(b * b for b in rate))
    return d2 * held_s * held_s


class FusionStatus:
    """Per-fusion bookkeeping, as PX4's estimator_innovations / test ratios."""

    __slots__ = ("name", "innov", "innov_var", "test_ratio", "fused", "rejected", "consecutive_rejects",
                 "recover_after", "time_last_fuse_us", "time_test_us")  # fmt: skip

    def __init__(self, name: str, recover_after: int = 0) -> None:
        self.name = name
        self.recover_after = recover_after  # consecutive rejections before a forced fusion (0: filter default)
        self.innov = 0.0
        self.innov_var = 0.0
        self.test_ratio = 0.0
        self.fused = 0
        self.rejected = 0
        self.consecutive_rejects = 0
        self.time_last_fuse_us = -1  # the filter time of the last fusion (-1: never), as PX4's time_last_fuse
        self.time_test_us = -1  # the filter time of the last innovation test (fused or rejected)


# the kinds of state reset: the control logic re-places the state instead of fusing a measurement
RESET_INITIALISE, RESET_TAUT, RESET_HEIGHT, RESET_DRAG = 0, 1, 2, 3
RESET_NAMES = ("initialise", "taut_placement", "height", "drag_scale")
# what a correlated misfit of the accelerometer must not drag at the full gain (fuse3)
SLOW_STATES = (ATT_N, ATT_E, ATT_D, GB_X, GB_Y, GB_Z)


def in_conflict(prior_var: float, data_var: float, d: float, conflict_sigma: float) -> bool:
    """A prior and a datum ``d`` from it do not both hold: more than ``conflict_sigma`` (> 0) sigma of their
    difference apart (``WindEkf.weigh_information``)."""
    return conflict_sigma > 0.0 and d * d > conflict_sigma * conflict_sigma * (prior_var + data_var)


def weighed_variance(prior_var: float, data_var: float, d: float, conflict_sigma: float) -> float:
    """The variance of a prior weighed with one datum ``d`` from it (both variances > 0): their combination, or in
    conflict (``in_conflict``) their equal mixture's, the two's mean and the square of half their difference."""
    if in_conflict(prior_var, data_var, d, conflict_sigma):
        return 0.5 * (prior_var + data_var) + 0.25 * d * d
    return 1.0 / (1.0 / prior_var + 1.0 / data_var)


class WindEkf:
    def __init__(self, model: BalloonModel, cfg: FilterConfig, sensors) -> None:
        self.model = model
        self.cfg = cfg
        self.dtype = np.float32 if cfg.float32 else np.float64
        dt = 1.0 / cfg.imu_rate_hz
        self.dt = dt
        z = self.dtype
        self.x = np.zeros(N, z)
        self.q = np.array([1.0, 0.0, 0.0, 0.0], z)  # nominal attitude, body -> NED
        self.P = np.zeros((N, N), z)
        self.F = np.eye(N, dtype=z)
        self.Qd = np.zeros(N, z)
        self._t1 = np.zeros((N, N), z)
        self._t2 = np.zeros((N, N), z)
        self.h = np.zeros(N, z)
        self._ph = np.zeros(N, z)
        self._k = np.zeros(N, z)
        self._v = np.zeros(N, z)
        self.dx = np.zeros(N, z)
        # three-row (vector) fusion of one sensor's axes: accelerometer, magnetometer
        self.H3 = np.zeros((3, N), z)
        self.ja = np.zeros((3, len(MODEL_COLUMNS)), z)  # d a / d x of this step (generated.COLUMNS)
        self.rt = np.zeros((3, 3), z)  # R^T of this step's attitude, for the accelerometer rows
        self.hja = np.zeros((3, len(MODEL_COLUMNS)), z)
        self._dt0 = np.full((), dt, z)
        self._pht = np.zeros((N, 3), z)
        self._k3 = np.zeros((N, 3), z)
        self._s3 = np.zeros((3, 3), z)
        self._si3 = np.zeros((3, 3), z)
        self._i3 = np.zeros(3, z)
        self._scale = np.ones(N, z)  # fix_covariance: per-state scale of an over-limit variance
        self._one = np.ones((), z)
        self._s = np.zeros((), z)  # 0-d operands/results: a Python scalar in a ufunc allocates a 0-d array
        self._r = np.zeros((), z)
        self._make_views()
        self.var_min = np.full(N, VAR_MIN, z)
        self.var_max = np.array(
            [POS_VAR_MAX_M2] * 3 + [VEL_VAR_MAX_M2S2] * 3 + [ATT_VAR_MAX_RAD2] * 3
            + [math.radians(GYRO_BIAS_SIGMA_MAX_DEG_S) ** 2] * 3 + [WIND_VAR_MAX_M2S2] * 2 + [WRATE_VAR_MAX_M2S4] * 2
            + [DRAG_VAR_MAX] + [POS_VAR_MAX_M2] + [ABIAS_VAR_MAX_M2S4], z
        )  # fmt: skip
        self.forces = Forces()
        rho0 = model.site_rho_kg_m3
        lift0 = (rho0 * model.volume_m3 - model.mass_kg) * G0
        self.rope = RopeShape(  # the paper's rope: the whole weight on a rod of the rope's length
            model.tether_length_m,
            calm_weight_share(lift0, model.rope_weight_n) if cfg.rope_model == "catenary" else model.rope_weight_n,
        )
        # process noise per step (diagonal): white acceleration, gyro noise, the wind's rate, random walks
        g = math.radians(sensors.gyro_dps)
        qv = cfg.accel_process_mps2**2 * dt
        self.wind_process = wp = wind_process(cfg.expected_wind_mps, cfg.turbulence_intensity, 2.0 * model.radius_m)
        self.rate_decay = math.exp(-dt / wp.tau_s)
        qr = wp.q_rate * dt
        self._q_flight = (
            [0.25 * qv * dt * dt] * 3
            + [qv] * 3
            + [g * g * dt * dt] * 3
            + [(math.radians(cfg.gyro_bias_walk_dps_rt_s)) ** 2 * dt] * 3
            + [0.0] * 2
            + [qr] * 2
            + [cfg.drag_walk_rt_s**2 * dt]
            + [cfg.baro_walk_m_rt_s**2 * dt]
            + [cfg.accel_bias_walk_mps2_rt_s**2 * dt]
        )
        self._q_ground = [GROUND_PROCESS_VAR] * 6 + self._q_flight[6:16] + [0.0] + self._q_flight[17:19]
        self._qd_flight = np.array(self._q_flight, z)
        self._q_rate0 = qr  # at the expected mean wind; scaled with the wind the filter sees (adapt_wind_noise)
        self._u0 = max(cfg.expected_wind_mps, 0.5)
        self._q_walk_step = wp.q_walk * dt  # the wind's growth per step when nothing constrains its rate
        self._qd_ground = np.array(self._q_ground, z)
        self._f_ground = False
        self._set_static_jacobian(True)
        self.mode = MODE_GROUND
        self.learn_drag = False  # set by the control logic: only in established free ascent
        self._drag_correlated = True
        self.recover_after = int(cfg.recover_after_s * cfg.imu_rate_hz)
        self.time_us = 0  # the filter's time, set by the control logic each step (the statuses' time of fusion)
        self.recorder = None  # post-flight only: postflight.smoother.SmootherRecorder sees every event
        # the one reset API (``reset``): counters per kind and in all, which outputs and the smoother read
        self.reset_counts = [0] * len(RESET_NAMES)
        self.reset_count = 0
        self.time_taut_us = -1  # the filter's time of the last taut placement (RESET_TAUT), -1 never
        # the attitude's variance about the magnetic field's axis that P does not hold, rad^2
        # (consistency.field_attitude_extra); an initialisation starts it again from P
        self.field_att_extra = 0.0

    _VIEWS = (
        "_scale_col",
        "_scale_row",
        "P_diag",
        "_k_col",
        "_ph_row",
        "_P_rows",
        "_P_cols",
        "_H3T",
        "_phtT",
        "H3_rows",
        "_F_vel_rows",
        "ja_flat",
        "_ja_pv",
        "_ja_wk",
        "_F_pv",
        "_F_wk",
        "H3_pv",
        "H3_wk",
        "hja_pv",
        "hja_wk",
    )

    def _make_views(self) -> None:
        self.P_diag = np.einsum("ii->i", self.P)  # writable view of the diagonal
        self._k_col = self._k.reshape(N, 1)  # views for the outer product without np.outer's overhead
        self._ph_row = self._ph.reshape(1, N)
        self._P_rows = [self.P[i] for i in range(N)]  # row / column views, for inhibition
        self._P_cols = [self.P[:, i] for i in range(N)]
        self._H3T = self.H3.T
        # the model's columns: position+velocity (states 0-5, ja 0-5), wind..drag (states 12-16, ja 6-10)
        assert MODEL_COLUMNS == (*range(0, 6), *range(12, 17))
        self.ja_flat = self.ja.reshape(-1)
        self._ja_pv, self._ja_wk = self.ja[:, 0:6], self.ja[:, 6:11]
        self._F_pv, self._F_wk = self.F[3:6, 0:6], self.F[3:6, 12:17]
        self.H3_pv, self.H3_wk = self.H3[:, 0:6], self.H3[:, 12:17]
        self.hja_pv, self.hja_wk = self.hja[:, 0:6], self.hja[:, 6:11]
        self.H3_rows = [self.H3[i] for i in range(3)]
        self._F_vel_rows = [self.F[VEL_N + i] for i in range(3)]
        self._phtT = self._pht.T
        self._scale_col = self._scale.reshape(N, 1)
        self._scale_row = self._scale.reshape(1, N)

    def __getstate__(self) -> dict:  # copies (snapshots, tests) must rebuild the views on their arrays
        return {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_views()

    # ------------------------------------------------------------------ initialisation

    def initialise(self, q: tuple[float, float, float, float], pos_d: float) -> None:
        """Resting on the ground station, attitude from the first accelerometer/magnetometer sample."""
        c = self.cfg
        self.x.fill(0.0)
        self.x[POS_D] = pos_d
        self.x[DRAG] = 1.0
        self.q[0], self.q[1], self.q[2], self.q[3] = q
        self.P.fill(0.0)
        tilt = math.radians(c.init_tilt_deg) ** 2
        init = [0.01] * 3 + [1e-4] * 3 + [tilt, tilt, math.radians(c.init_yaw_deg) ** 2]
        init += [math.radians(c.init_gyro_bias_dps) ** 2] * 3 + [c.init_wind_mps**2] * 2
        init += [self.wind_process.sigma_rate_mps2**2] * 2 + [c.init_drag**2] + [VAR_MIN] + [c.init_accel_bias_mps2**2]
        for i, v in enumerate(init):
            self.P[i, i] = v
        self.mode = MODE_GROUND
        self.reset(RESET_INITIALISE)

    def reset(self, kind: int) -> None:
        """Every re-placement of the state (not a fusion) is told here, after x and P were written:
        initialisation, a taut placement, a height reset, the drag scale weighed. Counted per kind and in
        all; the post-flight smoother cuts its chain where ``reset_count`` changes (postflight/reprocess.py)."""
        self.reset_counts[kind] += 1
        self.reset_count += 1
        if kind == RESET_TAUT:
            self.time_taut_us = self.time_us
        if kind == RESET_INITIALISE:  # the others leave the attitude's block of P as it was
            self.field_att_extra = 0.0

    # ------------------------------------------------------------------ prediction

    def predict(self, gx: float, gy: float, gz: float, rho: float) -> None:
        """One fixed step: attitude from the bias-corrected gyro, translation from the mode's model."""
        dt = self.dt
        x = self.x
        pn, pe, pd, vn, ve, vd, _, _, _, bx, by, bz, wn, we, rn, re, k, _, _ = x.tolist()
        q0, q1, q2, q3 = self.q.tolist()
        # attitude: q <- q (x) exp(omega dt / 2), omega = gyro - bias (paper's Omega)
        wx, wy, wz = gx - bx, gy - by, gz - bz
        ang = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
        if ang > 1e-12:
            s = math.sin(0.5 * ang) / ang * dt
            c = math.cos(0.5 * ang)
            ax, ay, az = wx * s, wy * s, wz * s
            q0, q1, q2, q3 = (
                q0 * c - q1 * ax - q2 * ay - q3 * az,
                q0 * ax + q1 * c + q2 * az - q3 * ay,
                q0 * ay - q1 * az + q2 * c + q3 * ax,
                q0 * az + q1 * ay - q2 * ax + q3 * c,
            )
        n = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        self.q[0], self.q[1], self.q[2], self.q[3] = q0 * n, q1 * n, q2 * n, q3 * n
        r = rotation(q0 * n, q1 * n, q2 * n, q3 * n)
        F = self.F
        ground = self.mode == MODE_GROUND
        if ground != self._f_ground:
            self._set_static_jacobian(ground)
        if ground:
            x[VEL_N] = x[VEL_E] = x[VEL_D] = 0.0
        else:
            f = accelerations(
                self.model, rho, pn, pe, pd, vn, ve, vd, wn, we, rn, re, k, self.mode == MODE_TAUT, self.forces
            )
            an, ae, ad = f.an, f.ae, f.ad
            x[POS_N] = pn + (vn + 0.5 * an * dt) * dt
            x[POS_E] = pe + (ve + 0.5 * ae * dt) * dt
            x[POS_D] = pd + (vd + 0.5 * ad * dt) * dt
            x[VEL_N] = vn + an * dt
            x[VEL_E] = ve + ae * dt
            x[VEL_D] = vd + ad * dt
            # d(vel)/d(x) = I + (d a / d x) dt over the model's columns (generated.COLUMNS)
            # d(vel)/d(x) = I + (d a / d x) dt: the model's columns are two contiguous blocks of F
            self.load_model_jacobian()
            np.multiply(self._ja_pv, self._dt0, out=self._F_pv)
            np.multiply(self._ja_wk, self._dt0, out=self._F_wk)
            F[VEL_N, VEL_N] += 1.0
            F[VEL_E, VEL_E] += 1.0
            F[VEL_D, VEL_D] += 1.0
            if self.learn_drag:
                self._drag_correlated = True
            else:
                F[3, DRAG] = F[4, DRAG] = F[5, DRAG] = 0.0
        # the wind: integrated Ornstein-Uhlenbeck (tuning.py)
        x[WIND_N] = wn + rn * dt
        x[WIND_E] = we + re * dt
        x[WRATE_N] = rn * self.rate_decay
        x[WRATE_E] = re * self.rate_decay
        # attitude error (NED) driven by the gyro-bias error: d(att)/dt = -R d(bias)
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
        F[6, 9], F[6, 10], F[6, 11] = -r0 * dt, -r1 * dt, -r2 * dt
        F[7, 9], F[7, 10], F[7, 11] = -r3 * dt, -r4 * dt, -r5 * dt
        F[8, 9], F[8, 10], F[8, 11] = -r6 * dt, -r7 * dt, -r8 * dt
        np.matmul(F, self.P, out=self._t1)
        np.matmul(self._t1, F.T, out=self.P)
        np.add(self.P_diag, self._qd_ground if ground else self._qd_flight, out=self.P_diag)
        if self.recorder is not None:
            self.recorder.predict(F)

    def load_model_jacobian(self) -> None:
        """Copy d a / d x of ``self.forces`` into the array the prediction and the accelerometer rows use."""
        flat = self.ja_flat
        for i, v in enumerate(self.forces.ja):
            flat[i] = v

    def _set_static_jacobian(self, ground: bool) -> None:
        """The parts of F that change only with the mode: on the ground the balloon is held still."""
        F = self.F
        F[0:6, :] = 0.0
        for i in range(6):
            F[i, i] = 1.0
        if not ground:
            for i in range(3):
                F[POS_N + i, VEL_N + i] = self.dt
        self._f_ground = ground
        if ground:
            F[3, 3] = F[4, 4] = F[5, 5] = 0.0
        F[WIND_N, WRATE_N] = F[WIND_E, WRATE_E] = self.dt
        F[WRATE_N, WRATE_N] = F[WRATE_E, WRATE_E] = self.rate_decay

    def adapt_wind_noise(self, mean_speed_mps: float, excess: float = 1.0) -> None:
        """Kaimal turbulence at the mean wind U: in the inertial range the spectrum the filter matches
        (tuning.py) scales as sigma_u^2 (L/U)^(-2/3) / U ~ TI^2 U^(8/3), and the rate's time constant
        D/U as 1/U, so q_rate ~ U^(14/3). Called about once a second with the filter's own mean wind.
        ``excess`` (>= 1, a variance ratio) scales it further where light air meanders beyond TI U
        (Estimator._turbulence_excess)."""
        u = min(max(mean_speed_mps, 0.5), 20.0)
        ratio = u / self._u0
        q = self._q_rate0 * ratio ** (14.0 / 3.0) * excess
        self._q_flight[WRATE_N] = self._q_flight[WRATE_E] = q
        self._qd_flight[WRATE_N] = self._qd_flight[WRATE_E] = q
        self._qd_ground[WRATE_N] = self._qd_ground[WRATE_E] = q
        self.rate_decay = math.exp(-self.dt * ratio / self.wind_process.tau_s)
        self._q_walk_step = q * (self.wind_process.tau_s / ratio) ** 2  # q is per step already
        self.F[WRATE_N, WRATE_N] = self.F[WRATE_E, WRATE_E] = self.rate_decay

    def inflate(self, steps: float) -> None:
        """Covariance growth of ``steps`` prediction steps without the state moving (sensor silence)."""
        q = self._q_ground if self.mode == MODE_GROUND else self._q_flight
        for i in range(N):
            self.Qd[i] = q[i] * steps
        # over a gap much longer than the rate's time constant the wind walks: q_walk per second
        self.Qd[WIND_N] = self.Qd[WIND_E] = self._q_walk_step * steps
        np.add(self.P_diag, self.Qd, out=self.P_diag)
        self.fix_covariance()

    def inflate_attitude(self, var: float) -> None:
        """The attitude's variance grown by ``var`` (rad², each NED axis): a turn the prediction could not follow; to
        its bound at most (a diagonal grown by less stays positive semi-definite, where one scaled down by the bound
        lands on it only to float32's rounding)."""
        for i in (ATT_N, ATT_E, ATT_D):
            self.P[i, i] = min(self.P[i, i] + var, self.var_max[i])
        self.fix_covariance()

    # ------------------------------------------------------------------ fusion

    def begin_update(self) -> None:
        self.dx.fill(0.0)

    def fuse(
        self, innov: float, r: float, status: FusionStatus, gate_sigma: float | None = None, recover: bool = True,
        att_gain: float = 1.0,
    ) -> bool:
        """Sequential scalar update with the row in ``self.h`` (all rows of one step share the same
        linearisation point, so a sequence equals one batch update with diagonal R). The attitude takes
        ``att_gain`` of its optimal gain (a row whose misfit is correlated, as ``fuse3``'s tilt), the covariance the
        one for the gain used (Joseph form)."""
        np.dot(self.h, self.dx, out=self._r)
        innov -= float(self._r)
        np.dot(self.P, self.h, out=self._ph)
        np.dot(self.h, self._ph, out=self._r)
        s = float(self._r) + r
        gate = self.cfg.gate_sigma if gate_sigma is None else gate_sigma
        status.innov = innov
        status.innov_var = s
        status.time_test_us = self.time_us
        if not (s > 0.0 and math.isfinite(innov)):
            status.rejected += 1
            status.consecutive_rejects += 1
            return False
        ratio = innov * innov / (gate * gate * s)
        status.test_ratio = ratio
        if ratio > 1.0:
            status.rejected += 1
            status.consecutive_rejects += 1
            if not recover or status.consecutive_rejects < (status.recover_after or self.recover_after):
                return False
            # persistently inconsistent: the model, not the sensor, is off. Fuse with the noise
            # inflated to put the innovation on the gate, so the state walks back without a jump.
            r += innov * innov / (gate * gate) - s
            s = innov * innov / (gate * gate)
            status.fused -= 1
        self._s[()] = 1.0 / s
        np.multiply(self._ph, self._s, out=self._k)
        np.multiply(self._k_col, self._ph_row, out=self._t1)
        np.subtract(self.P, self._t1, out=self.P)
        if att_gain < 1.0:
            # K' = D K: P for the gain used, P - K'HP - PH^T K'^T + K' S K'^T, differs from P - KHP only in the
            # attitude's block, by (1 - g)^2 KHP (as fuse3's)
            att = slice(ATT_N, ATT_D + 1)
            self.P[att, att] += (1.0 - att_gain) * (1.0 - att_gain) * self._t1[att, att]
            self._k[att] *= att_gain
        if self.recorder is not None:
            self.recorder.update(self.h, 1.0 / s, innov, self._k)
        self._s[()] = innov
        np.multiply(self._k, self._s, out=self._v)
        np.add(self.dx, self._v, out=self.dx)
        status.fused += 1
        status.consecutive_rejects = 0
        status.time_last_fuse_us = self.time_us
        return True

    def fuse3(
        self, i0: float, i1: float, i2: float, r: float, status: list[FusionStatus], r2_extra: float = 0.0,
        tilt_gain: float = 1.0, heading_gain: float = 1.0, axis: tuple[float, float, float] = (0.0, 0.0, 0.0),
        axis_var: float = 0.0,
    ) -> bool:
        """One sensor's three axes at once with the rows in ``self.H3``, as a 3x3 innovation covariance instead of three
        scalar updates (a third of the array operations). The noise: ``r`` per axis, ``r2_extra`` more on the third,
        and ``axis_var axis axis^T`` more (a motion the model leaves out along one direction of the sensor's frame,
        ``axis``'s, of any length: aid_sources/accel.py radial_noise).
        Each axis keeps its status (innovation, its variance, test ratio); the vector is rejected if
        any axis fails the gate, and after ``recover_after`` rejections in a row fused with its
        covariance inflated to put the worst axis on the gate (as ``fuse``). The tilt's rows of the gain take
        ``tilt_gain`` of it, the heading's and the gyro bias's ``heading_gain`` (``SLOW_STATES``: a correlated
        error is worth fewer independent samples, params.ACCEL_MODEL_CORR_S), and the covariance is the one for
        the gain used (Joseph form)."""
        np.dot(self.H3, self.dx, out=self._i3)
        c0, c1, c2 = self._i3.tolist()
        i0, i1, i2 = i0 - c0, i1 - c1, i2 - c2
        np.matmul(self.P, self._H3T, out=self._pht)
        np.matmul(self.H3, self._pht, out=self._s3)
        (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = self._s3.tolist()
        s00 += r
        s11 += r
        s22 += r + r2_extra
        s01 = s10 = 0.5 * (s01 + s10)
        s02 = s20 = 0.5 * (s02 + s20)
        s12 = s21 = 0.5 * (s12 + s21)
        if axis_var > 0.0:
            e0, e1, e2 = axis
            s00 += axis_var * e0 * e0
            s11 += axis_var * e1 * e1
            s22 += axis_var * e2 * e2
            s01 = s10 = s01 + axis_var * e0 * e1
            s02 = s20 = s02 + axis_var * e0 * e2
            s12 = s21 = s12 + axis_var * e1 * e2
        gate2 = self.cfg.gate_sigma**2
        worst = 0.0
        ok = True
        for st, inn, var in ((status[0], i0, s00), (status[1], i1, s11), (status[2], i2, s22)):
            st.innov, st.innov_var = inn, var
            st.time_test_us = self.time_us
            if not (var > 0.0 and math.isfinite(inn)):
                ok = False
                continue
            st.test_ratio = inn * inn / (gate2 * var)
            worst = max(worst, st.test_ratio)
        # cofactor inverse of the symmetric 3x3
        a00 = s11 * s22 - s12 * s12
        a01 = s02 * s12 - s01 * s22
        a02 = s01 * s12 - s02 * s11
        det = s00 * a00 + s01 * a01 + s02 * a02
        if not ok or not (det > 0.0 and math.isfinite(det)):
            for st in status:
                st.rejected += 1
                st.consecutive_rejects += 1
            return False
        scale = 1.0
        if worst > 1.0:
            for st in status:
                st.rejected += 1
                st.consecutive_rejects += 1
            if status[0].consecutive_rejects < (status[0].recover_after or self.recover_after):
                return False
            scale = 1.0 / worst  # persistently off: the model, not the sensor; walk back, no jump
            for st in status:
                st.fused -= 1
        inv = scale / det
        si = self._si3
        si[0, 0] = a00 * inv
        si[0, 1] = si[1, 0] = a01 * inv
        si[0, 2] = si[2, 0] = a02 * inv
        si[1, 1] = (s00 * s22 - s02 * s02) * inv
        si[1, 2] = si[2, 1] = (s01 * s02 - s00 * s12) * inv
        si[2, 2] = (s00 * s11 - s01 * s01) * inv
        np.matmul(self._pht, si, out=self._k3)
        np.matmul(self._k3, self._phtT, out=self._t1)
        np.subtract(self.P, self._t1, out=self.P)
        if tilt_gain < 1.0 or heading_gain < 1.0:
            # the tilt takes ``tilt_gain`` of its optimal gain, the heading and the gyro bias ``heading_gain``:
            # K' = D K. P for the gain used (Joseph form), P - K'HP - PH^T K'^T + K' S K'^T, differs from P - KHP only
            # in the attitude and gyro bias block, by (1 - d_i) (1 - d_j) KHP
            gains = (tilt_gain, tilt_gain, heading_gain, heading_gain, heading_gain, heading_gain)
            block = SLOW_STATES if heading_gain < 1.0 else SLOW_STATES[:2]  # the tilt's alone at full heading
            for a, i in enumerate(block):
                for b, j in enumerate(block):
                    self.P[i, j] += (1.0 - gains[a]) * (1.0 - gains[b]) * self._t1[i, j]
                self._k3[i, 0] *= gains[a]
                self._k3[i, 1] *= gains[a]
                self._k3[i, 2] *= gains[a]
        self._i3[0], self._i3[1], self._i3[2] = i0, i1, i2
        if self.recorder is not None:
            self.recorder.update3(self.H3, si, self._i3, self._k3)
        np.matmul(self._k3, self._i3, out=self._v)
        np.add(self.dx, self._v, out=self.dx)
        t = self.time_us
        for st in status:
            st.fused += 1
            st.consecutive_rejects = 0
            st.time_last_fuse_us = t
        return True

    def end_update(self) -> bool:
        """Apply the accumulated correction (attitude error into the quaternion), then fix the
        covariance: symmetrise, clamp the variances. Returns False if the state went non-finite."""
        if not self.learn_drag and self._drag_correlated:
            self.inhibit(DRAG)
            self._drag_correlated = False
        np.add(self.x, self.dx, out=self.x)
        x = self.x
        dn, de, dd = x[ATT_N : ATT_D + 1].tolist()
        if dn != 0.0 or de != 0.0 or dd != 0.0:
            q0, q1, q2, q3 = self.q.tolist()
            hn, he, hd = 0.5 * dn, 0.5 * de, 0.5 * dd
            # q <- dq (x) q with dq = (1, d/2) in NED
            a0 = q0 - hn * q1 - he * q2 - hd * q3
            a1 = q1 + hn * q0 + he * q3 - hd * q2
            a2 = q2 - hn * q3 + he * q0 + hd * q1
            a3 = q3 + hn * q2 - he * q1 + hd * q0
            n = 1.0 / math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
            self.q[0], self.q[1], self.q[2], self.q[3] = a0 * n, a1 * n, a2 * n, a3 * n
            x[ATT_N] = x[ATT_E] = x[ATT_D] = 0.0
        if x[DRAG] < DRAG_SCALE_MIN:
            x[DRAG] = DRAG_SCALE_MIN
        self.fix_covariance()
        # a NaN/inf anywhere in P reaches its diagonal within one prediction
        np.add.reduce(self.x, out=self._r)
        finite = math.isfinite(float(self._r))
        np.add.reduce(self.P_diag, out=self._r)
        return finite and math.isfinite(float(self._r))

    def cap_information(
        self, i: int, prior: float, prior_var: float, data_var_min: float, kind: int, conflict_sigma: float = 0.0
    ) -> tuple[float, float]:
        """What the data told state i since it was ``prior`` +- sqrt(``prior_var``) is worth at most a
        measurement of variance ``data_var_min``: a model error (not noise) that the fusions took for
        information is given back (``weigh_information``, a reset of ``kind``, with ``conflict_sigma``: a datum that
        contradicts its prior at that weight makes their mixture at once, capped or not). The data's own estimate,
        (x / P - prior / P0) / (1 / P - 1 / P0), and the variance it claimed (0, 0: it told nothing)."""
        var = float(self.P[i, i])
        info = 1.0 / var - 1.0 / prior_var if var > 0.0 and prior_var > 0.0 else 0.0
        if not info > 0.0:
            return 0.0, 0.0
        data = (float(self.x[i]) / var - prior / prior_var) / info
        weight = max(1.0 / info, data_var_min)  # the cap's: what the data claimed, at most data_var_min's worth
        if info > 1.0 / data_var_min or in_conflict(prior_var, weight, data - prior, conflict_sigma):
            self.weigh_information(i, prior, prior_var, data, weight, 0.0, kind, conflict_sigma)
        return data, 1.0 / info

    def weigh_information(
        self, i: int, prior: float, prior_var: float, data: float, data_var: float, walked_var: float, kind: int,
        conflict_sigma: float = 0.0,
    ) -> None:  # fmt: skip
        """State i as ``prior`` +- sqrt(``prior_var``) combined with one measurement ``data`` of variance
        ``data_var``, plus ``walked_var``, what its random walk has added since; its correlations are cut
        (``inhibit``). A re-placement, not a fusion: a reset of ``kind``. Where ``conflict_sigma`` > 0 and the two
        differ by more than that many sigma of their difference, they do not both hold and either may: the state is
        their equal mixture (its mean halfway, its variance the two's mean and the square of half their difference)."""
        if not (prior_var > 0.0 and data_var > 0.0):
            return
        d = data - prior
        self.inhibit(i)
        v = weighed_variance(prior_var, data_var, d, conflict_sigma)
        if in_conflict(prior_var, data_var, d, conflict_sigma):
            self.x[i] = prior + 0.5 * d
        else:
            self.x[i] = v * (prior / prior_var + data / data_var)
        self.P[i, i] = v + walked_var
        self.reset(kind)

    def inhibit(self, i: int) -> None:
        """Hold state i where it is (PX4's state inhibition): no correction, no correlations; its
        variance stays. The drag scale is learnt only in established free ascent (the climb rate
        against the known lift tells it); on the taut tether the quasi-static balance sees only
        k |w|^2, and the release transient would mistake the detection lag for drag."""
        self.dx[i] = 0.0
        if self.recorder is not None:
            self.recorder.broken()  # not a fusion: the smoother's chain is cut here
        v = float(self.P[i, i])
        self._P_rows[i].fill(0.0)
        self._P_cols[i].fill(0.0)
        self.P[i, i] = v

    def fix_covariance(self) -> None:
        """Symmetrise; variances above their limit are brought down by scaling their row and column
        (P <- D P D, a congruence: P stays positive semi-definite, which clipping the diagonal alone
        does not guarantee); variances below their floor are raised (adding to the diagonal keeps P
        positive definite)."""
        np.add(self.P, self.P.T, out=self._t2)
        self._s[()] = 0.5
        np.multiply(self._t2, self._s, out=self.P)
        np.divide(self.var_max, self.P_diag, out=self._scale)
        np.minimum.reduce(self._scale, out=self._r)
        if float(self._r) < 1.0:
            np.minimum(self._scale, self._one, out=self._scale)
            np.sqrt(self._scale, out=self._scale)
            np.multiply(self.P, self._scale_col, out=self.P)
            np.multiply(self.P, self._scale_row, out=self.P)
            np.minimum(self.P_diag, self.var_max, out=self.P_diag)  # float32 rounds d² P an ulp past the bound
        np.maximum(self.P_diag, self.var_min, out=self.P_diag)

    # ------------------------------------------------------------------ outputs

    def wind_accuracy(self) -> float:
        return math.sqrt(max(0.0, float(self.P[WIND_N, WIND_N]) + float(self.P[WIND_E, WIND_E])))
