"""Truth physics: equilibria, terminal speed, energy conservation, slack -> taut transition; the truth
options outside the firmware's model (Cd(Re), avionics below the centre)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from balloon_core.atmosphere import G0
from balloon_core.config import ConfigError, Design, TetherConfig
from balloon_core.rotation import quat_from_euler
from sim_hil.dynamics import (
    BalloonPhysics,
    TruthConfig,
    density_at,
    derivative,
    drag_per_speed,
    lever_arm_accel_b,
    net_lift_n,
    rk4_step,
    sphere_drag_coefficient,
    steady_blowdown_deg,
)
from sim_hil.simulator import TRUTH_COLUMNS, Simulation
from sim_hil.wind import WindConfig


def PaperTruth(**kw) -> TruthConfig:  # noqa: N802 - reads as the config it builds
    """These tests check the paper's balloon model (Eq. 5's straight rope); tests/unit/test_rope.py the
    lumped rope."""
    return TruthConfig(rope_model="paper", rope_drag=False, **kw)


def run(design=None, wind=None, truth=None, duration=200.0):
    sim = Simulation(design or Design(), wind or WindConfig(kind="steady"), truth or PaperTruth(), duration, seed=1)
    sim.run()
    return sim


@pytest.mark.parametrize("speed", [2.0, 3.0, 5.0])
def test_steady_blowdown_angle_matches_drag_over_net_lift(speed):
    sim = run(wind=WindConfig(kind="steady", mean_mps=speed), duration=200.0)
    last = sim.truth[-1]
    pn, pe, pd = last[4:7]
    angle = math.degrees(math.atan2(math.hypot(pn, pe), -pd))
    analytic = steady_blowdown_deg(sim.physics, speed, -pd)
    assert abs(angle - analytic) < 1.0
    assert last[13] == 1.0  # taut
    # downwind: the default wind comes from the west
    assert pe > 0 and abs(pn) < 0.5


def test_free_ascent_terminal_speed():
    design = replace(Design(), tether=TetherConfig(length_m=2000.0, linear_density_kg_m=0.0))
    sim = run(design=design, wind=WindConfig(kind="steady", mean_mps=0.0), duration=25.0)
    last = sim.truth[-1]
    ph = sim.physics
    h = -last[6]
    rho = density_at(ph, h)
    analytic = math.sqrt(net_lift_n(ph, h, 0.0) / (rho * ph.drag_factor))
    assert -last[9] == pytest.approx(analytic, rel=0.005)
    assert last[13] == 0.0


def test_no_wind_balloon_stands_above_anchor_at_length_plus_stretch():
    sim = run(wind=WindConfig(kind="steady", mean_mps=0.0), duration=150.0)
    ph = sim.physics
    last = sim.truth[-1]
    pn, pe, pd = last[4:7]
    height = -pd
    tension = net_lift_n(ph, height, ph.tether_length_m)
    expected = ph.tether_length_m + tension / ph.tether_k_n_m + ph.radius_m
    assert math.hypot(pn, pe) < 0.01
    assert height == pytest.approx(expected, abs=0.01)
    assert last[14] == pytest.approx(tension, rel=0.01)


def rotation(q0, q1, q2, q3):
    return np.array([
        [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
    ])  # fmt: skip


def energy(s, ph):
    pn, pe, pd, vn, ve, vd, q0, q1, q2, q3, p, q, r = s
    rho = density_at(ph, -pd)
    m_eff = ph.mass_kg + ph.added_mass_coefficient * rho * ph.volume_m3
    zz = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    zx, zy = 2 * (q1 * q3 + q0 * q2), 2 * (q2 * q3 - q0 * q1)
    att = np.array([pn, pe, pd]) + ph.radius_m * np.array([zx, zy, zz])
    d = np.linalg.norm(att)
    iz = ph.inertia_z_kgm2 if ph.static_moment_kgm else ph.inertia_kgm2
    kinetic = 0.5 * m_eff * (vn * vn + ve * ve + vd * vd) + 0.5 * ph.inertia_kgm2 * (p * p + q * q) + 0.5 * iz * r * r
    # centre of mass s/m below the centre along body z: m v_G^2 = m v^2 + 2 s v.(w x e_z) + ...
    sm = ph.static_moment_kgm
    kinetic += sm * np.dot([vn, ve, vd], rotation(q0, q1, q2, q3) @ [q, -p, 0.0])
    spring = 0.5 * ph.tether_k_n_m * max(0.0, d - ph.tether_length_m) ** 2
    lift = (ph.mass_kg - rho * ph.volume_m3) * G0 * pd  # force (m - rho V) g downwards on the centre
    righting = -sm * G0 * zz  # the weight's extra drop at the centre of mass
    rope = -ph.rope_kg_m * G0 * ph.tether_length_m * att[2]  # whole rope weight at the attachment
    return kinetic + spring - lift + rope + righting


def test_energy_conserved_without_drag_and_damping():
    truth = PaperTruth(drag=False, rot_damping_nms=0.0, tether_damping_ratio=0.0, isa_density=False)
    ph = BalloonPhysics.from_design(Design(), truth)
    ell = ph.tether_length_m + 0.1 + ph.radius_m
    th = math.radians(10.0)
    # rope along the chord: roll the body's down axis towards the anchor, a little off, spinning in yaw
    s = [0.0, ell * math.sin(th), -ell * math.cos(th), 0.0, 0.0, 0.0, *quat_from_euler(th + 0.02, 0.01, 0.3), 0, 0, 0.2]
    calm = (0.0,) * 6
    e0 = energy(s, ph)
    h = 1.0 / 200.0
    energies, tensions = [], []
    for _ in range(int(60.0 / h)):
        k1, tension = derivative(s, *calm, ph)
        tensions.append(tension)
        s = rk4_step(s, h, calm, calm, calm, ph, k1)
        energies.append(energy(s, ph))
    assert min(tensions) > 0.0  # stayed taut: the rope-weight model is continuous there
    swing = max(energies) - min(energies)
    kinetic_scale = 0.5 * ph.mass_kg * max(1.0, max(abs(v) for v in s[3:6])) ** 2
    assert abs(energies[-1] - e0) < 1e-5 * max(abs(e0), 1.0) + 1e-4 * kinetic_scale
    assert swing < 1e-3


def test_energy_decays_with_damping():
    truth = PaperTruth(drag=True, isa_density=False)
    ph = BalloonPhysics.from_design(Design(), truth)
    ell = ph.tether_length_m + 0.1 + ph.radius_m
    th = math.radians(20.0)
    s = [0.0, ell * math.sin(th), -ell * math.cos(th), 0.0, 0.0, 0.0, *quat_from_euler(0.0, 0.0, 0.0), 0, 0, 0]
    calm = (0.0,) * 6
    e0 = energy(s, ph)
    for _ in range(4000):
        k1, _ = derivative(s, *calm, ph)
        s = rk4_step(s, 0.005, calm, calm, calm, ph, k1)
    assert energy(s, ph) < e0


def test_slack_to_taut_transition_without_blow_up():
    sim = run(wind=WindConfig(), duration=120.0)
    t = sim.truth
    assert np.all(np.isfinite(t))
    taut = t[:, 13] > 0
    first = np.argmax(taut)
    assert 10.0 < t[first, 0] < 40.0  # free ascent then taut
    ph = sim.physics
    # the snatch load is bounded by the energy of the arriving balloon: T_peak <= sqrt(k m_eff) v + 2 T_static
    static = net_lift_n(ph, 95.0, ph.tether_length_m)
    m_eff = ph.mass_kg + ph.added_mass_coefficient * density_at(ph, 95.0) * ph.volume_m3
    v_arrive = np.max(np.linalg.norm(t[first - 100 : first, 7:10], axis=1))
    assert np.max(t[:, 14]) < math.sqrt(ph.tether_k_n_m * m_eff) * v_arrive + 2 * static
    # and it rings down: the last 20 s hold a tension near the static one
    assert np.mean(t[-2000:, 14]) == pytest.approx(static, rel=0.3)
    assert np.max(np.abs(t[:, 7:10])) < 12.0
    # before release the balloon sits still on the ground station
    held = t[:, 0] < sim.truth_cfg.release_s
    assert np.all(t[held, 4:10] == t[0, 4:10])


def test_balloon_aligns_with_rope_force_when_taut():
    """Paper Sec. 2.3: in the restricted-radial configuration the balloon is aligned with the rope."""
    sim = run(wind=WindConfig(kind="steady", mean_mps=3.0), duration=200.0)
    ph = sim.physics
    last = sim.truth[-1]
    tilt = math.degrees(math.acos(math.cos(math.radians(last[10])) * math.cos(math.radians(last[11]))))
    # the rope pulls at the bottom with tension along the chord + the rope's weight (Eq. 5):
    # its direction balances drag against the balloon's own net lift
    h = -last[6]
    drag = density_at(ph, h) * ph.drag_factor * 9.0
    lift_balloon = net_lift_n(ph, h, 0.0)
    assert tilt == pytest.approx(math.degrees(math.atan2(drag, lift_balloon)), abs=0.3)


# ---------------------------------------------------------------- Cd(Re): the drag crisis

def reynolds_at(ph, speed, height=100.0):
    return speed * 2.0 * ph.radius_m * density_at(ph, height) / ph.air_viscosity_pas


def test_drag_crisis_curve_is_continuous_in_range_and_shaped_like_the_data():
    re = np.geomspace(1e3, 1e7, 40001)
    cd = np.array([sphere_drag_coefficient(x) for x in re])
    assert np.all((cd > 0.1) & (cd < 0.5))
    assert np.max(np.abs(np.diff(cd))) < 1e-3  # continuous: no step between neighbours 0.02 % apart
    assert np.all(np.diff(cd * re**2) > 0)  # the drag force still rises with speed through the crisis
    ph = BalloonPhysics.from_design(Design(), PaperTruth(drag_model="reynolds"))
    assert ph.air_viscosity_pas / density_at(ph, 0.0) == pytest.approx(1.50e-5, rel=0.01)  # nu at 20 C
    re3 = reynolds_at(ph, 3.0)
    assert re3 == pytest.approx(4.0e5, rel=0.03)  # NOTES.md
    assert sphere_drag_coefficient(re3) == pytest.approx(0.30, abs=0.005)  # the firmware's Cd, mid-crisis
    assert 0.38 < sphere_drag_coefficient(5e4) < 0.48  # subcritical (Morrison's own fit: 0.41)
    # Morrison's published correlation is the special case Re_c = 2.63e5, n = 8 (his 7.94 and 8.00)
    x = 1e5 / 263000
    morrison = 24e-5 + 2.6 * 2e4 / (1 + 2e4**1.52) + 0.411 * x**-7.94 / (1 + x**-8) + 0.25 * 0.1 / 1.1
    assert sphere_drag_coefficient(1e5, 2.63e5, 8.0) == pytest.approx(morrison, rel=1e-12)
    past = cd[re > 6e5]
    assert 0.1 < past.min() < 0.2  # through the crisis
    assert cd[-1] > past.min() + 0.05 and cd[-1] < 0.3  # slow supercritical recovery
    # the law in the truth: 1/2 rho Cd(Re) A |u| and nothing at rest
    rho = density_at(ph, 100.0)
    assert drag_per_speed(ph, rho, 3.0) == pytest.approx(0.5 * rho * sphere_drag_coefficient(re3) * math.pi * 3.0)
    assert drag_per_speed(ph, rho, 0.0) == 0.0
    assert ph.drag_factor == 0.0


@pytest.mark.parametrize("speed", [2.0, 5.0])
def test_steady_blowdown_under_reynolds_drag_uses_cd_at_that_speed(speed):
    truth = PaperTruth(drag_model="reynolds")
    sim = run(wind=WindConfig(kind="steady", mean_mps=speed), truth=truth, duration=200.0)
    last = sim.truth[-1]
    pn, pe, pd = last[4:7]
    angle = math.degrees(math.atan2(math.hypot(pn, pe), -pd))
    ph = sim.physics
    rho = density_at(ph, -pd)
    cd = sphere_drag_coefficient(speed * 2.0 * ph.radius_m * rho / ph.air_viscosity_pas)
    drag = 0.5 * rho * cd * math.pi * ph.radius_m**2 * speed**2
    analytic = math.degrees(math.atan2(drag, net_lift_n(ph, -pd, ph.tether_length_m)))
    assert angle == pytest.approx(analytic, abs=1.0)
    assert steady_blowdown_deg(ph, speed, -pd) == pytest.approx(analytic, abs=1e-9)
    constant = steady_blowdown_deg(BalloonPhysics.from_design(Design(), PaperTruth()), speed, -pd)
    assert abs(angle - constant) > 3.0  # Cd = 0.3 would be far off: 2 m/s Cd 0.40, 5 m/s Cd 0.16


# ---------------------------------------------------------------- avionics below the centre

OFFSET = PaperTruth(avionics_offset_m=0.8)


def test_avionics_offset_physics_and_validation():
    ph0 = BalloonPhysics.from_design(Design(), PaperTruth())
    ph = BalloonPhysics.from_design(Design(), OFFSET)
    assert ph0.static_moment_kgm == 0.0 and ph0.imu_offset_m == 0.0 and ph0.inertia_z_kgm2 == ph0.inertia_kgm2
    assert ph.static_moment_kgm == pytest.approx(0.5 * 0.8)
    assert ph.static_moment_kgm / ph.mass_kg == pytest.approx(0.218, abs=0.001)  # centre of mass offset
    skin = (2 / 3) * 0.5 + 0.4 * Design().balloon.gas_mass_kg  # the rest of the shell + gas, r = 1
    assert ph.inertia_z_kgm2 == pytest.approx(skin)
    assert ph.inertia_kgm2 == pytest.approx(skin + 0.5 * 0.8**2)  # parallel axis
    with pytest.raises(ConfigError):
        BalloonPhysics.from_design(Design(), PaperTruth(avionics_offset_m=1.0))  # outside the sphere
    with pytest.raises(ConfigError):
        BalloonPhysics.from_design(Design(), PaperTruth(avionics_offset_m=0.5, avionics_kg=2.0))
    with pytest.raises(ConfigError):
        PaperTruth(avionics_offset_m=-0.1)
    with pytest.raises(ConfigError):
        PaperTruth(drag_model="stokes")


def test_energy_conserved_with_avionics_below_the_centre():
    """The Newton-Euler coupling about the centre (s terms both ways, the weight's moment, w x Iw) is
    what makes this hold: drop any one and the energy drifts by far more than the bound."""
    truth = replace(OFFSET, drag=False, rot_damping_nms=0.0, tether_damping_ratio=0.0, isa_density=False)
    ph = BalloonPhysics.from_design(Design(), truth)
    r, th = ph.radius_m, math.radians(10.0)
    stretch = net_lift_n(ph, 100.0, ph.tether_length_m) / ph.tether_k_n_m
    tension = ph.tether_k_n_m * stretch
    # start near the body's own equilibrium (down axis along r F_rope + s g) so that the undamped
    # ~1 Hz rocking stays small and the rope taut; swinging on the chord, spinning, rocking a little
    rope_down = tension * math.cos(th) + ph.rope_kg_m * G0 * ph.tether_length_m
    tilt = math.atan2(r * tension * math.sin(th), r * rope_down + ph.static_moment_kgm * G0)
    dist = ph.tether_length_m + stretch
    s = [0.0, dist * math.sin(th) - r * math.sin(tilt), -dist * math.cos(th) - r * math.cos(tilt), 0.1, 0.0, 0.0,
         *quat_from_euler(tilt + 0.03, -0.02, 0.3), 0.05, -0.05, 0.3]  # fmt: skip
    calm = (0.0,) * 6
    e0 = energy(s, ph)
    h = 1.0 / 200.0
    energies, tensions, rates = [], [], []
    for _ in range(int(30.0 / h)):
        k1, tension = derivative(s, *calm, ph)
        tensions.append(tension)
        s = rk4_step(s, h, calm, calm, calm, ph, k1)
        energies.append(energy(s, ph))
        rates.append(math.hypot(s[10], s[11]))
    assert min(tensions) > 0.0
    assert max(rates) > 0.1  # it does rock
    assert max(energies) - min(energies) < 1e-6
    assert abs(energies[-1] - e0) < 1e-6


@pytest.mark.slow
def test_low_centre_of_mass_rights_the_balloon_in_wind():
    """Moments about the centre in equilibrium: r e_z x F_rope + s e_z x g = 0, so the body's down axis
    lies along r F_rope + s g: tan(tilt) = r drag / (r (rho V - m) g + s g), less than without."""
    sim = run(wind=WindConfig(kind="steady", mean_mps=3.0), truth=OFFSET, duration=200.0)
    ph = sim.physics
    last = sim.truth[-1]
    tilt = math.degrees(math.acos(math.cos(math.radians(last[10])) * math.cos(math.radians(last[11]))))
    h = -last[6]
    drag = density_at(ph, h) * 0.5 * 0.3 * math.pi * ph.radius_m**2 * 9.0
    r = ph.radius_m
    expected = math.degrees(math.atan2(r * drag, r * net_lift_n(ph, h, 0.0) + ph.static_moment_kgm * G0))
    assert tilt == pytest.approx(expected, abs=0.3)
    assert expected < math.degrees(math.atan2(drag, net_lift_n(ph, h, 0.0))) - 0.8


@pytest.mark.slow
def test_avionics_below_the_centre_hang_vertical_and_read_minus_g_in_calm():
    sim = Simulation(Design(), WindConfig(kind="steady", mean_mps=0.0), OFFSET, 150.0, seed=2)
    acc = np.array([smp.accel for smp in sim.samples()])
    last = sim.truth[-1000:]
    assert np.all(last[:, 13] == 1.0)  # taut
    assert np.max(np.abs(last[:, 10:12])) < 0.05  # body z vertical (roll, pitch in degrees)
    np.testing.assert_allclose(acc[-1000:].mean(axis=0), (0.0, 0.0, -G0), atol=0.003)


def test_lever_arm_term_is_zero_at_the_centre_and_matches_the_imu_point_motion():
    assert lever_arm_accel_b(0.3, -0.2, 0.5, 1.0, -2.0, 0.7, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)
    ph = BalloonPhysics.from_design(Design(), replace(OFFSET, isa_density=False))
    d = ph.imu_offset_m
    ell = ph.tether_length_m + 0.05 + ph.radius_m
    s = [0.0, 0.0, -ell, 0.2, -0.1, 0.0, *quat_from_euler(0.3, -0.2, 0.4), 0.6, -0.5, 0.3]
    calm = (0.0,) * 6
    h = 1e-3

    def imu_point(st):
        return np.array(st[0:3]) + rotation(*st[6:10]) @ [0.0, 0.0, d]

    states = [s]
    for _ in range(2):
        k1, _ = derivative(states[-1], *calm, ph)
        states.append(rk4_step(states[-1], h, calm, calm, calm, ph, k1))
    a_fd = (imu_point(states[2]) - 2 * imu_point(states[1]) + imu_point(states[0])) / h**2
    mid = states[1]
    k1, _ = derivative(mid, *calm, ph)
    lever = lever_arm_accel_b(*mid[10:13], *k1[10:13], 0.0, 0.0, d)
    a_model = np.array(k1[3:6]) + rotation(*mid[6:10]) @ lever
    assert np.linalg.norm(lever) > 0.2  # the term matters here
    np.testing.assert_allclose(a_model, a_fd, atol=2e-4)


def test_an_asymmetric_sphere_turns_its_x_axis_downwind():
    """The yaw moment (``yaw_moment_coefficient``): 1/2 rho |u|^2 C A D sin(beta) about body z, zero for a perfect
    sphere. Level at rest, body x north, in a 3 m/s wind to the east (beta = 90 deg): the closed form; body x east
    (beta = 0): none. Flown in a steady wind from the west it weathervanes from its boot heading of 30 deg to 90 deg,
    and without the moment it keeps its heading."""
    c = 0.02
    ph = BalloonPhysics.from_design(Design(), PaperTruth(yaw_moment_coefficient=c))
    r = ph.radius_m
    s = [0.0, 0.0, -20.0, 0.0, 0.0, 0.0, *quat_from_euler(0.0, 0.0, 0.0), 0.0, 0.0, 0.0]
    wind = (0.0, 3.0, 0.0, 0.0, 0.0, 0.0)
    k, _ = derivative(s, *wind, ph)
    rho = density_at(ph, 20.0)
    assert math.isclose(k[12] * ph.inertia_kgm2, 0.5 * rho * 9.0 * c * math.pi * r * r * 2.0 * r, rel_tol=1e-12)
    s_east = s[:6] + list(quat_from_euler(0.0, 0.0, math.pi / 2)) + [0.0, 0.0, 0.0]
    k, _ = derivative(s_east, *wind, ph)
    assert abs(k[12]) < 1e-12
    k, _ = derivative(s, *wind, BalloonPhysics.from_design(Design(), PaperTruth()))
    assert k[12] == 0.0
    steady = WindConfig(kind="steady", from_deg=270.0)
    turned = run(wind=steady, truth=PaperTruth(yaw_moment_coefficient=c), duration=150.0)
    still = run(wind=steady, truth=PaperTruth(), duration=150.0)
    late = turned.truth[:, 0] > 100.0
    yaw = TRUTH_COLUMNS.index("yaw_deg")
    heading = turned.truth[late, yaw]
    assert np.all(np.abs(heading - 90.0) < 3.0), (heading.min(), heading.max())
    assert np.all(np.abs(still.truth[late, yaw] - 30.0) < 1.0)
