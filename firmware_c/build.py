"""Compile the C core for this host: a shared library per real type (``float``, the firmware as
flown; ``double``, the reference the lockstep harness holds against the Python core's float64), with the
C compiler the machine has (``cc``; no Python headers). The library's name carries a hash of the
sources and flags, so a stale build is never loaded; it is built at install (``make``) and else at
first use, into ``firmware_c/build/`` (or the user's cache if the package is read-only).

    python -m firmware_c.build            # both libraries, prints their paths
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
# the core as flashed, and the host's own entry points (host/: the batch hand-over of a replay)
SOURCES = sorted((HERE / "src").glob("*.c")) + sorted((HERE / "host").glob("*.c"))
HEADERS = sorted((HERE / "src").glob("*.h")) + sorted((HERE / "include").glob("*.h"))
FLAGS = ("-std=c99", "-O3", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-DBW_HOST_RECORDER")
REALS = {"float": ("-Wdouble-promotion",), "double": ("-DBW_DOUBLE",)}


class BuildError(RuntimeError):
    """The C core could not be built (no compiler, or it failed): a one-line reason."""


def _build_dirs() -> list[Path]:
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "balloon-wind"
    return [HERE / "build", cache]


def library(real: str = "float", extra: tuple[str, ...] = ()) -> Path:
    """The path of the host library for ``real`` ("float" or "double"), compiled if not yet built."""
    if real not in REALS:
        raise ValueError(f"real type {real!r}: 'float' or 'double'")
    return shared_library(f"libbwcore_{real}", SOURCES, HEADERS, FLAGS + REALS[real] + extra, "the C core",
                          "", (HERE / "include", HERE / "src"))  # fmt: skip


def shared_library(
    stem: str, sources: list[Path], headers: list[Path], flags: tuple[str, ...], what: str, hint: str = "",
    includes: tuple[Path, ...] = (),
) -> Path:
    """``stem``-<hash>.so built from ``sources`` with ``flags`` (the hash covers the flags, the sources and
    ``headers``): found in a build directory, else compiled there (the C core's, or another host helper's:
    sim_hil/native.py); an older build of the same stem is removed. ``what`` names it in errors, ``hint``
    ends the one about a missing compiler."""
    h = hashlib.sha256(" ".join(flags).encode())
    for p in list(sources) + list(headers):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    name = f"{stem}-{h.hexdigest()[:16]}.so"
    for d in _build_dirs():
        if (d / name).exists():
            return d / name
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise BuildError(f"{what} needs a C compiler (cc or gcc, or $CC) to build, and none was found{hint}")
    last = ""
    for d in _build_dirs():
        try:
            d.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(suffix=".so", dir=d)
            os.close(fd)
        except OSError as e:
            last = str(e)
            continue
        cmd = [cc, *flags, *(f"-I{i}" for i in includes), "-o", tmp, *map(str, sources), "-lm"]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True)
        except OSError as e:  # $CC names no program
            os.unlink(tmp)
            raise BuildError(f"{what} needs a C compiler to build, and {cc} cannot be run ({e.strerror})") from None
        if r.returncode != 0:
            os.unlink(tmp)
            first = (r.stderr.strip().splitlines() or ["no message"])[0]
            raise BuildError(f"{what} did not compile ({cc}): {first}")
        os.replace(tmp, d / name)  # atomic: a parallel build of the same sources writes the same file
        for old in d.glob(f"{stem}-*.so"):
            if old.name != name:
                old.unlink(missing_ok=True)
        return d / name
    raise BuildError(f"no writable place for {what}'s build: {last}")


def main() -> int:
    try:
        for real in REALS:
            print(library(real))
    except BuildError as e:
        print(f"firmware_c.build: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
