"""Products under their final names only when complete: the one helper every program writes its files
through (docs/usage.md, "Errors and exit codes").

A product is written under a temporary name beside its final one (``.NAME.part-PID.EXT``: the same
directory, hence the same file system, so the rename is atomic; the extension kept, so a writer that
picks the format from the name still does) and renamed to its final name by ``Products.commit()``, all
of a run's products together. An error, Ctrl-C or SIGTERM (``sigterm_raises``) leaves the with-block
by an exception and every temporary file is removed: nothing half-written is left under a final name,
and an older product of the same name stays as it was. Only a SIGKILL can leave a temporary name.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from typing import IO, Any

PART = ".part-"


def part_path(final: str) -> str:
    """The temporary name of ``final``: hidden, beside it, this process's, same extension."""
    folder, base = os.path.split(os.path.abspath(final))
    stem, ext = os.path.splitext(base)
    return os.path.join(folder, f".{stem}{PART}{os.getpid()}{ext}")


class Products:
    """A run's output files, each written under ``path(final)`` and renamed by ``commit()``.

    Use as a context manager: whatever is not committed when the block is left (an exception, or a run
    that decided not to commit) is removed."""

    def __init__(self) -> None:
        self._pending: list[tuple[str, str]] = []  # (temporary, final)

    def path(self, final: str) -> str:
        """Where to write the product ``final`` now (its temporary name)."""
        tmp = part_path(final)
        self._pending.append((tmp, final))
        return tmp

    def open(self, final: str, mode: str = "w", **kw: Any) -> IO:
        """``open()`` on the temporary name of ``final``."""
        return open(self.path(final), mode, **kw)

    @property
    def finals(self) -> list[str]:
        return [final for _, final in self._pending]

    def commit(self) -> list[str]:
        """Rename every product written to its final name; returns the final names (those written)."""
        done = []
        for tmp, final in self._pending:
            if os.path.exists(tmp):
                os.replace(tmp, final)
                done.append(final)
        self._pending = []
        return done

    def discard(self) -> None:
        """Remove every temporary file not committed (the final names are not touched)."""
        for tmp, _ in self._pending:
            with contextlib.suppress(OSError):
                os.remove(tmp)
        self._pending = []

    def __enter__(self) -> Products:
        return self

    def __exit__(self, *exc: object) -> None:
        self.discard()


@contextlib.contextmanager
def atomic_open(final: str, mode: str = "w", **kw: Any) -> Iterator[IO]:
    """One file: written under its temporary name, renamed when the block ends normally, else removed."""
    with Products() as products:
        with products.open(final, mode, **kw) as fh:
            yield fh
        products.commit()


def sigterm_raises() -> None:
    """SIGTERM raises KeyboardInterrupt (as Ctrl-C does) so that a run's ``finally`` and ``with`` blocks
    remove its temporary files; for runs that do not poll a ``userargs.stop_flag``."""

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)
