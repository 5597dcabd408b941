"""How the balloon's axis turns against what the taut model says of it, frequency by frequency (a diagnosis tool).

    python tools/rope_waves.py field-rope-multisine
    python tools/rope_waves.py multisine --seed 2

Flies a multisine scenario with the filter (the Python core) and, at each of its lines, fits three angles from the
vertical in the plane of the mean wind: the truth's body axis (along the rope's pull at the balloon: what the
alignment measures), the taut model's pull direction at the truth's state (position, velocity, wind and its rate,
the drag scale; the filter's own rope shape: ``aid_sources/tether.py``'s prediction, where the filter's state
error plays no part), and the rope's chord. It prints the body axis over the model's pull and over the chord (gain
and phase, deg): where the first is not 1 at 0 deg, the alignment's model is wrong at that frequency whatever the
state. A rope with mass carries transverse waves, which no static shape holds: past its first quarter-wave (the
truth's mean tension gives its speed) its top turns against the chord (docs/estimator.md, "The real rope at
0.1 Hz")."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from balloon_core.config import SIM_IMU_HZ  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from firmware_py.estimator.generated import rope_direction, rope_direction_plain  # noqa: E402
from firmware_py.estimator.state import MODE_TAUT  # noqa: E402
from sim_hil.scenarios import SCENARIOS  # noqa: E402
from sim_hil.simulator import TRUTH_COLUMNS, Simulation  # noqa: E402

DURATION_S = 300.0
START_S = 60.0  # after the release, the climb and the taut entry


def fit(t: np.ndarray, y: np.ndarray, f_hz: float) -> complex:
    """The complex amplitude of y at f_hz (least squares with a constant and a trend)."""
    a = np.column_stack([np.cos(2 * math.pi * f_hz * t), np.sin(2 * math.pi * f_hz * t), np.ones_like(t), t - t.mean()])
    c = np.linalg.lstsq(a, y, rcond=None)[0]
    return complex(c[0], -c[1])


def fly(scenario: str, seed: int) -> tuple[np.ndarray, float]:
    """Rows (time s, body axis, the model's pull, chord: rad from the vertical, downwind positive; the wind along the
    mean wind, m/s) of the taut steps from START_S, and the truth's mean tension along the rope, N."""
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
        w = (float(row[col["wind_n"]]), float(row[col["wind_e"]]))
        rate, last = (0.0, 0.0) if last is None else ((w[0] - last[0]) * SIM_IMU_HZ, (w[1] - last[1]) * SIM_IMU_HZ), w
        ekf = est.ekf
        if s.time_usec < START_S * 1e6 or ekf.mode != MODE_TAUT or not ekf.forces.taut:
            continue
        fn = rope_direction if ekf.model.rope_drag_m2 > 0.0 else rope_direction_plain
        p = [float(row[col[c]]) for c in ("pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d")]
        n = fn(*p, *w, *rate, sc.truth.drag_coefficient_scale, *ekf.forces.params)
        ro, pi, ya = (math.radians(float(row[col[c]])) for c in ("roll_deg", "pitch_deg", "yaw_deg"))
        zn = math.cos(ro) * math.sin(pi) * math.cos(ya) + math.sin(ro) * math.sin(ya)  # the body's down axis, N, E
        ze = math.cos(ro) * math.sin(pi) * math.sin(ya) - math.sin(ro) * math.cos(ya)
        raw.append((s.time_usec * 1e-6, zn, ze, n[0], n[1], *p[:3], *w, float(row[col["tension_n"]]),
                    float(row[col["anchor_tension_n"]])))  # fmt: skip
    r = np.array(raw)
    d = np.array([r[:, 8].mean(), r[:, 9].mean()])
    d /= np.linalg.norm(d)
    along = lambda n, e: n * d[0] + e * d[1]  # noqa: E731
    # the body's down axis and the pull on the balloon point to the anchor: their lean is upwind
    rows = np.column_stack([r[:, 0], np.arcsin(np.clip(-along(r[:, 1], r[:, 2]), -1.0, 1.0)),
                            np.arcsin(np.clip(-along(r[:, 3], r[:, 4]), -1.0, 1.0)),
                            np.arctan2(along(r[:, 5], r[:, 6]), -r[:, 7]), along(r[:, 8], r[:, 9])])  # fmt: skip
    return rows, 0.5 * float(np.median(r[:, 10]) + np.median(r[:, 11]))


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog="rope_waves", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", choices=sorted(n for n, s in SCENARIOS.items() if s.wind.kind == "multisine"),
                    metavar="SCENARIO", help="a multisine scenario (its lines are the frequencies)")  # fmt: skip
    ap.add_argument("--seed", type=userargs.seed, default=1)
    a = ap.parse_args(argv)
    sc = SCENARIOS[a.scenario]
    rows, tension = fly(a.scenario, a.seed)
    t, body, model, chord = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    length, kg_m = sc.design.tether.length_m, sc.design.tether.linear_density_kg_m
    c = math.sqrt(tension / kg_m)
    print(f"{a.scenario} (seed {a.seed}, the truth's {sc.truth.rope_model} rope, the filter's {sc.filter.rope_model}): "
          f"mean body axis {math.degrees(body.mean()):.1f} deg, the model's pull {math.degrees(model.mean()):.1f}, "
          f"chord {math.degrees(chord.mean()):.1f}; the rope's mean tension {tension:.1f} N, its waves {c:.0f} m/s, "
          f"a quarter-wave {c / (4 * length):.3f} Hz")  # fmt: skip
    print("f Hz    body / model's pull (gain, phase)    body / chord (gain, phase)")
    for f in sorted(sc.wind.multisine_hz):
        if f * (t[-1] - t[0]) < 2.0:
            continue  # fewer than two periods in the window
        b = fit(t, body, f)
        r1, r2 = b / fit(t, model, f), b / fit(t, chord, f)
        print(f"{f:<6g}  {abs(r1):5.2f} {math.degrees(np.angle(r1)):+5.0f}                         "
              f"{abs(r2):5.2f} {math.degrees(np.angle(r2)):+5.0f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
