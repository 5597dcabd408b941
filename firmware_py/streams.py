"""Between the samples and the estimator: the IMU rate measured from the stream, the filter's rate
chosen from it, a faster stream averaged down to the filter's step; and, on a live link to an autopilot,
asking it for the sensor streams at the rate the filter needs.

Every input goes through ``InputPipeline`` (the live firmware and ``estimator_steps`` for post-flight
reprocessing alike), so both see the same samples."""

from __future__ import annotations

import math
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design
from balloon_core.samples import (
    HIGHRES_IMUS,
    IMU_MESSAGES,
    MSG_HIGHRES_IMU,
    MSG_SCALED_IMU,
    MSG_SCALED_PRESSURE,
    PRESSURE_MESSAGES,
    GroundSample,
    ImuSample,
    Sample,
    WinchSample,
)
from balloon_core.wire import pack
from firmware_py.estimator.control import Estimator, valid_imu
from firmware_py.estimator.params import REORDER_WINDOW_US
from firmware_py.estimator.state import FilterConfig

RATE_WINDOW_S = 2.0  # the IMU rate is the median sample interval over this much of the stream
RATE_SETTLE_MAX_S = 6.0  # a stream slower than the filter's rate: wait this long for it to speed up
RATE_TOLERANCE = 0.1  # within 10 % of the filter's rate the estimator's own clock takes the jitter
QUICK_WINDOW_S = 0.25  # a stream already at the filter's rate over this much is decided at once
MAX_HELD = 20_000  # samples held while the rate is measured (bounds memory whatever the stream)


def feed_ground(est: Estimator, s: GroundSample) -> bool:
    """A sample from the ground into the estimator, on the sensor clock: the winch's and the ground
    station's clocks are not the balloon's, so it counts from the newest sensor sample (its arrival)."""
    t = max(est.t_last_us, 0)
    if type(s) is WinchSample:
        return est.on_winch(t, s.line_length_m, s.speed_mps, s.tension_n)
    return est.on_ground_baro(t, s.pressure_hpa, s.temperature_c)


def feed(est: Estimator, s: Sample) -> bool:
    """Hand one sample to the estimator. Returns True when the filter advanced (an IMU step)."""
    if type(s) is ImuSample:
        return est.on_imu(s.t_us, s.ax, s.ay, s.az, s.gx, s.gy, s.gz, s.mx, s.my, s.mz)
    est.on_baro(s.t_us, s.pressure_hpa, s.temperature_c)
    return False


# ------------------------------------------------------------------------------------------ the rate


def measure_rate_hz(t_us: Iterable[int]) -> float | None:
    """Sample rate from timestamps: 1 / median interval between distinct times (robust to loss,
    duplicates, reordering and jitter). None with fewer than two distinct times."""
    t = sorted(set(t_us))
    if len(t) < 2:
        return None
    d = sorted(b - a for a, b in zip(t, t[1:]))
    return 1e6 / d[len(d) // 2]


@dataclass(frozen=True)
class RateDecision:
    stream_hz: float | None  # measured (None: too few samples)
    filter_hz: float  # the estimator's fixed step rate
    resample: bool  # average the stream down to filter_hz
    warning: str | None  # one line for stderr, or None


def decide_rate(stream_hz: float | None, cfg_hz: float, explicit: bool) -> RateDecision:
    """The filter's rate. ``cfg_hz`` is ``[filter] imu_rate_hz`` (``explicit``: the config sets it, else
    it is the default, the rate the filter is tuned at). Within 10 % the filter runs at cfg_hz and
    takes the samples as they come; a faster stream is averaged down to cfg_hz; a slower one sets the
    filter's rate, unless the config gives it explicitly (then the filter predicts through the gaps).
    An explicit rate that the stream contradicts by more than 10 % is warned about."""
    if stream_hz is None:
        return RateDecision(None, cfg_hz, False, None)
    ratio = stream_hz / cfg_hz
    warning = None
    if explicit and abs(ratio - 1.0) > RATE_TOLERANCE:
        warning = (f"[filter] imu_rate_hz = {cfg_hz:g} but the IMU stream runs at {stream_hz:.1f} Hz; "
                   f"using {cfg_hz:g} Hz")  # fmt: skip
    if ratio > 1.0 + RATE_TOLERANCE:
        return RateDecision(stream_hz, cfg_hz, True, warning)
    if ratio < 1.0 - RATE_TOLERANCE and not explicit:
        return RateDecision(stream_hz, round(stream_hz, 1), False, None)
    return RateDecision(stream_hz, cfg_hz, False, warning)


def _valid_imu(s: ImuSample) -> bool:
    return valid_imu(s.ax, s.ay, s.az, s.gx, s.gy, s.gz)


class Resampler:
    """A stream faster than the filter, averaged to its step: the valid IMU samples whose times fall in
    one step (bins of 1/rate on the sensor's clock, centred on its first sample's time + k steps) become
    one sample stamped with the bin's centre. The times are the log's own: a gap stays a gap, a dropout
    a dropout; the jitter and the lost samples inside a step do not move the estimator's clock (a mean
    of the times would, by up to half a step, and make it count spurious jitter and gaps). The
    magnetometer is the mean of the bin's readings (NaN if none). Barometer samples and samples
    the estimator will reject pass straight through; a sample older than the open bin is dropped and
    counted (``reordered``), one repeating the last time too (``duplicates``); time going back by more
    than the estimator's reorder window is a reboot: the bins start again from it."""

    def __init__(self, rate_hz: float) -> None:
        self.dt_us = round(1e6 / rate_hz)
        self.t0: int | None = None
        self.k = 0
        self.n = 0
        self.mag_n = 0
        self.sum = [0.0] * 9  # a(3), g(3), m(3)
        self.last_t = -1
        self.duplicates = 0
        self.reordered = 0

    def push(self, s: Sample) -> list[Sample]:
        if type(s) is not ImuSample or not _valid_imu(s):
            return [s]
        t = s.t_us
        if self.t0 is None:
            self.t0 = t
        k = (t - self.t0 + self.dt_us // 2) // self.dt_us
        out: list[Sample] = []
        if self.n and k != self.k:
            if t == self.last_t:
                self.duplicates += 1
                return out
            if k < self.k:
                if self.last_t - t <= REORDER_WINDOW_US:
                    self.reordered += 1
                    return out
                out.append(self._close())  # a reboot: start the bins again from this sample
                self.t0 = t
                k = 0
            else:
                out.append(self._close())
        elif self.n and t == self.last_t:
            self.duplicates += 1
            return out
        self.k = k
        self._add(s)
        return out

    def flush(self) -> list[Sample]:
        return [self._close()] if self.n else []

    def _add(self, s: ImuSample) -> None:
        acc = self.sum
        for i, v in enumerate((s.ax, s.ay, s.az, s.gx, s.gy, s.gz)):
            acc[i] += v
        if math.isfinite(s.mx) and math.isfinite(s.my) and math.isfinite(s.mz):
            acc[6] += s.mx
            acc[7] += s.my
            acc[8] += s.mz
            self.mag_n += 1
        self.n += 1
        self.last_t = s.t_us

    def _close(self) -> ImuSample:
        acc, n, m = self.sum, self.n, self.mag_n
        mag = (acc[6] / m, acc[7] / m, acc[8] / m) if m else (math.nan, math.nan, math.nan)
        out = ImuSample(self.t0 + self.k * self.dt_us, *(v / n for v in acc[:6]), *mag)
        self.sum = [0.0] * 9
        self.n = self.mag_n = 0
        return out


class InputPipeline:
    """Samples in, samples for the estimator out. Holds the first samples until the IMU rate is known
    (at once after ``QUICK_WINDOW_S`` if the stream runs at the filter's rate; otherwise after
    ``RATE_WINDOW_S`` of valid IMU samples on the sensor's clock; if that window is slower than the
    filter's rate it waits up to ``RATE_SETTLE_MAX_S`` for the stream to speed up, as it does once an
    autopilot has been asked for its streams), then decides the filter's rate (``decide_rate``) and
    releases everything held, averaged down (``Resampler``) when the stream is faster than the filter.
    ``hold`` (a callable) keeps the decision open while a live stream request is under way."""

    def __init__(self, cfg: FilterConfig, rate_explicit: bool = False, hold: Callable[[], bool] | None = None) -> None:
        self.base_cfg = cfg
        self.explicit = rate_explicit
        self.hold = hold
        self.decision: RateDecision | None = None
        self.cfg: FilterConfig | None = None  # the estimator's config, once decided
        self.resampler: Resampler | None = None
        self._held: deque[Sample] = deque()
        self._imu_t: deque[int] = deque()
        self._t_first: int | None = None

    @property
    def decided(self) -> bool:
        return self.decision is not None

    @property
    def duplicates(self) -> int:
        return self.resampler.duplicates if self.resampler else 0

    @property
    def reordered(self) -> int:
        return self.resampler.reordered if self.resampler else 0

    def push(self, s: Sample) -> list[Sample]:
        if self.decision is not None:
            return self.resampler.push(s) if self.resampler else [s]
        self._held.append(s)
        if len(self._held) > MAX_HELD:
            self._held.popleft()
        if type(s) is not ImuSample or not _valid_imu(s):
            return []
        t = s.t_us
        if self._imu_t and self._imu_t[-1] - t > REORDER_WINDOW_US:  # a reboot while measuring
            return self._decide(list(self._imu_t))
        if self._t_first is None:
            self._t_first = t
        self._imu_t.append(t)
        while self._imu_t[-1] - self._imu_t[0] > RATE_WINDOW_S * 1e6 + 1:
            self._imu_t.popleft()  # the last RATE_WINDOW_S
        if self.hold is not None and self.hold():
            return []
        span = self._imu_t[-1] - self._imu_t[0]
        if span < RATE_WINDOW_S * 1e6 - 1:
            # the common case decides at once: a stream at the filter's own rate over QUICK_WINDOW_S
            # (a lockstep sender waiting for WIND_COV then never waits on the measurement)
            quick = measure_rate_hz(self._imu_t) if span >= QUICK_WINDOW_S * 1e6 else None
            if quick is None or abs(quick / self.base_cfg.imu_rate_hz - 1.0) > RATE_TOLERANCE:
                return []
            return self._decide(list(self._imu_t))
        rate = measure_rate_hz(self._imu_t)
        slow = rate is not None and rate < (1.0 - RATE_TOLERANCE) * self.base_cfg.imu_rate_hz
        if slow and t - self._t_first < RATE_SETTLE_MAX_S * 1e6:
            return []
        return self._decide(list(self._imu_t))

    def flush(self) -> list[Sample]:
        """End of the input: decide with what there is (if undecided) and release everything."""
        out = self._decide(list(self._imu_t)) if self.decision is None else []
        if self.resampler is not None:
            out += self.resampler.flush()
        return out

    def _decide(self, times: list[int]) -> list[Sample]:
        self.decision = decide_rate(measure_rate_hz(times), self.base_cfg.imu_rate_hz, self.explicit)
        self.cfg = replace(self.base_cfg, imu_rate_hz=self.decision.filter_hz)
        if self.decision.resample:
            self.resampler = Resampler(self.decision.filter_hz)
        held, self._held = list(self._held), deque()
        self._imu_t.clear()
        if self.resampler is None:
            return held
        out: list[Sample] = []
        for s in held:
            out += self.resampler.push(s)
        return out


def estimator_steps(
    design: Design,
    cfg: FilterConfig,
    samples: Iterable[Sample],
    rate_explicit: bool = False,
    warn: Callable[[str], None] | None = None,
) -> Iterator[tuple[Estimator, Sample, bool]]:
    """Post-flight: run samples (e.g. ``postflight.logs.read_flight(path).samples()``) through
    the same pipeline as the live firmware into an Estimator built at the chosen rate. Yields
    ``(estimator, sample_fed, advanced)`` after every sample handed to it (``advanced``: a filter step
    was taken, the moment to record the state). ``warn`` gets the one-line rate warning, if any."""
    pipe = InputPipeline(cfg, rate_explicit)
    est: Estimator | None = None

    def run(batch: list[Sample]) -> Iterator[tuple[Estimator, Sample, bool]]:
        nonlocal est
        if est is None and batch:
            from firmware_py.core_c import new_core  # the core [filter] core names

            est, _ = new_core(design, pipe.cfg)
            if pipe.decision.warning and warn is not None:
                warn(pipe.decision.warning)
        for s in batch:
            yield est, s, feed(est, s)

    for s in samples:
        out = pipe.push(s)
        if out:
            yield from run(out)
    yield from run(pipe.flush())


# ------------------------------------------------------------------------------- live stream requests

ACK_TIMEOUT_S = 1.0
SET_INTERVAL_TRIES = 3
DATA_STREAM_TRIES = 3
DATA_STREAM_EVERY_S = 2.0
SETTLE_S = 1.0  # after the autopilot's first HEARTBEAT, how long its streams are watched before asking
RECHECK_S = 3.0  # after an accepted request, how long the stream has to come up to rate
RATE_WINDOW_WALL_S = 2.0
ENOUGH = 0.7  # a stream arriving at less than this fraction of the rate asked for is asked for again
BARO_RATE_HZ = 20.0
FAILED_RESULTS = frozenset({
    mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_UNSUPPORTED, mavlink.MAV_RESULT_FAILED,
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
})  # fmt: skip


def is_autopilot(hb) -> bool:
    """A flight controller's HEARTBEAT: not a ground station, not our simulator (autopilot INVALID), not
    another balloon firmware (FREE_BALLOON + GENERIC)."""
    if hb.autopilot == mavlink.MAV_AUTOPILOT_INVALID or hb.type == mavlink.MAV_TYPE_GCS:
        return False
    return not (hb.type == mavlink.MAV_TYPE_FREE_BALLOON and hb.autopilot == mavlink.MAV_AUTOPILOT_GENERIC)


class _Want:
    __slots__ = ("msg_id", "rate_hz", "state", "tries", "t_sent", "t_state")

    def __init__(self, msg_id: int, rate_hz: float) -> None:
        self.msg_id, self.rate_hz = msg_id, rate_hz
        self.state = "idle"  # idle -> waiting -> accepted | fallback; done / given_up
        self.tries = 0
        self.t_sent = self.t_state = 0.0


class StreamRequester:
    """On a live link: once an autopilot's HEARTBEAT is heard and its IMU (or pressure) messages do not
    arrive at the rate the filter needs, ask for them with MAV_CMD_SET_MESSAGE_INTERVAL (COMMAND_LONG,
    interval in us) for the IMU message in use (else HIGHRES_IMU from PX4, SCALED_IMU from others) and,
    unless the IMU message carries the barometer, the pressure message in use (else SCALED_PRESSURE).
    No COMMAND_ACK within 1 s: ask again, 3 times; refused (DENIED, UNSUPPORTED, FAILED) or never
    answered: REQUEST_DATA_STREAM (MAV_DATA_STREAM_RAW_SENSORS) instead, up to 3 times, 2 s apart,
    while the streams stay slow. Frames come out of ``poll``; the caller sends them on the link."""

    def __init__(self, mav, sampler, imu_rate_hz: float, baro_rate_hz: float = BARO_RATE_HZ) -> None:
        self.mav = mav  # the firmware's own MAVLink encoder (one sequence number on the link)
        self.sampler = sampler
        self.imu_rate_hz = imu_rate_hz
        self.baro_rate_hz = baro_rate_hz
        self.target: tuple[int, int] | None = None
        self.autopilot = None
        self.t_heard = 0.0
        self.wants: dict[str, _Want] = {}
        self.arrivals: dict[str, deque[float]] = {"imu": deque(), "baro": deque()}
        self.interval_sent = self.accepted = self.refused = self.unanswered = 0
        self.data_stream_sent = 0
        self._data_stream_tries = 0
        self._t_data_stream = -1e9
        self._fallback = False
        self._now = 0.0

    # ----------------------------------------------------------------- what arrives

    def on_message(self, msg, now: float) -> None:
        self._now = now
        mid = msg.get_msgId()
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            if self.target is None and is_autopilot(msg):
                self.target = (msg.get_srcSystem(), msg.get_srcComponent())
                self.autopilot = msg.autopilot
                self.t_heard = now
            return
        if self.target is None or msg.get_srcSystem() != self.target[0]:
            return
        imu_key, baro_key = self.sampler.imu_key, self.sampler.baro_key
        if mid in IMU_MESSAGES:
            if imu_key is None or imu_key[0] == mid:  # the instance in use (the others do not count)
                self.arrivals["imu"].append(now)
                if mid in HIGHRES_IMUS and self.sampler.embedded_baro:
                    self.arrivals["baro"].append(now)
        elif mid in PRESSURE_MESSAGES:
            if baro_key is None or baro_key[0] == mid:
                self.arrivals["baro"].append(now)
        elif mid == mavlink.MAVLINK_MSG_ID_COMMAND_ACK and msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            if getattr(msg, "target_system", 0) not in (0, self.mav.srcSystem):
                return
            waiting = sorted((w for w in self.wants.values() if w.state == "waiting"), key=lambda w: w.t_sent)
            if not waiting or msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
                return
            w = waiting[0]  # acknowledgements come in the order of the commands
            if msg.result == mavlink.MAV_RESULT_ACCEPTED:
                self.accepted += 1
                w.state, w.t_state = "accepted", now
            elif msg.result in FAILED_RESULTS:
                self.refused += 1
                w.state, w.t_state = "fallback", now

    def rate_hz(self, kind: str) -> float:
        q = self.arrivals[kind]
        while q and q[0] < self._now - RATE_WINDOW_WALL_S:
            q.popleft()
        return len(q) / RATE_WINDOW_WALL_S

    def _needed(self) -> dict[str, tuple[int, float]]:
        s = self.sampler
        need = {}
        if s.imu_key is not None and s.imu_key[1] == self.target[0]:
            imu_id = s.imu_key[0]
        else:
            imu_id = MSG_HIGHRES_IMU if self.autopilot == mavlink.MAV_AUTOPILOT_PX4 else MSG_SCALED_IMU
        need["imu"] = (imu_id, self.imu_rate_hz)
        if not (s.embedded_baro or (imu_id in HIGHRES_IMUS and self.autopilot == mavlink.MAV_AUTOPILOT_PX4)):
            ours = s.baro_key is not None and s.baro_key[1] == self.target[0]
            baro_id = s.baro_key[0] if ours else MSG_SCALED_PRESSURE
            need["baro"] = (baro_id, self.baro_rate_hz)
        return need

    # ----------------------------------------------------------------- what to send

    def pending(self) -> bool:
        """A request is under way (the rate measurement should wait for its effect)."""
        if self.target is None:
            return False
        if self._now - self.t_heard < SETTLE_S:
            return True
        if any(w.state in ("waiting", "accepted") for w in self.wants.values()):
            return True
        return self._fallback and self._data_stream_tries < DATA_STREAM_TRIES and self._slow()

    def _slow(self) -> bool:
        return any(self.rate_hz(k) < ENOUGH * self.wants[k].rate_hz for k in self.wants)

    def poll(self, now: float) -> list[bytes]:
        self._now = now
        if self.target is None or now - self.t_heard < SETTLE_S:
            return []
        out: list[bytes] = []
        for kind, (msg_id, rate) in self._needed().items():
            w = self.wants.get(kind)
            if w is None or (w.msg_id != msg_id and w.state in ("idle", "done")):
                w = self.wants[kind] = _Want(msg_id, rate)
            slow = self.rate_hz(kind) < ENOUGH * rate
            if w.state == "idle" and slow:
                out.append(self._set_interval(w, now))
            elif w.state == "waiting" and now - w.t_sent >= ACK_TIMEOUT_S:
                if w.tries < SET_INTERVAL_TRIES:
                    out.append(self._set_interval(w, now))
                else:
                    self.unanswered += 1
                    w.state, w.t_state = "fallback", now
            elif w.state == "accepted" and now - w.t_state >= RECHECK_S:
                w.state = "done" if not slow else "fallback"
            if w.state == "fallback":
                self._fallback = True
        if self._fallback and self._data_stream_tries < DATA_STREAM_TRIES and self._slow():
            if now - self._t_data_stream >= DATA_STREAM_EVERY_S:
                out.append(self._data_stream(now))
        return out

    def _set_interval(self, w: _Want, now: float) -> bytes:
        w.tries += 1
        w.state, w.t_sent = "waiting", now
        self.interval_sent += 1
        sysid, compid = self.target
        interval_us = round(1e6 / w.rate_hz)
        return pack(self.mav, self.mav.command_long_encode(
            sysid, compid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, w.tries - 1, w.msg_id, interval_us, 0, 0, 0, 0, 0
        ))  # fmt: skip

    def _data_stream(self, now: float) -> bytes:
        self._data_stream_tries += 1
        self._t_data_stream = now
        self.data_stream_sent += 1
        sysid, compid = self.target
        rate = max(1, math.ceil(self.imu_rate_hz))
        return pack(self.mav, self.mav.request_data_stream_encode(
            sysid, compid, mavlink.MAV_DATA_STREAM_RAW_SENSORS, rate, 1
        ))  # fmt: skip

    def summary(self) -> str:
        if self.target is None:
            return ""
        return (
            f", stream requests: {self.interval_sent} SET_MESSAGE_INTERVAL ({self.accepted} accepted, "
            f"{self.refused} refused, {self.unanswered} unanswered), {self.data_stream_sent} REQUEST_DATA_STREAM"
        )


def print_warning(line: str) -> None:
    print(f"balloon-fw: {line}", file=sys.stderr)
