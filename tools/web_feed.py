"""A scripted MAVLink feed for ``balloon-gs web`` (tests, benchmarks/bench_web.py, the README's screenshot),
and the means to run the program and a browser on it (``WebServer``, ``launch_chromium``):
balloons as balloon-fw sends them (WIND_COV at ``rate_hz``, HEARTBEAT + SYS_STATUS + ESTIMATOR_STATUS once a
second) over loopback UDP, each of whose state a test can change while it runs (sensors silent, a misfit, the
link dead), and optionally a winch (WINCH_STATUS) paying out and reeling in.

``python tools/web_feed.py PORT [--balloons N] [--rate HZ] [--winch]`` feeds a ``balloon-gs web udpin:...``."""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import pack

SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_AHRS)  # fmt: skip
GOOD = (mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_VELOCITY_VERT
        | mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_VERT_AGL)  # fmt: skip
WINCH_HEALTHY, WINCH_MOVING, WINCH_CLUTCH = (mavlink.MAV_WINCH_STATUS_HEALTHY, mavlink.MAV_WINCH_STATUS_MOVING,
                                              mavlink.MAV_WINCH_STATUS_CLUTCH_ENGAGED)  # fmt: skip
WINCH_SYSID = 250  # the winch: a component of the ground's system
MODE_TAUT = 2
WINCH_SPEED_MPS = 1.0  # the reel's speed while a leg runs
WINCH_MAX_M = 150.0  # the line paid out at the top of a leg
SHEAR_PER_M = 0.02  # the scripted wind grows by this fraction a metre of height


@dataclass
class Balloon:
    """One scripted balloon: its wind (toward N and E, m/s), stated accuracy and height; the flags a test flips."""

    sysid: int
    n: float = 3.0
    e: float = -1.0
    acc: float = 0.3
    alt_m: float = 100.0
    wobble_mps: float = 0.3  # a slow oscillation on the wind (the charts move)
    sensors_lost: bool = False  # SYS_STATUS clears every sensor's health (balloon-fw's silent sensors)
    misfit: int = 0  # SYS_STATUS health bits cleared (balloon-fw's consistency monitor)
    silent: bool = False  # the link is dead: nothing is sent
    sent: int = 0  # WIND_COV sent
    last: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # (n, e, acc) of the last WIND_COV sent
    mav: object = field(default=None, repr=False)


class Feed(threading.Thread):
    """Sends every balloon's messages to ``127.0.0.1:port`` on a fixed schedule (``rate_hz``) until ``stop``."""

    def __init__(self, port: int, balloons: list[Balloon], rate_hz: float = 10.0, winch: bool = False,
                 host: str = "127.0.0.1") -> None:  # fmt: skip
        super().__init__(daemon=True)
        self.addr = (host, port)
        self.balloons = {b.sysid: b for b in balloons}
        self.rate_hz = rate_hz
        self.winch = winch
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.line_m = 0.0
        for b in balloons:
            b.mav = mavlink.MAVLink(None, srcSystem=b.sysid, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.winch_mav = mavlink.MAVLink(None, srcSystem=WINCH_SYSID, srcComponent=mavlink.MAV_COMP_ID_WINCH)

    def sent(self) -> dict[int, int]:
        with self.lock:
            return {s: b.sent for s, b in self.balloons.items()}

    def last(self, sysid: int) -> tuple[float, float, float]:
        with self.lock:
            return self.balloons[sysid].last

    def set(self, sysid: int, **changes) -> None:
        with self.lock:
            for k, v in changes.items():
                setattr(self.balloons[sysid], k, v)

    def run(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        period = 1.0 / self.rate_hz
        per_second = max(1, round(self.rate_hz))
        k = 0
        t0 = next_t = time.monotonic()
        try:
            while not self.stop.is_set():
                t_us = 100_000_000 + int(k * period * 1e6)
                reel = self._winch_step(k * period) if self.winch else None
                frames = []
                with self.lock:
                    if reel is not None and k % per_second == 0:
                        w = self.winch_mav
                        status = WINCH_HEALTHY | WINCH_CLUTCH | (WINCH_MOVING if reel else 0)
                        frames.append(pack(w, w.winch_status_encode(t_us, self.line_m, reel, math.nan, math.nan,
                                                                    math.nan, 0, status)))  # fmt: skip
                    for b in self.balloons.values():
                        if not b.silent:
                            frames += self._balloon_frames(b, k, t_us, per_second, k * period)
                for f in frames:
                    sock.sendto(f, self.addr)
                k += 1
                next_t = t0 + k * period
                delay = next_t - time.monotonic()
                if delay > 0:
                    self.stop.wait(delay)
        finally:
            sock.close()

    def _winch_step(self, t: float) -> float:
        """The reel's speed now (out, then in, then out...): the line follows it."""
        leg_s = WINCH_MAX_M / WINCH_SPEED_MPS
        phase = (t % (2 * leg_s)) / leg_s
        reel = WINCH_SPEED_MPS if phase < 1.0 else -WINCH_SPEED_MPS
        self.line_m = WINCH_SPEED_MPS * leg_s * (phase if phase < 1.0 else 2.0 - phase)
        return reel

    def _balloon_frames(self, b: Balloon, k: int, t_us: int, per_second: int, t: float) -> list[bytes]:
        mav = b.mav
        out = []
        if k % per_second == 0:
            hb = mav.heartbeat_encode(mavlink.MAV_TYPE_FREE_BALLOON, mavlink.MAV_AUTOPILOT_GENERIC, 0, MODE_TAUT,
                                      mavlink.MAV_STATE_ACTIVE)  # fmt: skip
            health = 0 if b.sensors_lost else SENSORS & ~b.misfit
            st = mav.sys_status_encode(SENSORS, SENSORS, health, 0, 0xFFFF, -1, -1, 0, 0, 0, 0, 0, 0)
            est = 0 if b.sensors_lost else GOOD
            es = mav.estimator_status_encode(t_us, est, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            out += [pack(mav, hb), pack(mav, st), pack(mav, es)]
        alt = self.line_m if self.winch else b.alt_m
        grow = 1.0 + SHEAR_PER_M * alt if self.winch else 1.0
        wob = b.wobble_mps * math.sin(2 * math.pi * t / 30.0 + b.sysid)
        n, e = (b.n + wob) * grow, (b.e - 0.5 * wob) * grow
        out.append(pack(mav, mav.wind_cov_encode(t_us, n, e, math.nan, 0.2, 0.0, alt, b.acc, 0.0)))
        b.sent += 1
        b.last = (n, e, b.acc)
        return out


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("port", type=int)
    ap.add_argument("--balloons", type=int, default=2)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--winch", action="store_true")
    args = ap.parse_args(argv)
    feed = Feed(args.port, [Balloon(sysid=i + 1, n=2.0 + i, e=-1.0 + 0.7 * i) for i in range(args.balloons)],
                args.rate, args.winch)  # fmt: skip
    feed.start()
    try:
        while feed.is_alive():
            feed.join(0.5)
    except KeyboardInterrupt:
        feed.stop.set()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
