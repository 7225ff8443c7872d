"""core.eye_to_hand: a fixed camera's targets in the base frame, with the mount covariance."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.errors import InputError


def test_eye_to_hand_localizer_rotates_and_adds_the_mount_covariance():
    from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
    from eye_in_hand.core.transforms import from_rotvec

    base_T_cam = from_rotvec([0.1, -0.2, 0.9], [0.2, 0.6, -1.2])
    R = base_T_cam[:3, :3]
    p_cam = np.array([0.05, -0.02, 0.45])
    cov_cam = np.diag([1e-8, 2e-8, 9e-8])
    loc = EyeToHandLocalizer(base_T_cam)
    res = loc.locate(7, p_cam, cov_cam, now_ns=10**12)      # no pose: no staleness either
    assert np.allclose(res.point_base, R @ p_cam + base_T_cam[:3, 3], atol=1e-15)
    assert np.allclose(res.covariance, R @ cov_cam @ R.T, atol=1e-20)
    # a pure mount translation sigma adds isotropically; a rotation sigma grows with range
    cov_he = np.diag([4e-8, 4e-8, 4e-8, 0, 0, 0])
    r2 = EyeToHandLocalizer(base_T_cam, cov_he).locate(7, p_cam, cov_cam)
    assert np.allclose(r2.covariance - res.covariance, 4e-8 * np.eye(3), atol=1e-20)
    rot = EyeToHandLocalizer(base_T_cam, np.diag([0, 0, 0, 1e-6, 1e-6, 1e-6]))
    near, far = rot.locate(0, p_cam * 0.5).covariance, rot.locate(0, p_cam * 2).covariance
    assert np.trace(far) == pytest.approx(16 * np.trace(near))
    with pytest.raises(InputError, match="cov_hand_eye"):
        EyeToHandLocalizer(base_T_cam, -np.eye(6))


def test_anisotropic_covariances_pin_the_mount_jacobian():
    """Full anisotropic camera and mount covariances, checked against the documented
    ``R cov_cam R^T + J cov_hand_eye J^T``, ``J = [I, -[R p_cam]x]``: the mount's translation
    covariance is in the base frame (not rotated by R), its rotation vector applied on the
    left (lever arm ``R p_cam``, not ``p_cam``). Isotropic covariances cannot tell these apart."""
    from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
    from eye_in_hand.core.transforms import from_rotvec

    base_T_cam = from_rotvec([0.4, -0.9, 1.3], [0.7, -0.2, 0.9])
    R = base_T_cam[:3, :3]
    p_cam = np.array([0.08, -0.05, 0.6])
    A = np.array([[1.0, 0.3, -0.2], [0.0, 2.0, 0.5], [0.1, 0.0, 3.0]])
    cov_cam = 1e-8 * A @ A.T
    B = np.random.default_rng(3).normal(size=(6, 6)) * np.r_[1e-3, 2e-3, 5e-4, 1e-3, 3e-3, 2e-4]
    cov_he = B.T @ B
    res = EyeToHandLocalizer(base_T_cam, cov_he).locate(1, p_cam, cov_cam)
    q = R @ p_cam
    skew = np.array([[0.0, -q[2], q[1]], [q[2], 0.0, -q[0]], [-q[1], q[0], 0.0]])
    J = np.hstack([np.eye(3), -skew])
    want = R @ cov_cam @ R.T + J @ cov_he @ J.T
    np.testing.assert_allclose(res.covariance, want, rtol=1e-10, atol=1e-22)
    np.testing.assert_allclose(res.point_base, q + base_T_cam[:3, 3], atol=1e-15)
    assert np.allclose(res.base_T_ee, np.eye(4))
