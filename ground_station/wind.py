"""WIND_COV as the ground station keeps it: one record per message, from any MAVLink vehicle."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np

from balloon_core.score import direction_from_deg, wind_unknown

CSV_COLUMNS = ("time_usec", "sysid", "compid", "wind_x", "wind_y", "wind_z", "var_horiz", "var_vert",
               "wind_alt", "horiz_accuracy", "vert_accuracy", "speed_mps", "from_deg")  # fmt: skip


@dataclass(frozen=True)
class WindRecord:
    time_usec: int
    sysid: int
    compid: int
    wind_x: float
    wind_y: float
    wind_z: float
    var_horiz: float
    var_vert: float
    wind_alt: float
    horiz_accuracy: float
    vert_accuracy: float

    @classmethod
    def from_msg(cls, m) -> WindRecord:
        return cls(m.time_usec, m.get_srcSystem(), m.get_srcComponent(), m.wind_x, m.wind_y, m.wind_z,
                   m.var_horiz, m.var_vert, m.wind_alt, m.horiz_accuracy, m.vert_accuracy)  # fmt: skip

    @property
    def speed_mps(self) -> float:
        return math.hypot(self.wind_x, self.wind_y)

    @property
    def known(self) -> bool:
        """Is the horizontal wind known (finite, and ``balloon_core.score.wind_unknown``; a vehicle reporting
        accuracy 0, as PX4 does, counts as known)? An infinite component is never a wind (nor a calm from 180°)."""
        finite = math.isfinite(self.wind_x) and math.isfinite(self.wind_y)
        return finite and not bool(wind_unknown(self.speed_mps, self.horiz_accuracy))

    @property
    def from_deg(self) -> float:
        return float(direction_from_deg(self.wind_x, self.wind_y))

    def csv_row(self) -> list:
        return [self.time_usec, self.sysid, self.compid, *(f"{v:.5g}" for v in (
            self.wind_x, self.wind_y, self.wind_z, self.var_horiz, self.var_vert, self.wind_alt,
            self.horiz_accuracy, self.vert_accuracy, self.speed_mps, self.from_deg))]  # fmt: skip


def read_records(path: str) -> list[WindRecord]:
    """WIND_COV records from a ground-station CSV, a .tlog or a raw MAVLink capture, in the file's order. A CSV may
    start with a UTF-8 byte-order mark (a spreadsheet's export); one that is not text, or whose row is cut short, is
    a ValueError naming the file (and the line)."""
    if path.endswith(".csv"):
        return _read_csv(path)
    from balloon_core.wire import LinkStats, capture_messages

    return [WindRecord.from_msg(m) for m in capture_messages(path, LinkStats()) if m.get_type() == "WIND_COV"]


def _read_csv(path: str) -> list[WindRecord]:
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        try:
            names = reader.fieldnames or ()
            missing = [c for c in CSV_COLUMNS[:11] if c not in names]
            if missing:
                raise ValueError(f"{path}: not a ground-station WIND_COV CSV (no column {', '.join(missing[:3])})")
            return [_csv_record(r, f"{path} line {reader.line_num}", len(names)) for r in reader]
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a text CSV (it holds bytes that are not UTF-8 text): a ground-station "
                             "WIND_COV CSV is text") from None  # fmt: skip
        except csv.Error as exc:
            raise ValueError(f"{path} line {reader.line_num}: not a text CSV ({exc})") from None


def _csv_record(r: dict, where: str, n_columns: int) -> WindRecord:
    """One row of a ground-station CSV; ValueError naming ``where`` for a row cut short or a value that is no number."""
    if any(r[k] is None for k in CSV_COLUMNS[:11]):  # fewer values than the header names
        given = sum(v is not None for v in r.values())
        raise ValueError(f"{where} is incomplete ({given} of {n_columns} values): is the file cut off?")
    try:
        return WindRecord(int(r["time_usec"]), int(r["sysid"]), int(r["compid"]),
                          *(float(r[k]) for k in CSV_COLUMNS[3:11]))  # fmt: skip
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def as_arrays(records: list[WindRecord]) -> dict[str, np.ndarray]:
    """Columns in time order (duplicates of a time dropped), time in seconds since boot."""
    recs = sorted({r.time_usec: r for r in records}.values(), key=lambda r: r.time_usec)
    return {
        "time_s": np.array([r.time_usec * 1e-6 for r in recs]),
        "wind_n": np.array([r.wind_x for r in recs]),
        "wind_e": np.array([r.wind_y for r in recs]),
        "accuracy": np.array([r.horiz_accuracy for r in recs]),
        "variability": np.array([r.var_horiz for r in recs]),
        "alt": np.array([r.wind_alt for r in recs]),
    }
