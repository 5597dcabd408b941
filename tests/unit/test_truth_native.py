"""The simulator's compiled physics (sim_hil/native.py, sim_hil/csrc/truth.c) against the Python functions
they twin (dynamics.derivative and rk4_step, rope.rope_derivative, anchor_tension_n, rope_airborne),
kept as the reference: the same initial state, N steps each, the states compared.

Tolerance: the C follows the Python's operand order without fused multiply-adds, so on one machine the
two agree to the bit; another compiler or libm may round a pow, sin or cos (or reassociate) differently
in the last place (gcc must not turn pow(x, 2) into x * x: -fno-builtin-pow). Each step then differs by
a few ulp (1e-16 of the state's scale); over these N = 400 steps a relative perturbation of 1e-15 of the
initial state grows to at most 3e-14 in every variant here (measured: the states are not chaotic; a
30-segment rope at this step is, and is left out). The bound REL = 1e-9 of each state's scale leaves
four orders of magnitude above that, and is still four below any effect the truth is used for (a
millimetre on a 100 m rope is 1e-5)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from balloon_core.config import Design
from sim_hil import native
from sim_hil.dynamics import BalloonPhysics, TruthConfig, derivative, rk4_step
from sim_hil.rope import anchor_tension_n, rope_airborne
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation

pytestmark = pytest.mark.skipif(not native.available(), reason=f"no compiled physics: {native.why_not()}")

REL = 1e-9  # of the state's scale (see the module's docstring)
STEPS = 400
H = 0.005

VARIANTS = {
    "lumped": TruthConfig(),
    "lumped-no-drag": TruthConfig(rope_drag=False),
    "lumped-shear": TruthConfig(shear_exponent=0.14),
    "lumped-veer": TruthConfig(shear_exponent=0.14, veer_deg_per_100m=20.0),
    "lumped-reynolds-offset": TruthConfig(drag_model="reynolds", avionics_offset_m=0.3),
    "lumped-yaw-moment": TruthConfig(yaw_moment_coefficient=0.05),
    "paper-yaw-moment-offset": TruthConfig(rope_model="paper", yaw_moment_coefficient=0.05, avionics_offset_m=0.3),
    "lumped-20-segments": TruthConfig(rope_segments=20),
    "paper": TruthConfig(rope_model="paper"),
    "paper-shear-no-fk": TruthConfig(rope_model="paper", shear_exponent=0.2, froude_krylov=False, isa_density=False),
}


def initial_state(ph: BalloonPhysics, rng: np.random.Generator) -> list[float]:
    """The balloon blown 30 degrees downwind near its height, turning; the rope's nodes on the chord,
    the lowest ones below the ground (the ground's push and friction), all moving."""
    length = ph.tether_length_m
    a = math.radians(30.0)
    top = (length * math.sin(a), 0.2 * length * math.sin(a), -length * math.cos(a))
    q = rng.normal(size=4) * 0.1 + np.array([1.0, 0.0, 0.0, 0.0])
    q /= np.linalg.norm(q)
    s = [top[0], top[1], top[2] - ph.radius_m, *rng.normal(size=3), *q, *(0.1 * rng.normal(size=3))]
    if ph.rope is not None:
        n = ph.rope.n_nodes
        pos = []
        for i in range(1, n + 1):
            f = i / ph.rope.segments
            pos += [top[0] * f, top[1] * f, top[2] * f * 0.97 + (0.02 if i <= 2 else 0.0)]
        s += pos + list(0.3 * rng.normal(size=3 * n))
    return [float(x) for x in s]


def wind_rows(rng: np.random.Generator, steps: int) -> np.ndarray:
    """A gusty wind (n, e, d, dn, de, dd) at half steps."""
    t = np.arange(2 * steps + 1) * 0.5 * H
    rows = np.empty((len(t), 6))
    rows[:, 0] = 4.0 + np.sin(2.0 * t) + 0.3 * rng.normal(size=len(t))
    rows[:, 1] = 1.0 + 0.5 * np.cos(3.0 * t)
    rows[:, 2] = 0.2 * np.sin(5.0 * t)
    rows[:, 3] = 2.0 * np.cos(2.0 * t)
    rows[:, 4] = -1.5 * np.sin(3.0 * t)
    rows[:, 5] = np.cos(5.0 * t)
    return rows


def close(a: list[float], b: list[float]) -> bool:
    scale = 1.0 + max(abs(x) for x in a)
    return all(abs(x - y) <= REL * scale for x, y in zip(a, b)) and len(a) == len(b)


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_compiled_steps_follow_the_python_reference(name):
    ph = BalloonPhysics.from_design(Design(), VARIANTS[name])
    rng = np.random.default_rng(7)
    s0 = initial_state(ph, rng)
    rows = wind_rows(rng, STEPS)
    wind = rows.tolist()
    # the derivative alone, at the initial state
    st = native.NativeStepper(ph, s0)
    tension_c = st.derivative(tuple(wind[0]))
    k_ref, tension_ref = derivative(s0, *wind[0], ph)
    assert close(k_ref, st.k1.tolist())
    assert abs(tension_c - tension_ref) <= REL * (1.0 + abs(tension_ref))
    # N steps, each returning the tension, the k1 and (step_keep) the state before it with the rope's status
    st.set_wind(rows)
    s = s0
    for j in range(STEPS):
        k1, tension = derivative(s, *wind[2 * j], ph)
        tc = st.step_keep(H, j)
        pre = st.pre.tolist()
        assert abs(tc - tension) <= REL * (1.0 + abs(tension))
        assert close(s, pre[:-2])
        if ph.rope is not None:
            anchor = anchor_tension_n(ph.rope, s[13:])
            assert abs(pre[-2] - anchor) <= REL * (1.0 + anchor)
            assert (pre[-1] != 0.0) == rope_airborne(ph.rope, s[13:])
        s = rk4_step(s, H, wind[2 * j], wind[2 * j + 1], wind[2 * j + 2], ph, k1)
    assert close(s, st.s.tolist())
    assert max(abs(x) for x in s[3:6]) > 0.1  # it moved: the comparison is not of two resting states


def test_several_steps_in_one_call_are_the_steps_one_by_one():
    ph = BalloonPhysics.from_design(Design(), TruthConfig())
    rng = np.random.default_rng(3)
    s0 = initial_state(ph, rng)
    rows = wind_rows(rng, 10)
    one, many = native.NativeStepper(ph, s0), native.NativeStepper(ph, s0)
    one.set_wind(rows)
    many.set_wind(rows)
    t1 = one.step_keep(H, 0)
    for j in range(1, 10):
        one.step(H, j)
    tm = many.steps_keep(H, 0, 10)
    assert t1 == tm and one.s.tolist() == many.s.tolist() and one.pre.tolist() == many.pre.tolist()


@pytest.mark.parametrize("scenario", ["field-rope", "paper-reference"])
def test_simulated_flight_truth_and_sensors_follow_the_reference(scenario):
    """A whole simulated flight (release, lift-off of the rope, gusts): the truth table and the sensor
    samples of the compiled path within REL of the Python reference's."""
    sc = SCENARIOS[scenario]
    runs = []
    for reference in (True, False):
        sim = Simulation(sc.design, sc.wind, replace(sc.truth), 15.0, 4, reference=reference)
        assert sim.native is not reference
        samples = list(sim.samples())
        runs.append((sim.truth.copy(), samples, sim.state))
    (t_ref, s_ref, x_ref), (t_c, s_c, x_c) = runs
    scale = 1.0 + np.abs(t_ref).max(axis=0)
    assert np.all(np.abs(t_c - t_ref) <= REL * scale)
    assert len(s_ref) == len(s_c)
    for a, b in zip(s_ref, s_c):
        assert close([*a.accel, *a.gyro, *a.mag], [*b.accel, *b.gyro, *b.mag])
        assert (a.baro is None) == (b.baro is None)
    assert close(x_ref, x_c)


def test_reference_everywhere_when_asked(monkeypatch):
    monkeypatch.setenv(native.DISABLE_ENV, "1")
    assert not native.available() and native.DISABLE_ENV in native.why_not()
    sc = SCENARIOS["field-rope"]
    assert not Simulation(sc.design, sc.wind, sc.truth, 1.0, 1).native


def test_no_compiler_falls_back_to_the_python_reference(monkeypatch):
    import firmware_c.build as build

    def fail(*args, **kwargs):
        raise build.BuildError("the simulator's C physics needs a C compiler (cc or gcc) to build")

    monkeypatch.setattr(build, "shared_library", fail)
    monkeypatch.setattr(native, "_LIB", None)
    monkeypatch.setattr(native, "_WHY_NOT", "")
    assert not native.available() and "C compiler" in native.why_not()
    sc = SCENARIOS["paper-reference"]
    sim = Simulation(sc.design, sc.wind, sc.truth, 8.0, 2)
    assert not sim.native
    assert sim.run() == 800
