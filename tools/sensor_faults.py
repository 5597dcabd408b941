"""The faults a field day's sensors have, each injected into the same flight some seconds after the taut entry: the
wind's RMS error, error / stated accuracy (RMS over RMS) and share beyond 3 sigma over the window after the fault's
start, against the flight without it (its RMS error's ratio), and the magnetometer's field jumps the estimator saw.

    python tools/sensor_faults.py --faults switched-x,switched-y,burst --scenarios field-rope --seeds 2 3

Faults (the readings changed between the simulator and the estimator, not the truth):
- ``switched-x``, ``switched-y``, ``switched-z``: a field fixed in the body switched on beside the magnetometer and
  left on (a heater, a radio, a servo; 0.02 G along x, 0.05 G along y or z; what ``[truth] mag_switched_gauss``
  makes in the simulator);
- ``disturbed``: 0.1 G along x for 10 s, then gone;
- ``burst``: 0.2 s of 0.1 G along x and 0.05 G along y in every 2 s (a radio's transmissions);
- ``mag-lost``: no magnetometer for 60 s;
- ``imu-lost``: no IMU sample for 3 s (the samples a stuck sensor's watch drops, balloon_core.samples.STUCK_US);
- ``imu-gap``: none for 0.6 s (a link's, beyond ``max_gap_s``);
- ``accel-warm``, ``gyro-warm``: the sun on the IMU, its bias moving with the temperature over a minute and staying:
  the accelerometer's 5 mg along x, the gyro's 0.1 deg/s about x;
- ``baro-warm``, ``thermo-sun``: the barometer's offset 0.5 hPa (4 m) over a minute, the thermometer 10 K warm over
  a minute (in the sun, unshaded), both left so.
Not in the test suite: a study. The C core by default (``--core py`` the Python one)."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

import numpy as np

from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import MODE_TAUT
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation

FAULTS = ("switched-x", "switched-y", "switched-z", "disturbed", "burst", "mag-lost", "imu-lost", "imu-gap",
          "accel-warm", "gyro-warm", "baro-warm", "thermo-sun")
SWITCHED = {"switched-x": (0, 0.02), "switched-y": (1, 0.05), "switched-z": (2, 0.05)}


def faulty(fault: str, since_s: float | None, accel, gyro, mag) -> tuple | None:
    """The IMU sample's readings ``since_s`` after the fault's start (None before it), or None where it is lost."""
    if since_s is None or fault == "none":
        return accel, gyro, mag
    m = list(mag)
    if fault in SWITCHED:
        axis, gauss = SWITCHED[fault]
        m[axis] += gauss
    elif fault == "disturbed" and since_s < 10.0:
        m[0] += 0.1
    elif fault == "burst" and since_s % 2.0 < 0.2:
        m[0] += 0.1
        m[1] += 0.05
    elif fault == "mag-lost" and since_s < 60.0:
        m = [math.nan] * 3
    elif (fault == "imu-lost" and since_s < 3.0) or (fault == "imu-gap" and since_s < 0.6):
        return None
    elif fault == "accel-warm":
        accel = (accel[0] + 0.05 * min(since_s / 60.0, 1.0), accel[1], accel[2])
    elif fault == "gyro-warm":
        gyro = (gyro[0] + math.radians(0.1) * min(since_s / 60.0, 1.0), gyro[1], gyro[2])
    return accel, gyro, tuple(m)


def faulty_baro(fault: str, since_s: float | None, baro: tuple[float, float]) -> tuple[float, float]:
    """The barometer's and thermometer's sample (hPa, degrees C) ``since_s`` after the fault's start (None before)."""
    if since_s is None:
        return baro
    ramp = min(since_s / 60.0, 1.0)
    if fault == "baro-warm":
        return baro[0] + 0.5 * ramp, baro[1]
    if fault == "thermo-sun":
        return baro[0], baro[1] + 10.0 * ramp
    return baro


def fly(
    name: str, seed: int, fault: str, at_s: float, window_s: float, core: str, skip_s: float = 0.0,
    duration_s: float | None = None,
) -> tuple[float, float, float, int]:
    """RMS error (m/s), error / accuracy (RMS over RMS), share beyond 3 sigma over ``window_s`` from ``skip_s`` after
    the fault's start ``at_s`` after the taut entry, and the field jumps counted. The flight lasts ``duration_s`` from
    the boot (the wind drawn for it), by default 80 s more than the fault's window."""
    sc = SCENARIOS[name]
    duration_s = at_s + skip_s + window_s + 80.0 if duration_s is None else duration_s
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, seed)
    est = Estimator(sc.design, replace(sc.filter, core=core))
    rows, entry = [], None
    for s in sim.samples():
        t = s.time_usec
        since = None if entry is None or t * 1e-6 < entry + at_s else t * 1e-6 - entry - at_s
        if s.baro:
            est.on_baro(t, *faulty_baro(fault, since, s.baro))
        if entry is None and est.ekf.mode == MODE_TAUT:
            entry = t * 1e-6
        readings = faulty(fault, since, s.accel, s.gyro, s.mag)
        if readings is not None:
            est.on_imu(t, *readings[0], *readings[1], *readings[2])
        if since is not None and skip_s <= since < skip_s + window_s:
            rows.append((t * 1e-6, *est.wind(), est.wind_accuracy()))
    if not rows:
        raise SystemExit(f"{name} seed {seed}: the balloon never flew taut long enough")
    r, truth = np.array(rows), sim.truth
    err = np.hypot(r[:, 1] - np.interp(r[:, 0], truth[:, 0], truth[:, 1]),
                   r[:, 2] - np.interp(r[:, 0], truth[:, 0], truth[:, 2]))  # fmt: skip
    rms = float(np.sqrt(np.mean(err**2)))
    return rms, float(rms / np.sqrt(np.mean(r[:, 3] ** 2))), float(np.mean(err > 3.0 * r[:, 3])), int(
        est.counters.field_jumps)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faults", default=",".join(FAULTS), help=f"comma-separated, of {', '.join(FAULTS)}")
    ap.add_argument("--scenarios", nargs="+", default=["field-rope", "paper-reference", "field-gusty-6"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[2, 3])
    ap.add_argument("--at", type=float, default=30.0, help="the fault's start, s after the taut entry")
    ap.add_argument("--window", type=float, default=90.0, help="s scored from the fault's start")
    ap.add_argument("--core", choices=("c", "py"), default="c")
    a = ap.parse_args(argv)
    faults = a.faults.split(",")
    bad = [f for f in faults if f not in FAULTS] + [s for s in a.scenarios if s not in SCENARIOS]
    if bad:
        print(f"sensor_faults: unknown fault or scenario: {', '.join(bad)}", file=sys.stderr)
        return 2
    print("| scenario | seed | fault | RMS error, m/s | x without | error/accuracy | beyond 3 sigma | jumps |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for name in a.scenarios:
        for seed in a.seeds:
            base = fly(name, seed, "none", a.at, a.window, a.core)
            for fault in ["none", *faults]:
                r = base if fault == "none" else fly(name, seed, fault, a.at, a.window, a.core)
                print(f"| {name} | {seed} | {fault} | {r[0]:.3f} | {r[0] / base[0]:.2f} | {r[1]:.2f} | "
                      f"{100 * r[2]:.1f} % | {r[3]} |", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
