"""``balloon-gs listen ENDPOINT``: live view of WIND_COV from any MAVLink vehicle, with link
statistics, CSV and tlog logging; stops cleanly on SIGINT/SIGTERM (or after --duration)."""

from __future__ import annotations

import csv
import sys
import time

from pymavlink.dialects.v20 import common as mavlink

from firmware_py.mavio import Decoder, LinkStats, TlogSink, open_link, pack
from ground_station.wind import CSV_COLUMNS, WindRecord

MODE_NAMES = {0: "ground", 1: "free", 2: "taut"}  # balloon-fw's HEARTBEAT custom_mode


class GroundStation:
    def __init__(self, csv_path: str | None = None, tlog_path: str | None = None, out=sys.stdout) -> None:
        self.stats = LinkStats()
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.last: WindRecord | None = None
        self.mode = "?"
        self.vehicle_type: int | None = None
        self.wind_count = 0
        self._window: list[float] = []
        self.out = out
        self._csv_fh = open(csv_path, "w", newline="") if csv_path else None
        self._csv = csv.writer(self._csv_fh) if self._csv_fh else None
        if self._csv:
            self._csv.writerow(CSV_COLUMNS)
        self._tlog = TlogSink(tlog_path) if tlog_path else None

    def handle(self, m, now: float) -> None:
        if self._tlog:
            self._tlog.send(bytes(m.get_msgbuf()))
        t = m.get_type()
        if t == "WIND_COV":
            rec = WindRecord.from_msg(m)
            self.last = rec
            self.wind_count += 1
            self._window.append(now)
            if self._csv:
                self._csv.writerow(rec.csv_row())
        elif t == "HEARTBEAT" and m.type != mavlink.MAV_TYPE_GCS:
            self.vehicle_type = m.type
            if m.type == mavlink.MAV_TYPE_FREE_BALLOON:
                self.mode = MODE_NAMES.get(m.custom_mode, str(m.custom_mode))

    def heartbeat(self) -> bytes:
        return pack(self.mav, self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
        ))  # fmt: skip

    def rate(self, now: float) -> float:
        self._window = [t for t in self._window if now - t <= 2.0]
        return len(self._window) / 2.0

    def status_line(self, now: float) -> str:
        s = self.stats
        link = f"{self.rate(now):4.1f} msg/s, lost {s.lost}, CRC errors {s.bad_frames}"
        r = self.last
        if r is None:
            return f"waiting for WIND_COV | {link}"
        var = "  n/a" if r.var_horiz != r.var_horiz else f"{r.var_horiz:5.2f}"
        return (
            f"t={r.time_usec * 1e-6:7.1f}s wind {r.speed_mps:5.2f} m/s from {r.from_deg:5.1f} deg "
            f"(N {r.wind_x:+5.2f} E {r.wind_y:+5.2f}) ±{r.horiz_accuracy:4.2f} var {var} "
            f"alt {r.wind_alt:6.1f} m mode {self.mode} | {link}"
        )

    def close(self) -> None:
        if self._csv_fh:
            self._csv_fh.close()
        if self._tlog:
            self._tlog.close()

    def summary(self) -> str:
        s = self.stats
        return (f"balloon-gs: {self.wind_count} WIND_COV, {s.frames} frames, {s.lost} lost, "
                f"{s.bad_frames} CRC errors, {s.garbage_bytes} garbage bytes")  # fmt: skip


def listen(endpoint: str, gs: GroundStation, stop, duration_s: float | None = None) -> None:
    link = open_link(endpoint)
    dec = Decoder(gs.stats)
    tty = gs.out.isatty()
    t0 = time.monotonic()
    next_show = next_hb = t0
    try:
        while not stop():
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            data = link.recv(0.1)
            if data:
                for m in dec.feed(data):
                    gs.handle(m, now)
            if now >= next_hb:
                link.send(gs.heartbeat())
                next_hb = now + 1.0
            if now >= next_show:
                line = gs.status_line(now)
                gs.out.write(("\r\x1b[K" + line) if tty else line + "\n")
                gs.out.flush()
                next_show = now + 1.0
    finally:
        link.close()
        if tty:
            gs.out.write("\n")
