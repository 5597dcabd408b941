"""The ground reference's file (docs/usage.md, "A ground reference"): a CSV of the ground station's own
barometer readings, for ``balloon-gs reprocess --ground-pressure`` (the whole file, after the flight) and
``balloon-gs listen --ground-pressure`` (the newest row, sent up the link as it is appended).

A header row, then one row per reading:

- the time, one of: ``time_s`` (seconds on the balloon's sensor clock, since its boot: what
  ``balloon-sim --ground-csv`` writes) or ``time_unix_s`` (UNIX seconds, UTC: what a logger with a clock
  writes; reprocessing needs the log's UTC for it);
- ``pressure_hpa`` (required): the ground's absolute pressure, hPa;
- ``temperature_c`` (optional, may be empty): the ground's air temperature, degC.

Other columns are ignored. A row whose values do not parse is an error naming its line. A UTF-8
byte-order mark is accepted. The file is read as a stream (``ground_rows``): memory does not grow with it.
A reading outside a ground station's weather (300-1100 hPa, -80 to 60 C) is not an error here: the
estimator rejects and counts it (firmware_py/estimator/aid_sources/ground_ref.py)."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from typing import NamedTuple

TIME_COLUMNS = ("time_s", "time_unix_s")


class GroundReadings(NamedTuple):
    time_column: str  # "time_s" (sensor clock) or "time_unix_s" (UTC)
    time_s: list[float]
    pressure_hpa: list[float]
    temperature_c: list[float]  # NaN where not given


def _number(text: str, where: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{where}: not a finite number: {text!r}")
    return x


def parse_row(header: list[str], row: list[str], where: str) -> tuple[float, float, float]:
    """(time s, pressure hPa, temperature degC or NaN) of one row under ``header``."""
    col = {name.strip(): i for i, name in enumerate(header)}
    tcol = next(c for c in TIME_COLUMNS if c in col)
    if len(row) <= max(col[tcol], col["pressure_hpa"]):
        raise ValueError(f"{where}: too few values")
    t = _number(row[col[tcol]], where)
    p = _number(row[col["pressure_hpa"]], where)
    i = col.get("temperature_c")
    temp = _number(row[i], where) if i is not None and i < len(row) and row[i].strip() else math.nan
    return t, p, temp


def check_header(header: list[str], path: str) -> str:
    """The time column of a header; ValueError if the header lacks a time or the pressure."""
    names = [h.strip() for h in header]
    tcol = next((c for c in TIME_COLUMNS if c in names), None)
    if tcol is None or "pressure_hpa" not in names:
        raise ValueError(f"{path}: a ground-pressure CSV needs a header with time_s (or time_unix_s) and pressure_hpa")
    return tcol


def ground_rows(path: str) -> tuple[str, Iterator[tuple[float, float, float]]]:
    """(the time column, the rows as (time s, pressure hPa, temperature degC or NaN)), read as a stream:
    one row at a time, memory flat in the file's length. A UTF-8 byte-order mark (a spreadsheet's
    export) is skipped. ValueError (one line) for a file that is not a ground-pressure CSV or a row that
    does not parse, naming its line (raised by the iterator when it reaches that row)."""
    try:
        fh = open(path, newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc}") from None
    try:
        reader = csv.reader(fh)
        header = next(reader, None)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        fh.close()
        raise ValueError(f"{path}: cannot read: {exc}") from None
    if header is None:
        fh.close()
        raise ValueError(f"{path}: empty file")
    try:
        tcol = check_header(header, path)
    except ValueError:
        fh.close()
        raise

    def rows() -> Iterator[tuple[float, float, float]]:
        with fh:
            try:
                for row in reader:
                    if row and "".join(row).strip():
                        yield parse_row(header, row, f"{path} line {reader.line_num}")
            except (OSError, UnicodeDecodeError, csv.Error) as exc:
                raise ValueError(f"{path} line {reader.line_num}: cannot read: {exc}") from None

    return tcol, rows()


def scan_ground_csv(path: str) -> tuple[str, int]:
    """(the time column, the number of readings): the whole file checked, a row at a time, before any
    work; ValueError (one line) if it is not a ground-pressure CSV, holds no reading, or its time goes back
    (a logger appends in time order; the readings are merged into the flight by time, as ``balloon-gs report``
    refuses a truth CSV out of order)."""
    tcol, rows = ground_rows(path)
    n, before = 0, -math.inf
    for t, _, _ in rows:
        n += 1
        if t < before:
            rows.close()
            raise ValueError(f"{path}: the ground-pressure CSV's {tcol} goes back (reading {n}: {t:.1f} s after "
                             f"{before:.1f} s); a logger writes its readings in time order")  # fmt: skip
        before = t
    if n == 0:
        raise ValueError(f"{path}: no readings")
    return tcol, n


def read_ground_csv(path: str) -> GroundReadings:
    """The whole file in lists (for small files and tests; reprocessing streams it: ``ground_rows``);
    ValueError (one line) if it is not a ground-pressure CSV."""
    tcol, rows = ground_rows(path)
    out = GroundReadings(tcol, [], [], [])
    for t, p, temp in rows:
        out.time_s.append(t)
        out.pressure_hpa.append(p)
        out.temperature_c.append(temp)
    if not out.time_s:
        raise ValueError(f"{path}: no readings")
    return out


def write_ground_csv(path: str, time_s, pressure_hpa, temperature_c) -> None:
    """A ground-pressure CSV on the sensor clock (``time_s``)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "pressure_hpa", "temperature_c"])
        for t, p, temp in zip(time_s, pressure_hpa, temperature_c):
            w.writerow([f"{t:.3f}", f"{p:.4f}", "" if temp != temp else f"{temp:.2f}"])
