"""The golden test's window into the estimator: the one place that follows the code's module names.

After every sample the firmware takes, its float64 state (x, P, q, mode, counters) goes into one hash.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np


def _messages(fw, path: Path):
    """Every sample of the flight, into ``fw`` as the firmware program takes it."""
    if path.suffix in (".ulg", ".bin"):
        from postflight.logs import read_flight

        for s in read_flight(str(path)).samples():
            fw.push(s)
        return
    from balloon_core.wire import capture_messages

    for m in capture_messages(str(path), fw.stats):
        fw.handle(m)


def run_digest(path: Path) -> str:
    from balloon_core.config import Design
    from firmware_py.app import Firmware

    fw = Firmware(Design(), sink=None)
    fw.sinks = [type("S", (), {"send_at": lambda self, f, t: None})()]
    h = hashlib.sha256()
    orig = fw._step

    def step(s):
        orig(s)
        e = fw.est
        h.update(np.asarray(e.ekf.x, np.float64).tobytes())
        h.update(np.asarray(e.ekf.P, np.float64).tobytes())
        h.update(np.asarray(e.ekf.q, np.float64).tobytes())
        h.update(repr((e.ekf.mode, sorted(e.counters.as_dict().items()), e.unconfirmed)).encode())

    fw._step = step
    _messages(fw, path)
    fw.flush()
    return h.hexdigest()
