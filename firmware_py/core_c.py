"""The C core (firmware_c/) behind the Python estimator's interface: ``CEstimator`` and ``CWindCovOutput``
stand in for ``estimator.control.Estimator`` and ``estimator.outputs.WindCovOutput`` wherever the firmware,
the replay or a study runs the filter (``[filter] core = "c"``, ``balloon-fw --core c``).

The binding is ctypes over the host library that ``firmware_c.build`` compiles (no Python headers): the
estimator's whole state is one C struct owned here, and its arrays (x, P, q) are numpy views of that
memory, read without a copy. The real type follows ``[filter] float32``: the float build is the firmware
as flown, the double build the one the lockstep harness holds against the Python core's float64."""

from __future__ import annotations

import ctypes as C
import math
from typing import Any

import numpy as np

from balloon_core.config import Design
from firmware_py.estimator.consistency import SOURCES
from firmware_py.estimator.ekf import RESET_NAMES
from firmware_py.estimator.model import BalloonModel
from firmware_py.estimator.state import MODE_NAMES, N_STATES, FilterConfig

N = N_STATES
NCOL = 11
COUNTER_NAMES = (
    "imu_samples", "baro_samples", "rejected", "duplicates", "reordered", "jitter", "gaps", "long_gaps",
    "time_resets", "numeric_resets", "taut_resets", "mode_switches", "baro_resets", "false_releases", "field_jumps",
)  # fmt: skip
CONFIG_FIELDS = (
    "radius_m", "volume_m3", "mass_kg", "half_cd_area_m2", "tether_length_m", "rope_kg_m", "rope_drag_m2",
    "rope_cn_d_m", "accel_mps2", "baro_m", "gyro_dps", "mag_gauss", "mag_declination_deg", "ground_pressure_hpa",
    "altitude_amsl_m", "imu_rate_hz", "accel_process_mps2", "expected_wind_mps", "turbulence_intensity",
    "drag_walk_rt_s", "baro_walk_m_rt_s", "accel_bias_walk_mps2_rt_s", "gyro_bias_walk_dps_rt_s",
    "accel_model_mps2", "accel_taut_mps2", "accel_static_mps2", "align_rad", "radial_m", "radial_rate_mps",
)  # fmt: skip
CONFIG_FIELDS_2 = (
    "gate_sigma", "recover_after_s", "init_wind_mps", "init_drag", "init_accel_bias_mps2", "init_gyro_bias_dps",
    "init_tilt_deg", "init_yaw_deg", "taut_margin_m", "mode_dwell_s", "release_accel_mps2", "release_height_m",
    "max_gap_s",
)  # fmt: skip
CONFIG_MOUNT = ("imu_alignment_deg", "imu_roll_deg", "imu_pitch_deg")  # [sensors], the IMU's mounting: last


def _structs(real):
    """The C structs of include/bw_core.h for one real type (checked against the library's sizeof)."""
    i32, i64, f32, d, u8 = C.c_int32, C.c_int64, C.c_float, C.c_double, C.c_uint8

    class Config(C.Structure):
        _fields_ = ([(n, d) for n in CONFIG_FIELDS] + [("rope_catenary", d)] + [(n, d) for n in CONFIG_FIELDS_2]
                    + [(n, d) for n in CONFIG_MOUNT])

    class Status(C.Structure):
        _fields_ = [("innov", real), ("innov_var", real), ("test_ratio", real), ("fused", i32), ("rejected", i32),
                    ("consecutive_rejects", i32), ("recover_after", i32), ("time_last_fuse_us", i64),
                    ("time_test_us", i64)]  # fmt: skip

    class Counters(C.Structure):
        _fields_ = [(n, C.c_uint32) for n in COUNTER_NAMES]

    class Forces(C.Structure):
        _fields_ = [("an", real), ("ae", real), ("ad", real), ("ja", real * (3 * NCOL)), ("jpull", real * NCOL),
                    ("tension_n", real), ("m_eff_kg", real), ("taut", i32), ("params", real * 10),
                    ("attach_ned", real * 3), ("rope_weight_n", real)]  # fmt: skip

    class Model(C.Structure):
        _fields_ = [
            (n, real)
            for n in (
                "radius_m",
                "volume_m3",
                "mass_kg",
                "half_cd_area_m2",
                "tether_length_m",
                "rope_kg_m",
                "rope_drag_m2",
                "rope_cn_d_m",
                "lam_g",
                "rope_weight_n",
            )
        ]
        _fields_ += [(n, real) for n in (
            "turbulence_intensity", "release_height_m", "release_accel_mps2", "taut_margin_m", "imu_rate_hz",
            "gate_sigma", "gate2", "radial_var", "radial_rate_var")]  # fmt: skip

    class Ekf(C.Structure):
        _fields_ = [
            ("m", Model), ("x", real * N), ("q", real * 4), ("P", real * (N * N)), ("T", real * (N * N)),
            ("h", real * N), ("dx", real * N), ("ph", real * N), ("H3", real * (3 * N)), ("pht", real * (3 * N)),
            ("var_max", real * N), ("q_flight", real * N), ("q_ground", real * N), ("qd_ground", real * N),
            ("dt", real), ("rate_decay", real), ("q_rate0", real), ("u0", real), ("q_walk_step", real),
            ("wp_tau_s", real), ("wp_q_rate", real), ("wp_q_walk", real), ("sigma_rate", real), ("forces", Forces),
            ("rope_chord_m", real), ("rope_weight_n", real), ("rope_rate_mps", real), ("mode", u8),
            ("learn_drag", u8), ("drag_correlated", u8), ("field_window", u8),
            ("recover_after", i32), ("field_heading_var", real), ("time_us", i64), ("time_taut_us", i64),
            ("taut_phase", i32),
            ("noise_phase", i32), ("reset_counts", i32 * len(RESET_NAMES)),
            ("reset_count", i32), ("field_att_extra", real),
        ]  # fmt: skip

    class Consistency(C.Structure):
        _fields_ = [
            ("nis", real * len(SOURCES)),
            ("flags", i32),
            ("inflation", real),
            ("flag_changes", i32),
            ("slow_tilt", real),
            ("slow_tilt_var", real),
            ("balance_n", real),
            ("balance_e", real),
            ("balance_var", real),
            ("lean_tilt", real),
            ("lean_misfit", real),
        ]

    class Schedule(C.Structure):
        _fields_ = [(n, i32) for n in ("taut_every", "align_reset", "baro_reset", "baro_recover", "mag_recover",
                                       "field_learn", "field_flight", "wind_noise_every", "release_confirm",
                                       "release_height", "turbulence_from", "turbulence_to")] + [
            ("rope_shape_alpha", real)]  # fmt: skip

    class WindCov(C.Structure):
        _fields_ = [("time_usec", i64)] + [
            (n, f32)
            for n in (
                "wind_x",
                "wind_y",
                "wind_z",
                "var_horiz",
                "var_vert",
                "wind_alt",
                "horiz_accuracy",
                "vert_accuracy",
            )
        ]

    class Out(C.Structure):
        _fields_ = [
            ("alpha", real),
            ("ln", real),
            ("le", real),
            ("primed", i32),
            ("ring_n", real * 60),
            ("ring_e", real * 60),
            ("count", i64),
            ("next_slot_us", i64),
            ("site_altitude_m", d),
        ]

    rest = [
        ("accel_var", real), ("accel_static_var", real), ("accel_taut_var", real),
        ("vertical_gust_var", real), ("align_var", real), ("baro_var", real), ("mag_sigma", real), ("mag_var", real),
        ("declination", real), ("catenary", u8), ("mount", u8),
        ("n_dwell", i32), ("n_learn_drag", i32), ("n_false_release", i32), ("n_taut_pull", i32), ("n_confirm", i32),
        ("a_accel", real), ("a_taut", real), ("a_baro", real), ("a_confirm", real),
        ("dt_us", i64), ("max_gap_steps", i32),
        ("initialised", u8), ("joined", u8), ("unconfirmed", u8), ("was_slack", u8), ("t_filter_us", i64),
        ("t_last_us", i64), ("t_boot_us", i64), ("step", i64),
        ("last_gyro", real * 3), ("release_count", i32), ("field_n", i32), ("field_sum", real * 6),
        ("field_strength", real * 2),
        ("acc_mean", real * 3), ("acc_var", real), ("confirm_count", i32),
        ("field_ned", real * 3), ("dwell", i32), ("accel_innov2", real), ("innov_alpha", real), ("mean_speed", real),
        ("speed_alpha", real), ("speed_var", real), ("slack", i32), ("pulling", i32),
        ("height_above", i32),
        ("accel_var_excess", real), ("align_innov2", real * 2), ("align_mean", real),
        ("a_align_innov", real), ("drag_prior", real * 2), ("ascent_data", real), ("ascent_var", real),
        ("ascent_climb", real),
        ("turbulence", real * 3),
        ("p_ref_pa", real), ("zeroing", i32), ("ref_pos_d", real), ("t_ref_k", real),
        ("zero_sum", real), ("zero_n", i32), ("join_height", real), ("rho", real), ("height_baro", real),
        ("baro_pending", i32), ("baro_outside", i32), ("winch_tension_n", real), ("accel_radial_innov2", real),
        ("winch_samples", i64),
        ("winch_t_us", i64), ("accel_hbias", real * 2),
        ("ground_samples", i64), ("ground_t_us", i64), ("ground_p_pa", real), ("ground_p0_pa", real),
        ("p_ref0_pa", real), ("accel_hbias_var", real), ("level_mean", real * 2), ("level_var", real),
        ("wind_taut_mps", real),
        ("winch_rejected", i64), ("ground_rejected", i64), ("winch_reject_reason", i32),
        ("ground_reject_reason", i32),
    ]  # fmt: skip

    class Estimator(C.Structure):
        _fields_ = [
            ("ekf", Ekf), ("probe", Forces), ("sched", Schedule), ("cfg", C.POINTER(Config)), ("counters", Counters),
            ("consistency", Consistency), ("accel_status", Status * 3), ("baro_status", Status),
            ("heading_status", Status), ("mag_status", Status * 3), ("taut_status", Status * 4), ("out", Out),
            *rest,
        ]  # fmt: skip

    return Config, Estimator, WindCov


_LIBS: dict[str, tuple] = {}


def load(real: str = "float"):
    """(library, Config, Estimator, WindCov) for ``real``, building the library if needed
    (firmware_c.build.BuildError if it cannot be)."""
    if real in _LIBS:
        return _LIBS[real]
    from firmware_c.build import library

    ct = C.c_float if real == "float" else C.c_double
    lib = C.CDLL(str(library(real)))
    Config, Est, WindCov = _structs(ct)
    lib.bw_sizeof_estimator.restype = C.c_size_t
    if lib.bw_sizeof_estimator() != C.sizeof(Est):
        raise RuntimeError(f"firmware_py.core_c: bw_estimator_t is {lib.bw_sizeof_estimator()} B in C, "
                           f"{C.sizeof(Est)} B here: the binding does not match include/bw_core.h")  # fmt: skip
    P = C.POINTER(Est)
    lib.bw_init.argtypes = [P, C.POINTER(Config)]
    lib.bw_on_imu.argtypes = [P, C.c_int64] + [ct] * 9
    lib.bw_on_baro.argtypes = [P, C.c_int64, ct, ct]
    lib.bw_coast.argtypes = [P, ct]
    lib.bw_on_winch.argtypes = [P, C.c_int64, ct, ct, ct]
    lib.bw_on_ground_baro.argtypes = [P, C.c_int64, ct, ct]
    lib.bw_reset.argtypes = [P]
    lib.bw_output_update.argtypes = [P, C.c_int64]
    lib.bw_output_reset.argtypes = [P]
    lib.bw_wind_cov.argtypes = [P, C.POINTER(WindCov)]
    lib.bw_wind_accuracy.argtypes = [P]
    lib.bw_wind_accuracy.restype = ct
    lib.bw_config_default.argtypes = [C.POINTER(Config)]
    vp = C.c_void_p
    lib.bw_on_batch.argtypes = [P, C.c_int, vp, vp, vp, C.c_int64, C.c_int32, C.c_int64, vp, vp, vp, vp]
    _LIBS[real] = (lib, Config, Est, WindCov)
    return _LIBS[real]


def config_struct(design: Design, cfg: FilterConfig, Config):
    """bw_config_t from the design file and the [filter] tuning (the numbers the Python core derives)."""
    catenary = cfg.rope_model == "catenary"
    m = BalloonModel.from_design(design, cfg.rope_normal_cd, rope_drag_at_balloon=not catenary)
    s, site = design.sensors, design.site
    c = Config()
    for name in ("radius_m", "volume_m3", "mass_kg", "half_cd_area_m2", "tether_length_m", "rope_drag_m2",
                 "rope_cn_d_m"):  # fmt: skip
        setattr(c, name, getattr(m, name))
    c.rope_kg_m = m.rope_kg_m
    c.accel_mps2, c.baro_m, c.gyro_dps, c.mag_gauss = s.accel_mps2, s.baro_m, s.gyro_dps, s.mag_gauss
    for name in CONFIG_MOUNT:
        setattr(c, name, getattr(s, name))
    c.mag_declination_deg = site.mag_declination_deg
    c.ground_pressure_hpa = math.nan if site.ground_pressure_hpa is None else site.ground_pressure_hpa
    c.altitude_amsl_m = site.altitude_amsl_m
    for name in CONFIG_FIELDS[CONFIG_FIELDS.index("imu_rate_hz") :] + CONFIG_FIELDS_2:
        setattr(c, name, getattr(cfg, name))
    c.rope_catenary = float(catenary)
    return c


class _Counters:
    """est.counters: the C counters by name (as control.Counters)."""

    __slots__ = ("_c",)

    def __init__(self, c) -> None:
        object.__setattr__(self, "_c", c)

    def __getattr__(self, name: str) -> int:
        return getattr(self._c, name)

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self._c, name) for name in COUNTER_NAMES}


class _Consistency:
    __slots__ = ("_m",)

    def __init__(self, m) -> None:
        self._m = m

    @property
    def flags(self) -> int:
        return self._m.flags

    @property
    def inflation(self) -> float:
        return self._m.inflation

    @property
    def flag_changes(self) -> int:
        return self._m.flag_changes

    @property
    def nis(self) -> list[float]:
        return list(self._m.nis)

    @property
    def slow_tilt(self) -> float:
        return self._m.slow_tilt

    @property
    def slow_tilt_var(self) -> float:
        return self._m.slow_tilt_var

    @property
    def lean_tilt(self) -> float:
        return self._m.lean_tilt

    @property
    def lean_misfit(self) -> float:
        return self._m.lean_misfit

    def names(self) -> list[str]:
        return [name for i, name in enumerate(SOURCES) if self._m.flags >> i & 1]


class _Ekf:
    """est.ekf: the filter's state as numpy views of the C struct (no copy)."""

    def __init__(self, e, dtype) -> None:
        self._e = e
        self.x = np.ctypeslib.as_array(e.x)
        self.q = np.ctypeslib.as_array(e.q)
        self.P = np.ctypeslib.as_array(e.P).reshape(N, N)
        self.recorder = None

    @property
    def mode(self) -> int:
        return self._e.mode

    @property
    def reset_count(self) -> int:
        return self._e.reset_count

    @property
    def reset_counts(self) -> list[int]:
        return list(self._e.reset_counts)

    @property
    def rope_chord_m(self) -> float:
        return self._e.rope_chord_m

    @property
    def time_taut_us(self) -> int:
        return self._e.time_taut_us

    @property
    def field_att_extra(self) -> float:
        return self._e.field_att_extra

    def wind_accuracy(self) -> float:
        return math.sqrt(max(0.0, float(self.P[12, 12]) + float(self.P[13, 13])))


class _Field:
    """One field of the C estimator's struct as the Python core's attribute of the same name (read-only, its leading
    underscore dropped), through ``convert`` (``_floats`` for an array); ``doc`` says what it is."""

    def __init__(self, convert: Any = None, doc: str = "") -> None:
        self.convert, self.__doc__ = convert, doc or None

    def __set_name__(self, owner: type, name: str) -> None:
        self.field = name.lstrip("_")

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        v = getattr(obj._s, self.field)
        return v if self.convert is None else self.convert(v)


def _floats(values: Any) -> list[float]:
    return [float(v) for v in values]


class CEstimator:
    """The C core with the interface of ``estimator.control.Estimator`` (what the firmware, the input
    pipeline and the studies use of it)."""

    def __init__(self, design: Design, cfg: FilterConfig | None = None) -> None:
        self.design = design
        self.cfg = cfg or FilterConfig()
        self.real = "float" if self.cfg.float32 else "double"
        lib, Config, Est, _ = load(self.real)
        self._lib = lib
        self._s = Est()
        self._p = C.byref(self._s)
        self._config = config_struct(design, self.cfg, Config)  # the C estimator points at it
        if lib.bw_init(self._p, C.byref(self._config)) != 0:
            raise ValueError("the C core refused the design (rate, radius, mass and volume must be positive)")
        self._imu = lib.bw_on_imu
        self._baro = lib.bw_on_baro
        self.counters = _Counters(self._s.counters)
        self.consistency = _Consistency(self._s.consistency)
        self.ekf = _Ekf(self._s.ekf, np.float32 if self.real == "float" else np.float64)

    def on_imu(self, t_us, ax, ay, az, gx, gy, gz, mx=math.nan, my=math.nan, mz=math.nan) -> bool:
        return self._imu(self._p, t_us, ax, ay, az, gx, gy, gz, mx, my, mz) == 1

    def on_baro(self, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
        return self._baro(self._p, t_us, pressure_hpa, temperature_c) == 1

    def on_batch(self, block: SampleBlock, start: int, stop_us: int, told_flags: int, text_us: int) -> int:
        """Samples ``start ..`` of ``block`` through ``bw_on_batch`` (firmware_c/host/batch.c): each as
        ``on_imu`` (and the WIND_COV output's ``update`` after a step) or ``on_baro`` would take it, until one
        the caller must act on (an IMU step at or after ``stop_us``, or with consistency flags other than
        ``told_flags`` at or after ``text_us``, or a time reset). Returns how many were done; ``block``'s
        out arrays hold each one's result (``SampleBlock``)."""
        n = block.n - start
        b = block
        return self._lib.bw_on_batch(self._p, n, b.t_p + 8 * start, b.kind_p + 4 * start, b.v_p + 72 * start,
                                     stop_us, told_flags, text_us, b.stepped_p + 4 * start, b.steps_p + 8 * start,
                                     b.modes_p + 4 * start, b.flags_p + 4 * start)  # fmt: skip

    def on_winch(self, t_us: int, line_length_m: float, speed_mps: float, tension_n: float) -> bool:
        return self._lib.bw_on_winch(self._p, t_us, line_length_m, speed_mps, tension_n) == 1

    def on_ground_baro(self, t_us: int, pressure_hpa: float, temperature_c: float) -> bool:
        return self._lib.bw_on_ground_baro(self._p, t_us, pressure_hpa, temperature_c) == 1

    # the estimator's own fields, read as the Python core's attributes of the same names (_Field)
    winch_samples = _Field()
    ground_samples = _Field()
    winch_rejected = _Field()
    ground_rejected = _Field()
    winch_reject_reason = _Field()
    ground_reject_reason = _Field()
    winch_tension_n = _Field()
    accel_hbias = _Field(_floats, "The accelerometer's body x, y biases walked since the field was learnt "
                         "(accel.follow_horizontal_bias).")
    accel_hbias_var = _Field(float, "Its error variance, (m/s^2)^2 (accel.horizontal_bias_variance).")
    level_mean = _Field(_floats, "The horizontal specific force in NED, north and east, its mean over LEVEL_MEAN_S "
                        "(accel.level_noise).")
    level_var = _Field(float, "Its variance about that mean, per axis, (m/s^2)^2 (accel.level_noise).")
    wind_taut_mps = _Field(float, "The wind's speed the last taut placement put, m/s (tether.enter_taut).")
    rho = _Field(float, "The air density the filter takes, kg/m^3 (the site's until the barometer reads it).")
    _accel_radial_innov2 = _Field(float, "The accelerometer's innovations along the tether's radius, their mean "
                                  "square (accel.radial_noise).")
    p_ref_pa = _Field()

    def coast(self, seconds: float) -> None:
        self._lib.bw_coast(self._p, seconds)

    def reset(self) -> None:
        self._lib.bw_reset(self._p)

    # the state the firmware reads
    initialised = _Field(bool)
    t_last_us = _Field()
    step = _Field()
    dt_us = _Field()
    unconfirmed = _Field(bool)

    @property
    def mode_name(self) -> str:
        return MODE_NAMES[self._s.ekf.mode]

    height_baro = _Field()

    def wind(self) -> tuple[float, float]:
        x = self._s.ekf.x
        return x[12], x[13]

    def wind_accuracy(self) -> float:
        return self._lib.bw_wind_accuracy(self._p)

    def height_m(self) -> float:
        return -self._s.ekf.x[2]

    @property
    def struct(self):
        """The whole bw_estimator_t (the lockstep harness compares its fields)."""
        return self._s


class SampleBlock:
    """Samples for ``CEstimator.on_batch``, filled one by one (``imu``, ``baro``) and handed over together:
    times, kinds (``KIND_IMU``, ``KIND_BARO``) and 9 values a sample in; per sample out ``stepped`` (bit 0:
    the filter stepped, bit 1: a time reset), and after it the step count, the mode and the consistency
    flags."""

    KIND_IMU, KIND_BARO = 0, 1

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.n = 0
        self.t = np.zeros(capacity, np.int64)
        self.kind = np.zeros(capacity, np.int32)
        self.v = np.zeros((capacity, 9))
        self.stepped = np.zeros(capacity, np.int32)
        self.steps = np.zeros(capacity, np.int64)
        self.modes = np.zeros(capacity, np.int32)
        self.flags = np.zeros(capacity, np.int32)
        self.t_p, self.kind_p, self.v_p = self.t.ctypes.data, self.kind.ctypes.data, self.v.ctypes.data
        self.stepped_p, self.steps_p = self.stepped.ctypes.data, self.steps.ctypes.data
        self.modes_p, self.flags_p = self.modes.ctypes.data, self.flags.ctypes.data
        self._t: list[int] = []  # filled here, copied into the arrays by ``ready``
        self._kind: list[int] = []
        self._v: list[float] = []

    def add(self, t_us: int, kind: int, values) -> None:
        self._t.append(t_us)
        self._kind.append(kind)
        self._v.extend(values)

    def __len__(self) -> int:
        return len(self._t)

    def ready(self) -> None:
        """The samples added since the last ``clear`` into the arrays (``n`` of them)."""
        n = self.n = len(self._t)
        self.t[:n] = self._t
        self.kind[:n] = self._kind
        self.v.reshape(-1)[: 9 * n] = self._v

    def clear(self) -> None:
        self.n = 0
        self._t.clear()
        self._kind.clear()
        self._v.clear()


class CWindCovOutput:
    """WIND_COV's fields from the C core (``estimator.outputs.WindCovOutput``'s interface)."""

    def __init__(self, est: CEstimator) -> None:
        self._est = est
        self._lib = est._lib
        self._fields = load(est.real)[3]()

    def reset(self) -> None:
        self._lib.bw_output_reset(self._est._p)

    def update(self, est: CEstimator, t_us: int) -> None:
        self._lib.bw_output_update(est._p, t_us)

    def fields(self, est: CEstimator) -> tuple:
        f = self._fields
        self._lib.bw_wind_cov(est._p, C.byref(f))
        return (f.time_usec, f.wind_x, f.wind_y, f.wind_z, f.var_horiz, f.var_vert, f.wind_alt, f.horiz_accuracy,
                f.vert_accuracy)  # fmt: skip


def new_core(design: Design, cfg: FilterConfig):
    """(estimator, WIND_COV output) of the core ``cfg.core`` names: the C core or the Python reference.
    A C core that cannot be built is a firmware_c.build.BuildError (one line)."""
    if cfg.core == "c":
        est = CEstimator(design, cfg)
        return est, CWindCovOutput(est)
    from firmware_py.estimator.control import Estimator
    from firmware_py.estimator.outputs import WindCovOutput

    est = Estimator(design, cfg)
    return est, WindCovOutput(est.cfg.imu_rate_hz, design.site.altitude_amsl_m)
