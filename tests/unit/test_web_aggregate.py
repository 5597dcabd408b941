"""The browser ground station's aggregation (ground_station/web/aggregate.py): the WMO 2- and 10-minute means
(scalar speed, direction of the vector mean), the gust (highest 3-s running mean within the 10 minutes), the
decimation to at most 10 samples a second, the hour's one-second means and the winch profile."""

from __future__ import annotations

import math

import numpy as np
import pytest

from balloon_core.score import direction_from_deg
from ground_station.web.aggregate import (
    LONG_MEAN_S,
    BalloonSeries,
    Decimator,
    ProfileBuilder,
    gust,
    wmo_mean,
)


def toward(speed: float, from_deg: float) -> tuple[float, float]:
    """(north, east) of a wind of this speed blowing FROM this direction."""
    a = math.radians(from_deg)
    return -speed * math.cos(a), -speed * math.sin(a)


def test_the_mean_direction_is_the_vector_mean_across_north():
    n1, e1 = toward(4.0, 350.0)
    n2, e2 = toward(4.0, 10.0)
    t = np.array([0.0, 1.0])
    m = wmo_mean(t, np.array([n1, n2]), np.array([e1, e2]), now=1.0, period_s=600.0)
    assert m.from_deg == pytest.approx(0.0, abs=1e-9) or m.from_deg == pytest.approx(360.0, abs=1e-9)
    assert m.speed_mps == pytest.approx(4.0)  # the scalar mean speed, not the vector mean's (4 cos 10 deg)
    assert m.count == 2 and m.span_s == 1.0


def test_two_and_ten_minute_means_take_only_their_period():
    t = np.arange(6000) / 10.0  # 10 Hz for 10 minutes (times exact to the last bit: no drift of a sum)
    late = t >= 480.0  # the last 2 minutes at 6 m/s from 90 deg, before at 2 m/s from 270 deg
    speed, frm = np.where(late, 6.0, 2.0), np.where(late, 90.0, 270.0)
    n, e = -speed * np.cos(np.radians(frm)), -speed * np.sin(np.radians(frm))
    now = float(t[-1])
    m2 = wmo_mean(t, n, e, now, 120.0)
    m10 = wmo_mean(t, n, e, now, 600.0)
    assert m2.speed_mps == pytest.approx(6.0) and m2.from_deg == pytest.approx(90.0)
    assert m2.count == 1200
    assert m10.speed_mps == pytest.approx(0.8 * 2.0 + 0.2 * 6.0)  # the scalar mean speed
    # the vector mean: 0.8 * 2 m/s toward east, 0.2 * 6 m/s toward west: 0.4 m/s toward east, FROM 270 deg
    assert m10.from_deg == pytest.approx(270.0)
    assert m10.count == 6000
    assert wmo_mean(t, n, e, now + 1000.0, 600.0) is None


def brute_gust(t, speed, start, window=3.0):
    """The definition, sample by sample: the mean over (t_i - window, t_i] for every t_i - window >= start."""
    best = math.nan
    for ti in t:
        if ti - window >= start - 1e-9:
            m = float(np.mean(speed[(t > ti - window) & (t <= ti)]))
            best = m if math.isnan(best) else max(best, m)
    return best


def test_gust_is_the_highest_three_second_running_mean_inside_the_period():
    t = np.arange(0.0, 600.0, 0.1)
    speed = np.full(t.size, 5.0)
    speed[(t >= 300.0) & (t < 301.0)] = 15.0  # a 1-s peak: its 3-s running mean is (10 * 15 + 20 * 5) / 30
    g = gust(t, speed, start=0.0)
    assert g == pytest.approx((10 * 15.0 + 20 * 5.0) / 30.0)
    assert g < 15.0  # never the peak sample
    # irregular times and a random wind: the same as the definition computed sample by sample
    rng = np.random.default_rng(3)
    tr = np.cumsum(rng.uniform(0.05, 0.3, 800))
    sr = rng.gamma(4.0, 1.5, tr.size)
    assert gust(tr, sr, start=10.0) == pytest.approx(brute_gust(tr, sr, 10.0), rel=1e-12)
    # a peak before the period's start counts only through the windows wholly inside
    assert gust(t, speed, start=301.5) == pytest.approx(5.0)
    assert math.isnan(gust(np.array([0.0, 1.0]), np.array([1.0, 2.0]), start=0.0))  # no 3-s window fits


def test_series_statistics_with_a_gust_and_unknown_winds_left_out():
    s = BalloonSeries()
    for i in range(6000):  # 10 minutes at 10 Hz, 6 m/s from 200 deg, a 3-s gust of 12 m/s at 400 s
        t = 1000.0 + i * 0.1
        sp = 12.0 if 400.0 <= i * 0.1 < 403.0 else 6.0
        n, e = toward(sp, 200.0)
        s.add(t, n, e, 0.3, 100.0)
    n, e = toward(50.0, 20.0)
    s.add(1600.0, n, e, 60.0, 100.0)  # not known (accuracy above the speed): out of the means
    st = s.statistics(1600.0)
    assert st["mean_10min"]["from"] == pytest.approx(200.0, abs=0.01)
    assert st["mean_2min"]["speed"] == pytest.approx(6.0, abs=1e-3)
    assert st["gust"] == pytest.approx(12.0, abs=0.01)
    assert st["mean_10min"]["count"] == 5999  # the oldest left the 10 minutes, the unknown one never came in
    assert s.received == 6001


def test_decimation_never_exceeds_ten_a_second_and_keeps_a_ten_hz_stream():
    d = Decimator(10.0)
    fast = [5.0 + i * 0.01 for i in range(1000)]  # 100 Hz for 10 s
    kept_fast = np.array([t for t in fast if d.take(t)])
    assert 99 <= kept_fast.size <= 10.0 * 10 + 2
    assert np.min(np.diff(kept_fast)) >= 0.05 - 1e-9
    d2 = Decimator(10.0)
    rng = np.random.default_rng(1)
    ts = 7.0 + np.arange(600) * 0.1 + rng.uniform(-0.02, 0.02, 600)  # 10 Hz with 20 ms jitter, 60 s
    kept = np.array([t for t in ts if d2.take(float(t))])
    assert kept.size == 600  # a stream at the limit passes whole
    for w0 in np.arange(7.0, 66.0, 0.25):  # and no second holds more than 10 (+2)
        assert np.count_nonzero((kept >= w0) & (kept < w0 + 1.0)) <= 12
    d3 = Decimator(10.0)
    bursty = np.sort(rng.uniform(0.0, 60.0, 3000))  # 50 Hz, Poisson
    kept3 = np.array([t for t in bursty if d3.take(float(t))])
    assert kept3.size <= 60 * 10 + 2 and kept3.size >= 0.9 * 600


def test_series_pushes_decimated_samples_and_one_second_means():
    s = BalloonSeries(max_hz=10.0)
    for i in range(300):  # 30 Hz for 10 s
        n, e = toward(4.0, 90.0)
        s.add(50.0 + i / 30.0, n, e, 0.2, 80.0)
    new, hour = s.drain()
    assert 99 <= len(new) <= 100
    assert all(p.speed == pytest.approx(4.0) and p.from_deg == pytest.approx(90.0) for p in new)
    assert len(hour) == 9  # the seconds completed (the tenth is being averaged)
    assert hour[0].t == pytest.approx(50.5) and hour[0].speed == pytest.approx(4.0)
    assert s.drain() == ([], [])  # sent once


def test_charted_window_is_trimmed_to_ten_minutes():
    s = BalloonSeries()
    for i in range(8000):
        s.add(i * 0.1, 1.0, 1.0, 0.1, 10.0)
    assert s.charted[0].t > 799.9 - LONG_MEAN_S
    assert len(s.recent) <= 6000


def test_profile_legs_follow_the_reel_and_bin_by_height():
    p = ProfileBuilder(bin_m=10.0)
    for i in range(100):  # paying out: 0 .. 99 m, wind from 270 growing with height
        z = float(i)
        n, e = toward(2.0 + 0.05 * z, 270.0)
        p.add(i, n, e, 0.4, z, reel_mps=1.0)
    p.add(100, 1.0, 1.0, 0.4, 100.0, reel_mps=0.0)  # stopped: no leg, not counted
    for i in range(50):  # reeling in
        z = 100.0 - i
        n, e = toward(3.0, 250.0)
        p.add(200 + i, n, e, 0.5, z, reel_mps=-1.0)
    d = p.as_dict()
    assert [g["ascent"] for g in d["legs"]] == [True, False]
    up = d["legs"][0]["rows"]
    assert [r["z"] for r in up] == [5.0 + 10 * k for k in range(10)]
    assert up[0]["count"] == 10
    assert up[0]["speed"] == pytest.approx(2.0 + 0.05 * 4.5)
    assert up[0]["from"] == pytest.approx(270.0)
    assert up[0]["speed_err"] == pytest.approx(0.4)
    assert up[0]["from_err"] == pytest.approx(math.degrees(0.4 / up[0]["speed"]), abs=0.05)  # rounded to 0.1 deg
    down = d["legs"][1]["rows"]
    assert sum(r["count"] for r in down) == 50 and down[-1]["from"] == pytest.approx(250.0)


def test_direction_helper_agrees_with_the_core():
    n, e = toward(3.0, 123.0)
    assert float(direction_from_deg(n, e)) == pytest.approx(123.0)
