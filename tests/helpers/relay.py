"""A lossy UDP relay on loopback for the link tests: drops a fraction of the datagrams and swaps
some neighbours (reordering), in both directions (the reply path goes back to the last sender)."""

from __future__ import annotations

import random
import socket
import threading


class LossyRelay:
    def __init__(self, target_port: int, loss: float = 0.1, reorder: float = 0.05, seed: int = 1,
                 blackout: tuple[int, int] | None = None) -> None:  # fmt: skip
        """``blackout`` = (first, count): the datagrams toward the target numbered first .. first + count - 1
        are all dropped (a radio shadow), beside the random ``loss``."""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.target = ("127.0.0.1", target_port)
        self.client: tuple[str, int] | None = None
        self.loss, self.reorder = loss, reorder
        self.rng = random.Random(seed)
        self.dropped = self.forwarded = 0
        self.dropped_to_target = 0  # of them, on the way to the target
        self.blackout = blackout
        self._to_target = 0
        self._held: dict[tuple, bytes] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> LossyRelay:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            if addr == self.target:
                dest = self.client
            else:
                self.client = addr
                dest = self.target
            if dest is None:
                continue
            k = -1
            if dest == self.target:
                k, self._to_target = self._to_target, self._to_target + 1
            dark = self.blackout is not None and self.blackout[0] <= k < self.blackout[0] + self.blackout[1]
            if dark or self.rng.random() < self.loss:
                self.dropped += 1
                self.dropped_to_target += dest == self.target
                continue
            if dest in self._held:
                self.sock.sendto(data, dest)  # the later one overtakes the held one
                self.sock.sendto(self._held.pop(dest), dest)
                self.forwarded += 2
            elif self.rng.random() < self.reorder:
                self._held[dest] = data
            else:
                self.sock.sendto(data, dest)
                self.forwarded += 1
