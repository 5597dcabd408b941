"""Progress and status of long work, the same way in every program.

    with Progress("balloon-sim", total=3600.0, unit="s simulated", quiet=args.quiet) as bar:
        for s in samples:
            bar.update(s.time_usec * 1e-6)          # where we are (cheap: call it every step if you like)
        ...
    with Progress("balloon-fw", unit="", interval_s=5.0) as status:   # no total: a live status
        status.update(status="100 IMU/s, mode taut, wind 3.1 m/s ...")

Three ways to show it, chosen once from the stream:
- a terminal: a rich progress bar (percentage, elapsed, time left, the status text), redrawn in place
  (a spinner and the status when there is no total);
- not a terminal (a pipe, a log file): one plain line every ``interval_s`` (default 10 s),
  ``label: 35 % (1260/3600 s simulated), 12 s elapsed, ~22 s left | status``;
- ``quiet``: nothing.
The environment variable BALLOON_STATUS_INTERVAL_S overrides ``interval_s`` for every program.
``log(line)`` prints a line that stays (above the bar on a terminal; dropped when quiet). ``update``
only stores numbers; a background thread draws, so a hot loop pays an attribute store.
The program's own final summary is not this module's business: print it after ``close``.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from typing import TextIO

INTERVAL_ENV = "BALLOON_STATUS_INTERVAL_S"  # overrides every program's status-line period (tests, log files)


def stream_is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty() and os.environ.get("TERM", "") != "dumb"
    except (AttributeError, ValueError):
        return False


def fmt_duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``."""
    if not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Progress:
    """A progress bar (terminal), periodic status lines (no terminal) or nothing (quiet)."""

    def __init__(
        self,
        label: str,
        total: float | None = None,
        unit: str = "",
        *,
        quiet: bool = False,
        stream: TextIO | None = None,
        interval_s: float = 10.0,
        terminal: bool | None = None,
    ) -> None:
        self.label, self.total, self.unit = label, total, unit
        self.stream = stream if stream is not None else sys.stderr
        self.interval_s = float(os.environ.get(INTERVAL_ENV, interval_s))
        if quiet:
            self.mode = "quiet"
        elif terminal if terminal is not None else stream_is_terminal(self.stream):
            self.mode = "bar"
        else:
            self.mode = "lines"
        self.done = 0.0
        self.status = ""
        self.t0 = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rich = None
        self._task = None
        self._closed = False
        if self.mode == "bar":
            self._start_bar(terminal is True)
        if self.mode != "quiet":
            self._thread = threading.Thread(target=self._run, name=f"progress-{label}", daemon=True)
            self._thread.start()

    # ------------------------------------------------------------ the caller's side

    def update(self, done: float | None = None, status: str | None = None) -> None:
        """Where the work is (in ``unit``, out of ``total``) and/or a short status text."""
        if done is not None:
            self.done = done
        if status is not None:
            self.status = status

    def advance(self, amount: float = 1.0) -> None:
        self.done += amount

    def log(self, line: str) -> None:
        """A line that stays on screen (above the bar), or in the log; nothing when quiet."""
        if self.mode == "quiet":
            return
        with self._lock:
            if self._rich is not None:
                self._rich.console.print(line, markup=False, highlight=False, soft_wrap=True)
            else:
                self.stream.write(line + "\n")
                self.stream.flush()

    def close(self) -> None:
        """Stop drawing (a terminal keeps the final bar)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self._rich is not None:
            self._rich.update(self._task, completed=self.done, status=self.status)
            self._rich.stop()  # draws the final state

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ drawing

    def elapsed_s(self) -> float:
        return time.monotonic() - self.t0

    def line(self) -> str:
        """The plain one-line status (what a pipe gets every ``interval_s``)."""
        el = self.elapsed_s()
        unit = f" {self.unit}" if self.unit else ""
        if self.total:
            frac = min(max(self.done / self.total, 0.0), 1.0)
            left = el * (1.0 - frac) / frac if frac > 0 else math.inf
            head = (f"{self.label}: {100 * frac:3.0f} % ({_num(self.done)}/{_num(self.total)}{unit}), "
                    f"{fmt_duration(el)} elapsed, ~{fmt_duration(left)} left")  # fmt: skip
        else:
            head = f"{self.label}: {fmt_duration(el)}" + (f", {_num(self.done)}{unit}" if self.done else "")
        return head + (f" | {self.status}" if self.status else "")

    def _run(self) -> None:
        period = 0.25 if self.mode == "bar" else self.interval_s
        while not self._stop.wait(period):
            with self._lock:
                if self.mode == "bar":
                    self._draw_bar()
                else:
                    self.stream.write(self.line() + "\n")
                    self.stream.flush()

    def _start_bar(self, force: bool) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            SpinnerColumn,
            TaskProgressColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        from rich.progress import Progress as RichProgress
        from rich.table import Column

        console = Console(file=self.stream, force_terminal=force or None, highlight=False)
        fixed = Column(no_wrap=True)
        status = TextColumn("{task.fields[status]}", table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1))
        if self.total:
            cols = [TextColumn("{task.description}", table_column=fixed), BarColumn(bar_width=20),
                    TaskProgressColumn(), TimeElapsedColumn(), TextColumn("left", table_column=fixed),
                    TimeRemainingColumn(), status]  # fmt: skip
        else:
            cols = [SpinnerColumn(), TextColumn("{task.description}", table_column=fixed), TimeElapsedColumn(), status]
        self._rich = RichProgress(*cols, console=console, auto_refresh=False, transient=False, expand=True)
        self._task = self._rich.add_task(self.label, total=self.total, status="")
        self._rich.start()

    def _draw_bar(self) -> None:
        self._rich.update(self._task, completed=self.done, status=self.status)
        self._rich.refresh()


def _num(x: float) -> str:
    return f"{x:.0f}" if abs(x) >= 10 or x == int(x) else f"{x:.1f}"


class RateMeter:
    """Events per second over the last ``window_s`` (counts, not timestamps: constant memory)."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._marks: list[tuple[float, int]] = []

    def rate(self, now: float, count: int) -> float:
        marks = self._marks
        marks.append((now, count))
        while len(marks) > 2 and now - marks[1][0] >= self.window_s:
            marks.pop(0)
        t0, c0 = marks[0]
        return (count - c0) / (now - t0) if now > t0 else 0.0
