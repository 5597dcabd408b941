"""Estimator accuracy against the simulator's truth: every CONTRACT scenario x several seeds (the
paper's parameter study, Sec. 3.1-3.4), and the frequency response on the multisine wind.

    .venv/bin/python -m benchmarks.bench_accuracy [--seeds 5] [--duration 600] [--jobs 2]

Metrics after 120 s: band RMSE (horizontal vector, both low-passed below 0.05 Hz), raw RMSE, mean
speed error, mean direction error, reported horiz_accuracy / actual raw RMS error, and the RMS
error of the orientation the firmware computes on board (tilt, heading).
"""

from __future__ import annotations

import argparse
from multiprocessing import Pool

import numpy as np

from benchmarks.common import attitude_errors, fly, gain_flight, score_flight

SCENARIOS = ("paper-reference", "reduced-balloon", "increased-balloon", "better-accel", "better-baro",
             "better-gyro-rate", "better-orientation", "realistic-mems", "rope-drag")  # fmt: skip
GAIN_HZ = (0.01, 0.02, 0.05, 0.1, 0.2)


def variants() -> dict:
    """Mismatch checks beside the scenarios: the firmware not told about the rope's drag, and told
    about a drag the rope does not have."""
    from dataclasses import replace

    from firmware_py.state import FilterConfig
    from sim_hil.dynamics import TruthConfig
    from sim_hil.scenarios import SCENARIOS

    return {
        "multisine, no push": replace(SCENARIOS["multisine"], truth=TruthConfig(froude_krylov=False)),
        "rope-drag, fw not told": replace(SCENARIOS["rope-drag"], filter=FilterConfig()),
        "paper-ref, fw told rope": replace(SCENARIOS["paper-reference"], filter=FilterConfig(rope_normal_cd=1.1)),
    }


def one(job):
    name, seed, duration = job
    rows, truth, est = fly(name, duration, seed, variants().get(name))
    s = score_flight(rows, truth)
    g = gain_flight(rows, truth, GAIN_HZ) if name.startswith("multisine") else {}
    return name, seed, s, g, est.counters.taut_resets, attitude_errors(rows, truth)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    args = ap.parse_args()
    names = [*args.scenarios, *variants(), "multisine"]
    tables = [n for n in names if not n.startswith("multisine")]
    jobs = [(n, s, args.duration) for n in names for s in range(1, args.seeds + 1)]
    with Pool(args.jobs) as pool:
        results = pool.map(one, jobs)
    print(f"{args.seeds} seeds x {args.duration:.0f} s, metrics after 120 s (mean over seeds, [worst])")
    hdr = f"{'scenario':23s} {'band RMSE m/s':>15s} {'raw RMSE':>9s} {'speed err %':>13s} {'dir err deg':>13s} "
    print(hdr + f"{'acc/err':>8s} {'resets':>6s} {'tilt/yaw err deg':>17s}")
    for name in tables:
        rs = [r for r in results if r[0] == name]
        band = np.array([r[2].band_rmse_mps for r in rs])
        raw = np.array([r[2].raw_rmse_mps for r in rs])
        sp = np.array([r[2].speed_error_pct for r in rs])
        dr = np.array([r[2].direction_error_deg for r in rs])
        ratio = np.array([r[2].accuracy_ratio for r in rs])
        resets = sum(r[4] for r in rs)
        tilt = np.mean([r[5][0] for r in rs])
        yaw = np.mean([r[5][1] for r in rs])
        print(f"{name:23s} {band.mean():6.3f} [{band.max():5.3f}] {raw.mean():9.3f} "
              f"{np.abs(sp).mean():5.2f} [{np.abs(sp).max():5.2f}] {np.abs(dr).mean():5.2f} [{np.abs(dr).max():5.2f}] "
              f"{ratio.mean():8.2f} {resets:6d} {tilt:8.2f} {yaw:8.2f}")  # fmt: skip
    print("\nfrequency response on the multisine wind, |estimate / truth| of the along-wind component,")
    print("mean [min, max] over the seeds; 'no push': the truth without the accelerating air's push")
    print(f"{'':20s} " + " ".join(f"{f:>17.2f}" for f in GAIN_HZ) + "  Hz")
    for label, name in (("multisine", "multisine"), ("no push", "multisine, no push")):
        gains = np.array([[r[3][f] for f in GAIN_HZ] for r in results if r[0] == name])
        cells = [f"{m:5.2f} [{lo:4.2f}, {hi:4.2f}]" for m, lo, hi in
                 zip(gains.mean(axis=0), gains.min(axis=0), gains.max(axis=0), strict=True)]  # fmt: skip
        print(f"{label:20s} " + " ".join(f"{c:>17s}" for c in cells))


if __name__ == "__main__":
    main()
