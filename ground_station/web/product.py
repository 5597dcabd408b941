"""A reprocessed product (``balloon-gs reprocess``'s NetCDF, postflight/netcdf.py) as the page draws it:
the causal (real-time) and smoothed wind's speed and direction with their 1-sigma uncertainties, and the
winch legs' profiles when ``<stem>_profile.nc`` lies beside it. Read once, at start; no I/O after."""

from __future__ import annotations

import math
import os

import numpy as np

from balloon_core import userargs
from postflight.profile import QC_FEW_SAMPLES

MAX_POINTS = 4000  # the series are thinned to at most this many points (a long flight at 10 Hz is 36 000 an hour)
SERIES = {  # the page's key: the product's variable
    "speed": "wind_speed", "speed_err": "wind_speed_uncertainty",
    "from": "wind_from_direction", "from_err": "wind_from_direction_uncertainty",
    "causal_speed": "wind_speed_causal", "causal_speed_err": "wind_speed_causal_uncertainty",
    "causal_from": "wind_from_direction_causal", "causal_from_err": "wind_from_direction_causal_uncertainty",
}  # fmt: skip
PROFILE_VARS = {"speed": "wind_speed", "speed_err": "wind_speed_uncertainty", "from": "wind_from_direction",
                "from_err": "wind_from_direction_uncertainty"}  # fmt: skip


def profile_path(path: str) -> str:
    """The profile product beside a product: ``<stem>_profile.nc``."""
    stem, _ = os.path.splitext(path)
    return f"{stem}_profile.nc"


def _values(a, digits: int = 3) -> list[float | None]:
    return [round(float(x), digits) if math.isfinite(x) else None for x in np.asarray(a, float).ravel()]


def time_is_utc(attrs) -> bool:
    """Is a product's time axis UTC? Its CF units say so (``seconds since 1970-01-01 00:00:00 UTC``, as reprocess writes
    a log with GPS time); a sensor clock's (units without UTC, its long_name / time_reference saying "NOT UTC" and
    "since boot") is seconds since the boot, whatever date its units name."""
    units = str(attrs.get("units", "")).upper()
    said = " ".join(str(attrs.get(k, "")) for k in ("long_name", "time_reference")).upper()
    return "UTC" in units and "NOT UTC" not in said and "BOOT" not in said


def _check_series(ds, path: str) -> None:
    """A UserError unless ``time`` is the one dimension of the time coordinate and of every series, all numbers."""
    for var in ("time", *SERIES.values(), *(["height"] if "height" in ds else [])):
        a = ds[var]
        if a.dims != ("time",):
            dims = ", ".join(map(str, a.dims)) or "none: a scalar"
            raise userargs.UserError(f"{path}: not a balloon-gs reprocess product ({var} is not a series along a "
                                     f"time dimension; its dimensions: {dims})")  # fmt: skip
        if not np.issubdtype(a.dtype, np.number):
            raise userargs.UserError(f"{path}: not a balloon-gs reprocess product ({var} holds {a.dtype}, not numbers)")


def load_product(path: str) -> dict:
    """The product's series (thinned to ``MAX_POINTS``) and profiles as a JSON-able dict; a UserError
    (one line) if it is not a balloon-wind product."""
    userargs.require_extra("postflight")
    import xarray as xr

    try:
        ds = xr.open_dataset(path, engine="netcdf4", decode_times=False)
    except (OSError, ValueError) as exc:
        raise userargs.UserError(f"{path}: not a NetCDF product ({' '.join(str(exc).split())})") from None
    with ds:
        missing = [v for v in SERIES.values() if v not in ds]
        if missing or "time" not in ds:
            raise userargs.UserError(f"{path}: not a balloon-gs reprocess product (no {(missing or ['time'])[0]})")
        _check_series(ds, path)
        n = ds.sizes["time"]
        step = max(1, math.ceil(n / MAX_POINTS))
        out: dict = {"name": os.path.basename(path), "utc": time_is_utc(ds["time"].attrs), "points": n, "step": step,
                     "title": str(ds.attrs.get("title", "")), "history": str(ds.attrs.get("history", "")),
                     "time": _values(ds["time"].values[::step], 3)}  # fmt: skip
        for key, var in SERIES.items():
            out[key] = _values(ds[var].values[::step])
        if "height" in ds:
            out["height"] = _values(ds["height"].values[::step], 1)
    prof = profile_path(path)
    out["profile"] = load_profile(prof) if os.path.exists(prof) else None
    return out


def load_profile(path: str) -> dict:
    """Each leg of a ``<stem>_profile.nc``: ascent or descent, and per height bin with data its speed and
    direction with their 1-sigma uncertainties."""
    import xarray as xr

    try:
        ds = xr.open_dataset(path, engine="netcdf4", decode_times=False)
    except (OSError, ValueError) as exc:
        raise userargs.UserError(f"{path}: not a NetCDF profile ({' '.join(str(exc).split())})") from None
    with ds:
        try:
            return _profile_legs(ds, path)
        except (KeyError, IndexError, ValueError) as exc:
            raise userargs.UserError(f"{path}: not a balloon-gs reprocess profile (no {exc})") from None


def _profile_legs(ds, path: str) -> dict:
    """The legs of an open profile dataset (KeyError if a variable is missing): a contiguous ragged
    array, ``row_size`` bins of each leg in turn (only bins with data are written)."""
    z = np.asarray(ds["z"].values, float)
    cols = {key: np.asarray(ds[var].values, float) for key, var in PROFILE_VARS.items()}
    count = np.asarray(ds["sample_count"].values, int)
    qc = np.asarray(ds["qc_profile"].values, int) if "qc_profile" in ds else np.zeros(len(z), int)
    up = np.asarray(ds["leg_direction"].values) > 0
    sizes = np.asarray(ds["row_size"].values, int)
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    legs = []
    for k in range(ds.sizes["profile"]):
        rows = []
        for j in range(starts[k], starts[k] + sizes[k]):
            if qc[j] & QC_FEW_SAMPLES:  # too few samples for a mean worth drawing: left out
                continue
            vals = {key: _values(c[j : j + 1])[0] for key, c in cols.items()}
            rows.append({"z": round(float(z[j]), 1), **vals, "count": int(count[j]), "qc": int(qc[j])})
        legs.append({"ascent": bool(up[k]), "rows": rows})
    bin_m = float(ds["z_bnds"].values[0, 1] - ds["z_bnds"].values[0, 0]) if z.size else math.nan
    return {"name": os.path.basename(path), "bin_m": _values([bin_m], 1)[0], "legs": legs}
