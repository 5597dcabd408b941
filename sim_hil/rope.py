"""The tether as a lumped-mass line (docs/model.md, "The real rope"): the truth's default rope.

``segments`` elastic, tension-only segments between the anchor (node 0, fixed at the origin) and the
balloon's attachment point (node N, from the balloon's state). The N - 1 nodes between them are free
point masses, each carrying the mass of half of each neighbouring segment; the anchor and the balloon
take the outer halves. On every segment: an axial spring EA / l0 with a dashpot, both only while the
segment is stretched (a rope cannot push); cross-flow (normal) drag at the local wind,
1/2 rho Cn d l0 |u_n| u_n, half to each end node. Nodes below the ground (p_d > 0) meet a stiff,
damped ground with viscous friction: the rope lies on the grass until the balloon lifts it.

Unlike the paper's rope (Eq. 5: straight, its whole weight on the balloon) this one sags into a
catenary, shares its weight with the anchor, bows under its own drag, carries waves and lifts off the
ground node by node; tests/unit/test_rope.py checks its static shape against the elastic catenary.

The state of the interior nodes is 6 (N - 1) plain floats after the balloon's 13: positions (n, e, d)
of nodes 1 .. N-1, then their velocities. Pure functions over plain floats, as dynamics.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from balloon_core.atmosphere import G0

GROUND_STIFFNESS_N_M = 2000.0  # per node: a 0.17 kg node sinks 0.8 mm
GROUND_DAMPING_RATIO = 1.0  # of a node bouncing on the ground (critically damped: no bounce)
GROUND_FRICTION_RATIO = 1.0  # viscous friction along the ground, per unit of the ground damping
AIRBORNE_BELOW_M = -0.05  # a node above this height (p_d < -5 cm) is off the ground
# RK4 is stable for h |lambda| up to 2.785 on the negative real axis and 2.83 on the imaginary one; the simulator's
# step keeps the rope's stiffest mode below this (``LumpedRope.stable_step_s``)
RK4_H_LAMBDA_MAX = 2.5


@dataclass(frozen=True)
class LumpedRope:
    """Parameters of the lumped rope (SI), from the design and the [truth] options."""

    segments: int
    seg_length_m: float
    node_mass_kg: float
    seg_k_n_m: float  # EA / l0
    seg_c_ns_m: float  # axial dashpot of one segment
    drag_factor_m2: float  # 1/2 Cn d l0 (times rho |u_n| u_n), 0 without rope drag
    shear_exponent: float  # wind at height z: (z / shear_reference_m)^alpha times the reference wind
    shear_reference_m: float
    ground_c_ns_m: float
    # what a winch needs to rebuild the rope at another length (``at_length``)
    kg_m: float = 0.0
    ea_n: float = 0.0
    damping_ratio: float = 0.0
    normal_cd_d_m: float = 0.0  # Cn d, 0 without rope drag
    seg_rate_mps: float = 0.0  # the rest length's rate of one segment (the winch paying out / in)
    veer_rad_m: float = 0.0  # the wind turns clockwise with height by this much per metre (0: no veer)

    @classmethod
    def build(
        cls, length_m: float, kg_m: float, diameter_m: float, ea_n: float, segments: int, damping_ratio: float,
        normal_cd: float, drag: bool, shear_exponent: float, shear_reference_m: float, veer_rad_m: float = 0.0,
        speed_mps: float = 0.0,
    ) -> LumpedRope:  # fmt: skip
        """``speed_mps``: the winch's paying-out speed (negative: reeling in), shared by the segments."""
        l0 = length_m / segments
        m = max(kg_m * l0, 1e-6)
        k = ea_n / l0
        return cls(
            segments=segments,
            seg_length_m=l0,
            node_mass_kg=m,
            seg_k_n_m=k,
            seg_c_ns_m=2.0 * damping_ratio * math.sqrt(k * m),
            drag_factor_m2=0.5 * normal_cd * diameter_m * l0 if drag else 0.0,
            shear_exponent=shear_exponent,
            shear_reference_m=shear_reference_m,
            ground_c_ns_m=2.0 * GROUND_DAMPING_RATIO * math.sqrt(GROUND_STIFFNESS_N_M * m),
            kg_m=kg_m,
            ea_n=ea_n,
            damping_ratio=damping_ratio,
            normal_cd_d_m=normal_cd * diameter_m if drag else 0.0,
            seg_rate_mps=speed_mps / segments,
            veer_rad_m=veer_rad_m,
        )

    def at_length(self, length_m: float, speed_mps: float) -> LumpedRope:
        """The same rope with ``length_m`` paid out at ``speed_mps`` (a winch at the anchor): the segments
        keep their count and share the length (each node's mass, stiffness and dashpot follow it)."""
        return LumpedRope.build(
            length_m, self.kg_m, 1.0, self.ea_n, self.segments, self.damping_ratio, self.normal_cd_d_m,
            self.normal_cd_d_m > 0.0, self.shear_exponent, self.shear_reference_m, self.veer_rad_m, speed_mps,
        )  # fmt: skip

    def stable_step_s(self) -> float:
        """The longest RK4 step that integrates this rope. Its stiffest mode is the chain's highest, the nodes
        moving against their neighbours: m x'' = -4 k x - 4 c x', so lambda = 2 omega0 (-2 zeta +- sqrt(4 zeta^2 - 1)),
        omega0 = sqrt(k / m), zeta = c / (2 sqrt(k m)): |lambda| = 2 omega0 below zeta = 1/2 (complex), 2 omega0
        (2 zeta + sqrt(4 zeta^2 - 1)) above it (real, the dashpot then the stiffer part). A node on the ground adds
        its contact (critically damped: |lambda| = sqrt(k_ground / m)). The step keeps h |lambda| <=
        ``RK4_H_LAMBDA_MAX``; beyond it the chain does not blow up at once but rings, the rope going slack and taut
        at random (EA 200 kN on 100 m of 12 segments at 200 Hz: the tension's spread 0.7 -> 130 N)."""
        m = self.node_mass_kg
        w0 = math.sqrt(self.seg_k_n_m / m)
        zeta = self.seg_c_ns_m / (2.0 * math.sqrt(self.seg_k_n_m * m))
        lam = 2.0 * w0 * (2.0 * zeta + math.sqrt(4.0 * zeta * zeta - 1.0) if 2.0 * zeta >= 1.0 else 1.0)
        lam = max(lam, math.sqrt(GROUND_STIFFNESS_N_M / m))
        return RK4_H_LAMBDA_MAX / lam

    @property
    def n_nodes(self) -> int:
        """Free nodes between the anchor and the balloon."""
        return self.segments - 1


def shear_factor(exponent: float, reference_m: float, height_m: float) -> float:
    """Power-law wind profile u(z) = u_ref (z / z_ref)^alpha; 1 without shear, 0 at the ground."""
    if exponent == 0.0:
        return 1.0
    if height_m <= 0.0:
        return 0.0
    return (height_m / reference_m) ** exponent


def profile_wind(
    exponent: float, reference_m: float, veer_rad_m: float, height_m: float, wn: float, we: float
) -> tuple[float, float]:
    """The horizontal wind at ``height_m`` from the reference wind (wn, we) at ``reference_m``: the power
    law's speed (``shear_factor``) turned clockwise (seen from above: veer) by ``veer_rad_m`` per metre
    above the reference height."""
    sf = shear_factor(exponent, reference_m, height_m)
    if veer_rad_m == 0.0:
        return sf * wn, sf * we
    a = veer_rad_m * (height_m - reference_m)
    c, s = math.cos(a), math.sin(a)
    return sf * (c * wn - s * we), sf * (s * wn + c * we)


def anchor_tension_n(rope: LumpedRope, nodes: list[float]) -> float:
    """The pull of the bottom segment on the anchor (the winch's load cell), N, at rest-length rate."""
    n = rope.n_nodes
    x, y, z = nodes[0], nodes[1], nodes[2]
    length = math.sqrt(x * x + y * y + z * z)
    if length <= rope.seg_length_m or length < 1e-9:
        return 0.0
    rate = (x * nodes[3 * n] + y * nodes[3 * n + 1] + z * nodes[3 * n + 2]) / length - rope.seg_rate_mps
    return max(0.0, rope.seg_k_n_m * (length - rope.seg_length_m) + rope.seg_c_ns_m * rate)


def initial_nodes(rope: LumpedRope) -> list[float]:
    """Boot: the rope coiled at the anchor, at rest (positions then velocities, all zero)."""
    return [0.0] * (6 * rope.n_nodes)


def rope_derivative(
    rope: LumpedRope, nodes: list[float], top: tuple[float, float, float, float, float, float],
    wind: tuple[float, float, float], rho: float,
) -> tuple[list[float], tuple[float, float, float], float, float]:  # fmt: skip
    """d(nodes)/dt, the rope's force on the balloon at its attachment point (N, NED), the tension of
    the top segment and of the bottom one (at the anchor) [N].

    ``top`` is the attachment point's position and velocity (NED, from the anchor); ``wind`` the
    reference wind (n, e, d), scaled by ``shear_factor`` at each segment's mid-height; ``rho`` the air
    density (one value: it changes by 1 % over 100 m)."""
    n = rope.n_nodes
    m = rope.node_mass_kg
    l0 = rope.seg_length_m
    k, c = rope.seg_k_n_m, rope.seg_c_ns_m
    kd = rho * rope.drag_factor_m2
    wn, we, wd = wind
    # node coordinates with the anchor (0) and the attachment point (N) at the ends
    px = [0.0] + nodes[0 : 3 * n : 3] + [top[0]]
    py = [0.0] + nodes[1 : 3 * n : 3] + [top[1]]
    pz = [0.0] + nodes[2 : 3 * n : 3] + [top[2]]
    vx = [0.0] + nodes[3 * n :: 3] + [top[3]]
    vy = [0.0] + nodes[3 * n + 1 :: 3] + [top[4]]
    vz = [0.0] + nodes[3 * n + 2 :: 3] + [top[5]]
    fx = [0.0] * (n + 2)
    fy = [0.0] * (n + 2)
    fz = [0.0] * (n + 2)
    t_top = t_bottom = 0.0
    for j in range(n + 1):  # segment j joins node j and node j + 1
        dx, dy, dz = px[j + 1] - px[j], py[j + 1] - py[j], pz[j + 1] - pz[j]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if length > 1e-9:
            ex, ey, ez = dx / length, dy / length, dz / length
        else:
            ex = ey = 0.0
            ez = -1.0
        tension = 0.0
        if length > l0:
            # the dashpot acts on the strain's rate: the rest length's own (a winch) is not stretch
            rate = ex * (vx[j + 1] - vx[j]) + ey * (vy[j + 1] - vy[j]) + ez * (vz[j + 1] - vz[j]) - rope.seg_rate_mps
            tension = k * (length - l0) + c * rate
            if tension < 0.0:
                tension = 0.0
            fx[j] += tension * ex
            fy[j] += tension * ey
            fz[j] += tension * ez
            fx[j + 1] -= tension * ex
            fy[j + 1] -= tension * ey
            fz[j + 1] -= tension * ez
        if j == 0:
            t_bottom = tension
        if j == n:
            t_top = tension
        if kd > 0.0:
            if rope.veer_rad_m == 0.0:
                sf = shear_factor(rope.shear_exponent, rope.shear_reference_m, -0.5 * (pz[j] + pz[j + 1]))
                swn, swe = sf * wn, sf * we
            else:
                swn, swe = profile_wind(rope.shear_exponent, rope.shear_reference_m, rope.veer_rad_m,
                                        -0.5 * (pz[j] + pz[j + 1]), wn, we)  # fmt: skip
            ux = swn - 0.5 * (vx[j] + vx[j + 1])
            uy = swe - 0.5 * (vy[j] + vy[j + 1])
            uz = wd - 0.5 * (vz[j] + vz[j + 1])
            along = ux * ex + uy * ey + uz * ez
            ux, uy, uz = ux - along * ex, uy - along * ey, uz - along * ez
            half = 0.5 * kd * math.sqrt(ux * ux + uy * uy + uz * uz)
            fx[j] += half * ux
            fy[j] += half * uy
            fz[j] += half * uz
            fx[j + 1] += half * ux
            fy[j + 1] += half * uy
            fz[j + 1] += half * uz
    inv_m = 1.0 / m
    weight = m * G0
    acc = [0.0] * (3 * n)
    for i in range(1, n + 1):
        ax, ay, az = fx[i], fy[i], fz[i] + weight
        depth = pz[i]
        if depth > 0.0:  # on (in) the ground: pushed up, held by friction
            cg = rope.ground_c_ns_m
            push = GROUND_STIFFNESS_N_M * depth + cg * vz[i]
            if push > 0.0:
                az -= push
            cf = GROUND_FRICTION_RATIO * cg
            ax -= cf * vx[i]
            ay -= cf * vy[i]
        b = 3 * (i - 1)
        acc[b] = ax * inv_m
        acc[b + 1] = ay * inv_m
        acc[b + 2] = az * inv_m
    # the balloon carries the top half of the top segment's weight and its share of the drag
    force_top = (fx[n + 1], fy[n + 1], fz[n + 1] + 0.5 * weight)
    return nodes[3 * n :] + acc, force_top, t_top, t_bottom


def rope_airborne(rope: LumpedRope, nodes: list[float]) -> bool:
    """Every node off the ground."""
    return all(z < AIRBORNE_BELOW_M for z in nodes[2 : 3 * rope.n_nodes : 3])
