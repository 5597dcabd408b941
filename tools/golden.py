"""Golden output of the firmware: record once, check after a behaviour-preserving change.

``python tools/golden.py make-inputs`` writes the frozen input flights (tests/data/golden/*.gz);
``python tools/golden.py record`` writes tests/data/golden/expected.json from the current code;
``python tools/golden.py check`` (and tests/system/test_golden.py) compares, bit for bit:
- the whole output tlog of ``balloon-fw`` (WIND_COV float32 fields, HEARTBEAT, SYS_STATUS, WIND, ESTIMATOR_STATUS,
  STATUSTEXT, timestamps);
- a float64 digest of the estimator's state (x, P, q, mode, counters) after every sample, in process;
- the reprocessed product's variables (``balloon-gs reprocess``: causal and smoothed wind, float64).
Re-record only when an issue changes the estimator on purpose, and say so in the commit.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "data" / "golden"
DATA = ROOT / "tests" / "data"
# flights the firmware reads directly (tlog or raw capture), frozen as gzip files
FW_FLIGHTS = ("paper-reference.tlog", "reduced-balloon.tlog", "join-in-flight.tlog", "hostile.raw")
# logs read through the post-flight readers (the estimator digest only)
LOGS = ("pyulog-sample.ulg", "balloon-sim.bin")
REPROCESS = ("paper-reference.tlog", "balloon-sim.bin")


def _frames_tlog(data: bytes) -> list[tuple[bytes, bytes]]:
    """(timestamp, frame) pairs of a tlog (MAVLink 2 frames only: what the simulator writes)."""
    out, i = [], 0
    while i + 8 < len(data):
        ts = data[i : i + 8]
        assert data[i + 8] == 0xFD
        n = 12 + data[i + 9] + (13 if data[i + 10] & 1 else 0)
        out.append((ts, data[i + 8 : i + 8 + n]))
        i += 8 + n
    return out


def make_inputs() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for name, scenario, duration, seed in (("paper-reference", "paper-reference", 120, 3),
                                               ("reduced-balloon", "reduced-balloon", 120, 5)):  # fmt: skip
            out = Path(tmp) / f"{name}.tlog"
            args = ["--scenario", scenario, "--duration", str(duration), "--seed", str(seed), "--out", str(out),
                    "--truth", str(Path(tmp) / "t.csv")]  # fmt: skip
            subprocess.run(_program("sim_hil", *args), check=True, env=_ENV)
            (GOLDEN / f"{name}.tlog.gz").write_bytes(gzip.compress(out.read_bytes(), mtime=0))
        frames = _frames_tlog(gzip.decompress((GOLDEN / "reduced-balloon.tlog.gz").read_bytes()))
        # a restart in flight: the log starts 40 s after the sensor's boot
        tail = frames[len(frames) // 3 :]
        (GOLDEN / "join-in-flight.tlog.gz").write_bytes(gzip.compress(b"".join(t + f for t, f in tail), mtime=0))
        # a hostile serial capture: garbage, corrupt frames, a dropout, duplicated and swapped blocks, a reboot
        rng = np.random.default_rng(2026)
        pr = [f for _, f in _frames_tlog(gzip.decompress((GOLDEN / "paper-reference.tlog.gz").read_bytes()))]
        out = bytearray()
        for k, f in enumerate(pr):
            if 3000 <= k < 3200:  # a 1.5 s dropout
                continue
            if k % 997 == 0:
                out += rng.integers(0, 256, int(rng.integers(1, 60)), dtype=np.uint8).tobytes()
            if k % 613 == 0:
                f = bytearray(f)
                f[int(rng.integers(10, len(f)))] ^= 0x55
            out += f
            if k % 1499 == 0:
                out += f  # a duplicate
        block = bytes(out)
        swap = block[: len(block) // 2] + block[len(block) // 2 + 5000 : len(block) // 2 + 9000] + \
            block[len(block) // 2 : len(block) // 2 + 5000] + block[len(block) // 2 + 9000 :]
        hostile = swap + block[: len(block) // 4]  # a reboot: the sender's clock starts again
        (GOLDEN / "hostile.raw.gz").write_bytes(gzip.compress(hostile, mtime=0))


# the programs of this checkout (not of whatever is installed): python -m with the checkout first on the path
_ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _program(package: str, *args: str) -> list[str]:
    return [sys.executable, "-m", package, *args]


def _unpack(name: str, tmp: Path) -> Path:
    src = GOLDEN / f"{name}.gz" if (GOLDEN / f"{name}.gz").exists() else DATA / name
    dst = tmp / name
    if src.suffix == ".gz":
        dst.write_bytes(gzip.decompress(src.read_bytes()))
    else:
        shutil.copy(src, dst)
    return dst


def _fw_output(path: Path, tmp: Path) -> str:
    out = tmp / (path.name + ".out.tlog")
    subprocess.run(_program("firmware_py", "--in", str(path), "--out", str(out)), check=True, capture_output=True,
                   env=_ENV)  # fmt: skip
    return hashlib.sha256(out.read_bytes()).hexdigest()


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


def _digest(path: Path) -> str:
    """sha256 over the estimator's float64 state (x, P, q, mode, counters) after every sample the
    firmware takes, in process: the one place here that follows the code's names. The Python core's
    (the reference); the output tlog above is the default core's (the C core: the same bytes)."""
    from balloon_core.config import Design
    from firmware_py.app import Firmware
    from firmware_py.estimator.state import FilterConfig

    fw = Firmware(Design(), FilterConfig(core="py"), sink=None)
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


def _reprocess(path: Path, tmp: Path) -> dict[str, str]:
    import netCDF4  # noqa: PLC0415

    out = tmp / (path.name + ".nc")
    subprocess.run(_program("ground_station", "reprocess", str(path), "--out", str(out), "--quiet"), check=True,
                   capture_output=True, env=_ENV)  # fmt: skip
    with netCDF4.Dataset(out) as ds:
        ds.set_auto_mask(False)
        return {k: hashlib.sha256(np.ascontiguousarray(v[:]).tobytes()).hexdigest() for k, v in ds.variables.items()}


def compute() -> dict:
    sys.path.insert(0, str(ROOT))
    res: dict = {"firmware": {}, "digest": {}, "reprocess": {}}
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        for name in FW_FLIGHTS:
            p = _unpack(name, tmp)
            res["firmware"][name] = _fw_output(p, tmp)
            res["digest"][name] = _digest(p)
        for name in LOGS:
            res["digest"][name] = _digest(_unpack(name, tmp))
        for name in REPROCESS:
            res["reprocess"][name] = _reprocess(_unpack(name, tmp), tmp)
    return res


def main(argv: list[str]) -> int:
    cmd = argv[0] if argv else "check"
    if cmd == "make-inputs":
        make_inputs()
        return 0
    if cmd == "record":
        (GOLDEN / "expected.json").write_text(json.dumps(compute(), indent=1, sort_keys=True) + "\n")
        return 0
    expected = json.loads((GOLDEN / "expected.json").read_text())
    got = compute()
    bad = [f"{k}/{n}" for k in expected for n in expected[k] if expected[k][n] != got[k].get(n)]
    print("golden: identical" if not bad else "golden: DIFFERENT " + ", ".join(bad))
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
