"""Golden output of the firmware: record once, check after a behaviour-preserving change.

``python tools/golden.py make-inputs`` writes the frozen input flights (tests/data/golden/*.gz);
``python tools/golden.py record`` writes tests/data/golden/expected.json from the current code;
``python tools/golden.py check`` (and tests/system/test_golden.py) compares:
- bit for bit, the whole output tlog of ``balloon-fw`` (the C core: WIND_COV float32 fields, HEARTBEAT, SYS_STATUS,
  WIND, ESTIMATOR_STATUS, STATUSTEXT, timestamps). The C core is built without ``-march`` and is the same
  machine code on every x86-64 CPU;
- the Python core's history, in process: its discrete history (mode, counters, unconfirmed resets after every
  sample) exactly, and its state (x, sqrt diag P) at checkpoints within ``RTOL``;
- the reprocessed product's variables (``balloon-gs reprocess``): integer and text variables exactly, float
  variables by their moments within ``RTOL``.
The Python core and the smoother run on numpy, whose BLAS kernels differ from one CPU to another in the last
bits: their floats are compared with a stated tolerance, never by a hash of their bytes.
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
# floats of the Python core and the smoother: the last bits differ between CPUs' BLAS kernels (relative
# differences of 1e-15 growing to ~1e-12 over a flight); a change of the estimator moves them by far more
RTOL, ATOL = 1e-7, 1e-10
CHECKPOINTS = 24  # states kept per flight, evenly over its samples, and the last


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


def _digest(path: Path) -> dict:
    """The Python core's history after every sample the firmware takes, in process: the one place here
    that follows the code's names. ``events``: sha256 of the discrete history (mode, counters, unconfirmed
    resets); ``states``: x and sqrt diag P at ``CHECKPOINTS`` samples and the last, compared within RTOL.
    The output tlog above is the default core's (the C core)."""
    from balloon_core.config import Design
    from firmware_py.app import Firmware
    from firmware_py.estimator.state import FilterConfig

    fw = Firmware(Design(), FilterConfig(core="py"), sink=None)
    fw.sinks = [type("S", (), {"send_at": lambda self, f, t: None})()]
    h = hashlib.sha256()
    states: list[np.ndarray] = []
    orig = fw._step

    def step(s):
        orig(s)
        e = fw.est
        h.update(repr((e.ekf.mode, sorted(e.counters.as_dict().items()), e.unconfirmed)).encode())
        states.append(np.concatenate([np.asarray(e.ekf.x, np.float64), np.sqrt(np.abs(np.diag(e.ekf.P)))]))

    fw._step = step
    _messages(fw, path)
    fw.flush()
    idx = sorted({*np.linspace(0, len(states) - 1, CHECKPOINTS).astype(int).tolist()}) if states else []
    return {"events": h.hexdigest(), "samples": len(states), "states": [[float(v) for v in states[i]] for i in idx]}


def _moments(a: np.ndarray) -> list[float]:
    """Count of NaN, sum, sum of |a| and of a**2 over the finite values: a float variable's fingerprint."""
    a = np.asarray(a, np.float64).ravel()
    f = a[np.isfinite(a)]
    return [float(a.size - f.size), float(f.sum()), float(np.abs(f).sum()), float((f * f).sum())]


def _reprocess(path: Path, tmp: Path) -> dict:
    import netCDF4  # noqa: PLC0415

    out = tmp / (path.name + ".nc")
    subprocess.run(_program("ground_station", "reprocess", str(path), "--out", str(out), "--quiet"), check=True,
                   capture_output=True, env=_ENV)  # fmt: skip
    res: dict = {}
    with netCDF4.Dataset(out) as ds:
        ds.set_auto_mask(False)
        for k, v in ds.variables.items():
            a = np.ascontiguousarray(v[:])
            res[k] = _moments(a) if a.dtype.kind == "f" else hashlib.sha256(a.tobytes()).hexdigest()
    return res


def differences(expected: object, got: object, where: str = "") -> list[str]:
    """Where ``got`` differs from ``expected``: strings and integers exactly, floats within RTOL/ATOL."""
    if isinstance(expected, dict):
        if not isinstance(got, dict):
            return [where or "/"]
        return [d for k in expected for d in differences(expected[k], got.get(k), f"{where}/{k}")]
    if isinstance(expected, list):
        if not isinstance(got, list) or len(got) != len(expected):
            return [where]
        return [d for i, (e, g) in enumerate(zip(expected, got)) for d in differences(e, g, f"{where}[{i}]")][:1]
    if isinstance(expected, float) and isinstance(got, (int, float)):
        same = (np.isnan(expected) and np.isnan(got)) or abs(got - expected) <= ATOL + RTOL * abs(expected)
        return [] if same else [where]
    return [] if expected == got else [where]


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
    bad = differences(expected, got)
    print("golden: the same" if not bad else "golden: DIFFERENT " + ", ".join(bad))
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
