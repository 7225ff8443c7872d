"""Tests of eye_in_hand.core.triangulation: exactness, covariance, rejections."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.triangulation import (
    Rejected,
    triangulate,
    triangulate_dlt,
    triangulate_optimal,
    triangulate_parallax,
    triangulate_rectified,
)
from eye_in_hand.errors import InputError

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
METHODS = [triangulate_dlt, triangulate_parallax, triangulate_optimal]


def make_rig(rectify=True):
    left = CameraModel(K, [-0.3, 0.15, 0.001, -0.0005, -0.05], 1280, 720)
    right = CameraModel(K + np.diag([3.0, 2.0, 0.0]), [-0.28, 0.1, 0.0, 0.0, 0.0], 1280, 720)
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    rig = StereoRig(left, right, R, [-0.06, 0.001, 0.0005])
    return rig.rectified() if rectify else rig


RIG = make_rig()


def observe(rig, X):
    return rig.left.project(X[None])[0], rig.right.project((rig.R @ X + rig.T)[None])[0]


@pytest.mark.parametrize("fn", METHODS)
def test_noise_free_points_are_recovered_exactly(fn):
    rng = np.random.default_rng(11)
    for X in rng.uniform([-0.2, -0.1, 0.25], [0.2, 0.1, 1.5], (20, 3)):
        p = fn(RIG, *observe(RIG, X), sigma_px=0.3)
        assert np.allclose(p.point, X, atol=1e-9)
        assert p.residual_px < 1e-6
        assert p.disparity_px > 0
        assert np.all(np.linalg.eigvalsh(p.covariance) > 0)


@pytest.mark.parametrize("fn", METHODS)
def test_covariance_matches_monte_carlo(fn):
    rng = np.random.default_rng(12)
    X = np.array([0.08, -0.04, 0.5])
    pl, pr = observe(RIG, X)
    sigma = 0.3
    pts = np.array([fn(RIG, pl + rng.normal(0, sigma, 2), pr + rng.normal(0, sigma, 2)).point
                    for _ in range(300)])
    pred = fn(RIG, pl, pr, sigma_px=sigma).covariance
    mc = np.cov(pts.T)
    # standard deviations along x, y, z within 20 % (300 samples: ~4 % sampling error)
    assert np.allclose(np.sqrt(np.diag(mc)), np.sqrt(np.diag(pred)), rtol=0.2)
    # depth sigma follows the stereo limit Z^2 sigma_d / (f B), sigma_d = sqrt(2) sigma
    limit = X[2] ** 2 * np.sqrt(2) * sigma / (RIG.P1[0, 0] * RIG.baseline)
    assert np.sqrt(pred[2, 2]) == pytest.approx(limit, rel=0.1)


def test_methods_agree_under_noise():
    rng = np.random.default_rng(13)
    X = np.array([-0.1, 0.05, 0.45])
    pl, pr = observe(RIG, X)
    for _ in range(20):
        nl, nr = pl + rng.normal(0, 0.3, 2), pr + rng.normal(0, 0.3, 2)
        a = triangulate(RIG, nl, nr, method="dlt").point
        b = triangulate(RIG, nl, nr, method="disparity").point
        c = triangulate(RIG, nl, nr, method="optimal").point
        # measured over seeds 0-39 x 20 draws: |dlt - disparity| max 6.0e-5 m, |dlt - optimal|
        # max 2.7e-4 m (this seed 4.2e-5, 1.7e-4 m); 1.7x / 1.5x margin
        assert np.linalg.norm(a - b) < 1e-4 and np.linalg.norm(a - c) < 4e-4


@pytest.mark.parametrize("fn", METHODS)
def test_rejections_carry_reasons(fn):
    X = np.array([0.05, 0.0, 0.6])
    pl, pr = observe(RIG, X)
    with pytest.raises(Rejected) as exc:  # swapped images: negative disparity
        fn(RIG, pr, pl)
    assert exc.value.reason == "non_positive_disparity"
    with pytest.raises(Rejected) as exc:  # 20 px off the epipolar line
        fn(RIG, pl, pr + (0.0, 20.0), max_residual_px=2.0)
    assert exc.value.reason == "residual_gate" and "gate" in str(exc.value)
    fn(RIG, pl, pr + (0.0, 2.0), max_residual_px=2.0)  # within the gate


def test_bad_arguments():
    with pytest.raises(InputError, match="not rectified"):
        triangulate_dlt(make_rig(rectify=False), (1, 2), (3, 4))
    with pytest.raises(InputError, match="method"):
        triangulate(RIG, (1, 2), (3, 4), method="magic")
    with pytest.raises(InputError, match="left_px"):
        triangulate_dlt(RIG, (1, np.nan), (3, 4))
    with pytest.raises(InputError, match="sigma_px"):
        triangulate_dlt(RIG, (700, 300), (600, 300), sigma_px=0)


@pytest.mark.parametrize("fn", METHODS)
def test_per_image_sigmas_match_monte_carlo(fn):
    """sigma_px=(left, right): each image's own centre noise (the detector's estimate)."""
    rng = np.random.default_rng(13)
    X = np.array([-0.05, 0.03, 0.45])
    pl, pr = observe(RIG, X)
    sl, sr = 0.05, 0.4
    pts = np.array([fn(RIG, pl + rng.normal(0, sl, 2), pr + rng.normal(0, sr, 2)).point
                    for _ in range(300)])
    pred = fn(RIG, pl, pr, sigma_px=(sl, sr)).covariance
    assert np.allclose(np.sqrt(np.diag(np.cov(pts.T))), np.sqrt(np.diag(pred)), rtol=0.2)
    # one number = the same number on both sides
    np.testing.assert_allclose(fn(RIG, pl, pr, sigma_px=(0.3, 0.3)).covariance,
                               fn(RIG, pl, pr, sigma_px=0.3).covariance, rtol=1e-9)
    for bad in ((0.1, 0.0), (0.1, float("nan")), (0.1, 0.2, 0.3), "x"):
        with pytest.raises(InputError, match="sigma_px"):
            fn(RIG, pl, pr, sigma_px=bad)


@pytest.mark.parametrize("fn", METHODS)
def test_full_pixel_covariance_and_common_shift(fn):
    """pixel_cov: a shift alike in both images moves the point sideways, hardly in depth."""
    X = np.array([0.02, -0.01, 0.5])
    pl, pr = observe(RIG, X)
    diag = np.diag([0.05, 0.05, 0.4, 0.4]) ** 2
    np.testing.assert_allclose(fn(RIG, pl, pr, pixel_cov=diag).covariance,
                               fn(RIG, pl, pr, sigma_px=(0.05, 0.4)).covariance, rtol=1e-9)
    v = np.array([0.3, 0.0, 0.3, 0.0])                  # common 0.3 px shift along x
    common = fn(RIG, pl, pr, pixel_cov=np.outer(v, v)).covariance
    indep = fn(RIG, pl, pr, pixel_cov=np.diag(v * v)).covariance
    assert common[2, 2] < 0.05 * indep[2, 2]            # disparity unchanged: no depth error
    assert common[0, 0] > indep[0, 0]                   # lateral: the shifts add up
    with pytest.raises(InputError, match="pixel_cov"):
        fn(RIG, pl, pr, pixel_cov=-np.eye(4))


@pytest.mark.parametrize("fn", [triangulate_dlt, triangulate_parallax])
@pytest.mark.parametrize("rectified", [False, True])
def test_without_covariance_the_point_and_rejections_are_the_same_bits(fn, rectified):
    """``covariance=False`` (the locator's pass before its refinement) skips only the
    covariance: the point, residual and disparity are those of the full call to the last bit,
    and a pair is rejected for the same reason."""
    rng = np.random.default_rng(21)
    S = np.diag([0.09, 0.09, 0.16, 0.16]) + np.outer([0.1, 0.2, 0.1, 0.2], [0.1, 0.2, 0.1, 0.2])
    for X in rng.uniform([-0.2, -0.1, 0.25], [0.2, 0.1, 1.5], (10, 3)):
        pl, pr = observe(RIG, X)
        pl, pr = pl + rng.normal(0, 0.3, 2), pr + rng.normal(0, 0.3, 2)
        if rectified:
            pl, pr = RIG.left.rectify_points(pl[None])[0], RIG.right.rectify_points(pr[None])[0]
        full = fn(RIG, pl, pr, pixel_cov=S, max_residual_px=2.0, rectified=rectified)
        bare = fn(RIG, pl, pr, pixel_cov=S, max_residual_px=2.0, rectified=rectified,
                  covariance=False)
        assert bare.point.tobytes() == full.point.tobytes()
        assert (bare.residual_px, bare.disparity_px, bare.method) == \
            (full.residual_px, full.disparity_px, full.method)
        assert np.isnan(bare.covariance).all() and bare.covariance.shape == (3, 3)
        assert np.isfinite(full.covariance).all()
    pl, pr = observe(RIG, np.array([0.05, 0.0, 0.6]))
    for args, reason in (((pr, pl), "non_positive_disparity"),
                         ((pl, pr + (0.0, 20.0)), "residual_gate")):
        reasons = []
        for cov in (True, False):
            with pytest.raises(Rejected) as exc:
                fn(RIG, *args, max_residual_px=2.0, covariance=cov)
            reasons.append((exc.value.reason, str(exc.value)))
        assert reasons[0] == reasons[1] and reasons[0][0] == reason


@pytest.mark.parametrize("fn, method", [(triangulate_dlt, "dlt"),
                                        (triangulate_parallax, "disparity")])
def test_the_unchecked_rectified_entry_is_the_checked_functions(fn, method):
    """``triangulate_rectified`` (the stereo locator's, with a covariance it built) gives the
    checked function's point, covariance, residual and disparity to the last bit, with and
    without a covariance, the same rejections, and still refuses what it cannot use."""
    rng = np.random.default_rng(22)
    for X in rng.uniform([-0.2, -0.1, 0.25], [0.2, 0.1, 1.5], (20, 3)):
        pl, pr = observe(RIG, X)
        xl = RIG.left.rectify_points((pl + rng.normal(0, 0.3, 2))[None])[0]
        xr = RIG.right.rectify_points((pr + rng.normal(0, 0.3, 2))[None])[0]
        v = rng.normal(0, 0.2, 4)
        S = np.diag(np.repeat(rng.uniform(0.01, 0.3, 2), 2)) + np.outer(v, v)
        for cov in (S, None):
            want = fn(RIG, xl, xr, pixel_cov=S, max_residual_px=2.0, rectified=True,
                      covariance=cov is not None)
            got = triangulate_rectified(RIG, xl, xr, method=method, pixel_cov=cov,
                                        max_residual_px=2.0)
            assert got.point.tobytes() == want.point.tobytes()
            assert got.covariance.tobytes() == want.covariance.tobytes()
            assert (got.residual_px, got.disparity_px, got.method) == \
                (want.residual_px, want.disparity_px, want.method)
    pl, pr = observe(RIG, np.array([0.05, 0.0, 0.6]))
    xl, xr = RIG.left.rectify_points(pl[None])[0], RIG.right.rectify_points(pr[None])[0]
    for args, reason in (((xr, xl), "non_positive_disparity"),
                         ((xl, xr + (0.0, 20.0)), "residual_gate")):
        with pytest.raises(Rejected) as want_exc:
            fn(RIG, *args, max_residual_px=2.0, rectified=True)
        with pytest.raises(Rejected) as got_exc:
            triangulate_rectified(RIG, *args, method=method, pixel_cov=np.eye(4),
                                  max_residual_px=2.0)
        assert (got_exc.value.reason, str(got_exc.value)) == \
            (want_exc.value.reason, str(want_exc.value)) and got_exc.value.reason == reason
    with pytest.raises(InputError, match="finite"):
        triangulate_rectified(RIG, np.array([np.nan, 1.0]), xr, method=method, pixel_cov=None,
                              max_residual_px=None)
    with pytest.raises(InputError, match="method"):
        triangulate_rectified(RIG, xl, xr, method="optimal", pixel_cov=None, max_residual_px=None)
    if method == "disparity":            # a vertically rectified rig: no parallax
        vertical = StereoRig(RIG.left, RIG.right, np.eye(3), [0.0, -0.06, 0.0]).rectified()
        with pytest.raises(InputError, match="vertically"):
            triangulate_rectified(vertical, xl, xr, method=method, pixel_cov=None,
                                  max_residual_px=None)


def test_rays_parallel_to_machine_precision_are_rejected_not_a_crash():
    """A positive disparity of about 1e-9 px leaves the DLT Jacobian singular: that pair is
    rejected as at infinity (it raised numpy's LinAlgError, which no caller catches); without
    a covariance asked for, its point is returned."""
    P1, P2 = RIG.P1, RIG.P2
    singular = 0
    for xl0 in np.linspace(0.0, 1280.0, 65):
        for y in (50.0, 360.0, 700.0):
            xl = np.array([xl0, y])
            xr = np.array([xl0 - (P1[0, 2] - P2[0, 2]) - 1e-9, y])
            try:
                triangulate_dlt(RIG, xl, xr, rectified=True)
            except Rejected as exc:
                assert exc.reason == "non_positive_disparity" and "parallel" in str(exc)
                singular += 1
                bare = triangulate_dlt(RIG, xl, xr, rectified=True, covariance=False)
                assert np.isnan(bare.covariance).all() and bare.point[2] > 1e6
    assert singular > 0       # the case occurs on this grid (about half of it)
