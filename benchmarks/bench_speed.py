"""Firmware speed: median time of one IMU-sample step (predict + all fusions due at that sample)
and replay throughput (simulated seconds per wall second, MAVLink decode included), side by side
with FilterPy's ExtendedKalmanFilter on the same state size (15) and the same measurements per
step (3 accelerometer components at every sample, plus the barometer, heading and taut rows at
their rates), in one run.

    .venv/bin/python -m benchmarks.bench_speed
"""

from __future__ import annotations

import importlib.util
import statistics
import sys
import tempfile
import time

import numpy as np

from balloon_core.config import Design
from balloon_core.wire import LinkStats, TlogWriter, tlog_messages
from firmware_py.app import Firmware
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import MODE_TAUT, N_STATES
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation


def sensor_stream(duration_s: float):
    sc = SCENARIOS["paper-reference"]
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, 1)
    return list(sim.samples())


def step_times(samples, warm: int) -> list[float]:
    est = Estimator(Design())
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


def replay_rate(samples, duration_s: float) -> float:
    enc = SensorPacketEncoder()
    with tempfile.NamedTemporaryFile(suffix=".tlog") as fh:
        w = TlogWriter(fh)
        for s in samples:
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)
        fh.flush()
        fw = Firmware(Design(), sink=None)
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
    ours = step_times(samples, warm)
    print(f"{'filter':34s} {'median step us':>15s} {'p99 us':>8s} {'x real time':>12s}")
    print(f"{'balloon-wind EKF (replay: decode+)':34s} {statistics.median(ours) * 1e6:15.1f} "
          f"{np.percentile(ours, 99) * 1e6:8.1f} {replay_rate(samples, duration):12.0f}")  # fmt: skip
    if importlib.util.find_spec("filterpy") is None:
        print("FilterPy is not installed (the bench extra: pip install -e '.[bench]'): comparison skipped")
        return
    theirs = filterpy_step_times(samples, warm)
    print(f"{'FilterPy EKF (filter only)':34s} {statistics.median(theirs) * 1e6:15.1f} "
          f"{np.percentile(theirs, 99) * 1e6:8.1f} {filterpy_replay_rate(samples, duration):12.0f}")  # fmt: skip
    ratio = statistics.median(ours) / statistics.median(theirs)
    print(f"median step ours / FilterPy's: {ratio:.2f} (target <= 1.5); replay target >= 100x real time (100 Hz IMU)")
    print("FilterPy runs linear stand-in models (no force model, no Jacobians) with batch updates and")
    print("allocates per step; ours evaluates the balloon model and its Jacobians, allocation-free.")
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}")


if __name__ == "__main__":
    main()
