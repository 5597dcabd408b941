"""The winch: its schedule, the lumped rope paid in to a new length settling on that length's elastic
catenary, the simulator's truth and WINCH_STATUS following the schedule, the MAVLink round trip of
WINCH_STATUS and of the ground reference, and the estimator's tether length following WINCH_STATUS."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from balloon_core.atmosphere import G0
from balloon_core.config import ConfigError, Design
from balloon_core.samples import BaroSample, GroundBaroSample, ImuSample, MavlinkSampler, WinchSample
from balloon_core.wire import Decoder, LinkStats
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.params import WINCH_REJECT_LENGTH, WINCH_REJECT_SPEED
from firmware_py.estimator.state import MODE_TAUT, FilterConfig
from sim_hil.dynamics import TruthConfig
from sim_hil.packets import SensorPacketEncoder
from sim_hil.rope import LumpedRope, anchor_tension_n, rope_derivative
from sim_hil.simulator import TRUTH_COLUMNS, SensorSample, Simulation
from sim_hil.winch import WinchConfig, line_length_m
from sim_hil.wind import WindConfig
from tests.unit.test_rope import EA, KG_M, W, elastic_catenary


def test_schedule_is_piecewise_linear_and_held_outside():
    w = WinchConfig(times_s=(10.0, 20.0, 30.0), lengths_m=(50.0, 55.0, 45.0))
    assert line_length_m(w, 0.0) == (50.0, 0.0)
    assert line_length_m(w, 15.0) == pytest.approx((52.5, 0.5))
    assert line_length_m(w, 25.0) == pytest.approx((50.0, -1.0))
    assert line_length_m(w, 99.0) == (45.0, 0.0)
    with pytest.raises(ConfigError, match="faster than"):
        WinchConfig(times_s=(0.0, 10.0), lengths_m=(30.0, 50.0), max_speed_mps=1.0)
    with pytest.raises(ConfigError, match="increase"):
        WinchConfig(times_s=(0.0, 0.0), lengths_m=(30.0, 30.0))
    assert not WinchConfig().enabled


def _step(rope, nodes, topv, h):
    calm = (0.0, 0.0, 0.0)
    k1, *_ = rope_derivative(rope, nodes, topv, calm, 1.2)
    s2 = [a + 0.5 * h * b for a, b in zip(nodes, k1)]
    k2, *_ = rope_derivative(rope, s2, topv, calm, 1.2)
    s3 = [a + 0.5 * h * b for a, b in zip(nodes, k2)]
    k3, *_ = rope_derivative(rope, s3, topv, calm, 1.2)
    s4 = [a + h * b for a, b in zip(nodes, k3)]
    k4, *_ = rope_derivative(rope, s4, topv, calm, 1.2)
    out = [a + h / 6.0 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(nodes, k1, k2, k3, k4)]
    for i in range(len(out) // 2, len(out)):
        out[i] *= 1.0 - 2.0 * h  # a little viscous damping: the equilibrium is the rope's alone
    return out


@pytest.mark.slow
def test_rope_reeled_in_settles_on_the_catenary_of_its_new_length():
    """80 m of rope reeled in at 1 m/s to 60 m under a balloon held where a 60 m rope sags: at rest the
    nodes lie on the elastic catenary of 60 m with the tensions the rope pulls with (physics, not the code)."""
    segments, start, final, speed = 20, 80.0, 60.0, 1.0
    rope = LumpedRope.build(start, KG_M, 0.0047, EA, segments, 0.5, 1.1, True, 0.0, 100.0)
    top = (18.0, 0.0, -56.0)  # chord 58.8 m: the 60 m rope sags
    n = rope.n_nodes
    nodes = []
    for i in range(1, n + 1):
        f = i / segments
        nodes += [top[0] * f, top[1] * f, top[2] * f - 5.0 * math.sin(math.pi * f)]  # hanging below the chord
    nodes += [0.0] * (3 * n)
    h, t = 0.002, 0.0
    topv = (*top, 0.0, 0.0, 0.0)
    while t < 60.0:
        length = max(final, start - speed * t)
        r = rope.at_length(length, -speed if length > final else 0.0)
        nodes = _step(r, nodes, topv, h)
        t += h
    assert r.seg_length_m * segments == pytest.approx(final)
    _, force, _, t_bottom = rope_derivative(r, nodes, topv, (0.0, 0.0, 0.0), 1.2)
    hz = math.hypot(force[0], force[1])
    v_bottom = force[2] - W * final
    xe, ze = elastic_catenary(hz, v_bottom, final)
    assert xe == pytest.approx(top[0], abs=0.3) and ze == pytest.approx(-top[2], abs=0.3)
    worst = max(
        math.hypot(nodes[3 * i] - x, -nodes[3 * i + 2] - z)
        for i in range(n)
        for x, z in [elastic_catenary(hz, v_bottom, (i + 1) * final / segments)]
    )
    assert worst < 0.5, worst
    assert anchor_tension_n(r, nodes) == pytest.approx(t_bottom, rel=1e-6)
    assert t_bottom == pytest.approx(math.hypot(hz, v_bottom + 0.5 * r.node_mass_kg * G0), rel=0.02)


@pytest.fixture(scope="module")
def winch_flight():
    """25 s of the reference balloon on a winch: 100 m, paid in to 94 m from 12 s to 18 s; ground reference."""
    w = WinchConfig(times_s=(0.0, 12.0, 18.0), lengths_m=(100.0, 100.0, 94.0))
    truth = TruthConfig(ground_baro_hz=1.0, pressure_drift_hpa_h=-2.0)
    sim = Simulation(Design(), WindConfig(kind="steady"), truth, 25.0, 3, winch=w)
    samples = list(sim.samples())
    return w, sim, samples


@pytest.mark.slow
def test_simulated_winch_follows_its_schedule(winch_flight):
    w, sim, samples = winch_flight
    col = {c: i for i, c in enumerate(TRUTH_COLUMNS)}
    for row in sim.truth[::50]:
        assert row[col["line_length_m"]] == pytest.approx(line_length_m(w, row[0])[0], abs=1e-9)
    reports = [(s.time_usec, s.winch) for s in samples if s.winch is not None]
    assert len(reports) == pytest.approx(25 * w.status_hz, abs=1)
    for t_us, (length, speed, _, status) in reports:
        assert (length, speed) == pytest.approx(line_length_m(w, t_us * 1e-6), abs=1e-9)
        assert bool(status & mavlink.MAV_WINCH_STATUS_MOVING) == (speed != 0.0)
    # the load cell reads the anchor's pull (noise 0.05 kg) once the rope is up
    i = int(22.0 * sim.imu_hz)
    kg = next(r[1][2] for r in reports if r[0] >= samples[i].time_usec)
    assert kg * G0 == pytest.approx(sim.truth[i, col["anchor_tension_n"]], abs=0.3 * G0 + 2.0)
    grounds = [s.ground for s in samples if s.ground is not None]
    assert len(grounds) == pytest.approx(25, abs=1)
    assert grounds[-1][0] == pytest.approx(1013.25 - 2.0 * 25 / 3600, abs=0.05)


def test_winch_status_and_ground_reference_round_trip_through_pymavlink():
    enc = SensorPacketEncoder()
    s = SensorSample(2_000_000, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0), (0.2, 0.0, 0.45), (1000.5, 20.0),
                     winch=(87.5, -0.75, 3.25, 13), ground=(1012.34, 17.5))  # fmt: skip
    dec = Decoder(LinkStats())
    msgs = [m for f in enc.encode(s) for m in dec.feed(f)]
    winch = next(m for m in msgs if m.get_type() == "WINCH_STATUS")
    assert winch.get_srcComponent() == mavlink.MAV_COMP_ID_WINCH
    sampler = MavlinkSampler()
    out = [x for m in msgs for x in (sampler.convert(m) or ())]
    (ws,) = [x for x in out if type(x) is WinchSample]
    assert ws.line_length_m == pytest.approx(87.5) and ws.speed_mps == pytest.approx(-0.75)
    assert ws.tension_n == pytest.approx(3.25 * G0, rel=1e-6) and ws.status == 13
    (gs,) = [x for x in out if type(x) is GroundBaroSample]
    assert gs.pressure_hpa == pytest.approx(1012.34, abs=1e-4) and gs.temperature_c == pytest.approx(17.5)
    # the balloon's barometer stays its own: one BaroSample, the balloon's pressure
    (b,) = [x for x in out if type(x) is BaroSample]
    assert b.pressure_hpa == pytest.approx(1000.5)
    assert sum(type(x) is ImuSample for x in out) == 1


def test_pressure_from_another_system_is_never_the_balloons():
    """An autopilot's SCALED_IMU + SCALED_PRESSURE (system 1): the ground station's pressure (255) heard
    first, and a third system's, are not taken for the balloon's barometer."""

    def frame(sysid, name, *a):
        mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        m = getattr(mav, name)(*a)
        m.pack(mav)
        return m

    s = MavlinkSampler()
    (g,) = s.convert(frame(255, "scaled_pressure_encode", 10, 1005.0, 0.0, 1500, 0))
    assert type(g) is GroundBaroSample
    assert s.convert(frame(1, "scaled_imu_encode", 10, 0, 0, -1000, 0, 0, 0, 200, 10, 400))
    assert s.convert(frame(7, "scaled_pressure_encode", 20, 990.0, 0.0, 1500, 0)) == ()
    (b,) = s.convert(frame(1, "scaled_pressure_encode", 30, 1000.0, 0.0, 1500, 0))
    assert type(b) is BaroSample and b.pressure_hpa == pytest.approx(1000.0)
    # another ground sysid: 255 is then an ordinary other system, ignored
    s2 = MavlinkSampler(ground_sysid=200)
    s2.convert(frame(1, "scaled_imu_encode", 10, 0, 0, -1000, 0, 0, 0, 200, 10, 400))
    assert s2.convert(frame(255, "scaled_pressure_encode", 10, 1005.0, 0.0, 1500, 0)) == ()
    (g2,) = s2.convert(frame(200, "scaled_pressure_encode", 10, 1005.0, 0.0, 1500, 0))
    assert type(g2) is GroundBaroSample


def test_estimator_tether_length_follows_winch_status():
    est = Estimator(Design(), FilterConfig())
    m0 = est.model
    chord0, weight0 = est.ekf.rope.chord_m, est.ekf.rope.weight_n
    assert m0.tether_length_m == 100.0
    assert est.on_winch(1000, 60.0, 0.5, math.nan)
    assert est.model.tether_length_m == 60.0 and est.ekf.model is est.model
    assert est.ekf.rope.chord_m == pytest.approx(0.6 * chord0)
    assert est.ekf.rope.weight_n == pytest.approx(0.6 * weight0)
    assert est.ekf.rope.rate_mps == pytest.approx(0.5 * est.ekf.rope.chord_m / 60.0)
    assert est.model.rope_weight_n == pytest.approx(0.6 * m0.rope_weight_n)
    # a length that is no winch's, or a speed no winch reels at, is refused and counted: the model keeps
    # the last plausible one
    rate = est.ekf.rope.rate_mps
    assert not est.on_winch(2000, math.nan, 0.0, 1.0)
    assert not est.on_winch(2000, -5.0, 0.0, 1.0)
    assert not est.on_winch(2000, 106.0, 0.0, 1.0)  # beyond the drum's 100 m rope + 5 m
    assert est.winch_reject_reason == WINCH_REJECT_LENGTH
    assert not est.on_winch(2000, 60.0, 1e9, 20.0) and not est.on_winch(2000, 60.0, math.inf, 20.0)
    assert est.winch_reject_reason == WINCH_REJECT_SPEED
    assert est.model.tether_length_m == 60.0 and est.ekf.rope.rate_mps == rate
    assert (est.winch_samples, est.winch_rejected) == (1, 5)
    assert est.on_winch(2000, 104.0, 0.0, 20.0)  # within the margin
    assert est.winch_tension_n == 20.0 and est.model.tether_length_m == 104.0


@pytest.mark.slow
def test_firmware_tether_follows_winch_status_in_flight(winch_flight):
    """In flight the filter's anchor distance follows the paid-in line (94 m from 100 m), and without
    WINCH_STATUS the same flight keeps the design's 100 m."""
    _, sim, samples = winch_flight
    col = {c: i for i, c in enumerate(TRUTH_COLUMNS)}

    def run(with_winch: bool):
        est = Estimator(Design(), FilterConfig())
        for s in samples:
            if s.baro:
                est.on_baro(s.time_usec, *s.baro)
            if with_winch and s.winch is not None:
                est.on_winch(max(est.t_last_us, 0), s.winch[0], s.winch[1], s.winch[2] * G0)
            est.on_imu(s.time_usec, *s.accel, *s.gyro, *s.mag)
        return est

    est = run(True)
    assert est.ekf.mode == MODE_TAUT and est.model.tether_length_m == pytest.approx(94.0)
    x = est.ekf.x
    dist = math.sqrt(float(x[0]) ** 2 + float(x[1]) ** 2 + float(x[2]) ** 2)
    t = sim.truth[-1]
    true_dist = math.sqrt(t[col["pos_n"]] ** 2 + t[col["pos_e"]] ** 2 + t[col["pos_d"]] ** 2)
    assert dist == pytest.approx(true_dist, abs=1.5)  # the rope's sag and stretch: the chord is not the line
    plain = run(False)
    assert plain.model.tether_length_m == 100.0 and plain.ekf.rope.rate_mps == 0.0
    xp = plain.ekf.x
    assert math.sqrt(float(xp[0]) ** 2 + float(xp[1]) ** 2 + float(xp[2]) ** 2) > true_dist + 3.0


def test_profile_scenarios_are_listed_and_their_design_file_round_trips(tmp_path):
    import subprocess
    import sys

    from sim_hil.scenarios import SCENARIOS, resolve

    out = subprocess.run([sys.executable, "-m", "sim_hil", "--list-scenarios"], capture_output=True, text=True)
    listed = [line.split()[0] for line in out.stdout.splitlines() if line.strip()]
    for name in ("profile", "profile-fast"):
        assert name in listed
        sc = SCENARIOS[name]
        assert sc.filter == FilterConfig()  # the firmware knows the design, not the truth's profile
        assert (sc.truth.shear_exponent, sc.truth.shear_reference_m, sc.truth.veer_deg_per_100m) == (0.14, 100.0, 10.0)
        assert min(sc.winch.lengths_m) == 30.0 and max(sc.winch.lengths_m) == 150.0
        path = tmp_path / f"{name}.toml"
        path.write_text(sc.to_toml())
        again = resolve("paper-reference", str(path))
        assert (again.design, again.truth, again.winch) == (sc.design, sc.truth, sc.winch)


def test_truth_wind_veers_and_shears_about_the_reference_height():
    from sim_hil.rope import profile_wind

    rad = math.radians(10.0) / 100.0
    wn, we = profile_wind(0.14, 100.0, rad, 100.0, 0.0, 3.0)  # a westerly at the reference: unchanged
    assert (wn, we) == pytest.approx((0.0, 3.0))
    wn, we = profile_wind(0.14, 100.0, rad, 150.0, 0.0, 3.0)
    assert math.hypot(wn, we) == pytest.approx(3.0 * 1.5**0.14)
    frm = math.degrees(math.atan2(-we, -wn)) % 360.0
    assert frm == pytest.approx(275.0)  # veered: from 5 deg further clockwise 50 m higher


@pytest.mark.parametrize("hz", [5e-324, 1e-6])
def test_a_rate_slower_than_one_reading_a_flight_reads_once(hz):
    """Any positive rate the design file allows runs: the winch's and the ground's readings at 1e-6 Hz or at the
    smallest float come once, at the start (5e-324 Hz overflowed the interval's integer before)."""
    w = WinchConfig(times_s=(0.0,), lengths_m=(100.0,), status_hz=hz)
    sim = Simulation(Design(), WindConfig(kind="steady"), TruthConfig(ground_baro_hz=hz), 2.0, 1, winch=w)
    samples = list(sim.samples())
    assert sum(s.winch is not None for s in samples) == 1
    assert sum(s.ground is not None for s in samples) == 1
