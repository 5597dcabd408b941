"""6-DOF tethered spherical balloon (truth model), paper Sec. 2.2 with NOTES.md's corrections.

State (13 plain floats): position NED of the sphere's centre relative to the anchor [m], velocity NED
[m/s], attitude quaternion body(FRD)->NED (w, x, y, z), angular rate in body axes [rad/s]. The
derivative is a pure function of plain floats (no numpy): at one state per call numpy's per-call
overhead would dominate, and a C port maps one line to one line.

Translational (Morison form, NOTES.md), paper Eq. (6):
    (m + Ca rho V) a = (1 + Ca) rho V du/dt + 1/2 rho Cd pi r^2 |u - v| (u - v)
                       + F_tether + (rho V - m) g_up + F_rope
Rotational, paper Eq. (7): I dw/dt = r_att x (F_tether + F_rope) - c_rot w, with the tether and the
rope weight acting at the bottom attachment point r_att = (0, 0, r) in FRD. The sphere is isotropic
(I scalar), so the gyroscopic term w x I w vanishes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_py.atmosphere import G0, ISA_EXP, LAPSE_K_M, R_AIR
from firmware_py.config import Design, build_section


@dataclass(frozen=True)
class TruthConfig:
    """Truth-model options beyond the shared design (the [truth] section)."""

    added_mass_coefficient: float = 0.5  # Ca of a sphere
    tether_ea_n: float = 20000.0  # axial stiffness EA of the rope (NOTES.md: 5-30 kN)
    tether_damping_ratio: float = 0.2  # of the axial rope mode
    rope_drag: bool = False  # Hoerner cross-flow drag on the rope (paper neglects it)
    rope_normal_cd: float = 1.1
    rot_damping_nms: float = 0.5  # rotational air damping torque per rad/s
    release_s: float = 5.0  # boot resting on the ground station, released after this time
    initial_yaw_deg: float = 30.0
    physics_hz: float = 200.0
    isa_density: bool = True  # False: constant ground density (energy-conservation tests)
    drag: bool = True
    spatial_filter: bool = True  # the balloon feels the wind averaged over its diameter (wind.py)
    froude_krylov: bool = True  # the push of the accelerating air, (1 + Ca) rho V du/dt
    # sensor errors beyond Table 2's white noise (the realistic-mems scenario; NOTES.md figures)
    gyro_bias_dps: float = 0.0  # 1-sigma turn-on bias per axis
    gyro_bias_walk_dps_rt_s: float = 0.0  # bias random walk, deg/s per sqrt(s)
    accel_bias_mps2: float = 0.0  # 1-sigma turn-on bias per axis
    baro_offset_m: float = 0.0  # 1-sigma constant barometer offset
    mag_bias_gauss: float = 0.0  # 1-sigma hard-iron offset per axis
    quantize: bool = False  # 16-bit LSBs: +-8 g, +-2000 deg/s, +-8 gauss; 0.01 hPa; 0.01 C
    mag_field_h_gauss: float = 0.20  # horizontal earth field
    mag_field_z_gauss: float = 0.45  # vertical earth field (down)

    @classmethod
    def from_dict(cls, values: dict) -> TruthConfig:
        return build_section(cls, "truth", values)


@dataclass(frozen=True)
class BalloonPhysics:
    """Derived physical parameters (SI), computed once from the design and the truth options."""

    radius_m: float
    volume_m3: float
    mass_kg: float
    inertia_kgm2: float
    drag_factor: float  # 1/2 Cd pi r^2 (times rho at run time)
    added_mass_coefficient: float
    tether_length_m: float
    rope_kg_m: float
    tether_k_n_m: float
    tether_c_ns_m: float
    rope_drag_factor: float  # 1/2 Cn d (times rho and airborne length at run time)
    rot_damping_nms: float
    fluid_acceleration: float  # 1 with the Froude-Krylov / added-mass push of gusts, 0 without
    ground_pressure_pa: float
    ground_temperature_k: float
    isa_density: bool

    @classmethod
    def from_design(cls, design: Design, truth: TruthConfig) -> BalloonPhysics:
        b, t = design.balloon, design.tether
        r = b.radius_m
        volume = b.volume_m3
        mass = b.mass_kg
        # thin shell (skin + avionics) + uniform gas sphere
        inertia = (2.0 / 3.0) * b.skin_and_avionics_kg * r * r + 0.4 * b.gas_mass_kg * r * r
        k = truth.tether_ea_n / t.length_m
        p0 = (design.site.ground_pressure_hpa or 1013.25) * 100.0
        t0 = design.site.ground_temperature_c + 273.15
        rho0 = p0 / (R_AIR * t0)
        m_eff = mass + truth.added_mass_coefficient * rho0 * volume
        c = 2.0 * truth.tether_damping_ratio * math.sqrt(k * m_eff)
        return cls(
            radius_m=r,
            volume_m3=volume,
            mass_kg=mass,
            inertia_kgm2=inertia,
            drag_factor=0.5 * b.drag_coefficient * math.pi * r * r if truth.drag else 0.0,
            added_mass_coefficient=truth.added_mass_coefficient,
            tether_length_m=t.length_m,
            rope_kg_m=t.linear_density_kg_m,
            tether_k_n_m=k,
            tether_c_ns_m=c,
            rope_drag_factor=0.5 * truth.rope_normal_cd * t.diameter_m if truth.rope_drag else 0.0,
            rot_damping_nms=truth.rot_damping_nms,
            fluid_acceleration=1.0 if truth.froude_krylov else 0.0,
            ground_pressure_pa=p0,
            ground_temperature_k=t0,
            isa_density=truth.isa_density,
        )


def density_at(ph: BalloonPhysics, height_m: float) -> float:
    """ISA air density at a height above the site (or the ground density if isa_density is off)."""
    t0 = ph.ground_temperature_k
    if not ph.isa_density:
        return ph.ground_pressure_pa / (R_AIR * t0)
    temp = t0 - LAPSE_K_M * height_m
    return ph.ground_pressure_pa * (temp / t0) ** ISA_EXP / (R_AIR * temp)


def derivative(
    s: list[float], wn: float, we: float, wd: float, dwn: float, dwe: float, dwd: float, ph: BalloonPhysics
) -> tuple[list[float], float]:
    """d(state)/dt for the free (not held) balloon and the tether tension [N]."""
    pn, pe, pd, vn, ve, vd, q0, q1, q2, q3, p, q, r = s
    rad = ph.radius_m
    rho = density_at(ph, -pd)
    rho_v = rho * ph.volume_m3
    # third column of the body->NED rotation: where the body's down axis points
    zx = 2.0 * (q1 * q3 + q0 * q2)
    zy = 2.0 * (q2 * q3 - q0 * q1)
    zz = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    # attachment point (bottom of the sphere) relative to the anchor, and its velocity
    an, ae, ad = pn + rad * zx, pe + rad * zy, pd + rad * zz
    # omega in NED = R w_b; velocity of the attachment point = v + omega_ned x (rad * z_axis)
    r00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    r01 = 2.0 * (q1 * q2 - q0 * q3)
    r10 = 2.0 * (q1 * q2 + q0 * q3)
    r11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    r20 = 2.0 * (q1 * q3 - q0 * q2)
    r21 = 2.0 * (q2 * q3 + q0 * q1)
    on = r00 * p + r01 * q + zx * r
    oe = r10 * p + r11 * q + zy * r
    od = r20 * p + r21 * q + zz * r
    avn = vn + rad * (oe * zz - od * zy)
    ave = ve + rad * (od * zx - on * zz)
    avd = vd + rad * (on * zy - oe * zx)
    dist = math.sqrt(an * an + ae * ae + ad * ad)
    length = ph.tether_length_m
    tension = 0.0
    ftn = fte = ftd = 0.0
    if dist > length:
        rate = (an * avn + ae * ave + ad * avd) / dist
        tension = ph.tether_k_n_m * (dist - length) + ph.tether_c_ns_m * rate
        if tension < 0.0:
            tension = 0.0
        ftn, fte, ftd = -tension * an / dist, -tension * ae / dist, -tension * ad / dist
        airborne = length  # paper Eq. (5) when taut: the whole rope
    else:
        airborne = -ad if ad < 0.0 else 0.0  # slack: the rope hanging below the attachment point
        if airborne > length:
            airborne = length
    ftd += ph.rope_kg_m * G0 * airborne  # paper Eq. (5), acting at the attachment point
    # aerodynamic drag on the sphere's frontal area (paper Eq. 3 corrected)
    un, ue, ud = wn - vn, we - ve, wd - vd
    speed = math.sqrt(un * un + ue * ue + ud * ud)
    kd = rho * ph.drag_factor * speed
    fan, fae, fad = kd * un, kd * ue, kd * ud
    if ph.rope_drag_factor > 0.0 and dist > 0.0:
        # cross-flow drag on a straight rope, half of it carried by the balloon; the rope's mean
        # velocity is half the balloon's
        en, ee, ed = an / dist, ae / dist, ad / dist
        rn, re, rd = wn - 0.5 * vn, we - 0.5 * ve, wd - 0.5 * vd
        along = rn * en + re * ee + rd * ed
        cn, ce, cd = rn - along * en, re - along * ee, rd - along * ed
        cs = math.sqrt(cn * cn + ce * ce + cd * cd)
        kr = 0.5 * rho * ph.rope_drag_factor * min(dist, length) * cs
        ftn += kr * cn
        fte += kr * ce
        ftd += kr * cd
    ca_rho_v = ph.added_mass_coefficient * rho_v
    fk = (rho_v + ca_rho_v) * ph.fluid_acceleration  # Froude-Krylov + added-mass force of the accelerating air
    inv_m = 1.0 / (ph.mass_kg + ca_rho_v)
    an_ = (fk * dwn + fan + ftn) * inv_m
    ae_ = (fk * dwe + fae + fte) * inv_m
    ad_ = (fk * dwd + fad + ftd + (ph.mass_kg - rho_v) * G0) * inv_m
    # torque of tether + rope forces at r_att = (0, 0, rad) body: F_body = R^T F_ned
    fbx = r00 * ftn + r10 * fte + r20 * ftd
    fby = r01 * ftn + r11 * fte + r21 * ftd
    inv_i = 1.0 / ph.inertia_kgm2
    c = ph.rot_damping_nms
    dp = (-rad * fby - c * p) * inv_i
    dq = (rad * fbx - c * q) * inv_i
    dr = (-c * r) * inv_i
    dq0 = 0.5 * (-q1 * p - q2 * q - q3 * r)
    dq1 = 0.5 * (q0 * p + q2 * r - q3 * q)
    dq2 = 0.5 * (q0 * q - q1 * r + q3 * p)
    dq3 = 0.5 * (q0 * r + q1 * q - q2 * p)
    return [vn, ve, vd, an_, ae_, ad_, dq0, dq1, dq2, dq3, dp, dq, dr], tension


def rk4_step(
    s: list[float], h: float, w0: tuple, wm: tuple, w1: tuple, ph: BalloonPhysics, k1: list[float]
) -> list[float]:
    """One classical Runge-Kutta step of size h. ``w0, wm, w1`` are the wind (n, e, d, dn, de, dd) at
    t, t + h/2, t + h; ``k1`` is the derivative at t (already evaluated by the caller for the sensors)."""
    h2 = 0.5 * h
    s2 = [a + h2 * b for a, b in zip(s, k1)]
    k2, _ = derivative(s2, *wm, ph)
    s3 = [a + h2 * b for a, b in zip(s, k2)]
    k3, _ = derivative(s3, *wm, ph)
    s4 = [a + h * b for a, b in zip(s, k3)]
    k4, _ = derivative(s4, *w1, ph)
    h6 = h / 6.0
    out = [a + h6 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(s, k1, k2, k3, k4)]
    n = 1.0 / math.sqrt(out[6] ** 2 + out[7] ** 2 + out[8] ** 2 + out[9] ** 2)
    out[6] *= n
    out[7] *= n
    out[8] *= n
    out[9] *= n
    return out


def quat_from_euler(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]


def euler_from_quat(q0: float, q1: float, q2: float, q3: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians, ZYX convention."""
    roll = math.atan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (q0 * q2 - q3 * q1))))
    yaw = math.atan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


def resting_state(ph: BalloonPhysics, yaw_rad: float) -> list[float]:
    """Boot: sitting level on the ground station, the attachment point at the anchor."""
    return [0.0, 0.0, -ph.radius_m, 0.0, 0.0, 0.0, *quat_from_euler(0.0, 0.0, yaw_rad), 0.0, 0.0, 0.0]


def net_lift_n(ph: BalloonPhysics, height_m: float, rope_airborne_m: float) -> float:
    """Buoyancy minus weight of balloon and airborne rope, N (up positive)."""
    return (density_at(ph, height_m) * ph.volume_m3 - ph.mass_kg - ph.rope_kg_m * rope_airborne_m) * G0


def steady_blowdown_deg(ph: BalloonPhysics, wind_mps: float, height_m: float) -> float:
    """Analytic equilibrium tether angle from vertical, tan(theta) = drag / net lift (taut)."""
    drag = density_at(ph, height_m) * ph.drag_factor * wind_mps * wind_mps
    return math.degrees(math.atan2(drag, net_lift_n(ph, height_m, ph.tether_length_m)))
