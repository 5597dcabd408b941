"""``balloon-gs web`` as a program, without a browser: the user errors (exit 2, one line), the bind warning,
Ctrl-C and SIGTERM, the assets all its own (no request leaves the machine), no path traversal to anything but
the product it was given, the decoding as ``listen`` decodes (two balloons over loopback UDP, read from the
WebSocket), and a malformed message from a page dropped and counted."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import subprocess
import urllib.request

import pytest

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
