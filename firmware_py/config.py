"""One TOML file describes one design (CONTRACT.md): balloon, tether, site and sensors.

``balloon-sim`` and ``balloon-fw`` read the same file. The shared sections are parsed here; a program
may own extra sections ([wind], [truth] for the simulator, [filter] for the firmware). Every key is
optional; an unknown section or key is a clear error, never silently ignored.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Every top-level section any program of the project understands.
KNOWN_SECTIONS = ("balloon", "tether", "site", "sensors", "wind", "truth", "filter")


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


@dataclass(frozen=True)
class SensorsConfig:
    """1-sigma sensor errors (paper Table 2)."""

    accel_mps2: float = 0.01
    baro_m: float = 1.0
    gyro_dps: float = 1.0
    mag_gauss: float = 0.005
    thermometer_k: float = 0.2


@dataclass(frozen=True)
class Design:
    balloon: BalloonConfig = field(default_factory=BalloonConfig)
    tether: TetherConfig = field(default_factory=TetherConfig)
    site: SiteConfig = field(default_factory=SiteConfig)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)


_SHARED = {"balloon": BalloonConfig, "tether": TetherConfig, "site": SiteConfig, "sensors": SensorsConfig}


def build_section(cls: type, section: str, values: dict[str, Any]) -> Any:
    """Instantiate a frozen dataclass from a TOML table, rejecting unknown keys and non-finite numbers."""
    if not isinstance(values, dict):
        raise ConfigError(f"[{section}] must be a table")
    names = {f.name: f for f in dataclasses.fields(cls)}
    for key, val in values.items():
        if key not in names:
            raise ConfigError(f"unknown key '{key}' in [{section}]; known: {', '.join(sorted(names))}")
        if isinstance(val, bool):
            continue
        if isinstance(val, (int, float)) and not math.isfinite(float(val)):
            raise ConfigError(f"[{section}] {key} must be finite, got {val}")
    converted = {}
    for key, val in values.items():
        default = names[key].default
        if isinstance(default, float) or (default is None and isinstance(val, (int, float))):
            if not isinstance(val, (int, float)) or isinstance(val, bool):
                raise ConfigError(f"[{section}] {key} must be a number, got {val!r}")
            val = float(val)
        converted[key] = val
    return cls(**converted)


def _check_design(d: Design) -> None:
    positive = {
        "balloon.radius_m": d.balloon.radius_m,
        "balloon.skin_and_avionics_kg": d.balloon.skin_and_avionics_kg,
        "balloon.drag_coefficient": d.balloon.drag_coefficient,
        "tether.length_m": d.tether.length_m,
        "sensors.accel_mps2": d.sensors.accel_mps2,
        "sensors.baro_m": d.sensors.baro_m,
        "sensors.gyro_dps": d.sensors.gyro_dps,
        "sensors.mag_gauss": d.sensors.mag_gauss,
        "sensors.thermometer_k": d.sensors.thermometer_k,
    }
    for name, v in positive.items():
        if not v > 0.0:
            raise ConfigError(f"{name} must be > 0, got {v}")
    if d.balloon.gas_density_kg_m3 < 0 or d.tether.linear_density_kg_m < 0:
        raise ConfigError("densities must be >= 0")
    if d.site.ground_pressure_hpa is not None and not 300.0 <= d.site.ground_pressure_hpa <= 1100.0:
        raise ConfigError(f"site.ground_pressure_hpa out of range: {d.site.ground_pressure_hpa}")


def design_from_dict(data: dict[str, Any]) -> Design:
    """The shared sections of a parsed TOML document as a validated :class:`Design`."""
    for section in data:
        if section not in KNOWN_SECTIONS:
            raise ConfigError(f"unknown section [{section}]; known: {', '.join(KNOWN_SECTIONS)}")
    parts = {name: build_section(cls, name, data.get(name, {})) for name, cls in _SHARED.items()}
    design = Design(**parts)
    _check_design(design)
    return design


def load_toml(path: str | Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {path}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from exc


def load_design(path: str | Path | None) -> Design:
    return Design() if path is None else design_from_dict(load_toml(path))
