"""Weather (the ground pressure and temperature drifting from boot) and the accelerometer bias walk in
the sensor models (docs/model.md, "Weather and wandering biases").

The expectations are written here from the physics (hypsometric equation, barometric formula, a random
walk's variance), with the test's own constants, not taken from the code under test."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from balloon_core import atmosphere
from balloon_core.config import SCHEMA, ConfigError, Design, SensorsConfig, design_from_dict, lift_balance
from balloon_core.rotation import imu_mount, imu_to_body, rotation
from sim_hil import cli as sim_cli
from sim_hil.dynamics import BalloonPhysics, TruthConfig, density_at
from sim_hil.sensors import SensorSuite

R_DRY = 287.05  # J/(kg K)
GRAVITY = 9.80665  # m/s^2
LAPSE = 0.0065  # K/m
P_BOOT = 101325.0  # the default site: 1013.25 hPa, 20 C
T_BOOT = 293.15
IMU_HZ = 100.0
NOISELESS = dataclasses.replace(
    Design(), sensors=SensorsConfig(accel_mps2=0.0, baro_m=0.0, gyro_dps=0.0, mag_gauss=0.0, thermometer_k=0.0)
)


def barometric_pa(height_m: float, ground_pa: float, ground_k: float) -> float:
    """ISA pressure at a height above a ground with this pressure and temperature (constant lapse)."""
    return ground_pa * (1.0 - LAPSE * height_m / ground_k) ** (GRAVITY / (R_DRY * LAPSE))


def line_fit(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """(slope, intercept, standard error of the slope) of a least-squares line."""
    slope, intercept = np.polyfit(t, y, 1)
    resid = y - (slope * t + intercept)
    se = math.sqrt(resid.var(ddof=2) / np.sum((t - t.mean()) ** 2))
    return float(slope), float(intercept), se


# ---------------------------------------------------------------- weather


@pytest.mark.parametrize("height_m", [0.0, 100.0])
def test_falling_barometer_lifts_the_apparent_height_by_the_hypsometric_amount(height_m):
    """-2 hPa/h at the ground, the balloon held at a fixed height for an hour: the baro's apparent height
    (hypsometric, against the boot ground pressure) rises by (R T_m / g) ln(p0 / (p0 - 2 hPa)) ~ 16.9 m,
    and the pressure falls at -2 hPa/h times the barometric p(h)/p0 (the whole column scales with p0)."""
    s = SensorSuite(Design(), TruthConfig(pressure_drift_hpa_h=-2.0), IMU_HZ, seed=11)
    times = np.arange(0.0, 3600.0 + 0.5, 1.0)
    hpa = np.array([s.baro(height_m, float(t))[0] for t in times])

    t_mean = T_BOOT - LAPSE * height_m / 2.0  # the layer's mean temperature
    apparent = R_DRY * t_mean / GRAVITY * np.log(P_BOOT / (hpa * 100.0))
    expected_rise = R_DRY * t_mean / GRAVITY * math.log(P_BOOT / (P_BOOT - 200.0))
    assert 16.0 < expected_rise < 17.5
    rate, start, se = line_fit(times, apparent)
    # the hypsometric height is ln of a linear pressure: 2 cm of curvature over the hour, below 1 SE
    assert rate * 3600.0 == pytest.approx(expected_rise, abs=5.0 * se * 3600.0 + 0.02)
    assert start == pytest.approx(height_m, abs=0.2)

    slope, _, se_p = line_fit(times / 3600.0, hpa)
    expected_slope = -2.0 * barometric_pa(height_m, P_BOOT, T_BOOT) / P_BOOT
    assert slope == pytest.approx(expected_slope, abs=5.0 * se_p)
    assert se_p < 0.01  # the test can tell -2 hPa/h from -1.98 (the factor p(h)/p0 at 100 m)


def test_warming_ground_drives_the_thermometer_and_the_pressure_aloft():
    """+3 K/h: the thermometer at 100 m reads T0 + 3 K/h t - L h; the pressure at a fixed height rises
    slightly (a warmer column is lighter: p(h) = p0 (1 - L h / T0(t))^(g / R L)), ground pressure held."""
    h = 100.0
    s = SensorSuite(Design(), TruthConfig(temperature_drift_k_h=3.0), IMU_HZ, seed=12)
    times = np.arange(0.0, 3600.0 + 0.5, 1.0)
    readings = np.array([s.baro(h, float(t)) for t in times])
    temp_c, hpa = readings[:, 1], readings[:, 0]

    slope, start, se = line_fit(times / 3600.0, temp_c)
    assert slope == pytest.approx(3.0, abs=5.0 * se)
    assert start == pytest.approx(T_BOOT - 273.15 - LAPSE * h, abs=0.05)

    expected = np.array([barometric_pa(h, P_BOOT, T_BOOT + 3.0 * t / 3600.0) for t in times]) / 100.0
    rise = (expected[-1] - expected[0]) * 100.0
    assert 10.0 < rise < 15.0  # Pa over the hour: ~1 m of apparent height
    slope, _, se = line_fit(times / 3600.0, hpa - expected)
    assert abs(slope) < 5.0 * se
    assert abs(np.mean(hpa - expected)) < 5.0 * np.std(hpa - expected) / math.sqrt(len(times))


def test_ground_conditions_are_linear_from_boot():
    p, t = atmosphere.ground_conditions(P_BOOT, T_BOOT, -2.0, 1.5, 0.0)
    assert (p, t) == (P_BOOT, T_BOOT)
    p, t = atmosphere.ground_conditions(P_BOOT, T_BOOT, -2.0, 1.5, 5400.0)
    assert p == pytest.approx(P_BOOT - 300.0, abs=1e-9)
    assert t == pytest.approx(T_BOOT + 2.25, abs=1e-12)


@pytest.mark.parametrize("altitude_m", [-400.0, 1500.0, 3000.0])
def test_a_site_above_the_sea_flies_in_its_own_thinner_air(altitude_m):
    """A site's altitude without its ground pressure: the simulator's barometer reads the standard atmosphere's
    pressure there (1013.25 hPa and 15 C at the sea, 6.5 K/km, 845.6 hPa at 1500 m), not the sea's, and the balloon
    carries what that air lifts: the reference balloon, with a fifth of its buoyancy to spare at the sea, carries its
    rope at 1500 m and not at 3000 m. A ground pressure given is the site's whatever its altitude."""
    high = dataclasses.replace(NOISELESS, site=dataclasses.replace(NOISELESS.site, altitude_amsl_m=altitude_m))
    expected = 101325.0 * (1.0 - LAPSE * altitude_m / 288.15) ** (GRAVITY / (R_DRY * LAPSE))
    assert SensorSuite(high, TruthConfig(), IMU_HZ, seed=3).baro(0.0, 0.0)[0] == pytest.approx(expected / 100.0)
    assert lift_balance(high)[0] == pytest.approx(lift_balance(NOISELESS)[0] * expected / P_BOOT)
    air = density_at(BalloonPhysics.from_design(high, TruthConfig()), 0.0)  # what the truth's balloon flies in
    assert air == pytest.approx(expected / (R_DRY * T_BOOT))
    net_at_sea = lift_balance(NOISELESS)[-1]
    assert net_at_sea > 0.2 * lift_balance(NOISELESS)[0]
    if altitude_m == 1500.0:
        assert 845.0 < expected / 100.0 < 846.0 and lift_balance(high)[-1] > 0.0
    if altitude_m == 3000.0:
        assert lift_balance(high)[-1] < 0.0
        with pytest.raises(ConfigError, match="cannot lift its tether.*the air: 701.1 hPa at 20 C"):
            design_from_dict({"site": {"altitude_amsl_m": altitude_m}})
    given = dataclasses.replace(high, site=dataclasses.replace(high.site, ground_pressure_hpa=990.0))
    assert SensorSuite(given, TruthConfig(), IMU_HZ, seed=3).baro(0.0, 0.0)[0] == pytest.approx(990.0)


def test_weather_beyond_any_site_is_refused():
    lo_pa, hi_pa = atmosphere.GROUND_PRESSURE_RANGE_PA
    lo_k, hi_k = atmosphere.GROUND_TEMPERATURE_RANGE_K
    site = SCHEMA["site"]
    assert (lo_pa / 100.0, hi_pa / 100.0) == (site["ground_pressure_hpa"].lo, site["ground_pressure_hpa"].hi)
    assert (lo_k - 273.15, hi_k - 273.15) == pytest.approx(
        (site["ground_temperature_c"].lo, site["ground_temperature_c"].hi)
    )
    with pytest.raises(ValueError, match="pressure_drift_hpa_h"):
        atmosphere.ground_conditions(P_BOOT, T_BOOT, -50.0, 0.0, 16 * 3600.0)  # 213 hPa
    with pytest.raises(ValueError, match="temperature_drift_k_h"):
        atmosphere.ground_conditions(P_BOOT, T_BOOT, 0.0, 20.0, 3 * 3600.0)  # 80 C
    for key, bad in (
        ("pressure_drift_hpa_h", 60.0),
        ("temperature_drift_k_h", -25.0),
        ("accel_bias_walk_mps2_rt_s", 2.0),
    ):
        with pytest.raises(ConfigError, match=key):
            TruthConfig.from_dict({key: bad})


def test_balloon_sim_refuses_a_flight_whose_weather_leaves_any_site(tmp_path, capsys):
    cfg = tmp_path / "front.toml"
    cfg.write_text("[truth]\npressure_drift_hpa_h = -50.0\n")
    out = tmp_path / "never.tlog"
    assert sim_cli.main(["--duration", str(16 * 3600), "--config", str(cfg), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pressure_drift_hpa_h" in err
    assert not out.exists()


# ---------------------------------------------------------------- accelerometer bias walk


def chi2_bounds(dof: int, z: float = 4.0) -> tuple[float, float]:
    """Wilson-Hilferty: chi2(dof) / dof lies within these at +-z sigma."""
    a = 2.0 / (9.0 * dof)
    return (1.0 - a - z * math.sqrt(a)) ** 3, (1.0 - a + z * math.sqrt(a)) ** 3


def test_accel_bias_walk_variance_grows_linearly_with_time():
    """Var(b(T)) = walk^2 T: checked at T1 = 1 s and on the independent increment b(T2) - b(T1) over
    the next 2 s, over 400 seeds x 3 axes (chi-square with 1200 degrees of freedom each: +-16 %); the
    axes, and the gyro's walk, uncorrelated."""
    walk = 0.002
    n1, n2 = int(1 * IMU_HZ), int(3 * IMU_HZ)
    truth = TruthConfig(accel_bias_walk_mps2_rt_s=walk, gyro_bias_walk_dps_rt_s=0.01)  # both on: own columns
    f, omega, q = (0.0, 0.0, -GRAVITY), (0.0, 0.0, 0.0), [1.0, 0.0, 0.0, 0.0]
    b1, b2, g1 = [], [], []
    for seed in range(400):
        s = SensorSuite(Design(), truth, IMU_HZ, seed)
        for k in range(n2):
            if k == n1:
                b1.append(s.accel_bias)
                g1.append(s.gyro_bias)
            s.imu(f, omega, q)
        b2.append(s.accel_bias)
    axes = np.corrcoef(np.array(b1).T, np.array(g1).T)  # the three axes and the gyro's wander independently
    assert np.max(np.abs(axes - np.eye(6))) < 4.0 / math.sqrt(len(b1))
    b1, b2 = np.array(b1).ravel(), np.array(b2).ravel()
    lo, hi = chi2_bounds(b1.size)
    assert lo < np.sum(b1**2) / (walk**2 * n1 / IMU_HZ) / b1.size < hi
    assert lo < np.sum((b2 - b1) ** 2) / (walk**2 * (n2 - n1) / IMU_HZ) / b1.size < hi
    assert abs(np.corrcoef(b1, b2 - b1)[0, 1]) < 4.0 / math.sqrt(b1.size)  # independent increments


def test_the_accelerometer_reads_the_wandering_bias():
    """Noiseless sensors: every reading is the truth plus the bias the walk has reached."""
    s = SensorSuite(NOISELESS, TruthConfig(accel_bias_walk_mps2_rt_s=0.01), IMU_HZ, seed=3)
    f, omega, q = (0.3, -0.2, -GRAVITY), (0.01, 0.02, -0.03), [0.9, 0.1, -0.2, 0.3]
    n = math.sqrt(sum(x * x for x in q))
    q = [x / n for x in q]
    rt = np.array(rotation(*q)).reshape(3, 3)  # row-major R (body -> NED)
    truth_b = rt.T @ np.array(f)
    moved = 0.0
    for _ in range(1000):
        bias = s.accel_bias
        acc, _, _ = s.imu(f, omega, q)
        assert np.allclose(np.array(acc) - truth_b, bias, rtol=0.0, atol=1e-12)
        moved = max(moved, max(abs(b) for b in s.accel_bias))
    assert moved > 1e-3  # it did wander (1-sigma after 10 s: 0.03 m/s^2)


def test_an_imu_mounted_askew_reads_in_its_own_axes():
    """[truth] imu_roll_deg, imu_pitch_deg: noiseless readings are the body's turned into the IMU's axes (its z then
    sees gravity tilted by the mounting), the same rotation for the rate and the field; the firmware's turn back
    (rotation.imu_to_body) gives the body's readings again; and its errors are the IMU's own (added after)."""
    f, omega, q = (0.3, -0.2, -GRAVITY), (0.01, 0.02, -0.03), [1.0, 0.0, 0.0, 0.0]
    body = SensorSuite(NOISELESS, TruthConfig(), IMU_HZ, seed=3).imu(f, omega, q)
    askew = SensorSuite(NOISELESS, TruthConfig(imu_roll_deg=2.0, imu_pitch_deg=-1.0), IMU_HZ, seed=3)
    acc, gyro, mag = askew.imu(f, omega, q)
    m = imu_mount(2.0, -1.0)
    for read, true in zip((acc, gyro, mag), body, strict=True):
        assert np.linalg.norm(read) == pytest.approx(np.linalg.norm(true), rel=1e-12)  # a rotation
        assert imu_to_body(m, *read) == pytest.approx(true, abs=1e-12)
    level = SensorSuite(NOISELESS, TruthConfig(imu_pitch_deg=3.0), IMU_HZ, seed=3).imu((0.0, 0.0, -GRAVITY), omega, q)
    assert math.degrees(math.atan2(level[0][0], -level[0][2])) == pytest.approx(3.0, abs=1e-9)  # pitched up 3 deg
    bias = SensorSuite(NOISELESS, TruthConfig(imu_roll_deg=2.0, accel_bias_mps2=0.05), IMU_HZ, seed=4)
    b = list(bias.accel_bias)
    acc_b, _, _ = bias.imu(f, omega, q)
    clean = SensorSuite(NOISELESS, TruthConfig(imu_roll_deg=2.0), IMU_HZ, seed=4).imu(f, omega, q)[0]
    assert np.allclose(np.array(acc_b) - np.array(clean), b, atol=1e-12)  # the bias in the IMU's axes


def test_the_ground_stations_steel_falls_off_as_a_dipole():
    """[truth] ground_field_gauss: the field at the magnetometer is the earth's and the ground station's, the latter
    (1 + h / scale)^-3 of its value at the ground; a noiseless magnetometer at rest and level reads that sum."""
    truth = TruthConfig(ground_field_gauss=(0.08, -0.06, 0.04), ground_field_scale_m=3.0)
    s = SensorSuite(NOISELESS, truth, IMU_HZ, seed=3)
    earth = SensorSuite(NOISELESS, TruthConfig(), IMU_HZ, seed=3).field_ned
    assert s.field_at(0.0) == pytest.approx(tuple(e + g for e, g in zip(earth, (0.08, -0.06, 0.04))), abs=1e-15)
    assert s.field_at(3.0) == pytest.approx(tuple(e + g / 8.0 for e, g in zip(earth, (0.08, -0.06, 0.04))), abs=1e-15)
    assert math.dist(s.field_at(100.0), earth) < 1e-5  # a hundred metres up: the earth's alone
    _, _, mag = s.imu((0.0, 0.0, -GRAVITY), (0.0, 0.0, 0.0), [1.0, 0.0, 0.0, 0.0], None, 6.0)
    assert mag == pytest.approx(s.field_at(6.0), abs=1e-15)
    with pytest.raises(ConfigError):
        TruthConfig(ground_field_scale_m=0.0)


# ---------------------------------------------------------------- defaults


def test_defaults_leave_the_readings_as_they_were():
    """No drift, no walk: noiseless readings equal the boot-ground ISA and the rotated truth at any time,
    and with noise a reading does not depend on the time it is asked for."""
    s = SensorSuite(NOISELESS, TruthConfig(), IMU_HZ, seed=5)
    for t in (0.0, 3600.0, 7 * 86400.0):
        for h in (0.0, 57.0, 100.0):
            hpa, temp_c = s.baro(h, t)
            assert hpa * 100.0 == pytest.approx(barometric_pa(h, P_BOOT, T_BOOT), rel=1e-12)
            assert temp_c == pytest.approx(T_BOOT - 273.15 - LAPSE * h, abs=1e-12)
    assert s.baro(42.0) == s.baro(42.0, 0.0)
    f, q = (0.1, 0.2, -GRAVITY), [1.0, 0.0, 0.0, 0.0]
    for _ in range(5000):
        acc, gyro, _ = s.imu(f, (0.0, 0.0, 0.0), q)
        assert acc == pytest.approx(f, abs=1e-12) and gyro == (0.0, 0.0, 0.0)
    assert s.accel_bias == [0.0, 0.0, 0.0]

    a, b = (SensorSuite(Design(), TruthConfig(), IMU_HZ, seed=9) for _ in range(2))
    for k in range(200):
        assert a.imu(f, (0.0, 0.0, 0.0), q) == b.imu(f, (0.0, 0.0, 0.0), q)
        assert a.baro(80.0, 0.0) == b.baro(80.0, 3600.0 + k)
