"""Single-camera calibration (Zhang's method, ``cv2.calibrateCameraExtended``) with per-view
errors, outlier flags and rejection, coverage and parameter standard deviations."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from eye_in_hand.core.calibration.board import BoardDetection
from eye_in_hand.core.calibration.quality import coverage, outlier_threshold
from eye_in_hand.core.camera import CameraModel
from eye_in_hand.errors import CalibrationError, InputError

#: Fewest corners a view needs to take part in a calibration.
MIN_POINTS_PER_VIEW = 6

_INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


@dataclass(frozen=True)
class CalibrationOptions:
    """Which camera parameters are estimated.

    Attributes:
        rational: use the 8-coefficient ``rational_polynomial`` model (k1..k6, p1, p2) instead
            of ``plumb_bob`` (k1, k2, p1, p2, k3).
        fix_k3: keep k3 at 0.
        zero_tangent: keep p1 = p2 = 0.
        fix_aspect: keep fx / fy at its initial value (1 for a fresh calibration).
        fix_principal_point: keep cx, cy at the image centre.
    """

    rational: bool = False
    fix_k3: bool = False
    zero_tangent: bool = False
    fix_aspect: bool = False
    fix_principal_point: bool = False

    @property
    def distortion_model(self) -> str:
        """ROS name of the distortion model."""
        return "rational_polynomial" if self.rational else "plumb_bob"

    @property
    def n_dist(self) -> int:
        """Number of distortion coefficients."""
        return 8 if self.rational else 5

    def cv_flags(self) -> int:
        """The matching ``cv2.CALIB_*`` flags."""
        flags = 0
        if self.rational:
            flags |= cv2.CALIB_RATIONAL_MODEL
        if self.fix_k3:
            flags |= cv2.CALIB_FIX_K3
        if self.zero_tangent:
            flags |= cv2.CALIB_ZERO_TANGENT_DIST
        if self.fix_aspect:
            flags |= cv2.CALIB_FIX_ASPECT_RATIO
        if self.fix_principal_point:
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
        return flags

    def free_intrinsics(self) -> np.ndarray:
        """Mask over ``fx, fy, cx, cy, dist...``: True where the parameter is estimated.

        With ``fix_aspect`` fy is marked fixed; it follows fx at the initial ratio.
        """
        free = np.ones(4 + self.n_dist, dtype=bool)
        if self.fix_aspect:
            free[1] = False
        if self.fix_principal_point:
            free[2:4] = False
        if self.zero_tangent:
            free[4 + 2:4 + 4] = False
        if self.fix_k3:
            free[4 + 4] = False
        return free

    def to_dict(self) -> dict:
        """The options as a JSON-able dict."""
        return {"distortion_model": self.distortion_model, "fix_k3": self.fix_k3,
                "zero_tangent": self.zero_tangent, "fix_aspect": self.fix_aspect,
                "fix_principal_point": self.fix_principal_point}


@dataclass(frozen=True)
class ViewResult:
    """One board view in a calibration.

    Attributes:
        name: the image (file name, or ``topic@stamp`` for bag frames).
        n_points: corners observed.
        rms_px: RMS reprojection error of this view, pixels (NaN when not used).
        used: the view took part in the final solution.
        outlier: the view's RMS is above the outlier threshold.
        cam_T_board: array, shape (4, 4): board pose in the camera frame (None when not used).
        corners: array, shape (N, 2): observed corners, pixels.
        residuals: array, shape (N, 2): observed minus reprojected corners, pixels.
        index: position of the view in the detections given to the calibration.
    """

    name: str
    n_points: int
    rms_px: float
    used: bool
    outlier: bool
    cam_T_board: np.ndarray | None
    corners: np.ndarray
    residuals: np.ndarray
    index: int = -1

    def to_dict(self) -> dict:
        """JSON-able summary (without the arrays)."""
        return {"file": self.name, "rms_px": _f(self.rms_px), "used": self.used,
                "outlier": self.outlier, "n_points": self.n_points}


def _f(value: float) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


def _as_pose(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
    T[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    return T


def _rvec(R: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].reshape(3)


@dataclass(frozen=True)
class CameraCalibration:
    """Result of :func:`calibrate_camera`.

    Attributes:
        camera: the calibrated camera (R identity, P = [K | 0]).
        rms_px: overall RMS reprojection error over all corners of the used views, pixels.
        views: one entry per view given (used or rejected).
        std: standard deviations of the estimated parameters (``fx``, ``fy``, ``cx``, ``cy``,
            ``k1``...), from the Jacobian at the solution (``cv2.calibrateCameraExtended``);
            0 for fixed parameters.
        coverage: fraction of the image covered by the used boards.
        coverage_map: array, shape (h, w): boards per cell (see :func:`coverage`).
        outlier_threshold_px: the per-view RMS threshold used to flag outliers.
        rejected: names of views dropped by ``reject_outliers``.
        options: the options used.
    """

    camera: CameraModel
    rms_px: float
    views: tuple[ViewResult, ...]
    std: dict
    coverage: float
    coverage_map: np.ndarray
    outlier_threshold_px: float
    rejected: tuple[str, ...]
    options: CalibrationOptions

    @property
    def used_views(self) -> list[ViewResult]:
        """The views in the final solution."""
        return [v for v in self.views if v.used]

    def to_dict(self) -> dict:
        """JSON-able report content (``camera`` block + ``views`` list)."""
        cam = self.camera
        return {
            "camera": {
                "name": cam.name,
                "image_size": [cam.width, cam.height],
                "rms_px": _f(self.rms_px),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "distortion_model": cam.distortion_model,
                "std": {k: _f(v) for k, v in self.std.items()},
                "coverage": _f(self.coverage),
                "n_views_used": len(self.used_views),
                "outlier_threshold_px": _f(self.outlier_threshold_px),
                "outliers": [v.name for v in self.views if v.outlier],
                "rejected": list(self.rejected),
                "options": self.options.to_dict(),
            },
            "views": [v.to_dict() for v in self.views],
        }


def _usable(det: BoardDetection) -> bool:
    return bool(det.found) and det.n_corners >= MIN_POINTS_PER_VIEW


def _check_sizes(dets: Sequence[BoardDetection], names: Sequence[str], what: str
                 ) -> tuple[int, int]:
    sizes = {tuple(d.image_size) for d in dets}
    if len(sizes) > 1:
        first = tuple(dets[0].image_size)
        bad = next(i for i, d in enumerate(dets) if tuple(d.image_size) != first)
        raise CalibrationError(
            f"{what}: images differ in size: {names[0]} is {first[0]}x{first[1]}, "
            f"{names[bad]} is {dets[bad].image_size[0]}x{dets[bad].image_size[1]}")
    return tuple(dets[0].image_size)  # type: ignore[return-value]


def _names(dets: Sequence[BoardDetection], names: Sequence[str] | None, what: str) -> list[str]:
    if names is None:
        return [f"{what}[{i}]" for i in range(len(dets))]
    if len(names) != len(dets):
        raise InputError(f"{what}: {len(names)} names for {len(dets)} detections")
    return [str(n) for n in names]


def _std_dict(std_intr: np.ndarray, options: CalibrationOptions) -> dict:
    std = np.asarray(std_intr, dtype=np.float64).ravel()
    out = {n: float(std[i]) for i, n in enumerate(_INTRINSIC_NAMES)}
    for i, n in enumerate(_DIST_NAMES[:options.n_dist]):
        out[n] = float(std[4 + i]) if 4 + i < std.size else 0.0
    return out


def _mono_once(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
               options: CalibrationOptions):
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    try:
        # OpenCV's stubs refuse None for the initial K and dist, which the function takes
        rms, K, dist, rvecs, tvecs, std_intr, _std_extr, per_view = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            [o.astype(np.float32) for o in obj],
            [p.astype(np.float32).reshape(-1, 1, 2) for p in img],
            size, None, None, flags=options.cv_flags(), criteria=criteria)
    except cv2.error as exc:
        raise CalibrationError(f"cv2.calibrateCamera failed: {str(exc).strip()}") from exc
    dist = np.asarray(dist, dtype=np.float64).ravel()[:options.n_dist]
    if dist.size < options.n_dist:
        dist = np.concatenate([dist, np.zeros(options.n_dist - dist.size)])
    return float(rms), K, dist, rvecs, tvecs, std_intr, per_view


def calibrate_camera(detections: Sequence[BoardDetection], names: Sequence[str] | None = None, *,
                     options: CalibrationOptions = CalibrationOptions(),
                     reject_outliers: bool = False, outlier_threshold_px: float | None = None,
                     min_views: int = 3, camera_name: str = "camera",
                     max_rejection_rounds: int = 3) -> CameraCalibration:
    """Calibrate one camera from board detections (Zhang's method, ``cv2.calibrateCamera``).

    Views without a board (``found`` False) or with fewer than ``MIN_POINTS_PER_VIEW`` corners
    are ignored (callers list them with their reason). Views whose RMS is above the outlier
    threshold (:func:`outlier_threshold`) are flagged; with ``reject_outliers`` they are dropped
    and the calibration recomputed (up to ``max_rejection_rounds`` times, never going below
    ``min_views``).

    Args:
        detections: one per image, all of the same image size.
        names: the images' names for the report (default ``camera[i]``).
        options: which parameters to estimate.
        reject_outliers: drop flagged views and recompute.
        outlier_threshold_px: fixed per-view RMS threshold instead of the robust rule.
        min_views: fewest usable views accepted.
        camera_name: name written into the camera model.
        max_rejection_rounds: rejection rounds at most.

    Returns:
        The :class:`CameraCalibration`.

    Raises:
        CalibrationError: fewer than ``min_views`` usable views, image sizes differ, or OpenCV
            fails.
    """
    names = _names(detections, names, camera_name)
    usable = [i for i, d in enumerate(detections) if _usable(d)]
    if len(usable) < max(1, int(min_views)):
        raise CalibrationError(
            f"{camera_name}: only {len(usable)} usable board view(s) of {len(detections)} "
            f"image(s), need at least {min_views}")
    size = _check_sizes([detections[i] for i in usable], [names[i] for i in usable], camera_name)
    active = list(usable)
    rejected: list[int] = []
    for _round in range(max(0, int(max_rejection_rounds)) + 1):
        obj = [detections[i].object_points for i in active]
        img = [detections[i].corners for i in active]
        rms, K, dist, rvecs, tvecs, std_intr, per_view = _mono_once(obj, img, size, options)
        per_view = np.asarray(per_view, dtype=np.float64).ravel()
        thr = outlier_threshold(per_view, outlier_threshold_px)
        flagged = [active[k] for k in range(len(active)) if per_view[k] > thr]
        if not (reject_outliers and flagged) or _round == max_rejection_rounds:
            break
        if len(active) - len(flagged) < min_views:
            break
        rejected.extend(flagged)
        active = [i for i in active if i not in flagged]

    camera = CameraModel(K=K, dist=dist, width=size[0], height=size[1],
                         distortion_model=options.distortion_model, name=camera_name)
    pose_of = {i: _as_pose(rvecs[k], tvecs[k]) for k, i in enumerate(active)}
    views = []
    T: np.ndarray | None
    for i, det in enumerate(detections):
        if not det.found:
            continue
        if i in pose_of:
            T = pose_of[i]
            proj = _project(det.object_points, T, K, dist)
            res = det.corners - proj
            view_rms = float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
            views.append(ViewResult(names[i], det.n_corners, view_rms, True, view_rms > thr, T,
                                    det.corners, res, i))
        else:
            # rejected (or too few corners): report its error under the final intrinsics
            res, view_rms, T = _residuals_free_pose(det, K, dist)
            views.append(ViewResult(names[i], det.n_corners, view_rms, False,
                                    i in rejected or view_rms > thr, T, det.corners, res, i))
    frac, cmap = coverage([detections[i].corners for i in active], size)
    return CameraCalibration(camera=camera, rms_px=rms, views=tuple(views),
                             std=_std_dict(std_intr, options), coverage=frac, coverage_map=cmap,
                             outlier_threshold_px=thr,
                             rejected=tuple(names[i] for i in rejected), options=options)


def _project(obj: np.ndarray, cam_T_board: np.ndarray, K: np.ndarray, dist: np.ndarray
             ) -> np.ndarray:
    proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), _rvec(cam_T_board[:3, :3]),
                                cam_T_board[:3, 3].copy(), K, dist)
    return proj.reshape(-1, 2)


def _residuals_free_pose(det: BoardDetection, K: np.ndarray, dist: np.ndarray
                         ) -> tuple[np.ndarray, float, np.ndarray | None]:
    if det.n_corners < 4:
        return np.full((det.n_corners, 2), np.nan), float("nan"), None
    ok, rvec, tvec = cv2.solvePnP(det.object_points, det.corners.reshape(-1, 1, 2), K, dist,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return np.full((det.n_corners, 2), np.nan), float("nan"), None
    T = _as_pose(rvec, tvec)
    res = det.corners - _project(det.object_points, T, K, dist)
    return res, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))), T
