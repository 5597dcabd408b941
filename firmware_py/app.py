"""The firmware's main loop body: MAVLink messages in, estimator, WIND_COV + HEARTBEAT out.

Accepts HIGHRES_IMU (105) and HIL_SENSOR (107, what PX4-style simulators send; same fields and
``fields_updated`` bits) for the IMU, barometer and thermometer, and SCALED_PRESSURE (29) when the IMU
messages carry no barometer. Everything else is counted and ignored.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from firmware_py.config import Design
from firmware_py.control import Estimator
from firmware_py.mavio import LinkStats, pack
from firmware_py.outputs import WindCovOutput
from firmware_py.state import FilterConfig

FW_SYSID = 1
FW_COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1
ACC_GYRO_BITS = 0x3F
MAG_BITS = 0x1C0
PRESSURE_BIT = 0x200
TEMPERATURE_BIT = 0x1000
SENSOR_BITS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
               | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE)  # fmt: skip


class Firmware:
    def __init__(self, design: Design, cfg: FilterConfig | None = None, sink=None, wind_cov_hz: float = 10.0) -> None:
        self.est = Estimator(design, cfg)
        self.out = WindCovOutput(self.est.cfg.imu_rate_hz, design.site.altitude_amsl_m)
        self.sinks = [sink] if sink is not None else []
        self.mav = mavlink.MAVLink(None, srcSystem=FW_SYSID, srcComponent=FW_COMPID)
        self.period_us = round(1e6 / wind_cov_hz)
        self.stats = LinkStats()
        self.other_messages = 0
        self.wind_cov_sent = 0
        self._next_wind_us = 0
        self._next_hb_us = 0
        self._highres_baro = False
        self._last_temp_c = math.nan
        self.imu_missing = 0  # IMU samples missing by their time stamps (what 8-bit sequences cannot count)
        self._prev_imu_us = -1

    # ----------------------------------------------------------------- input

    def handle(self, msg) -> None:
        mid = msg.get_msgId()
        if mid in (mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, mavlink.MAVLINK_MSG_ID_HIL_SENSOR):
            self._imu(msg)
        elif mid == mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE:
            if not self._highres_baro:
                self.est.on_baro(msg.time_boot_ms * 1000, msg.press_abs, msg.temperature / 100.0)
        else:
            self.other_messages += 1

    def _imu(self, m) -> None:
        bits = m.fields_updated or 0xFFFF  # 0: a sender that does not fill the field
        t = m.time_usec
        est = self.est
        self._track_imu_time(t)
        if bits & PRESSURE_BIT:
            self._highres_baro = True
            temp = m.temperature if bits & TEMPERATURE_BIT else self._last_temp_c
            if bits & TEMPERATURE_BIT:
                self._last_temp_c = m.temperature
            est.on_baro(t, m.abs_pressure, temp if math.isfinite(temp) else 15.0)
        if bits & ACC_GYRO_BITS != ACC_GYRO_BITS:
            est.counters.rejected += 1
            return
        if bits & MAG_BITS == MAG_BITS:
            mx, my, mz = m.xmag, m.ymag, m.zmag
        else:
            mx = my = mz = math.nan
        resets = est.counters.time_resets
        if est.on_imu(t, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, mx, my, mz):
            self.out.update(est, t)
            self.emit_due(t)
        if est.counters.time_resets != resets:
            self.out.reset()
            self._next_wind_us = self._next_hb_us = 0

    def _track_imu_time(self, t_us: int) -> None:
        """Count IMU samples missing between this one and the previous (at the filter's IMU rate). Late
        ones are not counted twice; time going back by more than a second is a restart."""
        prev = self._prev_imu_us
        if prev >= 0 and t_us > prev:
            self.imu_missing += max(0, (t_us - prev + self.est.dt_us // 2) // self.est.dt_us - 1)
        if t_us > prev or t_us < prev - 1_000_000:
            self._prev_imu_us = t_us

    # ----------------------------------------------------------------- output

    def emit_due(self, t_us: int) -> None:
        """WIND_COV at its rate and HEARTBEAT at 1 Hz, on the sensor clock."""
        if t_us >= self._next_hb_us:
            self.heartbeat(t_us)
            self._next_hb_us = t_us + 1_000_000
        if t_us >= self._next_wind_us:
            self.wind_cov(t_us)
            self._next_wind_us = t_us - t_us % self.period_us + self.period_us

    def heartbeat(self, t_us: int) -> None:
        frame = pack(self.mav, self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, self.est.ekf.mode,
            mavlink.MAV_STATE_ACTIVE if self.est.initialised else mavlink.MAV_STATE_STANDBY,
        ))  # fmt: skip
        self._send(frame, t_us)
        self.sys_status(t_us)

    def sys_status(self, t_us: int) -> None:
        """SYS_STATUS with each HEARTBEAT: the health a ground station (or a lockstep sender) shows.
        ``drop_rate_comm`` = input packets lost (c%), ``errors_comm`` = corrupt input frames,
        ``errors_count1`` = input packets lost, ``errors_count2`` = filter resets (reboot + numeric +
        taut + baro), ``errors_count3`` = long input gaps, ``errors_count4`` = IMU samples missing by
        their time stamps."""
        c, st = self.est.counters, self.stats
        sensors = SENSOR_BITS
        resets = c.time_resets + c.numeric_resets + c.taut_resets + c.baro_resets
        frame = pack(self.mav, self.mav.sys_status_encode(
            sensors, sensors, sensors, 0, 0xFFFF, -1, -1, min(round(10000 * st.lost_fraction()), 10000),
            min(st.bad_frames, 0xFFFF), min(st.lost, 0xFFFF), min(resets, 0xFFFF), min(c.long_gaps, 0xFFFF),
            min(self.imu_missing, 0xFFFF),
        ))  # fmt: skip
        self._send(frame, t_us)

    def wind_cov(self, t_us: int) -> None:
        self._send(pack(self.mav, self.mav.wind_cov_encode(*self.out.fields(self.est))), t_us)
        self.wind_cov_sent += 1

    def _send(self, frame: bytes, t_us: int) -> None:
        for sink in self.sinks:
            if hasattr(sink, "send_at"):
                sink.send_at(frame, t_us)
            else:
                sink.send(frame)

    def coast(self, now_s: float) -> None:
        """Sensors silent: keep talking (WIND_COV every call, HEARTBEAT each second), honestly."""
        self.est.coast(0.1)
        t = max(self.est.t_last_us, 0)
        if now_s - getattr(self, "_last_hb_wall", 0.0) >= 1.0:
            self._last_hb_wall = now_s
            self.heartbeat(t)
        self.wind_cov(t)

    def summary(self) -> str:
        c = self.est.counters
        return (
            f"balloon-fw: {c.imu_samples} IMU samples, {c.baro_samples} baro samples, "
            f"{c.rejected} rejected, {self.stats.bad_frames} bad frames, {self.other_messages} other messages, "
            f"{c.duplicates} duplicates, "
            f"{c.reordered} reordered, {c.gaps} gaps, {c.long_gaps} long gaps, "
            f"resets: {c.time_resets} reboot, {c.numeric_resets} numeric, {c.taut_resets} taut, "
            f"{c.baro_resets} baro, {c.false_releases} false release, {c.mode_switches} mode switches, "
            f"{self.wind_cov_sent} WIND_COV sent, final mode {self.est.mode_name}, "
            f"input packets {self.stats.loss_summary()}, {self.imu_missing} IMU samples missing by time"
        )

    def status(self) -> str:
        """Health and estimate at a glance (the live status line): input loss first (what a narrow
        terminal must show), then mode, wind, accuracy."""
        est = self.est
        if not est.initialised:
            return f"waiting for the sensors, {self.stats.lost} lost"
        wn, we = est.wind()
        frm = math.degrees(math.atan2(-we, -wn)) % 360.0
        return (f"{self.stats.lost} lost ({100 * self.stats.lost_fraction():.1f} %), {self.imu_missing} IMU missing, "
                f"{est.counters.long_gaps} long gaps, mode {est.mode_name}, wind {math.hypot(wn, we):.1f} m/s "
                f"from {frm:03.0f} deg \u00b1{est.ekf.wind_accuracy():.2f}")  # fmt: skip
