"""``balloon-gs listen ENDPOINT``: live view of WIND_COV from any MAVLink vehicle, with link
statistics, CSV and tlog logging; stops cleanly on SIGINT/SIGTERM (or after --duration). ``balloon-gs listen
FILE`` (a .tlog or a raw capture) reads a recorded link through the same station at once (``read_file``).

On a terminal: a table redrawn in place (rich Live), one row per balloon (system id), that fits 80x24
and shows more columns (N/E components, variability, altitude, a sparkline of the last minutes) on a
wide screen. A row whose WIND_COV stopped more than ``STALE_S`` ago is marked STALE. Not on a
terminal (piped, logged): one plain line per balloon every second.

A balloon-fw's model misfit (docs/protocol.md, "Model misfit") shows twice: the state ``MISFIT`` while
its SYS_STATUS clears a health bit (what is flagged now), and below the table the latest STATUSTEXT of
each system (what the balloon last said, and how long ago).

A balloon-fw whose sensors have gone silent keeps sending WIND_COV (its accuracy growing); its SYS_STATUS
then clears every sensor's health bit, the gyro's too (which a misfit never clears): the state is
``SENSORS LOST``. A wind that is not known (NaN, or an accuracy as large as the wind could be:
``balloon_core.score.wind_unknown``) is shown as ``—``, never as a calm from 180°."""

from __future__ import annotations

import contextlib
import csv
import math
import os
import sys
import time
from collections import deque
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink
from rich import box
from rich.console import Console, Group
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from balloon_core.progress import fmt_duration, stream_is_terminal
from balloon_core.wire import (
    TLOG_EPOCH_US,
    Decoder,
    LinkStats,
    TlogSink,
    capture_messages,
    message_time_us,
    open_link,
    pack,
    plausible_record_times,
)
from ground_station.wind import CSV_COLUMNS, WindRecord

MODE_NAMES = {0: "ground", 1: "free", 2: "taut"}  # balloon-fw's HEARTBEAT custom_mode
# what balloon-fw says of its optional sources (its NAMED_VALUE_INT counts, firmware_py.app.SOURCE_COUNTS)
SOURCES_SAID = (("winch", "winch_used", "winch_rej"), ("ground reference", "gref_used", "gref_rej"))
# balloon-fw's SYS_STATUS health bits that its consistency monitor clears (docs/protocol.md, "Model misfit"); the
# AHRS bit is the estimator's own model: the tether's alignment and radius, and the force balance
MISFIT_BITS = (
    (mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL, "accel"), (mavlink.MAV_SYS_STATUS_AHRS, "model"),
    (mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE, "baro"), (mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG, "mag"),
)  # fmt: skip
SILENT_BIT = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO  # balloon-fw clears it only when its sensors are silent
UNKNOWN = "—"  # a value not known (yet)
SEVERITY_NAMES = {v: e.name.removeprefix("MAV_SEVERITY_") for v, e in mavlink.enums["MAV_SEVERITY"].items()}
# after the WIND_COV columns, each CSV row says what was lost so far: packets from that system lost on the
# way here (sequence numbers), and the sensor packets the balloon lost (its SYS_STATUS errors_count1; empty
# until it reported)
LOSS_COLUMNS = ("link_lost", "input_lost")
# a frame identical (bytes and sequence number) to one of the last this many of its sender (system, component) is a
# duplicate: fewer than the 256 of a sequence cycle, after which a sender's unchanged message (a HEARTBEAT) comes back
# byte for byte
DEDUP_FRAMES = 128
STALE_S = 2.0  # no WIND_COV for this long: the row's wind is old
HB_LATE_S = 3.0  # no HEARTBEAT for this long: shown in red
RATE_WINDOW_S = 2.0
SPARK = "▁▂▃▄▅▆▇█"
SPARK_MAX = 120  # seconds of wind speed in the sparkline (as much as a wide screen holds)
# column key: (header, justification); the wide headers where they differ
COLUMNS = {
    "sys": ("sys", "right"), "t": ("t [s]", "right"), "wind": ("wind", "right"), "from": ("from", "right"),
    "N": ("N", "right"), "E": ("E", "right"), "acc": ("±acc", "right"), "var": ("var", "right"),
    "alt": ("alt m", "right"), "mode": ("mode", "left"), "hz": ("Hz", "right"), "rst": ("rst", "right"),
    "lost": ("lost", "right"), "in": ("in%", "right"), "hb": ("hb", "right"), "state": ("state", "left"),
}  # fmt: skip
STATE_STYLES = {"WAIT": "yellow", "STALE": "bold white on red", "SENSORS LOST": "bold white on red",
                "MISFIT": "bold yellow", "OK": "green"}  # fmt: skip
WIDE_HEADERS = {"wind": "wind m/s", "from": "from °"}
# the richest that fits wins; the last always does (80 columns)
LAYOUTS = (
    ("sys", "t", "wind", "from", "N", "E", "acc", "var", "alt", "mode", "hz", "rst", "lost", "in", "hb", "state"),
    ("sys", "wind", "from", "N", "E", "acc", "var", "alt", "mode", "hz", "rst", "lost", "in", "hb", "state"),
    ("sys", "wind", "from", "acc", "mode", "hz", "rst", "lost", "in", "hb", "state"),
)


class _Null:
    def write(self, _s: str) -> int:
        return 0

    def flush(self) -> None:
        pass


_NULL = _Null()


@dataclass
class Vehicle:
    """What the ground station knows of one system id."""

    sysid: int
    last: WindRecord | None = None
    wind_at: float | None = None  # monotonic time of the last WIND_COV
    hb_at: float | None = None  # ... of the last HEARTBEAT
    mode: str = "?"
    vehicle_type: int | None = None
    status: object | None = None  # the last SYS_STATUS (balloon-fw: resets, input loss, model misfit)
    text: str | None = None  # the last STATUSTEXT
    text_severity: int = mavlink.MAV_SEVERITY_INFO
    text_at: float | None = None  # monotonic time of the last STATUSTEXT
    wind_count: int = 0
    estimator_flags: int | None = None  # the last ESTIMATOR_STATUS flags (ESTIMATOR_STATUS_FLAGS)
    named: dict = field(default_factory=dict)  # NAMED_VALUE_INT by name (balloon-fw: its sources' counts)
    times: deque = field(default_factory=deque)  # WIND_COV arrival times within RATE_WINDOW_S
    history: deque = field(default_factory=lambda: deque(maxlen=240))  # (arrival time, speed) each second

    @property
    def ours(self) -> bool:
        return self.vehicle_type == mavlink.MAV_TYPE_FREE_BALLOON

    def rate(self, now: float) -> float:
        while self.times and now - self.times[0] > RATE_WINDOW_S:
            self.times.popleft()
        return len(self.times) / RATE_WINDOW_S

    def age(self, now: float) -> float:
        return math.inf if self.wind_at is None else now - self.wind_at

    def stale(self, now: float) -> bool:
        return self.last is not None and self.age(now) > STALE_S

    def resets(self) -> int | None:
        """Filter resets the balloon reports (balloon-fw's SYS_STATUS errors_count2)."""
        return int(self.status.errors_count2) if self.status is not None and self.ours else None

    def input_lost(self) -> int | None:
        """Sensor packets the balloon's firmware lost (SYS_STATUS errors_count1, balloon-fw only)."""
        return int(self.status.errors_count1) if self.status is not None and self.ours else None

    def input_loss(self) -> str | None:
        """What the balloon says it lost on its sensor link (balloon-fw's SYS_STATUS): ``12 lost (0.1 %),
        3 IMU missing, 0 long gaps``."""
        st = self.status
        if st is None or not self.ours:
            return None
        return (f"{st.errors_count1} lost ({st.drop_rate_comm / 100.0:.1f} %), {st.errors_count4} IMU missing, "
                f"{st.errors_count3} long gaps")  # fmt: skip

    def input_lost_pct(self) -> float | None:
        """Sensor packets the balloon's firmware lost, % (SYS_STATUS drop_rate_comm)."""
        return self.status.drop_rate_comm / 100.0 if self.status is not None else None

    def _unhealthy(self) -> int:
        """The health bits the balloon's SYS_STATUS clears among the present and enabled ones (balloon-fw only)."""
        st = self.status
        if st is None or not self.ours:
            return 0
        bad = st.onboard_control_sensors_present & st.onboard_control_sensors_enabled
        return bad & ~st.onboard_control_sensors_health

    def sensors_lost(self) -> bool:
        """The balloon says its sensors are silent: its SYS_STATUS clears the gyro's health (``SILENT_BIT``)."""
        return bool(self._unhealthy() & SILENT_BIT)

    def misfit(self) -> list[str]:
        """What the balloon's model does not explain now: the health bits its SYS_STATUS clears
        (``MISFIT_BITS``; balloon-fw only), unless its sensors are silent (then all are cleared)."""
        bad = self._unhealthy()
        if bad & SILENT_BIT:
            return []
        return [name for bit, name in MISFIT_BITS if bad & bit]

    def said(self, now: float) -> str | None:
        """The last STATUSTEXT with its severity and age: ``<text> (WARNING, 5 s ago)``."""
        if self.text is None:
            return None
        sev = SEVERITY_NAMES.get(self.text_severity, str(self.text_severity))
        return f"{self.text} ({sev}, {now - self.text_at:.0f} s ago)"

    def text_line(self, now: float) -> str | None:
        """The last STATUSTEXT as the view shows it, below the table: ``sys 3: <text> (WARNING, 5 s ago)``."""
        said = self.said(now)
        return None if said is None else f"sys {self.sysid}: {said}"

    def warning_active(self) -> bool:
        """The last STATUSTEXT is a warning (or worse) and the balloon still reports a misfit."""
        return self.text is not None and self.text_severity <= mavlink.MAV_SEVERITY_WARNING and bool(self.misfit())

    def state(self, now: float) -> str:
        """The one state every view shows, the worst first: ``WAIT`` (no WIND_COV yet), ``STALE`` (none for
        ``STALE_S``), ``SENSORS LOST``, ``MISFIT`` or ``OK``."""
        if self.last is None:
            return "WAIT"
        if self.stale(now):
            return "STALE"
        if self.sensors_lost():
            return "SENSORS LOST"
        if self.misfit():
            return "MISFIT"
        return "OK"


@dataclass(frozen=True)
class Winch:
    """The last WINCH_STATUS: when it came (monotonic s), the paid-out line (m), the reel's speed (m/s,
    positive paying out)."""

    at: float
    line_length_m: float
    speed_mps: float


class GroundStation:
    def __init__(self, csv_path: str | None = None, tlog_path: str | None = None, out=sys.stdout,
                 ground_pressure: str | None = None, sysid: int = 255) -> None:  # fmt: skip
        self.stats = LinkStats()
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.ground = GroundReferenceFile(ground_pressure) if ground_pressure else None
        self.ground_sent = 0
        self.vehicles: dict[int, Vehicle] = {}
        self.wind_count = 0
        self.out = out
        self.endpoint = ""
        self.t0 = time.monotonic()
        self._csv_fh = open(csv_path, "w", newline="") if csv_path else None
        self._csv = csv.writer(self._csv_fh) if self._csv_fh else None
        self.csv_path, self.tlog_path = csv_path, tlog_path
        if self._csv:
            self._csv.writerow(CSV_COLUMNS + LOSS_COLUMNS)
        self._tlog = TlogSink(tlog_path) if tlog_path else None
        self.winch: Winch | None = None  # the last WINCH_STATUS (any system: the site has one winch)
        self.duplicates = 0  # frames received twice (a relay or a radio repeating), dropped
        self.unknown_not_logged = 0  # frames of a message id the dialect lacks, not copied into the tlog log
        self._recent: dict[tuple[int, int], tuple[deque[bytes], set[bytes]]] = {}  # per sender: its last frames

    # ------------------------------------------------------------ input

    def vehicle(self, sysid: int) -> Vehicle:
        v = self.vehicles.get(sysid)
        if v is None:
            v = self.vehicles[sysid] = Vehicle(sysid)
        return v

    def _duplicate(self, sender: tuple[int, int], frame: bytes) -> bool:
        """The same frame (bytes and sequence number) as one of the last ``DEDUP_FRAMES`` of its sender."""
        recent = self._recent.get(sender)
        if recent is None:
            recent = self._recent[sender] = (deque(), set())
        order, seen = recent
        if frame in seen:
            self.duplicates += 1
            return True
        order.append(frame)
        seen.add(frame)
        if len(order) > DEDUP_FRAMES:
            seen.discard(order.popleft())
        return False

    def handle(self, m, now: float, stamp_us: int | None = None) -> bool:
        """Take one decoded message; False if it was a duplicate (dropped). ``stamp_us``: its record's time in the tlog
        log (a recording's own; None: now)."""
        frame = bytes(m.get_msgbuf())
        if self._duplicate((m.get_srcSystem(), m.get_srcComponent()), frame):
            return False
        t = m.get_type()
        if self._tlog and t.startswith("UNKNOWN"):
            self.unknown_not_logged += 1  # an id the dialect lacks: its CRC unchecked, pymavlink could not read it back
        elif self._tlog:
            if stamp_us is None:
                self._tlog.send(frame)
            else:
                self._tlog.record(stamp_us, frame)
        if t == "WIND_COV":
            rec = WindRecord.from_msg(m)
            v = self.vehicle(rec.sysid)
            v.last, v.wind_at = rec, now
            v.wind_count += 1
            v.times.append(now)
            if rec.known and (not v.history or now - v.history[-1][0] >= 1.0):
                v.history.append((now, rec.speed_mps))
            self.wind_count += 1
            if self._csv:
                lost = v.input_lost()
                self._csv.writerow(rec.csv_row() + [self.link_lost(v.sysid), "" if lost is None else lost])
        elif t == "HEARTBEAT" and m.type != mavlink.MAV_TYPE_GCS:
            v = self.vehicle(m.get_srcSystem())
            v.vehicle_type, v.hb_at = m.type, now
            if m.type == mavlink.MAV_TYPE_FREE_BALLOON:
                v.mode = MODE_NAMES.get(m.custom_mode, str(m.custom_mode))
        elif t == "SYS_STATUS":
            self.vehicle(m.get_srcSystem()).status = m
        elif t == "STATUSTEXT":
            v = self.vehicle(m.get_srcSystem())
            v.text, v.text_severity, v.text_at = m.text, m.severity, now
        elif t == "ESTIMATOR_STATUS":
            self.vehicle(m.get_srcSystem()).estimator_flags = int(m.flags)
        elif t == "NAMED_VALUE_INT":
            self.vehicle(m.get_srcSystem()).named[str(m.name).rstrip("\x00")] = int(m.value)
        elif t == "WINCH_STATUS":  # the site's winch (a component of the ground's system, docs/protocol.md)
            self.winch = Winch(now, float(m.line_length), float(m.speed))
        return True

    def heartbeat(self) -> bytes:
        return pack(self.mav, self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
        ))  # fmt: skip

    def ground_reference(self) -> bytes | None:
        """The newest ground reading as SCALED_PRESSURE from this station's system, if there is a new one."""
        if self.ground is None:
            return None
        reading = self.ground.newest()
        if reading is None:
            return None
        hpa, temp_c = reading
        self.ground_sent += 1
        ms = int((time.monotonic() - self.t0) * 1000.0)
        cdeg = int(round(temp_c * 100.0)) if temp_c == temp_c else 0
        return pack(self.mav, self.mav.scaled_pressure_encode(ms, hpa, 0.0, cdeg, 0))

    def link_lost(self, sysid: int) -> int:
        """Packets from this system lost on the way to the ground station (all its components)."""
        return sum(s.lost for (sys_, _), s in self.stats.senders.items() if sys_ == sysid)

    # ------------------------------------------------------------ the plain line (not a terminal)

    @property
    def last(self) -> WindRecord | None:
        """The newest WIND_COV of any vehicle."""
        recs = [v for v in self.vehicles.values() if v.last is not None]
        return max(recs, key=lambda v: v.wind_at).last if recs else None

    def status_lines(self, now: float) -> list[str]:
        s = self.stats
        link = f"lost {s.lost}, CRC errors {s.bad_frames}, {self.duplicates} duplicates dropped"
        shown = [v for v in self.vehicles.values() if v.last is not None]
        if not shown:
            return [f"waiting for WIND_COV | {link}"]
        lines = []
        for v in sorted(shown, key=lambda v: v.sysid):
            r = v.last
            var = "  n/a" if r.var_horiz != r.var_horiz else f"{r.var_horiz:5.2f}"
            stale = f" STALE {v.age(now):.0f} s" if v.stale(now) else ""
            stale += " SENSORS LOST" if v.sensors_lost() else ""
            if r.known:
                wind = (f"wind {r.speed_mps:5.2f} m/s from {r.from_deg:5.1f} deg "
                        f"(N {r.wind_x:+5.2f} E {r.wind_y:+5.2f})")  # fmt: skip
            else:
                wind = f"wind {UNKNOWN} (not known)"
            resets = v.resets()
            health = f"resets {resets}, " if resets is not None else ""
            misfit = v.misfit()
            health += f"MISFIT {','.join(misfit)}, " if misfit else ""
            hb = "-" if v.hb_at is None else f"{now - v.hb_at:.0f} s"
            said = v.said(now)
            loss = v.input_loss()
            health += f"balloon input {loss}, " if loss else ""
            health += "".join(f"{what}: {v.named[a]} used, {v.named[b]} rejected, " for what, a, b in SOURCES_SAID
                              if a in v.named and b in v.named)  # fmt: skip
            lines.append(
                f"sys {v.sysid}: t={r.time_usec * 1e-6:7.1f}s {wind} ±{r.horiz_accuracy:4.2f} var {var} "
                f"alt {r.wind_alt:6.1f} m mode {v.mode}{stale} | {v.rate(now):4.1f} msg/s, {health}"
                f"heartbeat {hb} ago, {link}" + (f" | said: {said}" if said else "")
            )
        return lines

    def status_line(self, now: float) -> str:
        return "\n".join(self.status_lines(now))

    # ------------------------------------------------------------ the terminal view

    def view(self, now: float, width: int):
        """A rich renderable: header, one row per system id, footer; fits ``width`` columns, with the
        richest set of columns (``LAYOUTS``) whose table fits."""
        s = self.stats
        head = Text(no_wrap=True, overflow="ellipsis")
        head.append("balloon-gs ", style="bold")
        head.append(f"{self.endpoint}  up {fmt_duration(now - self.t0)}")
        link = Text(no_wrap=True, overflow="ellipsis")
        link.append(f"link: {s.frames} frames, ")
        link.append(f"{s.lost} lost", style="red bold" if s.lost else "")
        link.append(
            f", {s.bad_frames} CRC errors, {s.garbage_bytes} garbage bytes, {self.duplicates} duplicates, "
            f"{s.bytes / 1024:.0f} kB"
        )
        if head.cell_len + 2 + link.cell_len <= width:
            head.append("  ")
            head.append_text(link)
            lines = [head]
        else:
            lines = [head, link]
        console = Console(width=width, file=_NULL)
        for keys in LAYOUTS:
            table = self._table(now, keys, 0)
            natural = Measurement.get(console, console.options.update_width(10_000), table).maximum
            if natural <= width or keys is LAYOUTS[-1]:
                break
        spark_w = min(SPARK_MAX, width - natural - 3)
        if "t" in keys and spark_w >= 10:
            table = self._table(now, keys, spark_w)
        logs = ", ".join(p for p in (self.csv_path, self.tlog_path) if p)
        notes = [f"STALE: no WIND_COV for {STALE_S:g} s.  SENSORS LOST: the balloon hears no sensor.  MISFIT: data "
                 f"unexplained.  {UNKNOWN}: not known.  rst: filter resets.  lost: lost on the way here.  in%: sensor "
                 "packets the balloon lost.  hb: heartbeat age.  Ctrl-C stops."]  # fmt: skip
        if len(notes[0]) > width:
            notes = ["wind, ±acc: m/s; from: deg; rst: filter resets; lost: lost on the way here;",
                     f"in%: sensor packets the balloon lost; hb: heartbeat age; STALE: no WIND_COV {STALE_S:g} s",
                     f"SENSORS LOST: the balloon hears no sensor; {UNKNOWN}: the wind is not known (yet)",
                     "MISFIT: the model does not explain the data (±acc grown). Ctrl-C stops."]  # fmt: skip
        if logs:
            notes[-1] += f" Logging to {logs}."
        foot = [Text(n, no_wrap=True, overflow="ellipsis", style="dim") for n in notes]
        return Group(*lines, table, *self._text_lines(now), *foot)

    def _text_lines(self, now: float) -> list[Text]:
        """The latest STATUSTEXT of each system, below the table: yellow while its misfit warning is
        active, dim once cleared or for any other message."""
        out = []
        for v in sorted(self.vehicles.values(), key=lambda v: v.sysid):
            line = v.text_line(now)
            if line is not None:
                style = "bold yellow" if v.warning_active() else "dim"
                out.append(Text(line, no_wrap=True, overflow="ellipsis", style=style))
        return out

    def _table(self, now: float, keys: tuple[str, ...], spark_w: int):
        t = Table(box=box.SIMPLE_HEAD, pad_edge=False, expand=False, padding=(0, 1), show_edge=False)
        wide = "t" in keys
        for k in keys:
            header, justify = COLUMNS[k]
            if wide and k in WIDE_HEADERS:
                header = WIDE_HEADERS[k]
            t.add_column(header, justify=justify, no_wrap=True, overflow="ellipsis")
        if spark_w:
            t.add_column(f"wind, last {spark_w} s", no_wrap=True)
        if not self.vehicles:
            t.add_row(*(["-"] * len(t.columns)))
        for v in sorted(self.vehicles.values(), key=lambda v: v.sysid):
            cells = self._cells(v, now)
            row = [cells[k] for k in keys]
            if spark_w:
                row.append(Text(sparkline([sp for _, sp in v.history][-spark_w:]),
                                style="dim" if v.stale(now) else "cyan"))  # fmt: skip
            t.add_row(*row)
        return t

    def _cells(self, v: Vehicle, now: float) -> dict:
        r = v.last
        dim = "dim" if v.stale(now) else ""
        c: dict = {"sys": str(v.sysid)}
        if r is None:
            for k in ("t", "wind", "from", "N", "E", "acc", "var", "alt"):
                c[k] = "-"
        else:
            var = "-" if r.var_horiz != r.var_horiz else f"{r.var_horiz:.2f}"
            vals = {"t": f"{r.time_usec * 1e-6:.1f}", "wind": f"{r.speed_mps:.2f}", "from": f"{r.from_deg:03.0f}",
                    "N": f"{r.wind_x:+.2f}", "E": f"{r.wind_y:+.2f}", "acc": f"{r.horiz_accuracy:.2f}", "var": var,
                    "alt": f"{r.wind_alt:.0f}"}  # fmt: skip
            if not r.known:
                vals.update(dict.fromkeys(("wind", "from", "N", "E"), UNKNOWN))
            if r.horiz_accuracy != r.horiz_accuracy:
                vals["acc"] = UNKNOWN
            if r.wind_alt != r.wind_alt:
                vals["alt"] = UNKNOWN
            for k, x in vals.items():
                c[k] = Text(x, style=dim)
        resets = v.resets()
        lost = self.link_lost(v.sysid)
        in_pct = v.input_lost_pct()
        hb_age = None if v.hb_at is None else now - v.hb_at
        c["mode"] = Text(v.mode, style=dim)
        c["hz"] = f"{v.rate(now):.0f}"
        c["rst"] = Text("-" if resets is None else str(resets), style="yellow" if resets else "")
        c["lost"] = Text(str(lost), style="red bold" if lost else "")
        c["in"] = Text("-" if in_pct is None else f"{in_pct:.1f}", style="red bold" if in_pct else "")
        late = hb_age is None or hb_age > HB_LATE_S
        c["hb"] = Text("-" if hb_age is None else f"{hb_age:.0f}s", style="red bold" if late else "")
        state = v.state(now)
        label = f"STALE {v.age(now):.0f}s" if state == "STALE" else state
        c["state"] = Text(label, style=STATE_STYLES[state])
        return c

    def close(self) -> None:
        if self._csv_fh:
            self._csv_fh.close()
        if self._tlog:
            self._tlog.close()

    def summary(self) -> str:
        """The last line: what came, what was lost on the way here, and what each balloon said it lost
        on its own sensor link (its last SYS_STATUS)."""
        s = self.stats
        said = "; ".join(f"sys {v.sysid} reported its sensor input {v.input_loss()}"
                         for v in sorted(self.vehicles.values(), key=lambda v: v.sysid) if v.input_loss())  # fmt: skip
        n = len(self.vehicles)
        stamps = (f", {s.bad_stamps} record time{'' if s.bad_stamps == 1 else 's'} damaged (not used)"
                  if s.bad_stamps else "")  # fmt: skip
        u = self.unknown_not_logged
        unknown = f", {u} frame{'' if u == 1 else 's'} of an unknown message id not logged to the tlog" if u else ""
        return (f"balloon-gs: {self.wind_count} WIND_COV from {n} system{'' if n == 1 else 's'}, {s.frames} frames, "
                f"{s.lost} lost, {s.bad_frames} CRC errors, {s.garbage_bytes} garbage bytes, "
                f"{self.duplicates} duplicates dropped{stamps}{unknown}" + (f"; {said}" if said else ""))  # fmt: skip


def sparkline(values: list[float]) -> str:
    if not values:
        return ""
    lo, hi = min(values), max(values)
    span = hi - lo if hi > lo else 1.0
    return "".join(SPARK[min(len(SPARK) - 1, int((x - lo) / span * len(SPARK)))] for x in values)


TAIL_BYTES = 4096  # the end of a ground-barometer CSV read each second (its newest rows)


class GroundReferenceFile:
    """A ground-barometer CSV that a logger appends to (balloon_core/groundref.py): its newest row, once."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.header: list[str] | None = None
        self._last: tuple | None = None

    def newest(self) -> tuple[float, float] | None:
        """(hPa, degC or NaN) of the last complete row if it is new since the last call; None otherwise.
        Only the header and the file's last few kB are read: memory and time flat in the file's length."""
        from balloon_core.groundref import check_header, parse_row

        try:
            with open(self.path, "rb") as fh:
                if self.header is None:
                    first = fh.readline().decode("utf-8-sig", "replace")
                    if not first.endswith("\n"):
                        return None  # the header is being written
                    header = next(csv.reader([first]))
                    check_header(header, self.path)
                    self.header = header
                size = fh.seek(0, os.SEEK_END)
                fh.seek(max(0, size - TAIL_BYTES))
                tail = fh.read().decode("utf-8-sig", "replace")
        except OSError:
            return None
        lines = tail.split("\n")[:-1]  # complete lines only (a row being written has no newline yet)
        if size > TAIL_BYTES:
            lines = lines[1:]  # the first may be cut
        rows = [r for r in csv.reader(lines) if r and "".join(r).strip() and r != self.header]
        if not rows:
            return None
        try:
            t, hpa, temp = parse_row(self.header, rows[-1], self.path)
        except ValueError:
            return None  # not a reading
        if self._last == (t, hpa):
            return None
        self._last = (t, hpa)
        return hpa, temp


class Receiver:
    """One link into a ``GroundStation``: each ``step`` waits for data at most ``timeout_s``, decodes it into
    the station, and sends the station's HEARTBEAT (and ground reference) once a second. ``lock`` (any
    context manager) guards the station when another thread reads it (``balloon-gs web``)."""

    def __init__(self, endpoint: str, gs: GroundStation, lock=None, on_message=None) -> None:
        self.link = open_link(endpoint)
        self.endpoint = endpoint
        self.gs = gs
        self.dec = Decoder(gs.stats)
        self.lock = lock if lock is not None else contextlib.nullcontext()
        self.on_message = on_message  # called with (message, now) for each one the station took, under lock
        self._next_hb = time.monotonic()

    def step(self, timeout_s: float) -> None:
        data = self.link.recv(timeout_s)
        now = time.monotonic()
        with self.lock:
            if data:
                for m in self.dec.feed(data, self.link.datagrams):
                    if self.gs.handle(m, now) and self.on_message is not None:
                        self.on_message(m, now)
            if now >= self._next_hb:
                self.link.send(self.gs.heartbeat())
                ground = self.gs.ground_reference()
                if ground is not None:
                    self.link.send(ground)
                self._next_hb = now + 1.0

    def close(self) -> None:
        self.link.close()


def listen(endpoint: str, gs: GroundStation, stop, duration_s: float | None = None) -> None:
    rx = Receiver(endpoint, gs)
    gs.endpoint = endpoint
    tty = stream_is_terminal(gs.out)
    live = None
    if tty:
        from rich.console import Console
        from rich.live import Live

        console = Console(file=gs.out)
        live = Live(console=console, auto_refresh=False, transient=False, redirect_stdout=False,
                    redirect_stderr=False, vertical_overflow="ellipsis")  # fmt: skip
        live.start()
    t0 = time.monotonic()
    next_show = t0
    try:
        while not stop():
            now = time.monotonic()
            if duration_s is not None and now - t0 >= duration_s:
                break
            rx.step(0.1)
            now = time.monotonic()
            if now >= next_show:
                if live is not None:
                    live.update(gs.view(now, live.console.size.width), refresh=True)
                    next_show = now + 0.25
                else:
                    for line in gs.status_lines(now):
                        gs.out.write(line + "\n")
                    gs.out.flush()
                    next_show = now + 1.0
    finally:
        rx.close()
        if live is not None:
            live.update(gs.view(time.monotonic(), live.console.size.width), refresh=True)
            live.stop()


def recording(path: str, stats: LinkStats):
    """(message, time s) of a recorded link (a .tlog or a raw capture, ``wire.capture_messages``) in its order: the
    record's time where the file has one (a tlog's; one not plausible against its neighbours, a damaged record
    header, is counted in ``stats.bad_stamps`` and does not move the clock: ``wire.plausible_record_times``); in a raw
    capture the senders' own clocks (``wire.message_time_us``), each sender's set where it is first heard against the
    time then (two balloons booted an hour apart are heard on one clock), never going back; None before the first
    message that tells one."""
    now = None
    offset: dict[int, float] = {}  # a raw capture's sender: its clock's offset from the recording's
    msgs = capture_messages(path, stats)
    tlog = path.endswith(".tlog")
    pairs = plausible_record_times(((m, m._timestamp) for m in msgs), stats) if tlog else ((m, None) for m in msgs)
    for m, t in pairs:
        if not tlog:
            us = message_time_us(m)
            if us is not None:
                sysid = m.get_srcSystem()
                if sysid not in offset:
                    offset[sysid] = 0.0 if now is None else now - us * 1e-6
                t = us * 1e-6 + offset[sysid]
        if t is not None and math.isfinite(t):
            now = t if now is None else max(now, t)
        yield m, now


def no_wind_refusal(path: str, stats: LinkStats, wind_count: int) -> str | None:
    """Why a recording read whole is not one for the ground station (as ``balloon-fw`` and ``balloon-replay`` refuse
    what holds nothing for them): no MAVLink frame at all (an empty file, a picture, noise), or frames but no WIND_COV
    (a sensor capture: ``balloon-fw --in`` makes its wind); None if it holds WIND_COV."""
    if stats.frames == 0:
        return f"{path}: no MAVLink frame in this file (not a recording of a MAVLink link?)"
    if wind_count == 0:
        return (f"{path}: {stats.frames} MAVLink frames but no WIND_COV: nothing for the ground station to show (a "
                "sensor capture? balloon-fw --in makes its wind)")  # fmt: skip
    return None


def read_file(path: str, gs: GroundStation, stop, duration_s: float | None = None) -> None:
    """A recorded link through the station as it came (``recording``): the CSV and the tlog logged as a live run
    logs them, then the view at the recording's end, on the recording's clock; ``duration_s``: only its first
    seconds; the tlog log stamped with the recording's times. Nothing is sent: a file has no one to send to.
    ValueError (nothing shown) for a file that holds no WIND_COV (``no_wind_refusal``), also where ``duration_s`` cut
    it before any: the rest is read for one."""
    gs.endpoint = path
    now = start = None
    whole = True  # read to its end (not stopped, not cut by ``duration_s``)
    epoch_us = 0 if path.endswith(".tlog") else TLOG_EPOCH_US  # the tlog log's stamps: the record's, or as simulated
    for m, now in recording(path, gs.stats):
        if stop():
            whole = False
            break
        start = now if start is None else start
        if duration_s is not None and now is not None and now - start > duration_s:
            whole = False
            break
        stamp = None if now is None else epoch_us + round(now * 1e6)
        gs.handle(m, 0.0 if now is None else now, stamp)
    refusal = no_wind_refusal(path, gs.stats, gs.wind_count)
    if refusal is not None and not whole and gs.stats.frames and not stop():  # cut by --duration: is the rest alike?
        rest = LinkStats()
        if any(m.get_type() == "WIND_COV" for m, _ in recording(path, rest)):
            refusal = None  # a recording of wind whose first seconds hold none
        else:
            refusal, whole = no_wind_refusal(path, rest, 0), True
    if refusal is not None and (whole or gs.stats.frames == 0) and not stop():
        raise ValueError(refusal)
    now = 0.0 if now is None else now
    if stream_is_terminal(gs.out):
        console = Console(file=gs.out)
        console.print(gs.view(now, console.size.width))
    else:
        for line in gs.status_lines(now):
            gs.out.write(line + "\n")
        gs.out.flush()
