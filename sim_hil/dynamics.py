"""6-DOF tethered spherical balloon (truth model), paper Sec. 2.2 with the corrections in docs/model.md.

State (13 plain floats): position NED of the sphere's centre relative to the anchor [m], velocity NED
[m/s], attitude quaternion body(FRD)->NED (w, x, y, z), angular rate in body axes [rad/s]. The
derivative is a pure function of plain floats (no numpy): at one state per call numpy's per-call
overhead would dominate, and a C port maps one line to one line.

Translational (Morison form, docs/model.md), paper Eq. (6):
    (m + Ca rho V) a = (1 + Ca) rho V du/dt + 1/2 rho Cd pi r^2 |u - v| (u - v)
                       + F_tether + (rho V - m) g_up + F_rope
Rotational, paper Eq. (7): I dw/dt = r_att x (F_tether + F_rope) - c_rot w, with the tether and the
rope weight acting at the bottom attachment point r_att = (0, 0, r) in FRD. The sphere is isotropic
(I scalar), so the gyroscopic term w x I w vanishes.

Options that the firmware's model does not have (docs/model.md, "Truth options"):

- ``drag_model = "reynolds"``: Cd(Re) through the drag crisis (``sphere_drag_coefficient``).
- ``avionics_offset_m > 0``: the avionics (a point mass, the IMU and the barometer with it) hang
  below the centre, so the centre of mass does too; Newton-Euler about the centre
  (``_offset_accelerations``) and the IMU's lever-arm terms (``lever_arm_accel_b``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from balloon_core.atmosphere import G0, ISA_EXP, LAPSE_K_M, R_AIR
from balloon_core.config import ConfigError, Design, build_section
from balloon_core.rotation import quat_from_euler, rotation
from sim_hil.rope import LumpedRope, initial_nodes, profile_wind, rope_derivative, shear_factor

SUTHERLAND_MU0_PAS = 1.716e-5  # dynamic viscosity of air at 273.15 K (White, Viscous Fluid Flow)
SUTHERLAND_T0_K = 273.15
SUTHERLAND_S_K = 110.4


@dataclass(frozen=True)
class TruthConfig:
    """Truth-model options beyond the shared design (the [truth] section)."""

    # the rope: "lumped" = the real rope (rope.py: elastic lumped-mass line, its weight shared with the
    # anchor, its own drag, lying on the ground until lifted); "paper" = Eq. (5), straight, massless
    # but its whole weight at the balloon
    rope_model: str = "lumped"
    rope_segments: int = 12
    rope_damping_ratio: float = 0.5  # of one segment's axial mode (lumped)
    added_mass_coefficient: float = 0.5  # Ca of a sphere
    tether_ea_n: float = 20000.0  # axial stiffness EA of the rope (docs/model.md: 5-30 kN)
    tether_damping_ratio: float = 0.2  # of the axial rope mode (paper rope)
    rope_drag: bool = True  # Hoerner cross-flow drag on the rope (the paper neglects it)
    rope_normal_cd: float = 1.1
    shear_exponent: float = 0.0  # power-law wind profile (z / shear_reference_m)^alpha; 0 = uniform
    shear_reference_m: float = 0.0  # the height where the wind is the [wind] section's; 0: the tether length
    veer_deg_per_100m: float = 0.0  # the wind turns clockwise with height (from the reference height up)
    # the ground reference: a barometer and thermometer at the anchor, sent up the link as SCALED_PRESSURE
    # from the ground station's system ([site] ground_sysid); 0 Hz: none
    ground_baro_hz: float = 0.0
    ground_baro_hpa: float = 0.01  # 1-sigma white noise of the ground barometer
    ground_thermometer_k: float = 0.1
    rot_damping_nms: float = 0.5  # rotational air damping torque per rad/s
    # the sphere's asymmetry (a seam, the valve, avionics on the skin) as a weak vane: the air turns the balloon
    # about its body z by C q A D sin(beta), beta the relative air's azimuth in the body (0: a perfect sphere, which
    # never turns: yaw_moment_nm)
    yaw_moment_coefficient: float = 0.0
    release_s: float = 5.0  # boot resting on the ground station, released after this time
    initial_yaw_deg: float = 30.0
    physics_hz: float = 200.0
    isa_density: bool = True  # False: constant ground density (energy-conservation tests)
    drag: bool = True
    spatial_filter: bool = True  # the balloon feels the wind averaged over its diameter (wind.py)
    froude_krylov: bool = True  # the push of the accelerating air, (1 + Ca) rho V du/dt
    # sensor errors beyond Table 2's white noise (the realistic-mems scenario; docs/model.md figures)
    gyro_bias_dps: float = 0.0  # 1-sigma turn-on bias per axis
    gyro_bias_walk_dps_rt_s: float = 0.0  # bias random walk, deg/s per sqrt(s)
    accel_bias_mps2: float = 0.0  # 1-sigma turn-on bias per axis
    accel_bias_walk_mps2_rt_s: float = 0.0  # bias random walk, m/s^2 per sqrt(s)
    baro_offset_m: float = 0.0  # 1-sigma constant barometer offset
    mag_bias_gauss: float = 0.0  # 1-sigma hard-iron offset per axis (drawn from the seed)
    mag_hard_iron_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)  # fixed hard-iron offset, the IMU's FRD axes
    # a current switched beside the magnetometer (a heater, a radio, a servo): this field, the IMU's FRD axes, added
    # from mag_switched_on_s after the boot until mag_switched_off_s (0: on to the end)
    mag_switched_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_switched_on_s: float = 0.0
    mag_switched_off_s: float = 0.0
    # the IMU board mounted askew on the balloon: its axes the body's (the tether's axis z) turned by roll about x,
    # then pitch about the new y; every inertial and magnetic reading in its own axes (sensors.py)
    imu_roll_deg: float = 0.0
    imu_pitch_deg: float = 0.0
    # the steel of the ground station (a winch, a vehicle, the anchor) adds to the earth's field near it, NED gauss at
    # the ground, falling off as a dipole's, (1 + h / ground_field_scale_m)^-3 of it at the magnetometer's height h
    ground_field_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ground_field_scale_m: float = 3.0
    quantize: bool = False  # 16-bit LSBs: +-8 g, +-2000 deg/s, +-8 gauss; 0.01 hPa; 0.01 C
    mag_field_h_gauss: float = 0.20  # horizontal earth field
    mag_field_z_gauss: float = 0.45  # vertical earth field (down)
    # weather: the site's ground pressure and temperature change linearly from their [site] values at
    # boot (t = 0), atmosphere.ground_conditions; the barometer and the thermometer follow (SensorSuite.baro)
    pressure_drift_hpa_h: float = 0.0  # e.g. -2 for a falling barometer
    temperature_drift_k_h: float = 0.0
    # sphere drag: "constant" = the design's drag_coefficient; "reynolds" = Cd(Re) through the drag
    # crisis (sphere_drag_coefficient), the design's Cd is then the firmware's belief only
    drag_model: str = "constant"
    # the balloon flown is not quite the one designed: its C_d is the design's times this (constant drag model;
    # a user knows a balloon's C_d to ~10 %, the design file's is the firmware's belief only)
    drag_coefficient_scale: float = 1.0
    drag_crisis_reynolds: float = 4.1e5  # centre of the crisis: Cd(3 m/s, r = 1 m, 100 m) = 0.30
    drag_crisis_exponent: float = 4.0  # steepness; <= ~5 keeps the drag force rising with speed
    # avionics as a point mass (part of skin_and_avionics_kg) this far below the centre, along body +z;
    # 0 = the avionics counted in the shell, centre of mass at the centre (the paper's model)
    avionics_offset_m: float = 0.0
    avionics_kg: float = 0.5

    def __post_init__(self) -> None:
        if self.rope_model not in ("lumped", "paper"):
            raise ConfigError(f"truth.rope_model must be lumped or paper, got {self.rope_model!r}")
        if not (isinstance(self.rope_segments, int) and 2 <= self.rope_segments <= 200):
            raise ConfigError(f"truth.rope_segments must be an integer in [2, 200], got {self.rope_segments!r}")
        if self.drag_model not in ("constant", "reynolds"):
            raise ConfigError(f"truth.drag_model must be constant or reynolds, got {self.drag_model!r}")
        if not 0.1 <= self.drag_coefficient_scale <= 10.0:
            raise ConfigError(f"truth.drag_coefficient_scale must be in [0.1, 10], got {self.drag_coefficient_scale!r}")
        if self.drag_coefficient_scale != 1.0 and self.drag_model != "constant":
            raise ConfigError("truth.drag_coefficient_scale applies to the constant drag model only")
        if not (self.drag_crisis_reynolds > 0.0 and self.drag_crisis_exponent > 0.0):
            raise ConfigError("truth.drag_crisis_reynolds and truth.drag_crisis_exponent must be > 0")
        if self.avionics_offset_m < 0.0 or self.avionics_kg < 0.0:
            raise ConfigError("truth.avionics_offset_m and truth.avionics_kg must be >= 0")
        for name in ("mag_hard_iron_gauss", "ground_field_gauss", "mag_switched_gauss"):
            hi = getattr(self, name)
            if (
                not isinstance(hi, tuple)
                or len(hi) != 3
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in hi)
            ):
                raise ConfigError(f"truth.{name} must be three finite numbers, got {hi!r}")
        if not self.ground_field_scale_m > 0.0:
            raise ConfigError("truth.ground_field_scale_m must be > 0")
        if not (self.mag_switched_on_s >= 0.0 and self.mag_switched_off_s >= 0.0):
            raise ConfigError("truth.mag_switched_on_s and truth.mag_switched_off_s must be >= 0")

    @classmethod
    def from_dict(cls, values: dict) -> TruthConfig:
        for name in ("mag_hard_iron_gauss", "ground_field_gauss", "mag_switched_gauss"):
            hi = values.get(name)
            if isinstance(hi, (list, tuple)):
                if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in hi):
                    raise ConfigError(f"[truth] {name} must be numbers, got {hi!r}")
                values = dict(values, **{name: tuple(float(x) for x in hi)})
        return build_section(cls, "truth", values)


@dataclass(frozen=True)
class BalloonPhysics:
    """Derived physical parameters (SI), computed once from the design and the truth options."""

    radius_m: float
    volume_m3: float
    mass_kg: float
    inertia_kgm2: float  # about the centre, body x and y (and z when the avionics sit at the centre)
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
    # drag_model = "reynolds": Cd(Re) instead of the constant in drag_factor (0 drag_factor then)
    reynolds_drag: bool = False
    frontal_area_m2: float = 0.0
    air_viscosity_pas: float = 0.0  # Sutherland at the ground temperature
    drag_crisis_reynolds: float = 4.1e5
    drag_crisis_exponent: float = 4.0
    # avionics below the centre: static moment s = m_a d [kg m] (m times the centre-of-mass offset),
    # IMU lever arm d [m], yaw inertia (the x/y one is inertia_kgm2)
    static_moment_kgm: float = 0.0
    imu_offset_m: float = 0.0
    inertia_z_kgm2: float = 0.0
    rope: LumpedRope | None = None  # the lumped rope (rope_model = "lumped"); None: the paper's rope
    shear_exponent: float = 0.0
    shear_reference_m: float = 100.0  # the height of the reference wind
    veer_rad_m: float = 0.0
    yaw_moment_m3: float = 0.0  # 1/2 C pi r^2 2r: the yaw moment over rho |u|^2 at sin(beta) = 1
    tether_ea_n: float = 20000.0

    @classmethod
    def from_design(cls, design: Design, truth: TruthConfig) -> BalloonPhysics:
        b, t = design.balloon, design.tether
        r = b.radius_m
        volume = b.volume_m3
        mass = b.mass_kg
        d = truth.avionics_offset_m
        if d > 0.0:
            if d >= r:
                raise ConfigError(f"truth.avionics_offset_m = {d} must be inside the sphere (< radius {r})")
            if truth.avionics_kg > b.skin_and_avionics_kg:
                raise ConfigError("truth.avionics_kg must not exceed balloon.skin_and_avionics_kg")
        inertia, inertia_z = offset_inertia_kgm2(b.skin_and_avionics_kg, b.gas_mass_kg, r, truth.avionics_kg, d)
        k = truth.tether_ea_n / t.length_m
        p0 = design.site.ground_pressure_pa
        t0 = design.site.ground_temperature_c + 273.15
        rho0 = p0 / (R_AIR * t0)
        m_eff = mass + truth.added_mass_coefficient * rho0 * volume
        c = 2.0 * truth.tether_damping_ratio * math.sqrt(k * m_eff)
        reynolds = truth.drag and truth.drag_model == "reynolds"
        z_ref = truth.shear_reference_m or t.length_m
        veer = math.radians(truth.veer_deg_per_100m) / 100.0
        return cls(
            radius_m=r,
            volume_m3=volume,
            mass_kg=mass,
            inertia_kgm2=inertia,
            drag_factor=0.5 * b.drag_coefficient * truth.drag_coefficient_scale * math.pi * r * r
            if truth.drag and not reynolds
            else 0.0,
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
            reynolds_drag=reynolds,
            frontal_area_m2=math.pi * r * r,
            air_viscosity_pas=sutherland_viscosity_pas(t0),
            drag_crisis_reynolds=truth.drag_crisis_reynolds,
            drag_crisis_exponent=truth.drag_crisis_exponent,
            static_moment_kgm=truth.avionics_kg * d if d > 0.0 else 0.0,
            imu_offset_m=d,
            inertia_z_kgm2=inertia_z,
            rope=LumpedRope.build(
                t.length_m, t.linear_density_kg_m, t.diameter_m, truth.tether_ea_n, truth.rope_segments,
                truth.rope_damping_ratio, truth.rope_normal_cd, truth.rope_drag, truth.shear_exponent, z_ref, veer,
            ) if truth.rope_model == "lumped" else None,
            shear_exponent=truth.shear_exponent,
            shear_reference_m=z_ref,
            veer_rad_m=veer,
            yaw_moment_m3=0.5 * truth.yaw_moment_coefficient * math.pi * r * r * 2.0 * r,
            tether_ea_n=truth.tether_ea_n,
        )  # fmt: skip

    def at_length(self, length_m: float, speed_mps: float) -> BalloonPhysics:
        """The physics with ``length_m`` of rope paid out at ``speed_mps`` (the winch, sim_hil/winch.py):
        the lumped rope rebuilt at that length, the paper's rope's length and stiffness EA / L."""
        rope = self.rope.at_length(length_m, speed_mps) if self.rope is not None else None
        k = self.tether_ea_n / length_m
        c = self.tether_c_ns_m * math.sqrt(k / self.tether_k_n_m)
        return replace(self, tether_length_m=length_m, rope=rope, tether_k_n_m=k, tether_c_ns_m=c)


def offset_inertia_kgm2(
    skin_and_avionics_kg: float, gas_kg: float, radius_m: float, avionics_kg: float, offset_m: float
) -> tuple[float, float]:
    """Inertia about the sphere's centre, (transverse x/y, axial z), kg m^2.

    offset 0 (the paper's model): thin shell of skin + avionics and a uniform gas sphere, isotropic,
    I = (2/3) m_sa r^2 + (2/5) m_gas r^2. offset d > 0: the avionics are a point mass m_a at
    (0, 0, d): shell of the rest, I_z = (2/3)(m_sa - m_a) r^2 + (2/5) m_gas r^2, and by the parallel
    axis theorem I_x = I_y = I_z + m_a d^2. (The step at d -> 0+ is the legacy model's (2/3) m_a r^2
    for avionics smeared over the skin; it keeps offset 0 bit-identical with earlier runs.)"""
    r2 = radius_m * radius_m
    if offset_m <= 0.0:
        iso = (2.0 / 3.0) * skin_and_avionics_kg * r2 + 0.4 * gas_kg * r2
        return iso, iso
    axial = (2.0 / 3.0) * (skin_and_avionics_kg - avionics_kg) * r2 + 0.4 * gas_kg * r2
    return axial + avionics_kg * offset_m * offset_m, axial


def sutherland_viscosity_pas(temperature_k: float) -> float:
    """Dynamic viscosity of air, Sutherland's law mu = mu0 (T/T0)^1.5 (T0 + S)/(T + S): 1.81e-5 Pa s at
    20 C. The kinematic viscosity nu = mu / rho is 1.50e-5 m^2/s at the ground, 1.52e-5 at 100 m."""
    return (
        SUTHERLAND_MU0_PAS
        * (temperature_k / SUTHERLAND_T0_K) ** 1.5
        * ((SUTHERLAND_T0_K + SUTHERLAND_S_K) / (temperature_k + SUTHERLAND_S_K))
    )


def sphere_drag_coefficient(re: float, crisis_re: float = 4.1e5, crisis_exponent: float = 4.0) -> float:
    """Cd of a sphere against the Reynolds number Re = |u| 2r / nu, through the drag crisis.

    Morrison's correlation (F. A. Morrison, An Introduction to Fluid Mechanics, CUP 2013: 24/Re
    creeping flow, the 2.6 term for the recirculating range, the crisis term, the slow supercritical
    recovery toward 0.25) with the crisis position Re_c and steepness n as parameters:

        Cd = 24/Re + 2.6 (Re/5) / (1 + (Re/5)^1.52) + 0.411 x^-(n - 0.06) / (1 + x^-n)
             + 0.25 (Re/1e6) / (1 + Re/1e6),          x = Re / Re_c

    Morrison fits a smooth sphere in a quiet tunnel: Re_c = 2.63e5, n = 8 (his 7.94 and 8.00). Where
    the crisis falls depends on surface roughness and free-stream turbulence, so it is a parameter:
    Re_c = 4.1e5 puts the reference balloon at 3 m/s (Re ~ 4e5, docs/model.md) in mid-crisis with
    Cd = 0.30, the firmware's constant. n = 4 smears the crisis as atmospheric turbulence does: the
    drag force (Cd Re^2) then still rises with speed (d ln Cd / d ln Re >= -1.4 > -2); a tunnel-sharp
    n = 8 makes it fall just above Re_c, a negative aerodynamic damping we do not claim for a balloon
    in turbulent air. Values for r = 1 m at 100 m: 0.38-0.42 from 0.1 to 2 m/s, 0.36 at 2.5, 0.30
    at 3, 0.20 at 4, 0.16 at 5, minimum 0.14 near 7 m/s, 0.16 at 12, 0.20 at 30, -> 0.25."""
    x = re / 5.0
    y = re / crisis_re
    return (
        24.0 / re
        + 2.6 * x / (1.0 + x**1.52)
        + 0.411 * y ** (0.06 - crisis_exponent) / (1.0 + y ** (-crisis_exponent))
        + 0.25 * (re / 1.0e6) / (1.0 + re / 1.0e6)
    )


def drag_per_speed(ph: BalloonPhysics, rho: float, speed: float) -> float:
    """k in F_drag = k (u - v) [N s/m]: 1/2 rho Cd pi r^2 |u - v|, Cd constant or Cd(Re) with
    Re = |u - v| 2 r rho / mu (continuous at |u - v| = 0: Stokes' 24/Re makes k finite there)."""
    if not ph.reynolds_drag:
        return rho * ph.drag_factor * speed
    if speed <= 0.0:
        return 0.0
    re = speed * 2.0 * ph.radius_m * rho / ph.air_viscosity_pas
    cd = sphere_drag_coefficient(re, ph.drag_crisis_reynolds, ph.drag_crisis_exponent)
    return 0.5 * rho * cd * ph.frontal_area_m2 * speed


def lever_arm_accel_b(
    p: float, q: float, r: float, dp: float, dq: float, dr: float, x: float, y: float, z: float
) -> tuple[float, float, float]:
    """Acceleration of a body point at (x, y, z) FRD relative to the centre's, in body axes:
    dw/dt x rho + w x (w x rho). Zero for rho = 0; the IMU adds it to the centre's specific force."""
    wr = p * x + q * y + r * z
    w2 = p * p + q * q + r * r
    return (
        dq * z - dr * y + p * wr - x * w2,
        dr * x - dp * z + q * wr - y * w2,
        dp * y - dq * x + r * wr - z * w2,
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
    """d(state)/dt for the free (not held) balloon (and the lumped rope's nodes after its 13 values) and
    the tether tension at the balloon [N]. The wind is the reference wind (at the tether length's
    height); with shear the balloon feels it scaled to its own height."""
    pn, pe, pd, vn, ve, vd, q0, q1, q2, q3, p, q, r = s[:13]
    if ph.veer_rad_m:
        wn_ref, we_ref = wn, we
        wn, we = profile_wind(ph.shear_exponent, ph.shear_reference_m, ph.veer_rad_m, -pd, wn, we)
        dwn, dwe = profile_wind(ph.shear_exponent, ph.shear_reference_m, ph.veer_rad_m, -pd, dwn, dwe)
    elif ph.shear_exponent:
        sf = shear_factor(ph.shear_exponent, ph.shear_reference_m, -pd)
        wn_ref, we_ref = wn, we
        wn, we, dwn, dwe = sf * wn, sf * we, sf * dwn, sf * dwe
    else:
        wn_ref, we_ref = wn, we
    rad = ph.radius_m
    rho = density_at(ph, -pd)
    rho_v = rho * ph.volume_m3
    # third column of the body->NED rotation: where the body's down axis points
    r00, r01, zx, r10, r11, zy, r20, r21, zz = rotation(q0, q1, q2, q3)
    # attachment point (bottom of the sphere) relative to the anchor, and its velocity
    an, ae, ad = pn + rad * zx, pe + rad * zy, pd + rad * zz
    # omega in NED = R w_b; velocity of the attachment point = v + omega_ned x (rad * z_axis)
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
    nodes_dot: list[float] = []
    if ph.rope is not None:
        nodes_dot, (ftn, fte, ftd), tension, _ = rope_derivative(
            ph.rope, s[13:], (an, ae, ad, avn, ave, avd), (wn_ref, we_ref, wd), rho
        )
    elif dist > length:
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
    if ph.rope is None:
        ftd += ph.rope_kg_m * G0 * airborne  # paper Eq. (5), acting at the attachment point
    # aerodynamic drag on the sphere's frontal area (paper Eq. 3 corrected)
    un, ue, ud = wn - vn, we - ve, wd - vd
    speed = math.sqrt(un * un + ue * ue + ud * ud)
    kd = drag_per_speed(ph, rho, speed) if ph.reynolds_drag else rho * ph.drag_factor * speed
    fan, fae, fad = kd * un, kd * ue, kd * ud
    if ph.rope is None and ph.rope_drag_factor > 0.0 and dist > 0.0:
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
    if ph.static_moment_kgm != 0.0:
        tz = yaw_moment_nm(ph, rho, un, ue, ud, speed, r00, r10, r20, r01, r11, r21) if ph.yaw_moment_m3 else 0.0
        acc = _offset_accelerations(
            ph, fk * dwn + fan + ftn, fk * dwe + fae + fte, fk * dwd + fad + ftd + (ph.mass_kg - rho_v) * G0,
            ftn, fte, ftd, ph.mass_kg + ca_rho_v, q0, q1, q2, q3, p, q, r, tz,
        )  # fmt: skip
        return [vn, ve, vd, *acc, *nodes_dot], tension
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
    if ph.yaw_moment_m3:
        dr += yaw_moment_nm(ph, rho, un, ue, ud, speed, r00, r10, r20, r01, r11, r21) * inv_i
    dq0 = 0.5 * (-q1 * p - q2 * q - q3 * r)
    dq1 = 0.5 * (q0 * p + q2 * r - q3 * q)
    dq2 = 0.5 * (q0 * q - q1 * r + q3 * p)
    dq3 = 0.5 * (q0 * r + q1 * q - q2 * p)
    return [vn, ve, vd, an_, ae_, ad_, dq0, dq1, dq2, dq3, dp, dq, dr, *nodes_dot], tension


def _offset_accelerations(
    ph: BalloonPhysics, fn: float, fe: float, fd: float, ftn: float, fte: float, ftd: float, m_eff: float,
    q0: float, q1: float, q2: float, q3: float, p: float, q: float, r: float, tz: float = 0.0,
) -> list[float]:  # fmt: skip
    """Derivatives (a_NED, dq/dt, dw/dt) when the centre of mass is s/m below the centre.

    Newton-Euler about the sphere's centre C (the state's reference point, where buoyancy, drag, the
    fluid-acceleration force and the added mass act), with the rigid mass m's static moment
    s = m r_G = m_a d e_z (body) and M = m + Ca rho V (the added mass of a sphere moves with the centre
    and has no rotational part):

        M a_C + s R (dw/dt x e_z + w x (w x e_z)) = F
        I_C dw/dt + w x I_C w + s e_z x (R^T a_C) = r_att x F_rope + s e_z x R^T (0, 0, g) - c_rot w

    F is the total force of the centre-of-mass-free model (weight, buoyancy, drag, fluid acceleration,
    tether, rope); only the weight's moment arm is new: it acts at the centre of mass and rights the
    balloon. In body axes (A = R^T a_C, b = R^T F) two 2x2 systems and two scalar ones,

        M Ax + s dq = bx - s p r          I_x dq + s Ax = My - p r (I_x - I_z)
        M Ay - s dp = by - s q r          I_x dp - s Ay = Mx - q r (I_z - I_x)
        M Az = bz + s (p^2 + q^2)         I_z dr = -c_rot r + tz

    with determinant M I_x - s^2 > 0. The total energy 1/2 M |v|^2 + s v.R(w x e_z) + 1/2 w.I_C w
    - (m - rho V) g p_d - s g (e_z . down) + rope and spring terms is conserved without drag and
    damping (tests/system/test_scenarios.py)."""
    rad = ph.radius_m
    sm = ph.static_moment_kgm
    ix, iz = ph.inertia_kgm2, ph.inertia_z_kgm2
    c = ph.rot_damping_nms
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation(q0, q1, q2, q3)
    # total force and the rope force in body axes
    bx = r00 * fn + r10 * fe + r20 * fd
    by = r01 * fn + r11 * fe + r21 * fd
    bz = r02 * fn + r12 * fe + r22 * fd
    fbx = r00 * ftn + r10 * fte + r20 * ftd
    fby = r01 * ftn + r11 * fte + r21 * ftd
    # moments about the centre: rope at (0, 0, rad), weight m g at the centre of mass, air damping
    sg = sm * G0
    mx = -rad * fby - sg * r21 - c * p - q * r * (iz - ix)
    my = rad * fbx + sg * r20 - c * q - p * r * (ix - iz)
    bx -= sm * p * r
    by -= sm * q * r
    det = m_eff * ix - sm * sm
    ax = (ix * bx - sm * my) / det
    dq = (m_eff * my - sm * bx) / det
    ay = (ix * by + sm * mx) / det
    dp = (m_eff * mx + sm * by) / det
    az = (bz + sm * (p * p + q * q)) / m_eff
    dr = -c * r / iz
    if tz:
        dr += tz / iz
    return [
        r00 * ax + r01 * ay + r02 * az,
        r10 * ax + r11 * ay + r12 * az,
        r20 * ax + r21 * ay + r22 * az,
        0.5 * (-q1 * p - q2 * q - q3 * r),
        0.5 * (q0 * p + q2 * r - q3 * q),
        0.5 * (q0 * q - q1 * r + q3 * p),
        0.5 * (q0 * r + q1 * q - q2 * p),
        dp,
        dq,
        dr,
    ]


def yaw_moment_nm(ph: BalloonPhysics, rho: float, un: float, ue: float, ud: float, speed: float,
                  r00: float, r10: float, r20: float, r01: float, r11: float, r21: float) -> float:
    """The asymmetric sphere's yaw moment about its body z, N m: 1/2 rho |u|^2 C A D sin(beta), ``beta`` the azimuth
    in the body of the air relative to the balloon ``u`` (NED), from body x towards body y; it turns the body's x
    axis downwind, as a weak vane (``TruthConfig.yaw_moment_coefficient``). (r00, r10, r20) and (r01, r11, r21) are
    the body's x and y axes in NED."""
    ubx = r00 * un + r10 * ue + r20 * ud
    uby = r01 * un + r11 * ue + r21 * ud
    uh = math.sqrt(ubx * ubx + uby * uby)
    if uh <= 0.0:
        return 0.0
    return rho * ph.yaw_moment_m3 * speed * speed * uby / uh


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


def resting_state(ph: BalloonPhysics, yaw_rad: float) -> list[float]:
    """Boot: sitting level on the ground station, the attachment point at the anchor (the lumped
    rope coiled there)."""
    nodes = initial_nodes(ph.rope) if ph.rope is not None else []
    return [0.0, 0.0, -ph.radius_m, 0.0, 0.0, 0.0, *quat_from_euler(0.0, 0.0, yaw_rad), 0.0, 0.0, 0.0, *nodes]


def net_lift_n(ph: BalloonPhysics, height_m: float, rope_airborne_m: float) -> float:
    """Buoyancy minus weight of balloon and airborne rope, N (up positive)."""
    return (density_at(ph, height_m) * ph.volume_m3 - ph.mass_kg - ph.rope_kg_m * rope_airborne_m) * G0


def steady_blowdown_deg(ph: BalloonPhysics, wind_mps: float, height_m: float) -> float:
    """Analytic equilibrium tether angle from vertical, tan(theta) = drag / net lift (taut), with the
    truth's drag law (Cd constant, or Cd(Re) at this wind speed)."""
    drag = drag_per_speed(ph, density_at(ph, height_m), wind_mps) * wind_mps
    return math.degrees(math.atan2(drag, net_lift_n(ph, height_m, ph.tether_length_m)))
