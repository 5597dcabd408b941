"""Writes ``balloon-sim.bin``: a synthetic ArduPilot DataFlash log of a simulated balloon flight, written
from the DataFlash format (FMT records describing every message type, then binary records:
0xA3 0x95 type payload), with the UNIT / MULT / FMTU unit metadata ArduPilot logs carry, and the truth
wind beside it (``balloon-sim-truth.csv``, 1 Hz).

No small public DataFlash log with a barometer and magnetometer was at hand, so this one is made from
the simulator: paper-reference scenario, seed 8, 90 s, IMU 200 Hz (ArduPilot's fast IMU logging; the
firmware averages it to its 100 Hz step), MAG 50 Hz, BARO 20 Hz, GPS 5 Hz (for UTC), and a 0.3 s IMU
dropout at 60 s. Run from the repository root: ``python tests/data/make_dataflash.py``."""

from __future__ import annotations

import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from sim_hil.scenarios import SCENARIOS  # noqa: E402
from sim_hil.simulator import TRUTH_COLUMNS, Simulation  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
BOOT_UTC_S = 1_780_293_600  # 2026-06-01T06:00:00Z, the autopilot's boot
GPS_EPOCH_UNIX_S, GPS_LEAP_S = 315_964_800, 18
FMT, UNIT, MULT, FMTU, IMU, MAG, BARO, GPS = 128, 100, 101, 102, 103, 104, 105, 106
TYPES = {  # type: (name, format, columns, units, mults)
    UNIT: ("UNIT", "QbZ", "TimeUS,Id,Label", None, None),
    MULT: ("MULT", "Qbd", "TimeUS,Id,Mult", None, None),
    FMTU: ("FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", None, None),
    IMU: ("IMU", "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", "s#EEEooo", "F-000000"),
    MAG: ("MAG", "QBhhh", "TimeUS,I,MagX,MagY,MagZ", "s#GGG", "F-CCC"),
    BARO: ("BARO", "QBffcf", "TimeUS,I,Alt,Press,Temp,CRt", "s#mPOn", "F-00B0"),
    GPS: ("GPS", "QBBIHB", "TimeUS,I,Status,GMS,GWk,NSats", "s#----", "F-----"),
}
STRUCT = {"Q": "Q", "B": "B", "b": "b", "f": "f", "h": "h", "c": "h", "I": "I", "H": "H", "d": "d", "Z": "64s",
          "N": "16s", "n": "4s"}  # fmt: skip
UNITS = {"s": "s", "#": "instance", "E": "rad/s", "o": "m/s/s", "G": "Gauss", "P": "Pa", "O": "degC", "m": "m",
         "n": "m/s", "-": ""}  # fmt: skip
MULTS = {"-": 0.0, "0": 1.0, "B": 1e-2, "C": 1e-3, "F": 1e-6}


def struct_of(fmt: str) -> str:
    return "<" + "".join(STRUCT[c] for c in fmt)


def record(mtype: int, fmt: str, *values) -> bytes:
    return bytes((0xA3, 0x95, mtype)) + struct.pack(struct_of(fmt), *values)


def fmt_record(mtype: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + struct.calcsize(struct_of(fmt))
    return record(FMT, "BBnNZ", mtype, length, name.encode(), fmt.encode(), columns.encode())


def main() -> None:
    sc = SCENARIOS["paper-reference"]
    sim = Simulation(sc.design, sc.wind, sc.truth, 90.0, 8, imu_hz=200.0)
    out = bytearray(fmt_record(FMT, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    for t, (name, fmt, cols, _, _) in TYPES.items():
        out += fmt_record(t, name, fmt, cols)
    for uid, label in UNITS.items():
        out += record(UNIT, "QbZ", 0, ord(uid), label.encode())
    for mid, mult in MULTS.items():
        out += record(MULT, "Qbd", 0, ord(mid), mult)
    for t, (_, _, _, units, mults) in TYPES.items():
        if units:
            out += record(FMTU, "QBNN", 0, t, units.encode(), mults.encode())
    for k, s in enumerate(sim.samples()):
        t_us = s.time_usec
        if not 60_000_000 <= t_us < 60_300_000:  # a 0.3 s IMU dropout
            out += record(IMU, "QBffffff", t_us, 0, *s.gyro, *s.accel)
        if k % 4 == 0:
            out += record(MAG, "QBhhh", t_us, 0, *(round(v * 1000.0) for v in s.mag))
        if s.baro is not None:
            hpa, temp_c = s.baro
            out += record(BARO, "QBffcf", t_us, 0, 0.0, hpa * 100.0, round(temp_c * 100.0), 0.0)
        if k % 40 == 0:
            gps_s = BOOT_UTC_S + t_us * 1e-6 + GPS_LEAP_S - GPS_EPOCH_UNIX_S
            week = int(gps_s // 604_800)
            out += record(GPS, "QBBIHB", t_us, 0, 3, round((gps_s - week * 604_800) * 1000), week, 12)
    with open(os.path.join(HERE, "balloon-sim.bin"), "wb") as fh:
        fh.write(out)
    cols = [TRUTH_COLUMNS.index(c) for c in ("time_s", "wind_n", "wind_e")]
    with open(os.path.join(HERE, "balloon-sim-truth.csv"), "w") as fh:
        fh.write("time_s,wind_n,wind_e\n")
        for row in sim.truth[::200]:
            fh.write(",".join(f"{row[c]:.4f}" for c in cols) + "\n")


if __name__ == "__main__":
    main()
