"""How the wind follows an error of the attitude about the magnetic field's axis (a diagnosis tool).

    python tools/attitude_step.py field-rope-multisine --from-deg 0 --steady
    python tools/attitude_step.py field-rope-multisine --from-deg 200 --axis down

Flies a scenario once on the Python core, then again from the same sensor samples with the estimate's attitude
turned by ``--deg`` (1 deg) at ``--at`` s (150 s) about the magnetic field's axis as the filter has learnt it
(``--axis field``; ``down`` or ``north`` for those axes), and prints how far the second run's wind is from the
first's at times after the step: along the mean wind (downwind positive) and across it (positive to the right of
downwind). The magnetometer cannot see a rotation about the field, only the accelerometer holds it (``cos I`` of it
is a tilt): what the wind does here is what it does when the gyro's noise turns the attitude that way
(docs/estimator.md, "What limits the envelope now")."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from balloon_core import userargs  # noqa: E402
from firmware_py.estimator.control import Estimator  # noqa: E402
from sim_hil.scenarios import SCENARIOS, Scenario  # noqa: E402
from sim_hil.simulator import Simulation  # noqa: E402

AFTER_S = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 40.0, 70.0, 100.0)  # the times the answer is printed at, s
AT_RANGE_S = (60.0, 3600.0)  # the step: after the release, the climb and the taut entry; at most an hour in
MAX_DEG = 10.0  # a small error: the answer is the filter's linear one
AXES = {"down": (0.0, 0.0, 1.0), "north": (1.0, 0.0, 0.0)}  # "field": the filter's learnt field


def turn(q: np.ndarray, rotvec_ned: np.ndarray) -> None:
    """q <- dq (x) q: the attitude turned by the rotation vector ``rotvec_ned`` (rad) in NED."""
    angle = float(np.linalg.norm(rotvec_ned))
    if angle == 0.0:
        return
    c, (sn, se, sd) = math.cos(0.5 * angle), math.sin(0.5 * angle) * rotvec_ned / angle
    q0, q1, q2, q3 = q.tolist()
    q[:] = (c * q0 - sn * q1 - se * q2 - sd * q3, c * q1 + sn * q0 + se * q3 - sd * q2,
            c * q2 - sn * q3 + se * q0 + sd * q1, c * q3 + sn * q2 - se * q1 + sd * q0)  # fmt: skip


def fly(sc: Scenario, samples: list, step_at_s: float | None, deg: float, axis: str) -> np.ndarray:
    """[time, wind N, wind E] of every sample; the attitude turned once, at the first sample from ``step_at_s``."""
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    step_us = None if step_at_s is None else round(step_at_s * 1e6)
    out = []
    for s in samples:
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        if step_us is not None and s.time_usec >= step_us:
            step_us = None
            b = np.array(AXES.get(axis, est.field_ned), float)
            turn(est.ekf.q, math.radians(deg) * b / np.linalg.norm(b))
        out.append((s.time_usec * 1e-6, *est.wind()))
    return np.array(out)


def step_response(sc: Scenario, degs: tuple[float, ...] = (1.0,), seed: int = 1, at_s: float = 150.0,
                  axis: str = "field") -> list[list[tuple[float, float, float]]]:  # fmt: skip
    """For each step in ``degs``: [(seconds after the step, the wind's change along the mean wind, across it)]
    at ``AFTER_S``, m/s, against one run without a step over the same samples."""
    samples = list(Simulation(sc.design, sc.wind, sc.truth, at_s + AFTER_S[-1] + 1.0, seed).samples())
    base = fly(sc, samples, None, 0.0, axis)
    towards = math.radians(sc.wind.from_deg + 180.0)
    cn, ce = math.cos(towards), math.sin(towards)
    out = []
    for deg in degs:
        moved = fly(sc, samples, at_s, deg, axis)
        dn, de = moved[:, 1] - base[:, 1], moved[:, 2] - base[:, 2]
        rows = []
        for dt in AFTER_S:
            i = int(np.argmin(np.abs(base[:, 0] - (at_s + dt))))
            rows.append((dt, float(dn[i] * cn + de[i] * ce), float(-dn[i] * ce + de[i] * cn)))
        out.append(rows)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog="attitude_step", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", choices=sorted(SCENARIOS), metavar="SCENARIO")
    ap.add_argument(
        "--from-deg", type=userargs.between(0.0, 360.0), help="the wind's direction (default: the scenario's)"
    )
    ap.add_argument("--steady", action="store_true", help="a steady wind of the scenario's mean instead")
    ap.add_argument("--seed", type=userargs.seed, default=1)
    ap.add_argument("--at", type=userargs.between(*AT_RANGE_S), default=150.0, help="time of the step, s (default 150)")
    ap.add_argument("--deg", type=userargs.between(-MAX_DEG, MAX_DEG), default=1.0, help="the turn, deg (default 1)")
    ap.add_argument("--axis", choices=("field", *AXES), default="field")
    a = ap.parse_args(argv)
    sc = SCENARIOS[a.scenario]
    wind = sc.wind if a.from_deg is None else dataclasses.replace(sc.wind, from_deg=a.from_deg)
    if a.steady:
        wind = dataclasses.replace(wind, kind="steady")
    sc = dataclasses.replace(sc, wind=wind)
    print(f"{a.scenario} ({wind.kind} {wind.mean_mps:g} m/s from {wind.from_deg:g} deg), the attitude turned "
          f"{a.deg:g} deg about the {a.axis} axis at {a.at:g} s: the wind's change, m/s (along: downwind; across: "
          "to its right)")  # fmt: skip
    for dt, along, across in step_response(sc, (a.deg,), a.seed, a.at, a.axis)[0]:
        print(f"  after {dt:5.1f} s: along {along:+.3f}  across {across:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
