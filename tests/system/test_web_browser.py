"""``balloon-gs web`` in a real browser (Debian's chromium through Playwright; skipped without it): the page
loads with no console error and asks no other host for anything; it shows each balloon's speed and
direction as the last WIND_COV sent (two system ids); SENSORS LOST within 3 s of the sensors going silent;
STALE when the link dies; it reconnects after the server restarts; it fits a phone's width; a product's
causal and smoothed wind and its profiles."""

from __future__ import annotations

import math
import re
import signal
import time

import pytest

from tests.helpers.web import WebServer, free_udp_port, have_browser, launch_chromium, wait_until, write_product
from tools.web_feed import Balloon, Feed

pytestmark = [pytest.mark.network, pytest.mark.skipif(not have_browser(), reason="no /usr/bin/chromium or playwright")]

SENSORS_LOST_WITHIN_S = 3.0  # the brief: the banner within 3 s of the sensors going silent
STALE_WITHIN_S = 2.0 + 3.0  # listen's STALE_S, and the same 3 s


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = launch_chromium(p)
        yield b
        b.close()


class Page:
    """A page on the server, with its console errors and every request it made."""

    def __init__(self, browser, url: str, width: int = 1280) -> None:
        self.page = browser.new_page(viewport={"width": width, "height": 900})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(url)

    def text(self, sysid: int, key: str) -> str:
        return self.page.locator(f'article[data-sysid="{sysid}"] [data-k="{key}"]').inner_text()

    def close(self) -> None:
        self.page.close()


def shown_matches(page: Page, sysid: int, n: float, e: float) -> bool:
    """The page's speed and direction are this wind's, within their display rounding (0.01 m/s, 1 deg)."""
    speed, frm = math.hypot(n, e), math.degrees(math.atan2(-e, -n)) % 360.0
    try:
        s, d = float(page.text(sysid, "speed")), float(page.text(sysid, "from"))
    except ValueError:
        return False
    return abs(s - speed) <= 0.005 + 1e-6 and abs((d - frm + 180.0) % 360.0 - 180.0) <= 0.5 + 1e-6


def test_two_balloons_shown_as_sent_then_sensors_lost_then_stale(browser):
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=4, n=3.2, e=-1.1), Balloon(sysid=11, n=-2.0, e=4.5, wobble_mps=0.6)])
    feed.start()
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector('article[data-sysid="11"] [data-k="state"]:text("OK")', timeout=15000)
        assert page.page.locator("#conn").inner_text() == "live"
        # the wind as the last WIND_COV sent: freeze the feed's values by stopping it, then compare
        feed.set(4, silent=True)
        feed.set(11, silent=True)
        time.sleep(0.5)
        for sysid in (4, 11):
            n, e, _ = feed.last(sysid)
            assert wait_until(lambda s=sysid, n=n, e=e: shown_matches(page, s, n, e), 3.0), (
                sysid, page.text(sysid, "speed"), page.text(sysid, "from"), feed.last(sysid))
        feed.set(4, silent=False)
        feed.set(11, silent=False)
        page.page.wait_for_selector('article[data-sysid="4"] [data-k="state"]:text("OK")', timeout=10000)
        # the sensors go silent: balloon-fw's SYS_STATUS clears every health bit, the gyro's too
        t0 = time.monotonic()
        feed.set(4, sensors_lost=True)
        banner = page.page.locator('article[data-sysid="4"] [data-k="banner"]')
        assert wait_until(lambda: "SENSORS LOST" in banner.inner_text(), SENSORS_LOST_WITHIN_S + 1.0, 0.05)
        assert time.monotonic() - t0 <= SENSORS_LOST_WITHIN_S
        assert page.text(11, "state") == "OK"  # the other balloon is not concerned
        # the link dies: nothing more from sysid 11
        t0 = time.monotonic()
        feed.set(11, silent=True)
        banner11 = page.page.locator('article[data-sysid="11"] [data-k="banner"]')
        assert wait_until(lambda: "STALE" in banner11.inner_text(), STALE_WITHIN_S + 1.0, 0.1)
        assert time.monotonic() - t0 <= STALE_WITHIN_S
        assert page.text(11, "state").startswith("STALE")
        # the 10-minute means and the gust are on the page, as numbers (the gust once a whole 3 s window of
        # samples is in: waited for, never timed)
        assert wait_until(lambda: re.match(r"\d+\.\d\d m/s from \d{3}°", page.text(4, "m10")), 10.0, 0.1)
        assert wait_until(lambda: re.match(r"\d+\.\d\d m/s", page.text(4, "gust")), 10.0, 0.1), page.text(4, "gust")
        assert not page.errors, page.errors
        assert all(u.startswith(srv.url) or u.startswith("data:") for u in page.requests), page.requests
    finally:
        feed.stop.set()
        page.close()
        srv.stop(signal.SIGTERM)


def test_the_page_reconnects_after_the_server_restarts(browser):
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=2)])
    feed.start()
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector('article[data-sysid="2"] [data-k="state"]:text("OK")', timeout=15000)
        http_port = srv.port
        code, _ = srv.stop(signal.SIGTERM)
        assert code == 0
        banner = page.page.locator("#page-banner")
        assert wait_until(lambda: "DISCONNECTED" in banner.inner_text(), 5.0)
        srv = WebServer(f"udpin:127.0.0.1:{port}", port=http_port)
        assert wait_until(lambda: page.page.locator("#conn").inner_text() == "live", 10.0)
        page.page.wait_for_selector('article[data-sysid="2"] [data-k="state"]:text("OK")', timeout=10000)
        assert not banner.is_visible()
        # a console error for the refused connections while the server was down is the browser's, not the page's
        assert not [e for e in page.errors if "WebSocket" not in e and "ERR_CONNECTION_REFUSED" not in e], page.errors
    finally:
        feed.stop.set()
        page.close()
        srv.stop(signal.SIGTERM)


def test_phone_width_and_a_winched_profile(browser):
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=1), Balloon(sysid=2, n=-3.0, e=1.0)], winch=True)
    feed.start()
    page = Page(browser, srv.url, width=375)
    try:
        page.page.wait_for_selector('article[data-sysid="2"] .profile:not(.hidden) svg circle', timeout=15000)
        width = page.page.evaluate("document.documentElement.scrollWidth")
        assert width <= 375, width  # no sideways scrolling on a phone
        # both boxes in one layout (the page is live: measured one after the other, the first may have changed)
        top1, bottom0 = page.page.evaluate(
            """() => {
                const r = [1, 2].map(s => document.querySelector(`article[data-sysid="${s}"]`).getBoundingClientRect());
                return [r[1].top, r[0].bottom];
            }"""
        )
        assert top1 >= bottom0 - 0.5, (top1, bottom0)  # one column
        assert "leg 1 up" in page.page.locator('article[data-sysid="1"] .profile h3').inner_text()
        assert "winch:" in page.page.locator("#winch").inner_text()
        assert not page.errors, page.errors
    finally:
        feed.stop.set()
        page.close()
        srv.stop(signal.SIGTERM)


def test_a_product_shows_causal_and_smoothed_wind_and_its_profiles(browser, tmp_path):
    product = write_product(tmp_path / "flight.nc")
    srv = WebServer("--product", str(product))
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector("#product .profile:not(.hidden) svg circle", timeout=15000)
        text = page.page.locator("#product").inner_text()
        assert "flight.nc" in text and "smoothed" in text and "causal" in text
        assert page.page.locator("#product .uplot").count() == 2
        assert "leg 2 down" in page.page.locator("#product .profile h3").inner_text()
        assert not page.errors, page.errors
    finally:
        page.close()
        srv.stop(signal.SIGTERM)
