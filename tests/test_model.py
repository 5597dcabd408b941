"""The filter's model: Jacobians against finite differences, measurement rows against perturbation."""

import copy
import math

import numpy as np
import pytest

from firmware_py.config import Design
from firmware_py.control import Estimator
from firmware_py.ekf import FusionStatus
from firmware_py.measurements import fuse_accel, fuse_heading
from firmware_py.model import BalloonModel, Forces, accelerations
from firmware_py.state import ATT_D, ATT_N, MODE_FREE, N_STATES

MODEL = BalloonModel.from_design(Design())


def acc(x, taut):
    f = accelerations(MODEL, 1.2, *x, taut, Forces())
    return np.array([f.an, f.ae, f.ad]), f


@pytest.mark.parametrize("taut", [False, True])
def test_model_jacobians(taut):
    x = np.array([3.0, 40.0, -92.0, 0.2, 0.3, -0.1, 0.5, 3.0, 1.1])  # pos, vel, wind n/e, drag scale
    _, f = acc(x, taut)
    num = np.zeros((3, 9))
    for i in range(9):
        d = np.zeros(9)
        d[i] = 1e-6
        num[:, i] = (acc(x + d, taut)[0] - acc(x - d, taut)[0]) / 2e-6
    j = np.array(f.j).reshape(3, 3)
    ana = np.column_stack([np.array(f.jp).reshape(3, 3), -j, j[:, :2], f.dk])
    # taut: the pendulum stiffness keeps its dominant term and the centripetal term is not
    # differentiated (2 |v_t| / |p|, a few 1e-3 /s): stated tolerance 5e-3 /s
    tol = 5e-3 if taut else 1e-6
    assert np.allclose(ana, num, atol=tol)
    if taut:
        assert f.tension_n > 0.0


def rotate_ned(q, d):
    """Quaternion of (I + [d x]) R(q), the filter's attitude-error convention."""
    h = np.asarray(d) * 0.5
    q0, q1, q2, q3 = q
    return np.array([
        q0 - h[0] * q1 - h[1] * q2 - h[2] * q3,
        q1 + h[0] * q0 + h[1] * q3 - h[2] * q2,
        q2 - h[0] * q3 + h[1] * q0 + h[2] * q1,
        q3 + h[0] * q2 - h[1] * q1 + h[2] * q0,
    ])  # fmt: skip


@pytest.fixture
def tilted():
    est = Estimator(Design())
    est.on_imu(0, 1.5, -2.0, -9.5, 0.0, 0.0, 0.0, 0.15, 0.1, 0.45)
    est.ekf.mode = MODE_FREE
    return est.ekf


def innovations(ekf, fn):
    """Run a fusion with a huge gate on a copy; return the innovations and rows it produced."""
    e = copy.deepcopy(ekf)
    out = []
    orig = e.fuse

    def spy(innov, r, status, gate_sigma=None, recover=True):
        out.append((innov, e.h.copy()))
        return orig(innov, r, status, 1e9, recover)

    e.fuse = spy
    e.begin_update()
    fn(e)
    return out


def test_accel_and_heading_rows_match_finite_differences(tilted):
    ekf = tilted
    meas = (0.3, -0.2, -9.7)
    mag = (0.12, 0.14, 0.43)
    st = [FusionStatus("a") for _ in range(3)]
    for fn in (
        lambda e: fuse_accel(e, *meas, 0.01, st),
        lambda e: fuse_heading(e, *mag, 0.0, 0.005, st[0]),
    ):
        base = innovations(ekf, fn)
        for k in range(3):  # attitude error components
            d = np.zeros(3)
            d[k] = 1e-6
            pert = copy.deepcopy(ekf)
            q = rotate_ned(pert.q, d)
            pert.q[:] = q / np.linalg.norm(q)
            moved = innovations(pert, fn)
            for (i0, h0), (i1, _) in zip(base, moved, strict=True):
                # innovation = z - h(x): d(innov)/d(att) = -h row
                assert (i1 - i0) / 1e-6 == pytest.approx(-h0[ATT_N + k], abs=2e-3 * max(1.0, abs(h0[ATT_N + k])))
    assert ATT_D == ATT_N + 2 and N_STATES == 15
    assert math.isfinite(base[0][0])


def test_rope_drag_jacobians():
    model = BalloonModel.from_design(Design(), rope_normal_cd=1.1)
    assert model.rope_drag_m2 == pytest.approx(0.25 * 1.1 * Design().tether.diameter_m * 100.0)
    x = np.array([3.0, 40.0, -92.0, 0.2, 0.3, -0.1, 0.5, 3.0, 1.0])

    def a(x):
        f = accelerations(model, 1.2, *x, True, Forces())
        return np.array([f.an, f.ae, f.ad]), f

    _, f = a(x)
    assert 0.5 < np.linalg.norm(f.rope) < 2.0  # ~1 N: half of the rope's ~2 N at 2.5 m/s cross-flow
    num = np.zeros((3, 3))
    for i in range(3):  # wind n, e and drag scale only change u: compare d a / d u through the wind
        d = np.zeros(9)
        d[6 + min(i, 1)] = 1e-6
        if i < 2:
            num[:, i] = (a(x + d)[0] - a(x - d)[0]) / 2e-6
    j = np.array(f.j).reshape(3, 3)
    assert np.allclose(j[:, :2], num[:, :2], atol=1e-6)
