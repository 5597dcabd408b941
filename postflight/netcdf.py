"""Post-flight products of a ``WindProduct``: NetCDF-4 / CF-1.8 (xarray, engine netcdf4), WMO averages as CSV
and NetCDF, and the reader ``balloon-gs report`` uses for a ``.nc``. Plots: ``product_plot``.

``wind.nc`` holds the estimator-rate series; each averaging period gets its own pair of files beside it,
``wind_avg_1s.nc`` + ``wind_avg_1s.csv`` and ``wind_avg_10min.nc`` + ``wind_avg_10min.csv``. (Not groups of
one file: compliance-checker 6.1's CF-1.8 group check wants every group's ``time`` to be one dimension,
which two periods cannot share, so a file with both groups would fail it.) See docs/usage.md,
"Post-flight products"."""

from __future__ import annotations

import csv
import datetime as dt
import importlib.metadata
import os
import re

import numpy as np

from balloon_core.atomic import Products
from balloon_core.score import direction_from_deg
from firmware_py.estimator.consistency import CONSISTENCY_S, FLAG_NIS
from postflight.averages import AVERAGE_FIELDS, product_averages, speed_direction_sigma
from postflight.product import (
    CONSISTENCY_MASKS,
    CONSISTENCY_MEANINGS,
    FLAG_AFTER_GAP,
    FLAG_NO_BARO,
    FLAG_SEGMENT_START,
    FLAG_SMOOTHED,
    FLAG_WIND_UNKNOWN,
    WindProduct,
)

MODE_VALUES = (0, 1, 2)  # firmware_py.estimator.state MODE_GROUND, MODE_FREE, MODE_TAUT
MODE_MEANINGS = "ground free_ascent taut"
FLAG_MASKS = (FLAG_SMOOTHED, FLAG_SEGMENT_START, FLAG_NO_BARO, FLAG_WIND_UNKNOWN, FLAG_AFTER_GAP)
FLAG_MEANINGS = "smoothed segment_start no_barometer wind_unknown after_data_gap"
AVERAGE_PERIODS_S = {"avg_1s": 1.0, "avg_10min": 600.0}
UTC_UNITS = "seconds since 1970-01-01 00:00:00 UTC"
# CF time units need a reference date and the sensor clock has none: the UNIX epoch stands in for the boot,
# and the attributes say so (time_reference, long_name, comment)
BOOT_UNITS = "seconds since 1970-01-01 00:00:00"
REFERENCES = ("A Numerical Study of Low-cost Wind Velocity Estimation using EKF and Tethered, Spherical Helium "
              "Balloon; WMO-No. 8 (Guide to Instruments and Methods of Observation), Vol. I, Ch. 5")  # fmt: skip
_FLOAT = {"dtype": "float32", "zlib": True, "complevel": 4, "_FillValue": np.float32(np.nan)}


def software_version() -> str:
    try:
        return importlib.metadata.version("balloon-wind")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _check(p: WindProduct) -> int:
    n = len(p.time_s)
    for name, v in p.__dict__.items():
        if isinstance(v, np.ndarray) and v.shape != (n,):
            raise ValueError(f"WindProduct.{name} has shape {v.shape}, expected ({n},)")
    if n > 1 and np.any(np.diff(p.time_s) <= 0):
        raise ValueError("WindProduct.time_s must be strictly increasing")
    return n


def _attr_name(key: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", key)
    return name if name[:1].isalpha() else f"attr_{name}"


def _time_attrs(utc_start_s: float | None) -> dict[str, str]:
    if utc_start_s is not None:
        return {"standard_name": "time", "long_name": "time (UTC)", "units": UTC_UNITS, "calendar": "standard",
                "axis": "T"}  # fmt: skip
    return {"standard_name": "time", "units": BOOT_UNITS, "calendar": "standard", "axis": "T",
            "long_name": "time since the sensor clock's zero (boot), NOT UTC",
            "time_reference": "sensor clock since boot; 1970-01-01 00:00:00 stands for the boot, not a date",
            "comment": "The source log holds no absolute time: read the values as seconds since boot. CF time "
                       "units need a reference date, so the UNIX epoch stands in for the boot."}  # fmt: skip


def _time_values(p: WindProduct, t: np.ndarray) -> np.ndarray:
    return np.asarray(t, float) + (p.utc_start_s if p.utc_start_s is not None else 0.0)


def _as_written(a) -> np.ndarray:
    """A float variable as the file holds it (``_FLOAT``: float32), computed in float64 before: the same values,
    half the memory while a day's product is put together (24 h at 10 Hz: 16 such variables)."""
    return np.asarray(a, float).astype(_FLOAT["dtype"])


def _wind_vars(n, e, sn, se, suffix: str, what: str) -> dict:
    speed = np.hypot(n, e)
    sig_s, sig_d = speed_direction_sigma(n, e, sn, se)
    std = suffix == ""  # only the best (smoothed) estimate carries the standard names: one variable per name

    def var(name, data, units, long, sname, anc=True):
        data = _as_written(data)
        attrs = {"long_name": f"{long}, {what}", "units": units}
        if std and sname:
            attrs["standard_name"] = sname
        if anc:
            attrs["ancillary_variables"] = f"{name}{suffix}_uncertainty" + (" flags" if std else "")
        return f"{name}{suffix}", data, attrs

    def unc(name, data, units, long, sname):
        data = _as_written(data)
        attrs = {"long_name": f"1-sigma uncertainty of the {long}, {what}", "units": units}
        if std:
            attrs["standard_name"] = f"{sname} standard_error"
        return f"{name}{suffix}_uncertainty", data, attrs

    out = [
        var("eastward_wind", e, "m s-1", "eastward wind (air velocity toward east)", "eastward_wind"),
        unc("eastward_wind", se, "m s-1", "eastward wind", "eastward_wind"),
        var("northward_wind", n, "m s-1", "northward wind (air velocity toward north)", "northward_wind"),
        unc("northward_wind", sn, "m s-1", "northward wind", "northward_wind"),
        var("wind_speed", speed, "m s-1", "horizontal wind speed", "wind_speed"),
        unc("wind_speed", sig_s, "m s-1", "wind speed (linear propagation)", "wind_speed"),
        var("wind_from_direction", np.where(speed > 0.0, direction_from_deg(n, e), np.nan), "degree",
            "direction the wind blows from, clockwise from north (north_reference says which), none in still air",
            "wind_from_direction"),
        unc("wind_from_direction", sig_d, "degree", "wind direction (linear propagation, capped at 180)",
            "wind_from_direction"),
    ]  # fmt: skip
    return {name: (data, attrs) for name, data, attrs in out}


def to_dataset(product: WindProduct, history: str | None = None):
    """The root group as an xarray Dataset (times as raw numbers with CF units: the file is exactly this)."""
    import xarray as xr

    p = product
    _check(p)
    t = _time_values(p, p.time_s)
    f = lambda a: np.asarray(a, float)  # noqa: E731
    vars_: dict = {}
    vars_.update(_wind_vars(f(p.wind_n), f(p.wind_e), f(p.sigma_n), f(p.sigma_e), "", "smoothed (zero-lag)"))
    vars_.update(_wind_vars(f(p.causal_n), f(p.causal_e), f(p.causal_sigma_n), f(p.causal_sigma_e), "_causal",
                            "real-time (causal) filter, as WIND_COV carried it"))  # fmt: skip
    boot = p.time_s if p.time_since_boot_s is None else p.time_since_boot_s
    vars_["time_since_boot"] = (f(boot), {"long_name": "time since the sensor clock's zero (boot)", "units": "s"})
    if p.segment is not None:
        vars_["segment"] = (np.asarray(p.segment, np.int16), {
            "long_name": "segment of the log: each its own filter and smoother run (the sensor clock went back, "
                         "a reboot, or jumped, in between)", "units": "1",
            "comment": "time runs on across segments: a segment whose sensor clock starts before the previous one "
                       "ended is shifted to follow it; time_since_boot is the sensor clock"})  # fmt: skip
    vars_["height"] = (_as_written(p.height_m), {"standard_name": "height", "long_name": "height of the balloon "
                                                 "above the tether anchor (ground station)", "units": "m",
                                                 "positive": "up"})  # fmt: skip
    vars_["northward_position"] = (_as_written(p.pos_n), {"long_name": "balloon position north of the tether anchor",
                                                "units": "m"})  # fmt: skip
    vars_["eastward_position"] = (_as_written(p.pos_e), {"long_name": "balloon position east of the tether anchor",
                                               "units": "m"})  # fmt: skip
    vars_["air_pressure"] = (_as_written(p.air_pressure_pa), {"standard_name": "air_pressure", "long_name":
                                                              "air pressure at the balloon (barometer)",
                                                              "units": "Pa"})  # fmt: skip
    vars_["air_temperature"] = (_as_written(p.air_temperature_k), {"standard_name": "air_temperature", "long_name":
                                                         "air temperature at the balloon (thermometer)",
                                                         "units": "K"})  # fmt: skip
    vars_["mode"] = (
        np.asarray(p.mode, np.int8),
        {"long_name": "estimator mode", "flag_values": np.array(MODE_VALUES, np.int8), "flag_meanings": MODE_MEANINGS},
    )
    vars_["flags"] = (np.asarray(p.flags, np.int8), {
        "standard_name": "status_flag", "long_name": "estimator health flags (bit field)",
        "flag_masks": np.array(FLAG_MASKS, np.int8), "flag_meanings": FLAG_MEANINGS})  # fmt: skip
    vars_.update(_consistency_vars(p))
    ds = xr.Dataset({k: (("time",), v, a) for k, (v, a) in vars_.items()},
                    coords={"time": ("time", t, _time_attrs(p.utc_start_s))})  # fmt: skip
    ds.attrs.update(global_attrs(p, history))
    return ds


def _consistency_vars(p: WindProduct) -> dict:
    """The real-time filter's consistency monitor (firmware_py/estimator/consistency.py), when the product
    has it: which aid sources its model did not explain, and the factor it put on the reported accuracy."""
    out: dict = {}
    if p.consistency_flags is not None:
        out["consistency_flags_causal"] = (np.asarray(p.consistency_flags, np.int8), {
            "standard_name": "status_flag",
            "long_name": "aid sources the real-time (causal) filter's model does not explain (bit field)",
            "flag_masks": np.array(CONSISTENCY_MASKS, np.int8), "flag_meanings": CONSISTENCY_MEANINGS,
            "comment": f"A source is flagged while its normalised innovation squared, averaged over "
                       f"{CONSISTENCY_S:g} s, is above {FLAG_NIS:g}: its innovations are {FLAG_NIS**0.5:.1f} times "
                       "or more what the filter expects. The firmware said the same in flight (SYS_STATUS health, "
                       "STATUSTEXT)."})  # fmt: skip
    if p.accuracy_inflation is not None:
        out["accuracy_inflation_causal"] = (_as_written(p.accuracy_inflation), {
            "long_name": "factor on the real-time (causal) filter's horizontal accuracy from its consistency "
                         "monitor", "units": "1",
            "comment": "sqrt of the largest windowed normalised innovation squared (the accelerometer's counted as "
                       "(1 + NIS) / 2), at least 1. WIND_COV's "
                       "horiz_accuracy included it, and so do the *_causal_uncertainty variables (that accuracy) "
                       "and the smoothed *_uncertainty ones (the smoother's model is the filter's)."})  # fmt: skip
    return out


def global_attrs(p: WindProduct, history: str | None = None) -> dict[str, str]:
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    src = p.attrs.get("source_log", "")
    attrs = {
        "Conventions": "CF-1.8",
        "title": "Horizontal wind from a tethered helium balloon (balloon-wind post-flight reprocessing)",
        "institution": p.attrs.get("institution", "not given"),
        "source": "tethered spherical helium balloon with IMU, magnetometer, barometer and thermometer; "
                  "balloon-wind extended Kalman filter with a Rauch-Tung-Striebel smoother",
        "history": f"{now} written by balloon-wind {software_version()}"
                   + (f" from {src}" if src else "") + (f"; {history}" if history else ""),
        "references": REFERENCES,
        "comment": "Winds are the air's velocity (toward); wind_from_direction is meteorological (from). "
                   "Averages by the WMO conventions are in the files *_avg_1s.nc and *_avg_10min.nc beside this one.",
        "software_version": f"balloon-wind {software_version()}",
        "time_reference": "UTC" if p.utc_start_s is not None else "sensor clock (since boot), not UTC",
    }  # fmt: skip
    for k, v in p.attrs.items():
        name = _attr_name(k)
        if name == "history":
            attrs["history"] = f"{v}\n{attrs['history']}"
        elif name not in ("Conventions",):  # a count or a number stays one (NetCDF attributes are typed)
            numeric = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            attrs[name] = v if numeric else str(v)
    return attrs


def _float_encoding(ds, *raw: str) -> dict:
    enc = {k: dict(_FLOAT) for k, v in ds.data_vars.items() if v.dtype.kind == "f" and k not in raw}
    for k in ("time", *raw):
        enc[k] = {"dtype": "float64", "_FillValue": None}
    return enc


def write_netcdf(product: WindProduct, path: str, history: str | None = None) -> None:
    """Write the product as NetCDF-4, CF-1.8.

    ``product.attrs`` become global attributes (expected keys: ``design_toml``, ``source_log``,
    ``source_log_sha256``; any other key is copied too; ``history`` is put before this program's line)."""
    ds = to_dataset(product, history)
    enc = _float_encoding(ds, "time_since_boot")
    for k in ("mode", "flags", "consistency_flags_causal"):
        if k in ds:
            enc[k] = {"dtype": "int8", "zlib": True}
    if "segment" in ds:
        enc["segment"] = {"dtype": "int16", "zlib": True}
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    ds.to_netcdf(path, engine="netcdf4", format="NETCDF4", encoding=enc)


def avg_dataset(product: WindProduct, period_s: float, history: str | None = None):
    """The averages over ``period_s`` as a CF-1.8 Dataset: ``time`` (middle of each period) with ``time_bnds``."""
    import xarray as xr

    a = product_averages(product, period_s)
    t0, t1 = _time_values(product, a["time_start_s"]), _time_values(product, a["time_end_s"])
    tattrs = _time_attrs(product.utc_start_s) | {"bounds": "time_bnds"}
    tattrs["long_name"] = "middle of the averaging period, " + tattrs["long_name"]
    data = {"time_bnds": (("time", "nv"), np.stack([t0, t1], axis=1), {})}
    for key, units, long, sname, cm in AVERAGE_FIELDS:
        attrs = {"long_name": long, "units": units}
        if sname:
            attrs["standard_name"] = sname
        if cm:
            attrs["cell_methods"] = cm if "maximum" in cm else f"{cm} (interval: {_sample_interval(product):g} s)"
        data[key] = (("time",), a[key], attrs)
    ds = xr.Dataset(data, coords={"time": ("time", (t0 + t1) / 2, tattrs)})
    ds.attrs.update(global_attrs(product, history))
    ds.attrs["title"] = f"{period_s:g}-s wind averages by the WMO conventions, {ds.attrs['title']}"
    ds.attrs["averaging_period"] = f"{period_s:g} s"
    ds.attrs["comment"] = ("Averages of the smoothed wind (samples flagged wind_unknown left out) by WMO-No. 8, "
                           "Vol. I, Ch. 5; statistics are NaN where less than half the period has data.")  # fmt: skip
    return ds


def _sample_interval(product: WindProduct) -> float:
    return float(np.median(np.diff(product.time_s))) if len(product.time_s) > 1 else 0.0


def write_averages(product: WindProduct, stem: str, history: str | None = None,
                   products: Products | None = None) -> list[str]:  # fmt: skip
    """``<stem>_avg_1s.{nc,csv}`` and ``<stem>_avg_10min.{nc,csv}``; returns the paths (final names). Each
    under a temporary name, renamed when all are written (or joining ``products``: the caller commits)."""
    if products is None:
        with Products() as own:
            finals = write_averages(product, stem, history, own)
            own.commit()
        return finals
    paths = []
    os.makedirs(os.path.dirname(stem) or ".", exist_ok=True)
    for name, period in AVERAGE_PERIODS_S.items():
        ds = avg_dataset(product, period, history)
        nc, csv_path = f"{stem}_{name}.nc", f"{stem}_{name}.csv"
        ds.to_netcdf(products.path(nc), engine="netcdf4", format="NETCDF4",
                     encoding=_float_encoding(ds, "time_bnds"))  # fmt: skip
        _write_avg_csv(product, product_averages(product, period), products.path(csv_path))
        paths += [nc, csv_path]
    return paths


def _write_avg_csv(product: WindProduct, a: dict[str, np.ndarray], path: str) -> str:
    cols = ["time_start_s", "time_end_s", *(f[0] for f in AVERAGE_FIELDS)]
    utc = product.utc_start_s is not None
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow((["time_start_utc"] if utc else []) + cols)
        for i in range(len(a["time_start_s"])):
            row = [f"{a[c][i]:.3f}" if c.startswith("time_") else f"{a[c][i]:.6g}" for c in cols]
            if utc:
                ts = dt.datetime.fromtimestamp(a["time_start_s"][i] + product.utc_start_s, dt.UTC)
                row = [ts.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z", *row]
            w.writerow(row)
    return path


def product_paths(nc_path: str, plot_path: str | None = None) -> dict[str, str | None]:
    """Every file ``balloon-gs reprocess --out NC_PATH [--plot PLOT_PATH]`` may write, by the option it
    comes from (for ``userargs.check_outputs``: none may be an input or another output): the NetCDF, the
    averages beside it, the winch profile ``<stem>_profile.nc``, the plot and the profile's plot."""
    stem = os.path.splitext(nc_path)[0]
    paths: dict[str, str | None] = {"--out": nc_path}
    for name in AVERAGE_PERIODS_S:
        paths[f"--out (its {name} averages)"] = f"{stem}_{name}.nc"
        paths[f"--out (its {name} averages CSV)"] = f"{stem}_{name}.csv"
    paths["--out (its winch profile)"] = f"{stem}_profile.nc"
    paths["--plot"] = plot_path
    if plot_path:
        base, ext = os.path.splitext(plot_path)
        paths["--plot (the winch profile's)"] = f"{base}_profile{ext}"
    return paths


def write_products(product: WindProduct, nc_path: str, plot_path: str | None = None,
                   history: str | None = None, products: Products | None = None) -> list[str]:  # fmt: skip
    """Everything ``balloon-gs reprocess`` writes: the NetCDF, the averages beside it (``write_averages`` with
    the NetCDF's name less ``.nc`` as stem) and, if asked, the plot. Returns the paths (final names).

    Each file is written under a temporary name beside its final one (balloon_core/atomic.py); all are
    renamed only once every one is complete: an error (or Ctrl-C) on the way leaves none of them, old or
    half-written. With ``products`` given, they join it and the caller commits."""
    if products is None:
        with Products() as own:
            finals = write_products(product, nc_path, plot_path, history, own)
            own.commit()
        return finals
    os.makedirs(os.path.dirname(os.path.abspath(nc_path)), exist_ok=True)
    stem = os.path.splitext(nc_path)[0]
    write_netcdf(product, products.path(nc_path), history)
    finals = [nc_path, *write_averages(product, stem, history, products)]
    if plot_path:
        from postflight.plot import plot_product  # matplotlib only when a plot is asked for

        plot_product(product, products.path(plot_path))
        finals.append(plot_path)
    return finals


def read_netcdf_wind(path: str) -> dict[str, np.ndarray]:
    """The smoothed wind of a product file in the form ``wind.as_arrays`` gives (time since boot,
    wind_n, wind_e, accuracy = sqrt(sigma_n^2 + sigma_e^2) like WIND_COV's horiz_accuracy), in the file's order
    (a product of two boots: the second's time since boot starts again), the samples without a finite time left out
    and a wind that is not a number kept as it is (the reader judges both)."""
    import xarray as xr

    try:
        ds = xr.open_dataset(path, engine="netcdf4", decode_times=False)
    except Exception as exc:  # a missing, truncated or foreign file: one line for the user
        raise ValueError(f"{path}: cannot read as NetCDF ({type(exc).__name__}: {exc})") from None
    with ds:
        need = ("eastward_wind", "northward_wind", "eastward_wind_uncertainty", "northward_wind_uncertainty")
        missing = [v for v in need if v not in ds]
        if missing:
            raise ValueError(f"{path}: not a wind product (no {', '.join(missing)})")
        t = ds["time_since_boot"].values if "time_since_boot" in ds else ds["time"].values
        out = {
            "time_s": np.asarray(t, float),
            "wind_n": ds["northward_wind"].values.astype(float),
            "wind_e": ds["eastward_wind"].values.astype(float),
            "accuracy": np.hypot(ds["northward_wind_uncertainty"].values.astype(float),
                                 ds["eastward_wind_uncertainty"].values.astype(float)),
            "variability": np.full(ds.sizes["time"], np.nan),
            "alt": ds["height"].values.astype(float) if "height" in ds else np.full(ds.sizes["time"], np.nan),
        }  # fmt: skip
    keep = np.isfinite(out["time_s"])
    return {k: v[keep] for k, v in out.items()}
