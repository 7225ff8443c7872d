"""core.handeye.refine: the conventions and figures behind the refinements' covariances.

The covariance of X is in the documented parameters (translation, then a rotation vector
applied on the left, in the parent frame: :func:`perturb`), scaled by the residual variance
``2 cost / (m - p)`` of the fit: with corner noise of 0.5 px the reported sigma is 0.5 px.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.handeye.refine import perturb, refine_pose_space, refine_reprojection
from eye_in_hand.core.handeye.synthetic import make_problem


def test_perturb_rotates_on_the_left_in_the_parent_frame() -> None:
    T0 = np.eye(4)
    T0[:3, :3] = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    T0[:3, 3] = [0.4, -0.2, 0.9]
    p = np.array([0.01, 0.02, -0.03, 0.05, -0.02, 0.04])
    T = perturb(T0, p)
    np.testing.assert_allclose(T[:3, :3], Rotation.from_rotvec(p[3:]).as_matrix() @ T0[:3, :3],
                               atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], p[:3], atol=0)       # the translation is absolute
    np.testing.assert_allclose(T[3], [0, 0, 0, 1], atol=0)
    # not the right-hand (child-frame) perturbation: they differ at this rotation
    right = T0[:3, :3] @ Rotation.from_rotvec(p[3:]).as_matrix()
    assert np.max(np.abs(right - T[:3, :3])) > 1e-2


@pytest.mark.parametrize("noise_px", [0.5, 1.0])
def test_reprojection_sigma_is_the_corner_noise(noise_px: float) -> None:
    """The residual standard deviation over the degrees of freedom: the corner noise (per
    coordinate) the problem was made with, within 5 % over ~1300 residuals."""
    P = make_problem(12, seed=23, noise_px=noise_px)
    res = refine_reprojection(P.X, P.Y, P.samples, P.views, "eye_in_hand")
    assert res.sigma == pytest.approx(noise_px, rel=0.05), res.sigma
    assert res.covariance.shape == (6, 6)
    np.testing.assert_allclose(res.covariance, res.covariance_full[:6, :6], atol=0)
    # the covariance scales with the residual variance: four times the noise variance
    res2 = refine_reprojection(P.X, P.Y, make_problem(12, seed=23, noise_px=2 * noise_px).samples,
                               P.views, "eye_in_hand")
    ratio = np.trace(res2.covariance) / np.trace(res.covariance)
    assert ratio == pytest.approx(4.0, rel=0.15), ratio


def test_pose_space_covariance_is_x_block() -> None:
    P = make_problem(12, seed=24, noise_px=0.5)
    bte = np.stack([s.base_T_ee for s in P.samples])
    ctb = np.stack([s.cam_T_board for s in P.samples])
    res = refine_pose_space(P.X, P.Y, bte, ctb, "eye_in_hand")
    np.testing.assert_allclose(res.covariance, res.covariance_full[:6, :6], atol=0)


def test_pose_space_residuals_are_normalised_by_their_own_scales() -> None:
    """Board poses with 1 mrad of rotation noise and 0.1 mm of translation noise, refined with
    those scales: the normalised residuals have unit spread (sigma about 1), each component
    divided by its own scale."""
    P = make_problem(30, seed=25, noise_px=0.0)
    rng = np.random.default_rng(3)
    s_r, s_t = 1e-3, 1e-4
    ctb = P.true_cam_T_board.copy()
    for C in ctb:
        C[:3, :3] = C[:3, :3] @ Rotation.from_rotvec(rng.normal(scale=s_r, size=3)).as_matrix()
        C[:3, 3] += rng.normal(scale=s_t, size=3)
    res = refine_pose_space(P.X, P.Y, P.true_base_T_ee, ctb, "eye_in_hand", scales=(s_r, s_t))
    assert res.sigma == pytest.approx(1.0, rel=0.2), res.sigma
