"""Every measurement row the filter fuses against finite differences of its own innovation, in the
taut configuration (where the wind is measured): accelerometer, magnetic field, barometer, radius,
radial rate and the two rope-alignment rows, over every state including the attitude error."""

import copy

import numpy as np
import pytest

from balloon_core.config import Design
from balloon_core.rotation import rotation
from firmware_py.estimator.aid_sources.accel import fuse_accel
from firmware_py.estimator.aid_sources.baro import fuse_baro
from firmware_py.estimator.aid_sources.magnetometer import fuse_mag_field
from firmware_py.estimator.aid_sources.tether import fuse_taut
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.ekf import FusionStatus
from firmware_py.estimator.model import accelerations
from firmware_py.estimator.params import LEAN_COS_MIN
from firmware_py.estimator.state import ABIAS_Z, ATT_N, DRAG, MODE_TAUT, N_STATES, STATE_NAMES
from tests.unit.test_model import rotate_ned


@pytest.fixture
def taut_ekf():
    return taut_state()


def taut_state():
    """A taut filter at a state with every column non-zero (the drag scale's included)."""
    est = Estimator(Design())
    est.on_imu(0, 1.5, -2.0, -9.5, 0.01, -0.02, 0.03, 0.15, 0.1, 0.45)
    ekf = est.ekf
    ekf.mode = MODE_TAUT
    ekf.learn_drag = True  # every column, the drag scale's included
    ekf.x[:] = [3.0, 40.0, -92.3, 0.2, 0.3, -0.1, 0, 0, 0, 0, 0, 0, 0.5, 3.0, 0.05, -0.03, 1.0, 0.7, 0.03]
    return ekf


def _refresh(e):
    x = e.x.tolist()
    accelerations(e.model, 1.2, *x[0:6], *x[12:17], True, e.forces)
    e.load_model_jacobian()


def _innovations(ekf, fn):
    e = copy.deepcopy(ekf)
    _refresh(e)
    out = []

    def spy(innov, r, status, gate_sigma=None, recover=True, att_gain=1.0):
        out.append((innov, e.h.copy()))
        return True

    def spy3(i0, i1, i2, r, status, r2_extra=0.0, tilt_gain=1.0, heading_gain=1.0, axis=None, axis_var=0.0):
        out.extend((i, e.H3[k].copy()) for k, i in enumerate((i0, i1, i2)))
        return True

    e.fuse = spy
    e.fuse3 = spy3
    e.begin_update()
    fn(e)
    return out


ST = [FusionStatus(str(i)) for i in range(4)]
FUSIONS = {
    "accel": lambda e: fuse_accel(e, 0.3, -0.2, -9.7, 0.01, ST[:3]),
    "mag": lambda e: fuse_mag_field(e, 0.12, 0.14, 0.43, (0.2, 0.01, 0.45), 1e-4, ST[:3]),
    "baro": lambda e: fuse_baro(e, 91.0, -1.0, 1.0, ST[0]),
    "taut": lambda e: fuse_taut(e, 0.1, 0.1, 0.1, 0.1, ST, (float("nan"),) * 3, 0.1, 0.5),
}


@pytest.mark.parametrize("name", list(FUSIONS))
def test_rows_match_finite_differences(taut_ekf, name):
    fn = FUSIONS[name]
    base = _innovations(taut_ekf, fn)
    assert base and all(np.isfinite(i) for i, _ in base)
    eps = 1e-6
    for j in range(N_STATES):
        if ATT_N <= j < ATT_N + 3:
            d = np.zeros(3)
            d[j - ATT_N] = eps
            p, m = copy.deepcopy(taut_ekf), copy.deepcopy(taut_ekf)
            for e, s in ((p, 1.0), (m, -1.0)):
                q = rotate_ned(e.q, s * d)
                e.q[:] = q / np.linalg.norm(q)
        else:
            p, m = copy.deepcopy(taut_ekf), copy.deepcopy(taut_ekf)
            p.x[j] += eps
            m.x[j] -= eps
        if name == "accel" and j == ABIAS_Z:
            continue  # learnt at rest only: in flight the row uses its value, not its column (accel.py)
        for k, ((_, h0), (ip, _), (im, _)) in enumerate(zip(base, _innovations(p, fn), _innovations(m, fn),
                                                            strict=True)):  # fmt: skip
            num = -(ip - im) / (2 * eps)  # innovation = z - h(x)
            if name == "taut" and k >= 2 and ATT_N <= j < ATT_N + 3:
                # the field unknown (NaN here), the alignment takes the attitude as a parameter (its variance in
                # the noise, tether.py): the tilt moves the innovation, the row has no attitude column
                assert h0[j] == 0.0 and num != 0.0
                continue
            assert h0[j] == pytest.approx(num, rel=1e-4, abs=1e-6), (name, STATE_NAMES[j])
    assert STATE_NAMES[DRAG] == "drag_scale" and len(STATE_NAMES) == N_STATES


def _alignment_rows(ekf, fn):
    """The two alignment rows a fusion makes: (innovation, row, noise) of each."""
    e = copy.deepcopy(ekf)
    _refresh(e)
    out = []

    def spy(innov, r, status, gate_sigma=None, recover=True, att_gain=1.0):
        out.append((innov, e.h.copy(), r))
        return True

    e.fuse = spy
    e.begin_update()
    fn(e)
    return out[2:]


@pytest.mark.parametrize(("share", "nominal"), [(1.0, 0.1), (0.5, 0.1), (0.5, 0.05), (0.5, 0.0)])
def test_the_alignment_column_about_the_field_is_the_rotation_about_it(taut_ekf, share, nominal):
    """With the earth field known, the alignment's rows take a share of the rotation about the field's axis as a
    column (tether.field_axis_row): ``share`` times the nominal noise over the noise fused (0.1 here) of how far that
    rotation moves the body's down axis along each component (finite differences of the attitude; the components'
    azimuth and the attachment point stay parameters, as in every other row), and no part across the axis (the
    magnetometer's). The row's variance from the attitude is the same as without the column: what the column takes
    of it is out of the noise (which keeps at least the alignment's own). The field unknown: no column, all of it
    noise. The along component lies in the lean's vertical plane (its angle), the across one is horizontal; the
    along one's noise is at least the nominal over cos^2(lean) (tether.fuse_taut)."""
    field = (0.2, 0.05, 0.45)
    b = np.array(field) / np.linalg.norm(field)
    rows = _alignment_rows(taut_ekf, lambda e: fuse_taut(e, 0.1, 0.1, 0.1, 0.1, ST, field, nominal, share))
    bare = _alignment_rows(taut_ekf, lambda e: fuse_taut(e, 0.1, 0.1, 0.1, 0.1, ST, (float("nan"),) * 3, 0.1, share))
    down = lambda q: np.array(rotation(*q)[2::3])  # noqa: E731 - the body's down axis, NED
    z = down(taut_ekf.q.tolist())
    lean = np.hypot(z[0], z[1])
    an, ae = -z[0] / lean, -z[1] / lean
    eps = 1e-6
    dz = (down(rotate_ned(taut_ekf.q, eps * b)) - down(rotate_ned(taut_ekf.q, -eps * b))) / (2 * eps)
    p_att = taut_ekf.P[ATT_N : ATT_N + 3, ATT_N : ATT_N + 3]
    cz2 = max(z[2], LEAN_COS_MIN) ** 2
    components = ((np.array([an * z[2], ae * z[2], lean]), max(0.1, nominal / cz2), max(0.1, 0.1 / cz2)),
                  (np.array([-ae, an, 0.0]), 0.1, 0.1))  # fmt: skip
    for (innov, h, r), (innov0, h0, r0), (c, var, var0) in zip(rows, bare, components, strict=True):
        h_att = h[ATT_N : ATT_N + 3]
        num = c @ dz
        assert abs(num) > 1e-2
        assert h_att @ b == pytest.approx(share * nominal / var * num, rel=1e-5, abs=1e-12)
        assert np.linalg.norm(np.cross(h_att, b)) < 1e-12
        assert not h0[ATT_N : ATT_N + 3].any() and innov0 == innov
        assert r == pytest.approx(var + max(0.0, r0 - var0 - h_att @ p_att @ h_att), rel=1e-9)
