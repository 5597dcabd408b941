"""The one sample interface: every input (live MAVLink, tlogs, raw captures, PX4 ULog, ArduPilot
DataFlash) is turned into these samples before it reaches the estimator, so the live firmware and the
post-flight reprocessing see exactly the same thing.

Units are the estimator's: specific force in body FRD (m/s^2, level and at rest z = -9.81), body rates
(rad/s), magnetic field (gauss, NaN when the sample holds no new magnetometer reading), pressure
(hPa), temperature (degC). ``t_us`` is the sensor's own clock (microseconds since its boot)."""

from __future__ import annotations

import math
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.atmosphere import G0


class ImuSample(NamedTuple):
    t_us: int
    ax: float
    ay: float
    az: float
    gx: float
    gy: float
    gz: float
    mx: float = math.nan
    my: float = math.nan
    mz: float = math.nan


class BaroSample(NamedTuple):
    t_us: int
    pressure_hpa: float
    temperature_c: float


class WinchSample(NamedTuple):
    """WINCH_STATUS: the paid-out line (m), the reel's speed (m/s, positive paying out), the pull at the
    anchor (N; NaN when the winch does not measure it) and its status flags. ``t_us`` the winch's clock."""

    t_us: int
    line_length_m: float
    speed_mps: float
    tension_n: float
    status: int


class GroundBaroSample(NamedTuple):
    """The ground reference: SCALED_PRESSURE from the ground station's system (``[site] ground_sysid``),
    pressure hPa, temperature degC (NaN: none). ``t_us`` the ground station's clock."""

    t_us: int
    pressure_hpa: float
    temperature_c: float


Sample = ImuSample | BaroSample
GroundSample = WinchSample | GroundBaroSample  # what comes up from the ground: not the balloon's sensors


# ---------------------------------------------------------------------------------------------- MAVLink

MSG_HIGHRES_IMU = mavlink.MAVLINK_MSG_ID_HIGHRES_IMU  # 105, PX4 and our simulator
MSG_HIL_SENSOR = mavlink.MAVLINK_MSG_ID_HIL_SENSOR  # 107, PX4-style simulators
MSG_SCALED_IMU = mavlink.MAVLINK_MSG_ID_SCALED_IMU  # 26, ArduPilot (and 116, 129: the 2nd and 3rd IMU)
MSG_SCALED_IMU2 = mavlink.MAVLINK_MSG_ID_SCALED_IMU2
MSG_SCALED_IMU3 = mavlink.MAVLINK_MSG_ID_SCALED_IMU3
MSG_SCALED_PRESSURE = mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE  # 29 (and 137, 143: the 2nd and 3rd barometer)
MSG_SCALED_PRESSURE2 = mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE2
MSG_SCALED_PRESSURE3 = mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE3
HIGHRES_IMUS = (MSG_HIGHRES_IMU, MSG_HIL_SENSOR)
SCALED_IMUS = (MSG_SCALED_IMU, MSG_SCALED_IMU2, MSG_SCALED_IMU3)
IMU_MESSAGES = HIGHRES_IMUS + SCALED_IMUS
PRESSURE_MESSAGES = (MSG_SCALED_PRESSURE, MSG_SCALED_PRESSURE2, MSG_SCALED_PRESSURE3)
SENSOR_MESSAGES = frozenset(IMU_MESSAGES + PRESSURE_MESSAGES)
MSG_WINCH_STATUS = mavlink.MAVLINK_MSG_ID_WINCH_STATUS  # 9005, from the winch (any system)
GROUND_SYSID = 255  # [site] ground_sysid's default: the ground station's system

ACC_GYRO_BITS = 0x3F  # HIGHRES_IMU / HIL_SENSOR fields_updated
MAG_BITS = 0x1C0
PRESSURE_BIT = 0x200
TEMPERATURE_BIT = 0x1000
NO_TEMPERATURE_C = 15.0  # a barometer sample before any thermometer reading: ISA sea level
MILLI_G = G0 / 1000.0  # SCALED_IMU acceleration unit, m/s^2
# a sensor time beyond this (2^53 us: 285 years since the boot, the largest whole number a double holds) is no clock's:
# the sample is counted (``Sampler.bad_time``) and not used; every time below it fits the cores' int64 and a tlog's
# stamp (its epoch + the time < 2^64)
MAX_TIME_US = 2**53
# a sensor (accelerometer, gyro, magnetometer) whose reading repeats bit for bit this long is stuck (a hung bus, a
# frozen driver: a live sensor's noise never repeats a reading of three axes): its readings are not used until they
# change, and counted (``MavlinkSampler.stuck``)
STUCK_US = 1_000_000
SWITCH_AFTER = 200  # IMU messages from other instances in a row (selected one silent): take the newest


def scaled_imu_sample(m) -> ImuSample:
    """SCALED_IMU / SCALED_IMU2 / SCALED_IMU3 in the estimator's units. ``xacc`` is milli-g of specific
    force as the accelerometer measures it (level at rest zacc = -1000), ``xgyro`` mrad/s, ``xmag``
    milligauss (all three 0: no magnetometer), ``time_boot_ms`` ms since the autopilot's boot."""
    if m.xmag == 0 and m.ymag == 0 and m.zmag == 0:
        mx = my = mz = math.nan
    else:
        mx, my, mz = m.xmag * 1e-3, m.ymag * 1e-3, m.zmag * 1e-3
    return ImuSample(
        m.time_boot_ms * 1000, m.xacc * MILLI_G, m.yacc * MILLI_G, m.zacc * MILLI_G,
        m.xgyro * 1e-3, m.ygyro * 1e-3, m.zgyro * 1e-3, mx, my, mz,
    )  # fmt: skip


def scaled_pressure_sample(m) -> BaroSample:
    """SCALED_PRESSURE / 2 / 3: ``press_abs`` hPa, ``temperature`` cdegC, ``time_boot_ms`` ms."""
    return BaroSample(m.time_boot_ms * 1000, m.press_abs, m.temperature / 100.0)


def winch_sample(m) -> WinchSample:
    """WINCH_STATUS: ``line_length`` m, ``speed`` m/s, ``tension`` kg (NaN: not measured) as N."""
    return WinchSample(m.time_usec, m.line_length, m.speed, m.tension * G0, m.status)


class MavlinkSampler:
    """MAVLink messages -> samples: the one converter for live links, tlogs and raw captures.

    One IMU and one barometer: the first IMU instance heard (message type, sender, ``id``) is used; the
    others are counted in ``ignored``. (If the chosen one falls silent while another keeps talking for
    ``SWITCH_AFTER`` messages, the other is taken and ``switched`` counts it.) The barometer is the one
    inside the chosen HIGHRES_IMU / HIL_SENSOR when it carries one (``fields_updated``), else the first
    SCALED_PRESSURE* instance heard. A message whose values are NaN or out of range still becomes a
    sample: the estimator rejects and counts it.

    From the ground: WINCH_STATUS (any sender) becomes a ``WinchSample``; SCALED_PRESSURE from
    ``ground_sysid`` (unless that is the IMU's own system) a ``GroundBaroSample``. The balloon's
    barometer is the IMU's system's: once the IMU is known, pressure from any other system is ignored
    (and a barometer chosen before from another system is given up for the IMU's own)."""

    def __init__(self, ground_sysid: int = GROUND_SYSID) -> None:
        self.ground_sysid = ground_sysid
        self.ground_messages = 0  # WINCH_STATUS and ground SCALED_PRESSURE converted
        self.imu_key: tuple | None = None
        self.baro_key: tuple | None = None
        self.embedded_baro = False  # the chosen IMU message carries the barometer
        self.ignored = 0
        self.baro_beside = 0  # pressure messages beside IMU messages that carry the barometer themselves
        self.bad_time = 0  # IMU messages whose time is beyond MAX_TIME_US: not used
        self.bad_mag = 0  # magnetometer readings that are not numbers (NaN, inf): the sample used without them
        self.bad_temperature = 0  # thermometer readings that are not numbers: the last good one (or ISA's) used
        self.stuck = 0  # IMU samples with a stuck sensor (STUCK_US): its readings not used
        self.last_readings = [math.nan] * 9  # the last accelerometer, gyro and magnetometer readings, as sent
        self.repeat_since = [-1, -1, -1]  # when each of the three began to repeat its reading (-1: never)
        self.switched = 0
        self._others = 0
        self._last_temp_c = math.nan
        self._last_mag: tuple[int, int, int] | None = None

    @staticmethod
    def is_sensor(msg) -> bool:
        return msg.get_msgId() in SENSOR_MESSAGES

    def _key(self, msg, mid: int) -> tuple:
        return (mid, msg.get_srcSystem(), msg.get_srcComponent(), getattr(msg, "id", 0) if mid in HIGHRES_IMUS else 0)

    def _chosen_imu(self, key: tuple) -> bool:
        if self.imu_key is None:
            self.imu_key = key
        if key == self.imu_key:
            self._others = 0
            return True
        self._others += 1
        if self._others >= SWITCH_AFTER:
            self.imu_key, self._others, self.embedded_baro, self._last_mag = key, 0, False, None
            self.switched += 1
            return True
        self.ignored += 1
        return False

    def convert(self, msg) -> tuple[Sample, ...] | None:
        """The samples in one message (a HIGHRES_IMU may hold a barometer and an IMU sample, in that
        order); () for a sensor message that is not used; None for a message that is not a sensor's."""
        mid = msg.get_msgId()
        if mid in HIGHRES_IMUS:
            if not self._chosen_imu(self._key(msg, mid)):
                return ()
            if not 0 <= msg.time_usec <= MAX_TIME_US:
                self.bad_time += 1
                return ()
            return self._highres(msg)
        if mid in SCALED_IMUS:
            if not self._chosen_imu(self._key(msg, mid)):
                return ()
            s = scaled_imu_sample(msg)
            mag = (msg.xmag, msg.ymag, msg.zmag)
            if mag == self._last_mag:  # the autopilot repeats its last magnetometer reading: not a new sample
                s = s._replace(mx=math.nan, my=math.nan, mz=math.nan)
            self._last_mag = mag
            return (s,)
        if mid in PRESSURE_MESSAGES:
            key = self._key(msg, mid)
            src = key[1]
            imu_sys = self.imu_key[1] if self.imu_key is not None else None
            if src == self.ground_sysid and src != imu_sys:
                if mid != MSG_SCALED_PRESSURE:
                    return ()
                self.ground_messages += 1
                return (GroundBaroSample(msg.time_boot_ms * 1000, msg.press_abs, msg.temperature / 100.0),)
            if imu_sys is not None and src != imu_sys:
                self.ignored += 1  # not the balloon's: its barometer is its IMU's system's
                return ()
            if self.baro_key is None or (imu_sys is not None and self.baro_key[1] != imu_sys):
                self.baro_key = key
            if self.embedded_baro:
                self.baro_beside += 1  # the IMU messages carry the barometer: this one is not needed
                return ()
            if key != self.baro_key:
                self.ignored += 1
                return ()
            return (scaled_pressure_sample(msg),)
        if mid == MSG_WINCH_STATUS:
            self.ground_messages += 1
            return (winch_sample(msg),)
        return None

    def _highres(self, m) -> tuple[Sample, ...]:
        bits = m.fields_updated or 0xFFFF  # 0: a sender that does not fill the field
        t = m.time_usec
        out: list[Sample] = []
        if bits & PRESSURE_BIT:
            self.embedded_baro = True
            if bits & TEMPERATURE_BIT:
                if math.isfinite(m.temperature):
                    self._last_temp_c = m.temperature
                else:
                    self.bad_temperature += 1
            temp = self._last_temp_c
            out.append(BaroSample(t, m.abs_pressure, temp if math.isfinite(temp) else NO_TEMPERATURE_C))
        if bits & ACC_GYRO_BITS != ACC_GYRO_BITS:  # no new accelerometer + gyro: a sample the estimator rejects
            out.append(ImuSample(t, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan))
            return tuple(out)
        if bits & MAG_BITS == MAG_BITS:
            mx, my, mz = m.xmag, m.ymag, m.zmag
            if not (math.isfinite(mx) and math.isfinite(my) and math.isfinite(mz)):
                self.bad_mag += 1
                mx = my = mz = math.nan
        else:
            mx = my = mz = math.nan
        r = (m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, mx, my, mz)
        stuck = self._stuck(t, r)
        if stuck:
            self.stuck += 1
            if stuck & 3:  # the accelerometer or the gyro: the sample is not used (the estimator counts it rejected)
                r = (math.nan,) * 9
            else:  # the magnetometer: the sample without it
                r = (*r[:6], math.nan, math.nan, math.nan)
        out.append(ImuSample(t, *r))
        return tuple(out)

    def _stuck(self, t_us: int, readings: tuple) -> int:
        """Which of the accelerometer (1), the gyro (2) and the magnetometer (4) have sent the same reading, bit for
        bit, for STUCK_US up to this sample at ``t_us`` (a reading that is not a number never repeats)."""
        last, since, out = self.last_readings, self.repeat_since, 0
        for i in range(3):
            new = readings[3 * i : 3 * i + 3]
            if all(a == b for a, b in zip(new, last[3 * i : 3 * i + 3])):  # (not the tuples': NaN is NaN there)
                if since[i] < 0:
                    since[i] = t_us
                elif t_us - since[i] >= STUCK_US:
                    out |= 1 << i
            else:
                since[i] = -1
                last[3 * i : 3 * i + 3] = new
        return out
