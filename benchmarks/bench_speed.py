"""Firmware speed: median time of one IMU-sample step (predict + all fusions due at that sample)
and replay throughput (simulated seconds per wall second, MAVLink decode included), side by side
with FilterPy's ExtendedKalmanFilter on the same state size (19) and the same measurements per
step (3 accelerometer and 3 magnetometer components at every sample, plus the barometer and the taut
rows at their rates), in one run: the C core alone (its step timed in C, firmware_c/replay/bench.c),
the C core through its Python binding, the Python core, FilterPy.

    .venv/bin/python -m benchmarks.bench_speed
"""

from __future__ import annotations

import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from balloon_core.config import Design
from balloon_core.wire import LinkStats, TlogWriter, tlog_messages
from firmware_py.app import Firmware
from firmware_py.core_c import new_core
from firmware_py.estimator.state import MODE_TAUT, N_STATES, FilterConfig
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation

ROOT = Path(__file__).resolve().parents[1]


def sensor_stream(duration_s: float):
    sc = SCENARIOS["paper-reference"]
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, 1)
    return list(sim.samples())


def step_times(samples, warm: int, core: str = "py") -> list[float]:
    est = new_core(Design(), FilterConfig(core=core))[0]
    times = []
    clock = time.perf_counter
    for i, s in enumerate(samples):
        t0 = clock()
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        dt = clock() - t0
        if i >= warm:
            times.append(dt)
    assert est.ekf.mode == MODE_TAUT
    return times


def filterpy_step_times(samples, warm: int) -> list[float]:
    """FilterPy's EKF with our sizes: 17 states; per sample two 3-row updates (accelerometer and
    magnetic field), plus a 1-row baro update at 20 Hz and a 4-row taut update at 20 Hz. Linear
    stand-in models (the cost is the filter's algebra, which is what is compared)."""
    from filterpy.kalman import ExtendedKalmanFilter

    n = N_STATES
    ekf = ExtendedKalmanFilter(dim_x=n, dim_z=3)
    ekf.F = np.eye(n) + 0.01 * np.eye(n, k=3)
    ekf.Q = np.eye(n) * 1e-4
    ekf.P *= 0.1
    h3 = np.zeros((3, n))
    h3[:, 6:9] = np.eye(3)
    h1 = np.zeros((1, n))
    h1[0, 2] = 1.0
    h4 = np.zeros((4, n))
    h4[:, 0:4] = np.eye(4)
    r3, r1, r4 = np.eye(3) * 0.03, np.eye(1), np.eye(4) * 0.01
    times = []
    clock = time.perf_counter
    for i, s in enumerate(samples):
        t0 = clock()
        ekf.predict()
        ekf.update(np.array(s.accel).reshape(3, 1), lambda x: h3, lambda x: h3 @ x, R=r3)
        ekf.update(np.array(s.mag).reshape(3, 1), lambda x: h3, lambda x: h3 @ x, R=r3)
        if s.baro:
            ekf.update(np.array([[s.baro[0]]]), lambda x: h1, lambda x: h1 @ x, R=r1)
        if i % 5 == 2:
            ekf.update(np.zeros((4, 1)), lambda x: h4, lambda x: h4 @ x, R=r4)
        dt = clock() - t0
        if i >= warm:
            times.append(dt)
    return times


def c_step_ns(samples, warm: int) -> tuple[float, float]:
    """(median, p99) ns of the C core's own step (float build, as flown), timed in C."""
    from balloon_core.samples import BaroSample, ImuSample
    from firmware_py import lockstep

    subprocess.run(["make", "-s", "-C", str(ROOT / "firmware_c"), "bench"], check=True)
    stream = []
    for s in samples:
        if s.baro:
            stream.append(BaroSample(s.time_usec, *s.baro))
        stream.append(ImuSample(s.time_usec, *s.accel, *s.gyro, *s.mag))
    with tempfile.TemporaryDirectory() as t:
        path = f"{t}/stream.bin"
        lockstep.write_stream(path, Design(), FilterConfig(float32=True), stream)
        out = subprocess.run([str(ROOT / "firmware_c" / "build" / "bench_float"), path, str(warm)],
                             capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    return float(out[3]), float(out[5])


def reprocess_seconds(duration_s: float, core_note: str = "") -> float:
    """Wall time of ``balloon-gs reprocess`` (causal filter + smoother + NetCDF) on a simulated flight."""
    with tempfile.TemporaryDirectory() as t:
        tlog = f"{t}/f.tlog"
        subprocess.run([sys.executable, "-m", "sim_hil", "--scenario", "paper-reference", "--duration",
                        str(duration_s), "--seed", "1", "--out", tlog, "--truth", f"{t}/t.csv"], check=True,
                       capture_output=True)  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "ground_station", "reprocess", tlog, "--out", f"{t}/f.nc", "--quiet"],
                       check=True, capture_output=True)  # fmt: skip
        return time.perf_counter() - t0


def replay_rate(samples, duration_s: float, core: str = "py") -> float:
    enc = SensorPacketEncoder()
    with tempfile.NamedTemporaryFile(suffix=".tlog") as fh:
        w = TlogWriter(fh)
        for s in samples:
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)
        fh.flush()
        fw = Firmware(Design(), FilterConfig(core=core), sink=None)
        t0 = time.perf_counter()
        for m in tlog_messages(fh.name, LinkStats()):
            fw.handle(m)
        wall = time.perf_counter() - t0
    return duration_s / wall


def filterpy_replay_rate(samples, duration_s: float) -> float:
    t0 = time.perf_counter()
    filterpy_step_times(samples, 0)
    return duration_s / (time.perf_counter() - t0)


def main() -> None:
    duration = 300.0
    samples = sensor_stream(duration)
    warm = 6000  # after release and the first taut seconds
    c_med, c_p99 = c_step_ns(samples, warm)
    rows = [("balloon-wind C core (C, float32)", c_med / 1e3, c_p99 / 1e3, float("nan"))]
    for core, label in (("c", "C core via Python (replay: decode+)"), ("py", "Python core (replay: decode+)")):
        t = step_times(samples, warm, core)
        rows.append(
            (label, statistics.median(t) * 1e6, np.percentile(t, 99) * 1e6, replay_rate(samples, duration, core))
        )
    have_fp = importlib.util.find_spec("filterpy") is not None
    if have_fp:
        theirs = filterpy_step_times(samples, warm)
        rows.append(("FilterPy EKF (filter only)", statistics.median(theirs) * 1e6, np.percentile(theirs, 99) * 1e6,
                     filterpy_replay_rate(samples, duration)))  # fmt: skip
    print(f"{'filter':36s} {'median step us':>15s} {'p99 us':>8s} {'x real time':>12s}")
    for label, med, p99, rate in rows:
        print(f"{label:36s} {med:15.2f} {p99:8.1f} {'-' if rate != rate else f'{rate:.0f}':>12s}")
    if have_fp:
        fp = rows[-1][1]
        print(f"C step / FilterPy's: 1/{fp / rows[0][1]:.0f} (target <= 1/10); Python core / FilterPy's: "
              f"{rows[2][1] / fp:.2f}")  # fmt: skip
    else:
        print("FilterPy is not installed (the bench extra: pip install -e '.[bench]'): comparison skipped")
    print(f"balloon-fw --core c replay: {rows[1][3]:.0f}x real time (target >= 300x; MAVLink decode and the")
    print("input pipeline in Python bound it: the C step is a few per cent of a sample's time)")
    print(f"balloon-gs reprocess of a 1 h flight: {reprocess_seconds(3600.0):.1f} s (target <= 20 s; the smoother")
    print("records every step of the Python core)")
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}")


if __name__ == "__main__":
    main()
