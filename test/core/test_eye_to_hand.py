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
