"""Post-flight products: the CF-1.8 NetCDF (round trip + compliance check), WMO averages, the plot, and
``balloon-gs report`` on a .nc."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
import xarray as xr

from balloon_core.score import direction_from_deg
from postflight.averages import (
    YAMARTINO_K,
    speed_direction_sigma,
    wind_averages,
)
from postflight.netcdf import read_netcdf_wind, write_netcdf, write_products
from postflight.product import FLAG_SEGMENT_START, FLAG_SMOOTHED, FLAG_WIND_UNKNOWN, WindProduct

UTC0 = 1_700_000_000.0  # 2023-11-14T22:13:20Z


def make_product(n: int = 6000, utc: float | None = UTC0, seed: int = 0) -> WindProduct:
    """10 Hz synthetic flight: 5 s on the ground (wind unknown), free ascent, then taut."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    wn = -3.0 + 0.5 * np.sin(2 * np.pi * 0.01 * t) + 0.2 * rng.standard_normal(n)
    we = -1.0 + 0.5 * np.cos(2 * np.pi * 0.02 * t) + 0.2 * rng.standard_normal(n)
    mode = np.where(t < 5, 0, np.where(t < 20, 1, 2)).astype(np.int8)
    flags = np.where(mode == 0, FLAG_WIND_UNKNOWN, FLAG_SMOOTHED).astype(np.int8)
    flags[min(200, n - 1)] |= FLAG_SEGMENT_START
    h = np.where(mode == 0, 0.0, np.minimum(t * 5, 90.0))
    wn[:3] = np.nan  # before the filter started
    we[:3] = np.nan
    # the consistency monitor: the accelerometer flagged from 30 s, the tether alignment too from 40 s to 50 s
    cons = np.where(t >= 30, 1, 0) | np.where((t >= 40) & (t < 50), 2, 0)
    inflation = np.where(cons != 0, 1.5 + 0.5 * (cons == 3), 1.0 + 0.1 * (t >= 20))
    return WindProduct(
        time_s=t, wind_n=wn, wind_e=we, sigma_n=np.full(n, 0.3), sigma_e=np.full(n, 0.4),
        causal_n=wn + 0.1, causal_e=we - 0.1, causal_sigma_n=np.full(n, 0.5), causal_sigma_e=np.full(n, 0.6),
        height_m=h, pos_n=-0.3 * h, pos_e=-0.1 * h, air_pressure_pa=101325.0 - 12.0 * h,
        air_temperature_k=288.15 - 0.0065 * h, mode=mode, flags=flags, consistency_flags=cons.astype(np.int8),
        accuracy_inflation=inflation, utc_start_s=utc,
        attrs={"design_toml": "[balloon]\nradius_m = 1.0\n", "source_log": "flight.ulg",
               "source_log_sha256": "ab" * 32},
    )  # fmt: skip


def cf_failures(path: str) -> list[tuple[int, str, list[str]]]:
    """compliance-checker's CF-1.8 results that did not fully pass: (weight 3 high / 2 medium / 1 low, name, msgs).
    Offline: with no ``standard_name_vocabulary`` it uses its packaged standard-name table."""
    from compliance_checker.cf.cf_1_8 import CF1_8Check
    from compliance_checker.suite import CheckSuite

    cs = CheckSuite()
    cs.checkers = {"cf:1.8": CF1_8Check}  # only this one (loading all imports deprecated IOOS checkers)
    results, errors = cs.run_all(cs.load_dataset(path), ["cf:1.8"], skip_checks=[])["cf:1.8"]
    assert not errors, errors
    bad = []
    for r in results:
        v = r.value
        if not (v[0] == v[1] if isinstance(v, tuple) else bool(v)):
            bad.append((r.weight, r.name, r.msgs))
    return bad


# ---------------------------------------------------------------- NetCDF


@pytest.mark.parametrize("utc", [UTC0, None], ids=["utc", "sensor-clock"])
def test_netcdf_round_trip_and_cf_check(tmp_path, utc):
    p = make_product(utc=utc)
    path = str(tmp_path / "wind.nc")
    write_netcdf(p, path)
    with xr.open_dataset(path) as ds:
        # values (float32 on disk), NaN kept
        np.testing.assert_allclose(ds["northward_wind"].values, p.wind_n, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(ds["eastward_wind"].values, p.wind_e, rtol=1e-6, atol=1e-6)
        assert np.isnan(ds["eastward_wind"].values[:3]).all()
        np.testing.assert_allclose(ds["eastward_wind_uncertainty"].values, 0.4, rtol=1e-6)
        np.testing.assert_allclose(ds["northward_wind_causal"].values, p.causal_n, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(ds["air_pressure"].values, p.air_pressure_pa, rtol=1e-6)
        np.testing.assert_allclose(ds["time_since_boot"].values, p.time_s)
        spd = np.hypot(p.wind_n, p.wind_e)
        np.testing.assert_allclose(ds["wind_speed"].values, spd, rtol=1e-5)
        np.testing.assert_allclose(ds["wind_from_direction"].values, direction_from_deg(p.wind_n, p.wind_e),
                                   rtol=1e-5)  # fmt: skip
        assert ds["mode"].dtype == np.int8 and (ds["mode"].values == p.mode).all()
        assert (ds["flags"].values == p.flags).all()
        # time: UTC datetimes, or the sensor clock said to be not UTC
        t = ds["time"].values
        assert t.dtype.kind == "M"
        t_s = (t - np.datetime64("1970-01-01T00:00:00")) / np.timedelta64(1, "ns") * 1e-9
        np.testing.assert_allclose(t_s, p.time_s + (utc or 0.0), atol=1e-3)
        if utc is None:
            assert "NOT UTC" in ds["time"].attrs["long_name"]
            assert ds.attrs["time_reference"].startswith("sensor clock")
        else:
            assert ds["time"].encoding["units"].startswith("seconds since 1970-01-01")
        # names and units
        expect = {"eastward_wind": ("eastward_wind", "m s-1"), "northward_wind": ("northward_wind", "m s-1"),
                  "wind_speed": ("wind_speed", "m s-1"), "wind_from_direction": ("wind_from_direction", "degree"),
                  "eastward_wind_uncertainty": ("eastward_wind standard_error", "m s-1"),
                  "northward_wind_uncertainty": ("northward_wind standard_error", "m s-1"),
                  "wind_speed_uncertainty": ("wind_speed standard_error", "m s-1"),
                  "wind_from_direction_uncertainty": ("wind_from_direction standard_error", "degree"),
                  "height": ("height", "m"), "air_pressure": ("air_pressure", "Pa"),
                  "air_temperature": ("air_temperature", "K")}  # fmt: skip
        for name, (sname, units) in expect.items():
            assert (ds[name].attrs["standard_name"], ds[name].attrs["units"]) == (sname, units), name
        assert ds["height"].attrs["positive"] == "up"
        # only the smoothed estimate carries the standard names: selecting by standard_name is unambiguous
        assert "standard_name" not in ds["eastward_wind_causal"].attrs
        assert sum(v.attrs.get("standard_name") == "eastward_wind" for v in ds.data_vars.values()) == 1
        # CF flags
        assert list(ds["mode"].attrs["flag_values"]) == [0, 1, 2]
        assert ds["mode"].attrs["flag_meanings"].split() == ["ground", "free_ascent", "taut"]
        assert list(ds["flags"].attrs["flag_masks"]) == [1, 2, 4, 8, 16]
        assert len(ds["flags"].attrs["flag_meanings"].split()) == 5
        # the causal filter's consistency monitor: its flags (CF flag masks) and its accuracy factor
        cf = ds["consistency_flags_causal"]
        assert cf.dtype == np.int8 and (cf.values == p.consistency_flags).all()
        assert cf.attrs["standard_name"] == "status_flag"
        assert list(cf.attrs["flag_masks"]) == [1, 2, 4, 8, 16, 32]
        assert cf.attrs["flag_meanings"].split() == [
            f"{n}_misfit" for n in ("accel", "align", "radius", "baro", "mag", "force")
        ]
        assert int(np.count_nonzero(cf.values & 2)) == 100  # 40-50 s at 10 Hz
        np.testing.assert_allclose(ds["accuracy_inflation_causal"].values, p.accuracy_inflation, rtol=1e-6)
        assert ds["accuracy_inflation_causal"].attrs["units"] == "1"
        # global attributes
        a = ds.attrs
        assert a["Conventions"] == "CF-1.8"
        assert a["design_toml"] == p.attrs["design_toml"]
        assert a["source_log"] == "flight.ulg" and a["source_log_sha256"] == "ab" * 32
        assert a["software_version"].startswith("balloon-wind ")
        for k in ("title", "institution", "source", "history", "references"):
            assert a[k]
    bad = cf_failures(path)
    assert not bad, bad  # no failure at any priority (high, medium or low)


def test_a_product_without_the_consistency_monitor_has_no_such_variables(tmp_path):
    p = make_product(n=300)
    p.consistency_flags = p.accuracy_inflation = None  # a product built elsewhere
    path = str(tmp_path / "wind.nc")
    write_netcdf(p, path)
    with xr.open_dataset(path) as ds:
        assert "consistency_flags_causal" not in ds and "accuracy_inflation_causal" not in ds
        assert (ds["flags"].values == p.flags).all()


def test_speed_and_direction_uncertainty_by_linear_propagation():
    # wind toward north at 5 m/s: speed error is the N error, direction error the E error over the speed
    s, d = speed_direction_sigma(np.array([5.0]), np.array([0.0]), np.array([0.3]), np.array([0.4]))
    assert s[0] == pytest.approx(0.3) and d[0] == pytest.approx(math.degrees(0.4 / 5.0))
    # against Monte Carlo at 45 deg
    rng = np.random.default_rng(1)
    n0, e0, sn, se = 3.0, 3.0, 0.05, 0.1
    n, e = n0 + sn * rng.standard_normal(200_000), e0 + se * rng.standard_normal(200_000)
    s, d = speed_direction_sigma(np.array([n0]), np.array([e0]), np.array([sn]), np.array([se]))
    assert s[0] == pytest.approx(np.std(np.hypot(n, e)), rel=0.02)
    assert d[0] == pytest.approx(np.std(direction_from_deg(n, e)), rel=0.02)
    # low-speed guard: no infinities, direction unknown
    s, d = speed_direction_sigma(np.array([0.0, 1e-4]), np.array([0.0, 0.0]), np.array([0.3, 0.3]),
                                 np.array([0.4, 0.4]))  # fmt: skip
    assert np.all(np.isfinite(s)) and s[0] == pytest.approx(0.4)
    assert list(d) == [180.0, 180.0]


def test_direction_is_where_the_wind_blows_from():
    # air moving toward north comes from the south; toward east, from the west
    assert direction_from_deg(np.array([1.0, 0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0, -1.0])).tolist() == [
        180.0, 270.0, 0.0, 90.0]  # fmt: skip


def test_reader_rejects_a_file_that_is_not_a_product(tmp_path):
    bad = tmp_path / "x.nc"
    bad.write_bytes(b"not netcdf at all")
    with pytest.raises(ValueError, match="cannot read as NetCDF"):
        read_netcdf_wind(str(bad))
    other = tmp_path / "other.nc"
    xr.Dataset({"foo": ("time", np.arange(3.0))}).to_netcdf(other)
    with pytest.raises(ValueError, match="not a wind product"):
        read_netcdf_wind(str(other))


# ---------------------------------------------------------------- averages


def _grid(seconds: float, hz: float = 10.0) -> np.ndarray:
    return np.arange(int(seconds * hz)) / hz


def test_constant_wind_has_zero_spread_and_gust_equals_mean():
    t = _grid(1200)
    n, e = np.full(t.size, -2.0), np.full(t.size, -3.0)
    a = wind_averages(t, n, e, 600.0)
    assert len(a["time_start_s"]) == 2
    sp = math.hypot(2.0, 3.0)
    np.testing.assert_allclose(a["scalar_mean_wind_speed"], sp)
    np.testing.assert_allclose(a["vector_mean_wind_speed"], sp)
    np.testing.assert_allclose(a["wind_speed_of_gust"], sp)
    for k in ("wind_speed_std", "eastward_wind_std", "northward_wind_std", "turbulence_intensity"):
        np.testing.assert_allclose(a[k], 0.0, atol=1e-12)
    np.testing.assert_allclose(a["wind_from_direction_std"], 0.0, atol=1e-5)
    np.testing.assert_allclose(a["vector_mean_wind_from_direction"], direction_from_deg(-2.0, -3.0))
    np.testing.assert_allclose(a["valid_fraction"], 1.0)


def test_reversing_wind_has_zero_vector_mean_but_positive_scalar_mean():
    t = _grid(600)
    n = np.where((t // 60) % 2 == 0, 4.0, -4.0)  # a minute north, a minute south
    a = wind_averages(t, n, np.zeros(t.size), 600.0)
    assert a["scalar_mean_wind_speed"][0] == pytest.approx(4.0)
    assert a["vector_mean_wind_speed"][0] == pytest.approx(0.0, abs=1e-12)
    assert a["northward_wind_std"][0] == pytest.approx(4.0)
    assert a["wind_speed_std"][0] == pytest.approx(0.0, abs=1e-12)


def test_gust_is_the_highest_3s_running_mean():
    t = _grid(600)
    s = np.full(t.size, 2.0)
    s[(t >= 100) & (t < 103)] = 6.0  # a 3-s gust: its 3-s mean is 6
    s[(t >= 300) & (t < 301)] = 9.0  # a 1-s spike: its 3-s mean is only 2 + 7/3
    a = wind_averages(t, s, np.zeros(t.size), 600.0)
    assert a["wind_speed_of_gust"][0] == pytest.approx(6.0)
    s[(t >= 100) & (t < 103)] = 2.0
    a = wind_averages(t, s, np.zeros(t.size), 600.0)
    assert a["wind_speed_of_gust"][0] == pytest.approx(2.0 + 7.0 / 3.0)
    # 1-s periods cannot hold a 3-s window; 10-s ones find the gust in their own period only
    assert np.isnan(wind_averages(t, s, np.zeros(t.size), 1.0)["wind_speed_of_gust"]).all()
    a10 = wind_averages(t, s, np.zeros(t.size), 10.0)
    assert a10["wind_speed_of_gust"][30] == pytest.approx(2.0 + 7.0 / 3.0)
    assert a10["wind_speed_of_gust"][29] == pytest.approx(2.0)


def test_direction_std_of_a_symmetric_alternation_is_yamartino():
    t = _grid(600)
    theta = 10.0
    d = np.radians(np.where(np.arange(t.size) % 2 == 0, 250.0 - theta, 250.0 + theta))  # from WSW
    n, e = -3.0 * np.cos(d), -3.0 * np.sin(d)
    a = wind_averages(t, n, e, 600.0)
    eps = math.sin(math.radians(theta))
    assert a["wind_from_direction_std"][0] == pytest.approx(math.degrees(math.asin(eps) * (1 + YAMARTINO_K * eps**3)))
    assert a["wind_from_direction_std"][0] == pytest.approx(theta, rel=0.01)  # the true std of ±theta
    assert a["vector_mean_wind_from_direction"][0] == pytest.approx(250.0)
    assert a["vector_mean_wind_speed"][0] == pytest.approx(3.0 * math.cos(math.radians(theta)))
    assert a["scalar_mean_wind_speed"][0] == pytest.approx(3.0)


def test_periods_align_to_the_clock_and_sparse_periods_are_blank():
    t = 0.1 * np.arange(1, 9000)  # starts 0.1 s after boot
    n = np.full(t.size, 3.0)
    n[(t > 650) & (t < 1150)] = np.nan  # 2nd period less than half covered
    a = wind_averages(t, n, np.zeros(t.size), 600.0, clock_offset_s=UTC0 + 30.0)  # boot at xx:13:50 UTC
    np.testing.assert_allclose((a["time_start_s"] + UTC0 + 30.0) % 600.0, 0.0, atol=1e-3)
    assert a["time_start_s"][0] == pytest.approx(-230.0, abs=1e-3)
    assert a["valid_fraction"][1] < 0.5 and np.isnan(a["scalar_mean_wind_speed"][1])
    assert a["scalar_mean_wind_speed"][0] == pytest.approx(3.0)
    assert a["turbulence_intensity"][0] == pytest.approx(0.0)


def test_turbulence_intensity_is_speed_std_over_mean():
    t = _grid(600)
    s = 5.0 + np.where(np.arange(t.size) % 2 == 0, 1.0, -1.0)
    a = wind_averages(t, s, np.zeros(t.size), 600.0)
    assert a["turbulence_intensity"][0] == pytest.approx(1.0 / 5.0)


def test_write_products_writes_the_averages_as_csv_and_cf_netcdf(tmp_path):
    p = make_product(n=14000)
    paths = write_products(p, str(tmp_path / "wind.nc"))
    assert sorted(x.rsplit("/", 1)[1] for x in paths) == sorted(
        ["wind.nc", "wind_avg_1s.nc", "wind_avg_1s.csv", "wind_avg_10min.nc", "wind_avg_10min.csv"])  # fmt: skip
    with open(tmp_path / "wind_avg_10min.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    with xr.open_dataset(tmp_path / "wind_avg_10min.nc") as ds:
        assert ds.sizes["time"] == len(rows) == 3  # 22:10, 22:20, 22:30 (the flight is 22:13:20 - 22:36:40)
        assert rows[0]["time_start_utc"] == "2023-11-14T22:10:00.000Z"
        np.testing.assert_allclose(ds["scalar_mean_wind_speed"].values,
                                   [float(r["scalar_mean_wind_speed"]) for r in rows], rtol=1e-5)  # fmt: skip
        assert ds["wind_speed_of_gust"].attrs["standard_name"] == "wind_speed_of_gust"
        assert ds["time"].attrs["bounds"] == "time_bnds"
        # the ground samples (wind unknown) are not averaged in
        assert int(rows[0]["n_samples"]) == np.sum((p.time_s < 400) & (p.time_s >= 5) & np.isfinite(p.wind_n))
        assert ds["n_samples"].dtype.kind == "i"  # a count, written as one (CSV "123", not "123.0")
    with xr.open_dataset(tmp_path / "wind_avg_1s.nc") as ds:
        i = 100  # one 1-s period well inside the flight
        sel = p.time_s >= ds["time_bnds"].values[i, 0].astype("datetime64[ms]").astype(float) / 1e3 - UTC0 - 1e-6
        sel &= p.time_s < ds["time_bnds"].values[i, 1].astype("datetime64[ms]").astype(float) / 1e3 - UTC0 - 1e-6
        assert sel.sum() == 10
        assert float(ds["northward_wind"].values[i]) == pytest.approx(np.mean(p.wind_n[sel]), rel=1e-5)
    for name in ("wind_avg_1s.nc", "wind_avg_10min.nc"):
        bad = cf_failures(str(tmp_path / name))
        assert not bad, (name, bad)


# ---------------------------------------------------------------- plot


@pytest.mark.slow
def test_plot_writes_a_png(tmp_path):
    from postflight.plot import plot_product

    path = tmp_path / "wind.png"
    plot_product(make_product(n=3000), str(path))
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


# ---------------------------------------------------------------- report


@pytest.mark.slow
def test_report_scores_a_netcdf_like_the_csv_of_the_same_wind(tmp_path, capsys):
    from ground_station.cli import main
    from ground_station.report import report
    from ground_station.wind import CSV_COLUMNS, WindRecord

    p = make_product(n=6000)
    nc = str(tmp_path / "wind.nc")
    write_netcdf(p, nc)
    ok = np.isfinite(p.wind_n)
    acc = np.hypot(p.sigma_n, p.sigma_e)
    with open(tmp_path / "wind.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for i in np.flatnonzero(ok):
            w.writerow(WindRecord(round(p.time_s[i] * 1e6), 1, 1, p.wind_n[i], p.wind_e[i], math.nan, math.nan,
                                  math.nan, p.height_m[i], acc[i], 0.0).csv_row())  # fmt: skip
    rng = np.random.default_rng(5)
    truth = tmp_path / "truth.csv"
    tt = np.arange(60000) * 0.01
    np.savetxt(truth, np.c_[tt, np.interp(tt, p.time_s[ok], p.wind_n[ok]) + 0.2 * rng.standard_normal(tt.size),
                            np.interp(tt, p.time_s[ok], p.wind_e[ok]) + 0.2 * rng.standard_normal(tt.size)],
               delimiter=",", header="time_s,wind_n,wind_e", comments="")  # fmt: skip
    s_nc = report(nc, str(truth))
    s_csv = report(str(tmp_path / "wind.csv"), str(truth))
    assert s_nc.duration_s == pytest.approx(s_csv.duration_s)
    for k in ("band_rmse_mps", "raw_rmse_mps", "mean_accuracy_mps", "error_ratio", "est_speed_mps"):
        assert getattr(s_nc, k) == pytest.approx(getattr(s_csv, k), rel=1e-3), k
    assert s_nc.mean_accuracy_mps == pytest.approx(0.5)  # sqrt(0.3^2 + 0.4^2)
    # the command line: 0 and a score on a product, 2 and one line on a file that is not one
    assert main(["report", nc, "--truth", str(truth), "--plot", str(tmp_path / "r.png")]) == 0
    assert "band RMSE" in capsys.readouterr().out
    (tmp_path / "bad.nc").write_text("nope")
    assert main(["report", str(tmp_path / "bad.nc"), "--truth", str(truth)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.nc" in err
