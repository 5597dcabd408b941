"""The winch profile product (postflight/profile.py): legs found from the winch, the power law and the
veer recovered from a known profile, the CF-1.8 featureType profile NetCDF and its plot; on a simulated
``profile-fast`` flight, the reprocessed profile against the truth (slow)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from postflight.product import FLAG_SMOOTHED, WindProduct
from postflight.profile import _fit_line, find_legs, plot_profile, wind_profile, write_profile
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
        for name in ("eastward_wind", "northward_wind", "wind_speed", "wind_from_direction"):
            assert ds[name].attrs["standard_name"] == name and ds[name].dims == ("profile", "z")
            assert ds[f"{name}_uncertainty"].attrs["standard_name"] == f"{name} standard_error"
        assert list(ds["leg_direction"].values) == [1, -1]
        assert float(ds["power_law_exponent"]) == pytest.approx(prof.alpha, rel=1e-6)
        assert float(ds["wind_veer"]) == pytest.approx(prof.veer_deg_100m, rel=1e-6)
        np.testing.assert_allclose(ds["wind_speed"].values, np.stack([g.speed for g in prof.legs]), rtol=1e-5)
    png = tmp_path / "flight_profile.png"
    plot_profile(prof, str(png))
    assert png.stat().st_size > 10_000 and math.isfinite(prof.alpha)


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
            if not np.isfinite(g.u[j]) or sel.sum() < 20:
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
    assert 0.6 < math.sqrt(np.mean(np.square(ratio))) < 1.6
    # the truth's bins fitted as the profile fits the estimate's (the same weights)
    z = np.array(tz)
    _, true_alpha, _ = _fit_line(np.log(z / prof.reference_height_m), np.log(np.array(ts)), np.array(sig))
    assert abs(prof.alpha - true_alpha) < 0.03, (prof.alpha, true_alpha)
