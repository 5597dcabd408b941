"""The simulator on the wire: sensor packets to a UDP endpoint or serial port, paced in real time or
``--speed N`` times faster, optionally in lockstep with the firmware.

Lockstep handshake: the firmware, like any MAVLink vehicle, sends its WIND_COV (and HEARTBEAT) back
on the link its sensor packets come from. WIND_COV.time_usec is the newest IMU sample the estimate
includes, so it says how far the firmware has got. Before sending a sample at simulated time t, the
simulator waits until the newest WIND_COV time is within ``window`` seconds of t. Nothing is lost on
loopback however fast the run. If no WIND_COV arrives for ``timeout`` seconds (firmware not running),
it stops waiting, counts a timeout, and waits again once WIND_COV reappears.
"""

from __future__ import annotations

import sys
import time

from balloon_core import userargs
from balloon_core.wire import Decoder, LinkStats, open_link
from sim_hil.packets import SensorPacketEncoder
from sim_hil.simulator import Simulation


class Lockstep:
    """Waits for the firmware's WIND_COV time before a sample is sent; also keeps the firmware's last
    SYS_STATUS (its own count of the packets it lost)."""

    def __init__(self, link, window_s: float, timeout_s: float) -> None:
        self.link = link
        self.dec = Decoder(LinkStats())
        self.window_us = int(window_s * 1e6)
        self.timeout_s = timeout_s
        self.fw_time_us = -1
        self.engaged = True
        self.timeouts = 0
        self.first_us: int | None = None  # the first sample's time: the firmware gets going from there
        self.sent_us = -1  # the newest sample time let through: no WIND_COV can be ahead of it
        self.fw_status = None  # the firmware's latest SYS_STATUS
        self.fw_status_at = 0.0

    def poll(self, wait_s: float) -> None:
        data = self.link.recv(wait_s)
        while data:
            for m in self.dec.feed(data, self.link.datagrams):
                kind = m.get_type()
                if kind == "WIND_COV":
                    if m.time_usec <= self.sent_us:  # not a stale one from before a restart
                        self.fw_time_us = max(self.fw_time_us, m.time_usec)
                    self.engaged = True
                elif kind == "SYS_STATUS":
                    self.fw_status, self.fw_status_at = m, time.monotonic()
            data = self.link.recv(0.0)

    def wait_for(self, t_us: int) -> None:
        """Block until the sample at ``t_us`` may be sent (then it counts as sent)."""
        if self.first_us is None or t_us < self.sent_us - 1_000_000:
            # the first sample, or time went back (the capture holds a restart): start again from here
            self.first_us, self.fw_time_us = t_us, -1
        self._wait(t_us)
        self.note_sent(t_us)

    def note_sent(self, t_us: int) -> None:
        """A sample at ``t_us`` went out (a small step back is reordering, a big one a restart)."""
        self.sent_us = max(self.sent_us, t_us) if t_us >= self.sent_us - 1_000_000 else t_us

    def _wait(self, t_us: int) -> None:
        horizon = (self.first_us if self.fw_time_us < 0 else self.fw_time_us) + self.window_us
        if t_us <= horizon:
            return
        if not self.engaged:
            self.poll(0.0)
            return
        deadline = time.monotonic() + self.timeout_s
        while t_us > self.fw_time_us + self.window_us:
            if time.monotonic() > deadline:
                self.timeouts += 1
                self.engaged = False
                return
            self.poll(0.02)

    def finish(self, wait_s: float) -> bool:
        """After the last sample: wait until the firmware has caught up with it and sent a SYS_STATUS
        after that. True if it did within ``wait_s``."""
        deadline = time.monotonic() + wait_s
        caught_up_at = None
        while time.monotonic() < deadline:
            self.poll(0.05)
            if caught_up_at is None and self.fw_time_us >= self.sent_us - 200_000:
                caught_up_at = time.monotonic()
            if caught_up_at is not None and self.fw_status is not None and self.fw_status_at > caught_up_at:
                return True
        return False

    def firmware_lost(self) -> int | None:
        """The firmware's own count of sensor packets lost on the way in (None: it never said)."""
        return None if self.fw_status is None else int(self.fw_status.errors_count1)


def stream(sim: Simulation, enc: SensorPacketEncoder, spec: str, speed: float, lockstep: bool,
           window_s: float = 0.5, timeout_s: float = 2.0, stop=lambda: False, progress=None) -> int:  # fmt: skip
    """Send every sample's frames to ``spec``; returns the number of IMU samples sent."""
    link = open_link(spec)
    ls = Lockstep(link, window_s, timeout_s)
    t0 = time.monotonic()
    n = 0
    try:
        for s in sim.samples():
            if stop():
                break
            if speed > 0:
                ahead = t0 + s.time_usec * 1e-6 / speed - time.monotonic()
                if ahead > 0.002:
                    time.sleep(ahead)
            if lockstep:
                ls.wait_for(s.time_usec)
            elif n % 100 == 0:
                ls.poll(0.0)  # drain what comes back
            for frame in enc.encode(s):
                link.send(frame)
            n += 1
            if progress is not None:
                progress.done = s.time_usec * 1e-6
    finally:
        link.close()
    if lockstep and ls.timeouts:
        print(f"balloon-sim: lockstep: {ls.timeouts} timeouts waiting for the firmware", file=sys.stderr)
    return n


def stream_udp(sim: Simulation, enc: SensorPacketEncoder, spec: str, args, progress=None) -> int:

    stop = userargs.stop_flag()
    return stream(sim, enc, spec, args.speed, args.lockstep, args.lockstep_window, 2.0, stop,
                  progress)  # fmt: skip
