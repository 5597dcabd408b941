"""A paper-reference truth flight: prints a summary and writes a plot of the wind and the balloon.

    .venv/bin/python -m sim_hil.demo [--duration 600] [--seed 1] [--plot out/flight.png]
"""

from __future__ import annotations

import argparse
import math
import os

import numpy as np

from sim_hil.dynamics import steady_blowdown_deg
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import TRUTH_COLUMNS, Simulation


def plot_flight(truth: np.ndarray, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = {name: truth[:, i] for i, name in enumerate(TRUTH_COLUMNS)}
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax[0].plot(c["time_s"], np.hypot(c["wind_n"], c["wind_e"]), label="wind speed")
    ax[0].plot(c["time_s"], np.hypot(c["vel_n"], c["vel_e"]), label="balloon horizontal speed", alpha=0.7)
    ax[0].set_ylabel("m/s")
    ax[0].legend(loc="upper right")
    ax[1].plot(c["time_s"], c["height_m"], label="height")
    ax[1].plot(c["time_s"], np.hypot(c["pos_n"], c["pos_e"]), label="horizontal distance")
    ax[1].set_ylabel("m")
    ax[1].legend(loc="lower right")
    ax[2].plot(c["time_s"], c["roll_deg"], label="roll")
    ax[2].plot(c["time_s"], c["pitch_deg"], label="pitch")
    ax[2].plot(c["time_s"], c["tension_n"], label="tension [N]")
    ax[2].set_xlabel("time since boot [s]")
    ax[2].legend(loc="upper right")
    fig.suptitle("balloon-sim paper-reference: truth")
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.savefig(path, dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--plot", default="out/flight.png")
    args = ap.parse_args()
    sc = SCENARIOS["paper-reference"]
    sim = Simulation(sc.design, sc.wind, sc.truth, args.duration, args.seed)
    sim.run()
    c = {name: sim.truth[:, i] for i, name in enumerate(TRUTH_COLUMNS)}
    taut = c["tether_taut"] > 0
    late = c["time_s"] > 120.0
    speed = np.hypot(c["wind_n"], c["wind_e"])
    angle = np.degrees(np.arctan2(np.hypot(c["pos_n"], c["pos_e"]), -c["pos_d"]))
    mean_wind = speed[late].mean()
    print(f"scenario paper-reference, seed {args.seed}, {args.duration:.0f} s")
    print(f"first taut at {c['time_s'][np.argmax(taut)]:.1f} s; taut {100 * taut.mean():.0f} % of the flight")
    print(f"wind after 120 s: mean {mean_wind:.2f} m/s, std {speed[late].std():.2f} m/s")
    print(f"blow-down angle: mean {angle[late].mean():.1f} deg "
          f"(steady analytic at the mean wind {steady_blowdown_deg(sim.physics, mean_wind, 92.0):.1f} deg)")
    print(f"mean height {c['height_m'][late].mean():.1f} m, mean tension {c['tension_n'][late].mean():.1f} N")
    plot_flight(sim.truth, args.plot)
    print(f"plot: {args.plot} ({math.ceil(os.path.getsize(args.plot) / 1024)} KiB)")


if __name__ == "__main__":
    main()
