"""Memory of long flights: ``balloon-fw`` replaying a tlog and ``balloon-gs reprocess`` of it.

    .venv/bin/python -m benchmarks.bench_memory [--hours 0.25 1] [--hours 1 6 24]

For each flight length, ``balloon-sim`` writes a tlog of paper-reference (100 Hz IMU), then each program
runs on it in a fresh process and its peak resident memory (ru_maxrss of that child alone) and wall time
are measured. ``balloon-fw`` reads the file a chunk at a time and holds counters only: its peak must not
grow with the flight. ``reprocess`` holds 9 bytes a sample and a few hundred bytes an estimate (the
smoother's store spills to a temporary directory): the target is <= 2 GB for 24 h. The default (a quarter
hour and one hour) takes a few minutes; 6 h and 24 h take hours on a small machine (the simulator alone
writes a 24 h tlog in about 11 min, the filter runs at about 20x real time per core).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

PEAK = "import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL); " \
       "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"  # fmt: skip
TARGET_REPROCESS_24H_MB = 2048


def peak_mb(*cmd: str) -> tuple[float, float]:
    """(peak resident memory MB, wall s) of one program run in its own process."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", PEAK, *cmd], check=True, capture_output=True, text=True)
    return int(out.stdout.split()[-1]) / 1024, time.perf_counter() - t0


def one(hours: float, tmp: str) -> dict:
    py = sys.executable
    tlog = os.path.join(tmp, f"flight-{hours:g}h.tlog")
    t0 = time.perf_counter()
    subprocess.run([py, "-m", "sim_hil", "--scenario", "paper-reference", "--duration", str(hours * 3600),
                    "--seed", "1", "--out", tlog, "--quiet"], check=True, capture_output=True)  # fmt: skip
    row = {"hours": hours, "tlog_mb": os.path.getsize(tlog) / 1e6, "sim_s": time.perf_counter() - t0}
    row["fw_mb"], row["fw_s"] = peak_mb(py, "-m", "firmware_py", "--in", tlog, "--out",
                                        os.path.join(tmp, "wind.tlog"), "--quiet")  # fmt: skip
    row["rp_mb"], row["rp_s"] = peak_mb(py, "-m", "ground_station", "reprocess", tlog, "--out",
                                        os.path.join(tmp, "wind.nc"), "--quiet")  # fmt: skip
    os.remove(tlog)
    return row


def table(rows: list[dict]) -> list[str]:
    head = f"{'flight':>8s} {'tlog':>8s} | {'balloon-fw peak':>15s} {'wall':>7s} | {'reprocess peak':>14s} {'wall':>7s}"
    lines = [head]
    for r in rows:
        lines.append(f"{r['hours']:>6g} h {r['tlog_mb']:>5.0f} MB | {r['fw_mb']:>12.0f} MB {r['fw_s']:>6.0f} s | "
                     f"{r['rp_mb']:>11.0f} MB {r['rp_s']:>6.0f} s")  # fmt: skip
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        per_h = (b["rp_mb"] - a["rp_mb"]) / (b["hours"] - a["hours"])
        lines.append(f"reprocess grows {per_h:.0f} MB per flight hour between {a['hours']:g} h and {b['hours']:g} h "
                     f"(24 h by that slope: {b['rp_mb'] + per_h * (24 - b['hours']):.0f} MB, target "
                     f"<= {TARGET_REPROCESS_24H_MB} MB); balloon-fw {b['fw_mb'] - a['fw_mb']:+.0f} MB")  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[0.25, 1.0], help="flight lengths [h]")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for h in args.hours:
            rows.append(one(h, tmp))
            print(table(rows)[-1] if len(rows) > 1 else "\n".join(table(rows)), flush=True)
    print("\n".join(table(rows)))


if __name__ == "__main__":
    main()
