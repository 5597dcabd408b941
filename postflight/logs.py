"""Flight files in, estimator samples out: the edge adapters for post-flight reprocessing.

``read_flight(path)`` reads a PX4 ULog (``.ulg``, pyulog), an ArduPilot DataFlash log (``.bin``,
pymavlink's DFReader), a telemetry log (``.tlog``) or a raw MAVLink capture (anything else), chosen by
extension and then by the file's first bytes, into a ``Flight``: the samples as numpy arrays (in time
order for logs; in arrival order for MAVLink, whose reordering and reboots the estimator handles as the
live firmware does) and what the log says about itself (``FlightMeta``). ``Flight.samples()`` iterates
them as ``balloon_core.samples`` ImuSample / BaroSample, the interface every input goes through;
``firmware_py.streams.estimator_steps`` runs them through the live firmware's input pipeline into an
Estimator. A file that cannot be read, or that holds no IMU samples, is a ValueError with one clear line.

One reader a format: ``postflight/ulog.py``, ``dataflash.py``, ``mavlink_log.py`` (tlog and raw), over
the shared data model of ``postflight/flight.py``; this module is the one door that picks among them.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

from postflight.dataflash import read_dataflash
from postflight.flight import DATAFLASH_MAGIC, ULOG_MAGIC, Flight, describe_error
from postflight.mavlink_log import read_mavlink
from postflight.ulog import read_ulog

# ------------------------------------------------------------------------------------------ one door


def flight_format(path: str) -> str:
    """ "ulog", "dataflash", "tlog" or "raw": by extension, else by the first bytes."""
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ulg":
        return "ulog"
    if ext == ".tlog":
        return "tlog"
    with open(path, "rb") as fh:
        head = fh.read(8)
    if ext == ".bin":  # DataFlash's name, but also a common one for a raw serial capture: the bytes decide
        return "dataflash" if head.startswith(DATAFLASH_MAGIC) else "raw"
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    return "raw"


def read_flight(path: str) -> Flight:
    """Any flight file -> Flight. ValueError (one line, for exit 2) if it is missing, empty, unreadable
    or holds no IMU samples."""
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise ValueError(f"{path}: empty file")
    kind = flight_format(path)
    reader = {"ulog": read_ulog, "dataflash": read_dataflash}.get(kind, read_mavlink)
    try:
        return reader(path)
    except ValueError as exc:
        if str(exc).startswith(path):
            raise
        raise ValueError(f"{path}: cannot read this {kind} log: {describe_error(exc)}") from exc
    except Exception as exc:  # a third-party reader's own failure on a damaged file: one line  # noqa: BLE001
        raise ValueError(f"{path}: cannot read this {kind} log: {describe_error(exc)}") from exc


# ------------------------------------------------------------------------------------------ a look


def main(argv: list[str] | None = None) -> int:
    """``python -m postflight.logs FILE [--estimate]``: what a flight file holds and, with
    --estimate, what the estimator makes of it (ten lines over the flight, then its counters)."""
    import argparse

    from balloon_core.config import Design
    from firmware_py.estimator.state import FilterConfig
    from firmware_py.streams import estimator_steps

    ap = argparse.ArgumentParser(prog="python -m postflight.logs", description=main.__doc__)
    ap.add_argument("file")
    ap.add_argument("--estimate", action="store_true", help="run the estimator over it")
    args = ap.parse_args(argv)
    try:
        flight = read_flight(args.file)
    except (ValueError, OSError) as exc:
        print(f"flightlog: {exc}", file=sys.stderr)
        return 2
    m = flight.meta
    print(m.describe())
    print(f"sensors {m.sensors}, utc_start_s {m.utc_start_s} ({m.utc_source}), sha256 {m.sha256}")
    for note in m.notes:
        print(f"note: {note}")
    if not args.estimate:
        return 0
    rows, est = [], None
    for est, s, advanced in estimator_steps(Design(), FilterConfig(), flight.samples(), warn=print):
        if advanced:
            wn, we = est.wind()
            rows.append((s.t_us * 1e-6, wn, we, est.wind_accuracy(), est.ekf.mode, est.height_m()))
    r = np.array(rows)
    print(f"filter at {est.cfg.imu_rate_hz:g} Hz, {len(r)} steps, all finite: {bool(np.all(np.isfinite(r)))}")
    for k in np.linspace(0, len(r) - 1, 10).astype(int):
        t, wn, we, acc, mode, h = r[k]
        print(f"t {t - r[0, 0]:7.1f} s  wind N {wn:6.2f} E {we:6.2f} |{math.hypot(wn, we):5.2f}| m/s  "
              f"accuracy {acc:5.2f} m/s  mode {int(mode)}  height {h:6.1f} m")  # fmt: skip
    print("counters", {k: v for k, v in est.counters.as_dict().items() if v})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
