"""Named scenarios (docs/usage.md): a design + wind + truth options. The paper's Figs. 6-12 cases and
a few of our own. "better" = 10x smaller 1-sigma error of that sensor.

The paper's scenarios (``paper-reference`` to ``drag-crisis``) keep the paper's idealisations: its
straight rope with the whole weight on the balloon (``rope_model = "paper"``), no rope drag, no
vertical wind. The truth cases after ``rope-drag`` are outside the firmware's model on purpose (a
two-axis multisine, wind speeds far from 3 m/s, class-B turbulence, a low centre of mass, a hard-iron
offset, Cd(Re)); their ``filter`` stays the default: the firmware is not told.

The ``field-*`` scenarios are the real world, the default truth of a design file: the lumped-mass
rope with its own drag, vertical turbulence, and then shear, weather, wandering biases. Their
``filter`` is the default too: the firmware knows only the design."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from balloon_core.config import (
    ConfigError,
    Design,
    SensorsConfig,
    check_winch_reach,
    design_from_dict,
    load_toml,
    section_values,
    to_toml,
)
from firmware_py.estimator.state import FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.winch import WinchConfig
from sim_hil.wind import WindConfig


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    design: Design = field(default_factory=Design)
    wind: WindConfig = field(default_factory=WindConfig)
    truth: TruthConfig = field(default_factory=TruthConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)  # what the firmware should be told
    winch: WinchConfig = field(default_factory=WinchConfig)  # the winch's schedule (none: the design's length)

    def to_toml(self) -> str:
        """The whole scenario as one design file, for balloon-sim and balloon-fw alike."""
        sections = {**{n: getattr(self.design, n) for n in ("balloon", "tether", "site", "sensors")},
                    "wind": self.wind, "truth": self.truth, "filter": self.filter}  # fmt: skip
        if self.winch.enabled:
            sections["winch"] = self.winch
        return to_toml(sections, f"# scenario {self.name}: {self.description}")


def _with(**sections) -> Design:
    return replace(Design(), **sections)


_REF = Design()
_S = _REF.sensors
_B = _REF.balloon
_MS2D = WindConfig(kind="multisine", multisine_axes="both")

_MS2D_FIELD = WindConfig(kind="multisine", multisine_axes="both")
_BIASES = {"gyro_bias_dps": 0.3, "gyro_bias_walk_dps_rt_s": 0.002, "accel_bias_mps2": 0.02,
           "accel_bias_walk_mps2_rt_s": 0.001}  # fmt: skip
_WEATHER = {"pressure_drift_hpa_h": -2.0, "temperature_drift_k_h": 1.0}


def _paper(sc: Scenario, rope_drag: bool = False) -> Scenario:
    """A scenario of the paper's world: its rope (Eq. 5), without rope drag unless asked, no vertical wind;
    the design file says so (the firmware's rope is the paper's too: the paper's Figs. 6-12)."""
    truth = replace(sc.truth, rope_model="paper", rope_drag=rope_drag)
    told = replace(sc.filter, rope_model="paper", rope_normal_cd=sc.filter.rope_normal_cd if rope_drag else 0.0)
    return replace(sc, truth=truth, wind=replace(sc.wind, vertical=False), filter=told)


_PAPER_SCENARIOS = tuple(
    s if s.truth.rope_model == "paper" else _paper(s)
    for s in (
        Scenario("paper-reference", "r = 1.0 m, 100 m tether, 3 m/s VdH + Kaimal wind, Table 2 sensors"),
        Scenario("reduced-balloon", "r = 0.92 m (paper Fig. 7)", _with(balloon=replace(_B, radius_m=0.92))),
        Scenario("increased-balloon", "r = 1.15 m (paper Fig. 8)", _with(balloon=replace(_B, radius_m=1.15))),
        Scenario("better-accel", "accelerometer 0.001 m/s^2 (Fig. 9)", _with(sensors=replace(_S, accel_mps2=0.001))),
        Scenario("better-baro", "barometer 0.1 m (Fig. 10)", _with(sensors=replace(_S, baro_m=0.1))),
        Scenario("better-gyro-rate", "gyro 0.1 deg/s (Fig. 11)", _with(sensors=replace(_S, gyro_dps=0.1))),
        Scenario(
            "better-orientation",
            "magnetometer 0.0005 gauss: the orientation source that is not also a rate sensor (Fig. 12)",
            _with(sensors=replace(_S, mag_gauss=0.0005)),
        ),
        Scenario(
            "realistic-mems",
            "MEMS-grade noise densities with turn-on biases, gyro bias walk, baro offset, quantisation",
            _with(sensors=SensorsConfig(accel_mps2=0.014, baro_m=0.1, gyro_dps=0.07, mag_gauss=0.002)),
            truth=TruthConfig(
                gyro_bias_dps=0.3,
                gyro_bias_walk_dps_rt_s=0.002,
                accel_bias_mps2=0.02,
                baro_offset_m=1.0,
                mag_bias_gauss=0.0,
                quantize=True,
            ),  # fmt: skip
        ),
        Scenario(
            "multisine",
            "paper reference balloon in a 3 m/s multisine wind (frequency response)",
            wind=WindConfig(kind="multisine"),
        ),
        Scenario("steady", "paper reference balloon in a steady 3 m/s wind", wind=WindConfig(kind="steady")),
        Scenario("calm", "no wind: the balloon stands above the anchor", wind=WindConfig(kind="steady", mean_mps=0.0)),
        _paper(
            Scenario(
                "rope-drag",
                "paper reference with Hoerner cross-flow drag on the rope (the firmware told so)",
                filter=FilterConfig(rope_normal_cd=1.1),
            ),
            rope_drag=True,
        ),
        Scenario("multisine-2d", "multisine along and across a 3 m/s westerly (independent phases)", wind=_MS2D),
        Scenario(
            "multisine-2d-ne",
            "multisine-2d from 45 deg (north-east): both axes mix N and E",
            wind=replace(_MS2D, from_deg=45.0),
        ),
        Scenario("multisine-2d-s", "multisine-2d from 170 deg (nearly south)", wind=replace(_MS2D, from_deg=170.0)),
        Scenario(
            "reduced-multisine",
            "r = 0.92 m balloon in the multisine-2d wind",
            _with(balloon=replace(_B, radius_m=0.92)),
            wind=_MS2D,
        ),
        Scenario(
            "steady-1",
            "steady 1 m/s: the balloon nearly upright, little drag to see",
            wind=WindConfig(kind="steady", mean_mps=1.0),
        ),
        Scenario(
            "steady-8",
            "steady 8 m/s: blown far down (72 deg from vertical, 31 m high)",
            wind=WindConfig(kind="steady", mean_mps=8.0),
        ),
        Scenario(
            "gusty-6",
            "6 m/s VdH + Kaimal, IEC class B turbulence (sigma_u 1.41 m/s, 24 %)",
            wind=WindConfig(mean_mps=6.0, iec_class="B"),
        ),
        Scenario(
            "com-offset",
            "0.5 kg avionics + IMU 0.8 m below the centre (CoM 0.22 m low); 3 m/s VdH + Kaimal",
            truth=TruthConfig(avionics_offset_m=0.8),
        ),
        Scenario(
            "hard-iron",
            "magnetometer hard-iron offset (0.03, -0.02, 0.015) gauss, body axes",
            truth=TruthConfig(mag_hard_iron_gauss=(0.03, -0.02, 0.015)),
        ),
        Scenario(
            "drag-crisis",
            "Cd(Re) through the drag crisis (0.30 only at ~3 m/s); 3 m/s VdH + Kaimal",
            truth=TruthConfig(drag_model="reynolds"),
        ),
    )
)

_FIELD_SCENARIOS = (
    Scenario("field-rope", "the real rope (lumped masses, elastic, its own drag); 3 m/s VdH + Kaimal with vertical"),
    Scenario("field-rope-multisine", "the real rope in a two-axis 3 m/s multisine", wind=_MS2D_FIELD),
    Scenario(
        "field-catenary",
        "the real rope without its drag (the catenary alone); steady 3 m/s",
        wind=WindConfig(kind="steady"),
        truth=TruthConfig(rope_drag=False),
    ),
    Scenario(
        "field-shear",
        "the real rope in a sheared wind (power law, exponent 0.14)",
        truth=TruthConfig(shear_exponent=0.14),
    ),
    Scenario(
        "field-weather",
        "the real rope; ground pressure falling 2 hPa/h, air warming 1 K/h",
        truth=TruthConfig(**_WEATHER),
    ),
    Scenario(
        "field-biases", "the real rope; gyro and accelerometer turn-on biases that wander", truth=TruthConfig(**_BIASES)
    ),
    Scenario(
        "field-reduced",
        "r = 0.92 m (2.6 N spare lift at 100 m) on the real rope",
        _with(balloon=replace(_B, radius_m=0.92)),
    ),
    Scenario(
        "field-gusty-6",
        "the real rope; 6 m/s VdH + Kaimal, IEC class B with vertical",
        wind=WindConfig(mean_mps=6.0, iec_class="B"),
    ),
    Scenario(
        "field-all",
        "everything at once: real rope, shear, weather, wandering biases, vertical wind (run 1 h)",
        truth=TruthConfig(shear_exponent=0.14, **_WEATHER, **_BIASES),
    ),
    Scenario(
        "field-front",
        "the real rope, wandering biases; a front: at 300 s the wind veers 90 deg in a minute (3 m/s VdH + Kaimal)",
        wind=WindConfig(turn_deg=90.0, turn_start_s=300.0, turn_duration_s=60.0),
        truth=TruthConfig(**_BIASES),
    ),
    Scenario(
        "field-turning",
        "the real rope, wandering biases; the balloon turns: its asymmetry a weak vane (yaw moment 0.01), 60 deg "
        "from its boot heading once blown downwind",
        truth=TruthConfig(yaw_moment_coefficient=0.01, **_BIASES),
    ),
    Scenario(
        "field-turning-hard-iron",
        "the real rope; the balloon turns (yaw moment 0.01) with a magnetometer hard-iron offset (0.03, -0.02, 0.015) "
        "gauss, body axes",
        truth=TruthConfig(yaw_moment_coefficient=0.01, mag_hard_iron_gauss=(0.03, -0.02, 0.015)),
    ),
)


def winch_profile(low_m: float, high_m: float, speed_mps: float, hold_s: float, settle_s: float) -> WinchConfig:
    """A winch schedule for a profile: ``settle_s`` at ``low_m`` after the launch, up to ``high_m`` and
    down again at ``speed_mps``, ``hold_s`` at the top and at the end."""
    leg = (high_m - low_m) / speed_mps
    t = (0.0, settle_s, settle_s + leg, settle_s + leg + hold_s, settle_s + 2.0 * leg + hold_s,
         settle_s + 2.0 * leg + 2.0 * hold_s)  # fmt: skip
    return WinchConfig(times_s=t, lengths_m=(low_m, low_m, high_m, high_m, low_m, low_m))


# the profile's world: 3 m/s at 100 m, power law 0.14, veering 10 deg per 100 m, on a winch between 30
# and 150 m: the drum holds 150 m of rope ([tether] length_m, the longest line, where the lift is
# checked). The r = 1.15 m balloon lifts 150 m of the reference rope with 23 N to spare (the reference
# one only 2 N); ten segments keep the lumped rope's shortest (3 m) stable at 400 Hz.
_PROFILE_TRUTH = TruthConfig(shear_exponent=0.14, shear_reference_m=100.0, veer_deg_per_100m=10.0,
                             rope_segments=10, physics_hz=400.0)  # fmt: skip
_PROFILE_DESIGN = _with(balloon=replace(_B, radius_m=1.15), tether=replace(_REF.tether, length_m=150.0))
_PROFILE_SCENARIOS = (
    Scenario(
        "profile",
        "a winch profile 30-150-30 m at 0.25 m/s on the real rope; 3 m/s at 100 m, shear 0.14, veer 10 deg/100 m",
        _PROFILE_DESIGN,
        truth=_PROFILE_TRUTH,
        winch=winch_profile(30.0, 150.0, 0.25, 30.0, 120.0),
    ),
    Scenario(
        "profile-fast",
        "profile at 1 m/s (30-150-30 m in 5 min): the quick check",
        _PROFILE_DESIGN,
        truth=_PROFILE_TRUTH,
        winch=winch_profile(30.0, 150.0, 1.0, 10.0, 60.0),
    ),
)

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (*_PAPER_SCENARIOS, *_FIELD_SCENARIOS, *_PROFILE_SCENARIOS)}

WIND_CHOICES = {
    "vdh": {"kind": "vdh"},
    "vdh-paper": {"kind": "vdh", "vdh_amplitude": "paper"},
    "multisine": {"kind": "multisine"},
    "steady": {"kind": "steady"},
}


# what a run flies when it names no scenario: a design file alone flies the real world (the lumped rope with its own
# drag, vertical air: the default truth of a design file), with neither the paper's reference case
DESIGN_FILE_SCENARIO = "field-rope"
DEFAULT_SCENARIO = "paper-reference"


def scenario_name(name: str | None, config_path: str | None) -> str:
    """The scenario a run flies: ``name`` if given, else DESIGN_FILE_SCENARIO with a design file (``config_path``),
    else DEFAULT_SCENARIO."""
    if name is not None:
        return name
    return DESIGN_FILE_SCENARIO if config_path else DEFAULT_SCENARIO


def resolve(name: str, config_path: str | None = None, wind_choice: str | None = None) -> Scenario:
    """The scenario ``name``, overridden by a TOML config file's sections and a ``--wind`` choice."""
    if name not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{name}'; known: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[name]
    if config_path:
        data = load_toml(config_path)
        design_from_dict(data)  # validates sections and keys
        merged = {
            sec: {**section_values(getattr(sc.design, sec)), **data.get(sec, {})}
            for sec in ("balloon", "tether", "site", "sensors")
        }
        sc = replace(
            sc,
            design=design_from_dict(merged),
            wind=WindConfig.from_dict({**section_values(sc.wind), **data.get("wind", {})}),
            truth=TruthConfig.from_dict({**section_values(sc.truth), **data.get("truth", {})}),
            filter=FilterConfig.from_dict({**section_values(sc.filter), **data.get("filter", {})}),
            winch=WinchConfig.from_dict({**section_values(sc.winch), **data.get("winch", {})}),
        )
    if sc.winch.enabled:  # the drum's rope holds the longest line (as balloon-fw and reprocess check the file)
        check_winch_reach(sc.winch.lengths_m, sc.design.tether.length_m)
    if wind_choice:
        if wind_choice not in WIND_CHOICES:
            raise ConfigError(f"unknown --wind '{wind_choice}'; known: {', '.join(WIND_CHOICES)}")
        sc = replace(sc, wind=replace(sc.wind, **WIND_CHOICES[wind_choice]))
    return sc
