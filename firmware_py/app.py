"""The firmware's main loop body: MAVLink messages in, estimator, WIND_COV + HEARTBEAT out.

Every message goes through the one sample interface (``balloon_core.samples``: HIGHRES_IMU and HIL_SENSOR
with their ``fields_updated`` bits, ArduPilot's SCALED_IMU/2/3, SCALED_PRESSURE/2/3) and the input
pipeline (``firmware_py.streams``: the IMU rate measured from the stream, a faster stream averaged to the
filter's step), exactly as post-flight reprocessing does. What comes up from the ground (WINCH_STATUS,
the ground reference's SCALED_PRESSURE from ``[site] ground_sysid``) goes straight to the estimator,
stamped with the newest sensor time (``streams.feed_ground``). Everything else is counted and ignored.

When the estimator's consistency monitor (``firmware_py.estimator.consistency``) says the model does not
explain an aid source's data, the reported ``horiz_accuracy`` already grows (``Estimator.wind_accuracy``);
this module says why: a STATUSTEXT when the flags change, the health bits of SYS_STATUS, ESTIMATOR_STATUS,
the live status line and the summary (docs/protocol.md, "Model misfit", "ESTIMATOR_STATUS").

Besides WIND_COV it sends ArduPilot's WIND (168) at 1 Hz (``WIND_EVERY``), which MAVProxy and Mission Planner show, so
frames are packed with pymavlink's ``ardupilotmega`` dialect (which includes ``common``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design, build_section
from balloon_core.samples import (
    BaroSample,
    GroundBaroSample,
    GroundSample,
    ImuSample,
    MavlinkSampler,
    Sample,
    WinchSample,
)
from balloon_core.score import direction_from_deg, wind_unknown
from balloon_core.wire import FastPacker, LinkStats, pack
from firmware_py import gcs
from firmware_py.core_c import SampleBlock, new_core
from firmware_py.estimator.aid_sources.ground_ref import ground_counts
from firmware_py.estimator.aid_sources.winch import winch_counts
from firmware_py.estimator.consistency import ACCEL, ALIGN, BARO, FLAG_NIS, MAG, RADIUS, SOURCES
from firmware_py.estimator.params import REORDER_WINDOW_US
from firmware_py.estimator.state import MODE_GROUND, MODE_TAUT, POS_D, POS_E, POS_N, FilterConfig
from firmware_py.streams import InputPipeline, feed, feed_ground, print_warning

FW_SYSID = 1
FW_COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1
SENSOR_BITS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
               | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
               | mavlink.MAV_SYS_STATUS_AHRS)  # fmt: skip
# the SYS_STATUS health bit a flagged aid source clears, in consistency.SOURCES order: the accelerometer,
# the barometer and the magnetometer their own sensor's; the tether model's two (align: the rope's
# direction, radius: its length) and the force balance (the model's forces against the balloon's motion) the AHRS
# bit, the estimator's own model
MISFIT_HEALTH_BITS = {
    "accel": mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL, "align": mavlink.MAV_SYS_STATUS_AHRS,
    "radius": mavlink.MAV_SYS_STATUS_AHRS, "baro": mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE,
    "mag": mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG, "force": mavlink.MAV_SYS_STATUS_AHRS,
}  # fmt: skip
assert tuple(MISFIT_HEALTH_BITS) == SOURCES
TEXT_MAX = 50  # STATUSTEXT's text field, characters
# WIND (168) goes out just before every WIND_EVERY-th WIND_COV (1 Hz at the default 10 Hz): a ground station
# that reads both (QGroundControl) is left holding WIND_COV's value, never one or the other at random
WIND_EVERY = 10
# the optional sources' counts, as NAMED_VALUE_INT names (at most 10 characters): WINCH_STATUS, ground reference
SOURCE_COUNTS = (("winch_used", "winch_rej"), ("gref_used", "gref_rej"))
TEXT_INTERVAL_US = 1_000_000  # at most one consistency STATUSTEXT a second (sensor clock)
# the sensors' own health bits: all cleared while the sensors are silent (the gyro has no innovation, so
# a cleared gyro bit says "silent", never "misfit")
SILENT_HEALTH_BITS = SENSOR_BITS & ~mavlink.MAV_SYS_STATUS_AHRS
RECENT_IMU = 256  # IMU sample times remembered to tell a late sample from a copy (2.5 s at 100 Hz)
BATCH_SAMPLES = 256  # a file replay's samples handed to the C core at most in one call (``use_batches``)
_BARO_PAD = (0.0,) * 7  # a barometer sample's unused values in a SampleBlock row
CONSISTENT_TEXT = "wind model consistent again"
PACK_WIND_COV = FastPacker(mavlink.MAVLink_wind_cov_message)  # the 10 Hz output, packed without a message object
RESTARTED_TEXT = "wind model check restarted (filter reset)"
NEVER_STARTED = (" (never started: no IMU sample with a magnetometer reading and gravity's reaction up the body,"
                 " FRD zacc < 0: level at rest zacc = -9.81; check the accelerometer's sign and mounting)")
# an IMU time more than this ahead of the last one, or behind it by more than the reorder window, starts a new clock
# (a reboot, a long silence) or is a glitch: it is used once CLOCK_CONFIRM samples in a row run on from it, each within
# this of the one before (``ClockGuard``)
CLOCK_STEP_MAX_US = 1_000_000
CLOCK_CONFIRM = 5

# The parameters a ground station reads (PARAM_REQUEST_LIST: firmware_py/gcs.py; names, meanings and units in
# docs/protocol.md), each named once: the design the filter was started with (``balloon-fw --config``), as (name,
# design section, key) in the design file's units, read-only (the filter is not reconfigured in flight); a value None
# is left out (no ground pressure given); then WIND_COV_HZ, the rate WIND_COV goes out at. All reals (gcs.Param).
PARAMETERS = (
    ("BAL_RADIUS", "balloon", "radius_m"),
    ("BAL_MASS", "balloon", "skin_and_avionics_kg"),
    ("BAL_GAS_RHO", "balloon", "gas_density_kg_m3"),
    ("BAL_CD", "balloon", "drag_coefficient"),
    ("TETH_LEN", "tether", "length_m"),
    ("TETH_RHO_L", "tether", "linear_density_kg_m"),
    ("SITE_ALT", "site", "altitude_amsl_m"),
    ("SITE_DECL", "site", "mag_declination_deg"),
    ("SITE_GND_P", "site", "ground_pressure_hpa"),
    ("SNS_ACC_SD", "sensors", "accel_mps2"),
    ("SNS_BARO_SD", "sensors", "baro_m"),
    ("SNS_GYRO_SD", "sensors", "gyro_dps"),
    ("SNS_MAG_SD", "sensors", "mag_gauss"),
    ("SNS_IMU_ROLL", "sensors", "imu_roll_deg"),
    ("SNS_IMU_PITCH", "sensors", "imu_pitch_deg"),
    ("SNS_IMU_ALIGN", "sensors", "imu_alignment_deg"),
)
WIND_COV_RATE_PARAM = "WIND_COV_HZ"


def parameters(design: Design, wind_cov_hz: float) -> tuple[gcs.Param, ...]:
    """``PARAMETERS`` of this design, then the WIND_COV rate, in that order (the indices a ground station reads)."""
    values = [(name, getattr(getattr(design, section), key)) for name, section, key in PARAMETERS]
    values.append((WIND_COV_RATE_PARAM, wind_cov_hz))
    return gcs.check_params(tuple(gcs.Param(name, v) for name, v in values if v is not None))


class ClockGuard:
    """The sender's IMU clock, told from a glitch. A reboot starts its clock again and a long silence jumps it ahead,
    and the samples after either run on from there; one sample stamped 0, a minute back or an hour ahead (a bit error
    the CRC let through, a sender's bug) does not, and the estimator must not take it for a reboot (it starts the filter
    again, the barometer's zero with it, in flight) or a gap. A message whose time is off the last one used by more
    than a step (CLOCK_STEP_MAX_US ahead, REORDER_WINDOW_US back) is held; once CLOCK_CONFIRM IMU samples have run on
    from it, each within a step of the one before, it is the clock (``new_clocks``), and all that was held is used;
    a message on the old clock first makes what was held a glitch (``glitches``: its messages dropped). The firmware
    judges its IMU messages (with the barometer one carries); post-flight reprocessing each sample, IMU and
    barometer alike (postflight/reprocess.py)."""

    def __init__(self) -> None:
        self._held: list[tuple] = []  # the samples of each message held on a clock not yet confirmed
        self._new = -1  # ... the newest of their times
        self._imu = 0  # ... how many of them end in an IMU sample
        self.glitches = 0
        self.new_clocks = 0

    @property
    def pending(self) -> bool:
        return bool(self._held)

    def admit(self, samples: tuple, last_us: int) -> list[tuple]:
        """The messages' samples to use now, in order, given one message's (``samples``) and the newest time used
        (``last_us``, -1: none yet): it alone, those held and it, or none (held or dropped)."""
        t_us = samples[-1].t_us
        imu = type(samples[-1]) is ImuSample
        if self._held:
            if 0 <= t_us - self._new <= CLOCK_STEP_MAX_US:  # on from the time held
                self._held.append(samples)
                self._new = max(self._new, t_us)
                self._imu += imu
                if self._imu < CLOCK_CONFIRM:
                    return []
                out, self._held = self._held, []
                self.new_clocks += 1
                return out
            self.end()  # a message off that clock: those held were no clock's
        if last_us < 0 or -REORDER_WINDOW_US < t_us - last_us <= CLOCK_STEP_MAX_US:
            return [samples]
        self._held, self._new, self._imu = [samples], t_us, int(imu)
        return []

    def end(self) -> None:
        """What is held is dropped (a glitch, or the input ended before its clock was confirmed)."""
        self.glitches += len(self._held)
        self._held = []


def misfit_health(flags: int) -> int:
    """The SYS_STATUS health bits the consistency flags clear (``MISFIT_HEALTH_BITS``)."""
    bits = 0
    for i, bit in enumerate(MISFIT_HEALTH_BITS.values()):
        if flags >> i & 1:
            bits |= bit
    return bits


def misfit_text(names: list[str], inflation: float) -> str:
    """The STATUSTEXT of a model misfit, at most ``TEXT_MAX`` characters: the flagged sources and the
    factor on the reported accuracy, in the longest form that fits."""
    who = ",".join(names)
    forms = (f"wind uncertain: model misfit {who} (accuracy x{inflation:.1f})",
             f"wind uncertain: misfit {who} (acc x{inflation:.1f})",
             f"wind uncertain: misfit {who} x{inflation:.1f}",
             f"misfit {who} acc x{inflation:.1f}")  # fmt: skip
    for text in forms:
        if len(text) <= TEXT_MAX:
            return text
    return forms[-1][:TEXT_MAX]


def wind_fields(wind_n: float, wind_e: float) -> tuple[float, float, float]:
    """WIND (168, ardupilotmega): (direction the wind comes FROM in degrees [0, 360), 0 = north,
    clockwise; horizontal speed m/s; vertical speed m/s, NaN: not estimated) of the air velocity
    north / east that WIND_COV carries."""
    direction = np.float32(direction_from_deg(wind_n, wind_e)) % np.float32(360.0)  # the wire's float32: < 360
    return float(direction), math.hypot(wind_n, wind_e), math.nan


def estimator_flags(initialised: bool, silent: bool, mode: int, flags: int, wind_known: bool) -> int:
    """ESTIMATOR_STATUS ``flags`` (ESTIMATOR_STATUS_FLAGS) of the filter's health (docs/protocol.md):
    a "good" bit is set when that part of the estimate is trusted, ACCEL_ERROR while the accelerometer
    misfits the force model, CONST_POS_MODE while the balloon rests on the ground station."""
    if not initialised:
        return 0
    bits = mavlink.ESTIMATOR_CONST_POS_MODE if mode == MODE_GROUND else 0
    if flags >> ACCEL & 1:
        bits |= mavlink.ESTIMATOR_ACCEL_ERROR
    if silent:  # nothing is measured: nothing is good
        return bits
    if not flags >> MAG & 1:
        bits |= mavlink.ESTIMATOR_ATTITUDE
    if wind_known and not flags >> ACCEL & 1:
        bits |= mavlink.ESTIMATOR_VELOCITY_HORIZ
    if not flags >> BARO & 1:
        bits |= mavlink.ESTIMATOR_VELOCITY_VERT | mavlink.ESTIMATOR_POS_VERT_AGL
    if mode == MODE_TAUT and not flags & (1 << ALIGN | 1 << RADIUS):
        bits |= mavlink.ESTIMATOR_POS_HORIZ_REL
    return bits


@dataclass(frozen=True)
class OutputConfig:
    """The ``[outputs]`` section. ``qgc_direction``: QGroundControl shows the wind's direction from whichever
    of WIND_COV (where the air goes TO) and WIND (where it comes FROM) came last. "to" (default): WIND before
    every tenth WIND_COV, so QGC holds WIND_COV's; "from": WIND after every WIND_COV, so QGC holds the
    meteorological direction (MAVProxy, Mission Planner and balloon-gs are the same either way)."""

    qgc_direction: str = "to"

    @classmethod
    def from_dict(cls, values: dict) -> OutputConfig:
        return build_section(cls, "outputs", values)


class Firmware:
    def __init__(
        self, design: Design, cfg: FilterConfig | None = None, sink=None, wind_cov_hz: float = 10.0,
        rate_explicit: bool = False, warn=print_warning, outputs: OutputConfig | None = None,
    ) -> None:  # fmt: skip
        self.design = design
        self.wind_after_each = (outputs or OutputConfig()).qgc_direction == "from"
        self.est, self.out = new_core(design, cfg or FilterConfig())
        self.sinks = [sink] if sink is not None else []
        self.mav = mavlink.MAVLink(None, srcSystem=FW_SYSID, srcComponent=FW_COMPID)
        self.period_us = round(1e6 / wind_cov_hz)
        self.params = parameters(design, 1e6 / self.period_us)  # what a ground station reads (fixed: the design's)
        self.stats = LinkStats()
        self.sampler = MavlinkSampler(design.site.ground_sysid)
        self.pipe = InputPipeline(self.est.cfg, rate_explicit, hold=self._hold)
        self.streams = None  # a live link's StreamRequester (cli.run_live), for its hold and summary
        self.warn = warn
        self.other_messages = 0
        self.samples_in = 0  # sensor samples (IMU and barometer) taken from the messages
        self.wind_cov_sent = 0
        self._next_wind_us = 0
        self._next_hb_us = 0
        self.imu_missing = 0  # IMU samples missing by their time stamps (what 8-bit sequences cannot count)
        self._prev_imu_us = -1
        self.clock = ClockGuard()
        self._recent_imu_us: deque[int] = deque(maxlen=RECENT_IMU)  # sample times seen lately (a late one's twin)
        # the consistency monitor's verdicts: filter steps in flight (where it judges), with each source flagged
        self.flight_steps = 0
        self.misfit_steps = [0] * len(SOURCES)
        self.texts_sent = 0
        self._last_step = 0
        self._told_flags = 0  # the flags the last STATUSTEXT told (0 before any: consistent)
        self._next_text_us = 0
        self.silent = False  # the sensors fell silent (``coast``): SYS_STATUS and ESTIMATOR_STATUS say so
        self.wind_sent = 0
        self._block: SampleBlock | None = None  # samples waiting for the C core (``use_batches``)
        self._block_t_us = -1  # the newest IMU sample's time put in the block

    def use_batches(self) -> None:
        """A file replay on the C core: the samples go to it a block at a time (``SampleBlock``, one call),
        handed over whenever an output may be due (the outputs then carry the same state and the same link
        statistics as one call a sample would give: the same bytes) and read back for the bookkeeping of
        each step. Whatever reads the estimator first runs what waits (``drain``)."""
        if hasattr(self.est, "on_batch"):
            self._block = SampleBlock(BATCH_SAMPLES)

    # ----------------------------------------------------------------- input

    def handle(self, msg, link=None) -> None:
        """One decoded message; ``link``: the link it came in on (live), where a request's answer goes."""
        samples = self.sampler.convert(msg)
        if samples is None:
            self.other_messages += 1
            if self._live:  # a ground station's request, answered on its own link (firmware_py/gcs.py)
                for frame in gcs.answer(self.mav, msg, self.params):
                    if link is None:
                        self._send(frame, max(self.est.t_last_us, 0))
                    else:
                        link.send(frame)
            return
        if samples and type(samples[-1]) is ImuSample:  # its time judged (ClockGuard), the barometer it carries with it
            for held in self.clock.admit(samples, self._prev_imu_us):
                for s in held:
                    self.push(s)
            return
        for s in samples:
            self.push(s)

    def push(self, s: Sample | GroundSample) -> None:
        """One sample from any source: through the input pipeline into the estimator."""
        if type(s) is WinchSample or type(s) is GroundBaroSample:
            self.drain()
            feed_ground(self.est, s)
            return
        self.silent = False
        self.samples_in += 1
        if type(s) is not BaroSample:
            self._track_imu_time(s.t_us)
        decided = self.pipe.decided
        out = self.pipe.push(s)
        if not decided:
            if self.pipe.decided:
                self._configure()
            elif self._live and type(s) is not BaroSample and s.t_us >= self._next_hb_us:
                self.heartbeat(s.t_us)  # still measuring the rate: a live link hears from us all the same
                self._next_hb_us = s.t_us + 1_000_000
        for r in out:
            self._step(r)

    def flush(self) -> None:
        """End of a file: decide the rate with what there is and run what is held."""
        self.clock.end()
        decided = self.pipe.decided
        out = self.pipe.flush()
        if not decided:
            self._configure()
        for r in out:
            self._step(r)
        self.drain()

    @property
    def _live(self) -> bool:
        return not any(hasattr(sink, "send_at") for sink in self.sinks)

    def _hold(self) -> bool:
        return self.streams is not None and self.streams.pending()

    def _configure(self) -> None:
        """The rate is known: the estimator runs at it (a new one only if it differs from the config's)."""
        d = self.pipe.decision
        if d.warning:
            self.warn(d.warning)
        if self.pipe.cfg.imu_rate_hz != self.est.cfg.imu_rate_hz:
            self.drain()
            self.est, self.out = new_core(self.design, self.pipe.cfg)
            if self._block is not None and not hasattr(self.est, "on_batch"):
                self._block = None

    def _step(self, s: Sample) -> None:
        blk = self._block
        if blk is not None:
            if type(s) is BaroSample:
                blk.add(s.t_us, SampleBlock.KIND_BARO, (s.pressure_hpa, s.temperature_c, *_BARO_PAD))
                if len(blk) >= BATCH_SAMPLES:
                    self.drain()
            else:
                t = s.t_us
                blk.add(t, SampleBlock.KIND_IMU, s[1:])
                back = t < self._block_t_us  # time going back may be a reboot: the outputs start again
                self._block_t_us = t
                if t >= self._next_wind_us or t >= self._next_hb_us or back or len(blk) >= BATCH_SAMPLES:
                    self.drain()  # its outputs may be due: now, with this message's link statistics
            return
        est = self.est
        if type(s) is BaroSample:
            est.on_baro(s.t_us, s.pressure_hpa, s.temperature_c)
            return
        resets = est.counters.time_resets
        if feed(est, s):
            self._judge(s.t_us)
            self.out.update(est, s.t_us)
            self.emit_due(s.t_us)
        if est.counters.time_resets != resets:
            self._time_reset(s.t_us)

    def _time_reset(self, t_us: int) -> None:
        """The estimator counted a reboot of the sender: the outputs start again."""
        est = self.est
        self.out.reset()
        self._next_wind_us = self._next_hb_us = self._next_text_us = 0
        self._last_step = est.step
        if self._told_flags and not est.consistency.flags:  # the reboot forgot the misfit: say so
            self.statustext(mavlink.MAV_SEVERITY_INFO, RESTARTED_TEXT, t_us)
            self._told_flags = 0

    def drain(self) -> None:
        """The samples waiting in the block (``use_batches``) through the C core, in pieces that end where
        the firmware must act (``CEstimator.on_batch``): each step counted as ``_judge`` counts it, and at
        the piece's last sample what ``_step`` does after ``feed`` (the output's update is the C call's)."""
        blk = self._block
        if blk is None or not len(blk):
            return
        blk.ready()
        self.run_block(blk)
        blk.clear()

    def run_block(self, blk: SampleBlock, done: int = 0) -> None:
        """``drain``'s work on a block whose arrays hold its ``n`` samples (``SampleBlock.ready``; the tlog
        scanner's block, firmware_py/replay.py, is filled in C). ``done``: its first piece has been through
        the C core already (the scanner ran it), what follows it has not."""
        est = self.est
        i, n = 0, blk.n
        while i < n:
            if done:
                end, done = done, 0
            else:
                end = i + est.on_batch(blk, i, min(self._next_wind_us, self._next_hb_us), self._told_flags,
                                       self._next_text_us)  # fmt: skip
            stepped = blk.stepped[i:end].tolist()
            steps, modes, flags = blk.steps[i:end].tolist(), blk.modes[i:end].tolist(), blk.flags[i:end].tolist()
            last = end - i - 1
            self._count_steps(stepped, steps, modes, flags, last)
            t = int(blk.t[end - 1])
            if stepped[last] & 1:
                self._judge(t)
                self.emit_due(t)
            if stepped[last] & 2:
                self._time_reset(t)
            i = end

    def _count_steps(self, stepped: list[int], steps: list[int], modes: list[int], flags: list[int], n: int) -> None:
        """``_count`` of each of the first ``n`` samples that stepped (``drain``'s pieces), in one loop."""
        last = self._last_step
        if n and 1 in (head := stepped[:n]):
            s = steps[:n]
            if s[0] >= last and MODE_GROUND not in modes[:n] and not any(flags[:n]) and s == sorted(s):
                # the usual piece, in flight, consistent, the step count rising: the counts telescope
                step = s[n - 1 - head[::-1].index(1)]
                self.flight_steps += step - last
                self._last_step = step
                return
        flight = 0
        misfit = self.misfit_steps
        for k in range(n):
            if stepped[k] & 1:
                step = steps[k]
                d = step - last
                last = step
                if d > 0 and modes[k] != MODE_GROUND:  # as _count: a step back counts none
                    flight += d
                    f = flags[k]
                    if f:
                        for i in range(len(SOURCES)):
                            if f >> i & 1:
                                misfit[i] += d
        self._last_step = last
        self.flight_steps += flight

    def _count(self, step: int, mode: int, flags: int) -> None:
        """The steps since the last count, in flight and with each source flagged."""
        steps = max(0, step - self._last_step)
        self._last_step = step
        if mode != MODE_GROUND:  # the monitor judges in flight only
            self.flight_steps += steps
            for i in range(len(SOURCES)):
                if flags >> i & 1:
                    self.misfit_steps[i] += steps

    def _judge(self, t_us: int) -> None:
        """After a filter step: count the steps in flight with each source flagged, and tell a change of
        the flags (STATUSTEXT, at most one a second: a change within the second is told after it)."""
        est = self.est
        flags = est.consistency.flags
        self._count(est.step, est.ekf.mode, flags)
        if flags == self._told_flags or t_us < self._next_text_us:
            return
        self._told_flags = flags
        self._next_text_us = t_us + TEXT_INTERVAL_US
        c = est.consistency
        if flags:
            self.statustext(mavlink.MAV_SEVERITY_WARNING, misfit_text(c.names(), c.inflation), t_us)
        else:
            self.statustext(mavlink.MAV_SEVERITY_INFO, CONSISTENT_TEXT, t_us)

    def _track_imu_time(self, t_us: int) -> None:
        """Count IMU samples missing between this one and the previous (at the filter's IMU rate). A late
        one (reordered, within a second) fills a hole it left: it is no longer missing (it is counted as
        reordered, once); a copy of a recent one changes nothing; time going back by more than a second is
        a restart."""
        prev = self._prev_imu_us
        recent = self._recent_imu_us
        if t_us > prev:
            if prev >= 0:
                self.imu_missing += max(0, (t_us - prev + self.est.dt_us // 2) // self.est.dt_us - 1)
            recent.append(t_us)
            self._prev_imu_us = t_us
        elif t_us >= prev - 1_000_000:
            if t_us not in recent:
                recent.append(t_us)
                self.imu_missing = max(0, self.imu_missing - 1)
        else:
            recent.clear()
            recent.append(t_us)
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
            mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC,
            mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, self.est.ekf.mode,  # custom_mode: the filter's mode
            mavlink.MAV_STATE_ACTIVE if self.est.initialised else mavlink.MAV_STATE_STANDBY,
        ))  # fmt: skip
        self._send(frame, t_us)
        self.sys_status(t_us)
        if self.est.initialised:
            self.estimator_status(t_us)
            self.source_counts(t_us)

    def source_counts(self, t_us: int) -> None:
        """What the filter made of each optional source it was given (``SOURCE_COUNTS``), as NAMED_VALUE_INT
        once a second: the live view shows ``winch: N used, M rejected`` as the summary does."""
        est = self.est
        for (name_used, name_rej), (used, rej) in zip(SOURCE_COUNTS, (
            (est.winch_samples, est.winch_rejected), (est.ground_samples, est.ground_rejected),
        )):  # fmt: skip
            if used or rej:
                ms = (t_us // 1000) & 0xFFFFFFFF
                for name, value in ((name_used, used), (name_rej, rej)):
                    self._send(pack(self.mav, self.mav.named_value_int_encode(ms, name.encode(), int(value))), t_us)

    def sys_status(self, t_us: int) -> None:
        """SYS_STATUS with each HEARTBEAT: the health a ground station (or a lockstep sender) shows.
        ``drop_rate_comm`` = input packets lost (c%), ``errors_comm`` = corrupt input frames,
        ``errors_count1`` = input packets lost, ``errors_count2`` = filter resets (reboot + numeric +
        taut + baro), ``errors_count3`` = long input gaps, ``errors_count4`` = IMU samples missing by
        their time stamps.

        Sensors present and enabled: gyro, accelerometer, magnetometer, absolute pressure and AHRS (the
        estimator). Healthy: all of them unless the consistency monitor flags a source, whose bit is then
        cleared (``MISFIT_HEALTH_BITS``): accel -> 3D_ACCEL, baro -> ABSOLUTE_PRESSURE, mag -> 3D_MAG,
        align and radius (the tether model) -> AHRS. The gyro has no innovation and stays healthy, unless
        the sensors are silent: then every sensor bit is cleared (``SILENT_HEALTH_BITS``)."""
        c, st = self.est.counters, self.stats
        sensors = SENSOR_BITS
        health = sensors & ~misfit_health(self.est.consistency.flags)
        if self.silent:
            health &= ~SILENT_HEALTH_BITS
        resets = c.time_resets + c.numeric_resets + c.taut_resets + c.baro_resets
        frame = pack(self.mav, self.mav.sys_status_encode(
            sensors, sensors, health, 0, 0xFFFF, -1, -1, min(round(10000 * st.lost_fraction()), 10000),
            min(st.bad_frames, 0xFFFF), min(st.lost, 0xFFFF), min(resets, 0xFFFF), min(c.long_gaps, 0xFFFF),
            min(self.imu_missing, 0xFFFF),
        ))  # fmt: skip
        self._send(frame, t_us)

    def estimator_status(self, t_us: int) -> None:
        """ESTIMATOR_STATUS (230) at 1 Hz: ``estimator_flags``; the ratios are the consistency monitor's
        windowed NIS over its flag threshold (1 = flagged): vel_ratio accel, pos_horiz_ratio align,
        pos_vert_ratio baro, mag_ratio mag, hagl_ratio radius, tas_ratio the largest of the six (the wind's accuracy
        factor is the square root of the largest as consistency.stated_nis counts it: the accelerometer's NIS as
        (1 + NIS) / 2); the position's 1-sigma from P."""
        est = self.est
        c, P = est.consistency, est.ekf.P
        bits = estimator_flags(est.initialised, self.silent, est.ekf.mode, c.flags, self.wind_known())
        r = [v / FLAG_NIS for v in c.nis]
        frame = pack(self.mav, self.mav.estimator_status_encode(
            max(est.t_last_us, 0), bits, r[ACCEL], r[ALIGN], r[BARO], r[MAG], r[RADIUS], max(r),
            math.sqrt(float(P[POS_N, POS_N] + P[POS_E, POS_E])), math.sqrt(float(P[POS_D, POS_D])),
        ))  # fmt: skip
        self._send(frame, t_us)

    def wind_known(self) -> bool:
        """Is the wind known: the sensors heard, in flight (not resting on the ground), not an unconfirmed
        join in flight, and an accuracy below what the wind itself could be (``wind_unknown``)?"""
        est = self.est
        if not est.initialised or self.silent or est.ekf.mode == MODE_GROUND or est.unconfirmed:
            return False
        wn, we = est.wind()
        return not wind_unknown(math.hypot(wn, we), est.wind_accuracy())

    def wind(self, t_us: int) -> None:
        """WIND (168), the estimate WIND_COV carries (``wind_fields``)."""
        self._send(pack(self.mav, self.mav.wind_encode(*wind_fields(*self.est.wind()))), t_us)
        self.wind_sent += 1

    def statustext(self, severity: int, text: str, t_us: int) -> None:
        """A STATUSTEXT (one chunk: ``id`` 0), ASCII, at most ``TEXT_MAX`` characters."""
        data = text.encode("ascii", "replace")[:TEXT_MAX]
        self._send(pack(self.mav, self.mav.statustext_encode(severity, data)), t_us)
        self.texts_sent += 1

    def wind_cov(self, t_us: int) -> None:
        """WIND_COV, and before every ``WIND_EVERY``-th one WIND (once the filter has started); with
        ``[outputs] qgc_direction = "from"`` WIND after every one instead (``OutputConfig``)."""
        if not self.wind_after_each and self.wind_cov_sent % WIND_EVERY == 0 and self.est.initialised:
            self.wind(t_us)
        self._send(PACK_WIND_COV(self.mav, *self.out.fields(self.est)), t_us)
        self.wind_cov_sent += 1
        if self.wind_after_each and self.est.initialised:
            self.wind(t_us)

    def _send(self, frame: bytes, t_us: int) -> None:
        for sink in self.sinks:
            if hasattr(sink, "send_at"):
                sink.send_at(frame, t_us)
            else:
                sink.send(frame)

    def coast(self, now_s: float) -> None:
        """Sensors silent: keep talking (WIND_COV every call, HEARTBEAT each second), honestly."""
        self.drain()
        self.est.coast(0.1)
        self.silent = True
        t = max(self.est.t_last_us, 0)
        if now_s - getattr(self, "_last_hb_wall", 0.0) >= 1.0:
            self._last_hb_wall = now_s
            self.heartbeat(t)
        self.wind_cov(t)

    def summary(self) -> str:
        self.drain()
        c = self.est.counters
        return (
            f"balloon-fw: {c.imu_samples} IMU samples, {c.baro_samples} baro samples, "
            f"{c.rejected} rejected, {self.stats.bad_frames} bad frames"
            f"{' (the file ends inside a frame)' if self.stats.truncated else ''}, "
            f"{self.stats.garbage_bytes} garbage bytes, {self.other_messages} other messages, "
            f"{self.sampler.ignored} from other sensor instances, "
            f"{self.sampler.bad_time} with an impossible time, {self.sampler.stuck} with a stuck sensor, "
            f"{self.sampler.bad_mag} magnetometer and {self.sampler.bad_temperature} thermometer readings not numbers, "
            f"{self.clock.glitches} off the IMU's clock, {self.clock.new_clocks} new IMU clocks, "
            f"{self.sampler.baro_beside} pressure messages not needed (the IMU messages carry the barometer), "
            f"{c.duplicates + self.pipe.duplicates} duplicates, "
            f"{c.reordered + self.pipe.reordered} reordered, {c.gaps} gaps, {c.long_gaps} long gaps, "
            f"resets: {c.time_resets} reboot, {c.numeric_resets} numeric, {c.taut_resets} taut, "
            f"{c.baro_resets} baro, {c.false_releases} false release, {c.mode_switches} mode switches, "
            f"{c.field_jumps} jumps of the magnetometer's own field, "
            f"{self.wind_cov_sent} WIND_COV sent, {self.wind_sent} WIND sent, final mode {self.est.mode_name}"
            f"{'' if self.est.initialised or not c.rejected else NEVER_STARTED}, "
            f"filter at {self.est.cfg.imu_rate_hz:g} Hz{self._rate_note()} on the {self._core_name()}, "
            f"input packets {self.stats.loss_summary()}, {self.imu_missing} IMU samples missing by time, "
            f"{winch_counts(self.est)}, {ground_counts(self.est)}"
            f"{self._consistency_note()}" + (self.streams.summary() if self.streams is not None else "")
        )

    def _consistency_note(self) -> str:
        """``, model misfit: accel 12 % of flight time, align 3 %`` (each flagged source's share of the
        filter steps in flight), ``, model consistent`` if none was ever flagged in flight."""
        if self.flight_steps == 0:
            return ", model not judged (never in flight)"
        parts = []
        for name, steps in zip(SOURCES, self.misfit_steps):
            if steps:
                pct = 100.0 * steps / self.flight_steps
                parts.append(f"{name} {pct:.0f} %" if pct >= 1.0 else f"{name} <1 %")
        if not parts:
            return ", model consistent"
        parts[0] += " of flight time"
        return ", model misfit: " + ", ".join(parts)

    def _core_name(self) -> str:
        real = "float32" if self.est.cfg.float32 else "float64"
        return f"C core ({real})" if self.est.cfg.core == "c" else f"Python core ({real})"

    def _rate_note(self) -> str:
        d = self.pipe.decision
        if d is None or d.stream_hz is None:
            return ""
        return f" (IMU stream {d.stream_hz:.1f} Hz{', averaged' if d.resample else ''})"

    def status(self) -> str:
        """Health and estimate at a glance (the live status line): input loss first (what a narrow
        terminal must show), then mode, wind, accuracy."""
        self.drain()
        est = self.est
        if not est.initialised:
            return f"waiting for the sensors, {self.stats.lost} lost"
        wn, we = est.wind()
        if self.wind_known():
            wind = f"wind {math.hypot(wn, we):.1f} m/s from {direction_from_deg(wn, we):03.0f} deg"
        else:
            wind = "wind not known"  # not the filter's calm from 180 deg
        wind += f" \u00b1{est.wind_accuracy():.2f}"
        return (f"{self.stats.lost} lost ({100 * self.stats.lost_fraction():.1f} %), {self.imu_missing} IMU missing, "
                f"{est.counters.long_gaps} long gaps, mode {est.mode_name}, {wind}"
                + (f", misfit {','.join(est.consistency.names())}" if est.consistency.flags else ""))  # fmt: skip
