"""Stereo triangulation of one point: DLT, parallax and optimal (reprojection) refinement.

All three take the point's pixel coordinates in both images and a :class:`StereoRig` that is
rectified (``rig.rectified()``, or loaded from ROS calibration files), and return a
:class:`StereoPoint` in the **left optical frame** (the unrectified left camera, the frame of
``camera_left_optical_frame``), with:

* ``residual_px``: the RMS reprojection error over the four image coordinates (pixels);
* ``covariance``: 3x3, propagated to first order from the pixel noise ``sigma_px`` on each image
  coordinate (``J S J^T`` for the closed forms, ``(J^T J)^-1 J^T S J (J^T J)^-1`` for the
  least-squares refinement, ``S`` the pixel covariance); ``sigma_px`` is one number for all four
  coordinates or a pair ``(left, right)``, or ``pixel_cov`` gives the whole (4, 4) ``S`` (the
  stereo locator's: per-detection edge terms plus a shading shift and a threshold-cut term
  common to both images, which move the point sideways, not in depth).

Methods:

(a) :func:`triangulate_dlt`: homogeneous linear least squares, four equations in the three
    unknowns, from the rectified (undistorted) pixels and ``P1, P2`` (SVD of a 4x4 system).
(b) :func:`triangulate_parallax`: ``Z = f B / d`` on rectified coordinates with
    ``d = x_l - x_r - (c_x1 - c_x2)``, then ``X, Y`` (horizontal rigs).
(c) :func:`triangulate_optimal`: Gauss-Newton on the reprojection error in both *distorted*
    images through the full camera models (the maximum-likelihood point for Gaussian pixel
    noise), started from the DLT point; Jacobians from ``cv2.projectPoints``.

Rejections raise :class:`Rejected` (a :class:`~eye_in_hand.errors.TriangulationError`) whose
``reason`` is one of :data:`REJECT_REASONS`, so callers can count them.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.errors import InputError, TriangulationError

__all__ = [
    "METHODS",
    "REJECT_REASONS",
    "Rejected",
    "StereoPoint",
    "rectify_pair",
    "triangulate_dlt",
    "triangulate_parallax",
    "triangulate_optimal",
    "triangulate_rectified",
    "triangulate",
]

#: Triangulation methods by name (the node's ``method`` parameter).
METHODS = ("dlt", "disparity", "optimal")
#: Why a point may be rejected.
REJECT_REASONS = ("behind_camera", "non_positive_disparity", "residual_gate", "not_converged")


class Rejected(TriangulationError):
    """A stereo point was rejected. ``reason`` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, eq=False)
class StereoPoint:
    """A triangulated point.

    Attributes:
        point: shape (3,), metres, in the left optical frame.
        covariance: shape (3, 3), m^2, in the left optical frame; NaN when the caller asked
            for none (``covariance=False``).
        residual_px: RMS reprojection error over the four image coordinates.
        method: "dlt", "disparity" or "optimal".
        disparity_px: rectified disparity ``x_l - x_r`` (NaN for a vertical rig).
    """

    point: np.ndarray
    covariance: np.ndarray
    residual_px: float
    method: str
    disparity_px: float = float("nan")


def _check_rig(rig: StereoRig) -> None:
    if not isinstance(rig, StereoRig):
        raise InputError("rig: expected a StereoRig")
    if not rig.is_rectified:
        raise InputError("rig: not rectified; use rig.rectified() or StereoRig.load(dir)")


def _px(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (2,) or not (math.isfinite(arr[0]) and math.isfinite(arr[1])):
        raise InputError(f"{name}: expected two finite pixel coordinates, got {value!r}")
    return arr


def rectify_pair(rig: StereoRig, left_px, right_px) -> tuple[np.ndarray, np.ndarray]:
    """Rectified pixel coordinates of one point seen in both distorted images.

    Args:
        rig: rectified stereo rig.
        left_px, right_px: distorted pixel coordinates, shape (2,).

    Returns:
        (left, right) rectified pixels, each shape (2,).
    """
    _check_rig(rig)
    return (rig.left.rectify_points(_px(left_px, "left_px"))[0],
            rig.right.rectify_points(_px(right_px, "right_px"))[0])


_JAC_STEP_PX = 0.5  # central-difference step of the rectification Jacobian (the map is smooth)
# the Jacobian of rectified inputs (read-only: shared by every call) and the homogeneous 1
_EYE4 = np.eye(4)
_EYE4.setflags(write=False)
_ONE = np.ones(1)
_ONE.setflags(write=False)


def _rectify_with_jacobian(rig: StereoRig, left_px, right_px
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rectified pixels of both images and d(rectified) / d(distorted), shape (4, 4).

    Pixel noise lives in the distorted images, where the target is detected; undistortion and
    the rectifying rotation and projection stretch it differently across the image, so the
    covariance propagates it through this Jacobian (block-diagonal: left, right).
    """
    _check_rig(rig)
    h = _JAC_STEP_PX
    offsets = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    out = []
    J = np.zeros((4, 4))
    for k, (cam, px, name) in enumerate(((rig.left, left_px, "left_px"),
                                         (rig.right, right_px, "right_px"))):
        r = cam.rectify_points(_px(px, name)[None, :] + offsets)
        out.append(r[0])
        J[2 * k:2 * k + 2, 2 * k] = (r[1] - r[2]) / (2 * h)
        J[2 * k:2 * k + 2, 2 * k + 1] = (r[3] - r[4]) / (2 * h)
    return out[0], out[1], J


def _dlt_rect(P1: np.ndarray, P2: np.ndarray, xl: np.ndarray, xr: np.ndarray,
              with_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """DLT point (3,) in the rectified-left frame and, optionally, d X / d (xl, yl, xr, yr).

    Each row ``a_i = u_i P[2] - P[k]`` of the system ``A [X; 1] = 0`` depends on one image
    coordinate ``u_i`` with ``d(a_i . [X; 1]) / d u_i = P[2] . [X; 1] = w_i``. Rows are scaled to
    unit norm. To first order the homogeneous solution moves like the least-squares solution
    of ``M X = -b`` (``M = A[:, :3]``, ``b = A[:, 3]``), so ``J = -(M^T M)^-1 M^T diag(s w)``
    with the row scales ``s``.
    """
    # rows (xl[0] P1[2] - P1[0], xl[1] P1[2] - P1[1], the same for the right), two at a time;
    # their norms as np.linalg.norm(A, axis=1) computes them, without its generic wrapper
    A = np.concatenate((xl[:, None] * P1[2] - P1[:2], xr[:, None] * P2[2] - P2[:2]))
    scale = 1.0 / np.sqrt(np.add.reduce(A * A, axis=1))
    A *= scale[:, None]
    _, _, vt = np.linalg.svd(A)
    Xh = vt[-1]
    if abs(Xh[3]) < 1e-15:
        return np.full(3, np.inf), None
    X = Xh[:3] / Xh[3]
    if not with_jacobian:
        return X, None
    h = np.concatenate((X, _ONE))   # np.append(X, 1.0)
    w = np.array([P1[2] @ h, P1[2] @ h, P2[2] @ h, P2[2] @ h]) * scale
    M = A[:, :3]
    try:
        J = -np.linalg.solve(M.T @ M, M.T * w[None, :])
    except np.linalg.LinAlgError:     # rays parallel to machine precision: no Jacobian
        return X, None
    return X, J


def _reproj_rms(P1: np.ndarray, P2: np.ndarray, X: np.ndarray, xl: np.ndarray,
                xr: np.ndarray) -> float:
    h = np.concatenate((X, _ONE))   # np.append(X, 1.0)
    a, b = P1 @ h, P2 @ h
    e = np.concatenate([a[:2] / a[2] - xl, b[:2] / b[2] - xr])
    return float(math.sqrt(np.add.reduce(e * e) / 4))   # np.mean, to the bit


def _finish(rig: StereoRig, X_rect: np.ndarray, cov_rect: np.ndarray | None, residual: float,
            method: str, disparity: float, max_residual_px: float | None) -> StereoPoint:
    """The point in the left optical frame after the rejections every method shares (behind a
    camera, the residual gate); ``cov_rect`` None: no covariance asked for (NaN)."""
    R1 = rig.R1
    X = R1.T @ X_rect  # rectified-left -> left optical frame
    X_right = rig.R @ X + rig.T
    if not (math.isfinite(X[0]) and math.isfinite(X[1]) and math.isfinite(X[2])
            and X[2] > 0 and X_right[2] > 0):
        raise Rejected("behind_camera",
                       f"triangulated point {np.round(X, 4).tolist()} m is behind a camera "
                       f"(z_left = {X[2]:.4f}, z_right = {X_right[2]:.4f})")
    if max_residual_px is not None and residual > max_residual_px:
        raise Rejected("residual_gate", f"reprojection residual {residual:.3f} px exceeds the "
                                        f"gate of {max_residual_px:.3f} px")
    if cov_rect is None:
        return StereoPoint(X, np.full((3, 3), np.nan), residual, method, disparity)
    cov = R1.T @ cov_rect @ R1
    return StereoPoint(X, 0.5 * (cov + cov.T), residual, method, disparity)


def _pixel_cov(sigma_px: float | Sequence[float], pixel_cov=None) -> np.ndarray:
    """Covariance (4, 4) of (xl, yl, xr, yr): ``pixel_cov`` when given (checked), else
    independent ``sigma_px`` per coordinate (one number or (left, right))."""
    if pixel_cov is None:
        s = _check_sigma(sigma_px)
        return np.diag(s * s)
    try:
        S = np.asarray(pixel_cov, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError("pixel_cov: expected a 4x4 matrix") from exc
    # np.allclose(S, S.T) spelled out for finite S (its defaults rtol 1e-5, atol 1e-8):
    # the same test without isclose's generic broadcasting and NaN handling, which cost more
    # than the triangulation itself
    if S.shape != (4, 4) or not np.isfinite(S).all() \
            or not (np.abs(S - S.T) <= 1e-8 + 1e-5 * np.abs(S.T)).all() \
            or np.linalg.eigvalsh(0.5 * (S + S.T)).min() < -1e-12 * max(1.0, np.abs(S).max()):
        raise InputError("pixel_cov: expected a symmetric positive semi-definite 4x4 matrix")
    return S


def _check_sigma(sigma_px: float | Sequence[float]) -> np.ndarray:
    """Per-coordinate sigmas (xl, yl, xr, yr), shape (4,), from one number or (left, right)."""
    try:
        vals = np.asarray(sigma_px, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"sigma_px: expected a number or (left, right), got {sigma_px!r}") \
            from exc
    if vals.size == 1:
        vals = np.repeat(vals, 2)
    if vals.size != 2 or not (np.all(np.isfinite(vals)) and np.all(vals > 0)):
        raise InputError(f"sigma_px: must be > 0 (one number or left, right), got {sigma_px}")
    return np.repeat(vals, 2)


def _disparity(rig: StereoRig, xl: np.ndarray, xr: np.ndarray) -> float:
    P1, P2 = rig.P1, rig.P2
    if abs(P2[0, 3]) >= abs(P2[1, 3]):
        return float((xl[0] - P1[0, 2]) - (xr[0] - P2[0, 2]))
    return float((xl[1] - P1[1, 2]) - (xr[1] - P2[1, 2]))


def _check_disparity(rig: StereoRig, d: float) -> None:
    # P2[0, 3] = -f B: for a rig with the right camera on the +x side, disparity must be > 0.
    sign = -math.copysign(1.0, rig.P2[0, 3] if abs(rig.P2[0, 3]) >= abs(rig.P2[1, 3])
                          else rig.P2[1, 3])
    if not d * sign > 0:
        raise Rejected("non_positive_disparity",
                       f"disparity {d:.3f} px is not positive: the point is at or beyond infinity "
                       f"or the left/right association is wrong")


def triangulate_dlt(rig: StereoRig, left_px, right_px, *, sigma_px: float | Sequence[float] = 0.5,
                    pixel_cov: np.ndarray | None = None,
                    max_residual_px: float | None = None,
                    rectified: bool = False, covariance: bool = True) -> StereoPoint:
    """(a) Linear (DLT) triangulation from rectified pixels with ``P1, P2``.

    Args:
        rig: rectified stereo rig.
        left_px, right_px: pixel coordinates, shape (2,): distorted image pixels, or rectified
            pixels when ``rectified`` is True.
        sigma_px: pixel noise (1 sigma) per coordinate for the covariance: one number, or
            (left, right) per image; in the images the inputs come from (distorted pixels,
            propagated through the rectification; or rectified pixels when ``rectified``).
        pixel_cov: optional full (4, 4) covariance of (xl, yl, xr, yr) instead of
            ``sigma_px`` (e.g. per-image terms plus a shift common to both images).
        max_residual_px: reject above this RMS reprojection residual (None: no gate).
        rectified: the inputs are already rectified pixel coordinates.
        covariance: False: the point and the rejections alone, the covariance NaN (``sigma_px``
            and ``pixel_cov`` are then neither used nor checked): for a caller that only needs
            where the point is, e.g. the stereo locator before it refines the centres. (A
            disparity so small that the rays are parallel to machine precision leaves no
            Jacobian: rejected when the covariance is asked for, its point returned when not.)

    Returns:
        The point in the left optical frame.

    Raises:
        InputError: bad arguments. Rejected: behind a camera, non-positive disparity, residual.
    """
    _check_rig(rig)
    S = _pixel_cov(sigma_px, pixel_cov) if covariance else None
    if rectified:
        xl, xr, Jpx = _px(left_px, "left_px"), _px(right_px, "right_px"), _EYE4
    else:
        xl, xr, Jpx = _rectify_with_jacobian(rig, left_px, right_px)
    return _dlt(rig, xl, xr, Jpx, S, covariance, max_residual_px)


def _dlt(rig: StereoRig, xl: np.ndarray, xr: np.ndarray, Jpx: np.ndarray, S: np.ndarray | None,
         covariance: bool, max_residual_px: float | None) -> StereoPoint:
    """:func:`triangulate_dlt`'s work on checked rectified pixels ``xl, xr`` (``Jpx`` their
    Jacobian from the inputs, ``S`` the inputs' covariance or None)."""
    d = _disparity(rig, xl, xr)
    _check_disparity(rig, d)
    P1, P2 = rig.P1, rig.P2
    X, J = _dlt_rect(P1, P2, xl, xr, with_jacobian=covariance)
    if X[0] == np.inf:            # _dlt_rect's answer for a solution at infinity
        raise Rejected("behind_camera", "the DLT solution is at infinity")
    if covariance and J is None:
        raise Rejected("non_positive_disparity",
                       f"disparity {d:.3g} px is too small to triangulate: the rays are "
                       "parallel to machine precision (the point is at infinity)")
    cov = None
    if S is not None and J is not None:
        J = J @ Jpx
        cov = J @ S @ J.T
    return _finish(rig, X, cov, _reproj_rms(P1, P2, X, xl, xr), "dlt", d, max_residual_px)


def triangulate_parallax(rig: StereoRig, left_px, right_px, *,
                         sigma_px: float | Sequence[float] = 0.5,
                         pixel_cov: np.ndarray | None = None,
                         max_residual_px: float | None = None,
                         rectified: bool = False, covariance: bool = True) -> StereoPoint:
    """(b) Parallax triangulation on rectified coordinates: ``Z = f B / d``, then X, Y.

    ``Y`` uses the mean of the two rectified rows (they agree up to noise). Horizontal rigs only.

    Arguments, returns and errors as :func:`triangulate_dlt`; also raises InputError for a
    vertically rectified rig.
    """
    _check_rig(rig)
    S = _pixel_cov(sigma_px, pixel_cov) if covariance else None
    _check_horizontal(rig)
    if rectified:
        xl, xr, Jpx = _px(left_px, "left_px"), _px(right_px, "right_px"), _EYE4
    else:
        xl, xr, Jpx = _rectify_with_jacobian(rig, left_px, right_px)
    return _parallax(rig, xl, xr, Jpx, S, max_residual_px)


def _check_horizontal(rig: StereoRig) -> None:
    if abs(rig.P2[1, 3]) > abs(rig.P2[0, 3]):
        raise InputError("parallax method: the rig is rectified vertically; use 'dlt' or "
                         "'optimal'")


def _parallax(rig: StereoRig, xl: np.ndarray, xr: np.ndarray, Jpx: np.ndarray,
              S: np.ndarray | None, max_residual_px: float | None) -> StereoPoint:
    """:func:`triangulate_parallax`'s work on checked rectified pixels of a horizontal rig
    (arguments as :func:`_dlt`'s)."""
    P1, P2 = rig.P1, rig.P2
    d = _disparity(rig, xl, xr)
    _check_disparity(rig, d)
    f, fy = P1[0, 0], P1[1, 1]
    cx, cy = P1[0, 2], P1[1, 2]
    fb = -P2[0, 3]  # = f * B
    Z = fb / d
    u = xl[0] - cx
    v = 0.5 * (xl[1] + xr[1]) - cy
    X_rect = np.array([u * Z / f, v * Z / fy, Z])
    if S is None:
        return _finish(rig, X_rect, None, _reproj_rms(P1, P2, X_rect, xl, xr), "disparity", d,
                       max_residual_px)
    # d Z / d(xl, yl, xr, yr) = (-Z/d, 0, Z/d, 0)
    dZ = np.array([-Z / d, 0.0, Z / d, 0.0])
    J = np.empty((3, 4))
    J[0] = (u / f) * dZ + np.array([Z / f, 0.0, 0.0, 0.0])
    J[1] = (v / fy) * dZ + np.array([0.0, 0.5 * Z / fy, 0.0, 0.5 * Z / fy])
    J[2] = dZ
    J = J @ Jpx
    cov = J @ S @ J.T
    return _finish(rig, X_rect, cov, _reproj_rms(P1, P2, X_rect, xl, xr), "disparity", d,
                   max_residual_px)


def triangulate_rectified(rig: StereoRig, xl: np.ndarray, xr: np.ndarray, *, method: str,
                          pixel_cov: np.ndarray | None,
                          max_residual_px: float | None) -> StereoPoint:
    """:func:`triangulate_dlt` (``method`` "dlt") or :func:`triangulate_parallax`
    ("disparity") of rectified pixels, for a caller that made the rig and the covariance
    itself: ``pixel_cov`` is used as given, not checked (the checks, an eigen-decomposition
    among them, cost a fifth of a located target's two triangulations; the stereo locator builds
    its covariance as a sum of squares, symmetric and positive semi-definite, for every blob
    pair). The same point, covariance and rejections, to the last bit.

    Args:
        rig: a rectified stereo rig.
        xl, xr: rectified pixel coordinates, float64, shape (2,).
        method: "dlt" or "disparity".
        pixel_cov: the (4, 4) covariance of (xl, yl, xr, yr): finite, symmetric, positive
            semi-definite; None for no covariance (NaN, as ``covariance=False``).
        max_residual_px: reject above this RMS reprojection residual (None: no gate).

    Raises:
        InputError: a coordinate is not finite, an unknown method, or "disparity" on a
            vertically rectified rig. Rejected: as the two functions.
    """
    if not (math.isfinite(xl[0]) and math.isfinite(xl[1]) and math.isfinite(xr[0])
            and math.isfinite(xr[1])):
        raise InputError(f"xl, xr: expected finite rectified pixel coordinates, got "
                         f"{xl!r}, {xr!r}")
    if method == "dlt":
        return _dlt(rig, xl, xr, _EYE4, pixel_cov, pixel_cov is not None, max_residual_px)
    if method == "disparity":
        _check_horizontal(rig)
        return _parallax(rig, xl, xr, _EYE4, pixel_cov, max_residual_px)
    raise InputError(f"method: {method!r} is not 'dlt' or 'disparity'")


def _project_with_jacobian(K: np.ndarray, dist: np.ndarray, R: np.ndarray, t: np.ndarray,
                           X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel of ``R X + t`` and its Jacobian d px / d X, shape (2,), (2, 3)."""
    rvec = cv2.Rodrigues(R)[0]
    img, jac = cv2.projectPoints(X.reshape(1, 1, 3), rvec, t.reshape(3, 1), K, dist)
    # columns 3:6 are d px / d tvec = d px / d (R X + t); chain with d(RX+t)/dX = R
    return img.reshape(2), jac[:, 3:6] @ R


def triangulate_optimal(rig: StereoRig, left_px, right_px, *,
                        sigma_px: float | Sequence[float] = 0.5,
                        pixel_cov: np.ndarray | None = None,
                        max_residual_px: float | None = None, max_iterations: int = 10,
                        initial: StereoPoint | None = None) -> StereoPoint:
    """(c) Optimal triangulation: minimise the reprojection error in both distorted images.

    Gauss-Newton over the point in the left optical frame through the full camera models
    (distortion included), from the DLT point (or ``initial``), until the step is below 1e-9 m.

    Args:
        rig: rectified stereo rig (only ``R, T`` and the cameras' ``K, dist`` are used here,
            plus ``P1, P2`` for the DLT start).
        left_px, right_px: distorted pixel coordinates, shape (2,).
        sigma_px: pixel noise for the covariance ``(J^T J)^-1 J^T S J (J^T J)^-1``, one number
            or (left, right).
        max_residual_px: residual gate (RMS over the four coordinates), None for no gate.
        max_iterations: Gauss-Newton iterations (>= 1).
        initial: a start point (e.g. from :func:`triangulate_dlt`); computed when None.

    Returns:
        The point in the left optical frame.

    Raises:
        InputError: bad arguments. Rejected: behind a camera, non-positive disparity, residual
            over the gate, or no convergence.
    """
    _check_rig(rig)
    S = _pixel_cov(sigma_px, pixel_cov)
    ul, ur = _px(left_px, "left_px"), _px(right_px, "right_px")
    start = initial if initial is not None else triangulate_dlt(rig, ul, ur, covariance=False)
    X = np.array(start.point, dtype=np.float64)
    I3, z3 = np.eye(3), np.zeros(3)
    Kl, dl, Kr, dr = rig.left.K, rig.left.dist, rig.right.K, rig.right.dist
    R, T = rig.R, rig.T
    converged = False
    for _ in range(max(1, int(max_iterations))):
        pl, Jl = _project_with_jacobian(Kl, dl, I3, z3, X)
        pr, Jr = _project_with_jacobian(Kr, dr, R, T, X)
        e = np.concatenate([pl - ul, pr - ur])
        J = np.vstack([Jl, Jr])
        step, *_ = np.linalg.lstsq(J, -e, rcond=None)
        X = X + step
        if not np.all(np.isfinite(X)):
            break
        if np.linalg.norm(step) < 1e-9:
            converged = True
            break
    if not converged and np.all(np.isfinite(X)):
        converged = bool(np.linalg.norm(step) < 1e-6)
    if not converged:
        raise Rejected("not_converged", "optimal triangulation did not converge "
                                        f"(last step {np.linalg.norm(step):.2e} m)")
    pl, Jl = _project_with_jacobian(Kl, dl, I3, z3, X)
    pr, Jr = _project_with_jacobian(Kr, dr, R, T, X)
    e = np.concatenate([pl - ul, pr - ur])
    J = np.vstack([Jl, Jr])
    residual = float(math.sqrt(np.mean(e * e)))
    # the estimator is unweighted least squares: sandwich covariance (= sigma^2 (J^T J)^-1
    # when the four sigmas are equal)
    JtJ_inv = np.linalg.inv(J.T @ J)
    cov_left = JtJ_inv @ (J.T @ S @ J) @ JtJ_inv
    # _finish works in the rectified frame: hand it X and cov rotated there
    R1 = rig.R1
    return _finish(rig, R1 @ X, R1 @ cov_left @ R1.T, residual, "optimal",
                   start.disparity_px, max_residual_px)


def triangulate(rig: StereoRig, left_px, right_px, *, method: str = "dlt",
                sigma_px: float | Sequence[float] = 0.5,
                max_residual_px: float | None = None) -> StereoPoint:
    """Triangulate with the named method ("dlt", "disparity" or "optimal").

    Arguments, returns and errors as the individual methods; InputError for an unknown method.
    """
    if method == "dlt":
        return triangulate_dlt(rig, left_px, right_px, sigma_px=sigma_px,
                               max_residual_px=max_residual_px)
    if method == "disparity":
        return triangulate_parallax(rig, left_px, right_px, sigma_px=sigma_px,
                                    max_residual_px=max_residual_px)
    if method == "optimal":
        return triangulate_optimal(rig, left_px, right_px, sigma_px=sigma_px,
                                   max_residual_px=max_residual_px)
    raise InputError(f"method: '{method}' is not one of {', '.join(METHODS)}")
