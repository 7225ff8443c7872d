"""Base-frame covariance against Monte Carlo, one noise source at a time.

With every source on at once a small term (the robot's rotation, say) hides under the larger
ones; alone, each must match its own sampling within a few per cent in every direction.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.transforms import from_rotvec

N = 20000  # whitened eigenvalues carry about +-3 sqrt(2/N) = +-3 % sampling error


def _setup():
    rng = np.random.default_rng(7)
    b_T_e = from_rotvec(rng.normal(size=3), [0.4, -0.1, 0.5])
    e_T_c = from_rotvec(rng.normal(scale=0.3, size=3), [0.03, -0.06, 0.04])
    return rng, b_T_e, e_T_c, np.array([0.03, 0.01, 0.5])


def _sample(b_T_e, e_T_c, p_c, dc, dx, dtb, drb):
    Rx = Rotation.from_rotvec(dx[:, 3:]).as_matrix() @ e_T_c[:3, :3]      # left, ee frame
    Rb = b_T_e[:3, :3] @ Rotation.from_rotvec(drb).as_matrix()            # flange frame
    p_ee = np.einsum("nij,nj->ni", Rx, p_c + dc) + e_T_c[:3, 3] + dx[:, :3]
    return np.einsum("nij,nj->ni", Rb, p_ee) + b_T_e[:3, 3] + dtb


@pytest.mark.parametrize("source", ["camera", "hand_eye", "robot_position", "robot_rotation"])
def test_each_source_alone_matches_monte_carlo(source: str) -> None:
    rng, b_T_e, e_T_c, p_c = _setup()
    z3, z6 = np.zeros((N, 3)), np.zeros((N, 6))
    kwargs: dict = {}
    dc, dx, dtb, drb = z3, z6, z3, z3
    if source == "camera":
        A = rng.normal(size=(3, 3)) * 1e-3
        kwargs["cov_cam"] = A @ A.T
        dc = rng.multivariate_normal(np.zeros(3), kwargs["cov_cam"], N)
    elif source == "hand_eye":
        B = rng.normal(size=(6, 6)) * np.r_[[1e-3] * 3, [2e-3] * 3][:, None]
        kwargs["cov_hand_eye"] = B @ B.T
        dx = rng.multivariate_normal(np.zeros(6), kwargs["cov_hand_eye"], N)
    elif source == "robot_position":
        kwargs["robot_sigma_pos_m"] = 3e-4
        dtb = rng.normal(scale=3e-4, size=(N, 3))
    else:
        kwargs["robot_sigma_rot_rad"] = 1e-3
        drb = rng.normal(scale=1e-3, size=(N, 3))
    p0, cov = target_in_base(b_T_e, e_T_c, p_c, **kwargs)
    samples = _sample(b_T_e, e_T_c, p_c, dc, dx, dtb, drb)
    err = samples - p0
    if source == "robot_rotation":
        # a rotation about the flange leaves the component along p_ee unchanged: the covariance
        # is rank 2; whiten in its range and check the null direction separately
        w, V = np.linalg.eigh(cov)
        null, rng_dirs = V[:, :1], V[:, 1:]
        assert w[0] < 1e-6 * w[-1]
        assert np.std(err @ null) < 0.05 * np.sqrt(w[1])
        z = (err @ rng_dirs) / np.sqrt(w[1:])
        eig = np.linalg.eigvalsh(np.atleast_2d(np.cov(z.T)))
    else:
        L = np.linalg.cholesky(cov)
        eig = np.linalg.eigvalsh(np.cov(np.linalg.solve(L, err.T)))
    assert np.all(np.abs(eig - 1.0) < 0.06), eig
