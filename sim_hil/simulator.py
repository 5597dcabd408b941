"""The truth simulation loop: wind -> 6-DOF balloon (RK4 at ``physics_hz``) -> sensors at their rates.

``Simulation.samples()`` yields one ``SensorSample`` per IMU period and fills the truth table as it
goes; what is done with the samples (tlog, UDP, tests) is the caller's business.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from balloon_core.atmosphere import G0
from balloon_core.config import Design
from balloon_core.rotation import euler_from_quat
from sim_hil import native
from sim_hil.dynamics import (
    BalloonPhysics,
    TruthConfig,
    derivative,
    lever_arm_accel_b,
    resting_state,
    rk4_step,
)
from sim_hil.rope import anchor_tension_n, profile_wind, rope_airborne, shear_factor
from sim_hil.sensors import SensorSuite
from sim_hil.winch import WinchConfig, line_length_m, load_cell_kg, status_flags
from sim_hil.wind import WindConfig, WindSeries, WindStream, wind_source

TRUTH_COLUMNS = (
    "time_s", "wind_n", "wind_e", "wind_d", "pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d",
    "roll_deg", "pitch_deg", "yaw_deg", "tether_taut", "tension_n", "height_m", "line_length_m",
    "anchor_tension_n",
)  # fmt: skip
CHUNK_STEPS = 4000
TRUTH_CHUNK_ROWS = 6000  # truth rows handed to the sink at a time (keep_truth=False): one minute at 100 Hz


# a state beyond these is not a balloon any more: the explicit integration has gone unstable (NaN fails too)
MAX_SPEED_MPS = 1000.0
MAX_HEIGHT_M = 20000.0
MAX_RATE_RPS = 1000.0


def _every(imu_hz: float, rate_hz: float, n_imu: int) -> int:
    """IMU samples between two readings at ``rate_hz`` (> 0): at least 1, at most the flight's length + 1 (a rate
    slower than one reading a flight reads once, at the start; 1e-300 Hz does not overflow)."""
    return max(1, min(round(min(imu_hz / rate_hz, n_imu + 1.0)), n_imu + 1))


def rope_steps_per_imu(physics: BalloonPhysics, winch: WinchConfig | None, imu_hz: float) -> int:
    """The physics steps per IMU sample the lumped rope needs to be integrated at all (``LumpedRope.stable_step_s``)
    at the shortest line it flies (the winch's, else the tether's): a stiff rope (a high-modulus fibre's EA is
    hundreds of kN) or a short line of many segments needs more than [truth] physics_hz. 1 without a lumped rope.
    ``winch``: the enabled winch, or None."""
    if physics.rope is None:
        return 1
    shortest = min(winch.lengths_m) if winch is not None and winch.lengths_m else None
    rope = physics.rope.at_length(shortest, 0.0) if shortest else physics.rope
    return max(1, math.ceil(1.0 / (rope.stable_step_s() * imu_hz) - 1e-9))


class SimulationDiverged(ValueError):
    """The truth integration blew up: the design is too stiff for the physics step (a user error)."""


@dataclass(frozen=True)
class SensorSample:
    time_usec: int
    accel: tuple[float, float, float]
    gyro: tuple[float, float, float]
    mag: tuple[float, float, float]
    baro: tuple[float, float] | None  # (hPa, degC) when a new barometer sample is due
    # the winch's report when one is due: (paid-out length m, speed m/s, load cell kg or NaN, status flags)
    winch: tuple[float, float, float, int] | None = None
    ground: tuple[float, float] | None = None  # the ground reference (hPa, degC) when one is due


class Simulation:
    def __init__(
        self,
        design: Design,
        wind: WindConfig,
        truth: TruthConfig,
        duration_s: float,
        seed: int,
        imu_hz: float = 100.0,
        baro_hz: float = 20.0,
        wind_series: WindSeries | WindStream | None = None,
        keep_truth: bool = True,
        truth_sink: Callable[[np.ndarray], None] | None = None,
        winch: WinchConfig | None = None,
        reference: bool = False,
    ) -> None:
        """``keep_truth``: the whole flight's truth table in ``self.truth`` (memory grows with the
        duration); otherwise it is handed to ``truth_sink`` in chunks of rows and not kept.
        ``reference``: integrate with the Python functions (dynamics.py, rope.py) even where their
        compiled twin (sim_hil/native.py, the default when it builds) is available."""
        if not (0.0 < duration_s < math.inf):
            raise ValueError(f"duration must be finite and > 0, got {duration_s}")
        self.design, self.truth_cfg = design, truth
        self.physics = BalloonPhysics.from_design(design, truth)
        self.winch = winch if winch is not None and winch.enabled else None
        # [truth] physics_hz, or finer where the lumped rope needs it (its shortest line is its stiffest)
        rope_spi = rope_steps_per_imu(self.physics, self.winch, imu_hz)
        self.steps_per_imu = max(1, round(truth.physics_hz / imu_hz), rope_spi)
        self.h = 1.0 / (imu_hz * self.steps_per_imu)
        self.baro_every = max(1, round(imu_hz / baro_hz))
        self.n_imu = int(round(duration_s * imu_hz))
        self.imu_hz = imu_hz
        self.wind = wind_series or wind_source(
            wind, duration_s + 1.0, seed, 2.0 * design.balloon.radius_m if truth.spatial_filter else 0.0
        )
        self.sensors = SensorSuite(design, truth, imu_hz, seed)
        self._state = resting_state(self.physics, math.radians(truth.initial_yaw_deg))
        self.native = not reference and native.available()
        self._stepper: native.NativeStepper | None = None
        self.keep_truth = keep_truth
        self.truth_sink = truth_sink
        rows = self.n_imu if keep_truth else min(self.n_imu, TRUTH_CHUNK_ROWS)
        self.truth = np.zeros((rows, len(TRUTH_COLUMNS)))
        self._truth_base = 0  # flight row index of self.truth[0]
        self._truth_rows = 0  # rows filled so far (whole flight)
        self.samples_done = 0  # IMU samples yielded so far
        self.winch_every = _every(imu_hz, self.winch.status_hz, self.n_imu) if self.winch else 0
        self.ground_every = _every(imu_hz, truth.ground_baro_hz, self.n_imu) if truth.ground_baro_hz > 0.0 else 0
        # the winch's load cell and the ground barometer draw from their own streams: the flight's other
        # sensors stay the same with them or without
        self._aux_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x47524E44]))

    def flush_truth(self) -> None:
        """Hand the truth rows not yet handed over to the sink (streaming mode; idempotent)."""
        if self.keep_truth:
            if self.truth_sink is not None and self._truth_rows > self._truth_base:
                self.truth_sink(self.truth[self._truth_base : self._truth_rows])
                self._truth_base = self._truth_rows
            return
        k = self._truth_rows - self._truth_base
        if k > 0 and self.truth_sink is not None:
            self.truth_sink(self.truth[:k])
        self._truth_base = self._truth_rows

    @property
    def state(self) -> list[float]:
        """The truth's state (dynamics.resting_state's layout) after the last physics step done."""
        return self._stepper.s.tolist() if self._stepper is not None else self._state

    def _wind_chunk(self, step0: int, n: int) -> np.ndarray:
        """Wind (n, e, d, dn, de, dd) at physics half-steps step0*h ... (step0+n)*h."""
        t = (step0 + np.arange(2 * n + 1) * 0.5) * self.h
        dt = self.wind.dt_s
        i0 = int(t[0] / dt)
        ned, rate = self.wind.window(i0, int(math.ceil(t[-1] / dt)) + 1)
        grid = (i0 + np.arange(len(ned))) * dt
        cols = [np.interp(t, grid, ned[:, k]) for k in range(3)]
        cols += [np.interp(t, grid, rate[:, k]) for k in range(3)]
        return np.column_stack(cols)

    def samples(self) -> Iterator[SensorSample]:
        ph = self.physics
        h = self.h
        release_step = int(round(self.truth_cfg.release_s / h))
        s = self._state
        spi = self.steps_per_imu
        n_steps = self.n_imu * spi
        truth = self.truth
        chunk_rows = len(truth)
        keep = self.keep_truth
        zero = [0.0] * 13
        baro_every = self.baro_every
        d = ph.imu_offset_m  # avionics (IMU, barometer) this far below the centre along body z
        base = ph
        winch = self.winch
        paid = (ph.tether_length_m, 0.0)
        if winch is not None:
            paid = line_length_m(winch, 0.0)
            ph = base.at_length(*paid)
        aux = self._aux_rng
        # the accelerometer's specific force: the mean acceleration over the sample interval (the change of
        # velocity, as a real IMU integrates and low-passes), not the derivative at the sample instant. A
        # stiff rope's fastest modes sampled at one instant per IMU interval alias, to DC when the physics
        # step is half the IMU's: 1.2 m/s^2 of false vertical acceleration on a 54 m rope of 12 segments
        v_prev: tuple[float, float, float] | None = None
        dt_imu = spi * h
        stepper = self._stepper = native.NativeStepper(ph, s) if self.native else None
        skip = 0  # physics steps already done by the C stepper (a whole IMU period in one call)
        for c0 in range(0, n_steps, CHUNK_STEPS):
            n = min(CHUNK_STEPS, n_steps - c0)
            wind_rows = self._wind_chunk(c0, n)
            wind = wind_rows.tolist()
            if stepper is not None:
                stepper.set_wind(wind_rows)
            for j in range(n):
                if skip:
                    skip -= 1
                    continue
                step = c0 + j
                w0 = wind[2 * j]
                if winch is not None:
                    now = line_length_m(winch, step * h)
                    if now != paid:
                        paid = now
                        ph = base.at_length(*paid)
                        if stepper is not None:
                            stepper.set_physics(ph)
                held = step < release_step
                at_imu = step % spi == 0
                rope_now = None  # (anchor tension, airborne) when the C step gave them
                if stepper is not None:  # k1 and the step in one call: the state before it kept for the IMU
                    if held:
                        k1, tension = zero, 0.0
                        if at_imu:
                            s = stepper.s.tolist()
                    elif at_imu:
                        if winch is None and spi > 1 and j + spi <= n:  # the physics stay: the whole period
                            tension = stepper.steps_keep(h, j, spi)
                            skip = spi - 1
                        else:
                            tension = stepper.step_keep(h, j)
                        s = stepper.pre.tolist()  # the state, then the rope's anchor tension and airborne flag
                        k1 = stepper.k1[:13].tolist()
                        if ph.rope is not None:
                            rope_now = s[-2], s[-1] != 0.0
                    else:
                        stepper.step(h, j)
                elif held:
                    k1, tension = zero, 0.0
                else:
                    k1, tension = derivative(s, *w0, ph)
                if at_imu:
                    i = step // spi
                    if not (abs(s[3]) + abs(s[4]) + abs(s[5]) < MAX_SPEED_MPS and -s[2] < MAX_HEIGHT_M
                            and abs(s[10]) + abs(s[11]) + abs(s[12]) < MAX_RATE_RPS):  # fmt: skip
                        raise SimulationDiverged(
                            f"the simulation diverged at t = {step * h:.2f} s (speed, height or spin beyond "
                            f"any balloon's): this design's rope stiffness or damping needs a finer physics step "
                            f"([truth] physics_hz, now {self.truth_cfg.physics_hz:g})"
                        )
                    if v_prev is None:
                        f_ned = (k1[3], k1[4], k1[5] - G0)
                    else:
                        f_ned = ((s[3] - v_prev[0]) / dt_imu, (s[4] - v_prev[1]) / dt_imu,
                                 (s[5] - v_prev[2]) / dt_imu - G0)  # fmt: skip
                    v_prev = (s[3], s[4], s[5])
                    height = -s[2]
                    if d:
                        lever = lever_arm_accel_b(s[10], s[11], s[12], k1[10], k1[11], k1[12], 0.0, 0.0, d)
                        q0, q1, q2, q3 = s[6:10]
                        sensor_height = height - d * (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
                        acc, gyro, mag = self.sensors.imu(f_ned, (s[10], s[11], s[12]), s[6:10], lever, sensor_height,
                                                            step * h)
                    else:
                        sensor_height = height
                        acc, gyro, mag = self.sensors.imu(f_ned, (s[10], s[11], s[12]), s[6:10], None, sensor_height,
                                                            step * h)
                    baro = self.sensors.baro(sensor_height, step * h) if i % baro_every == 0 else None
                    roll, pitch, yaw = euler_from_quat(*s[6:10])
                    if ph.veer_rad_m:
                        wtn, wte = profile_wind(ph.shear_exponent, ph.shear_reference_m, ph.veer_rad_m, height,
                                                w0[0], w0[1])  # fmt: skip
                    else:
                        sf = shear_factor(ph.shear_exponent, ph.shear_reference_m, height)
                        wtn, wte = sf * w0[0], sf * w0[1]
                    if ph.rope is None:
                        taut, anchor = tension > 0.0, tension
                    elif rope_now is not None:
                        taut, anchor = tension > 0.0 and rope_now[1], rope_now[0]
                    else:
                        taut = tension > 0.0 and rope_airborne(ph.rope, s[13:])
                        anchor = anchor_tension_n(ph.rope, s[13:])
                    if not keep and i - self._truth_base == chunk_rows:
                        self.flush_truth()
                    truth[i - self._truth_base if not keep else i] = (
                        step * h, wtn, wte, w0[2], s[0], s[1], s[2], s[3], s[4], s[5],
                        math.degrees(roll), math.degrees(pitch), math.degrees(yaw),
                        1.0 if taut else 0.0, tension, height, paid[0], anchor,
                    )  # fmt: skip
                    self._truth_rows = i + 1
                    self.samples_done = i + 1
                    report = None
                    if winch is not None and i % self.winch_every == 0:
                        kg = load_cell_kg(anchor, float(aux.standard_normal()), winch)
                        report = (paid[0], paid[1], kg, status_flags(paid[1]))
                    ground = None
                    if self.ground_every and i % self.ground_every == 0:
                        ground = self._ground_reading(step * h, aux)
                    yield SensorSample(round(step * h * 1e6), acc, gyro, mag, baro, report, ground)
                if stepper is None:
                    if not held:
                        s = rk4_step(s, h, w0, wind[2 * j + 1], wind[2 * j + 2], ph, k1)
                    self._state = s

    def _ground_reading(self, time_s: float, rng: np.random.Generator) -> tuple[float, float]:
        """The ground reference at the anchor: the weather's ground pressure and temperature (the truth's
        drift) plus the ground barometer's and thermometer's noise, (hPa, degC)."""
        p0, t0 = self.sensors.ground(time_s)
        tc = self.truth_cfg
        n = rng.standard_normal(2)
        return p0 / 100.0 + tc.ground_baro_hpa * float(n[0]), t0 - 273.15 + tc.ground_thermometer_k * float(n[1])

    def run(self) -> int:
        """Run the whole flight, discarding the sensor samples; returns their count."""
        n = sum(1 for _ in self.samples())
        self.flush_truth()
        return n


class TruthCsvWriter:
    """The truth CSV written as the rows come (a truth sink): memory does not grow with the flight."""

    def __init__(self, path: str) -> None:
        self.fh = open(path, "w")
        self.fh.write(",".join(TRUTH_COLUMNS) + "\n")

    def __call__(self, rows: np.ndarray) -> None:
        np.savetxt(self.fh, rows, delimiter=",", fmt="%.6f")

    def close(self) -> None:
        self.fh.close()


def write_truth_csv(path: str, truth: np.ndarray) -> None:
    np.savetxt(path, truth, delimiter=",", header=",".join(TRUTH_COLUMNS), comments="", fmt="%.6f")
