"""Contract audit (docs: /work/shared/CONTRACT.md), the parts a black-box check reads without the project's own
tools: ``balloon-gs web`` shows each system id's speed and the direction the wind comes FROM, and a stale state,
in words on the page as served (a reader or a checker without the page's script sees them too)."""

from __future__ import annotations

import html
import math
import re
import socket
import time
import urllib.request

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack
from tests.helpers.web import WebServer, free_udp_port, wait_until

STALE_AFTER_S = 2.0  # the contract's "a stale state in words when a balloon's link goes quiet" (listen's STALE_S)


def _page_text(url: str) -> str:
    """The served page's text as a reader without the script gets it: tags dropped, entities decoded."""
    with urllib.request.urlopen(url, timeout=5) as r:
        body = r.read().decode("utf-8")
    return html.unescape(re.sub(r"<[^>]+>", " ", body))


def _page_with(url: str, words: str, times: int) -> str | None:
    text = _page_text(url)
    return text if text.count(words) >= times else None


@pytest.mark.network
def test_web_page_as_served_shows_speed_from_direction_and_stale_in_words():
    udp = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{udp}")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    # sys 1: air toward the east, a wind FROM 270 deg; sys 3: air toward the north-west, FROM 135 deg
    winds = {1: (0.0, 3.0), 3: (2.0, -2.0)}
    mavs = {s: mavlink.MAVLink(None, srcSystem=s, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1) for s in winds}
    try:
        for k in range(1, 21):
            for s, (n, e) in winds.items():
                m = mavs[s]
                frame = pack(m, m.wind_cov_encode(k * 100_000, n, e, math.nan, math.nan, math.nan, 100.0, 0.3, 0.0))
                sock.sendto(frame, ("127.0.0.1", udp))
            time.sleep(0.02)
        text = wait_until(lambda: _page_with(srv.url, "Balloon sys 3", 1), 5.0)
        assert text, _page_text(srv.url)
        assert "Balloon sys 1: 3.00 m/s from 270°" in text, text
        assert "Balloon sys 3: 2.83 m/s from 135°" in text, text
        # the link goes quiet: the state in words
        stale = wait_until(lambda: _page_with(srv.url, "STALE: no WIND_COV", 2), STALE_AFTER_S + 5.0)
        assert stale, _page_text(srv.url)
    finally:
        sock.close()
        srv.stop()
