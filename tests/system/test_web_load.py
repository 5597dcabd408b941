"""``balloon-gs web`` under load, short: 5 balloons x 10 Hz for ``LOAD_S`` with a page open. The server stays
within 150 MB, the page's JS heap stays flat, the page is fed, and no WIND_COV is lost on the way
(received = sent). Its CPU share depends on the machine: that is the benchmark's, with the 10-minute run
(``python -m benchmarks.bench_web``), never a test's."""

from __future__ import annotations

import pytest

from benchmarks.bench_web import TARGET_HEAP_GROWTH_MB, TARGET_RSS_MB, run_load, table
from tests.helpers.web import have_browser

pytestmark = [pytest.mark.slow, pytest.mark.network,
              pytest.mark.skipif(not have_browser(), reason="no /usr/bin/chromium or playwright")]  # fmt: skip

LOAD_S = 30.0


def test_five_balloons_at_ten_hz():
    r = run_load(LOAD_S, balloons=5, rate_hz=10.0)
    print(table(r))
    assert r.sent == r.received and r.sent >= 5 * 10 * LOAD_S * 0.9
    assert r.rss_peak_mb <= TARGET_RSS_MB, table(r)
    assert r.heap_growth_mb <= TARGET_HEAP_GROWTH_MB, table(r)
    assert r.pushed >= 0.5 * 10 * LOAD_S  # the page was fed (about 10 updates a second)
    assert not r.page_errors, r.page_errors
