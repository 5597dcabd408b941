"""What the browser ground station shows of each balloon, computed from its WIND_COV stream: pure
computation (no I/O, no clock of its own: every time is an argument, in seconds).

- the WMO means (WMO-No. 8, Vol. I, Ch. 5) over the last 2 and 10 minutes: the scalar mean speed and the
  direction of the vector mean (FROM, 0-360 deg: 350 deg and 10 deg average to 0 deg, never 180 deg);
- the gust: the highest 3-s running mean of the speed whose window lies wholly within the last 10 minutes;
- these windows on the flight's own clock (``FlightClock``: WIND_COV ``time_usec`` where it is known and goes
  forward, so a log replayed at ``--speed 10`` is averaged over 2 minutes of flight, not of replay), on the
  arrival times where it is not;
- the charts' series, decimated to at most ``PUSH_HZ`` samples a second per balloon, and the hour's series
  as one-second means;
- during a winched flight, the profile building up: per winch leg (the reel paying out or reeling in), the
  wind's vector mean in height bins of ``postflight.profile.BIN_M`` against WIND_COV ``wind_alt``, with
  the stated accuracy as the error bar.

Winds are the air's velocity TOWARD north (``n``) and east (``e``) as WIND_COV carries them. Samples whose
wind is not known (``balloon_core.score.wind_unknown``, or not a finite number) are left out of the means, the
gust and the profile (as the products leave them out), and shown on the charts as gaps."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from balloon_core.score import direction_from_deg, wind_unknown
from balloon_core.wire import MAX_CLOCK_STEP_US
from postflight.averages import GUST_WINDOW_S
from postflight.profile import BIN_M

SHORT_MEAN_S = 120.0  # WMO: the 2-minute mean (aviation reports)
LONG_MEAN_S = 600.0  # WMO: the 10-minute mean, and the period of the gust
HOUR_S = 3600.0  # the long chart
HOUR_BIN_S = 1.0  # the long chart's resolution: one-second means
PUSH_HZ = 10.0  # at most this many samples a second per balloon go to the browser
REEL_DEADBAND_MPS = 0.05  # the winch's reel slower than this is stopped: no leg
WINCH_FRESH_S = 3.0  # a WINCH_STATUS older than this says nothing of the reel now
DIRECTION_SIGMA_CAP_DEG = 180.0  # the direction's error bar when the speed is within its accuracy
RECENT_MAX = int(LONG_MEAN_S * 100)  # the statistics keep at most 10 minutes at 100 Hz (whatever a clock says)


def speed_from(n: float, e: float) -> tuple[float, float]:
    """(speed m/s, direction FROM deg in [0, 360)) of the air's velocity toward north ``n`` and east ``e``."""
    return math.hypot(n, e), float(direction_from_deg(n, e))


def wind_known(n: float, e: float, acc: float) -> bool:
    """A wind worth a sample of the means: finite components, and known (``balloon_core.score.wind_unknown``)."""
    return math.isfinite(n) and math.isfinite(e) and not bool(wind_unknown(math.hypot(n, e), acc))


def direction_sigma_deg(speed_mps: float, accuracy_mps: float) -> float:
    """The direction's 1-sigma of a wind of this speed with this horizontal accuracy (small-angle), capped."""
    if not (speed_mps > 0.0) or not math.isfinite(accuracy_mps):
        return DIRECTION_SIGMA_CAP_DEG
    return min(math.degrees(accuracy_mps / speed_mps), DIRECTION_SIGMA_CAP_DEG)


@dataclass(frozen=True)
class Mean:
    """A WMO mean over a period: scalar mean speed (m/s), direction of the vector mean (FROM, deg), and
    the span of time the samples cover (s) and their count."""

    speed_mps: float
    from_deg: float
    span_s: float
    count: int


def wmo_mean(t: np.ndarray, n: np.ndarray, e: np.ndarray, now: float, period_s: float) -> Mean | None:
    """The mean over the samples in (now - period_s, now]; None without any."""
    sel = t > now - period_s
    if not np.any(sel):
        return None
    tn, nn, ee = t[sel], n[sel], e[sel]
    return Mean(float(np.mean(np.hypot(nn, ee))), float(direction_from_deg(np.mean(nn), np.mean(ee))),
                float(tn[-1] - tn[0]), int(tn.size))  # fmt: skip


def gust(t: np.ndarray, speed: np.ndarray, start: float, window_s: float = GUST_WINDOW_S) -> float:
    """The highest running mean of ``speed`` over ``window_s`` (the samples in (t_i - window_s, t_i]) whose
    window lies wholly after ``start`` (t_i - window_s >= start); NaN if no window fits. ``t`` ascending."""
    if t.size == 0:
        return math.nan
    csum = np.concatenate([[0.0], np.cumsum(speed)])
    ends = np.nonzero(t - window_s >= start - 1e-9)[0]
    if ends.size == 0:
        return math.nan
    starts = np.searchsorted(t, t[ends] - window_s, side="right")
    counts = ends + 1 - starts
    means = (csum[ends + 1] - csum[starts]) / counts
    return float(np.max(means))


class Decimator:
    """At most ``max_hz`` samples a second: a sample is taken when it is due (one interval after the last
    due time) or at most ``JITTER`` of an interval early, so that a stream at ``max_hz`` whose arrival times
    jitter passes whole; any faster stream is thinned to ``max_hz``. Over any ``W`` seconds at most
    ``W * max_hz + 2`` are taken."""

    JITTER = 0.25  # of an interval

    def __init__(self, max_hz: float = PUSH_HZ) -> None:
        self.interval_s = 1.0 / max_hz
        self.early_s = self.JITTER * self.interval_s
        self._due: float | None = None
        self.taken = 0
        self.dropped = 0

    def take(self, t: float) -> bool:
        if self._due is not None and t < self._due - self.early_s:
            self.dropped += 1
            return False
        self._due = (t if self._due is None else max(self._due, t - self.early_s)) + self.interval_s
        self.taken += 1
        return True


class FlightClock:
    """The statistics' time axis of one balloon (s): it runs with the flight's own clock (WIND_COV ``time_usec``)
    while that is known (not 0) and goes forward (by less than a day), and with the arrival times elsewhere
    (no time, a clock that stood still or went back: a restart, a late packet), continuously: the axis never
    goes back. It starts at the first sample's arrival time."""

    def __init__(self) -> None:
        self.flight = False  # the last step was on the flight's clock
        self._offset = 0.0  # axis = flight time + offset (flight) or arrival time + offset (arrival)
        self._last: tuple[float, float, float | None] | None = None  # (axis, arrival, flight s) of the last sample

    def see(self, wall: float, time_usec: int | None) -> float:
        """The axis time of a sample that arrived at ``wall`` (s) carrying ``time_usec`` (None: no clock)."""
        fs = time_usec * 1e-6 if time_usec else None
        last = self._last
        if last is None:
            self._offset = 0.0
            self.flight = False
            t = wall
        elif fs is not None and last[2] is not None and 0.0 < fs - last[2] <= MAX_CLOCK_STEP_US * 1e-6:
            if not self.flight:
                self._offset, self.flight = last[0] - last[2], True
            t = fs + self._offset
        else:
            if self.flight:
                self._offset, self.flight = last[0] - last[1], False
            t = max(last[0], wall + self._offset)
        self._last = (t, wall, fs)
        return t

    def now(self, wall: float) -> float:
        """The axis time at ``wall``: the last sample's, plus the time since it arrived (a silence counts in full)."""
        if self._last is None:
            return wall
        t, at, _ = self._last
        return t + max(0.0, wall - at)


@dataclass
class _Bin:
    """Sums of one height bin of one leg."""

    n: float = 0.0
    e: float = 0.0
    acc2: float = 0.0
    count: int = 0


@dataclass
class Leg:
    """One winch leg: ascent (paying out) or descent, its start time and its height bins (index -> sums)."""

    ascent: bool
    start: float
    bins: dict[int, _Bin] = field(default_factory=dict)

    def rows(self, bin_m: float) -> list[dict]:
        """Per bin, by height: the middle height (m), the vector mean's speed and direction (FROM) and their
        error bars (the RMS of the stated accuracy), and the count."""
        out = []
        for k in sorted(self.bins):
            b = self.bins[k]
            sp, frm = speed_from(b.n / b.count, b.e / b.count)
            acc = math.sqrt(b.acc2 / b.count)
            out.append({"z": (k + 0.5) * bin_m, "speed": _num(sp), "speed_err": _num(acc), "from": _num(frm, 1),
                        "from_err": _num(direction_sigma_deg(sp, acc), 1), "count": b.count})  # fmt: skip
        return out


class ProfileBuilder:
    """The profile of a winched flight as it builds up: a new leg each time the reel starts or turns."""

    def __init__(self, bin_m: float = BIN_M) -> None:
        self.bin_m = bin_m
        self.legs: list[Leg] = []
        self._reel = 0  # +1 paying out, -1 reeling in, 0 stopped
        self.version = 0  # counts the changes (the server sends the profile when it changed)

    def add(self, t: float, n: float, e: float, acc: float, alt_m: float, reel_mps: float | None) -> None:
        reel = 0 if reel_mps is None or abs(reel_mps) < REEL_DEADBAND_MPS else (1 if reel_mps > 0 else -1)
        if reel != self._reel:
            self._reel = reel
            if reel:
                self.legs.append(Leg(ascent=reel > 0, start=t))
        if not reel or not math.isfinite(alt_m) or not math.isfinite(acc):
            return
        b = self.legs[-1].bins.setdefault(math.floor(alt_m / self.bin_m), _Bin())
        b.n += n
        b.e += e
        b.acc2 += acc * acc
        b.count += 1
        self.version += 1

    def as_dict(self) -> dict:
        return {"bin_m": self.bin_m, "legs": [{"ascent": g.ascent, "start": g.start, "rows": g.rows(self.bin_m)}
                                              for g in self.legs]}  # fmt: skip


@dataclass
class Point:
    """One sample as the charts show it: time (s), speed (m/s), direction FROM (deg), accuracy (m/s);
    speed and direction NaN when the wind is not known."""

    t: float
    speed: float
    from_deg: float
    acc: float

    def row(self) -> list[float | None]:
        return [round(self.t, 3), _num(self.speed), _num(self.from_deg), _num(self.acc)]


def _num(x: float, digits: int = 3) -> float | None:
    """A number for JSON: rounded, None for NaN or infinity."""
    return round(x, digits) if math.isfinite(x) else None


class BalloonSeries:
    """One balloon's wind over time: the last 10 minutes in full for the statistics, the decimated samples
    for the charts (those not yet sent in ``outbox``), the hour as one-second means, and the profile."""

    def __init__(self, max_hz: float = PUSH_HZ, bin_m: float = BIN_M) -> None:
        # (t, n, e) of known winds over the last LONG_MEAN_S of ``clock`` (the flight's, where known)
        self.recent: deque[tuple[float, float, float]] = deque(maxlen=RECENT_MAX)
        self.clock = FlightClock()
        self.charted: deque[Point] = deque()  # decimated, last LONG_MEAN_S
        self.hour: deque[Point] = deque()  # one-second means, last HOUR_S
        self.outbox: list[Point] = []  # decimated samples not sent yet
        self.hour_outbox: list[Point] = []
        self.decimator = Decimator(max_hz)
        self.profile = ProfileBuilder(bin_m)
        self.received = 0
        self._sec: list[float] | None = None  # the second being averaged: [second, sum n, sum e, sum acc, count]

    def add(self, t: float, n: float, e: float, acc: float, alt_m: float, reel_mps: float | None = None,
            time_usec: int | None = None) -> None:  # fmt: skip
        """One WIND_COV that arrived at ``t`` (s), carrying ``time_usec`` (the flight's clock; None: none);
        ``reel_mps`` the winch's reel speed then (None: no winch)."""
        self.received += 1
        known = wind_known(n, e, acc)
        ts = self.clock.see(t, time_usec)
        if known:
            self.recent.append((ts, n, e))
            self.profile.add(t, n, e, acc, alt_m, reel_mps)
        if self.decimator.take(t):
            sp, frm = speed_from(n, e) if known else (math.nan, math.nan)
            p = Point(t, sp, frm, acc)
            self.charted.append(p)
            self.outbox.append(p)
        self._add_second(t, n, e, acc, known)
        self._trim(t, ts)

    def _add_second(self, t: float, n: float, e: float, acc: float, known: bool) -> None:
        sec = math.floor(t / HOUR_BIN_S)
        if self._sec is not None and self._sec[0] != sec:
            self._flush_second()
        if self._sec is None:
            self._sec = [sec, 0.0, 0.0, 0.0, 0]
        if known:
            self._sec[1] += n
            self._sec[2] += e
            self._sec[3] += acc
            self._sec[4] += 1

    def _flush_second(self) -> None:
        sec, sn, se, sa, c = self._sec
        self._sec = None
        t = (sec + 0.5) * HOUR_BIN_S
        if c:
            sp, frm = speed_from(sn / c, se / c)
            p = Point(t, sp, frm, sa / c)
        else:
            p = Point(t, math.nan, math.nan, math.nan)
        self.hour.append(p)
        self.hour_outbox.append(p)

    def _trim(self, now: float, now_stats: float) -> None:
        for dq, keep, t in ((self.recent, LONG_MEAN_S, now_stats), (self.charted, LONG_MEAN_S, now),
                            (self.hour, HOUR_S, now)):  # fmt: skip
            while dq and _time(dq[0]) <= t - keep:
                dq.popleft()

    def drain(self) -> tuple[list[Point], list[Point]]:
        """The decimated samples and the one-second means not sent yet (then forgotten)."""
        out, hour = self.outbox, self.hour_outbox
        self.outbox, self.hour_outbox = [], []
        return out, hour

    def statistics(self, now: float) -> dict:
        """The WMO 2- and 10-minute means and the gust over the last 10 minutes as of ``now`` (arrival time, s),
        on the flight's clock where it is known (``clock``: "balloon", else "arrival")."""
        now = self.clock.now(now)
        if self.recent:
            a = np.array(self.recent)
            t, n, e = a[:, 0], a[:, 1], a[:, 2]
        else:
            t = n = e = np.zeros(0)
        sel = t > now - LONG_MEAN_S
        out: dict = {}
        for key, period in (("mean_2min", SHORT_MEAN_S), ("mean_10min", LONG_MEAN_S)):
            m = wmo_mean(t, n, e, now, period)
            out[key] = None if m is None else {"speed": _num(m.speed_mps), "from": _num(m.from_deg, 1),
                                               "span_s": round(m.span_s, 1), "count": m.count}  # fmt: skip
        # windows wholly within the 10 minutes and within the data (less than 10 minutes so far: what there is)
        g = math.nan
        if np.any(sel):
            g = gust(t[sel], np.hypot(n[sel], e[sel]), max(now - LONG_MEAN_S, float(t[sel][0])))
        out["gust"] = _num(g)
        out["clock"] = "balloon" if self.clock.flight else "arrival"
        return out


def _time(x) -> float:
    return x.t if isinstance(x, Point) else x[0]
