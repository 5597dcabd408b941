"""The browser ground station's model (ground_station/web/live.py) on listen's GroundStation, in process: the
state each balloon shows is listen's (``Vehicle.state``), the snapshot and the updates carry the samples
once each, a winch splits the samples into legs, and every message is strict JSON (no NaN)."""

from __future__ import annotations

import json
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import Decoder, LinkStats, pack
from ground_station.listen import STALE_S, GroundStation, Receiver
from ground_station.web.live import LiveModel
from tools.web_feed import GOOD, SENSORS


class Sender:
    def __init__(self, sysid: int, compid: int = mavlink.MAV_COMP_ID_AUTOPILOT1) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.dec = Decoder(LinkStats())

    def msgs(self, *encoded) -> list:
        return [m for e in encoded for m in self.dec.feed(pack(self.mav, e))]


def feed(model: LiveModel, msgs: list, now: float) -> None:
    for m in msgs:
        if model.gs.handle(m, now):
            model.on_message(m, now)


def balloon_second(s: Sender, t: float, n: float, e: float, health: int = SENSORS, alt: float = 50.0) -> list:
    mav = s.mav
    out = s.msgs(mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, 2, 4),
                 mav.sys_status_encode(SENSORS, SENSORS, health, 0, 0xFFFF, -1, -1, 0, 0, 0, 0, 0, 0),
                 mav.estimator_status_encode(int(t * 1e6), GOOD, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip
    return out + s.msgs(*(mav.wind_cov_encode(int((t + k / 10) * 1e6), n, e, math.nan, 0.2, 0.0, alt, 0.3, 0.0)
                          for k in range(10)))  # fmt: skip


def test_states_samples_and_json_as_listen_sees_them():
    model = LiveModel(GroundStation(out=None))
    a, b = Sender(1), Sender(2)
    for sec in range(5):
        feed(model, balloon_second(a, sec, 3.0, -1.0), 100.0 + sec)
        feed(model, balloon_second(b, sec, -2.0, 2.0, health=0 if sec >= 3 else SENSORS), 100.0 + sec)
    snap = model.snapshot(104.5)
    json.dumps(snap, allow_nan=False)
    one, two = snap["balloons"]
    assert (one["sysid"], two["sysid"]) == (1, 2)
    assert one["state"] == "OK" and two["state"] == "SENSORS LOST" and two["sensors_lost"]
    assert one["speed"] == round(math.hypot(3.0, -1.0), 3)
    assert one["from"] == round(math.degrees(math.atan2(1.0, -3.0)) % 360, 1)
    assert "velocity_horiz" in one["estimator"]
    # the same arrival time for a second's ten samples: one per 0.1 s slot only when they arrive spread out
    assert 1 <= len(one["samples"]) <= 50 and one["received"] == 50
    assert one["stats"]["mean_10min"]["count"] == 50
    up = model.update(104.6)
    assert up["balloons"][0]["samples"] == one["samples"][-len(up["balloons"][0]["samples"]) :]
    assert model.update(104.7)["balloons"][0]["samples"] == []  # sent once
    later = model.update(104.0 + STALE_S + 1.5)
    assert [x["state"] for x in later["balloons"]] == ["STALE", "STALE"]  # listen's rule: no WIND_COV for STALE_S
    assert model.gs.vehicles[1].state(104.0 + STALE_S + 1.5) == "STALE"


def test_a_winch_splits_the_samples_into_legs():
    model = LiveModel(GroundStation(out=None))
    balloon, winch = Sender(1), Sender(250, mavlink.MAV_COMP_ID_WINCH)
    for sec in range(40):
        reel = 1.0 if sec < 20 else -1.0
        length = sec if sec < 20 else 40 - sec
        feed(model, winch.msgs(winch.mav.winch_status_encode(sec * 1_000_000, length, reel, math.nan, math.nan,
                                                             math.nan, 0, 1)), 200.0 + sec)  # fmt: skip
        for k, m in enumerate(balloon_second(balloon, sec, 2.0, 2.0, alt=float(length))):
            feed(model, [m], 200.0 + sec + k * 0.07)
    prof = model.snapshot(240.0)["balloons"][0]["profile"]
    assert [g["ascent"] for g in prof["legs"]] == [True, False]
    assert [r["z"] for r in prof["legs"][0]["rows"]] == [5.0, 15.0]
    rows = [r for g in prof["legs"] for r in g["rows"]]
    assert all(abs(r["from"] - 225.0) < 0.05 and abs(r["speed_err"] - 0.3) < 1e-3 for r in rows)  # float32 fields
    assert model.snapshot(240.0)["winch"]["reel_mps"] == -1.0


@pytest.mark.network
def test_receiver_is_what_listen_runs():
    """``listen`` and ``web`` share one receiver (ground_station.listen.Receiver): a UDP endpoint bound
    here takes a frame into the station."""
    import socket

    gs = GroundStation(out=None)
    seen = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    rx = Receiver(f"udpin:127.0.0.1:{port}", gs, on_message=lambda m, now: seen.append(m.get_type()))
    try:
        s = Sender(5)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(pack(s.mav, s.mav.wind_cov_encode(1, 1.0, 1.0, 0.0, 0.1, 0.1, 10.0, 0.2, 0.0)),
                      ("127.0.0.1", port))  # fmt: skip
        for _ in range(20):
            rx.step(0.1)
            if seen:
                break
    finally:
        rx.close()
    assert seen == ["WIND_COV"] and gs.vehicles[5].wind_count == 1


def test_every_file_the_page_loads_ships_as_package_data():
    """pyproject.toml's package-data globs cover every file under ground_station/web/static (uPlot and its
    licence included): an installed balloon-gs web serves the same page as the checkout."""
    import fnmatch
    import tomllib
    from pathlib import Path

    from ground_station.web.server import STATIC_DIR, static_files

    root = Path(__file__).resolve().parents[2]
    globs = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    web = globs["ground_station.web"]
    files = static_files()
    assert {"index.html", "app.js", "app.css", "vendor/uplot/uPlot.iife.min.js", "vendor/uplot/uPlot.min.css",
            "vendor/uplot/LICENSE"} <= set(files)  # fmt: skip
    for rel in files:
        path = (STATIC_DIR / rel).relative_to(STATIC_DIR.parent).as_posix()
        assert any(fnmatch.fnmatch(path, g) and path.count("/") == g.count("/") for g in web), path


@pytest.mark.parametrize(("text", "want"), [("127.0.0.1:8000", ("127.0.0.1", 8000)), ("[::1]:0", ("::1", 0)),
                                            ("0.0.0.0:65535", ("0.0.0.0", 65535))])  # fmt: skip
def test_bind_is_host_and_port(text, want):
    from balloon_core.userargs import bind

    assert bind(text) == want


@pytest.mark.parametrize("text", ["8000", ":8000", "host:", "host:port", "h:65536", "h:-1"])
def test_a_bad_bind_is_refused(text):
    import argparse

    from balloon_core.userargs import bind

    with pytest.raises(argparse.ArgumentTypeError):
        bind(text)
