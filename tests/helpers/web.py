"""``balloon-gs web`` under test: start it on free ports, read its URL, stop it; a small synthetic product
(and its profile) to show; Debian's chromium through Playwright (the browser tests skip without it)."""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PY = sys.executable
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]  # fmt: skip
START_TIMEOUT_S = 30.0


def have_browser() -> bool:
    if not (os.path.exists(CHROMIUM) or shutil.which("chromium")):
        return False
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return False
    return True


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class WebServer:
    """``balloon-gs web ARGS --bind 127.0.0.1:PORT`` as a subprocess; ``url`` once it serves."""

    def __init__(self, *args: str, port: int = 0, host: str = "127.0.0.1") -> None:
        self.args = [PY, "-m", "ground_station", "web", *args, "--bind", f"{host}:{port}"]
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()  # "balloon-gs web: http://HOST:PORT/ (read-only; ...)"
        if not line.startswith("balloon-gs web: http://"):
            self.proc.kill()
            out, err = self.proc.communicate(timeout=10)
            raise RuntimeError(f"balloon-gs web did not start: {line}{out}{err}")
        self.url = line.split()[2]
        self.port = int(self.url.rstrip("/").rsplit(":", 1)[1])

    def stats(self) -> dict:
        import json
        import urllib.request

        with urllib.request.urlopen(self.url + "api/stats", timeout=5) as r:
            return json.load(r)

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 20.0) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            _, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return self.proc.returncode, err


def wait_until(cond, timeout_s: float, every_s: float = 0.1):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(every_s)
    return cond()


def launch_chromium(playwright):
    exe = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    return playwright.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)


def write_product(path: Path) -> Path:
    """A synthetic 20-minute product at 10 Hz with one winch leg up and one down (and its ``_profile.nc``)."""
    from postflight.netcdf import write_netcdf
    from postflight.product import WindProduct
    from postflight.profile import wind_profile, write_profile

    t = np.arange(12000) / 10.0
    leg = 300.0
    phase = (t % (2 * leg)) / leg
    reel = np.where(phase < 1.0, 0.5, -0.5)
    length = 0.5 * leg * np.where(phase < 1.0, phase, 2.0 - phase) + 5.0
    h = length * 0.9
    speed = 3.0 + 0.02 * h + 0.3 * np.sin(t / 20.0)
    frm = 250.0 + 0.1 * h
    n, e = -speed * np.cos(np.radians(frm)), -speed * np.sin(np.radians(frm))
    z = np.zeros_like(t)
    p = WindProduct(time_s=t, wind_n=n, wind_e=e, sigma_n=z + 0.2, sigma_e=z + 0.2, causal_n=n + 0.1,
                    causal_e=e - 0.1, causal_sigma_n=z + 0.35, causal_sigma_e=z + 0.35, height_m=h, pos_n=z, pos_e=z,
                    air_pressure_pa=z + 101000.0, air_temperature_k=z + 288.0, mode=np.full(t.size, 2, np.int8),
                    flags=np.ones(t.size, np.int8), line_length_m=length, reel_mps=reel)  # fmt: skip
    write_netcdf(p, str(path))
    prof = wind_profile(p)
    assert prof is not None and len(prof.legs) >= 2
    write_profile(prof, p, str(path.with_name(path.stem + "_profile.nc")))
    return path


def math_close_deg(a: float, b: float, tol: float) -> bool:
    return abs((a - b + 180.0) % 360.0 - 180.0) <= tol + 1e-9 and math.isfinite(a)
