"""The browser ground station's model: the ``GroundStation`` that ``balloon-gs listen`` keeps (the same
decoding, the same STALE / SENSORS LOST / MISFIT states) and each balloon's ``BalloonSeries``, turned into
the JSON-able messages the page draws. No I/O: the receivers (threads) feed it under ``lock``, the server
reads it under the same lock."""

from __future__ import annotations

import math
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground_station.listen import STALE_S, UNKNOWN, GroundStation, Vehicle
from ground_station.web.aggregate import PUSH_HZ, WINCH_FRESH_S, BalloonSeries, _num

STATS_EVERY_S = 1.0  # the means, the gust and the profile are recomputed at most this often per balloon
ESTIMATOR_FLAG_NAMES = {v: e.name.removeprefix("ESTIMATOR_").lower()
                        for v, e in mavlink.enums["ESTIMATOR_STATUS_FLAGS"].items() if v & (v - 1) == 0}  # fmt: skip


class LiveModel:
    """What the page shows of every balloon, in wall-clock seconds (the charts' axis)."""

    def __init__(self, gs: GroundStation, max_hz: float = PUSH_HZ) -> None:
        self.gs = gs
        self.lock = threading.Lock()
        self.series: dict[int, BalloonSeries] = {}
        self.max_hz = max_hz
        self.wall_minus_mono = time.time() - time.monotonic()
        self._stats: dict[int, tuple[float, dict]] = {}  # sysid -> (when, statistics)
        self._profile_sent: dict[int, int] = {}  # sysid -> the profile version last sent

    # ------------------------------------------------------------ input (the receivers, under lock)

    def on_message(self, m, now: float) -> None:
        if m.get_type() != "WIND_COV":
            return
        sysid = m.get_srcSystem()
        s = self.series.get(sysid)
        if s is None:
            s = self.series[sysid] = BalloonSeries(self.max_hz)
        w = self.gs.winch
        reel = w.speed_mps if w is not None and now - w.at <= WINCH_FRESH_S else None
        s.add(now + self.wall_minus_mono, m.wind_x, m.wind_y, m.horiz_accuracy, m.wind_alt, reel, m.time_usec)

    # ------------------------------------------------------------ output (the server, under lock)

    def received(self) -> dict[int, int]:
        """WIND_COV taken per system id (duplicates dropped)."""
        return {sysid: s.received for sysid, s in self.series.items()}

    def snapshot(self, now: float) -> dict:
        """Everything a page that just connected needs: each balloon's state, its last 10 minutes (decimated)
        and its hour (one-second means), statistics and profile."""
        balloons = []
        for v in self._vehicles():
            b = self._balloon(v, now, force=True)
            s = self.series.get(v.sysid)
            if s is not None:
                b["samples"] = [p.row() for p in s.charted]
                b["hour"] = [p.row() for p in s.hour]
            balloons.append(b)
        # the next update repeats the samples not drained yet: the page keeps only those newer than its last
        return {"type": "snapshot", **self._head(now), "balloons": balloons}

    def update(self, now: float) -> dict:
        """What changed since the last update (or snapshot): each balloon's state, its new samples."""
        balloons = []
        for v in self._vehicles():
            b = self._balloon(v, now, force=False)
            s = self.series.get(v.sysid)
            if s is not None:
                new, hour = s.drain()
                b["samples"] = [p.row() for p in new]
                b["hour"] = [p.row() for p in hour]
            balloons.append(b)
        return {"type": "update", **self._head(now), "balloons": balloons}

    def plain_text(self, now: float) -> list[str]:
        """Each balloon in one line of words, as the page's script would show it: its system id, its wind
        (speed and the direction it comes FROM, or not known) and its state, STALE with the link's silence.
        The page carries these lines for a reader without its script (``<noscript>``, ``server._index``)."""
        lines = []
        for v in self._vehicles():
            r = v.last
            state = v.state(now)
            if state == "STALE":
                state = f"STALE: no WIND_COV for {v.age(now):.0f} s"
            if r.known:
                wind = f"{r.speed_mps:.2f} m/s from {round(r.from_deg) % 360:03d}°"
            else:
                wind = f"wind {UNKNOWN} (not known)"
            lines.append(f"Balloon sys {v.sysid}: {wind}, {state}")
        return lines

    def _vehicles(self) -> list[Vehicle]:
        """The balloons: every system that sent WIND_COV."""
        return [v for _, v in sorted(self.gs.vehicles.items()) if v.last is not None]

    def _head(self, now: float) -> dict:
        st = self.gs.stats
        w = self.gs.winch
        winch = None
        if w is not None:
            winch = {"line_m": _num(w.line_length_m, 1), "reel_mps": _num(w.speed_mps, 2),
                     "age_s": round(now - w.at, 1)}  # fmt: skip
        return {"t": round(now + self.wall_minus_mono, 3), "stale_s": STALE_S, "unknown": UNKNOWN,
                "link": {"frames": st.frames, "lost": st.lost, "crc_errors": st.bad_frames,
                         "garbage_bytes": st.garbage_bytes, "duplicates": self.gs.duplicates},
                "winch": winch}  # fmt: skip

    def _balloon(self, v: Vehicle, now: float, force: bool) -> dict:
        r = v.last
        known = r.known
        speed, frm, n, e = (r.speed_mps, r.from_deg, r.wind_x, r.wind_y) if known else (math.nan,) * 4
        hb_age = None if v.hb_at is None else round(now - v.hb_at, 1)
        est = v.estimator_flags
        b = {
            "sysid": v.sysid, "state": v.state(now), "age_s": round(v.age(now), 1), "known": known,
            "speed": _num(speed), "from": _num(frm, 1), "n": _num(n), "e": _num(e), "var": _num(r.var_horiz),
            "acc": _num(r.horiz_accuracy), "alt": _num(r.wind_alt, 1),
            "mode": v.mode, "misfit": v.misfit(), "sensors_lost": v.sensors_lost(), "resets": v.resets(),
            "estimator": None if est is None else [name for bit, name in ESTIMATOR_FLAG_NAMES.items() if est & bit],
            "link_lost": self.gs.link_lost(v.sysid), "input_loss": v.input_loss(), "said": v.said(now),
            "warning": v.warning_active(), "hb_age_s": hb_age, "rate_hz": round(v.rate(now), 1),
            "received": v.wind_count,
        }  # fmt: skip
        s = self.series.get(v.sysid)
        if s is None:
            return b
        when, stats = self._stats.get(v.sysid, (-math.inf, {}))
        if force or now - when >= STATS_EVERY_S:
            stats = s.statistics(now + self.wall_minus_mono)
            self._stats[v.sysid] = (now, stats)
            b["stats"] = stats
        if s.profile.legs and (force or self._profile_sent.get(v.sysid) != s.profile.version):
            if force or now - when >= STATS_EVERY_S:
                b["profile"] = s.profile.as_dict()
                self._profile_sent[v.sysid] = s.profile.version
        return b
