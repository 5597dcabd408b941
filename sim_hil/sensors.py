"""Sensor models at the avionics: accelerometer (specific force, FRD), gyroscope, magnetometer,
barometer and thermometer. Table 2's figures as 1-sigma white noise by default; turn-on biases, bias
random walks (gyro, accelerometer), a fixed hard-iron offset, an IMU mounted askew (``rotation.imu_mount``),
quantisation and weather (the ground pressure and temperature drifting from boot, ``atmosphere.ground_conditions``)
as options (``TruthConfig``). The avionics sit at the sphere's centre unless ``TruthConfig.avionics_offset_m``
hangs them below it; the caller passes the accelerometer's lever-arm term then
(``dynamics.lever_arm_accel_b``).

Noise is drawn in blocks (one numpy call per block of samples), then consumed as plain floats. A row's
columns: 0-2 accelerometer, 3-5 gyro, 6-8 magnetometer, 9-11 gyro bias walk, 12 barometer,
13 thermometer, 14-16 accelerometer bias walk (only when that walk is on: without it a seed's stream
is the one it always was).
"""

from __future__ import annotations

import math

import numpy as np

from balloon_core.atmosphere import G0, ground_conditions, isa_pressure_pa, isa_temperature_k
from balloon_core.config import Design
from balloon_core.rotation import body_to_imu, imu_mount, rotation
from sim_hil.dynamics import TruthConfig

BLOCK = 4096
ACC_LSB = 16 * G0 / 65536.0
GYRO_LSB = math.radians(4000.0) / 65536.0
MAG_LSB = 16.0 / 65536.0


def _quant(x: float, lsb: float) -> float:
    return round(x / lsb) * lsb


class SensorSuite:
    """Turns truth (specific force, rates, attitude, height) into noisy sensor readings."""

    def __init__(self, design: Design, truth: TruthConfig, imu_hz: float, seed: int) -> None:
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 0x53454E53]))
        s = design.sensors
        self._sig = (s.accel_mps2, math.radians(s.gyro_dps), s.mag_gauss)
        self._baro_m = s.baro_m
        self._thermo_k = s.thermometer_k
        self._quantize = truth.quantize
        dec = math.radians(design.site.mag_declination_deg)
        self.field_ned = (
            truth.mag_field_h_gauss * math.cos(dec),
            truth.mag_field_h_gauss * math.sin(dec),
            truth.mag_field_z_gauss,
        )
        self.ground_pressure_pa = design.site.ground_pressure_pa
        self.ground_temperature_k = design.site.ground_temperature_c + 273.15
        r = self._rng
        self.gyro_bias = [float(x) for x in r.normal(0.0, math.radians(truth.gyro_bias_dps), 3)]
        self.accel_bias = [float(x) for x in r.normal(0.0, truth.accel_bias_mps2, 3)]
        self.mag_bias = [float(x) for x in r.normal(0.0, truth.mag_bias_gauss, 3)]
        if any(truth.mag_hard_iron_gauss):  # fixed hard iron (body frame) on top of the seeded draw
            self.mag_bias = [b + h for b, h in zip(self.mag_bias, truth.mag_hard_iron_gauss)]
        self.baro_offset_m = float(r.normal(0.0, truth.baro_offset_m)) if truth.baro_offset_m else 0.0
        # a current switched beside the magnetometer: its field, and when it is on (off 0: to the end)
        self._switched = truth.mag_switched_gauss if any(truth.mag_switched_gauss) else None
        self._switched_s = (truth.mag_switched_on_s, truth.mag_switched_off_s or math.inf)
        self._mount = imu_mount(truth.imu_roll_deg, truth.imu_pitch_deg)
        self._ground_field = truth.ground_field_gauss if any(truth.ground_field_gauss) else None
        self._ground_field_m = truth.ground_field_scale_m
        self._walk = math.radians(truth.gyro_bias_walk_dps_rt_s) * math.sqrt(1.0 / imu_hz)
        self._accel_walk = truth.accel_bias_walk_mps2_rt_s * math.sqrt(1.0 / imu_hz)
        self._columns = 17 if self._accel_walk else 14
        self.pressure_drift_hpa_h = truth.pressure_drift_hpa_h
        self.temperature_drift_k_h = truth.temperature_drift_k_h
        self._noise: list[list[float]] = []
        self._k = BLOCK

    def _draw(self) -> list[float]:
        if self._k >= len(self._noise):
            self._noise = self._rng.standard_normal((BLOCK, self._columns)).tolist()
            self._k = 0
        row = self._noise[self._k]
        self._k += 1
        return row

    def imu(
        self,
        f_ned: tuple[float, float, float],
        omega_b: tuple[float, float, float],
        q: list[float],
        lever_b: tuple[float, float, float] | None = None,
        height_m: float = 0.0,
        time_s: float = 0.0,
    ) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
        """Accelerometer (specific force f = a - g, FRD, m/s^2), gyro (rad/s), magnetometer (gauss).
        ``f_ned`` is the centre's specific force; ``lever_b`` the sensor's acceleration relative to the
        centre in body axes (dw/dt x rho + w x (w x rho)), when it is not at the centre; ``height_m`` the
        magnetometer's above the ground (the ground station's own field, ``field_at``); ``time_s`` since the boot (a
        current switched beside the magnetometer, [truth] mag_switched_*)."""
        n = self._draw()
        q0, q1, q2, q3 = q
        # R^T (NED -> body) rows: the rotation's columns
        r00, r10, r20, r01, r11, r21, r02, r12, r22 = rotation(q0, q1, q2, q3)
        fn, fe, fd = f_ned
        bn, be, bd = self.field_at(height_m)
        f = (r00 * fn + r01 * fe + r02 * fd, r10 * fn + r11 * fe + r12 * fd, r20 * fn + r21 * fe + r22 * fd)
        w = omega_b
        m = (r00 * bn + r01 * be + r02 * bd, r10 * bn + r11 * be + r12 * bd, r20 * bn + r21 * be + r22 * bd)
        mount = self._mount
        if mount is not None:  # an IMU askew: the body's readings (the lever arm's with them) in its own axes
            if lever_b is not None:
                f = (f[0] + lever_b[0], f[1] + lever_b[1], f[2] + lever_b[2])
            f, w, m = body_to_imu(mount, *f), body_to_imu(mount, *w), body_to_imu(mount, *m)
        sa, sg, sm = self._sig
        ab, gb, mb = self.accel_bias, self.gyro_bias, self.mag_bias
        if self._switched is not None and self._switched_s[0] <= time_s < self._switched_s[1]:
            mb = [b + x for b, x in zip(mb, self._switched, strict=True)]
        acc = (f[0] + ab[0] + sa * n[0], f[1] + ab[1] + sa * n[1], f[2] + ab[2] + sa * n[2])
        gyro = (w[0] + gb[0] + sg * n[3], w[1] + gb[1] + sg * n[4], w[2] + gb[2] + sg * n[5])
        mag = (m[0] + mb[0] + sm * n[6], m[1] + mb[1] + sm * n[7], m[2] + mb[2] + sm * n[8])
        if lever_b is not None and mount is None:
            acc = (acc[0] + lever_b[0], acc[1] + lever_b[1], acc[2] + lever_b[2])
        return self._finish(n, acc, gyro, mag)

    def field_at(self, height_m: float) -> tuple[float, float, float]:
        """The field at the magnetometer, NED gauss: the earth's, and near the ground the ground station's own (its
        steel: [truth] ground_field_gauss at the ground, a dipole's fall, (1 + h / ground_field_scale_m)^-3)."""
        if self._ground_field is None:
            return self.field_ned
        k = (1.0 + max(height_m, 0.0) / self._ground_field_m) ** -3
        return tuple(b + k * g for b, g in zip(self.field_ned, self._ground_field, strict=True))

    def _finish(self, n: list[float], acc, gyro, mag):
        """The step's readings as the sensor gives them (quantised, when asked), its biases' walks one step on."""
        ab, gb = self.accel_bias, self.gyro_bias
        if self._walk:
            w = self._walk
            self.gyro_bias = [gb[0] + w * n[9], gb[1] + w * n[10], gb[2] + w * n[11]]
        if self._accel_walk:
            w = self._accel_walk
            self.accel_bias = [ab[0] + w * n[14], ab[1] + w * n[15], ab[2] + w * n[16]]
        if self._quantize:
            acc = (_quant(acc[0], ACC_LSB), _quant(acc[1], ACC_LSB), _quant(acc[2], ACC_LSB))
            gyro = (_quant(gyro[0], GYRO_LSB), _quant(gyro[1], GYRO_LSB), _quant(gyro[2], GYRO_LSB))
            mag = (_quant(mag[0], MAG_LSB), _quant(mag[1], MAG_LSB), _quant(mag[2], MAG_LSB))
        return acc, gyro, mag

    def ground(self, time_s: float) -> tuple[float, float]:
        """(pressure Pa, temperature K) at the site's ground ``time_s`` after boot (the weather)."""
        p0, t0 = self.ground_pressure_pa, self.ground_temperature_k
        if self.pressure_drift_hpa_h or self.temperature_drift_k_h:
            return ground_conditions(p0, t0, self.pressure_drift_hpa_h, self.temperature_drift_k_h, time_s)
        return p0, t0

    def baro(self, height_m: float, time_s: float = 0.0) -> tuple[float, float]:
        """(absolute pressure hPa, temperature C) at the balloon's height above the site (ISA from the
        ground pressure and temperature ``time_s`` after boot: the weather may have changed them)."""
        n = self._draw()
        p0, t0 = self.ground(time_s)
        temp_k = isa_temperature_k(height_m, t0)
        p = isa_pressure_pa(height_m + self.baro_offset_m, p0, t0)
        rho = p / (287.05 * temp_k)
        p += rho * G0 * self._baro_m * n[12]
        hpa = p / 100.0
        temp_c = temp_k - 273.15 + self._thermo_k * n[13]
        if self._quantize:
            hpa = round(hpa, 2)
            temp_c = round(temp_c, 2)
        return hpa, temp_c
