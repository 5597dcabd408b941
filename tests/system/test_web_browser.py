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

    def __init__(self, browser, url: str, width: int = 1280, timezone: str | None = None) -> None:
        self.page = browser.new_page(viewport={"width": width, "height": 900}, timezone_id=timezone)
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


def own_errors(page) -> list[str]:
    """The page's console errors but those of the refused connections while the server was down (the browser's)."""
    return [e for e in page.errors if "WebSocket" not in e and "ERR_CONNECTION_REFUSED" not in e]


def restarted(page, srv: WebServer, udp_port: int) -> tuple[WebServer, int]:
    """``srv`` stopped while the page watches, which says DISCONNECTED; a new server on the same HTTP port, and the
    page live on it again; and the old server's exit code."""
    http_port = srv.port
    code, _ = srv.stop(signal.SIGTERM)
    assert wait_until(lambda: "DISCONNECTED" in page.page.locator("#page-banner").inner_text(), 5.0)
    new = WebServer(f"udpin:127.0.0.1:{udp_port}", port=http_port)
    assert wait_until(lambda: page.page.locator("#conn").inner_text() == "live", 10.0)
    return new, code


def test_the_page_reconnects_after_the_server_restarts(browser):
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=2)])
    feed.start()
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector('article[data-sysid="2"] [data-k="state"]:text("OK")', timeout=15000)
        srv, code = restarted(page, srv, port)
        assert code == 0
        page.page.wait_for_selector('article[data-sysid="2"] [data-k="state"]:text("OK")', timeout=10000)
        assert not page.page.locator("#page-banner").is_visible()
        assert not own_errors(page), page.errors
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


def test_a_restarted_server_replaces_what_the_page_shows(browser):
    """After a restart the page holds what the new server knows: a balloon it has not heard of leaves the page
    (it is not left frozen as OK), the others go on."""
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=2), Balloon(sysid=3, n=-1.0)])
    feed.start()
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector('article[data-sysid="3"] [data-k="state"]:text("OK")', timeout=15000)
        feed.stop.set()
        feed.join(5)
        srv, _ = restarted(page, srv, port)  # no balloon yet
        assert wait_until(lambda: page.page.locator("article.card").count() == 0, 3.0)
        assert page.page.locator("#waiting").is_visible()
        feed = Feed(port, [Balloon(sysid=2)])  # one of them comes back
        feed.start()
        page.page.wait_for_selector('article[data-sysid="2"] [data-k="state"]:text("OK")', timeout=10000)
        assert page.page.locator('article[data-sysid="3"]').count() == 0
        assert not page.page.locator("#waiting").is_visible()
        assert not own_errors(page), page.errors
    finally:
        feed.stop.set()
        page.close()
        srv.stop(signal.SIGTERM)


def test_north_east_variability_and_the_means_clock_on_the_card(browser):
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=5, n=2.5, e=-1.25, wobble_mps=0.0)])
    feed.start()
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector('article[data-sysid="5"] [data-k="state"]:text("OK")', timeout=15000)
        assert wait_until(lambda: (page.text(5, "n"), page.text(5, "e")) == ("+2.50", "-1.25"), 5.0), (
            page.text(5, "n"), page.text(5, "e"))
        assert page.text(5, "var") == "0.20"  # the feed's var_horiz
        assert wait_until(lambda: "of flight (the balloon's clock)" in page.text(5, "m2"), 5.0), page.text(5, "m2")
        assert not page.errors, page.errors
    finally:
        feed.stop.set()
        page.close()
        srv.stop(signal.SIGTERM)


def hover_time(page: Page, chart: str) -> tuple[str, str]:
    """(label, value) of the time in a product chart's legend with the cursor in the middle of the chart."""
    box = page.page.locator(f"#product {chart} .u-over").bounding_box()
    page.page.mouse.move(box["x"] + 0.5 * box["width"], box["y"] + 0.5 * box["height"])
    row = page.page.locator(f"#product {chart} .u-legend tr.u-series").first
    return row.locator(".u-label").inner_text(), row.locator(".u-value").inner_text()


def test_a_products_time_is_the_sensor_clock_or_utc_never_the_browsers_zone(browser, tmp_path):
    """A simulated flight's product (sensor clock, no date): seconds since boot, not 1970. A product with GPS time:
    UTC, also in a browser whose zone is not (Asia/Kolkata is UTC+05:30)."""
    from tests.system.test_web import UTC_START_S, utc_product

    srv = WebServer("--product", str(write_product(tmp_path / "flight.nc")))
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector("#product .pc-speed .u-over", timeout=15000)
        label, value = hover_time(page, ".pc-speed")
        assert "since boot" in label and "UTC" not in label.replace("not UTC", ""), label
        assert "1970" not in value and 0.0 <= float(value.replace(",", "")) <= 1200.0, value
        assert not page.errors, page.errors
    finally:
        page.close()
        srv.stop(signal.SIGTERM)
    assert UTC_START_S == 1_767_225_600.0  # 2026-01-01 00:00 UTC: the 20 minutes are 12:00am-12:20am there
    srv = WebServer("--product", str(utc_product(tmp_path / "utc.nc")))
    page = Page(browser, srv.url, timezone="Asia/Kolkata")
    try:
        page.page.wait_for_selector("#product .pc-speed .u-over", timeout=15000)
        label, value = hover_time(page, ".pc-speed")
        assert "UTC" in label, label
        assert re.fullmatch(r"2026-01-01 12:[01]\dam", value), value  # not 5:40am, the browser's local time
        assert not page.errors, page.errors
    finally:
        page.close()
        srv.stop(signal.SIGTERM)


def test_a_profile_bin_without_a_direction_is_a_gap(browser, tmp_path):
    """A product's profile with a bin whose direction is NaN (its speed known): drawn with a gap there, no error."""
    import netCDF4

    from postflight.profile import QC_FEW_SAMPLES

    product = write_product(tmp_path / "flight.nc")
    with netCDF4.Dataset(product.with_name("flight_profile.nc"), "a") as nc:
        drawn = [j for j, q in enumerate(nc["qc_profile"][:]) if not int(q) & QC_FEW_SAMPLES]
        nc["wind_from_direction"][drawn[2]] = math.nan  # a bin in the middle of the first leg
    srv = WebServer("--product", str(product))
    page = Page(browser, srv.url)
    try:
        page.page.wait_for_selector("#product .profile:not(.hidden) .p-speed svg circle", timeout=15000)
        page.page.wait_for_timeout(500)
        speed = page.page.locator("#product .p-speed svg circle").count()
        assert speed == len(drawn) and page.page.locator("#product .p-from svg circle").count() == speed - 1
        assert not page.errors, page.errors
    finally:
        page.close()
        srv.stop(signal.SIGTERM)
