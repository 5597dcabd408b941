"""The study file (SPEC.toml): a base design, the axes to sweep, seeds, duration, metrics -> a list of cases.

    [study]
    base = "paper-reference"      # a scenario name (balloon-sim --list-scenarios); default paper-reference
    seeds = 3                      # 1..3, or a list of seeds: [1, 7, 42]
    duration_s = 600.0             # simulated flight per case
    start_s = 120.0                # scoring starts here (after release and the climb)
    combine = "grid"               # grid: cartesian product of the axes; zip: their i-th values together
    metrics = ["band_skill", ...]  # the metrics summarised and plotted (all are recorded); default MAIN

    [balloon]                      # optional: the programs' design sections override the base scenario
    radius_m = 1.1                 # ([balloon], [tether], [site], [sensors], [wind], [truth], [filter])

    [axes]                         # one sweep ("main"); or several [[sweep]] tables: name, combine, axes
    "balloon.radius_m" = [0.92, 1.0, 1.15]              # a list of points
    "wind.mean_mps" = {start = 1.0, stop = 10.0, num = 4}  # or an even grid (inclusive ends)
    "wind.mean_mps+filter.expected_wind_mps" = [1, 5]  # one axis setting several keys to the same value
    scenario = ["paper-reference", "better-gyro-rate"]  # whole scenarios as the points of an axis

Every key is checked against the real design dataclasses before anything runs; every case's design is
built (and so validated) once up front. A problem is a :class:`ConfigError` with one line.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from balloon_core.config import ConfigError, Design, LiftError, design_from_dict, read_toml
from balloon_core.userargs import MAX_DURATION_S, MAX_SEED
from firmware_py.estimator.state import FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.scenarios import SCENARIOS, Scenario
from sim_hil.wind import WindConfig
from study.metrics import METRICS

DESIGN_SECTIONS = ("balloon", "tether", "site", "sensors")
SECTIONS: dict[str, type] = {
    **{s: type(getattr(Design(), s)) for s in DESIGN_SECTIONS},
    "wind": WindConfig,
    "truth": TruthConfig,
    "filter": FilterConfig,
}
STUDY_KEYS = ("base", "seeds", "duration_s", "start_s", "combine", "metrics")
SWEEP_KEYS = ("name", "combine", "axes")
MIN_SCORED_S = 30.0
#: the most cases (points x seeds, over all sweeps) one run takes: the client holds the resolved case list
#: (1-5 kB a case) and every row in memory, 0.6-3 GB at this size (docs/study.md, "A 100 000-case sweep")
MAX_CASES = 500_000
#: bump when a metric's definition changes: stored parts of older versions are not reused
METRICS_VERSION = 1


@dataclass(frozen=True)
class Axis:
    name: str  # as written: "balloon.radius_m", "a+b" or "scenario"
    keys: tuple[str, ...]  # the design keys it sets ("scenario" for the scenario axis)
    values: tuple[Any, ...]


@dataclass(frozen=True)
class Sweep:
    name: str
    combine: str
    axes: tuple[Axis, ...]


@dataclass(frozen=True)
class Case:
    """One flight: the full resolved design (every section, every key), seed, duration, scoring start."""

    sweep: str
    point: dict[str, Any]  # axis name -> value of this case
    sections: dict[str, dict[str, Any]]
    seed: int
    duration_s: float
    start_s: float
    key: str = ""

    def payload(self) -> dict[str, Any]:
        """What a worker needs (plain data, cheap to pickle)."""
        return {"key": self.key, "sections": self.sections, "seed": self.seed, "duration_s": self.duration_s,
                "start_s": self.start_s}  # fmt: skip


@dataclass(frozen=True)
class Spec:
    base: str
    overrides: dict[str, dict[str, Any]]
    sweeps: tuple[Sweep, ...]
    seeds: tuple[int, ...]
    duration_s: float
    start_s: float
    metrics: tuple[str, ...]
    axis_names: tuple[str, ...] = field(default=())  # every axis of every sweep, in order of appearance

    def cases(self) -> list[Case]:
        out = []
        for sw in self.sweeps:
            for point in points(sw):
                sections = resolve_sections(self.base, self.overrides, point)
                for seed in self.seeds:
                    c = Case(sw.name, point, sections, seed, self.duration_s, self.start_s)
                    out.append(dataclasses.replace(c, key=case_key(c)))
        return out


# ---------------------------------------------------------------- parsing


def load_spec(path: str) -> Spec:
    return parse_spec(read_toml(path))


def parse_spec(data: dict[str, Any]) -> Spec:
    known = {"study", "axes", "sweep", *SECTIONS}
    for k in data:
        if k not in known:
            raise ConfigError(f"unknown section [{k}] in the study file; known: {', '.join(sorted(known))}")
    st = data.get("study", {})
    if not isinstance(st, dict):
        raise ConfigError("[study] must be a table")
    for k in st:
        if k not in STUDY_KEYS:
            raise ConfigError(f"unknown key '{k}' in [study]; known: {', '.join(STUDY_KEYS)}")
    base = st.get("base", "paper-reference")
    if not isinstance(base, str) or base not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{base}' as [study] base; known: {', '.join(SCENARIOS)}")
    overrides = {s: data[s] for s in SECTIONS if s in data}
    for s, tab in overrides.items():
        if not isinstance(tab, dict):
            raise ConfigError(f"[{s}] must be a table")
        for k, v in tab.items():
            check_value(f"{s}.{k}", v)
    seeds = parse_seeds(st.get("seeds", 1))
    duration = number("[study] duration_s", st.get("duration_s", 600.0))
    start = number("[study] start_s", st.get("start_s", 120.0))
    if start < 0 or duration - start < MIN_SCORED_S:
        raise ConfigError(f"[study] needs 0 <= start_s and duration_s - start_s >= {MIN_SCORED_S:g} s to score, "
                          f"got start_s {start:g}, duration_s {duration:g}")  # fmt: skip
    if duration > MAX_DURATION_S:
        raise ConfigError(f"[study] duration_s must be at most {MAX_DURATION_S:.0f} s (7 days), got {duration:g}")
    metrics = parse_metrics(st.get("metrics"))
    default_combine = st.get("combine", "grid")
    if "axes" in data and "sweep" in data:
        raise ConfigError("use either [axes] (one sweep) or [[sweep]] tables, not both")
    if "sweep" in data:
        raw = data["sweep"]
        if not isinstance(raw, list) or not raw:
            raise ConfigError("[[sweep]] must be one or more tables")
        sweeps = tuple(parse_sweep(sw, k, default_combine) for k, sw in enumerate(raw, 1))
    else:
        sweeps = (parse_sweep({"name": "main", "axes": data.get("axes", {})}, 1, default_combine),)
    names = [sw.name for sw in sweeps]
    if len(set(names)) != len(names):
        raise ConfigError(f"sweep names must differ, got {names}")
    axis_names = tuple(dict.fromkeys(a.name for sw in sweeps for a in sw.axes))
    spec = Spec(base, overrides, sweeps, seeds, duration, start, metrics, axis_names)
    check_size(spec)
    validate_designs(spec)
    return spec


def parse_sweep(sw: Any, k: int, default_combine: str) -> Sweep:
    if not isinstance(sw, dict):
        raise ConfigError(f"sweep {k} must be a table")
    for key in sw:
        if key not in SWEEP_KEYS:
            raise ConfigError(f"unknown key '{key}' in sweep {k}; known: {', '.join(SWEEP_KEYS)}")
    name = sw.get("name", f"sweep{k}")
    if not isinstance(name, str) or not name or any(c in name for c in "/\\ "):
        raise ConfigError(f"sweep {k}: name must be a word without spaces or slashes, got {name!r}")
    combine = sw.get("combine", default_combine)
    if combine not in ("grid", "zip"):
        raise ConfigError(f"sweep '{name}': combine must be grid or zip, got {combine!r}")
    axes_tab = sw.get("axes", {})
    if not isinstance(axes_tab, dict):
        raise ConfigError(f"sweep '{name}': axes must be a table")
    axes = tuple(parse_axis(a, v) for a, v in axes_tab.items())
    if combine == "zip" and len({len(a.values) for a in axes}) > 1:
        raise ConfigError(f"sweep '{name}': zip needs axes of equal length, got "
                          + ", ".join(f"{a.name} {len(a.values)}" for a in axes))  # fmt: skip
    seen: set[str] = set()
    for a in axes:
        for key in a.keys:
            if key in seen:
                raise ConfigError(f"sweep '{name}': {key} is set by two axes")
            seen.add(key)
    return Sweep(name, combine, axes)


def parse_axis(name: str, raw: Any) -> Axis:
    keys = tuple(k.strip() for k in name.split("+"))
    if "scenario" in keys and len(keys) > 1:
        raise ConfigError(f"axis '{name}': the scenario axis cannot be tied to other keys")
    if isinstance(raw, dict):
        values = grid_values(name, raw)
    elif isinstance(raw, list):
        values = tuple(raw)
    else:
        raise ConfigError(f"axis '{name}' must be a list of values or {{start, stop, num}}, got {raw!r}")
    if not values:
        raise ConfigError(f"axis '{name}' is empty")
    if keys == ("scenario",):
        for v in values:
            if not isinstance(v, str) or v not in SCENARIOS:
                raise ConfigError(f"axis 'scenario': unknown scenario {v!r}; known: {', '.join(SCENARIOS)}")
    else:
        for key in keys:
            for v in values:
                check_value(key, v, where=f"axis '{name}'")
    if len(set(map(repr, values))) != len(values):
        raise ConfigError(f"axis '{name}' repeats a value: {list(values)}")
    return Axis(name, keys, values)


def grid_values(name: str, raw: dict) -> tuple[float, ...]:
    for k in raw:
        if k not in ("start", "stop", "num"):
            raise ConfigError(f"axis '{name}': unknown key '{k}' in the grid; known: start, stop, num")
    if set(raw) != {"start", "stop", "num"}:
        raise ConfigError(f"axis '{name}': a grid needs start, stop and num")
    start, stop = number(f"axis '{name}' start", raw["start"]), number(f"axis '{name}' stop", raw["stop"])
    num = raw["num"]
    if not isinstance(num, int) or isinstance(num, bool) or num < 0:
        raise ConfigError(f"axis '{name}': num must be a whole number >= 0, got {num!r}")
    if num > MAX_CASES:  # before the grid is made
        raise ConfigError(f"axis '{name}': num must be at most {MAX_CASES} (the most cases of a study), got {num}")
    return tuple(round(float(x), 12) for x in np.linspace(start, stop, num))


def check_value(key: str, value: Any, where: str = "") -> None:
    """``key`` is 'section.name' of a real design field and ``value`` has that field's type."""
    at = f"{where}: " if where else ""
    section, _, name = key.partition(".")
    if section not in SECTIONS or not name:
        raise ConfigError(f"{at}unknown key '{key}'; keys are section.name with section one of "
                          f"{', '.join(SECTIONS)} (or 'scenario')")  # fmt: skip
    fields = {f.name: f for f in dataclasses.fields(SECTIONS[section])}
    if name not in fields:
        raise ConfigError(f"{at}unknown key '{key}'; [{section}] has {', '.join(sorted(fields))}")
    default = fields[name].default
    if default is dataclasses.MISSING:
        default = fields[name].default_factory()  # type: ignore[misc]
    if isinstance(default, bool):
        ok = isinstance(value, bool)
        kind = "true or false"
    elif isinstance(default, str):
        ok = isinstance(value, str)
        kind = "a string"
    elif isinstance(default, tuple):
        ok = isinstance(value, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)
        kind = "a list of numbers"
    else:  # float, or None (an optional number)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        kind = "a finite number"
    if not ok:
        raise ConfigError(f"{at}{key} must be {kind}, got {value!r}")


def number(what: str, v: Any) -> float:
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        raise ConfigError(f"{what} must be a finite number, got {v!r}")
    return float(v)


def parse_seeds(v: Any) -> tuple[int, ...]:
    if isinstance(v, int) and not isinstance(v, bool):
        if not 1 <= v <= MAX_CASES:  # before the seeds are made
            raise ConfigError(f"[study] seeds must be 1 .. {MAX_CASES} (the most cases of a study), got {v}")
        return tuple(range(1, v + 1))
    if isinstance(v, list) and v and all(isinstance(s, int) and not isinstance(s, bool) for s in v):
        for s in v:  # the range of balloon-sim --seed
            if not 0 <= s <= MAX_SEED:
                raise ConfigError(f"[study] seeds: a seed must be 0 .. {MAX_SEED}, got {s}")
        if len(set(v)) != len(v):
            raise ConfigError(f"[study] seeds repeats a seed: {v}")
        return tuple(v)
    raise ConfigError(f"[study] seeds must be a count >= 1 or a non-empty list of whole numbers, got {v!r}")


def n_cases(spec: Spec) -> int:
    """How many cases ``spec.cases()`` makes, counted without making them."""
    n_points = 0
    for sw in spec.sweeps:
        sizes = [len(a.values) for a in sw.axes]  # zip: all of one length (parse_sweep); no axes: one point
        n_points += (sizes[0] if sizes else 1) if sw.combine == "zip" else math.prod(sizes)
    return n_points * len(spec.seeds)


def check_size(spec: Spec) -> None:
    n = n_cases(spec)
    if n > MAX_CASES:
        raise ConfigError(f"the study has {n} cases (points x seeds); one run takes at most {MAX_CASES} "
                          "(fewer points or seeds, or the sweeps in several files)")  # fmt: skip


def parse_metrics(v: Any) -> tuple[str, ...]:
    from study.metrics import MAIN

    if v is None:
        return MAIN
    if not isinstance(v, list) or not v or not all(isinstance(m, str) for m in v):
        raise ConfigError(f"[study] metrics must be a non-empty list of names, got {v!r}")
    for m in v:
        if m not in METRICS:
            raise ConfigError(f"unknown metric '{m}'; known: {', '.join(METRICS)}")
    return tuple(dict.fromkeys(v))


# ---------------------------------------------------------------- cases


def points(sw: Sweep) -> list[dict[str, Any]]:
    if not sw.axes:
        return [{}]
    names = [a.name for a in sw.axes]
    if sw.combine == "zip":
        combos = zip(*(a.values for a in sw.axes))
    else:
        combos = itertools.product(*(a.values for a in sw.axes))
    return [dict(zip(names, c)) for c in combos]


def scenario_sections(sc: Scenario) -> dict[str, dict[str, Any]]:
    objs = {**{s: getattr(sc.design, s) for s in DESIGN_SECTIONS}, "wind": sc.wind, "truth": sc.truth,
            "filter": sc.filter}  # fmt: skip
    return {s: {k: jsonable(v) for k, v in dataclasses.asdict(o).items()} for s, o in objs.items()}


def jsonable(v: Any) -> Any:
    if isinstance(v, tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    return v


def resolve_sections(base: str, overrides: dict, point: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Every key of every section for this point: base scenario (or the point's scenario), then the file's
    sections, then the point's axis values."""
    scenario = point.get("scenario", base)
    secs = scenario_sections(SCENARIOS[scenario])
    for s, tab in overrides.items():
        secs[s].update({k: jsonable(v) for k, v in tab.items()})
    for name, value in point.items():
        if name == "scenario":
            continue
        for key in name.split("+"):
            s, _, k = key.strip().partition(".")
            secs[s][k] = jsonable(value)
    return secs


def build(sections: dict[str, dict[str, Any]]) -> tuple[Design, WindConfig, TruthConfig, FilterConfig]:
    """The dataclasses of a resolved case (the programs' own validation)."""
    design = design_from_dict({s: {k: v for k, v in sections[s].items() if v is not None} for s in DESIGN_SECTIONS})
    return (design, WindConfig.from_dict(sections["wind"]), TruthConfig.from_dict(sections["truth"]),
            FilterConfig.from_dict(sections["filter"]))  # fmt: skip


def validate_designs(spec: Spec) -> None:
    for sw in spec.sweeps:
        for point in points(sw):
            try:
                build(resolve_sections(spec.base, spec.overrides, point))
            except LiftError:
                continue  # a result, not a mistake: the case becomes a failed row that quotes the lift balance
            except ConfigError as e:
                where = ", ".join(f"{k} = {v}" for k, v in point.items()) or "the base design"
                raise ConfigError(f"sweep '{sw.name}' at {where}: {e}") from None


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """Hash of the code that computes a case (simulator, estimator, scoring, the case runner): results
    stored by other code are not reused as this code's. Plots, tables and I/O are not part of it."""
    import balloon_core
    import firmware_py
    import sim_hil

    here = Path(__file__).parent
    files = [*sorted(Path(balloon_core.__file__).parent.glob("*.py")),
             *sorted(Path(firmware_py.__file__).parent.rglob("*.py")),
             *sorted(Path(sim_hil.__file__).parent.glob("*.py")),
             here / "case.py", here / "metrics.py", here / "spec.py"]  # fmt: skip
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def case_key(c: Case) -> str:
    """Hash of everything that decides the case's numbers: the full design, seed, duration, scoring start,
    and the code that computes it (``code_fingerprint``)."""
    doc = {"v": METRICS_VERSION, "code": code_fingerprint(), "sections": c.sections, "seed": c.seed,
           "duration_s": c.duration_s,
           "start_s": c.start_s}  # fmt: skip
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:20]
