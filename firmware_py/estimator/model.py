"""The estimator's balloon model (paper Sec. 2.3): a point mass with drag, buoyancy and the rope,
in two configurations. Pure functions of plain floats; the Jacobians the EKF needs come with them.

Free ascent (rope slack):  m_eff a = D + N_b up + lambda g h_air down
Taut (restricted radial):  the same forces, with the radial component replaced by the constraint
                           a_r = -|v_t|^2 / |p_a| (the tether supplies what is needed, tension >= 0),
                           radial along the anchor -> attachment point p_a = p + r z_body (Eq. 7)
with D = k (1/2 rho Cd pi r^2) |u| u, u = w - v (paper Eq. 3 with the frontal area), N_b the balloon's
own net lift (rho V - m) g (Eq. 4 minus the weight), m_eff = m + Ca rho V (added mass), and the rope
weight of Eq. (5). The air's acceleration (Froude-Krylov) is unknown to the filter: process noise.
"""

from __future__ import annotations

from dataclasses import dataclass

from balloon_core.atmosphere import G0, P0_PA, air_density
from balloon_core.config import Design
from firmware_py.estimator.generated import COLUMNS, free_model, taut_model, taut_model_plain

# what the generated functions return, by name (tools/derive_model.py): n = len(COLUMNS) model columns
N_COLUMNS = len(COLUMNS)
FREE_JA = slice(3, 3 + 3 * N_COLUMNS)  # free_model: a (3), then d a / d x (3 x n)
TAUT_PULL = 3  # taut_model: a (3), tension / m_eff, d a / d x (3 x n), d(tension / m_eff) / d x (n)
TAUT_JA = slice(TAUT_PULL + 1, TAUT_PULL + 1 + 3 * N_COLUMNS)
TAUT_JPULL = slice(TAUT_JA.stop, TAUT_JA.stop + N_COLUMNS)
JA_DOWN_VD = 2 * N_COLUMNS + COLUMNS.index("vel_d")  # d a_d / d v_d in the row-major d a / d x
ROPE_JAC = 2  # rope_direction: n_N, n_E, then d n_N / d x (n), d n_E / d x (n)

ADDED_MASS_COEFFICIENT = 0.5
SITE_AIR_K = 293.15  # the air's temperature taken before the thermometer reads it (20 C: config.SiteConfig's default)


@dataclass(frozen=True)
class BalloonModel:
    radius_m: float
    volume_m3: float
    mass_kg: float
    half_cd_area_m2: float  # 1/2 Cd pi r^2
    tether_length_m: float  # anchor to the attachment point
    rope_kg_m: float
    rope_drag_m2: float = 0.0  # the balloon's share of the taut rope's cross-flow drag: 1/4 Cn d L
    rope_cn_d_m: float = 0.0  # Cn d: the rope's cross-flow drag per metre is 1/2 rho Cn d |u_n| u_n
    # the site's air before the barometer and the thermometer read it: the design's ground pressure, else the standard
    # atmosphere's at the site's altitude (config.SiteConfig.ground_pressure_pa), at SITE_AIR_K
    site_rho_kg_m3: float = air_density(P0_PA, SITE_AIR_K)

    @classmethod
    def from_design(cls, d: Design, rope_normal_cd: float = 0.0, rope_drag_at_balloon: bool = True) -> BalloonModel:
        b = d.balloon
        return cls(
            radius_m=b.radius_m,
            volume_m3=b.volume_m3,
            mass_kg=b.mass_kg,
            half_cd_area_m2=0.5 * b.drag_coefficient * b.frontal_area_m2,
            tether_length_m=d.tether.length_m,
            rope_kg_m=d.tether.linear_density_kg_m,
            rope_drag_m2=0.25 * rope_normal_cd * d.tether.diameter_m * d.tether.length_m * rope_drag_at_balloon,
            rope_cn_d_m=rope_normal_cd * d.tether.diameter_m,
            site_rho_kg_m3=air_density(d.site.ground_pressure_pa, SITE_AIR_K),
        )

    def lift_n(self, rho: float) -> float:
        """The balloon's own net lift in air of density ``rho`` (Eq. 4 less its weight; the rope not counted)."""
        return (rho * self.volume_m3 - self.mass_kg) * G0

    @property
    def rope_weight_n(self) -> float:
        return self.rope_kg_m * G0 * self.tether_length_m

    @property
    def taut_radius_m(self) -> float:
        """Distance anchor -> centre with the rope straight and in line with the centre (the taut
        placement); the taut model ties the rope to the attachment point, |p + r z_body| = L. The
        stretch (centimetres, but a systematic lean: docs/estimator.md) is not known to the filter."""
        return self.tether_length_m + self.radius_m


@dataclass
class Forces:
    """Model acceleration and its Jacobian for one state (scratch, reused). Columns of the Jacobians:
    ``generated.COLUMNS`` (position, velocity, wind, wind rate, drag scale)."""

    an: float = 0.0
    ae: float = 0.0
    ad: float = 0.0
    ja: tuple = (0.0,) * 33  # d a / d x, 3 x 11 row-major
    jpull: tuple = (0.0,) * 11  # d (tension / m_eff) / d x (taut)
    tension_n: float = 0.0
    taut: bool = False
    m_eff_kg: float = 1.0
    params: tuple = ()  # the parameter tuple of the generated functions at this step
    # input: the tether's attachment point relative to the centre, NED (radius times the body down axis),
    # set by the caller from the attitude; (0, 0, 0) puts it on the line anchor -> centre
    attach_ned: tuple = (0.0, 0.0, 0.0)
    # input: the rope weight the taut rod carries at the balloon (catenary.py: W_eff), N; NaN: the
    # paper's whole rope (Eq. 5)
    rope_weight_n: float = float("nan")


def rope_pickup_n(m: BalloonModel, pd: float, vd: float) -> float:
    """The pull (N, down) that picks the rope up from rest while the balloon climbs at ``-vd`` with part of
    the rope still on the ground: the rising rope takes up lambda |vd| kg a second to the climb's speed,
    lambda vd^2 (a rope lifted off its coil, its drum or the grass; a chain lifted from a heap). Against the
    balloon's drag at that climb, k c vd^2, it is lambda / (k c), 1-3 % for a 20 g/m rope: the free ascent that
    left it out learnt a drag scale that much too large, and read the taut wind low by half of it (the real
    rope's steady flights of the envelope, 2-3 % low). 0 descending, or with no rope or all of it aloft."""
    height = -pd - m.radius_m
    if vd >= 0.0 or height <= 0.0 or height >= m.tether_length_m:
        return 0.0
    return m.rope_kg_m * vd * vd


def parameters(
    m: BalloonModel, rho: float, pd: float, taut: bool, attach_ned: tuple = (0.0, 0.0, 0.0),
    rope_weight_n: float = float("nan"), pickup_n: float = 0.0,
) -> tuple[float, ...]:  # fmt: skip
    """(m_eff, push, c, lift, rope_w, rope_slope, kr, att_n, att_e, att_d) of the generated model, for
    air density ``rho``.

    push = (1 + Ca) rho V: the accelerating air's push per m/s^2 (Froude-Krylov + added mass);
    c = rho Cd pi r^2 / 2; lift = (rho V - m) g, the balloon's own net lift (Eq. 4 minus its weight);
    rope weight: taut, the share the rod carries (``rope_weight_n``, catenary.py; the whole rope of the
    paper's Eq. 5 if NaN); in free ascent the airborne part hanging below the balloon and, climbing, the
    pull that picks the rope up (``pickup_n``, ``rope_pickup_n``);
    att = the attachment point relative to the centre (taut: the rope pulls from there)."""
    rho_v = rho * m.volume_m3
    m_eff = m.mass_kg + ADDED_MASS_COEFFICIENT * rho_v
    lam_g = m.rope_kg_m * G0
    if taut:
        rope_w = lam_g * m.tether_length_m if rope_weight_n != rope_weight_n else rope_weight_n
        slope = 0.0
    else:
        height = -pd - m.radius_m
        if height <= 0.0:
            rope_w, slope = 0.0, 0.0
        elif height >= m.tether_length_m:
            rope_w, slope = lam_g * m.tether_length_m, 0.0
        else:  # lambda g (-pd - r), written as rope_w + slope * pd
            rope_w, slope = -lam_g * m.radius_m + pickup_n, -lam_g
    return (
        m_eff,
        (1.0 + ADDED_MASS_COEFFICIENT) * rho_v,
        rho * m.half_cd_area_m2,
        (rho_v - m.mass_kg) * G0,
        rope_w,
        slope,
        rho * m.rope_drag_m2 if taut else 0.0,
        *attach_ned,
    )


def accelerations(
    m: BalloonModel,
    rho: float,
    pn: float, pe: float, pd: float,
    vn: float, ve: float, vd: float,
    wn: float, we: float,
    rn: float, re: float,
    k: float,
    taut: bool,
    out: Forces,
) -> Forces:  # fmt: skip
    """Model acceleration a(x) and d a / d x in the free or the taut configuration. Taut with a
    negative pull (the rope would push): the rope is slack this instant, the free model applies
    with the whole rope hanging from the balloon. Taut, the rope pulls from ``out.attach_ned`` (the
    attitude enters as a parameter: no Jacobian column, its effect is r / L ~ 1 % of the tension's
    direction). Fills ``out``."""
    pickup = 0.0 if taut else rope_pickup_n(m, pd, vd)
    par = parameters(m, rho, pd, taut, out.attach_ned, out.rope_weight_n, pickup)
    out.params = par
    out.m_eff_kg = par[0]
    if taut:
        fn = taut_model if m.rope_drag_m2 > 0.0 else taut_model_plain
        r = fn(pn, pe, pd, vn, ve, vd, wn, we, rn, re, k, *par)
        if r[TAUT_PULL] > 0.0:
            out.an, out.ae, out.ad = r[0], r[1], r[2]
            out.tension_n = r[TAUT_PULL] * par[0]
            out.ja = r[TAUT_JA]
            out.jpull = r[TAUT_JPULL]
            out.taut = True
            return out
    r = free_model(pn, pe, pd, vn, ve, vd, wn, we, rn, re, k, *par)
    out.an, out.ae, out.ad = r[0], r[1], r[2]
    out.ja = r[FREE_JA]
    if pickup > 0.0:  # the pick-up's lambda vd^2 is in the parameter rope_w: its d a_d / d vd, 2 lambda vd / m_eff
        ja = list(out.ja)
        ja[JA_DOWN_VD] += 2.0 * pickup / (vd * par[0])
        out.ja = tuple(ja)
    out.tension_n = 0.0
    out.taut = False
    return out
