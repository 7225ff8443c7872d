"""Triangulation covariance against Monte Carlo, as a whole matrix and in the right frame.

The per-axis check of ``test_triangulation.py`` cannot see a covariance that is right in shape
but expressed in the wrong frame (the rectified frame instead of the left optical frame): the
two differ only by the rectification rotation, which mostly moves the off-diagonal terms. Here
the rig is verged by several degrees, so that rotation is large, and the errors are whitened with
the predicted full matrix: if the prediction is right, the whitened errors have unit covariance
and their squared norms average 3 (NEES).
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.triangulation import (
    triangulate_dlt,
    triangulate_optimal,
    triangulate_parallax,
)

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
METHODS = [triangulate_dlt, triangulate_parallax, triangulate_optimal]
N = 2000  # whitened-covariance eigenvalues carry ~ +-3*sqrt(2/N) = +-9 % sampling error


def verged_rig() -> StereoRig:
    """A rig whose cameras toe in by 8 degrees: the rectification rotation is about 4 degrees."""
    left = CameraModel(K, [-0.2, 0.1, 0.0, 0.0, 0.0], 1280, 720)
    right = CameraModel(K, [-0.2, 0.1, 0.0, 0.0, 0.0], 1280, 720)
    R = cv2.Rodrigues(np.array([0.02, -np.deg2rad(8.0), 0.01]))[0]
    return StereoRig(left, right, R, [-0.06, 0.002, 0.004]).rectified()


RIG = verged_rig()


def observe(rig: StereoRig, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return rig.left.project(X[None])[0], rig.right.project((rig.R @ X + rig.T)[None])[0]


def test_the_rig_has_a_large_rectification_rotation():
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(RIG.left.R)[0]))
    assert angle > 3.0


@pytest.mark.parametrize("fn", METHODS)
def test_whitened_errors_have_unit_covariance(fn):
    rng = np.random.default_rng(21)
    X = np.array([0.06, -0.03, 0.45])
    pl, pr = observe(RIG, X)
    sigma = 0.3
    pred = fn(RIG, pl, pr, sigma_px=sigma).covariance
    errors = np.array([fn(RIG, pl + rng.normal(0, sigma, 2), pr + rng.normal(0, sigma, 2),
                          sigma_px=sigma).point - X for _ in range(N)])
    L = np.linalg.cholesky(pred)
    z = np.linalg.solve(L, errors.T).T
    eig = np.linalg.eigvalsh(np.cov(z.T))
    assert eig.min() > 0.85 and eig.max() < 1.15, eig
    nees = float(np.mean(np.sum(z * z, axis=1)))
    assert nees == pytest.approx(3.0, rel=0.1)
    # the mean error is small against the spread (first-order propagation around an unbiased
    # estimate): |mean| below 10 % of one sigma in every whitened direction
    assert np.all(np.abs(z.mean(axis=0)) < 0.1)
