"""How the wind follows an error of the attitude about the magnetic field's axis (a diagnosis tool).

    python tools/attitude_step.py field-rope-multisine --from-deg 0 --steady
    python tools/attitude_step.py field-rope-multisine --from-deg 200 --axis down

Flies a scenario once on the Python core, then again from the same sensor samples with the estimate's attitude
turned by ``--deg`` (1 deg) at ``--at`` s (150 s) about the magnetic field's axis as the filter has learnt it
(``--axis field``; ``down`` or ``north`` for those axes), and prints how far the second run's wind is from the
first's, along and across the mean wind, at times after the step. The magnetometer cannot see a rotation about
the field, only the accelerometer holds it (``cos I`` of it is a tilt): what the wind does here is what it does
when the gyro's noise turns the attitude that way (docs/estimator.md, "What limits the envelope now")."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from firmware_py.estimator.control import Estimator  # noqa: E402
from sim_hil.scenarios import SCENARIOS  # noqa: E402
from sim_hil.simulator import Simulation  # noqa: E402

AFTER_S = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 40.0, 70.0, 100.0)


def turn(q: np.ndarray, rotvec_ned: np.ndarray) -> None:
    """q <- dq (x) q, dq the rotation ``rotvec_ned`` (rad) in NED: the filter's own attitude correction."""
    q0, q1, q2, q3 = q.tolist()
    hn, he, hd = 0.5 * rotvec_ned
    a = (q0 - hn * q1 - he * q2 - hd * q3, q1 + hn * q0 + he * q3 - hd * q2,
         q2 - hn * q3 + he * q0 + hd * q1, q3 + hn * q2 - he * q1 + hd * q0)  # fmt: skip
    q[:] = np.array(a) / math.sqrt(sum(v * v for v in a))


def fly(sc, samples, step_at_s: float | None, deg: float, axis: str) -> np.ndarray:
    est = Estimator(sc.design, dataclasses.replace(sc.filter, core="py"))
    out = []
    for s in samples:
        if s.baro:
            est.on_baro(s.time_usec, *s.baro)
        est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        t = s.time_usec * 1e-6
        if step_at_s is not None and step_at_s <= t < step_at_s + 0.5 / sc.filter.imu_rate_hz:
            b = {"down": np.array([0.0, 0.0, 1.0]), "north": np.array([1.0, 0.0, 0.0])}.get(axis)
            if b is None:
                b = np.array(est.field_ned, float)
                b /= np.linalg.norm(b)
            turn(est.ekf.q, math.radians(deg) * b)
        out.append((t, *est.wind()))
    return np.array(out)


def step_response(sc, seed: int = 1, at_s: float = 150.0, deg: float = 1.0, axis: str = "field"):
    """[(seconds after the step, the wind's change along the mean wind, across it)] at ``AFTER_S``, m/s."""
    samples = list(Simulation(sc.design, sc.wind, sc.truth, at_s + AFTER_S[-1] + 1.0, seed).samples())
    base, moved = fly(sc, samples, None, deg, axis), fly(sc, samples, at_s, deg, axis)
    towards = math.radians(sc.wind.from_deg + 180.0)
    cn, ce = math.cos(towards), math.sin(towards)
    dn, de = moved[:, 1] - base[:, 1], moved[:, 2] - base[:, 2]
    out = []
    for dt in AFTER_S:
        i = int(np.argmin(np.abs(base[:, 0] - (at_s + dt))))
        out.append((dt, float(dn[i] * cn + de[i] * ce), float(-dn[i] * ce + de[i] * cn)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario")
    ap.add_argument("--from-deg", type=float, default=None, help="the wind's direction (default: the scenario's)")
    ap.add_argument("--steady", action="store_true", help="a steady wind of the scenario's mean instead")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--at", type=float, default=150.0, help="time of the step, s (taut by then)")
    ap.add_argument("--deg", type=float, default=1.0)
    ap.add_argument("--axis", choices=("field", "down", "north"), default="field")
    a = ap.parse_args(argv)
    if a.scenario not in SCENARIOS:
        print(f"attitude_step: unknown scenario {a.scenario!r} (balloon-sim --list-scenarios)", file=sys.stderr)
        return 2
    sc = SCENARIOS[a.scenario]
    wind = sc.wind if a.from_deg is None else dataclasses.replace(sc.wind, from_deg=a.from_deg)
    if a.steady:
        wind = dataclasses.replace(wind, kind="steady")
    sc = dataclasses.replace(sc, wind=wind)
    kind = "steady" if a.steady else wind.kind
    print(
        f"{a.scenario} ({kind} {wind.mean_mps:g} m/s from {wind.from_deg:g} deg), the attitude turned {a.deg:g} "
        f"deg about the {a.axis} axis at {a.at:g} s: the wind's change, m/s"
    )
    for dt, along, across in step_response(sc, a.seed, a.at, a.deg, a.axis):
        print(f"  after {dt:5.1f} s: along {along:+.3f}  across {across:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
