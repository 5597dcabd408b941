"""The winch profile product (postflight/profile.py): legs found from the winch, the power law and the
veer recovered from a known profile, the CF-1.8 featureType profile NetCDF and its plot; on a simulated
``profile-fast`` flight, the reprocessed profile against the truth (slow)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from postflight.product import FLAG_SMOOTHED, WindProduct
from postflight.profile import (
    BIN_MIN_SAMPLES,
    MODE_TAUT,
    QC_FEW_SAMPLES,
    QC_INCONSISTENT,
    QC_WINCH_FAST,
    QC_WINCH_REJECTED,
    WINCH_FAST_MPS,
    _fit_line,
    find_legs,
    plot_profile,
    wind_profile,
    write_profile,
)
from tests.system.test_products import cf_failures

ALPHA, VEER_DEG_100M, U_REF, Z_REF = 0.14, 10.0, 3.0, 100.0


def true_wind(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(north, east) of a westerly 3 m/s at 100 m, power law 0.14, veering 10 deg per 100 m."""
    speed = U_REF * (z / Z_REF) ** ALPHA
    frm = np.radians(270.0 + VEER_DEG_100M * (z - Z_REF) / 100.0)
    return -speed * np.cos(frm), -speed * np.sin(frm)


def winch_product(seed: int, noise: float = 0.15) -> WindProduct:
    """10 Hz: 60 s at 30 m, up to 150 m at 0.5 m/s, 20 s, down again; the smoothed wind = the truth plus
    white noise of ``noise`` m/s, its reported 1-sigma ``noise``."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0 + 240.0 + 20.0 + 240.0 + 20.0, 0.1)
    line = np.interp(t, [0, 60, 300, 320, 560, 580], [30, 30, 150, 150, 30, 30])
    reel = np.gradient(line, t)
    h = 0.98 * line
    wn, we = true_wind(h)
    n = len(t)
    wn, we = wn + noise * rng.standard_normal(n), we + noise * rng.standard_normal(n)
    s = np.full(n, noise)
    return WindProduct(
        time_s=t, wind_n=wn, wind_e=we, sigma_n=s, sigma_e=s, causal_n=wn, causal_e=we, causal_sigma_n=s,
        causal_sigma_e=s, height_m=h, pos_n=0.1 * h, pos_e=0.2 * h, air_pressure_pa=101325.0 - 12.0 * h,
        air_temperature_k=288.15 - 0.0065 * h, mode=np.full(n, 2, np.int8), flags=np.full(n, FLAG_SMOOTHED, np.int8),
        line_length_m=line, reel_mps=reel,
    )  # fmt: skip


def test_legs_are_the_winch_reeling_one_way():
    p = winch_product(0)
    legs = find_legs(p.time_s, p.reel_mps, p.line_length_m)
    assert [up for *_, up in legs] == [True, False]
    (a0, b0, _), (a1, b1, _) = legs
    assert p.time_s[a0] == pytest.approx(60.0, abs=0.3) and p.time_s[b0 - 1] == pytest.approx(300.0, abs=0.3)
    assert p.time_s[a1] == pytest.approx(320.0, abs=0.3) and p.time_s[b1 - 1] == pytest.approx(560.0, abs=0.3)
    # no winch: no profile
    p.reel_mps = p.line_length_m = None
    assert wind_profile(p) is None


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_profile_recovers_a_known_power_law_and_veer(seed):
    prof = wind_profile(winch_product(seed))
    assert len(prof.legs) == 2
    assert prof.alpha == pytest.approx(ALPHA, abs=0.01)
    assert prof.veer_deg_100m == pytest.approx(VEER_DEG_100M, abs=1.0)
    # the fit's own sigma says how far it is off (within 3 sigma)
    assert abs(prof.alpha - ALPHA) < 3.0 * prof.sigma_alpha + 1e-3
    for leg in prof.legs:
        full = leg.count >= 50
        tn, te = true_wind(prof.heights_m[full])
        assert np.all(np.abs(leg.v[full] - tn) < 0.1) and np.all(np.abs(leg.u[full] - te) < 0.1)
        assert np.allclose(leg.sigma_u[full], 0.15)  # the samples' own 1-sigma (the error need not average down)


def test_profile_netcdf_is_cf_featuretype_profile_and_plots(tmp_path):
    p = winch_product(4)
    prof = wind_profile(p)
    path = str(tmp_path / "flight_profile.nc")
    write_profile(prof, p, path, "test")
    bad = cf_failures(path)
    assert not bad, bad
    with xr.open_dataset(path, decode_times=False) as ds:
        assert ds.attrs["featureType"] == "profile" and ds.attrs["Conventions"] == "CF-1.8"
        assert ds["profile"].attrs["cf_role"] == "profile_id" and ds.sizes["profile"] == 2
        assert ds["z"].attrs["positive"] == "up" and ds["z"].attrs["units"] == "m"
        assert ds["row_size"].attrs["sample_dimension"] == "obs"
        assert int(ds["row_size"].sum()) == ds.sizes["obs"]
        for name in ("eastward_wind", "northward_wind", "wind_speed", "wind_from_direction"):
            assert ds[name].attrs["standard_name"] == name and ds[name].dims == ("obs",)
            assert ds[f"{name}_uncertainty"].attrs["standard_name"] == f"{name} standard_error"
            anc = ds[name].attrs["ancillary_variables"].split()
            assert {f"{name}_uncertainty", "sample_count", "qc_profile"} <= set(anc)
            assert all(a in ds for a in anc)
        assert "wind_speed_spread" in ds["wind_speed"].attrs["ancillary_variables"].split()
        assert "wind_from_direction_spread" in ds["wind_from_direction"].attrs["ancillary_variables"].split()
        qc = ds["qc_profile"]
        assert qc.dtype == np.int8 and qc.attrs["flag_method"] == "bit"
        assert list(qc.attrs["flag_masks"]) == [1, 2, 4, 8]
        assert qc.attrs["flag_meanings"].split() == ["too_few_samples", "winch_too_fast", "estimate_inconsistent",
                                                      "winch_data_rejected"]  # fmt: skip
        for n in range(1, 5):
            assert qc.attrs[f"bit_{n}_description"]
            assert qc.attrs[f"bit_{n}_assessment"] in ("Bad", "Indeterminate")
        assert qc.attrs["bit_1_assessment"] == "Bad"
        assert list(ds["leg_direction"].values) == [1, -1]
        assert float(ds["power_law_exponent"]) == pytest.approx(prof.alpha, rel=1e-6)
        assert float(ds["wind_veer"]) == pytest.approx(prof.veer_deg_100m, rel=1e-6)
        # the bins with data, leg after leg: the same as the in-memory profile's
        written = [g.count > 0 for g in prof.legs]
        np.testing.assert_allclose(ds["wind_speed"].values, np.concatenate([g.speed[w] for g, w in
                                                                            zip(prof.legs, written)]), rtol=1e-5)
        np.testing.assert_allclose(ds["z"].values, np.concatenate([prof.heights_m[w] for w in written]))
        assert list(ds["row_size"].values) == [int(w.sum()) for w in written]
    png = tmp_path / "flight_profile.png"
    plot_profile(prof, str(png))
    assert png.stat().st_size > 10_000 and math.isfinite(prof.alpha)


def _open(path: str):
    """A written profile, read back: the bins of each leg (dicts of the per-bin variables by leg)."""
    with xr.open_dataset(path, decode_times=False) as ds:
        sizes = ds["row_size"].values.astype(int)
        names = ("z", "sample_count", "wind_speed", "wind_speed_spread", "wind_from_direction_spread",
                 "qc_profile", "reel_speed", "eastward_wind", "northward_wind")  # fmt: skip
        cols = {n: ds[n].values for n in names}
        attrs = dict(ds["qc_profile"].attrs)
    ends = np.cumsum(sizes)
    return [{n: c[e - m : e] for n, c in cols.items()} for m, e in zip(sizes, ends)], attrs


def _used(p: WindProduct, a: float, b: float, lo: float, hi: float) -> np.ndarray:
    """The samples a bin [lo, hi) of the leg from time a to b averages (taut, not wind_unknown)."""
    return ((p.time_s >= a) & (p.time_s <= b) & (p.height_m >= lo) & (p.height_m < hi) & (p.mode == MODE_TAUT))


def test_profile_bins_count_spread_and_quality(tmp_path):
    """Per bin: the samples counted (all the legs' used samples, no more), their spread recomputed from
    the samples, too few samples flagged, empty bins not written, no flag on a clean 0.5 m/s flight."""
    p = winch_product(5)
    # a stretch of the ascent not taut: the bin from 100 to 110 m keeps only a few samples
    a_leg = (p.time_s > 60.0) & (p.time_s < 300.0)
    p.mode[a_leg & (p.height_m >= 100.0) & (p.height_m < 110.0)] = 1
    few_idx = np.flatnonzero(a_leg & (p.height_m >= 100.0) & (p.height_m < 110.0))[:5]
    p.mode[few_idx] = MODE_TAUT
    assert len(few_idx) == 5 < BIN_MIN_SAMPLES
    prof = wind_profile(p)
    path = str(tmp_path / "flight_profile.nc")
    write_profile(prof, p, path, "test")
    assert not cf_failures(path)
    legs, attrs = _open(path)
    assert attrs["flag_method"] == "bit"
    legs_idx = find_legs(p.time_s, p.reel_mps, p.line_length_m)
    total_used = 0
    for leg, g, (a, b, _) in zip(legs, prof.legs, legs_idx):
        assert np.all(leg["sample_count"] > 0)  # an empty bin is not written
        assert np.all(np.isfinite(leg["wind_speed"])) and np.all(np.diff(leg["z"]) > 0)
        empty = prof.heights_m[g.count == 0]
        assert not np.isin(empty, leg["z"]).any() and len(leg["z"]) + len(empty) == len(prof.heights_m)
        t0, t1 = p.time_s[a], p.time_s[b - 1]
        for j, zc in enumerate(leg["z"]):
            sel = _used(p, t0, t1, zc - 5.0, zc + 5.0)
            assert leg["sample_count"][j] == sel.sum()
            speeds = np.hypot(p.wind_n[sel], p.wind_e[sel])
            assert leg["wind_speed_spread"][j] >= 0.0 and leg["wind_from_direction_spread"][j] >= 0.0
            assert leg["wind_speed_spread"][j] == pytest.approx(np.std(speeds), rel=1e-5, abs=1e-6)
            d = np.degrees(np.arctan2(-p.wind_e[sel], -p.wind_n[sel]))
            mean = math.degrees(math.atan2(-p.wind_e[sel].mean(), -p.wind_n[sel].mean()))
            rms = math.sqrt(np.mean(((d - mean + 180.0) % 360.0 - 180.0) ** 2))
            assert leg["wind_from_direction_spread"][j] == pytest.approx(rms, rel=1e-4, abs=1e-4)
            few = bool(leg["sample_count"][j] < BIN_MIN_SAMPLES)
            assert bool(leg["qc_profile"][j] & QC_FEW_SAMPLES) == few
        total_used += int(np.sum((p.time_s >= t0) & (p.time_s <= t1) & (p.mode == MODE_TAUT)))
        # 0.5 m/s, no consistency flags, no winch rejections: nothing else flagged
        assert not np.any(leg["qc_profile"] & (QC_WINCH_FAST | QC_INCONSISTENT | QC_WINCH_REJECTED))
        assert np.all((leg["reel_speed"] > 0.45) & (leg["reel_speed"] <= 0.5 + 1e-6))  # (the leg's ends ramp)
    assert sum(int(leg["sample_count"].sum()) for leg in legs) == total_used
    up = legs[0]
    j = int(np.flatnonzero(up["z"] == 105.0)[0])
    assert up["sample_count"][j] == 5 and up["qc_profile"][j] & QC_FEW_SAMPLES
    # a too-few bin is written but not fitted: the fit is the one without it
    assert prof.alpha == pytest.approx(ALPHA, abs=0.01)


def test_profile_quality_winch_fast_inconsistent_and_rejected(tmp_path):
    """The ascent reeled at 2 m/s from 90 m up sets winch_too_fast on its bins there and nowhere else; the
    consistency monitor's flag during one bin sets estimate_inconsistent there; a WINCH_STATUS rejected
    during the descent sets winch_data_rejected on all its bins, none of the ascent's."""
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 60.0 + 60.0 + 30.0 + 20.0 + 240.0 + 20.0, 0.1)
    knots_t, knots_l = [0, 60, 120, 150, 170, 410, 430], [30, 30, 60, 120, 120, 0, 0]
    line = np.interp(t, knots_t, knots_l)
    line[line < 30] = 30  # the descent stops at 30 m
    n = len(t)
    reel = np.gradient(line, t)
    h = 0.98 * line
    wn, we = true_wind(h)
    wn, we = wn + 0.15 * rng.standard_normal(n), we + 0.15 * rng.standard_normal(n)
    s = np.full(n, 0.15)
    cons = np.zeros(n, np.int8)
    cons[(t > 70.0) & (h >= 40.0) & (h < 50.0) & (reel > 0)] = 1
    rejected = np.zeros(n, np.int32)
    rejected[np.searchsorted(t, 300.0)] = 1
    p = WindProduct(
        time_s=t, wind_n=wn, wind_e=we, sigma_n=s, sigma_e=s, causal_n=wn, causal_e=we, causal_sigma_n=s,
        causal_sigma_e=s, height_m=h, pos_n=0.1 * h, pos_e=0.2 * h, air_pressure_pa=101325.0 - 12.0 * h,
        air_temperature_k=288.15 - 0.0065 * h, mode=np.full(n, 2, np.int8), flags=np.full(n, FLAG_SMOOTHED, np.int8),
        line_length_m=line, reel_mps=reel, consistency_flags=cons, winch_rejected=rejected,
    )  # fmt: skip
    prof = wind_profile(p)
    assert [g.ascent for g in prof.legs] == [True, False]
    path = str(tmp_path / "flight_profile.nc")
    write_profile(prof, p, path, "test")
    assert not cf_failures(path)
    (up, down), _ = _open(path)
    fast_up = up["reel_speed"] > WINCH_FAST_MPS
    assert fast_up.any() and (~fast_up).any()  # 0.5 m/s to 60 m, 2 m/s above
    np.testing.assert_array_equal((up["qc_profile"] & QC_WINCH_FAST) > 0, fast_up)
    assert np.all(up["z"][fast_up] > 60.0) and np.all(up["z"][~fast_up] < 70.0)
    assert not np.any(down["qc_profile"] & QC_WINCH_FAST)  # 0.375 m/s down
    np.testing.assert_array_equal((up["qc_profile"] & QC_INCONSISTENT) > 0, up["z"] == 45.0)
    assert not np.any(down["qc_profile"] & QC_INCONSISTENT)
    assert np.all(down["qc_profile"] & QC_WINCH_REJECTED) and not np.any(up["qc_profile"] & QC_WINCH_REJECTED)
    # a product knowing only the flight's count: every bin indeterminate
    p.winch_rejected = None
    p.attrs["winch_status_rejected"] = 3
    assert all(np.all(g.qc[g.count > 0] & QC_WINCH_REJECTED) for g in wind_profile(p).legs)


def _flight_samples(sim):
    """The simulator's samples as the firmware's input (balloon_core.samples), the winch's with them."""
    from balloon_core.atmosphere import G0
    from balloon_core.samples import BaroSample, ImuSample, WinchSample

    for s in sim.samples():
        if s.baro is not None:
            yield BaroSample(s.time_usec, *s.baro)
        yield ImuSample(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if s.winch is not None:
            length, speed, kg, status = s.winch
            yield WinchSample(s.time_usec, length, speed, kg * G0, status)


@pytest.mark.slow
def test_profile_fast_flight_against_the_truth():
    """profile-fast (1 m/s, 30-150-30 m), reprocessed: each leg's bins within 0.3 m/s and 5 deg RMS of
    the truth's wind at the balloon in the same bins of the true height, the reported 1-sigma honest,
    the fitted exponent within 0.03 of the one the truth's own bins give (at 1 m/s a bin is 10 s of a
    turbulent wind: the atmosphere's own profile over the legs is not the mean's 0.14)."""
    from postflight.reprocess import reprocess
    from sim_hil.scenarios import SCENARIOS
    from sim_hil.simulator import TRUTH_COLUMNS, Simulation

    sc = SCENARIOS["profile-fast"]
    sim = Simulation(sc.design, sc.wind, sc.truth, sc.winch.times_s[-1] + 5.0, 3, winch=sc.winch)
    product = reprocess(_flight_samples(sim), sc.design, sc.filter)
    prof = wind_profile(product)
    assert prof is not None and [g.ascent for g in prof.legs] == [True, False]
    col = {c: i for i, c in enumerate(TRUTH_COLUMNS)}
    tr = sim.truth
    half = 0.5 * prof.bin_m
    du, dv, ratio, tz, ts, sig = [], [], [], [], [], []
    for g in prof.legs:
        leg = (tr[:, col["time_s"]] >= g.start_s) & (tr[:, col["time_s"]] <= g.end_s)
        for j, zc in enumerate(prof.heights_m):
            sel = leg & (np.abs(tr[:, col["height_m"]] - zc) <= half)
            if not np.isfinite(g.u[j]) or g.count[j] < BIN_MIN_SAMPLES or sel.sum() < 20:
                continue
            te, tn = tr[sel, col["wind_e"]].mean(), tr[sel, col["wind_n"]].mean()
            du.append(math.hypot(g.u[j], g.v[j]) - math.hypot(te, tn))
            d = math.degrees(math.atan2(-g.u[j], -g.v[j]) - math.atan2(-te, -tn))
            dv.append((d + 180.0) % 360.0 - 180.0)
            ratio += [(g.u[j] - te) / g.sigma_u[j], (g.v[j] - tn) / g.sigma_v[j]]
            tz.append(zc)
            ts.append(math.hypot(te, tn))
            sig.append(g.sigma_speed[j] / math.hypot(g.u[j], g.v[j]))
    assert len(du) >= 16  # most of 30-150 m, both legs
    assert math.sqrt(np.mean(np.square(du))) < 0.3
    assert math.sqrt(np.mean(np.square(dv))) < 5.0
    # cautious (0.4 here): a bin's 1-sigma carries the drag scale's stated 7 % (test_estimator)
    assert 0.35 < math.sqrt(np.mean(np.square(ratio))) < 1.6
    # the truth's bins fitted as the profile fits the estimate's (the same weights)
    z = np.array(tz)
    _, true_alpha, _ = _fit_line(np.log(z / prof.reference_height_m), np.log(np.array(ts)), np.array(sig))
    assert abs(prof.alpha - true_alpha) < 0.03, (prof.alpha, true_alpha)
