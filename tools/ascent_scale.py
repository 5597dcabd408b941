"""What the free ascent learns of the balloon's drag, over the envelope benchmark's flights of one wind kind.

    .venv/bin/python tools/ascent_scale.py steady        # the full sample's 50 steady flights (about 10 s)
    .venv/bin/python tools/ascent_scale.py gusts --flights 64 --duration 300   # the quick sample's
    .venv/bin/python tools/ascent_scale.py kaimal --flights 64 --duration 300 --sample-seed 12   # a held-out one
    .venv/bin/python tools/ascent_scale.py steady --set tether.length_m=20 --set truth.rope_segments=48
                                                           # the same flights, their world changed (TOML values)

Flies each flight of ``benchmarks.bench_envelope``'s sample whose wind is of that kind on the Python core until
the taut entry, and takes the ascent's drag scale that the taut flight weighs (``Estimator._ascent_data``: the
cap at the end of its last spell of learning; the learning stops while the rope's pull is not known) and prints, over
those flights, how far it is from the truth's (``cd_scale``, the truth's C_d over the design's): the RMS, the
worst and the mean relative error, and the median 1-sigma the ascent's data claimed; and the wind the state took from
the release, AFTER_RELEASE_S later: its error over the 1-sigma the state's covariance gave it
(``WindEkf.wind_accuracy``, not the reported accuracy; median, p90). ``DRAG_ASCENT_FLOOR`` is the steady flights' RMS.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from benchmarks.bench_envelope import FULL_DURATION_S, SEED, WIND_KINDS, sample  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from firmware_py.estimator.state import MODE_FREE, MODE_GROUND, MODE_TAUT, WIND_E, WIND_N  # noqa: E402
from sim_hil.simulator import TRUTH_COLUMNS, Simulation  # noqa: E402
from study.spec import build  # noqa: E402
from tools.accuracy_terms import world  # noqa: E402

AFTER_RELEASE_S = 0.5  # when the wind the state took from the release is judged (the drag scale learns from then on)


def ascent_error(
    point: dict, duration_s: float = FULL_DURATION_S, settings: tuple[str, ...] = ()
) -> tuple[float, float, float, float, float] | None:  # fmt: skip
    """(the ascent's scale over the truth's - 1, the 1-sigma its data claimed, the ascent's scale, its climb m/s, the
    wind's error AFTER_RELEASE_S after the release over the 1-sigma the state gave it), None if it learnt nothing. The
    flight is the benchmark's of ``duration_s`` (its wind depends on the length), with ``settings``
    (``SECTION.KEY=VALUE``, ``accuracy_terms.override``) applied, flown until the ascent is weighed."""
    design, wind, truth_cfg, filt = build(world(point, settings))
    est = Estimator(design, dataclasses.replace(filt, core="py"))
    sim = Simulation(design, wind, truth_cfg, duration_s, point["seed"])
    released, wind_z = math.nan, math.nan
    for k, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        t = s.time_usec * 1e-6
        if est.ekf.mode == MODE_GROUND:  # (again, after a bump the filter took for a release)
            released, wind_z = math.nan, math.nan
        elif est.ekf.mode == MODE_FREE and not released <= t:
            released = t
        if math.isnan(wind_z) and t >= released + AFTER_RELEASE_S:
            x, truth = est.ekf.x, sim.truth[k]  # the truth's row of this sample
            tn, te = truth[TRUTH_COLUMNS.index("wind_n")], truth[TRUTH_COLUMNS.index("wind_e")]
            wind_z = math.hypot(x[WIND_N] - tn, x[WIND_E] - te) / est.ekf.wind_accuracy()
        if est.ekf.mode == MODE_TAUT and not est.ekf.learn_drag and est._ascent_var > 0.0:  # the ascent over and its
            # last spell of learning capped: what the taut flight weighs
            break
    if not est._ascent_var > 0.0:
        return None
    return (est._ascent_data / truth_cfg.drag_coefficient_scale - 1.0, math.sqrt(est._ascent_var), est._ascent_data,
            est._ascent_climb, wind_z)  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=WIND_KINDS)
    ap.add_argument("--flights", type=int, default=200, help="the sample's size (200: the full benchmark's)")
    ap.add_argument("--duration", type=float, default=FULL_DURATION_S,
                    help=f"the flights' length, s ({FULL_DURATION_S:g}: the full benchmark's; the wind depends on it)")
    ap.add_argument("--sample-seed", type=userargs.seed, default=SEED,
                    help=f"the sample's seed ({SEED}: the benchmark's fixed sample; another draws a held-out one)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="change every flight's world or design (TOML values), e.g. truth.rope_segments=48")
    a = ap.parse_args(argv)
    points = sample(a.flights, seed=a.sample_seed)
    settings = tuple(a.set)
    try:
        res = [(i, r) for i, p in enumerate(points)
               if p["wind_kind"] == a.kind and (r := ascent_error(p, a.duration, settings))]  # fmt: skip
    except (ValueError, TypeError) as e:  # ConfigError is a ValueError
        print(f"ascent_scale: {e}", file=sys.stderr)
        return 2
    if not res:
        print(f"ascent_scale: no {a.kind} flight learnt a drag scale", file=sys.stderr)
        return 2
    e, sd, _, _, z = np.array([r for _, r in res]).T
    rms, worst, mean = 100 * np.sqrt(np.mean(e**2)), 100 * np.abs(e).max(), 100 * e.mean()
    print(f"{len(e)} {a.kind} flights: the ascent's drag scale against the truth's C_d: RMS {rms:.1f} %, worst "
          f"{worst:.1f} %, mean {mean:+.1f} %; its claimed 1-sigma, median {100 * np.median(sd):.1f} %; the wind "
          f"{AFTER_RELEASE_S:g} s after the release, its error over its stated 1-sigma: median {np.nanmedian(z):.1f}, "
          f"p90 {np.nanpercentile(z, 90):.1f}")  # fmt: skip
    for i, (err, _, scale, climb, _) in sorted(res, key=lambda x: -abs(x[1][0]))[:3]:
        print(f"  flight {i}: the ascent read {scale:.2f} against the truth's {points[i]['cd_scale']:.2f} "
              f"({100 * err:+.0f} %), climbing at {climb:.1f} m/s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
