"""The browser ground station under load: ``balloon-gs web`` fed 5 balloons at 10 Hz over loopback UDP
(tools/web_feed.py: WIND_COV, and HEARTBEAT + SYS_STATUS + ESTIMATOR_STATUS once a second each) with one page
open in Debian's chromium.

    .venv/bin/python -m benchmarks.bench_web [--duration 600] [--balloons 5] [--rate 10]

Measured over the run (after ``WARMUP_S``): the server's CPU (user + system time of its process / wall time,
% of one core), its peak resident memory (sampled each second), the page's JS heap after a forced garbage
collection (Chrome DevTools Protocol) at the start and the end, and every WIND_COV counted: the server's
received count must equal what was sent. The targets: CPU <= 15 % of a core, RSS <= 150 MB, heap flat, none
lost. The full run is 10 minutes (the charts' window fills); ``tests/system/test_web_load.py`` runs 60 s."""

from __future__ import annotations

import argparse
import signal
import sys
import time
from dataclasses import dataclass

from tools.web_feed import Balloon, Feed, WebServer, free_udp_port, have_browser, launch_chromium, wait_until

WARMUP_S = 5.0
SAMPLE_EVERY_S = 1.0
TARGET_CPU_PCT = 15.0
TARGET_RSS_MB = 150.0
TARGET_HEAP_GROWTH_MB = 10.0  # "flat": what a 10-minute window of 5 balloons' samples may add is far less


@dataclass
class LoadResult:
    duration_s: float
    balloons: int
    rate_hz: float
    cpu_pct: float  # the server's, % of one core
    rss_peak_mb: float
    heap_start_mb: float
    heap_end_mb: float
    heap_peak_mb: float
    sent: int
    received: int
    pushed: int
    page_errors: list[str]

    @property
    def heap_growth_mb(self) -> float:
        return self.heap_end_mb - self.heap_start_mb

    def rows(self) -> list[tuple[str, str, str, bool]]:
        cpu, rss = self.cpu_pct, self.rss_peak_mb
        return [
            ("server CPU, % of one core", f"{cpu:.1f}", f"<= {TARGET_CPU_PCT:g}", cpu <= TARGET_CPU_PCT),
            ("server RSS peak, MB", f"{rss:.0f}", f"<= {TARGET_RSS_MB:g}", rss <= TARGET_RSS_MB),
            ("page JS heap start -> end (peak), MB",
             f"{self.heap_start_mb:.1f} -> {self.heap_end_mb:.1f} ({self.heap_peak_mb:.1f})",
             f"growth <= {TARGET_HEAP_GROWTH_MB:g}", self.heap_growth_mb <= TARGET_HEAP_GROWTH_MB),
            ("WIND_COV sent / received", f"{self.sent} / {self.received}", "equal", self.sent == self.received),
            ("updates pushed to the page", str(self.pushed), "", True),
            ("page console errors", str(len(self.page_errors)), "0", not self.page_errors),
        ]  # fmt: skip


def heap_mb(cdp) -> float:
    """The page's used JS heap after a full garbage collection, MB."""
    cdp.send("HeapProfiler.collectGarbage")
    return cdp.send("Runtime.getHeapUsage")["usedSize"] / 1e6


def run_load(duration_s: float, balloons: int = 5, rate_hz: float = 10.0) -> LoadResult:
    import psutil
    from playwright.sync_api import sync_playwright

    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=i + 1, n=2.0 + 0.5 * i, e=-1.0 + 0.8 * i) for i in range(balloons)], rate_hz)
    proc = psutil.Process(srv.proc.pid)
    errors: list[str] = []
    try:
        with sync_playwright() as p:
            browser = launch_chromium(p)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            feed.start()
            page.goto(srv.url)
            page.wait_for_selector(f'article[data-sysid="{balloons}"]', timeout=20000)
            cdp = page.context.new_cdp_session(page)
            time.sleep(WARMUP_S)
            heap0 = heap_peak = heap_mb(cdp)
            c0, t0 = proc.cpu_times(), time.monotonic()
            rss = proc.memory_info().rss
            next_heap = t0 + 60.0
            while time.monotonic() - t0 < duration_s:
                time.sleep(SAMPLE_EVERY_S)
                rss = max(rss, proc.memory_info().rss)
                if time.monotonic() >= next_heap:  # once a minute (a forced GC costs the page a little)
                    heap_peak = max(heap_peak, heap_mb(cdp))
                    next_heap += 60.0
            c1, t1 = proc.cpu_times(), time.monotonic()
            heap1 = heap_mb(cdp)
            browser.close()
        feed.stop.set()
        feed.join(5)
        sent = sum(feed.sent().values())
        wait_until(lambda: sum(srv.stats()["received"].values()) >= sent, 5.0)
        stats = srv.stats()
    finally:
        feed.stop.set()
        srv.stop(signal.SIGTERM)
    cpu = (c1.user + c1.system - c0.user - c0.system) / (t1 - t0) * 100.0
    return LoadResult(duration_s, balloons, rate_hz, cpu, rss / 1e6, heap0, heap1, max(heap_peak, heap1), sent,
                      sum(stats["received"].values()), stats["pushed"], errors)  # fmt: skip


def table(r: LoadResult) -> str:
    head = f"balloon-gs web: {r.balloons} balloons x {r.rate_hz:g} Hz for {r.duration_s:g} s, one page open"
    rows = [("measure", "value", "target", "")] + [(a, b, c, "ok" if ok else "MISSED") for a, b, c, ok in r.rows()]
    w = [max(len(row[k]) for row in rows) for k in range(4)]
    lines = [head] + ["  ".join(cell.ljust(w[k]) for k, cell in enumerate(row)).rstrip() for row in rows]
    lines.insert(2, "  ".join("-" * x for x in w))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="balloon-gs web under load (needs chromium and playwright)")
    ap.add_argument("--duration", type=float, default=600.0, help="seconds measured (after a warm-up)")
    ap.add_argument("--balloons", type=int, default=5)
    ap.add_argument("--rate", type=float, default=10.0, help="WIND_COV per second per balloon")
    args = ap.parse_args(argv)
    if not have_browser():
        print("bench_web: needs /usr/bin/chromium and playwright (pip install 'balloon-wind[test]')", file=sys.stderr)
        return 2
    r = run_load(args.duration, args.balloons, args.rate)
    print(table(r))
    return 0 if all(ok for *_, ok in r.rows()) else 1


if __name__ == "__main__":
    sys.exit(main())
