"""The lumped-mass rope (sim_hil/rope.py) against the elastic catenary, and the estimator's rope shape
(firmware_py/estimator/catenary.py) against the inextensible one: both checked against the closed-form
equations written out here, independently of the code under test."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from balloon_core.config import Design
from firmware_py.estimator.catenary import anchored_rope_spread, calm_weight_share, effective_rod, rope_chord
from sim_hil.dynamics import BalloonPhysics, TruthConfig
from sim_hil.rope import GROUND_STIFFNESS_N_M, RK4_H_LAMBDA_MAX, LumpedRope, rope_airborne, rope_derivative

EA = 20000.0
LENGTH = 100.0
KG_M = 0.02
W = KG_M * G0


def elastic_catenary(h: float, v_bottom: float, s: float) -> tuple[float, float]:
    """(horizontal, height) of the point at unstretched arc length s from the anchor of an elastic
    catenary (Irvine, Cable Structures, 1981) with horizontal tension h and vertical tension v_bottom
    at the anchor; weight W per unstretched metre, axial stiffness EA."""
    v = v_bottom + W * s
    x = (h / W) * (math.asinh(v / h) - math.asinh(v_bottom / h)) + h * s / EA
    z = (h / W) * (math.hypot(1.0, v / h) - math.hypot(1.0, v_bottom / h)) + (v_bottom * s + 0.5 * W * s * s) / EA
    return x, z


def settle(rope: LumpedRope, top: tuple[float, float, float], seconds: float = 40.0):
    """The rope alone, its top held at ``top``, relaxed to rest (its swing damped away)."""
    n = rope.n_nodes
    nodes = []
    for i in range(1, n + 1):  # start on the chord, slightly short of the rope: it sags from there
        f = i / rope.segments
        nodes += [top[0] * f, top[1] * f, top[2] * f]
    nodes += [0.0] * (3 * n)
    h = 0.002
    topv = (*top, 0.0, 0.0, 0.0)
    calm = (0.0, 0.0, 0.0)
    for _ in range(int(seconds / h)):
        k1, *_ = rope_derivative(rope, nodes, topv, calm, 1.2)
        s2 = [a + 0.5 * h * b for a, b in zip(nodes, k1)]
        k2, *_ = rope_derivative(rope, s2, topv, calm, 1.2)
        s3 = [a + 0.5 * h * b for a, b in zip(nodes, k2)]
        k3, *_ = rope_derivative(rope, s3, topv, calm, 1.2)
        s4 = [a + h * b for a, b in zip(nodes, k3)]
        k4, *_ = rope_derivative(rope, s4, topv, calm, 1.2)
        nodes = [a + h / 6.0 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(nodes, k1, k2, k3, k4)]
        for i in range(3 * n, 6 * n):  # a little viscous damping: the equilibrium is the rope's alone
            nodes[i] *= 1.0 - 2.0 * h
    _, force, t_top, t_bottom = rope_derivative(rope, nodes, topv, calm, 1.2)
    return nodes, force, t_top, t_bottom


@pytest.fixture(scope="module")
def settled():
    # 40 segments: the lumped chain approaches the continuous catenary as 1 / N^2; drag on (it damps
    # the swing in calm air and exerts nothing at rest)
    rope = LumpedRope.build(LENGTH, KG_M, 0.0047, EA, 40, 0.5, 1.1, True, 0.0, LENGTH)
    top = (30.0, 0.0, -94.0)  # chord 98.7 m of a 100 m rope: it sags
    return rope, top, *settle(rope, top)


def test_lumped_rope_at_rest_lies_on_the_elastic_catenary(settled):
    rope, top, nodes, force, t_top, t_bottom = settled
    # the pull on the balloon (top force) gives H and V_top; the anchor's vertical is V_top - W L
    # (the lumped ends: the balloon carries the top half-segment, the anchor the bottom one)
    h = math.hypot(force[0], force[1])
    half = 0.5 * rope.node_mass_kg * G0
    v_top = force[2]
    v_bottom = v_top - W * LENGTH
    assert h > 1.0 and v_bottom > 0.0
    # the curve through the anchor with these tensions ends at the held top (closure of the equations)
    xe, ze = elastic_catenary(h, v_bottom, LENGTH)
    assert xe == pytest.approx(top[0], abs=0.15)
    assert ze == pytest.approx(-top[2], abs=0.15)
    # every node on the catenary at its arc length
    seg = LENGTH / rope.segments
    worst = 0.0
    for i in range(rope.n_nodes):
        x, z = elastic_catenary(h, v_bottom, (i + 1) * seg)
        worst = max(worst, math.hypot(nodes[3 * i] - x, -nodes[3 * i + 2] - z))
    assert worst < 0.2, worst
    # anchor tension and the end angles
    assert t_bottom == pytest.approx(math.hypot(h, v_bottom + half), rel=0.01)
    assert t_top == pytest.approx(math.hypot(h, v_top - half), rel=0.01)
    bottom_deg = math.degrees(math.atan2(nodes[0], -nodes[2]))
    # (an end segment runs along the tension of its middle: half a segment in from the end)
    assert bottom_deg == pytest.approx(math.degrees(math.atan2(h, v_bottom + half)), abs=0.2)
    last = 3 * (rope.n_nodes - 1)  # the node below the attachment point: the top tangent
    top_deg = math.degrees(math.atan2(top[0] - nodes[last], nodes[last + 2] - top[2]))
    assert top_deg == pytest.approx(math.degrees(math.atan2(h, v_top - half)), abs=0.2)
    # the sag is real: the top tangent is the steepest, the bottom the shallowest, the chord between
    chord_deg = math.degrees(math.atan2(top[0], -top[2]))
    assert top_deg + 3.0 < chord_deg < bottom_deg - 3.0


def test_rope_shares_its_weight_with_the_anchor(settled):
    rope, _, nodes, force, _, t_bottom = settled
    # static balance of the free nodes: what the balloon holds up minus what the anchor holds down
    # is their weight; the anchor holds a share (the paper's rope puts all of it on the balloon)
    v_balloon = force[2] - 0.5 * rope.node_mass_kg * G0
    v_anchor = t_bottom * (-nodes[2]) / math.hypot(nodes[0], nodes[1], nodes[2])
    assert v_balloon - v_anchor == pytest.approx(rope.n_nodes * rope.node_mass_kg * G0, rel=1e-3)
    assert 0.1 * W * LENGTH < v_anchor < 0.5 * v_balloon


def test_rope_lies_on_the_ground_until_lifted():
    rope = LumpedRope.build(LENGTH, KG_M, 0.0047, EA, 12, 0.5, 1.1, True, 0.0, LENGTH)
    top = (0.0, 0.0, -40.0)  # the balloon 40 m up: the rest of the rope lies at the anchor
    nodes, force, _, _ = settle(rope, top, seconds=30.0)
    heights = [-nodes[3 * i + 2] for i in range(rope.n_nodes)]
    lifted = sum(1 for z in heights if z > 0.05)
    assert not rope_airborne(rope, nodes)
    assert 3 <= lifted <= 6  # 40 m of 100 m in 8.3 m segments, the lowest hanging one partly
    assert min(heights) > -0.01  # nothing sinks into the ground
    # the balloon carries the hanging part only: ~40 m of rope, not all of it
    assert 0.3 * W * LENGTH < force[2] < 0.5 * W * LENGTH


def test_default_truth_is_the_lumped_rope_and_the_paper_option_remains():
    ph = BalloonPhysics.from_design(Design(), TruthConfig())
    assert ph.rope is not None and ph.rope.segments >= 10 and ph.rope.drag_factor_m2 > 0.0
    assert BalloonPhysics.from_design(Design(), TruthConfig(rope_model="paper")).rope is None


def closed_catenary_chord(h: float, v_top: float, length: float) -> tuple[float, float]:
    v_bottom = v_top - W * length
    x = (h / W) * (math.asinh(v_top / h) - math.asinh(v_bottom / h))
    z = (h / W) * (math.hypot(1.0, v_top / h) - math.hypot(1.0, v_bottom / h))
    return x, z


@pytest.mark.parametrize("h", [1.0, 5.0, 20.0])
def test_estimator_rope_shape_is_the_inextensible_catenary(h):
    v_top = 31.3
    cn, ce, cd = rope_chord(-h, 0.0, v_top, LENGTH, W, 0.0, 0.0, 0.0)
    x, z = closed_catenary_chord(h, v_top, LENGTH)
    assert cn == pytest.approx(x, abs=0.01) and ce == 0.0 and -cd == pytest.approx(z, abs=0.01)
    # the rod that carries W_eff at the top pulls as the rope does, along the real chord
    w_eff = effective_rod(-h, 0.0, v_top, cn, ce, cd, W * LENGTH)
    t_c = h / (cn / math.hypot(cn, cd))
    assert v_top - w_eff == pytest.approx(t_c * (-cd) / math.hypot(cn, cd), rel=1e-9)
    assert 0.5 * W * LENGTH < w_eff < W * LENGTH  # more than the parabola's half: a deep sag


def test_weight_share_limits():
    assert calm_weight_share(1000.0, 1.0) == pytest.approx(0.5, rel=1e-3)  # light rope: the parabola's half
    assert calm_weight_share(19.7, 19.6) == pytest.approx(19.6, rel=0.3)  # no spare lift: all of it
    # the calm limit is the catenary's as the pull vanishes
    cn, ce, cd = rope_chord(-0.05, 0.0, 31.3, LENGTH, W, 0.0, 0.0, 0.0)
    assert effective_rod(-0.05, 0.0, 31.3, cn, ce, cd, W * LENGTH) == pytest.approx(
        calm_weight_share(31.3, W * LENGTH), abs=0.05
    )


def test_rope_drag_bows_the_rope_downwind():
    plain = rope_chord(-5.0, 0.0, 31.3, LENGTH, W, 0.0, 3.0, 0.0)
    bowed = rope_chord(-5.0, 0.0, 31.3, LENGTH, W, 0.5 * 1.2 * 1.1 * 0.0047, 3.0, 0.0)
    # the same pull at the top, the anchor further upwind: the chord leans further and is shorter
    assert bowed[0] > plain[0] + 3.0
    assert math.hypot(*bowed) < math.hypot(*plain)


@pytest.mark.parametrize("u", [0.05, 0.6, 1.6, 4.0])
def test_anchored_rope_is_the_catenary_from_the_anchor(u):
    """The airborne rope fed from the anchor (its lowest point there): the pull it puts on the balloon,
    (w a towards the anchor, w s down), shapes a rope of arc s through the anchor (``rope_chord``,
    integrated independently), and the spread is its distance from the hanging rope's w h."""
    a = 12.0
    x, h, s = a * u, a * (math.cosh(u) - 1.0), a * math.sinh(u)
    cn, ce, cd = rope_chord(-W * a, 0.0, W * s, s, W, 0.0, 0.0, 0.0)
    assert cn == pytest.approx(x, rel=1e-2) and ce == 0.0 and -cd == pytest.approx(h, rel=1e-2, abs=1e-3)
    assert anchored_rope_spread(W, x, h) == pytest.approx(W * math.hypot(s - h, a), rel=1e-9)


def test_anchored_rope_spread_limits():
    """Straight above the anchor both pictures agree; blown down they part, monotonically."""
    assert anchored_rope_spread(W, 0.0, 50.0) == 0.0 and anchored_rope_spread(W, 10.0, 0.0) == 0.0
    assert anchored_rope_spread(W, 0.01, 50.0) < 1e-3 * W * 50.0
    spreads = [anchored_rope_spread(W, 50.0 * math.sin(b), 50.0 * math.cos(b)) for b in (0.1, 0.4, 0.8, 1.2)]
    assert all(b > a for a, b in zip(spreads, spreads[1:]))
    assert spreads[2] > 0.5 * W * 50.0  # at 46 deg from the vertical the two differ by half the rope's weight


def _chain_eigenvalues(rope: LumpedRope) -> np.ndarray:
    """The axial chain's eigenvalues, written out here: N - 1 free nodes of mass m between two fixed ends,
    springs k and dashpots c between neighbours (x'' = -(K x + C x') / m, K = k tridiag(-1, 2, -1))."""
    n = rope.n_nodes
    t = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    m = rope.node_mass_kg
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-rope.seg_k_n_m * t / m, -rope.seg_c_ns_m * t / m]])
    return np.linalg.eigvals(a)


@pytest.mark.parametrize(("ea", "zeta", "length"), [(EA, 0.5, LENGTH), (200000.0, 0.5, LENGTH), (EA, 0.9, 30.0),
                                                    (1.26e6, 0.2, 150.0)])  # fmt: skip
def test_the_stable_step_covers_the_stiffest_mode(ea, zeta, length):
    # the analytic bound against the chain's own eigenvalues: never longer than the stiffest allows, at most a few
    # per cent shorter (the finite chain's top mode is 2 omega0 sin((N - 1) pi / 2N), a little under 2 omega0)
    rope = LumpedRope.build(length, KG_M, 0.005, ea, 12, zeta, 1.1, True, 0.0, 0.0)
    lam = float(np.max(np.abs(_chain_eigenvalues(rope))))
    h = rope.stable_step_s()
    assert h * lam <= RK4_H_LAMBDA_MAX + 1e-9
    assert h * lam >= 0.9 * RK4_H_LAMBDA_MAX or h * math.sqrt(GROUND_STIFFNESS_N_M / rope.node_mass_kg) > 2.4


def test_a_stiff_rope_is_integrated_not_rung():
    # 200 kN (a high-modulus fibre: Dyneema of 4 mm is ~1 MN) on the reference rope at the default physics_hz
    # 200 Hz would put the chain's top mode at h |lambda| = 3.8, beyond RK4's 2.8: the rope rang, slack and taut at
    # random (the tension's spread 130 N, 70 % of the time slack). The simulator steps finer where the rope needs it,
    # and the stiff rope then flies as the reference does (its stretch is a tenth: the same balloon, the same pull)
    from sim_hil.scenarios import SCENARIOS
    from sim_hil.simulator import TRUTH_COLUMNS, Simulation, rope_steps_per_imu

    sc = SCENARIOS["field-rope"]
    out = {}
    for ea in (EA, 200000.0):
        truth = replace(sc.truth, tether_ea_n=ea)
        sim = Simulation(sc.design, sc.wind, truth, 90.0, 3)
        for _ in sim.samples():
            pass
        col = {c: sim.truth[:, k] for k, c in enumerate(TRUTH_COLUMNS)}
        late = col["time_s"] > 45.0
        out[ea] = (sim.steps_per_imu, col["tension_n"][late].std(), np.mean(col["tether_taut"][late] < 0.5))
    assert out[EA][0] == round(sc.truth.physics_hz / 100.0)  # the reference keeps its step
    assert out[200000.0][0] > out[EA][0]
    assert out[200000.0][2] == 0.0 and out[200000.0][1] < 2.0 * out[EA][1] + 0.5, out
    assert rope_steps_per_imu(BalloonPhysics.from_design(sc.design, replace(sc.truth, rope_model="paper")), None,
                              100.0) == 1  # fmt: skip
