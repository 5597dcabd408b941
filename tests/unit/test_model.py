"""The filter's model: Jacobians against finite differences, measurement rows against perturbation."""

import copy
import math

import numpy as np
import pytest

from balloon_core.config import Design
from firmware_py.estimator.aid_sources.accel import fuse_accel
from firmware_py.estimator.aid_sources.magnetometer import fuse_heading
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.ekf import FusionStatus
from firmware_py.estimator.model import BalloonModel, Forces, accelerations
from firmware_py.estimator.state import ATT_D, ATT_N, MODE_FREE, N_STATES

MODEL = BalloonModel.from_design(Design())


def acc(x, taut):
    f = accelerations(MODEL, 1.2, *x, taut, Forces())
    return np.array([f.an, f.ae, f.ad]), f


# pos, vel, wind n/e, wind rate n/e, drag scale: a taut state blown down ~25 deg
X0 = np.array([3.0, 40.0, -92.0, 0.2, 0.3, -0.1, 0.5, 3.0, 0.05, -0.03, 1.1])


def central_jacobian(a, x):
    """d a / d x (3 x 11) by central differences of ``a(x) -> (acceleration, forces)``."""
    num = np.zeros((3, 11))
    for i in range(11):
        d = np.zeros(11)
        d[i] = 1e-6
        num[:, i] = (a(x + d)[0] - a(x - d)[0]) / 2e-6
    return num


@pytest.mark.parametrize("taut", [False, True])
def test_model_jacobians(taut):
    """The generated d a / d x (every column, the air's push and the taut projection included)
    against central differences of the generated a(x)."""
    _, f = acc(X0, taut)
    num = central_jacobian(lambda x: acc(x, taut), X0)
    assert np.allclose(np.array(f.ja).reshape(3, 11), num, rtol=1e-5, atol=1e-7)
    assert f.taut == taut
    if taut:
        assert f.tension_n > 0.0
        # the pull's gradient too: tension / m_eff
        g = np.zeros(11)
        for i in range(11):
            d = np.zeros(11)
            d[i] = 1e-6
            g[i] = (acc(X0 + d, True)[1].tension_n - acc(X0 - d, True)[1].tension_n) / 2e-6 / f.m_eff_kg
        assert np.allclose(f.jpull, g, rtol=1e-5, atol=1e-7)


def test_the_air_push_is_in_the_model():
    """(1 + Ca) rho V / m_eff per m/s^2 of the air's acceleration: 1.73 for the reference balloon."""
    x = X0.copy()
    x[8] = 0.0
    a0, f = acc(x, False)
    x[8] = 0.1
    a1, _ = acc(x, False)
    rho_v = 1.2 * MODEL.volume_m3
    beta = 1.5 * rho_v / (MODEL.mass_kg + 0.5 * rho_v)
    assert (a1 - a0)[0] == pytest.approx(0.1 * beta)
    assert 1.6 < beta < 1.9


@pytest.mark.slow
def test_generated_code_matches_the_derivation():
    """tools/derive_model.py regenerates the Python and the C it writes (generated.py, firmware_c/src/generated.[ch],
    params.h) exactly: no checked-in file is stale."""
    pytest.importorskip("sympy")
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, str(root / "tools" / "derive_model.py"), "--check"], capture_output=True,
                       text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr


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
    assert ATT_D == ATT_N + 2 and N_STATES == 19
    assert math.isfinite(base[0][0])


def test_rope_drag_jacobians():
    model = BalloonModel.from_design(Design(), rope_normal_cd=1.1)
    assert model.rope_drag_m2 == pytest.approx(0.25 * 1.1 * Design().tether.diameter_m * 100.0)

    def a(x):
        f = accelerations(model, 1.2, *x, True, Forces())
        return np.array([f.an, f.ae, f.ad]), f

    a1, f = a(X0)
    a0, _ = acc(X0, True)
    # ~1 N of cross-flow drag on the rope at 2.5 m/s, half of it carried by the balloon
    assert 0.3 < np.linalg.norm(a1 - a0) * f.m_eff_kg < 3.0
    assert np.allclose(np.array(f.ja).reshape(3, 11), central_jacobian(a, X0), rtol=1e-5, atol=1e-7)


def test_the_climbing_free_models_jacobian_carries_the_rope_pickup():
    """A climb at 4 m/s with half the rope aloft: the free model's d a / d x against central differences,
    d a_d / d v_d included (the pick-up's 2 lambda v_d / m_eff beside the generated columns)."""
    x0 = np.array([1.0, 2.0, -(MODEL.radius_m + 40.0), 0.5, 1.5, -4.0, 1.0, 3.0, 0.02, -0.01, 1.05])
    _, f = acc(x0, False)
    assert np.allclose(np.array(f.ja).reshape(3, 11), central_jacobian(lambda x: acc(x, False), x0), rtol=1e-5,
                       atol=1e-7)  # fmt: skip
    assert abs(2.0 * MODEL.rope_kg_m * x0[5] / f.m_eff_kg) > 1e-3  # the pick-up's share is there to be missed
