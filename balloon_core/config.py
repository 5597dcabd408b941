"""One TOML file describes one design (docs/usage.md): balloon, tether, site and sensors.

``balloon-sim`` and ``balloon-fw`` read the same file. The shared sections are parsed here; a program
may own extra sections ([wind], [truth] for the simulator, [filter] for the firmware). Every key is
optional; an unknown section or key is a clear error, never silently ignored.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from balloon_core.atmosphere import G0, P0_PA, R_AIR, T0_K, isa_pressure_pa


class ConfigError(ValueError):
    """A configuration file or value that cannot be used."""


@dataclass(frozen=True)
class BalloonConfig:
    radius_m: float = 1.0
    skin_and_avionics_kg: float = 1.0
    gas_density_kg_m3: float = 0.2
    drag_coefficient: float = 0.3

    @property
    def volume_m3(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius_m**3

    @property
    def gas_mass_kg(self) -> float:
        return self.gas_density_kg_m3 * self.volume_m3

    @property
    def mass_kg(self) -> float:
        """Rigid mass: skin + avionics + enclosed gas (closed balloon)."""
        return self.skin_and_avionics_kg + self.gas_mass_kg

    @property
    def frontal_area_m2(self) -> float:
        """pi r^2: the paper's Eq. (3) prints 2r (a length), see docs/model.md."""
        return math.pi * self.radius_m**2


NYLON_DENSITY_KG_M3 = 1140.0


@dataclass(frozen=True)
class TetherConfig:
    length_m: float = 100.0
    linear_density_kg_m: float = 0.02

    @property
    def diameter_m(self) -> float:
        """Of a solid nylon rope with this linear density (0.02 kg/m: 4.7 mm)."""
        return math.sqrt(4.0 * self.linear_density_kg_m / (math.pi * NYLON_DENSITY_KG_M3))


@dataclass(frozen=True)
class SiteConfig:
    altitude_amsl_m: float = 0.0
    mag_declination_deg: float = 0.0
    ground_pressure_hpa: float | None = None
    ground_temperature_c: float = 20.0  # project extension: ISA ground temperature (Table 1: rho = 1.2)
    ground_sysid: int = 255  # the MAVLink system whose SCALED_PRESSURE is the ground reference (not the balloon's)

    @property
    def ground_pressure_pa(self) -> float:
        """The air pressure at the ground, Pa: ``ground_pressure_hpa`` where given, else the standard atmosphere's at
        ``altitude_amsl_m`` (1013.25 hPa at sea level, 845.6 at 1500 m): the simulator's air and the lift check. The
        firmware without ``ground_pressure_hpa`` measures it (the barometer zeroed at the boot)."""
        if self.ground_pressure_hpa is not None:
            return self.ground_pressure_hpa * 100.0
        return isa_pressure_pa(self.altitude_amsl_m, P0_PA, T0_K)


@dataclass(frozen=True)
class SensorsConfig:
    """1-sigma sensor errors (paper Table 2)."""

    accel_mps2: float = 0.01
    baro_m: float = 1.0
    gyro_dps: float = 1.0
    mag_gauss: float = 0.005
    thermometer_k: float = 0.2
    # how well the IMU's axes are known against the balloon's tether axis (the rope's pull through the centre), deg:
    # a board mounted askew reads the lean that far off, which no sensor on the balloon can tell (docs/estimator.md)
    imu_alignment_deg: float = 0.0
    # the IMU's axes against the balloon's, as measured (the payload hung from its tether attachment, still: the
    # accelerometer's tilt), deg: the firmware turns every reading into the balloon's axes (rotation.imu_mount)
    imu_roll_deg: float = 0.0
    imu_pitch_deg: float = 0.0


@dataclass(frozen=True)
class Design:
    balloon: BalloonConfig = field(default_factory=BalloonConfig)
    tether: TetherConfig = field(default_factory=TetherConfig)
    site: SiteConfig = field(default_factory=SiteConfig)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)


_SHARED = {"balloon": BalloonConfig, "tether": TetherConfig, "site": SiteConfig, "sensors": SensorsConfig}


# ---------------------------------------------------------------- the schema of the whole file


@dataclass(frozen=True)
class Rule:
    """Type and range of one key: ``kind`` number | integer | bool | str | numbers; a number lies in
    [lo, hi] (lo excluded when ``lo_open``); a str is one of ``choices``; numbers is a list of them."""

    kind: str
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None

    def describe(self) -> str:
        if self.kind == "str":
            return " or ".join(repr(c) for c in self.choices)
        lo = "(" if self.lo_open else "["
        return f"a number in {lo}{self.lo:g}, {self.hi:g}]"


def num(lo: float, hi: float) -> Rule:
    return Rule("number", lo, hi)


def pos(hi: float) -> Rule:
    """A number > 0 and <= hi."""
    return Rule("number", 0.0, hi, lo_open=True)


BOOL = Rule("bool")


def one_of(*choices: str) -> Rule:
    return Rule("str", choices=choices)


#: Every key of every section any program reads, with its type and range. balloon-sim and balloon-fw
#: both check the whole file against it (``validate_document``), so one file gets one verdict; the
#: dataclasses that hold the values (here, sim_hil.wind, sim_hil.dynamics, firmware_py.estimator.state) must
#: have exactly these keys (tests/system/test_user_errors.py checks).
SCHEMA: dict[str, dict[str, Rule]] = {
    "balloon": {
        "radius_m": num(0.05, 20.0),
        "skin_and_avionics_kg": num(0.001, 1000.0),
        "gas_density_kg_m3": num(0.0, 10.0),
        "drag_coefficient": num(0.01, 3.0),
    },
    "tether": {"length_m": num(1.0, 5000.0), "linear_density_kg_m": num(0.0, 1.0)},
    # what the firmware sends besides WIND_COV (firmware_py.app.OutputConfig)
    "outputs": {"qgc_direction": one_of("to", "from")},
    "site": {
        "altitude_amsl_m": num(-500.0, 9000.0),
        "mag_declination_deg": num(-180.0, 180.0),
        "ground_pressure_hpa": num(300.0, 1100.0),
        "ground_temperature_c": num(-80.0, 60.0),
        "ground_sysid": Rule("integer", 1, 255),
    },
    "sensors": {
        "accel_mps2": num(1e-5, 10.0),
        "baro_m": num(1e-3, 1000.0),
        "gyro_dps": num(1e-4, 100.0),
        "mag_gauss": num(1e-6, 1.0),
        "thermometer_k": num(1e-3, 50.0),
        "imu_alignment_deg": num(0.0, 10.0),
        "imu_roll_deg": num(-10.0, 10.0),
        "imu_pitch_deg": num(-10.0, 10.0),
    },
    "wind": {
        "kind": one_of("vdh", "multisine", "steady"),
        "mean_mps": num(0.0, 50.0),
        "from_deg": num(-360.0, 360.0),
        "vdh_amplitude": one_of("consistent", "paper"),
        "gap_cph": num(0.01, 360.0),
        "turbulence": one_of("kaimal", "none"),
        "turbulence_intensity": num(0.0, 1.0),
        "iec_class": one_of("", "A", "B", "C"),
        "vertical": BOOL,
        "multisine_hz": Rule("numbers", 0.0, 100.0, lo_open=True),
        "multisine_amplitude_mps": num(0.0, 20.0),
        "multisine_axes": one_of("along", "both"),
        "sample_hz": num(1.0, 1000.0),
        "turn_deg": num(-3600.0, 3600.0),
        "turn_start_s": num(0.0, 1e7),
        "turn_duration_s": num(1.0, 1e7),
    },
    "truth": {
        "rope_model": one_of("lumped", "paper"),
        "rope_segments": Rule("integer", 2, 200),
        "rope_damping_ratio": num(0.0, 10.0),
        "shear_exponent": num(0.0, 1.0),
        "added_mass_coefficient": num(0.0, 2.0),
        "tether_ea_n": num(100.0, 1e9),
        "tether_damping_ratio": num(0.0, 10.0),
        "rope_drag": BOOL,
        "rope_normal_cd": num(0.0, 5.0),
        "rot_damping_nms": num(0.0, 50.0),
        "yaw_moment_coefficient": num(0.0, 0.5),
        "release_s": num(0.0, 3600.0),
        "initial_yaw_deg": num(-360.0, 360.0),
        "physics_hz": num(100.0, 10000.0),
        "isa_density": BOOL,
        "drag": BOOL,
        "spatial_filter": BOOL,
        "froude_krylov": BOOL,
        "gyro_bias_dps": num(0.0, 100.0),
        "gyro_bias_walk_dps_rt_s": num(0.0, 10.0),
        "accel_bias_mps2": num(0.0, 10.0),
        "accel_bias_walk_mps2_rt_s": num(0.0, 1.0),
        "baro_offset_m": num(0.0, 1000.0),
        "mag_bias_gauss": num(0.0, 1.0),
        "mag_hard_iron_gauss": Rule("numbers", -10.0, 10.0, length=3),
        "mag_switched_gauss": Rule("numbers", -10.0, 10.0, length=3),
        "mag_switched_on_s": num(0.0, 1e7),
        "mag_switched_off_s": num(0.0, 1e7),
        "imu_roll_deg": num(-10.0, 10.0),
        "imu_pitch_deg": num(-10.0, 10.0),
        "ground_field_gauss": Rule("numbers", -2.0, 2.0, length=3),
        "ground_field_scale_m": num(0.1, 1000.0),
        "quantize": BOOL,
        "mag_field_h_gauss": num(0.0, 2.0),
        "mag_field_z_gauss": num(-2.0, 2.0),
        "pressure_drift_hpa_h": num(-50.0, 50.0),
        "shear_reference_m": num(0.0, 10000.0),
        "veer_deg_per_100m": num(-180.0, 180.0),
        "ground_baro_hz": num(0.0, 100.0),
        "ground_baro_hpa": num(0.0, 10.0),
        "ground_thermometer_k": num(0.0, 10.0),
        "temperature_drift_k_h": num(-20.0, 20.0),
        "drag_model": one_of("constant", "reynolds"),
        "drag_coefficient_scale": num(0.1, 10.0),
        "drag_crisis_reynolds": num(1e3, 1e8),
        "drag_crisis_exponent": num(0.1, 10.0),
        "avionics_offset_m": num(0.0, 20.0),
        "avionics_kg": num(0.0, 1000.0),
    },
    "winch": {
        "times_s": Rule("numbers", 0.0, 1e6),
        "lengths_m": Rule("numbers", 1.0, 5000.0),
        "max_speed_mps": pos(10.0),
        "status_hz": pos(100.0),
        "tension_noise_kg": num(0.0, 100.0),
        "tension_measured": BOOL,
    },
    "filter": {
        "imu_rate_hz": num(1.0, 10000.0),
        "float32": BOOL,
        "core": one_of("c", "py"),
        "accel_process_mps2": num(1e-4, 100.0),
        "expected_wind_mps": num(0.0, 50.0),
        "turbulence_intensity": num(0.01, 1.0),
        "drag_walk_rt_s": num(0.0, 1.0),
        "baro_walk_m_rt_s": num(0.0, 10.0),
        "accel_bias_walk_mps2_rt_s": num(0.0, 1.0),
        "gyro_bias_walk_dps_rt_s": num(0.0, 10.0),
        "accel_model_mps2": num(0.0, 100.0),
        "accel_taut_mps2": num(0.0, 100.0),
        "accel_static_mps2": num(0.0, 100.0),
        "align_rad": num(0.0, 1.0),
        "radial_m": num(1e-3, 100.0),
        "radial_rate_mps": num(1e-3, 100.0),
        "rope_model": one_of("catenary", "paper"),
        "rope_normal_cd": num(0.0, 5.0),
        "gate_sigma": num(1.0, 100.0),
        "recover_after_s": num(0.0, 3600.0),
        "init_wind_mps": num(0.01, 100.0),
        "init_drag": num(1e-3, 10.0),
        "init_accel_bias_mps2": num(1e-4, 10.0),
        "init_gyro_bias_dps": num(1e-3, 100.0),
        "init_tilt_deg": num(0.01, 180.0),
        "init_yaw_deg": num(0.01, 360.0),
        "taut_margin_m": num(0.0, 100.0),
        "mode_dwell_s": num(0.0, 3600.0),
        "release_accel_mps2": num(0.1, 100.0),
        "release_height_m": num(0.0, 1000.0),
        "max_gap_s": num(0.01, 3600.0),
    },
}
KNOWN_SECTIONS = tuple(SCHEMA)
SIM_IMU_HZ = 100.0  # the simulator's IMU rate: its physics step must divide it evenly
# defaults of the simulator's keys that cross-key checks need when the file leaves them out
# (sim_hil.wind.WindConfig, sim_hil.dynamics.TruthConfig; tests/system/test_user_errors.py keeps them equal)
SIM_DEFAULTS = {
    "wind.sample_hz": 20.0,
    "wind.multisine_hz": (0.003, 0.01, 0.02, 0.05, 0.1, 0.2),
    "truth.avionics_kg": 0.5,
    "truth.physics_hz": 200.0,
}


def _literal(val: Any) -> str:
    """A value as it is written in TOML (true, not True)."""
    if isinstance(val, bool):
        return "true" if val else "false"
    return repr(val)


def check_value(section: str, key: str, val: Any) -> Any:
    """``val`` checked against the schema; numbers come back as float, lists as tuples of float."""
    rule = SCHEMA[section][key]
    where = f"[{section}] {key}"
    if rule.kind == "bool":
        if not isinstance(val, bool):
            raise ConfigError(f"{where} must be true or false, got {_literal(val)}")
        return val
    if rule.kind == "str":
        if not isinstance(val, str) or val not in rule.choices:
            raise ConfigError(f"{where} must be {rule.describe()}, got {_literal(val)}")
        return val
    if rule.kind == "numbers":
        if not isinstance(val, (list, tuple)) or (rule.length is not None and len(val) != rule.length):
            n = f"{rule.length} " if rule.length else ""
            raise ConfigError(f"{where} must be a list of {n}numbers, got {_literal(val)}")
        return tuple(_number(where, x, rule) for x in val)
    if rule.kind == "integer":
        if isinstance(val, float) and val.is_integer():  # 12.0 from a program that wrote numbers as floats
            val = int(val)
        if isinstance(val, bool) or not isinstance(val, int):
            raise ConfigError(f"{where} must be an integer, got {_literal(val)}")
        if not rule.lo <= val <= rule.hi:
            raise ConfigError(f"{where} must be an integer in [{rule.lo:g}, {rule.hi:g}], got {val}")
        return val
    return _number(where, val, rule)


def _number(where: str, val: Any, rule: Rule) -> float:
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise ConfigError(f"{where} must be a number, got {_literal(val)}")
    x = float(val)
    if not math.isfinite(x):
        raise ConfigError(f"{where} must be finite, got {val}")
    if x < rule.lo or x > rule.hi or (rule.lo_open and x == rule.lo):
        raise ConfigError(f"{where} must be {rule.describe()}, got {val}")
    return x


def check_winch_schedule(times_s, lengths_m, max_speed_mps: float) -> None:
    """A [winch] schedule every program refuses alike (ConfigError): as many times as lengths, the times
    increasing, no slope faster than ``max_speed_mps``."""
    t, lengths = tuple(times_s), tuple(lengths_m)
    if len(t) != len(lengths):
        raise ConfigError(f"[winch] times_s and lengths_m must have as many entries ({len(t)} and {len(lengths)})")
    if any(b <= a for a, b in zip(t, t[1:])):
        raise ConfigError("[winch] times_s must increase")
    for i in range(1, len(t)):
        speed = abs(lengths[i] - lengths[i - 1]) / (t[i] - t[i - 1])
        if speed > max_speed_mps * (1.0 + 1e-9):
            raise ConfigError(
                f"[winch] from {t[i - 1]:g} s to {t[i]:g} s the schedule reels at {speed:.3g} m/s, faster than "
                f"max_speed_mps = {max_speed_mps:g}"
            )


def check_winch_reach(lengths_m, tether_length_m: float) -> None:
    """With a winch, ``[tether] length_m`` is the rope on the drum: the longest line it can pay out, and
    the length the lift is checked at. A schedule beyond it is refused (ConfigError)."""
    longest = max(lengths_m, default=0.0)
    if longest > tether_length_m:
        raise ConfigError(
            f"[winch] lengths_m reaches {longest:g} m, beyond [tether] length_m = {tether_length_m:g} m (the rope on "
            "the drum, the longest line it can pay out, and where the lift is checked): a longer [tether] length_m"
        )


def validate_document(data: dict[str, Any], whole: bool = True) -> dict[str, dict[str, Any]]:
    """The whole parsed file checked against ``SCHEMA`` (every section, whichever program reads it),
    plus the checks that involve two keys. Returns the values with numbers as floats. ``whole`` False:
    one section on its own (``build_section``), not checked against the others' defaults."""
    out: dict[str, dict[str, Any]] = {}
    for section, values in data.items():
        if section not in SCHEMA:
            raise ConfigError(f"unknown section [{section}]; known: {', '.join(KNOWN_SECTIONS)}")
        if not isinstance(values, dict):
            raise ConfigError(f"[{section}] must be a table")
        known = SCHEMA[section]
        for key in values:
            if key not in known:
                raise ConfigError(f"unknown key '{key}' in [{section}]; known: {', '.join(sorted(known))}")
        out[section] = {key: check_value(section, key, val) for key, val in values.items()}
    wind, truth, balloon = out.get("wind", {}), out.get("truth", {}), out.get("balloon", {})
    sample_hz = wind.get("sample_hz", SIM_DEFAULTS["wind.sample_hz"])
    if max(wind.get("multisine_hz", SIM_DEFAULTS["wind.multisine_hz"]), default=0.0) >= sample_hz / 2:
        raise ConfigError(f"[wind] multisine_hz must lie below sample_hz / 2 (Nyquist, {sample_hz / 2:g} Hz)")
    physics_hz = truth.get("physics_hz", SIM_DEFAULTS["truth.physics_hz"])
    if physics_hz % SIM_IMU_HZ:
        raise ConfigError(f"[truth] physics_hz must be a multiple of the {SIM_IMU_HZ:g} Hz IMU rate: {physics_hz:g}")
    offset = truth.get("avionics_offset_m", 0.0)
    if offset > 0.0:
        radius = balloon.get("radius_m", BalloonConfig.radius_m)
        if offset >= radius:
            raise ConfigError(f"[truth] avionics_offset_m = {offset:g} must be inside the sphere (< radius {radius:g})")
        skin = balloon.get("skin_and_avionics_kg", BalloonConfig.skin_and_avionics_kg)
        if truth.get("avionics_kg", SIM_DEFAULTS["truth.avionics_kg"]) > skin:
            raise ConfigError("[truth] avionics_kg must not exceed [balloon] skin_and_avionics_kg")
    winch = out.get("winch")
    if winch is not None:
        check_winch_schedule(winch.get("times_s", ()), winch.get("lengths_m", ()), winch.get("max_speed_mps", 1.0))
        if whole:
            check_winch_reach(winch.get("lengths_m", ()), out.get("tether", {}).get("length_m", TetherConfig.length_m))
    return out


def build_section(cls: type, section: str, values: dict[str, Any]) -> Any:
    """Instantiate a frozen dataclass from a TOML table checked against ``SCHEMA``."""
    if not isinstance(values, dict):
        raise ConfigError(f"[{section}] must be a table")
    checked = validate_document({section: values}, whole=False)[section]
    return cls(**checked)


def lift_balance(d: Design) -> tuple[float, float, float, float, float]:
    """(buoyancy, skin and avionics weight, gas weight, tether weight, net lift) in N at the ground
    (the simulator's air: SiteConfig.ground_pressure_pa at ground_temperature_c)."""
    rho = d.site.ground_pressure_pa / (R_AIR * (d.site.ground_temperature_c + 273.15))
    b = d.balloon
    buoyancy = rho * b.volume_m3 * G0
    skin = b.skin_and_avionics_kg * G0
    gas = b.gas_mass_kg * G0
    rope = d.tether.linear_density_kg_m * d.tether.length_m * G0
    return buoyancy, skin, gas, rope, buoyancy - skin - gas - rope


class LiftError(ConfigError):
    """A design that is valid key by key but cannot lift its tether."""


def _check_design(d: Design) -> None:
    buoyancy, skin, gas, rope, net = lift_balance(d)
    if net <= 0.0:
        raise LiftError(
            f"the balloon cannot lift its tether: buoyancy {buoyancy:.2f} N - skin and avionics {skin:.2f} N "
            f"- gas {gas:.2f} N - tether {rope:.2f} N = net lift {net:.2f} N (needs > 0: a larger radius_m, "
            f"a lighter skin, gas or tether; the air: {d.site.ground_pressure_pa / 100.0:.1f} hPa at "
            f"{d.site.ground_temperature_c:g} C)"
        )


def design_from_dict(data: dict[str, Any]) -> Design:
    """The shared sections of a parsed TOML document as a validated :class:`Design`."""
    validate_document(data)
    parts = {name: build_section(cls, name, data.get(name, {})) for name, cls in _SHARED.items()}
    design = Design(**parts)
    _check_design(design)
    return design


def load_toml(path: str | Path) -> dict[str, Any]:
    """A design file, parsed and checked as a whole (``validate_document``): any error is a ConfigError."""
    data = read_toml(path)
    try:
        validate_document(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    return data


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML file parsed, not checked (a study file holds more than a design); errors are ConfigError."""
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {path}") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config file {path}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    return data


def load_design(path: str | Path | None) -> Design:
    return Design() if path is None else design_from_dict(load_toml(path))


# ---------------------------------------------------------------- writing a design file


def section_values(obj: Any) -> dict[str, Any]:
    """A section's dataclass as its keys and values (a key whose value is None, "not given", left out)."""
    return {k: v for k, v in asdict(obj).items() if v is not None}


def toml_value(v: Any) -> str:
    """One value as TOML writes it (floats as floats: ``12.0``)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, int):
        return repr(v)
    return repr(float(v))


def to_toml(sections: dict[str, Any], header: str) -> str:
    """A whole design file: ``header`` (a comment line), then each section (a dataclass or a dict) with
    every key and its value. ``load_toml`` reads it back to the same values."""
    lines = [header]
    for name, obj in sections.items():
        lines.append(f"\n[{name}]")
        values = obj if isinstance(obj, dict) else section_values(obj)
        for k, v in values.items():
            lines.append(f"{k} = {toml_value(v)}")
    return "\n".join(lines) + "\n"
