"""What the free ascent learns of the balloon's drag, over the envelope benchmark's flights of one wind kind.

    .venv/bin/python tools/ascent_scale.py steady        # the full sample's 50 steady flights (about 10 s)
    .venv/bin/python tools/ascent_scale.py gusts --flights 64

Flies each flight of ``benchmarks.bench_envelope``'s sample whose wind is of that kind on the Python core until
the ascent's drag scale is taken (the cap at the end of its learning, ``Estimator._ascent_data``) and prints, over
those flights, how far it is from the truth's (``cd_scale``, the truth's C_d over the design's): the RMS, the
worst and the mean relative error, and the median 1-sigma the ascent's data claimed. ``DRAG_ASCENT_FLOOR`` is the
steady flights' RMS.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_envelope import WIND_KINDS, sample, sections_of  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from sim_hil.simulator import Simulation  # noqa: E402
from study.spec import build  # noqa: E402

ASCENT_S = 90.0  # long enough for every sampled tether's climb


def ascent_error(point: dict) -> tuple[float, float] | None:
    """(the ascent's scale over the truth's - 1, the 1-sigma its data claimed), None if it learnt nothing."""
    design, wind, truth_cfg, filt = build(sections_of(point))
    est = Estimator(design, dataclasses.replace(filt, core="py"))
    for s in Simulation(design, wind, truth_cfg, ASCENT_S, point["seed"]).samples():
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if est._ascent_var > 0.0:
            return est._ascent_data / point["cd_scale"] - 1.0, math.sqrt(est._ascent_var)
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=WIND_KINDS)
    ap.add_argument("--flights", type=int, default=200, help="the sample's size (200: the full benchmark's)")
    a = ap.parse_args(argv)
    res = [r for p in sample(a.flights) if p["wind_kind"] == a.kind and (r := ascent_error(p)) is not None]
    if not res:
        print(f"ascent_scale: no {a.kind} flight learnt a drag scale", file=sys.stderr)
        return 2
    e, sd = np.array(res).T
    rms, worst, mean = 100 * np.sqrt(np.mean(e**2)), 100 * np.abs(e).max(), 100 * e.mean()
    print(f"{len(e)} {a.kind} flights: the ascent's drag scale against the truth's C_d: RMS {rms:.1f} %, worst "
          f"{worst:.1f} %, mean {mean:+.1f} %; its claimed 1-sigma, median {100 * np.median(sd):.1f} %")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
