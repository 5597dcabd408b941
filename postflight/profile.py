"""The wind profile of a winch flight (docs/usage.md, "A field day"): each ascent and descent of the
winch (a leg) binned by height, the power law and the veer fitted over all legs.

A leg is a stretch of the flight where the winch reels one way (``WindProduct.reel_mps`` of one sign
beyond ``REEL_MIN_MPS``) and the line's length changes by at least ``LEG_MIN_M``. In each height bin
(``bin_m``, default 10 m, by the smoothed height) the estimate's samples known to be a wind
(not flagged wind_unknown, taut) are averaged: u, v, their speed and direction. The uncertainty of a
bin's mean is the samples' own, sigma_bin^2 = mean(sigma^2): the smoothed wind's error is the model's
slow error, it does not average down over a bin (measured on the simulated profiles: 0.11 m/s RMS in
10 s bins at 1 m/s and in 40 s bins at 0.25 m/s alike; docs/estimator.md).

The power law u(z) = u_ref (z / z_ref)^alpha is a weighted least-squares line through ln(speed) against
ln(z); the veer the slope of the direction against height (degrees per 100 m, clockwise positive)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from balloon_core.score import direction_from_deg
from postflight.averages import speed_direction_sigma
from postflight.product import FLAG_WIND_UNKNOWN, WindProduct

REEL_MIN_MPS = 0.02  # the winch reels (a leg) above this speed
LEG_MIN_M = 20.0  # a leg changes the length by at least this much
BIN_M = 10.0  # default height bin
BIN_MIN_SAMPLES = 20  # a bin with fewer samples is left empty (NaN)
MODE_TAUT = 2


@dataclass
class Leg:
    start_s: float
    end_s: float
    ascent: bool  # paying out (up) or reeling in (down)
    # per bin (the profile's common height bins): means, their 1-sigma, the samples' time span
    u: np.ndarray
    v: np.ndarray
    sigma_u: np.ndarray
    sigma_v: np.ndarray
    speed: np.ndarray
    sigma_speed: np.ndarray
    direction: np.ndarray
    sigma_direction: np.ndarray
    time_s: np.ndarray  # middle time of the bin's samples
    count: np.ndarray  # samples in the bin


@dataclass
class Profile:
    heights_m: np.ndarray  # bin centres
    bin_m: float
    legs: list[Leg]
    alpha: float  # the fitted power-law exponent
    sigma_alpha: float
    veer_deg_100m: float  # direction change per 100 m (clockwise with height positive)
    sigma_veer_deg_100m: float
    reference_height_m: float  # where the fitted power law's speed is u_ref
    reference_speed_mps: float


def find_legs(time_s: np.ndarray, reel: np.ndarray, length: np.ndarray) -> list[tuple[int, int, bool]]:
    """(first, end, ascent) index ranges where the winch reels one way and the length changes by LEG_MIN_M."""
    sign = np.where(reel > REEL_MIN_MPS, 1, np.where(reel < -REEL_MIN_MPS, -1, 0))
    out = []
    i, n = 0, len(sign)
    while i < n:
        if sign[i] == 0:
            i += 1
            continue
        j = i
        while j < n and sign[j] == sign[i]:
            j += 1
        if abs(length[j - 1] - length[i]) >= LEG_MIN_M:
            out.append((i, j, bool(sign[i] > 0)))
        i = j
    return out


def _bin_leg(p: WindProduct, a: int, b: int, ascent: bool, edges: np.ndarray) -> Leg:
    h = p.height_m[a:b]
    ok = ((p.flags[a:b] & FLAG_WIND_UNKNOWN) == 0) & (p.mode[a:b] == MODE_TAUT) & np.isfinite(h)
    k = len(edges) - 1
    cols = {name: np.full(k, np.nan) for name in ("u", "v", "su", "sv", "t")}
    count = np.zeros(k, int)
    idx = np.digitize(h, edges) - 1
    for j in range(k):
        sel = ok & (idx == j)
        m = int(sel.sum())
        count[j] = m
        if m < BIN_MIN_SAMPLES:
            continue
        cols["u"][j] = p.wind_e[a:b][sel].mean()
        cols["v"][j] = p.wind_n[a:b][sel].mean()
        cols["su"][j] = math.sqrt(np.mean(p.sigma_e[a:b][sel] ** 2))
        cols["sv"][j] = math.sqrt(np.mean(p.sigma_n[a:b][sel] ** 2))
        cols["t"][j] = p.time_s[a:b][sel].mean()
    speed = np.hypot(cols["u"], cols["v"])
    s_speed, s_dir = speed_direction_sigma(cols["v"], cols["u"], cols["sv"], cols["su"])
    return Leg(
        float(p.time_s[a]), float(p.time_s[b - 1]), ascent, cols["u"], cols["v"], cols["su"], cols["sv"], speed,
        np.asarray(s_speed, float), direction_from_deg(cols["v"], cols["u"]), np.asarray(s_dir, float), cols["t"],
        count,
    )  # fmt: skip


def _fit_line(x: np.ndarray, y: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Weighted least squares y = a + b x: (a, b, sigma_b); NaN with fewer than three points."""
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(s) & (s > 0)
    if ok.sum() < 3:
        return math.nan, math.nan, math.nan
    w = 1.0 / s[ok] ** 2
    xm, ym = np.average(x[ok], weights=w), np.average(y[ok], weights=w)
    sxx = np.sum(w * (x[ok] - xm) ** 2)
    b = float(np.sum(w * (x[ok] - xm) * (y[ok] - ym)) / sxx)
    a = float(ym - b * xm)
    # the scatter of the points about the line, when larger than their sigmas say (turbulence)
    chi2 = float(np.sum(w * (y[ok] - a - b * x[ok]) ** 2)) / max(int(ok.sum()) - 2, 1)
    return a, b, math.sqrt(max(chi2, 1.0) / sxx)


def wind_profile(p: WindProduct, bin_m: float = BIN_M) -> Profile | None:
    """The profile of a winch flight; None without winch legs (or a barometer)."""
    if p.reel_mps is None or p.line_length_m is None or not np.any(np.isfinite(p.height_m)):
        return None
    legs_idx = find_legs(p.time_s, np.nan_to_num(p.reel_mps), np.nan_to_num(p.line_length_m))
    if not legs_idx:
        return None
    hmax = max(float(np.nanmax(p.height_m[a:b])) for a, b, _ in legs_idx)
    edges = np.arange(0.0, math.ceil(max(hmax, bin_m) / bin_m) * bin_m + 0.5 * bin_m, bin_m)
    legs = [_bin_leg(p, a, b, up, edges) for a, b, up in legs_idx]
    centres = 0.5 * (edges[:-1] + edges[1:])
    z = np.concatenate([centres] * len(legs))
    speed = np.concatenate([g.speed for g in legs])
    s_speed = np.concatenate([g.sigma_speed for g in legs])
    direction = np.concatenate([g.direction for g in legs])
    s_dir = np.concatenate([g.sigma_direction for g in legs])
    good = np.isfinite(speed) & (speed > 0.1)
    z_ref = float(np.exp(np.mean(np.log(z[good])))) if good.any() else math.nan
    a, alpha, s_alpha = _fit_line(np.log(z[good] / z_ref), np.log(speed[good]), s_speed[good] / speed[good])
    # direction unwrapped about its circular mean before the line
    mean_dir = math.degrees(math.atan2(np.nanmean(np.sin(np.radians(direction))),
                                       np.nanmean(np.cos(np.radians(direction)))))  # fmt: skip
    rel = (direction - mean_dir + 180.0) % 360.0 - 180.0
    _, veer, s_veer = _fit_line(z[good] / 100.0, rel[good], s_dir[good])
    return Profile(centres, bin_m, legs, alpha, s_alpha, veer, s_veer, z_ref, math.exp(a) if a == a else math.nan)


# ------------------------------------------------------------------------------------------ products


def profile_dataset(prof: Profile, p: WindProduct, history: str | None = None):
    """The profile as CF-1.8 discrete sampling geometry, featureType ``profile`` (the orthogonal
    multidimensional representation: every leg on the same height bins), as an xarray Dataset."""
    import xarray as xr

    from postflight.netcdf import _time_attrs, _time_values, global_attrs

    legs = prof.legs
    k = len(legs)
    stack = lambda name: np.stack([getattr(g, name) for g in legs])  # noqa: E731
    t_mid = _time_values(p, np.array([0.5 * (g.start_s + g.end_s) for g in legs]))
    t_attrs = _time_attrs(p.utc_start_s)
    t_attrs["long_name"] = "middle of the leg, " + t_attrs["long_name"]
    dims = ("profile", "z")

    def var(data, units, long, sname=None, anc=None):
        attrs = {"long_name": long, "units": units, "coordinates": "time z"}
        if sname:
            attrs["standard_name"] = sname
        if anc:
            attrs["ancillary_variables"] = anc
        return dims, data, attrs

    def unc(data, units, long, sname):
        return dims, data, {"long_name": f"1-sigma uncertainty of the bin's mean {long}", "units": units,
                            "standard_name": f"{sname} standard_error", "coordinates": "time z"}  # fmt: skip

    data = {
        "eastward_wind": var(stack("u"), "m s-1", "eastward wind, mean over the height bin", "eastward_wind",
                             "eastward_wind_uncertainty"),
        "eastward_wind_uncertainty": unc(stack("sigma_u"), "m s-1", "eastward wind", "eastward_wind"),
        "northward_wind": var(stack("v"), "m s-1", "northward wind, mean over the height bin", "northward_wind",
                              "northward_wind_uncertainty"),
        "northward_wind_uncertainty": unc(stack("sigma_v"), "m s-1", "northward wind", "northward_wind"),
        "wind_speed": var(stack("speed"), "m s-1", "horizontal wind speed of the bin's mean wind", "wind_speed",
                          "wind_speed_uncertainty"),
        "wind_speed_uncertainty": unc(stack("sigma_speed"), "m s-1", "wind speed", "wind_speed"),
        "wind_from_direction": var(stack("direction"), "degree", "direction the bin's mean wind blows from, "
                                   "clockwise from north", "wind_from_direction", "wind_from_direction_uncertainty"),
        "wind_from_direction_uncertainty": unc(stack("sigma_direction"), "degree", "wind direction",
                                               "wind_from_direction"),
        "sample_count": (dims, stack("count").astype(np.int32), {"long_name": "estimates averaged in the bin",
                                                                 "units": "1", "coordinates": "time z"}),
        "leg_direction": (("profile",), np.array([1 if g.ascent else -1 for g in legs], np.int8),
                          {"long_name": "winch leg: 1 ascent (paying out), -1 descent (reeling in)",
                           "flag_values": np.array([-1, 1], np.int8), "flag_meanings": "descent ascent"}),
        "leg_start": (("profile",), _time_values(p, np.array([g.start_s for g in legs])),
                      {"long_name": "start of the leg", "units": t_attrs["units"], "calendar": "standard"}),
        "leg_end": (("profile",), _time_values(p, np.array([g.end_s for g in legs])),
                    {"long_name": "end of the leg", "units": t_attrs["units"], "calendar": "standard"}),
        "power_law_exponent": ((), prof.alpha, {"long_name": "exponent alpha of the power law u(z) = u_ref "
                               "(z / z_ref)^alpha fitted to the speed over all legs", "units": "1"}),
        "power_law_exponent_uncertainty": ((), prof.sigma_alpha, {"long_name": "1-sigma uncertainty of the "
                                           "power-law exponent", "units": "1"}),
        "power_law_reference_height": ((), prof.reference_height_m, {"long_name": "z_ref of the power law",
                                       "units": "m"}),
        "power_law_reference_speed": ((), prof.reference_speed_mps, {"long_name": "u_ref of the power law "
                                      "(the fitted speed at z_ref)", "units": "m s-1"}),
        "wind_veer": ((), prof.veer_deg_100m, {"long_name": "change of the wind's direction with height, "
                      "clockwise positive, fitted over all legs", "units": "degree/(100 m)"}),
        "wind_veer_uncertainty": ((), prof.sigma_veer_deg_100m, {"long_name": "1-sigma uncertainty of the veer",
                                  "units": "degree/(100 m)"}),
    }  # fmt: skip
    coords = {
        "profile": ("profile", np.arange(k, dtype=np.int32), {"long_name": "winch leg number", "cf_role":
                    "profile_id"}),
        "time": ("profile", t_mid, t_attrs),
        "z": ("z", prof.heights_m, {"standard_name": "height", "long_name": "middle of the height bin, above "
              "the tether anchor", "units": "m", "positive": "up", "axis": "Z", "bounds": "z_bnds"}),
    }  # fmt: skip
    data["z_bnds"] = (("z", "nv"), np.stack([prof.heights_m - 0.5 * prof.bin_m, prof.heights_m + 0.5 * prof.bin_m],
                                            axis=1), {})  # fmt: skip
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(global_attrs(p, history))
    ds.attrs["featureType"] = "profile"
    ds.attrs["title"] = f"Wind profiles of the winch legs, {ds.attrs['title']}"
    ds.attrs["comment"] = (f"Each profile is one winch leg (ascent or descent); the smoothed wind averaged in "
                           f"{prof.bin_m:g} m height bins (samples flagged wind_unknown and outside taut flight left "
                           f"out). No horizontal position: the site's, the anchor's.")  # fmt: skip
    return ds


def write_profile(prof: Profile, p: WindProduct, path: str, history: str | None = None) -> None:
    """The profile NetCDF-4 (CF-1.8, featureType profile)."""
    from postflight.netcdf import _float_encoding

    ds = profile_dataset(prof, p, history)
    enc = _float_encoding(ds, "leg_start", "leg_end", "z", "z_bnds")
    for name in ("leg_direction", "sample_count", "profile"):
        enc[name] = {"dtype": ds[name].dtype.name}
    ds.to_netcdf(path, engine="netcdf4", format="NETCDF4", encoding=enc)


def plot_profile(prof: Profile, path: str) -> None:
    """Speed and direction against height, each leg its own colour, with 1-sigma error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_d) = plt.subplots(1, 2, figsize=(9, 6), sharey=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    z = prof.heights_m
    for i, g in enumerate(prof.legs):
        c = colours[i % len(colours)]
        label = f"leg {i} {'up' if g.ascent else 'down'}"
        ax_s.errorbar(g.speed, z, xerr=g.sigma_speed, fmt="o-", color=c, ms=3, capsize=2, label=label)
        ax_d.errorbar(g.direction, z, xerr=g.sigma_direction, fmt="o-", color=c, ms=3, capsize=2, label=label)
    if prof.alpha == prof.alpha:
        have = np.any([np.isfinite(g.speed) for g in prof.legs], axis=0)
        zz = np.linspace(z[have].min(), z[have].max(), 50) if have.any() else z
        ax_s.plot(prof.reference_speed_mps * (zz / prof.reference_height_m) ** prof.alpha, zz, "k--",
                  label=f"power law alpha = {prof.alpha:.3f} +- {prof.sigma_alpha:.3f}")  # fmt: skip
    ax_s.set_xlabel("wind speed [m/s]")
    ax_s.set_ylabel("height above the anchor [m]")
    ax_d.set_xlabel("direction the wind blows from [deg]")
    ax_d.set_title(f"veer {prof.veer_deg_100m:+.1f} +- {prof.sigma_veer_deg_100m:.1f} deg / 100 m", fontsize=10)
    for ax in (ax_s, ax_d):
        ax.grid(alpha=0.3)
    ax_s.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
