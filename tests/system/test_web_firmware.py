"""``balloon-gs web`` on the real chain, not a script: ``balloon-sim`` -> ``balloon-fw`` -> ``balloon-gs web``
over loopback UDP. What the page is pushed (read from the WebSocket): the balloon's wind while the simulator
runs, ``SENSORS LOST`` within 3 s once the simulator stops (the firmware keeps sending WIND_COV and clears
its sensors' health, as docs/protocol.md says), and ``STALE`` once the firmware is stopped too."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import threading
import time

import pytest

from tests.helpers.web import PY, WebServer, free_udp_port, wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow]

SIM_S, SIM_SPEED = 60.0, 4.0  # 60 s of flight at 4x real time
SENSORS_LOST_WITHIN_S = 3.0
STALE_WITHIN_S = 2.0 + 3.0


class Watch(threading.Thread):
    """Reads the WebSocket; keeps (monotonic time, the balloon's dict) of each update for ``sysid``."""

    def __init__(self, url: str, sysid: int = 1) -> None:
        super().__init__(daemon=True)
        self.url, self.sysid = url, sysid
        self.seen: list[tuple[float, dict]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        asyncio.run(self._read())

    async def _read(self) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as s, s.ws_connect(self.url.replace("http", "ws") + "ws") as ws:
            while not self.stop.is_set():
                try:
                    msg = await ws.receive(timeout=1.0)
                except TimeoutError:
                    continue
                if msg.type != aiohttp.WSMsgType.TEXT:
                    return
                for b in json.loads(msg.data)["balloons"]:
                    if b["sysid"] == self.sysid:
                        self.seen.append((time.monotonic(), b))

    def state_since(self, state: str, t0: float) -> float | None:
        """When the state was first pushed after t0."""
        return next((t for t, b in self.seen if t >= t0 and b["state"].startswith(state)), None)


def test_sensors_lost_then_stale_from_the_real_firmware():
    p_fw, p_gs = free_udp_port(), free_udp_port()
    srv = WebServer(f"udpin:127.0.0.1:{p_gs}")
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{p_fw}", "--out",
                           f"udpout:127.0.0.1:{p_gs}"], stderr=subprocess.PIPE, text=True)  # fmt: skip
    watch = Watch(srv.url)
    try:
        watch.start()
        time.sleep(0.5)
        sim = [PY, "-m", "sim_hil", "--duration", str(SIM_S), "--seed", "3", "--out", f"udpout:127.0.0.1:{p_fw}",
               "--speed", str(SIM_SPEED), "--quiet"]  # fmt: skip
        subprocess.run(sim, check=True, timeout=120, capture_output=True)
        t_quiet = time.monotonic()
        flowing = [b for _, b in watch.seen if b["state"] in ("OK", "MISFIT")]
        assert flowing and flowing[-1]["mode"] in ("free", "taut") and flowing[-1]["received"] > 100
        assert any(b["known"] and 0.0 <= b["from"] < 360.0 and b["speed"] > 0.0 for b in flowing)
        assert wait_until(lambda: watch.state_since("SENSORS LOST", t_quiet), SENSORS_LOST_WITHIN_S + 2.0)
        assert watch.state_since("SENSORS LOST", t_quiet) - t_quiet <= SENSORS_LOST_WITHIN_S
        fw.send_signal(signal.SIGTERM)
        fw.wait(10)
        t_dead = time.monotonic()
        assert wait_until(lambda: watch.state_since("STALE", t_dead), STALE_WITHIN_S + 2.0)
        assert watch.state_since("STALE", t_dead) - t_dead <= STALE_WITHIN_S
        stats = srv.stats()
        assert stats["lost"] == 0 and stats["received"]["1"] > SIM_S * 10 * 0.9
    finally:
        watch.stop.set()
        if fw.poll() is None:
            fw.kill()
            fw.wait(5)
        srv.stop(signal.SIGTERM)
