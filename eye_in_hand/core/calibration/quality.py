"""Quality figures of a calibration: outlier threshold, image coverage, stereo checks."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from eye_in_hand.core.calibration.board import BoardDetection, BoardSpec, _pair_points
from eye_in_hand.core.camera import StereoRig
from eye_in_hand.errors import CalibrationError

#: Default floor of the outlier threshold, as a multiple of the median per-view RMS.
OUTLIER_MEDIAN_FACTOR = 2.0
#: Robust spread term of the outlier threshold: median + this many scaled MADs.
OUTLIER_MAD_FACTOR = 4.0


def outlier_threshold(view_rms: np.ndarray, absolute_px: float | None = None) -> float:
    """The per-view RMS above which a view is flagged as an outlier.

    ``max(2 * median, median + 4 * 1.4826 * MAD)`` of the per-view RMS values, or
    ``absolute_px`` when given.

    Args:
        view_rms: array, shape (V,): per-view RMS, pixels.
        absolute_px: fixed threshold in pixels, overriding the robust rule.

    Returns:
        The threshold in pixels (inf when there are fewer than 3 views).
    """
    if absolute_px is not None:
        return float(absolute_px)
    vals = np.asarray(view_rms, dtype=np.float64)
    vals = vals[np.isfinite(vals)]
    if vals.size < 3:
        return float("inf")
    med = float(np.median(vals))
    mad = 1.4826 * float(np.median(np.abs(vals - med)))
    return max(OUTLIER_MEDIAN_FACTOR * med, med + OUTLIER_MAD_FACTOR * mad)


def coverage(corner_sets: Sequence[np.ndarray], image_size: tuple[int, int],
             scale: float = 0.25) -> tuple[float, np.ndarray]:
    """Fraction of the image area covered by at least one board (convex hull of its corners).

    Args:
        corner_sets: per view, array, shape (N, 2) of corner pixels.
        image_size: ``(width, height)``.
        scale: resolution of the coverage map relative to the image.

    Returns:
        ``(fraction, counts)``: fraction in [0, 1]; counts, array, shape
        (round(H*scale), round(W*scale)), int32: how many boards cover each cell.
    """
    w = max(1, int(round(image_size[0] * scale)))
    h = max(1, int(round(image_size[1] * scale)))
    counts = np.zeros((h, w), dtype=np.int32)
    for corners in corner_sets:
        pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] < 3:
            continue
        hull = cv2.convexHull(np.round(pts * scale).astype(np.int32))
        mask = np.zeros((h, w), dtype=np.uint8)
        cv2.fillConvexPoly(mask, hull, 1)
        counts += mask
    return float(np.count_nonzero(counts)) / float(h * w), counts


@dataclass(frozen=True)
class StereoQuality:
    """Geometric checks of a stereo calibration on the paired views.

    Attributes:
        epipolar_error_px: mean symmetric distance of a corner to the epipolar line of its
            partner, in undistorted pixels.
        epipolar_error_max_px: its maximum.
        rectified_dy_mean_px: mean |y_left - y_right| of corners after rectification.
        rectified_dy_max_px: its maximum.
        square_measured_mean: mean distance between adjacent corners triangulated in 3-D, in
            board units (should equal the board's square).
        square_measured_std: standard deviation of those distances.
        n_points: corners compared.
    """

    epipolar_error_px: float
    epipolar_error_max_px: float
    rectified_dy_mean_px: float
    rectified_dy_max_px: float
    square_measured_mean: float
    square_measured_std: float
    n_points: int


def stereo_quality(rig: StereoRig, pairs: Sequence[tuple[BoardDetection, BoardDetection]],
                   board: BoardSpec | None = None) -> StereoQuality:
    """Epipolar error, rectified row difference and triangulated square length.

    Args:
        rig: a rectified rig (:meth:`StereoRig.rectified`).
        pairs: ``(left, right)`` detections of the same board.
        board: the board (its ``cols`` give the corner grid for the square-length check;
            default: taken as the detections' grid, adjacent ids along rows).

    Returns:
        The :class:`StereoQuality`.

    Raises:
        CalibrationError: no pair has common corners, or the rig is not rectified.
    """
    if not rig.is_rectified:
        raise CalibrationError("stereo_quality: the rig must be rectified")
    K1, K2 = rig.left.K, rig.right.K
    Tx = np.array([[0, -rig.T[2], rig.T[1]], [rig.T[2], 0, -rig.T[0]], [-rig.T[1], rig.T[0], 0]])
    F = np.linalg.inv(K2).T @ Tx @ rig.R @ np.linalg.inv(K1)
    epi, dy, lengths = [], [], []
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    for ld, rd in pairs:
        ids, _obj, pl, pr = _pair_points(ld, rd)
        if ids.size == 0:
            continue
        ul = cv2.undistortPoints(pl.reshape(-1, 1, 2), K1, rig.left.dist, None, None, K1,
                                 crit).reshape(-1, 2)
        ur = cv2.undistortPoints(pr.reshape(-1, 1, 2), K2, rig.right.dist, None, None, K2,
                                 crit).reshape(-1, 2)
        hl = np.hstack([ul, np.ones((ul.shape[0], 1))])
        hr = np.hstack([ur, np.ones((ur.shape[0], 1))])
        lr = hl @ F.T  # epipolar lines in the right image
        ll = hr @ F    # epipolar lines in the left image
        d_r = np.abs(np.sum(lr * hr, axis=1)) / np.hypot(lr[:, 0], lr[:, 1])
        d_l = np.abs(np.sum(ll * hl, axis=1)) / np.hypot(ll[:, 0], ll[:, 1])
        epi.append(0.5 * (d_r + d_l))
        rl = rig.left.rectify_points(pl)
        rr = rig.right.rectify_points(pr)
        dy.append(np.abs(rl[:, 1] - rr[:, 1]))
        X = cv2.triangulatePoints(rig.P1, rig.P2, rl.T, rr.T)
        X = (X[:3] / X[3]).T
        cols = board.cols if board is not None else None
        if cols is None:
            continue
        pos = {int(i): k for k, i in enumerate(ids)}
        for i, k in pos.items():
            if (i % cols) < cols - 1 and (i + 1) in pos:
                lengths.append(np.linalg.norm(X[pos[i + 1]] - X[k]))
            if (i + cols) in pos:
                lengths.append(np.linalg.norm(X[pos[i + cols]] - X[k]))
    if not epi:
        raise CalibrationError("stereo_quality: no stereo pair with common board corners")
    e = np.concatenate(epi)
    d = np.concatenate(dy)
    sq = np.asarray(lengths, dtype=np.float64)
    return StereoQuality(
        epipolar_error_px=float(e.mean()), epipolar_error_max_px=float(e.max()),
        rectified_dy_mean_px=float(d.mean()), rectified_dy_max_px=float(d.max()),
        square_measured_mean=float(sq.mean()) if sq.size else float("nan"),
        square_measured_std=float(sq.std(ddof=1)) if sq.size > 1 else float("nan"),
        n_points=int(e.size))
