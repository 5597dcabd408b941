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
# a bin with fewer samples is flagged (QC_FEW_SAMPLES) and left out of the power-law and veer fits: 20
# samples are 2 s of the 10 Hz product; a 10 m bin crossed at the tethersonde practice's 0.5-1 m/s holds
# 100-200, so fewer means a bin only grazed (the top of a leg) or mostly not taut / wind_unknown
BIN_MIN_SAMPLES = 20
# the reel speed (m/s, mean |reel| over the bin's samples) above which a bin is flagged QC_WINCH_FAST:
# tethersonde practice reels 0.5-1 m/s; faster, a 10 m bin is under 10 s of a turbulent wind
WINCH_FAST_MPS = 1.0
MODE_TAUT = 2

# bits of the profile's ``qc_profile`` (CF flag_masks, flag_method "bit"; ARM style bit_N_description)
QC_FEW_SAMPLES = 1  # fewer than BIN_MIN_SAMPLES samples in the bin
QC_WINCH_FAST = 2  # the winch reeled faster than WINCH_FAST_MPS during the bin
QC_INCONSISTENT = 4  # the real-time filter's consistency monitor flagged a source during the bin
QC_WINCH_REJECTED = 8  # WINCH_STATUS records were rejected as implausible during the leg
QC_BITS = (
    (QC_FEW_SAMPLES, "too_few_samples", "Bad",
     f"fewer than {BIN_MIN_SAMPLES} estimates in the bin: its mean is left out of the power-law and veer fits"),
    (QC_WINCH_FAST, "winch_too_fast", "Indeterminate",
     f"the winch reeled faster than {WINCH_FAST_MPS:g} m/s (mean |reel speed| over the bin's estimates)"),
    (QC_INCONSISTENT, "estimate_inconsistent", "Indeterminate",
     "the real-time filter's consistency monitor flagged an aid source (consistency_flags_causal non-zero) "
     "at one or more of the bin's estimates"),
    (QC_WINCH_REJECTED, "winch_data_rejected", "Indeterminate",
     "WINCH_STATUS records were rejected as implausible during the leg (during the flight, when the product "
     "does not say when)"),
)  # fmt: skip


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
    # per bin: the samples' own spread (population standard deviation) of the speed, m/s, and of the
    # direction about the bin's mean direction, degree; NaN in an empty bin
    speed_spread: np.ndarray
    direction_spread: np.ndarray
    reel_mps: np.ndarray  # mean |reel speed| over the bin's samples, m/s (NaN: empty or not known)
    qc: np.ndarray  # QC_* bits per bin (0 in an empty bin: empty bins are not written)


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
    cols = {name: np.full(k, np.nan) for name in ("u", "v", "su", "sv", "t", "ss", "sd", "reel")}
    count = np.zeros(k, int)
    qc = np.zeros(k, np.int8)
    idx = np.digitize(h, edges) - 1
    we, wn = p.wind_e[a:b], p.wind_n[a:b]
    reel = None if p.reel_mps is None else np.abs(p.reel_mps[a:b])
    cons = None if p.consistency_flags is None else p.consistency_flags[a:b]
    rejected = _winch_rejected(p, a, b)
    for j in range(k):
        sel = ok & (idx == j)
        m = int(sel.sum())
        count[j] = m
        if m == 0:
            continue
        u, v = float(we[sel].mean()), float(wn[sel].mean())
        cols["u"][j], cols["v"][j] = u, v
        cols["su"][j] = math.sqrt(np.mean(p.sigma_e[a:b][sel] ** 2))
        cols["sv"][j] = math.sqrt(np.mean(p.sigma_n[a:b][sel] ** 2))
        cols["t"][j] = p.time_s[a:b][sel].mean()
        cols["ss"][j], cols["sd"][j] = bin_spread(wn[sel], we[sel])
        if reel is not None and np.any(np.isfinite(reel[sel])):
            cols["reel"][j] = float(np.nanmean(reel[sel]))
        qc[j] = (QC_FEW_SAMPLES * (m < BIN_MIN_SAMPLES) | QC_WINCH_FAST * bool(cols["reel"][j] > WINCH_FAST_MPS)
                 | QC_INCONSISTENT * bool(cons is not None and np.any(cons[sel] != 0))
                 | QC_WINCH_REJECTED * rejected)  # fmt: skip
    speed = np.hypot(cols["u"], cols["v"])
    s_speed, s_dir = speed_direction_sigma(cols["v"], cols["u"], cols["sv"], cols["su"])
    return Leg(
        float(p.time_s[a]), float(p.time_s[b - 1]), ascent, cols["u"], cols["v"], cols["su"], cols["sv"], speed,
        np.asarray(s_speed, float), direction_from_deg(cols["v"], cols["u"]), np.asarray(s_dir, float), cols["t"],
        count, cols["ss"], cols["sd"], cols["reel"], qc,
    )  # fmt: skip


def bin_spread(wind_n: np.ndarray, wind_e: np.ndarray) -> tuple[float, float]:
    """The spread of a bin's samples: the population standard deviation of their speeds (m/s) and the RMS
    of their directions' differences from the direction of the bin's mean wind (degree, wrapped to
    +-180)."""
    speed_spread = float(np.std(np.hypot(wind_n, wind_e)))
    mean_dir = direction_from_deg(np.mean(wind_n), np.mean(wind_e))
    d = (direction_from_deg(wind_n, wind_e) - mean_dir + 180.0) % 360.0 - 180.0
    return speed_spread, float(np.sqrt(np.mean(np.square(d))))


def _winch_rejected(p: WindProduct, a: int, b: int) -> bool:
    """WINCH_STATUS rejected during the samples a:b (``WindProduct.winch_rejected``); a product that only
    says how many in the whole flight (the ``winch_status_rejected`` attribute): any in the flight."""
    if p.winch_rejected is not None:
        return bool(np.any(p.winch_rejected[a:b] > 0))
    try:
        return int(p.attrs.get("winch_status_rejected", 0)) > 0
    except ValueError:
        return False


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
    enough = np.concatenate([g.count >= BIN_MIN_SAMPLES for g in legs])
    good = np.isfinite(speed) & (speed > 0.1) & enough
    z_ref = float(np.exp(np.mean(np.log(z[good])))) if good.any() else math.nan
    a, alpha, s_alpha = _fit_line(np.log(z[good] / z_ref), np.log(speed[good]), s_speed[good] / speed[good])
    # direction unwrapped about its circular mean before the line
    mean_dir = math.degrees(math.atan2(np.nanmean(np.sin(np.radians(direction[good]))),
                                       np.nanmean(np.cos(np.radians(direction[good])))))  # fmt: skip
    rel = (direction - mean_dir + 180.0) % 360.0 - 180.0
    _, veer, s_veer = _fit_line(z[good] / 100.0, rel[good], s_dir[good])
    return Profile(centres, bin_m, legs, alpha, s_alpha, veer, s_veer, z_ref, math.exp(a) if a == a else math.nan)


# ------------------------------------------------------------------------------------------ products


def profile_dataset(prof: Profile, p: WindProduct, history: str | None = None):
    """The profile as CF-1.8 discrete sampling geometry, featureType ``profile``, as an xarray Dataset:
    the contiguous ragged array representation (CF-1.8 9.3.3), each leg's bins with data one after the
    other along ``obs`` (``row_size`` of them per leg, upward in height); a bin without a sample is not
    written. Per bin: the means, their 1-sigma, the samples' count and spread, the reel speed and the
    ``qc_profile`` bits (QC_*)."""
    import xarray as xr

    from postflight.netcdf import _time_attrs, _time_values, global_attrs

    legs = prof.legs
    k = len(legs)
    rows = [np.flatnonzero(g.count > 0) for g in legs]
    cat = lambda name: np.concatenate([getattr(g, name)[r] for g, r in zip(legs, rows)])  # noqa: E731
    z = np.concatenate([prof.heights_m[r] for r in rows])
    t_mid = _time_values(p, np.array([0.5 * (g.start_s + g.end_s) for g in legs]))
    t_attrs = _time_attrs(p.utc_start_s)
    t_attrs["long_name"] = "middle of the leg, " + t_attrs["long_name"]
    dims = ("obs",)
    anc_common = "sample_count qc_profile"

    def var(data, units, long, sname, anc):
        attrs = {"long_name": long, "units": units, "coordinates": "time z", "standard_name": sname,
                 "ancillary_variables": f"{anc} {anc_common}"}  # fmt: skip
        return dims, data, attrs

    def unc(data, units, long, sname):
        return dims, data, {"long_name": f"1-sigma uncertainty of the bin's mean {long}", "units": units,
                            "standard_name": f"{sname} standard_error", "coordinates": "time z"}  # fmt: skip

    qc_attrs = {
        "long_name": "quality of the bin's mean wind (bit field)", "coordinates": "time z",
        "flag_masks": np.array([m for m, *_ in QC_BITS], np.int8),
        "flag_meanings": " ".join(name for _, name, *_ in QC_BITS), "flag_method": "bit",
        "comment": "0: none of the tests failed. A bin is written only when it holds at least one estimate.",
    }  # fmt: skip
    for n, (_, _, assessment, description) in enumerate(QC_BITS, 1):
        qc_attrs[f"bit_{n}_description"] = description
        qc_attrs[f"bit_{n}_assessment"] = assessment
    data = {
        "row_size": (("profile",), np.array([len(r) for r in rows], np.int32),
                     {"long_name": "number of height bins with data in the leg", "sample_dimension": "obs"}),
        "eastward_wind": var(cat("u"), "m s-1", "eastward wind, mean over the height bin", "eastward_wind",
                             "eastward_wind_uncertainty"),
        "eastward_wind_uncertainty": unc(cat("sigma_u"), "m s-1", "eastward wind", "eastward_wind"),
        "northward_wind": var(cat("v"), "m s-1", "northward wind, mean over the height bin", "northward_wind",
                              "northward_wind_uncertainty"),
        "northward_wind_uncertainty": unc(cat("sigma_v"), "m s-1", "northward wind", "northward_wind"),
        "wind_speed": var(cat("speed"), "m s-1", "horizontal wind speed of the bin's mean wind", "wind_speed",
                          "wind_speed_uncertainty wind_speed_spread"),
        "wind_speed_uncertainty": unc(cat("sigma_speed"), "m s-1", "wind speed", "wind_speed"),
        "wind_speed_spread": (dims, cat("speed_spread"), {
            "long_name": "standard deviation of the speeds of the bin's estimates (population, about their mean)",
            "units": "m s-1", "coordinates": "time z"}),
        "wind_from_direction": var(cat("direction"), "degree", "direction the bin's mean wind blows from, "
                                   "clockwise from north", "wind_from_direction",
                                   "wind_from_direction_uncertainty wind_from_direction_spread"),
        "wind_from_direction_uncertainty": unc(cat("sigma_direction"), "degree", "wind direction",
                                               "wind_from_direction"),
        "wind_from_direction_spread": (dims, cat("direction_spread"), {
            "long_name": "RMS difference of the directions of the bin's estimates from the direction of the "
                         "bin's mean wind (wrapped to +-180 degree)", "units": "degree", "coordinates": "time z"}),
        "sample_count": (dims, cat("count").astype(np.int32), {"long_name": "estimates averaged in the bin",
                                                               "units": "1", "coordinates": "time z"}),
        "reel_speed": (dims, cat("reel_mps"), {
            "long_name": "winch reel speed during the bin: mean of its magnitude over the bin's estimates",
            "units": "m s-1", "coordinates": "time z"}),
        "qc_profile": (dims, cat("qc").astype(np.int8), qc_attrs),
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
        "profile": ("profile", np.arange(k, dtype=np.int32), {"long_name": "winch leg number", "units": "1",
                    "cf_role": "profile_id"}),
        "time": ("profile", t_mid, t_attrs),
        "z": ("obs", z, {"standard_name": "height", "long_name": "middle of the height bin, above "
              "the tether anchor", "units": "m", "positive": "up", "axis": "Z", "bounds": "z_bnds"}),
    }  # fmt: skip
    data["z_bnds"] = (("obs", "nv"), np.stack([z - 0.5 * prof.bin_m, z + 0.5 * prof.bin_m], axis=1), {})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(global_attrs(p, history))
    ds.attrs["featureType"] = "profile"
    ds.attrs["title"] = f"Wind profiles of the winch legs, {ds.attrs['title']}"
    ds.attrs["comment"] = (f"Each profile is one winch leg (ascent or descent); the smoothed wind averaged in "
                           f"{prof.bin_m:g} m height bins (samples flagged wind_unknown and outside taut flight left "
                           f"out), stored as a contiguous ragged array: row_size bins of each leg in turn along obs, "
                           f"only bins holding an estimate. qc_profile flags each bin. No horizontal position: the "
                           f"site's, the anchor's.")  # fmt: skip
    ds.attrs["height_bin"] = f"{prof.bin_m:g} m"
    return ds


def write_profile(prof: Profile, p: WindProduct, path: str, history: str | None = None) -> None:
    """The profile NetCDF-4 (CF-1.8, featureType profile)."""
    from postflight.netcdf import _float_encoding

    ds = profile_dataset(prof, p, history)
    enc = _float_encoding(ds, "leg_start", "leg_end", "z", "z_bnds")
    for name in ("leg_direction", "sample_count", "profile", "row_size", "qc_profile"):
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
        few = g.count < BIN_MIN_SAMPLES  # flagged too_few_samples: not drawn (nor fitted)
        speed, direction = np.where(few, np.nan, g.speed), np.where(few, np.nan, g.direction)
        ax_s.errorbar(speed, z, xerr=g.sigma_speed, fmt="o-", color=c, ms=3, capsize=2, label=label)
        ax_d.errorbar(direction, z, xerr=g.sigma_direction, fmt="o-", color=c, ms=3, capsize=2, label=label)
    if prof.alpha == prof.alpha:
        have = np.any([np.isfinite(g.speed) & (g.count >= BIN_MIN_SAMPLES) for g in prof.legs], axis=0)
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
