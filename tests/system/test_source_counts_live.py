"""The live view gives the counts of each optional source as the firmware's summary does: balloon-fw sends them
once a second (NAMED_VALUE_INT), balloon-gs shows ``winch: N used, M rejected``."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from firmware_py.app import Firmware
from ground_station.listen import GroundStation
from sim_hil.packets import SensorPacketEncoder
from sim_hil.scenarios import SCENARIOS
from sim_hil.simulator import Simulation
from tests.system.test_wind_messages import Sink


def test_the_live_view_shows_what_the_firmware_made_of_the_winch():
    sc = SCENARIOS["profile-fast"]
    sim = Simulation(sc.design, sc.wind, sc.truth, 40.0, 4, winch=sc.winch)
    sink = Sink()
    fw = Firmware(sc.design, sc.filter, sink=sink)
    enc = SensorPacketEncoder()
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    for s in sim.samples():
        for frame in enc.encode(s):
            for m in mav.parse_buffer(frame) or []:
                fw.handle(m)
    fw.flush()
    counts = [m for _, m in sink.of("NAMED_VALUE_INT")]
    assert counts, "no counts sent"
    last = {str(m.name).rstrip("\x00"): m.value for m in counts[-4:]}
    # sent once a second: the last report is at most a second of WINCH_STATUS (10 Hz) behind the end
    assert 0 < last["winch_used"] <= fw.est.winch_samples <= last["winch_used"] + 10
    assert last["winch_rej"] == fw.est.winch_rejected
    assert "gref_used" not in last  # a source never given is not reported
    gs = GroundStation(out=None)
    for _, m in sink.sent:
        gs.handle(m, 100.0)
    line = gs.status_lines(100.0)[0]
    assert f"winch: {last['winch_used']} used, {last['winch_rej']} rejected" in line, line
