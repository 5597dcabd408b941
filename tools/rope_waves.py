"""How the balloon's axis turns against what the taut model says of it, frequency by frequency (a diagnosis tool).

    python tools/rope_waves.py field-rope-multisine
    python tools/rope_waves.py multisine-2d-ne --seed 2

Flies a multisine scenario with the filter (the Python core) and, at each of its lines (all fitted together with a
constant and a trend), fits three angles from the vertical in the plane of the mean wind: the truth's body axis
(along the rope's pull at the balloon: what the alignment measures), the taut model's pull direction at the truth's
state (position, velocity, wind and its rate, the truth's drag scale; the filter's own rope shape and attachment
point, from its attitude: ``aid_sources/tether.py``'s prediction, where the filter's state error plays no part but
that 1 % of the pull's direction), and the rope's chord. It prints the body axis over the model's pull and over
the chord (gain and phase, deg): where the first is not 1 at 0 deg, the alignment's model is wrong at that frequency
whatever the state. A rope with mass carries transverse waves, which no static shape holds; on the lumped rope the
truth's median tension gives their speed and the first quarter-wave (docs/estimator.md, "What limits the envelope
now", "The real rope at 0.1 Hz")."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from balloon_core.rotation import quat_from_euler, rotation  # noqa: E402
from balloon_core.score import sinusoid_fit  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from firmware_py.estimator.generated import rope_direction, rope_direction_plain  # noqa: E402
from firmware_py.estimator.state import MODE_TAUT  # noqa: E402
from sim_hil.scenarios import SCENARIOS  # noqa: E402
from sim_hil.simulator import TRUTH_COLUMNS, Simulation  # noqa: E402

DURATION_S = 300.0
START_S = 60.0  # after the release, the climb and the taut entry


def fly(scenario: str, seed: int) -> tuple[np.ndarray, float]:
    """Rows (time s; the body axis, the model's pull and the chord as angles from the vertical in the plane of the
    mean wind, downwind positive, rad) of the taut steps from START_S, and the truth's median rope tension, N."""
    sc = SCENARIOS[scenario]
    sim = Simulation(sc.design, sc.wind, sc.truth, DURATION_S, seed)
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    col = {c: j for j, c in enumerate(TRUTH_COLUMNS)}
    raw, last = [], None
    for i, s in enumerate(sim.samples()):
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        row = sim.truth[i]
        t, w = float(row[col["time_s"]]), (float(row[col["wind_n"]]), float(row[col["wind_e"]]))
        rate = (0.0, 0.0)  # the wind's rate: the truth's own difference
        if last is not None:
            rate = ((w[0] - last[1][0]) / (t - last[0]), (w[1] - last[1][1]) / (t - last[0]))
        last = (t, w)
        ekf = est.ekf
        if t < START_S or ekf.mode != MODE_TAUT or not ekf.forces.taut:
            continue
        fn = rope_direction if ekf.model.rope_drag_m2 > 0.0 else rope_direction_plain
        p = [float(row[col[c]]) for c in ("pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d")]
        n = fn(*p, *w, *rate, sc.truth.drag_coefficient_scale, *ekf.forces.params)
        euler = [math.radians(float(row[col[c]])) for c in ("roll_deg", "pitch_deg", "yaw_deg")]
        r = rotation(*quat_from_euler(*euler))  # its third column: the body's down axis in NED
        raw.append((t, r[2], r[5], r[8], n[0], n[1], *p[:3], *w, float(row[col["tension_n"]]),
                    float(row[col["anchor_tension_n"]])))  # fmt: skip
    a = np.array(raw)
    d = np.array([a[:, 9].mean(), a[:, 10].mean()])
    d /= np.linalg.norm(d)

    def along(n: np.ndarray, e: np.ndarray) -> np.ndarray:
        return n * d[0] + e * d[1]

    # each angle from the vertical, atan2(its part downwind, its part up from the anchor): the body's down axis and
    # the rope's pull on the balloon point to the anchor (down, and upwind as they lean), the chord from it
    pull_down = np.sqrt(np.maximum(1.0 - a[:, 4] ** 2 - a[:, 5] ** 2, 0.0))
    rows = np.column_stack([a[:, 0], np.arctan2(-along(a[:, 1], a[:, 2]), a[:, 3]),
                            np.arctan2(-along(a[:, 4], a[:, 5]), pull_down),
                            np.arctan2(along(a[:, 6], a[:, 7]), -a[:, 8])])  # fmt: skip
    return rows, 0.5 * float(np.median(a[:, 11]) + np.median(a[:, 12]))


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog="rope_waves", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", choices=sorted(n for n, s in SCENARIOS.items() if s.wind.kind == "multisine"),
                    metavar="SCENARIO", help="a multisine scenario (its lines are the frequencies)")  # fmt: skip
    ap.add_argument("--seed", type=userargs.seed, default=1)
    a = ap.parse_args(argv)
    sc = SCENARIOS[a.scenario]
    rows, tension = fly(a.scenario, a.seed)
    t = rows[:, 0]
    lines = [f for f in sorted(sc.wind.multisine_hz) if f * (t[-1] - t[0]) >= 2.0]  # two periods in the window
    z = sinusoid_fit(t, rows[:, 1:4], lines)
    body, model, chord = (np.degrees(rows[:, k].mean()) for k in (1, 2, 3))
    head = (f"{a.scenario} (seed {a.seed}, the truth's {sc.truth.rope_model} rope, the filter's "
            f"{sc.filter.rope_model}): mean body axis {body:.1f} deg, the model's pull {model:.1f}, "
            f"chord {chord:.1f}")  # fmt: skip
    if sc.truth.rope_model == "lumped":
        length, kg_m = sc.design.tether.length_m, sc.design.tether.linear_density_kg_m
        c = math.sqrt(tension / kg_m)
        head += (f"; the rope's median tension {tension:.1f} N, its waves {c:.0f} m/s, a quarter-wave "
                 f"{c / (4 * length):.3f} Hz")  # fmt: skip
    print(head)
    print("f Hz    body / model's pull (gain, phase)    body / chord (gain, phase)")
    for k, f in enumerate(lines):
        r1, r2 = z[k, 0] / z[k, 1], z[k, 0] / z[k, 2]
        print(f"{f:<6g}  {abs(r1):5.2f} {math.degrees(np.angle(r1)):+5.0f}                         "
              f"{abs(r2):5.2f} {math.degrees(np.angle(r2)):+5.0f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
