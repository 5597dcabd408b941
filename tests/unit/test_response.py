"""What users judge the estimator on, in CI-sized runs: it follows the wind in the band (gain and
phase along and across the mean wind on a two-axis multisine), it beats the constant true mean, its
reported accuracy matches its error; and the two IMU messages a simulator may send give the same
estimate bit for bit."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.config import Design
from balloon_core.score import describe, response, score
from firmware_py.app import Firmware
from firmware_py.estimator.control import Estimator
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from tests.helpers.flights import feed, stream

LINES_HZ = SCENARIOS["multisine-2d"].wind.multisine_hz


@pytest.fixture(scope="module")
def multisine_2d():
    samples, truth = stream("multisine-2d", 400.0, 21)
    est = Estimator(Design(), SCENARIOS["multisine-2d"].filter)
    rows = feed(est, samples, record=True)
    return rows, truth


@pytest.mark.slow
def test_two_axis_multisine_gain_and_phase_along_and_across(multisine_2d):
    """|H - 1| <= 0.35 at 0.02 and 0.05 Hz on both axes (0.4 at 0.1 Hz along): a delayed copy of
    the truth by the old filter's 4 s would score 0.49 and 1.18 at 0.02 and 0.05 Hz; a constant 1."""
    rows, truth = multisine_2d
    h = response(rows[:, 0], rows[:, 1], rows[:, 2], truth["time_s"], truth["wind_n"], truth["wind_e"],
                 (0.02, 0.05, 0.1), start_s=100.0, extra_hz=LINES_HZ)  # fmt: skip
    for f, bound in ((0.02, 0.35), (0.05, 0.35)):
        for axis in ("along", "cross"):
            gain, phase, err = describe(h[f][axis])
            assert err <= bound, (f, axis, gain, phase)
            assert abs(phase) < 25.0, (f, axis, gain, phase)
    assert describe(h[0.1]["along"])[2] <= 0.45


@pytest.mark.slow
def test_skill_against_the_constant_true_mean_and_honest_accuracy(multisine_2d):
    rows, truth = multisine_2d
    s = score(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], truth["time_s"], truth["wind_n"], truth["wind_e"],
              start_s=100.0)  # fmt: skip
    assert s.band_skill >= 0.6  # the constant scores 0, the old filter 0.41
    # cautious: the ascent's drag scale is stated to 7 % (test_estimator), and the attitude's slow error about the
    # field's axis is counted as correlated; 0.53 before the alignment's column about that axis, 0.475 with it (the
    # error fell 8 %, the stated accuracy rose 2 %)
    assert 0.45 <= s.error_ratio <= 1.5
    assert abs(s.speed_error_pct) <= 3.0 and abs(s.direction_error_deg) <= 2.0


def _wind_covs(samples, hil: bool) -> list[tuple]:
    """Run the firmware on the samples sent as HIGHRES_IMU or as HIL_SENSOR frames; decoded WIND_COV."""
    enc = SensorPacketEncoder()
    frames = []

    class Sink:
        def send(self, frame):
            frames.append(frame)

    fw = Firmware(Design(), sink=Sink())
    parser = mavlink.MAVLink(None)
    for s in samples:
        for frame in enc.encode(s):
            msg = parser.parse_char(frame)
            if hil and msg.get_type() == "HIGHRES_IMU":
                m = msg
                msg = mavlink.MAVLink_hil_sensor_message(
                    m.time_usec, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro, m.xmag, m.ymag, m.zmag,
                    m.abs_pressure, m.diff_pressure, m.pressure_alt, m.temperature, m.fields_updated, 0,
                )  # fmt: skip
            fw.handle(msg)
    out = mavlink.MAVLink(None)
    return [m.get_msgbuf() for f in frames if (m := out.parse_char(f)).get_type() == "WIND_COV"]  # wire bytes


def test_hil_sensor_gives_the_same_estimate_bit_for_bit():
    samples, _ = stream("paper-reference", 300.0, 11)
    a = _wind_covs(samples[:3000], hil=False)
    b = _wind_covs(samples[:3000], hil=True)
    assert len(a) > 250 and a == b
    last = mavlink.MAVLink(None).parse_char(a[-1])
    assert np.isfinite(last.wind_x) and last.horiz_accuracy < 2.0  # a real estimate by 30 s


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_launch_is_honest(seed):
    """From the release to the first minute on the tether the reported accuracy covers the error:
    at most 5 % of the estimates off by more than 3 sigma (the previous filter: 20-37 %), and the
    first 5 s (on the ground station, nothing known of the wind) never claim to know it."""
    samples, truth = stream("paper-reference", 300.0, seed)
    rows = feed(Estimator(Design(), SCENARIOS["paper-reference"].filter), samples[:9000], record=True)
    t = rows[:, 0]
    err = np.hypot(rows[:, 1] - truth["wind_n"][:9000], rows[:, 2] - truth["wind_e"][:9000])
    launch = (t >= 5.0) & (t < 60.0)
    assert np.mean(err[launch] > 3.0 * rows[launch, 3]) <= 0.05
    assert np.all(rows[t < 5.0, 3] > 3.0)
