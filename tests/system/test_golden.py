"""The restructured firmware gives the same output as the recorded one (tools/golden.py): the C core's
tlog bit for bit, the Python core's and the smoother's floats within a stated tolerance (numpy's BLAS kernels
differ between CPUs in the last bits).

Inputs are frozen files (tests/data/golden): two simulated flights, a restart in flight, a hostile
serial capture (garbage, corrupt frames, a dropout, duplicates, swapped blocks, a reboot), a PX4 ULog
and an ArduPilot DataFlash log. Compared: the whole output tlog of balloon-fw, the Python core's discrete
history and states, and the reprocessed product's variables. Delete or re-record only
when an issue changes the estimator on purpose."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

import golden  # noqa: E402

pytestmark = [pytest.mark.slow]

EXPECTED = json.loads((golden.GOLDEN / "expected.json").read_text())


@pytest.fixture(scope="module")
def got() -> dict:
    return golden.compute()


@pytest.mark.parametrize("kind", sorted(EXPECTED))
def test_same_output(got, kind):
    assert golden.differences(EXPECTED[kind], got[kind], kind) == []


def test_the_golden_check_can_fail(got):
    """Every flight has its own history, and the comparison sees a change far below any the estimator's
    tuning makes (1e-5 relative in one state of one checkpoint), while ignoring one in the last bits."""
    assert len({d["events"] + repr(d["states"][-1]) for d in got["digest"].values()}) == len(got["digest"])
    d = json.loads(json.dumps(got["digest"]))
    name = sorted(d)[0]
    last = d[name]["states"][-1]
    i = max(range(len(last)), key=lambda k: abs(last[k]))
    last[i] *= 1.0 + 1e-15
    assert golden.differences(got["digest"], d) == []
    last[i] *= 1.0 + 1e-5
    assert golden.differences(got["digest"], d) == [f"/{name}/states[{len(d[name]['states']) - 1}][{i}]"]
