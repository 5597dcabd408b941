"""balloon_core.rotation.rotation_error: the small rotation that turns an estimate into the truth."""

from __future__ import annotations

import math

import numpy as np

from balloon_core.rotation import quat_from_euler, rotation, rotation_error


def hamilton(p: tuple[float, ...], q: tuple[float, ...]) -> tuple[float, float, float, float]:
    """p (x) q, scalar first: the rotation q, then p (R(p q) = R(p) R(q))."""
    return (p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
            p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
            p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
            p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0])  # fmt: skip


def test_the_error_is_the_rotation_that_turns_the_estimate_into_the_truth():
    """R_true = R(turn by d) R_est for a small d about any axis, from any estimate: rotation_error gives d back (to
    second order), and nothing for the estimate itself."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        q_est = quat_from_euler(*rng.uniform(-math.pi, math.pi, 3) * (1.0, 0.45, 1.0))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-0.01, 0.01)
        turn = (math.cos(angle / 2.0), *(math.sin(angle / 2.0) * axis))
        q_true = hamilton(turn, q_est)
        m = np.array(rotation(*q_true)).reshape(3, 3) @ np.array(rotation(*q_est)).reshape(3, 3).T
        assert np.allclose(m, np.array(rotation(*turn)).reshape(3, 3), atol=1e-12)  # the composition is the turn's
        assert np.allclose(rotation_error(q_true, q_est), angle * axis, atol=1e-6)
        assert np.allclose(rotation_error(q_est, q_est), 0.0, atol=1e-15)
