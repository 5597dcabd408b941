"""The C core's builds (firmware_c/Makefile): strict C99 warnings as errors, the sanitised replay
(address + undefined behaviour) on a hostile stream, and the Cortex-M4F image under QEMU, whose
outputs must equal the host build's (skipped with a reason where the cross tools are not installed)."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import pytest

from balloon_core.config import Design
from firmware_py import lockstep
from firmware_py.estimator.state import FilterConfig
from tests.system.test_lockstep import base_stream

CORE = Path(__file__).resolve().parents[2] / "firmware_c"
pytestmark = pytest.mark.slow


def make(*targets: str) -> None:
    r = subprocess.run(["make", "-s", "-C", str(CORE), *targets], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr


def hostile(n: int = 6000) -> list:
    """The base flight with a reboot, a gap, NaN and out-of-range samples in it."""
    s = list(base_stream()[:n])
    s[1000] = s[1000]._replace(ax=float("nan")) if hasattr(s[1000], "ax") else s[1000]
    del s[2000:2300]
    t0 = s[4000].t_us
    s[4000:] = [x._replace(t_us=x.t_us - t0 + 5) for x in s[4000:]]
    return s


@pytest.fixture(scope="module")
def stream(tmp_path_factory):
    path = tmp_path_factory.mktemp("c") / "stream.bin"
    lockstep.write_stream(str(path), Design(), FilterConfig(float32=True), hostile())
    return path


def test_strict_builds_and_the_sanitised_replay(stream):
    """-std=c99 -Wall -Wextra -Werror -Wdouble-promotion (float) / -DBW_DOUBLE; the ASan+UBSan replay runs
    the hostile stream without a report and writes what the plain build writes, bit for bit."""
    make("host", "replay", "asan")
    build = CORE / "build"
    for exe in ("replay_float", "replay_asan"):
        r = subprocess.run([str(build / exe), str(stream), str(stream.with_suffix(f".{exe}"))], capture_output=True,
                           text=True, timeout=300)  # fmt: skip
        assert r.returncode == 0 and "runtime error" not in r.stderr and "ERROR" not in r.stderr, r.stderr
    a = lockstep.read_outputs(str(stream.with_suffix(".replay_asan")))
    b = lockstep.read_outputs(str(stream.with_suffix(".replay_float")))
    assert len(a) == len(b) > 4000
    equal, line = lockstep.compare_outputs(a, b)
    assert equal and "100.0 % bit-identical" in line, line
    assert len(set(a["reset_count"])) >= 2  # the reboot re-initialised the filter


def test_replay_program_equals_the_binding(stream):
    """The stand-alone replay (what the target runs) and the ctypes binding give the same numbers."""
    make("replay")
    out = stream.with_suffix(".f")
    subprocess.run([str(CORE / "build" / "replay_float"), str(stream), str(out)], check=True, timeout=300)
    rows = lockstep.read_outputs(str(out))
    from firmware_py.core_c import CEstimator

    est = CEstimator(Design(), dataclasses.replace(FilterConfig(), float32=True))
    k = 0
    for s in hostile():
        if type(s) is lockstep.BaroSample:
            est.on_baro(*s)
            continue
        est.on_imu(*s)
        assert rows["mode"][k] == est.ekf.mode and rows["f"][k][5 + 12] == est.ekf.x[12]
        k += 1
    assert k == len(rows)


@pytest.mark.skipif(not (shutil.which("arm-none-eabi-gcc") and shutil.which("qemu-system-arm")),
                    reason="arm-none-eabi-gcc / qemu-system-arm not installed")  # fmt: skip
def test_cortex_m4_under_qemu_equals_the_host_build(stream, tmp_path):
    make("arm-elf", "replay")
    from tools.arm import qemu

    s = tmp_path / "s.bin"
    s.write_bytes(stream.read_bytes())
    qemu(CORE / "build" / "arm" / "replay.elf", s, tmp_path / "arm.bin", tmp_path / "st.txt")
    subprocess.run([str(CORE / "build" / "replay_float"), str(s), str(tmp_path / "host.bin")], check=True)
    equal, line = lockstep.compare_outputs(lockstep.read_outputs(str(tmp_path / "arm.bin")),
                                           lockstep.read_outputs(str(tmp_path / "host.bin")))  # fmt: skip
    assert equal, line
    stats = (tmp_path / "st.txt").read_text().split()
    assert int(stats[stats.index("median_instructions") + 1]) > 1000  # the timer counted


def test_the_c_defaults_are_the_design_files_and_the_filters():
    """``bw_config_default`` (what a C user starts from) is the Python core's default design and ``[filter]``, field
    for field (its rope's cross-flow drag once assumed a 3 mm rope where the design's 0.02 kg/m is 4.7 mm)."""
    import ctypes
    import math

    from firmware_py.core_c import config_struct, load

    lib, Config, _, _ = load("double")
    c = Config()
    lib.bw_config_default(ctypes.byref(c))
    want = config_struct(Design(), FilterConfig(), Config)
    for name, _ in Config._fields_:
        a, b = getattr(c, name), getattr(want, name)
        assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-12), name


def test_the_c_tilt_term_follows_the_declared_walk_as_the_pythons():
    """``bw_lean_bias_rad`` is ``consistency.lean_bias_rad`` over a long field day: no bound on the walk in either core
    (a short lockstep flight cannot tell: the walk's variance passes a bound only after tens of minutes)."""
    import ctypes

    from firmware_py.core_c import load
    from firmware_py.estimator.consistency import lean_bias_rad

    lib, _, _, _ = load("double")
    f = lib.bw_lean_bias_rad
    f.restype, f.argtypes = ctypes.c_double, [ctypes.c_double, ctypes.c_double]
    for walk in (0.0, 0.0005, 0.001, 0.002):
        for t in (-1.0, 0.0, 600.0, 3600.0, 14400.0, 28800.0):
            assert f(walk, t) == pytest.approx(lean_bias_rad(walk, t), rel=1e-12), (walk, t)
