"""``balloon-gs web`` as a program, without a browser: the user errors (exit 2, one line), the bind warning,
Ctrl-C and SIGTERM, the assets all its own (no request leaves the machine), no path traversal to anything but
the product it was given, the decoding as ``listen`` decodes (two balloons over loopback UDP, read from the
WebSocket), and a malformed message from a page dropped and counted."""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import socket
import subprocess
import time
import urllib.request

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack
from tests.helpers.web import PY, WebServer, free_tcp_port, free_udp_port, wait_until, write_product
from tools.web_feed import Balloon, Feed

pytestmark = [pytest.mark.network]


def web(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "ground_station", "web", *args], capture_output=True, text=True, timeout=timeout)


def one_line_error(r: subprocess.CompletedProcess) -> None:
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("balloon-gs") and "Traceback" not in r.stderr, r.stderr


@pytest.fixture(scope="module")
def product(tmp_path_factory):
    return write_product(tmp_path_factory.mktemp("product") / "flight.nc")


# ---------------------------------------------------------------- user errors


@pytest.mark.parametrize("args", [[], ["--bind", "nonsense"], ["--bind", "127.0.0.1:99999"], ["udpin:nohost"],
                                  ["--product", "/nonexistent/flight.nc"]])  # fmt: skip
def test_user_errors_are_one_line_and_exit_2(args):
    one_line_error(web(*args))


def test_a_file_that_is_no_product_is_a_user_error(tmp_path):
    bad = tmp_path / "x.nc"
    bad.write_text("not netcdf")
    r = web("--product", str(bad), "--bind", "127.0.0.1:0")
    one_line_error(r)
    assert "x.nc" in r.stderr


def test_a_tcp_port_in_use_is_a_user_error():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        r = web(f"udpin:127.0.0.1:{free_udp_port()}", "--bind", f"127.0.0.1:{s.getsockname()[1]}")
    one_line_error(r)
    assert "cannot serve" in r.stderr


def test_an_address_it_cannot_serve_on_is_one_line_and_no_warning():
    """The warning for an address other than loopback comes once the page is served: a bind that fails (192.0.2.1
    is TEST-NET-1, no machine's own) is its error's one line alone."""
    r = web(f"udpin:127.0.0.1:{free_udp_port()}", "--bind", "192.0.2.1:0")
    one_line_error(r)
    assert "cannot serve" in r.stderr and "warning" not in r.stderr


def test_a_udp_port_already_bound_is_a_user_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        r = web(f"udpin:127.0.0.1:{s.getsockname()[1]}", "--bind", f"127.0.0.1:{free_tcp_port()}")
    one_line_error(r)


def test_without_aiohttp_it_names_the_extra(tmp_path):
    code = ("import sys\nsys.modules['aiohttp'] = None\nfrom ground_station.cli import main\n"
            f"sys.exit(main(['web', 'udpin:127.0.0.1:{free_udp_port()}']))\n")  # fmt: skip
    r = subprocess.run([PY, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60)
    one_line_error(r)
    assert "balloon-wind[web]" in r.stderr and "aiohttp" in r.stderr


# ---------------------------------------------------------------- running, stopping


def test_loopback_by_default_and_a_warning_for_any_other_address():
    srv = WebServer(f"udpin:127.0.0.1:{free_udp_port()}", host="127.0.0.2")
    try:
        assert srv.url.startswith("http://127.0.0.2:")
    finally:
        code, err = srv.stop(signal.SIGTERM)
    assert code == 0
    warnings = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and "127.0.0.2" in warnings[0]
    srv = WebServer(f"udpin:127.0.0.1:{free_udp_port()}")
    code, err = srv.stop(signal.SIGINT)
    assert "warning" not in err
    assert code == 130 and err.splitlines()[-1] == "balloon-gs web: interrupted (Ctrl-C)"  # as listen
    assert "Traceback" not in err


def get(url: str, path: str) -> tuple[int, dict, bytes]:
    """A raw GET (the path sent as is: no client-side normalisation of '..')."""
    host, port = url.split("//")[1].rstrip("/").split(":")
    with socket.create_connection((host, int(port)), timeout=5) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:])}
    return int(lines[0].split()[1]), headers, body


TRAVERSALS = [
    "/product/../../etc/passwd", "/product/..%2f..%2fetc%2fpasswd", "/product/%2e%2e/%2e%2e/etc/passwd",
    "/product/%2e%2e%2f%2e%2e%2fetc%2fpasswd", "/product//etc/passwd", "/product/%2fetc%2fpasswd",
    "/product/flight_profile.nc/../../../etc/passwd", "/static/../server.py", "/static/%2e%2e/server.py",
    "/static/..%2fserver.py", "/static//etc/passwd", "/static/%2fetc%2fpasswd", "//etc/passwd", "/../../etc/passwd",
    "/static/vendor/uplot/../../../server.py", "/product/data.json/../../../../etc/passwd", "/etc/passwd",
]  # fmt: skip


def test_only_its_own_files_and_the_given_product_are_served(product):
    srv = WebServer("--product", str(product))
    try:
        code, headers, body = get(srv.url, "/")
        assert code == 200 and b"balloon-gs" in body
        assert "default-src 'self'" in headers["content-security-policy"]
        # every asset the page names is served by this program: nothing from another host
        page = body.decode()
        assets = re.findall(r'(?:src|href)="([^"]+)"', page)
        assert assets and all(a.startswith("/static/") or a.startswith("data:") for a in assets), assets
        for a in assets:
            if a.startswith("/static/"):
                code, _, data = get(srv.url, a)
                assert code == 200 and data, a
                text = data.decode("utf-8", "replace")
                assert not re.search(r"""(?:src|href)\s*=\s*["']https?://|url\(\s*["']?https?://|fetch\(\s*["']https?:""",
                                     text), a  # fmt: skip
        code, _, data = get(srv.url, "/product/flight.nc")
        assert code == 200 and data.startswith(b"\x89HDF")
        code, _, data = get(srv.url, "/product/flight_profile.nc")
        assert code == 404  # its legs are in data.json; the one file served is the one given
        code, _, data = get(srv.url, "/product/data.json")
        p = json.loads(data)
        assert code == 200 and p["name"] == "flight.nc" and len(p["profile"]["legs"]) >= 2
        assert len(p["time"]) <= 4000 and len(p["causal_speed"]) == len(p["time"])
        for path in TRAVERSALS + [f"/product/{product.resolve()}", f"/product/{str(product.resolve())[1:]}",
                                  "/product/flight.cdl", "/static/nonexistent.js"]:  # fmt: skip
            code, _, data = get(srv.url, path)
            assert code in (400, 403, 404), (path, code)
            assert b"root:" not in data and b"import" not in data, path
    finally:
        srv.stop(signal.SIGTERM)


# ---------------------------------------------------------------- decoding as listen does, over the WebSocket


async def read_ws(url: str, sysids: set[int], bad: list) -> dict[int, dict]:
    """Connect, send the malformed messages ``bad`` and a valid ping, and read updates until every sysid shows."""
    import aiohttp

    seen: dict[int, dict] = {}
    async with aiohttp.ClientSession() as s, s.ws_connect(url.replace("http", "ws") + "ws") as ws:
        for b in bad:
            await (ws.send_bytes(b) if isinstance(b, bytes) else ws.send_str(b))
        await ws.send_str(json.dumps({"type": "ping"}))
        for _ in range(200):
            msg = json.loads((await ws.receive(timeout=5)).data)
            for b in msg["balloons"]:
                seen[b["sysid"]] = b
            if sysids <= set(seen):
                break
    return seen


def test_two_balloons_decoded_as_listen_decodes_them_and_malformed_messages_counted():
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    feed = Feed(port, [Balloon(sysid=3, n=4.0, e=-2.0), Balloon(sysid=9, n=-1.5, e=5.0, misfit=8)])
    feed.start()
    try:
        assert wait_until(lambda: set(srv.stats()["received"]) == {"3", "9"}, 20)
        bad = ["not json", json.dumps({"type": "arm"}), json.dumps([1, 2]), b"\x00\x01", "{}"]
        seen = asyncio.run(read_ws(srv.url, {3, 9}, bad))
        assert seen[3]["mode"] == "taut" and seen[3]["misfit"] == [] and seen[3]["estimator"]
        assert 0.0 <= seen[3]["from"] < 360.0 and seen[3]["speed"] > 0
        stats = srv.stats()
        assert stats["malformed_client_messages"] == len(bad)
        assert stats["lost"] == 0 and stats["duplicates"] == 0
        feed.stop.set()
        feed.join(5)
        sent = feed.sent()
        assert wait_until(lambda: srv.stats()["received"] == {str(k): v for k, v in sent.items()}, 10)
    finally:
        feed.stop.set()
        code, err = srv.stop(signal.SIGTERM)
    assert code == 0, err
    assert "WIND_COV from 2 systems" in err
    # sysid 9 cleared the barometer's health bit (8 = absolute pressure): MISFIT, as listen says it
    assert seen[3]["state"] == "OK" and seen[9]["state"] == "MISFIT" and seen[9]["misfit"] == ["baro"]


def test_a_recording_is_shown_as_it_ended(tmp_path):
    """``balloon-gs web FILE``: a recorded link (a .tlog) decoded as ``listen FILE`` decodes it, at once, its end
    now: every WIND_COV taken, the loss counted, the last wind (3 m/s from 135°) on the page, then stale as a quiet
    link; the recording is not touched."""
    from tests.system.test_ground_station import _recording

    tlog, _ = _recording(tmp_path)
    before = tlog.read_bytes()
    srv = WebServer(str(tlog))
    try:
        stats = srv.stats()
        assert stats["received"] == {"42": 199} and stats["lost"] == 1
        seen = asyncio.run(read_ws(srv.url, {42}, []))
        assert seen[42]["speed"] == pytest.approx(3.0, abs=0.01) and seen[42]["from"] == pytest.approx(135.0, abs=0.1)
        time.sleep(2.5)
        assert asyncio.run(read_ws(srv.url, {42}, []))[42]["state"] == "STALE"
    finally:
        code, err = srv.stop(signal.SIGTERM)
    assert code == 0, err
    assert "199 WIND_COV from 1 system" in err and tlog.read_bytes() == before


def test_stats_endpoint_is_json():
    srv = WebServer(f"udpin:127.0.0.1:{free_udp_port()}")
    try:
        with urllib.request.urlopen(srv.url + "api/stats", timeout=5) as r:
            assert r.headers["Content-Type"].startswith("application/json")
            assert json.load(r)["received"] == {}
    finally:
        srv.stop(signal.SIGTERM)


def test_a_profile_given_as_the_product_is_a_user_error(product):
    r = web("--product", str(product.with_name("flight_profile.nc")), "--bind", "127.0.0.1:0")
    one_line_error(r)
    assert "not a balloon-gs reprocess product" in r.stderr


# ---------------------------------------------------------------- the audit's defects


def test_an_unknown_bind_host_says_so():
    r = web(f"udpin:127.0.0.1:{free_udp_port()}", "--bind", "nosuchhost.invalid:8000")
    one_line_error(r)
    assert "nosuchhost.invalid" in r.stderr and "not known" in r.stderr and "error -2" not in r.stderr


@pytest.mark.parametrize("shape", ["time_along_obs", "scalar_time", "series_2d", "text_series"])
def test_a_time_that_is_not_the_series_dimension_is_a_user_error(tmp_path, shape):
    """``time`` a variable but not the dimension of the series (or a series that is no 1-D number): exit 2, one
    line naming what is wrong, never a KeyError's traceback."""
    import numpy as np
    import xarray as xr

    from ground_station.web.product import SERIES

    n = 5
    data = {v: ("time", np.zeros(n)) for v in SERIES.values()}
    if shape == "time_along_obs":
        data = {v: ("obs", np.zeros(n)) for v in SERIES.values()} | {"time": ("obs", np.arange(n, dtype=float))}
    elif shape == "scalar_time":
        data = {v: ("x", np.zeros(n)) for v in SERIES.values()} | {"time": ((), 0.0)}
    elif shape == "series_2d":
        data["wind_speed"] = (("time", "k"), np.zeros((n, 2)))
    else:
        data["wind_speed"] = ("time", np.array(list("abcde")))
    path = tmp_path / f"{shape}.nc"
    ds = xr.Dataset(data) if shape in ("time_along_obs", "scalar_time") else xr.Dataset(
        data, coords={"time": ("time", np.arange(n, dtype=float))})  # fmt: skip
    ds.to_netcdf(path, engine="netcdf4")
    r = web("--product", str(path), "--bind", "127.0.0.1:0")
    one_line_error(r)
    assert f"{shape}.nc: not a balloon-gs reprocess product" in r.stderr
    assert ("time" if "time" in shape else "wind_speed") in r.stderr.split("product", 1)[1]


UTC_START_S = 1_767_225_600.0  # 2026-01-01T00:00:00Z


def utc_product(path, minutes: float = 20.0):
    """A small product of a log with GPS time (``utc_start_s``: its time axis in UTC), 1 Hz, no profile."""
    import numpy as np

    from postflight.netcdf import write_netcdf
    from postflight.product import WindProduct

    t = np.arange(int(minutes * 60), dtype=float)
    z = np.zeros_like(t)
    p = WindProduct(time_s=t, wind_n=z - 3.0, wind_e=z + 1.0, sigma_n=z + 0.2, sigma_e=z + 0.2, causal_n=z - 3.0,
                    causal_e=z + 1.0, causal_sigma_n=z + 0.3, causal_sigma_e=z + 0.3, height_m=z + 50.0, pos_n=z,
                    pos_e=z, air_pressure_pa=z + 1e5, air_temperature_k=z + 288.0, mode=np.full(t.size, 2, np.int8),
                    flags=np.ones(t.size, np.int8), utc_start_s=UTC_START_S)  # fmt: skip
    write_netcdf(p, str(path))
    return path


def test_the_time_axis_is_utc_only_when_the_product_says_utc(tmp_path, product):
    """A simulated flight's product runs on the sensor clock (its long_name says "NOT UTC"): seconds since boot;
    one with GPS time has UTC units: UTC."""
    from ground_station.web.product import load_product

    assert load_product(str(product))["utc"] is False
    p = load_product(str(utc_product(tmp_path / "utc.nc")))
    assert p["utc"] is True and p["time"][0] == UTC_START_S


BAD_REQUESTS = [
    b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",  # a request line too long
    b"GET / HTTP/9.9\r\nHost: x\r\n\r\n",
    b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: -1\r\n\r\n",
    b"POST / HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",  # a bad chunk size
    b"GET / HTTP/1.1\r\nHost: x\r\n" + b"X: y\r\n" * 200 + b"\r\n",
]


def test_malformed_requests_are_answered_400_and_counted_without_a_traceback():
    srv = WebServer(f"udpin:127.0.0.1:{free_udp_port()}")
    try:
        for req in BAD_REQUESTS:
            host, port = srv.url.split("//")[1].rstrip("/").split(":")
            with socket.create_connection((host, int(port)), timeout=5) as s:
                s.sendall(req)
                first = s.recv(200).split(b"\r\n")[0]
            assert b" 400 " in first, (req[:40], first)
        code, _, _ = get(srv.url, "/")
        assert code == 200  # it goes on serving
        counted = srv.stats().get("bad_requests")
    finally:
        code, err = srv.stop(signal.SIGTERM)
    assert code == 0
    assert "Traceback" not in err and "Error handling request" not in err, err
    assert counted == len(BAD_REQUESTS)


async def ws_open(url: str, origin: str | None):
    """The first message of a WebSocket opened with this ``Origin`` (none: not a browser), or the refusal's status."""
    import aiohttp

    headers = {} if origin is None else {"Origin": origin}
    async with aiohttp.ClientSession() as s:
        try:
            async with s.ws_connect(url.replace("http", "ws") + "ws", headers=headers) as ws:
                return json.loads((await ws.receive(timeout=5)).data)
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status


def test_a_websocket_from_another_origin_is_refused():
    srv = WebServer(f"udpin:127.0.0.1:{free_udp_port()}")
    try:
        own = srv.url.rstrip("/")
        assert asyncio.run(ws_open(srv.url, None))["type"] == "snapshot"  # a tool, not a browser
        assert asyncio.run(ws_open(srv.url, own))["type"] == "snapshot"  # the page itself
        foreign = ["http://evil.example", "null", "http://127.0.0.1:1", f"https://attacker.test/{own}"]
        for origin in foreign:
            assert asyncio.run(ws_open(srv.url, origin)) == 403, origin
        assert srv.stats()["foreign_origins"] == len(foreign)
    finally:
        srv.stop(signal.SIGTERM)


def wind_cov(mav, t_us: int, n: float, e: float, var: float = 0.25) -> bytes:
    return pack(mav, mav.wind_cov_encode(t_us, n, e, math.nan, var, 0.0, 100.0, 0.3, 0.0))


def send(port: int, frames: list[bytes], every_s: float = 0.001) -> None:
    """Frames one datagram each, paced (loopback drops a burst larger than the receiver's buffer)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for f in frames:
            s.sendto(f, ("127.0.0.1", port))
            time.sleep(every_s)


def snapshot(url: str) -> dict[int, dict]:
    """Each balloon of the snapshot a page gets on connecting."""
    msg = asyncio.run(ws_open(url, None))
    return {b["sysid"]: b for b in msg["balloons"]}


def test_the_means_follow_the_flights_clock_not_the_arrival():
    """A log replayed fast (here 150 s of flight at 10 Hz in about 2 s): the 2-minute mean covers the last 2 minutes of
    the flight's own clock (WIND_COV time_usec), the 10-minute mean all 150 s; the page says which clock."""
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    try:  # 30 s at 6 m/s from 225 deg, then 120 s at 2 m/s from 225 deg
        frames = [wind_cov(mav, 10_000_000 + 100_000 * i, *((4.2426, 4.2426) if i < 300 else (1.4142, 1.4142)))
                  for i in range(1500)]  # fmt: skip
        send(port, frames)
        assert wait_until(lambda: srv.stats()["received"].get("7") == 1500, 10)
        st = snapshot(srv.url)[7]["stats"]
    finally:
        srv.stop(signal.SIGTERM)
    m2, m10 = st["mean_2min"], st["mean_10min"]
    assert 1150 <= m2["count"] <= 1200 and 115.0 <= m2["span_s"] <= 120.0, m2
    assert m2["speed"] == pytest.approx(2.0, abs=0.01) and m2["from"] == pytest.approx(225.0, abs=0.1)
    assert m10["count"] == 1500 and m10["span_s"] == pytest.approx(149.9, abs=0.1), m10
    assert m10["speed"] == pytest.approx((300 * 6.0 + 1200 * 2.0) / 1500, abs=0.01)
    assert st["clock"] == "balloon"


def test_a_wind_that_is_not_finite_is_no_sample_of_the_means():
    """One WIND_COV with wind_x = inf among good ones: left out of the means (counted as not known), never a
    mean of infinity from 180 deg; shown as not known while it is the last one; no numpy warning."""
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    mav = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
    try:
        frames = [wind_cov(mav, 1_000_000 + 100_000 * i, math.inf if i == 5 else 2.0, 2.0) for i in range(50)]
        send(port, frames + [wind_cov(mav, 6_000_000, math.inf, 0.0)])
        assert wait_until(lambda: srv.stats()["received"].get("9") == 51, 10)
        b = snapshot(srv.url)[9]
    finally:
        code, err = srv.stop(signal.SIGTERM)
    for key in ("mean_2min", "mean_10min"):
        m = b["stats"][key]
        assert m["count"] == 49 and m["speed"] == pytest.approx(math.hypot(2.0, 2.0), abs=1e-3), m
        assert m["from"] == pytest.approx(225.0, abs=0.1), m
    assert b["stats"]["gust"] == pytest.approx(math.hypot(2.0, 2.0), abs=1e-3)
    assert b["known"] is False and b["speed"] is None and b["from"] is None and b["n"] is None
    assert "RuntimeWarning" not in err and "Traceback" not in err, err


def test_the_north_and_east_components_and_the_variability_are_shown():
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    mav = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    try:
        send(port, [wind_cov(mav, 1_000_000 + 100_000 * i, 3.0, -1.5, var=0.42) for i in range(5)])
        assert wait_until(lambda: srv.stats()["received"].get("4") == 5, 10)
        b = snapshot(srv.url)[4]
    finally:
        srv.stop(signal.SIGTERM)
    assert (b["n"], b["e"], b["var"]) == (3.0, -1.5, 0.42)


def test_garbage_datagrams_cost_no_valid_frame_and_are_counted():
    """Each datagram is parsed on its own: one that starts a frame it does not hold (a v2 start claiming 255 bytes)
    swallows nothing of the next datagrams, from the same sender or others, and its bytes are counted."""
    port = free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{port}")
    mavs = {s: mavlink.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 2, 3)}
    frames = []
    for k in range(15):
        frames.append(b"\xfd\xff" + bytes(range(40)))
        frames += [wind_cov(mavs[s], 1_000_000 + 100_000 * k, 1.0, 1.0) for s in (1, 2, 3)]
    try:
        send(port, frames, every_s=0.005)
        assert wait_until(lambda: srv.stats()["received"] == {"1": 15, "2": 15, "3": 15}, 10), srv.stats()
        st = srv.stats()
        assert st["garbage_bytes"] == 15 * 42 and st["lost"] == 0, st
    finally:
        srv.stop(signal.SIGTERM)
