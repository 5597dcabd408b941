"""Speed of every program in one run, one table: the filter's step (the C core timed in C, the C core
and the Python core through Python, FilterPy's EKF on the same sizes when installed) and the physical
floor of that step (its dense algebra's flops at the machine's measured matmul rate); replay
(``balloon-fw``'s file path: tlog decoding + firmware, in process), reprocessing (``balloon-gs reprocess``
as a process), the simulator on both ropes (sensors, MAVLink packets, truth), and study cases per hour.

Where a faster path replaced a slower one the slower is timed beside it in the same run ("before"): the
simulator's Python reference physics (``Simulation(reference=True)``) and the replay's pymavlink decoding
with one C call a sample. Rates ("x") are simulated seconds per second of the program's own CPU time
(``CPU``: process time, the children's for a process), which other work on a shared machine disturbs
far less than wall time; the step times are medians of wall-clock steps. Compare rows of one run.

    .venv/bin/python -m benchmarks.bench_speed [--quick]
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import os
import resource
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
from sim_hil.simulator import Simulation, TruthCsvWriter

ROOT = Path(__file__).resolve().parents[1]
CPU = time.process_time  # this process's CPU time: what the rates are per
HOUR_S = 3600.0
# targets (issue 25)
TARGET_SIM_X = 200.0  # the lumped rope
TARGET_REPLAY_X = 1500.0  # balloon-fw --core c on a tlog
TARGET_C_VS_FILTERPY = 1 / 10


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
    """FilterPy's EKF with our sizes: 19 states; per sample two 3-row updates (accelerometer and
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


def step_flops(n: int = N_STATES, rows_per_step: float = 3 + 3 + (1 + 4) / 5) -> float:
    """Floating-point operations of one step's dense EKF algebra (the floor any implementation of this
    filter's size pays without exploiting sparsity): predict P = F P F^T + Q, two n x n x n products
    (4 n^3) and the sum (n^2); each scalar measurement row (sequential update) P H^T (2 n^2), the gain
    (n), P -= K (H P) (2 n^2): 4 n^2 + n. Rows per step: accelerometer 3 and magnetometer 3 at every
    sample, the barometer (1) and the taut rows (4) at a fifth of them. The models' evaluation
    (generated.c) and the state's update are left out: a lower bound."""
    return 4 * n**3 + n**2 + rows_per_step * (4 * n**2 + n)


def matmul_flops_per_s(size: int = 512, repeats: int = 7) -> float:
    """The machine's float64 rate on numpy's matmul (its BLAS): 2 size^3 per product per CPU second (the
    process's CPU time, all the BLAS threads': one core's rate, as the step runs on one), the best of
    ``repeats``."""
    a = np.random.default_rng(1).standard_normal((size, size))
    b = a.T.copy()
    a @ b
    best = min(_timed(lambda: a @ b) for _ in range(repeats))
    return 2.0 * size**3 / best


def small_matmul_flops_per_s(n: int = N_STATES, repeats: int = 20000) -> float:
    """The same for the filter's own size (n x n, one product per numpy call: call overhead included)."""
    a = np.random.default_rng(2).standard_normal((n, n))
    out = np.empty((n, n))
    t = _timed(lambda: [np.matmul(a, a, out=out) for _ in range(repeats)])
    return 2.0 * n**3 * repeats / t


def children_cpu() -> float:
    """CPU time (user + system) of the finished child processes."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _timed(fn) -> float:
    """CPU seconds of ``fn()``."""
    t0 = CPU()
    fn()
    return CPU() - t0


def write_tlog(samples, path: str) -> None:
    enc = SensorPacketEncoder()
    with open(path, "wb") as fh:
        w = TlogWriter(fh)
        for s in samples:
            for frame in enc.encode(s):
                w.write(s.time_usec, frame)


def replay_rate(tlog: str, duration_s: float, core: str = "c", how: str = "program", repeats: int = 2) -> float:
    """What ``balloon-fw --core CORE --in TLOG`` does, in process (no start-up, no output file). ``how``:
    "program", the program's own replay (``cli.replay_file``: on the C core the tlog scanner,
    firmware_py/replay.py); "fastmav", the records decoded in Python (the sensor messages by fastmav), each
    message through the firmware, the samples to the C core a block at a time (before the scanner);
    "pymavlink", all decoded by pymavlink, one C call a sample (before the blocks). Simulated seconds per
    CPU second, the best of ``repeats``."""
    from firmware_py.cli import replay_file

    best = np.inf
    for _ in range(repeats):
        fw = Firmware(Design(), FilterConfig(core=core), sink=None)
        t0 = CPU()
        if how == "program":
            replay_file(fw, tlog)
        else:
            if how == "fastmav":
                fw.use_batches()
            for m in tlog_messages(tlog, LinkStats(), fast=how == "fastmav"):
                fw.handle(m)
            fw.flush()
        best = min(best, CPU() - t0)
    return duration_s / best


def c_batch_rate(samples, duration_s: float, repeats: int = 2) -> float:
    """The replay's ceiling: the samples, already decoded and in one block, through the C core (float64,
    balloon-fw's default) in one ``CEstimator.on_batch`` call: the estimator's own cost, nothing in Python."""
    from firmware_py.core_c import SampleBlock

    n = len(samples) + sum(1 for s in samples if s.baro)
    blk = SampleBlock(n)
    for s in samples:
        if s.baro:
            blk.add(s.time_usec, SampleBlock.KIND_BARO, (*s.baro, *(0.0,) * 7))
        blk.add(s.time_usec, SampleBlock.KIND_IMU, (*s.accel, *s.gyro, *s.mag))
    blk.ready()
    best = np.inf
    for _ in range(repeats):
        est = new_core(Design(), FilterConfig(core="c"))[0]
        t0 = CPU()
        done = est.on_batch(blk, 0, 2**62, est.consistency.flags, 2**62)
        best = min(best, CPU() - t0)
        assert done == n
    return duration_s / best


def sim_rate(scenario: str, duration_s: float, reference: bool) -> float:
    """What ``balloon-sim --scenario S --out F.tlog --truth T.csv`` does (tlog and CSV to /dev/null)."""
    sc = SCENARIOS[scenario]
    truth = TruthCsvWriter(os.devnull)
    sim = Simulation(sc.design, sc.wind, sc.truth, duration_s, 1, keep_truth=False, truth_sink=truth,
                     reference=reference)  # fmt: skip
    enc, w = SensorPacketEncoder(), TlogWriter(io.BytesIO())
    t0 = CPU()
    for s in sim.samples():
        for frame in enc.encode(s):
            w.write(s.time_usec, frame)
    sim.flush_truth()
    wall = CPU() - t0
    truth.close()
    return duration_s / wall


def reprocess_rate(duration_s: float) -> float:
    """``balloon-gs reprocess`` (causal filter + smoother + NetCDF) of a simulated flight, as a process."""
    with tempfile.TemporaryDirectory() as t:
        tlog = f"{t}/f.tlog"
        subprocess.run([sys.executable, "-m", "sim_hil", "--scenario", "paper-reference", "--duration",
                        str(duration_s), "--seed", "1", "--out", tlog, "--quiet"], check=True,
                       capture_output=True)  # fmt: skip
        t0 = children_cpu()
        subprocess.run([sys.executable, "-m", "ground_station", "reprocess", tlog, "--out", f"{t}/f.nc", "--quiet"],
                       check=True, capture_output=True)  # fmt: skip
        return duration_s / (children_cpu() - t0)


def study_case_s(duration_s: float) -> float:
    """One paper-reference study case (simulator + firmware + metrics, ``study.case.run_case``) in process."""
    from benchmarks.bench_study import cases
    from study.case import run_case

    t0 = CPU()
    row = run_case(cases(duration_s, 1)[0].payload())
    assert row["status"] == "ok", row["error"]
    return CPU() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="shorter flights (noisier figures)")
    args = ap.parse_args(argv)
    duration = 120.0 if args.quick else 300.0
    sim_s = 60.0 if args.quick else 120.0
    reprocess_s = 300.0 if args.quick else 600.0
    case_s = 600.0
    samples = sensor_stream(duration)
    warm = 6000  # after release and the first taut seconds
    rows: list[tuple[str, str, str]] = []  # (what, figure, note)

    c_med, c_p99 = c_step_ns(samples, warm)
    tc = step_times(samples, warm, "c")
    tp = step_times(samples, warm, "py")
    rows.append(("filter step: C core, timed in C (float32)", f"{c_med / 1e3:.2f} us", f"p99 {c_p99 / 1e3:.1f} us"))
    rows.append(("filter step: C core via ctypes (float64)", f"{statistics.median(tc) * 1e6:.2f} us",
                 f"p99 {np.percentile(tc, 99) * 1e6:.1f} us"))  # fmt: skip
    rows.append(("filter step: Python core", f"{statistics.median(tp) * 1e6:.1f} us",
                 f"p99 {np.percentile(tp, 99) * 1e6:.1f} us"))  # fmt: skip
    fp_med = None
    if importlib.util.find_spec("filterpy") is not None:
        tf = filterpy_step_times(samples, warm)
        fp_med = statistics.median(tf)
        rows.append(("filter step: FilterPy EKF (same sizes)", f"{fp_med * 1e6:.1f} us",
                     f"p99 {np.percentile(tf, 99) * 1e6:.1f} us; C step 1/{fp_med / (c_med / 1e9):.0f} of it "
                     f"(target <= 1/{1 / TARGET_C_VS_FILTERPY:.0f})"))  # fmt: skip
    else:
        rows.append(("filter step: FilterPy EKF", "-", "not installed (pip install -e '.[bench]')"))
    flops = step_flops()
    big, small = matmul_flops_per_s(), small_matmul_flops_per_s()
    rows.append(("physical floor of a step (dense algebra)", f"{flops / big * 1e9:.0f} ns",
                 f"{flops / 1e3:.1f} kflop at {big / 1e9:.1f} GFLOP/s a core (numpy 512^2 matmul); "
                 f"{flops / small * 1e6:.1f} us at {small / 1e9:.2f} GFLOP/s (19^2 matmuls)"))  # fmt: skip

    with tempfile.TemporaryDirectory() as t:
        tlog = f"{t}/flight.tlog"
        write_tlog(samples, tlog)
        for core, how, label in (("c", "program", "replay balloon-fw --core c (C tlog scanner, blocks)"),
                                 ("c", "fastmav", "replay balloon-fw --core c (fastmav, blocks: before)"),
                                 ("c", "pymavlink", "replay balloon-fw --core c (pymavlink: before)"),
                                 ("py", "program", "replay balloon-fw --core py (fastmav)")):  # fmt: skip
            x = replay_rate(tlog, duration, core, how, repeats=3 if core == "c" else 1)
            note = f"target >= {TARGET_REPLAY_X:.0f}x" if (core, how) == ("c", "program") else ""
            rows.append((label, f"{x:.0f}x", note))
    x = c_batch_rate(samples, duration)
    rows.append(("replay's ceiling: the C core alone (float64)", f"{x:.0f}x",
                 f"{duration / x / len(samples) * 1e6:.1f} us an IMU sample: decoded samples, one call"))  # fmt: skip
    x = reprocess_rate(reprocess_s)
    rows.append((f"reprocess balloon-gs ({reprocess_s:.0f} s flight, process)", f"{x:.0f}x",
                 f"{reprocess_s / x:.1f} s with the program's start-up (the C core, with the smoother's recorder); "
                 "a 1 h and a 24 h flight: benchmarks.bench_reprocess"))  # fmt: skip
    for scenario, rope in (("paper-reference", "paper rope"), ("field-rope", "lumped rope")):
        for reference in (False, True):
            x = max(sim_rate(scenario, sim_s, reference) for _ in range(1 if reference else 3))  # the best
            label = f"simulator {rope} ({'Python reference: before' if reference else 'compiled'})"
            note = f"target >= {TARGET_SIM_X:.0f}x" if rope == "lumped rope" and not reference else ""
            rows.append((label, f"{x:.0f}x", note))
    t_case = study_case_s(case_s)
    rows.append((f"study: {case_s:.0f} s paper-reference cases per hour", f"{HOUR_S / t_case:.0f}/h",
                 f"one worker, in process ({t_case:.1f} CPU s a case); x workers on as many free cores"))  # fmt: skip

    print(f"balloon-wind speed, one run ({duration:.0f} s paper-reference stream for the filter and replay; "
          f"simulator {sim_s:.0f} s; x = simulated s per CPU s)")  # fmt: skip
    w = max(len(r[0]) for r in rows)
    print(f"{'what':{w}s}  {'figure':>9s}  note")
    for what, fig, note in rows:
        print(f"{what:{w}s}  {fig:>9s}  {note}")
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.1f} at the end")  # fmt: skip


if __name__ == "__main__":
    main()
