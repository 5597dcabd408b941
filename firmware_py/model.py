"""The estimator's balloon model (paper Sec. 2.3): a point mass with drag, buoyancy and the rope,
in two configurations. Pure functions of plain floats; the Jacobians the EKF needs come with them.

Free ascent (rope slack):  m_eff a = D + N_b up + lambda g h_air down
Taut (restricted radial):  the same forces, with the radial component replaced by the constraint
                           a_r = -|v_t|^2 / |p| (the tether supplies what is needed, tension >= 0)
with D = k (1/2 rho Cd pi r^2) |u| u, u = w - v (paper Eq. 3 with the frontal area), N_b the balloon's
own net lift (rho V - m) g (Eq. 4 minus the weight), m_eff = m + Ca rho V (added mass), and the rope
weight of Eq. (5). The air's acceleration (Froude-Krylov) is unknown to the filter: process noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_py.atmosphere import G0
from firmware_py.config import Design

ADDED_MASS_COEFFICIENT = 0.5


@dataclass(frozen=True)
class BalloonModel:
    radius_m: float
    volume_m3: float
    mass_kg: float
    half_cd_area_m2: float  # 1/2 Cd pi r^2
    tether_length_m: float  # anchor to the attachment point
    rope_kg_m: float
    rope_drag_m2: float = 0.0  # the balloon's share of the taut rope's cross-flow drag: 1/4 Cn d L

    @classmethod
    def from_design(cls, d: Design, rope_normal_cd: float = 0.0) -> BalloonModel:
        b = d.balloon
        return cls(
            radius_m=b.radius_m,
            volume_m3=b.volume_m3,
            mass_kg=b.mass_kg,
            half_cd_area_m2=0.5 * b.drag_coefficient * b.frontal_area_m2,
            tether_length_m=d.tether.length_m,
            rope_kg_m=d.tether.linear_density_kg_m,
            rope_drag_m2=0.25 * rope_normal_cd * d.tether.diameter_m * d.tether.length_m,
        )

    @property
    def taut_radius_m(self) -> float:
        """Distance anchor -> centre with the rope straight (stretch is centimetres: left to noise)."""
        return self.tether_length_m + self.radius_m


@dataclass
class Forces:
    """Model forces divided by m_eff and their sensitivities, for one state (scratch, reused)."""

    # acceleration NED
    an: float = 0.0
    ae: float = 0.0
    ad: float = 0.0
    # d a / d u (u = w - v), 3x3 symmetric, row-major (already projected if taut)
    j: tuple = (0.0,) * 9
    # d a / d drag_scale
    dk: tuple = (0.0, 0.0, 0.0)
    # d a / d position (taut pendulum stiffness), 3x3 row-major
    jp: tuple = (0.0,) * 9
    tension_n: float = 0.0
    taut: bool = False
    # taut only: d(tension / m_eff)/du and d(tension / m_eff)/d drag_scale (radial, unprojected)
    jr: tuple = (0.0, 0.0, 0.0)
    dkr: float = 0.0
    m_eff_kg: float = 1.0
    # taut with rope drag: the balloon's share of it (N, NED) and d(it)/du (N per m/s, 3x3 row-major)
    rope: tuple = (0.0, 0.0, 0.0)
    jrope: tuple = (0.0,) * 9


def accelerations(
    m: BalloonModel,
    rho: float,
    pn: float, pe: float, pd: float,
    vn: float, ve: float, vd: float,
    wn: float, we: float,
    k: float,
    taut: bool,
    out: Forces,
) -> Forces:  # fmt: skip
    """Model acceleration a(x) and its Jacobians (free or taut configuration). Fills ``out``."""
    rho_v = rho * m.volume_m3
    m_eff = m.mass_kg + ADDED_MASS_COEFFICIENT * rho_v
    inv_m = 1.0 / m_eff
    un, ue, ud = wn - vn, we - ve, -vd
    speed = math.sqrt(un * un + ue * ue + ud * ud) + 1e-6
    c = k * rho * m.half_cd_area_m2
    kd = c * speed * inv_m
    # drag/m_eff and d(drag/m_eff)/du = c/m (|u| I + u u^T / |u|)
    dn, de, dd = kd * un, kd * ue, kd * ud
    cs = c * inv_m / speed
    j = [kd + cs * un * un, cs * un * ue, cs * un * ud,
         cs * ue * un, kd + cs * ue * ue, cs * ue * ud,
         cs * ud * un, cs * ud * ue, kd + cs * ud * ud]  # fmt: skip
    dk = (dn / k, de / k, dd / k) if k > 1e-6 else (0.0, 0.0, 0.0)
    lift = (rho_v - m.mass_kg) * G0  # balloon's own net lift, up
    height = -pd - m.radius_m
    if taut:
        rope = m.rope_kg_m * G0 * m.tether_length_m
    else:
        rope = m.rope_kg_m * G0 * min(max(height, 0.0), m.tether_length_m)
    an, ae, ad = dn, de, dd + (rope - lift) * inv_m
    dist = math.sqrt(pn * pn + pe * pe + pd * pd) + 1e-9
    rope_f = (0.0, 0.0, 0.0)
    jrope = (0.0,) * 9
    if taut and m.rope_drag_m2 > 0.0:
        # cross-flow drag on the straight rope, half carried by the balloon (the truth's model with the
        # rope's own velocity neglected): R = rho (1/4 Cn d L) |u_n| u_n, u_n = (I - e e^T) u
        en, ee, ed = pn / dist, pe / dist, pd / dist
        ua = un * en + ue * ee + ud * ed
        cn, ce, cd = un - ua * en, ue - ua * ee, ud - ua * ed
        cs = math.sqrt(cn * cn + ce * ce + cd * cd) + 1e-6
        kr = rho * m.rope_drag_m2
        rope_f = (kr * cs * cn, kr * cs * ce, kr * cs * cd)
        an += rope_f[0] * inv_m
        ae += rope_f[1] * inv_m
        ad += rope_f[2] * inv_m
        # dR/du = kr (|c| I + c c^T / |c|)(I - e e^T)
        cv, ev = (cn, ce, cd), (en, ee, ed)
        g = [[kr * ((cs if r == q else 0.0) + cv[r] * cv[q] / cs) for q in range(3)] for r in range(3)]
        jr_ = [g[r][q] - (g[r][0] * en + g[r][1] * ee + g[r][2] * ed) * ev[q] for r in range(3) for q in range(3)]
        jrope = tuple(jr_)
        j = [j[i] + jr_[i] * inv_m for i in range(9)]
    # free ascent: the airborne rope grows with height (d rope / d p_d = -lambda g)
    slack_rope = not taut and 0.0 < height < m.tether_length_m
    jp = (0.0,) * 8 + ((-m.rope_kg_m * G0 * inv_m) if slack_rope else 0.0,)
    tension = 0.0
    jr = (0.0, 0.0, 0.0)
    dkr = 0.0
    if taut:
        en, ee, ed = pn / dist, pe / dist, pd / dist
        ar = an * en + ae * ee + ad * ed
        vr = vn * en + ve * ee + vd * ed
        vt2 = vn * vn + ve * ve + vd * vd - vr * vr
        pull = ar + vt2 / dist  # tension / m_eff needed to keep |p| = const
        if pull > 0.0:
            tension = pull * m_eff
            jr = (
                en * j[0] + ee * j[3] + ed * j[6],
                en * j[1] + ee * j[4] + ed * j[7],
                en * j[2] + ee * j[5] + ed * j[8],
            )
            dkr = en * dk[0] + ee * dk[1] + ed * dk[2]
            an, ae, ad = an - pull * en, ae - pull * ee, ad - pull * ed
            # project the sensitivities onto the tangent plane: (I - e e^T) J
            e = (en, ee, ed)
            jt = list(j)
            for col in range(3):
                s = en * j[col] + ee * j[3 + col] + ed * j[6 + col]
                for row in range(3):
                    jt[3 * row + col] = j[3 * row + col] - e[row] * s
            j = jt
            s = en * dk[0] + ee * dk[1] + ed * dk[2]
            dk = (dk[0] - en * s, dk[1] - ee * s, dk[2] - ed * s)
            # pendulum stiffness: d/dp of -(e e^T) a_free ~ -(a_r / |p|) (I - e e^T)
            g = -ar / dist
            jp = (g * (1 - en * en), -g * en * ee, -g * en * ed,
                  -g * ee * en, g * (1 - ee * ee), -g * ee * ed,
                  -g * ed * en, -g * ed * ee, g * (1 - ed * ed))  # fmt: skip
    out.an, out.ae, out.ad = an, ae, ad
    out.j, out.dk, out.jp = tuple(j), dk, jp
    out.tension_n = tension
    out.taut = tension > 0.0
    out.jr, out.dkr, out.m_eff_kg = jr, dkr, m_eff
    out.rope, out.jrope = rope_f, jrope
    return out
