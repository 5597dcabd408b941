"""The estimator's drag scale at the end of the free ascent and its wind-speed bias, per scenario and seed.

    .venv/bin/python tools/drag_bias.py paper-reference,multisine-2d
    .venv/bin/python tools/drag_bias.py steady --duration 200 --seeds 1 --quiet
    .venv/bin/python tools/drag_bias.py steady --duration 200 --seeds 1 --quiet --truth tether_ea_n=2e6

Prints the final drag scale (the truth's is 1 with the default constant Cd), the speed error in % and
the band skill (``benchmarks.common.score_flight``, after 120 s). ``--quiet`` divides every sensor's
noise by 1000 (the model's biases without the noise); ``--truth key=value`` overrides a [truth] option
(e.g. a rigid rope) to isolate a physical effect.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import fly, score_flight  # noqa: E402
from firmware_py.estimator.state import DRAG  # noqa: E402
from sim_hil.dynamics import TruthConfig  # noqa: E402
from sim_hil.scenarios import SCENARIOS  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", help="comma-separated scenario names")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--quiet", action="store_true", help="sensor noise / 1000")
    ap.add_argument("--truth", action="append", default=[], help="key=value [truth] override")
    a = ap.parse_args()
    for name in a.scenarios.split(","):
        sc = SCENARIOS[name]
        if a.quiet:
            s = sc.design.sensors
            quiet = replace(s, **{k: getattr(s, k) / 1000.0 for k in ("accel_mps2", "baro_m", "gyro_dps",
                                                                        "mag_gauss", "thermometer_k")})
            sc = replace(sc, design=replace(sc.design, sensors=quiet))
        if a.truth:
            values = {k: float(v) for k, v in (t.split("=", 1) for t in a.truth)}
            sc = replace(sc, truth=TruthConfig.from_dict({**sc.truth.__dict__, **values}))
        for seed in (int(x) for x in a.seeds.split(",")):
            rows, truth, est = fly(name, a.duration, seed, sc)
            s = score_flight(rows, truth)
            print(f"{name} {seed} drag {est.ekf.x[DRAG]:.4f} speed {s.speed_error_pct:+.2f}% skill {s.band_skill:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
