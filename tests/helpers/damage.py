"""Damaged bytes for the readers' tests: flipped bits, inserted garbage (magic bytes among it), dropped
runs and a cut tail, drawn from one ``random.Random``."""

from __future__ import annotations

import random


def damaged(data: bytes, rng: random.Random, flips: int, inserts: int, drops: int) -> bytes:
    """``data`` with ``flips`` flipped bits (bad CRCs, lengths, message ids, magic, times), ``inserts`` runs of
    garbage (some of it 0xFD / 0xFE), ``drops`` dropped runs, and up to 50 bytes cut off the end (inside a frame)."""
    out = bytearray(data)
    for _ in range(flips):
        k = rng.randrange(len(out))
        out[k] ^= 1 << rng.randrange(8)
    for _ in range(inserts):
        k = rng.randrange(len(out))
        out[k:k] = bytes(rng.choice((0xFD, 0xFE, rng.randrange(256))) for _ in range(rng.randrange(1, 40)))
    for _ in range(drops):
        k = rng.randrange(len(out))
        del out[k : k + rng.randrange(1, 30)]
    return bytes(out[: len(out) - rng.randrange(0, 50)])
