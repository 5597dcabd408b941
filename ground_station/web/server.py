"""``balloon-gs web``: the browser ground station's server (aiohttp, the ``[web]`` extra).

One receiver thread per endpoint decodes into the ``LiveModel`` (listen's ``GroundStation`` and each
balloon's series); an asyncio task pushes an update to every connected page ``PUSH_HZ`` times a second
over a WebSocket (a page that connects gets a snapshot first). Read-only: nothing the page sends reaches
the link; a page's message that is not one of ``CLIENT_MESSAGES`` is dropped and counted. A WebSocket is
opened only from the page's own origin (a browser's ``Origin`` naming another host is refused, 403, and counted);
a malformed HTTP request is answered 400 by aiohttp and counted, without a traceback on stderr.

Every file the page loads is served from ``static/`` by this program (uPlot vendored, no CDN): only the
files that are there at start, by exact name; with ``--product`` only that file, by its exact name (its
profile's legs are in ``/product/data.json``). Anything else is 404."""

from __future__ import annotations

import asyncio
import html
import json
import logging
import mimetypes
import os
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web
from aiohttp.http_exceptions import HttpProcessingError

from balloon_core.wire import LinkStats
from ground_station.listen import STALE_S, GroundStation, Receiver, no_wind_refusal, recording
from ground_station.web.aggregate import PUSH_HZ
from ground_station.web.live import LiveModel

STATIC_DIR = Path(__file__).resolve().parent / "static"
RECV_TIMEOUT_S = 0.1  # a receiver thread looks at the stop flag at least this often
STOP_POLL_S = 0.1
SEND_TIMEOUT_S = 2.0  # a page that takes longer to take one update is dropped (it reconnects by itself)
CLIENT_MESSAGES = ("hello", "ping")  # all a page may say (its JSON {"type": ...}); nothing commands the balloon
MAX_CLIENT_MESSAGE_BYTES = 4096
LOOPBACK = "127.0.0.1"
# the page's own files only; styles may be set by script (uPlot sizes its canvas)
CSP = ("default-src 'self'; connect-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
       "script-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'")  # fmt: skip


@dataclass
class Counters:
    """What the server saw of the pages: malformed messages dropped, updates pushed, pages connected, WebSockets
    refused for another origin, malformed HTTP requests (answered 400)."""

    malformed: int = 0
    pushed: int = 0
    connections: int = 0
    foreign_origins: int = 0
    bad_requests: int = 0


class _BadRequests(logging.Filter):
    """aiohttp logs a malformed request (too long a line, a bad header, version or chunk) with its traceback:
    counted here instead, not logged. Anything else (a fault of this server's) is logged as aiohttp logs it."""

    def __init__(self, counters: Counters) -> None:
        super().__init__()
        self.counters = counters

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            self.counters.bad_requests += 1
            return False
        return True


def static_files(root: Path = STATIC_DIR) -> dict[str, Path]:
    """URL path under /static/ -> file, for every file in ``root`` at start (the only ones ever served)."""
    return {p.relative_to(root).as_posix(): p for p in sorted(root.rglob("*")) if p.is_file()}


class WebStation:
    """The receivers, the model and the aiohttp application."""

    def __init__(self, endpoints: list[str], product: dict | None = None, product_files: dict[str, Path] | None = None,
                 max_hz: float = PUSH_HZ) -> None:  # fmt: skip
        self.gs = GroundStation(out=sys.stderr)
        self.gs.endpoint = " ".join(endpoints)
        self.model = LiveModel(self.gs, max_hz)
        self.push_every_s = 1.0 / max_hz
        self.endpoints = endpoints
        self.product_json = None if product is None else json.dumps(product, allow_nan=False).encode()
        self.product_files = product_files or {}
        self.static = static_files()
        self.counters = Counters()
        self.http_log = logging.Logger(f"{__name__}.http")  # aiohttp's server log: bad requests counted, not printed
        self.http_log.addFilter(_BadRequests(self.counters))
        self.clients: set[web.WebSocketResponse] = set()
        self._halt = threading.Event()
        self.receiver_error: BaseException | None = None
        self.receivers: list[Receiver] = []
        try:
            for ep in endpoints:  # opened here: a port already bound is the user's error, before serving
                if os.path.isfile(ep):
                    self.load_recording(ep)
                else:
                    self.receivers.append(Receiver(ep, self.gs, lock=self.model.lock,
                                                   on_message=self.model.on_message))  # fmt: skip
        except BaseException:
            self.close_links()
            raise
        self._threads = [threading.Thread(target=self._receive, args=(rx,), daemon=True, name=f"rx {rx.endpoint}")
                         for rx in self.receivers]  # fmt: skip

    # ------------------------------------------------------------ the link

    def load_recording(self, path: str) -> None:
        """A recorded link (a .tlog or a raw capture: ``listen.recording``) taken at once, as if it had just come,
        its end now: the page shows its last state and charts, which then turn stale as a quiet link does. ValueError
        for a file that holds no WIND_COV (``listen.no_wind_refusal``)."""
        end, first, winds = None, LinkStats(), 0
        for m, t in recording(path, first):  # the first pass finds the end (a day's log is not held)
            end = t if t is not None else end
            winds += m.get_type() == "WIND_COV"
        refusal = no_wind_refusal(path, first, winds)
        if refusal is not None:
            raise ValueError(refusal)
        now = time.monotonic()
        with self.model.lock:
            for m, t in recording(path, self.gs.stats):
                at = now if t is None or end is None else now - (end - t)
                if self.gs.handle(m, at):
                    self.model.on_message(m, at)

    def _receive(self, rx: Receiver) -> None:
        try:
            while not self._halt.is_set():
                rx.step(RECV_TIMEOUT_S)
        except (OSError, ValueError) as exc:
            self.receiver_error = exc
            self._halt.set()

    def close_links(self) -> None:
        self._halt.set()
        for t in getattr(self, "_threads", []):
            if t.is_alive():
                t.join(timeout=2.0)
        for rx in self.receivers:
            rx.close()
        self.receivers = []

    # ------------------------------------------------------------ HTTP

    def app(self) -> web.Application:
        app = web.Application(middlewares=[_headers])
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{path:.*}", self._static)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/api/stats", self._stats)
        app.router.add_get("/product/data.json", self._product_data)
        app.router.add_get("/product/{name}", self._product_file)
        return app

    async def _index(self, request: web.Request) -> web.StreamResponse:
        """The page, with each balloon's wind and state in words for a reader without its script
        (``<noscript>``: a browser that runs the script ignores it), refreshed every STALE_S seconds then."""
        page = self.static["index.html"].read_text(encoding="utf-8")
        with self.model.lock:
            lines = self.model.plain_text(time.monotonic())
        items = "".join(f"<li>{html.escape(line)}</li>" for line in lines)
        refresh = f'<noscript><meta http-equiv="refresh" content="{STALE_S:g}"></noscript>'
        page = page.replace("</head>", f"{refresh}\n</head>", 1)
        main = '<main id="balloons"'
        page = page.replace(main, f'<noscript><ul id="plain">{items}</ul></noscript>\n{main}', 1)
        return web.Response(text=page, content_type="text/html", charset="utf-8")

    async def _static(self, request: web.Request) -> web.StreamResponse:
        path = self.static.get(request.match_info["path"])  # exact names only: no "..", no absolute path
        if path is None:
            raise web.HTTPNotFound()
        return self._file(path)

    @staticmethod
    def _file(path: Path) -> web.Response:
        ctype = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        if path.suffix == ".js":
            ctype = "text/javascript"
        return web.Response(body=path.read_bytes(), content_type=ctype, charset="utf-8" if "text" in ctype else None)

    async def _product_data(self, request: web.Request) -> web.StreamResponse:
        if self.product_json is None:
            raise web.HTTPNotFound()
        return web.Response(body=self.product_json, content_type="application/json")

    async def _product_file(self, request: web.Request) -> web.StreamResponse:
        path = self.product_files.get(request.match_info["name"])  # the given file, by its exact name
        if path is None:
            raise web.HTTPNotFound()
        return web.FileResponse(path, headers={"Content-Disposition": f'attachment; filename="{path.name}"'})

    async def _stats(self, request: web.Request) -> web.StreamResponse:
        with self.model.lock:
            st = self.gs.stats
            body = {"received": {str(k): n for k, n in self.model.received().items()}, "frames": st.frames,
                    "lost": st.lost, "crc_errors": st.bad_frames, "garbage_bytes": st.garbage_bytes,
                    "duplicates": self.gs.duplicates,
                    "malformed_client_messages": self.counters.malformed, "pushed": self.counters.pushed,
                    "clients": len(self.clients), "connections": self.counters.connections,
                    "foreign_origins": self.counters.foreign_origins,
                    "bad_requests": self.counters.bad_requests}  # fmt: skip
        return web.json_response(body)

    # ------------------------------------------------------------ the WebSocket

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if not same_origin(request):  # another site's page in the user's browser: no data for it
            self.counters.foreign_origins += 1
            raise web.HTTPForbidden(text="WebSocket only from this server's own page\n")
        ws = web.WebSocketResponse(max_msg_size=MAX_CLIENT_MESSAGE_BYTES, heartbeat=10.0)
        await ws.prepare(request)
        self.counters.connections += 1
        with self.model.lock:
            snap = self.model.snapshot(time.monotonic())
        if self.product_json is not None:
            snap["product"] = True
        await ws.send_str(json.dumps(snap, allow_nan=False))
        self.clients.add(ws)
        try:
            async for msg in ws:
                if not self.client_message_ok(msg):
                    self.counters.malformed += 1
        finally:
            self.clients.discard(ws)
        return ws

    @staticmethod
    def client_message_ok(msg) -> bool:
        """A page's message is JSON {"type": one of CLIENT_MESSAGES}; anything else is malformed."""
        if msg.type != WSMsgType.TEXT:
            return False
        try:
            data = json.loads(msg.data)
        except ValueError:
            return False
        return isinstance(data, dict) and data.get("type") in CLIENT_MESSAGES

    async def push(self) -> None:
        """Every ``push_every_s``: what changed, to every page (nothing built while none is connected)."""
        while True:
            await asyncio.sleep(self.push_every_s)
            now = time.monotonic()
            with self.model.lock:
                if not self.clients:
                    for s in self.model.series.values():
                        s.drain()
                    continue
                text = json.dumps(self.model.update(now), allow_nan=False)
            for ws in list(self.clients):
                if ws.closed:
                    continue
                try:
                    await asyncio.wait_for(ws.send_str(text), SEND_TIMEOUT_S)
                    self.counters.pushed += 1
                except (ConnectionError, RuntimeError, TimeoutError):  # gone, or too slow: the others go on
                    self.clients.discard(ws)
                    asyncio.ensure_future(ws.close())

    async def serve(self, host: str, port: int, stop, announce=print) -> None:
        """Serve until ``stop()`` (or a receiver fails); ``announce`` gets the URL once listening."""
        runner = web.AppRunner(self.app(), access_log=None, handle_signals=False, logger=self.http_log)
        await runner.setup()
        try:
            site = web.TCPSite(runner, host, port)
            try:
                await site.start()
            except socket.gaierror as exc:  # the resolver's error (its errno is no OS error's)
                unknown = exc.errno in (socket.EAI_NONAME, getattr(socket, "EAI_NODATA", socket.EAI_NONAME))
                why = "is not known" if unknown else "cannot be resolved"
                raise OSError(f"cannot serve on {host}:{port}: host {host!r} {why} ({exc.strerror})") from None
            except OSError as exc:
                why = os.strerror(exc.errno).lower() if exc.errno else str(exc)
                raise OSError(f"cannot serve on {host}:{port}: {why}") from None
            bound = site._server.sockets[0].getsockname()[1] if site._server and site._server.sockets else port
            for t in self._threads:
                t.start()
            announce(f"http://{_url_host(host)}:{bound}/")
            pusher = asyncio.create_task(self.push())
            try:
                while not stop() and not self._halt.is_set():
                    await asyncio.sleep(STOP_POLL_S)
            finally:
                pusher.cancel()
                for ws in list(self.clients):
                    await ws.close()
        finally:
            await runner.cleanup()
            self.close_links()
        if self.receiver_error is not None:
            raise self.receiver_error


@web.middleware
async def _headers(request: web.Request, handler) -> web.StreamResponse:
    resp = await handler(request)
    resp.headers["Content-Security-Policy"] = CSP
    resp.headers["X-Content-Type-Options"] = "nosniff"
    resp.headers["Referrer-Policy"] = "no-referrer"
    resp.headers["Cache-Control"] = "no-store"
    return resp


def same_origin(request: web.Request) -> bool:
    """No ``Origin`` (not a browser), or one whose host and port are the ones the page was loaded from (``Host``)."""
    origin = request.headers.get("Origin")
    if origin is None:
        return True
    try:
        parts = urlsplit(origin)
    except ValueError:
        return False
    return parts.scheme in ("http", "https") and bool(parts.netloc) and parts.netloc.lower() == request.host.lower()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def run(endpoints: list[str], host: str, port: int, product_path: str | None, stop) -> GroundStation:
    """Load the product (if any), open the links, serve until stopped; the station (for its summary)."""
    product = files = None
    if product_path is not None:
        from ground_station.web.product import load_product

        product = load_product(product_path)  # with its profile's legs, if <stem>_profile.nc lies beside it
        files = {Path(product_path).name: Path(product_path).resolve()}  # the one file served as a file
    station = WebStation(endpoints, product, files)

    def announce(url: str) -> None:
        print(f"balloon-gs web: {url} (read-only; Ctrl-C stops)", flush=True)
        if host != LOOPBACK:  # once it serves: a bind that fails is the one line of its error
            print(f"balloon-gs web: warning: serving on {host}:{port}, not {LOOPBACK}: anyone who can reach it sees "
                  "the balloons (read-only)", file=sys.stderr, flush=True)  # fmt: skip

    try:
        asyncio.run(station.serve(host, port, stop, announce))
    finally:
        station.close_links()
    return station.gs
