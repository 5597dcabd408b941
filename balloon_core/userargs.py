"""Command-line argument checking shared by every program: argparse ``type=`` functions that turn a
bad value into a one-line error before any work starts, and a parser whose errors are one line.

Every user error of every program ends the same way (docs/usage.md, "Errors and exit codes"): exit
status 2 and ONE line on stderr, ``PROG: error: WHAT``. No usage block, no traceback.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import stat
import sys
import tempfile
from collections.abc import Callable
from typing import NoReturn

# a week of simulated flight (about an hour of computing); memory does not grow with it (the wind, the
# truth and the packets are streamed)
MAX_DURATION_S = 7 * 86400.0
MAX_SEED = 2**32 - 1
UDP_KINDS = ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")


class UserError(Exception):
    """A problem the user can fix (bad input file, ...): reported as one line, exit 2."""


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``PROG: error: MESSAGE`` (no usage block), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def fail(prog: str, message: object) -> int:
    """Print the one-line user error and return exit status 2."""
    text = " ".join(str(message).split()) or type(message).__name__
    print(f"{prog}: error: {text}", file=sys.stderr)
    return 2


class StopFlag:
    """Set by Ctrl-C (SIGINT) or SIGTERM instead of raising: ``stop()`` says whether to stop, and
    ``interrupted`` whether it was Ctrl-C (exit 130: the run could not finish) rather than a SIGTERM (a
    service told to stop, as ``balloon-sil`` stops its programs: exit 0 with the files finished)."""

    def __init__(self) -> None:
        self.signals: list[int] = []

    def __call__(self) -> bool:
        return bool(self.signals)

    @property
    def interrupted(self) -> bool:
        import signal

        return signal.SIGINT in self.signals


def stop_flag() -> StopFlag:
    """Install the SIGINT / SIGTERM handlers; the returned ``StopFlag`` says whether to stop."""
    import signal

    flag = StopFlag()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: flag.signals.append(signum))
    return flag


def ctrl_c_raises() -> object:
    """Ctrl-C (SIGINT) raises KeyboardInterrupt even when the process started with SIGINT ignored, as a shell starts
    a background job (``balloon-sim --out x.tlog & kill -INT $!``): for runs that do not poll a ``stop_flag`` (which
    takes SIGINT over in any case), so that every program stops on it alike (exit 130, nothing written). Returns the
    handler it replaced."""
    import signal

    return signal.signal(signal.SIGINT, signal.default_int_handler)


# what each optional part needs; `pip install balloon-wind` brings the firmware, simulator and live station
EXTRAS = {"postflight": ("pyulog", "xarray", "netCDF4"), "study": ("dask", "distributed", "pyarrow"),
          "web": ("aiohttp",)}


def require_extra(extra: str) -> None:
    """A UserError naming the extra to install if a module of ``extra`` is missing (exit 2, one line)."""
    import importlib.util

    missing = [m for m in EXTRAS[extra] if importlib.util.find_spec(m) is None]
    if missing:
        raise UserError(f"this needs {', '.join(missing)}: pip install 'balloon-wind[{extra}]' (or '[all]')")


# ---------------------------------------------------------------- numbers


def _number(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return x


def positive_float(text: str) -> float:
    """A finite number > 0 (nan, inf, 0 and negatives rejected)."""
    x = _number(text)
    if x <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return x


def nonneg_float(text: str) -> float:
    """A finite number >= 0."""
    x = _number(text)
    if x < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return x


def between(lo: float, hi: float) -> Callable[[str], float]:
    """An argparse type: a finite number from ``lo`` to ``hi``."""

    def check(text: str) -> float:
        x = _number(text)
        if not lo <= x <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo:g} .. {hi:g}, got {text!r}")
        return x

    return check


MIN_SPEED, MAX_SPEED = 0.01, 10000.0


def speed(text: str) -> float:
    """A pace: N x real time, 0.01 .. 10000, or 0 = as fast as possible."""
    x = nonneg_float(text)
    if x != 0.0 and not MIN_SPEED <= x <= MAX_SPEED:
        raise argparse.ArgumentTypeError(f"must be 0 (flat out) or {MIN_SPEED:g} .. {MAX_SPEED:g}, got {text!r}")
    return x


def positive_speed(text: str) -> float:
    """A pace: N x real time, 0.01 .. 10000."""
    x = positive_float(text)
    if not MIN_SPEED <= x <= MAX_SPEED:
        raise argparse.ArgumentTypeError(f"must be {MIN_SPEED:g} .. {MAX_SPEED:g}, got {text!r}")
    return x


def start_time(text: str) -> float:
    """A time since boot [s]: finite, >= 0."""
    return nonneg_float(text)


def duration(text: str) -> float:
    """Seconds: finite, > 0 and at most a week."""
    x = positive_float(text)
    if x > MAX_DURATION_S:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_DURATION_S:.0f} s (7 days), got {text!r}")
    return x


def _integer(text: str, lo: int, hi: int | None = None) -> int:
    """An integer from ``lo`` to ``hi`` (None: no upper end), written as Python writes one (0x.. too)."""
    try:
        n = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if n < lo or (hi is not None and n > hi):
        raise argparse.ArgumentTypeError(f"must be {lo} .. {hi}, got {text!r}" if hi is not None
                                         else f"must be >= {lo}, got {text!r}")  # fmt: skip
    return n


def seed(text: str) -> int:
    """An integer 0 .. 2^32 - 1."""
    return _integer(text, 0, MAX_SEED)


def sysid(text: str) -> int:
    """A MAVLink system id of a vehicle or ground station: an integer 1 .. 255 (0 is the broadcast address)."""
    return _integer(text, 1, 255)


# ---------------------------------------------------------------- endpoints and files


def _port(spec: str, text: str) -> None:
    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"{spec}: port must be 1..65535, got {text!r}")


COM_PORT = re.compile(r"COM\d+(:\d+)?$", re.IGNORECASE)  # a Windows serial port, optionally with its baud rate


def serial_path(spec: str) -> bool:
    """A serial port under /dev (``/dev/ttyUSB0``, ``/dev/ttyUSB0:57600``, ``/dev/pts/3``): a character device, or a
    name directly in /dev that does not exist yet (a port not plugged in: opening it is then the error). A file under
    /dev (``/dev/shm/flight.tlog``, a memory file system) is a file, and the rules for files hold for it."""
    if not spec.startswith("/dev/"):
        return False
    path, sep, baud = spec.rpartition(":")
    if not (sep and baud.isdigit()):
        path = spec
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return os.path.dirname(path) == "/dev"


def is_link(spec: str) -> bool:
    """A network endpoint or a serial port (not a file)."""
    return spec.startswith(UDP_KINDS) or serial_path(spec) or "://" in spec or bool(COM_PORT.match(spec))


def link(spec: str) -> str:
    """``udpin:HOST:PORT``, ``udpout:HOST:PORT``, ``/dev/ttyX[:BAUD]``, a pyserial URL or ``COMn[:BAUD]``."""
    if spec.startswith(UDP_KINDS):
        parts = spec.split(":")
        if len(parts) != 3 or not parts[1]:
            raise argparse.ArgumentTypeError(f"{spec}: expected {parts[0]}:HOST:PORT")
        _port(spec, parts[2])
        if not spec.startswith(("udpin:", "udpout:")):
            raise argparse.ArgumentTypeError(f"{spec}: only udpin: and udpout: endpoints are supported")
        return spec
    if serial_path(spec) or COM_PORT.match(spec):
        path, sep, baud = spec.rpartition(":")
        if sep and baud.isdigit():
            if int(baud) <= 0:
                raise argparse.ArgumentTypeError(f"{spec}: baud rate must be > 0")
        elif sep and not path.startswith("/dev/"):
            raise argparse.ArgumentTypeError(f"{spec}: baud rate must be a positive integer, got {baud!r}")
        return spec
    if "://" in spec:
        return spec
    raise argparse.ArgumentTypeError(f"{spec}: not a UDP endpoint (udpin:HOST:PORT, udpout:HOST:PORT) or serial port")


def scheduler_address(text: str) -> str:
    """A Dask scheduler's address: ``[PROTOCOL://]HOST:PORT`` with a port 1..65535 (``tcp://10.0.0.5:8786``)."""
    rest = text.split("://", 1)[1] if "://" in text else text
    host, sep, port = rest.rpartition(":")
    if not (sep and host and port.isdigit() and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(f"expected [PROTOCOL://]HOST:PORT (e.g. tcp://10.0.0.5:8786), got {text!r}")
    return text


def count(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, 1)


def bind(text: str) -> tuple[str, int]:
    """``HOST:PORT`` to listen on (``[::1]:8000`` for IPv6; port 0: any free one)."""
    host, sep, port = text.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT (e.g. 127.0.0.1:8000), got {text!r}")
    return host, int(port)


def output_path(path: str) -> str:
    """A file to be written: its directory exists and is writable, and it is not a directory."""
    if not path:
        raise argparse.ArgumentTypeError("empty output path")
    if path.endswith(tuple(c for c in (os.sep, os.altsep) if c)):
        raise argparse.ArgumentTypeError(f"{path}: names a directory (a file is expected)")
    if os.path.isdir(path):
        raise argparse.ArgumentTypeError(f"{path}: is a directory")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise argparse.ArgumentTypeError(f"{path}: directory {parent} does not exist")
    if not _can_create_in(parent) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise argparse.ArgumentTypeError(f"{path}: not writable")
    return path


def _can_create_in(directory: str) -> bool:
    """Whether a file can be made in ``directory`` (each product is written beside its final name, then renamed):
    tried with a file made and removed at once, as ``os.access`` says yes to root on a read-only file system or in
    /sys."""
    if not os.access(directory, os.W_OK | os.X_OK):
        return False
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-check-", dir=directory)
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def plot_path(path: str) -> str:
    """A figure to be written (``output_path``), its format named by its extension: one matplotlib writes (.png,
    .pdf, .svg, ...); without matplotlib (the extra not installed) the program says so when it draws."""
    output_path(path)
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        return path
    kinds = FigureCanvasBase.get_supported_filetypes()
    if os.path.splitext(path)[1].lower().lstrip(".") not in kinds:
        raise argparse.ArgumentTypeError(f"{path}: a figure's name ends in one of .{', .'.join(sorted(kinds))}")
    return path


def output_dir(path: str) -> str:
    """A directory to write into: it exists and is writable, or its parent does (it will be created)."""
    if os.path.isdir(path):
        if not _can_create_in(path):
            raise argparse.ArgumentTypeError(f"{path}: directory not writable")
        return path
    if os.path.exists(path):
        raise argparse.ArgumentTypeError(f"{path}: exists and is not a directory")
    output_path(path.rstrip(os.sep) or path)  # the parent must exist and be writable
    return path


def input_file(path: str) -> str:
    """An existing, readable regular file."""
    if not os.path.exists(path):
        raise argparse.ArgumentTypeError(f"{path}: no such file")
    if not os.path.isfile(path):
        raise argparse.ArgumentTypeError(f"{path}: not a regular file")
    if not os.access(path, os.R_OK):
        raise argparse.ArgumentTypeError(f"{path}: not readable")
    return path


def source(spec: str) -> str:
    """Where MAVLink comes from: an existing file (tlog or raw capture), a UDP endpoint or a serial port."""
    if is_link(spec) and not os.path.isfile(spec):
        return link(spec)
    if os.path.exists(spec):
        return input_file(spec)
    raise argparse.ArgumentTypeError(f"{spec}: no such file, and not a UDP endpoint or serial port")


def sink(spec: str) -> str:
    """Where MAVLink goes: a UDP endpoint, a serial port or a file (``FILE.tlog``, or raw bytes)."""
    if is_link(spec):
        return link(spec)
    return output_path(spec)


def tlog_sink(spec: str) -> str:
    """A UDP endpoint, a serial port or a ``.tlog`` file."""
    if not is_link(spec) and not spec.endswith(".tlog"):
        raise argparse.ArgumentTypeError(f"{spec}: expected a UDP endpoint, a serial port or FILE.tlog")
    return sink(spec)


# ---------------------------------------------------------------- one rule for every output option


def _same(a: str, b: str) -> bool:
    """The same file: the same real path (through symlinks), or the same inode if both exist."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(inputs: dict[str, str | None], outputs: dict[str, str | None]) -> None:
    """Before any work: a UserError naming the option if an output (a) is an input of the same run,
    (b) is another output of the same run or (c) cannot be written. Keys are how the user named the
    file (``"--out"``, ``"--out (its 1 s averages)"``); values None (not given) and links (UDP, serial)
    are skipped."""
    ins = {k: v for k, v in inputs.items() if v and not is_link(v)}
    outs = {k: v for k, v in outputs.items() if v and not is_link(v)}
    seen: list[tuple[str, str]] = []
    for name, path in outs.items():
        if os.path.realpath(path).startswith("/proc/") or os.path.realpath(path) == "/proc":
            raise UserError(f"{name} {path}: cannot be written (under /proc)")
        try:
            output_path(path)
        except argparse.ArgumentTypeError as exc:
            raise UserError(f"{name} {exc}") from None
        for iname, ipath in ins.items():
            if _same(path, ipath):
                raise UserError(f"{name} {path} is the input {iname} {ipath}")
        for oname, opath in seen:
            if _same(path, opath):
                raise UserError(f"{name} {path} is also the output {oname} {opath}")
        seen.append((name, path))
