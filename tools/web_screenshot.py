"""The README's picture of ``balloon-gs web`` (docs/web.png): three scripted balloons (tools/web_feed.py) on a
winch site, one flying well, one whose model misfits (its barometer flagged), one whose sensors went silent,
shown in Debian's chromium after ``--seconds`` of data. Run by ``make docs-figures`` (tools/docs_figures.py).

    .venv/bin/python -m tools.web_screenshot [--out docs/web.png] [--seconds 45]"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tools.web_feed import Balloon, Feed, WebServer, free_udp_port, have_browser, launch_chromium

ROOT = Path(__file__).resolve().parents[1]
VIEWPORT = {"width": 1400, "height": 1000}


def screenshot(out: Path, seconds: float) -> None:
    from playwright.sync_api import sync_playwright

    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=1, n=3.0, e=-1.5), Balloon(sysid=2, n=-2.0, e=3.5, wobble_mps=0.8),
                       Balloon(sysid=3, n=1.0, e=4.0)], winch=True)  # fmt: skip
    feed.start()
    try:
        time.sleep(seconds)
        feed.set(2, misfit=mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE)
        feed.set(3, sensors_lost=True)
        with sync_playwright() as p:
            browser = launch_chromium(p)
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(srv.url)
            page.wait_for_selector('article[data-sysid="3"] [data-k="state"]:text("SENSORS LOST")', timeout=20000)
            page.wait_for_selector('article[data-sysid="1"] .profile:not(.hidden)', timeout=20000)
            time.sleep(1.5)  # the charts' next redraw
            out.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(out), full_page=True)
            browser.close()
    finally:
        feed.stop.set()
        srv.stop(signal.SIGTERM)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "web.png")
    ap.add_argument("--seconds", type=float, default=45.0, help="of data before the picture")
    args = ap.parse_args(argv)
    if not have_browser():
        print("web_screenshot: needs /usr/bin/chromium (apt-get install chromium) and playwright", file=sys.stderr)
        return 2
    screenshot(args.out, args.seconds)
    print(f"web_screenshot: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
