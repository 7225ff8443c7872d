"""Stereo calibration: each camera alone, then a joint bundle adjustment over both cameras'
intrinsics and distortion, the extrinsic and every board pose, then rectification."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import scipy.linalg
from scipy.sparse import csr_matrix

from eye_in_hand.core.calibration.board import BoardDetection, BoardSpec, _pair_points
from eye_in_hand.core.calibration.mono import (
    _DIST_NAMES,
    _INTRINSIC_NAMES,
    MIN_POINTS_PER_VIEW,
    CalibrationOptions,
    CameraCalibration,
    _as_pose,
    _f,
    _names,
    _rvec,
    _usable,
    calibrate_camera,
)
from eye_in_hand.core.calibration.quality import StereoQuality, outlier_threshold, stereo_quality
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import average_transforms
from eye_in_hand.errors import CalibrationError, InputError

#: Accepted values of the ``method`` argument of :func:`calibrate_stereo`.
STEREO_METHODS: tuple[str, ...] = ("bundle", "opencv")


@dataclass(frozen=True)
class StereoViewResult:
    """One stereo pair in a stereo calibration.

    Attributes:
        name: the left image's name.
        right_name: the right image's name.
        left_found, right_found: the board was found in that image.
        n_points: corners used in the joint fit (left + right).
        rms_px: RMS reprojection error of this pair in the joint fit (NaN when not used).
        used: the pair took part in the final joint solution (both or one side).
        paired: the board was seen in both images (the pair counts for the extrinsic).
        outlier: the RMS is above the outlier threshold.
        left_residuals, right_residuals: arrays, shape (N, 2), observed minus reprojected
            (None when that side was not used).
    """

    name: str
    right_name: str
    left_found: bool
    right_found: bool
    n_points: int
    rms_px: float
    used: bool
    paired: bool
    outlier: bool
    left_residuals: np.ndarray | None = None
    right_residuals: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (without the arrays)."""
        return {"file": self.name, "right_file": self.right_name, "rms_px": _f(self.rms_px),
                "used": self.used, "paired": self.paired, "outlier": self.outlier,
                "left_found": self.left_found, "right_found": self.right_found,
                "n_points": self.n_points}


@dataclass(frozen=True)
class StereoCalibration:
    """Result of :func:`calibrate_stereo`.

    Attributes:
        rig: the calibrated, rectified rig (``X_right = R X_left + T``, board units).
        left, right: the per-camera (mono) calibrations the joint fit started from.
        rms_px: RMS reprojection error of the joint fit over all corners of both cameras.
        views: one entry per image pair.
        std: standard deviations from the joint fit's Jacobian: ``left.fx`` ...,
            ``right.k1`` ..., ``T.x``, ``T.y``, ``T.z``, ``baseline``, ``R.rx/ry/rz`` (rad).
        quality: the geometric checks.
        method: ``bundle`` or ``opencv``.
        alpha: the rectification's free-scaling parameter.
        outlier_threshold_px: the per-pair RMS threshold used to flag outliers.
        rejected: names of pairs dropped by ``reject_outliers``.
        options: the options used.
        fix_intrinsics: the intrinsics were kept at the mono results.
    """

    rig: StereoRig
    left: CameraCalibration
    right: CameraCalibration
    rms_px: float
    views: tuple[StereoViewResult, ...]
    std: dict[str, Any]
    quality: StereoQuality
    method: str
    alpha: float
    outlier_threshold_px: float
    rejected: tuple[str, ...]
    options: CalibrationOptions
    fix_intrinsics: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-able report content (``left``, ``right``, ``stereo`` blocks + ``views``)."""
        rig = self.rig

        def cam_block(cam: CameraModel, mono: CameraCalibration, side: str) -> dict[str, Any]:
            return {
                "name": cam.name,
                "image_size": [cam.width, cam.height],
                "rms_px": _f(self.side_rms(side)),
                "mono_rms_px": _f(mono.rms_px),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "distortion_model": cam.distortion_model,
                "R_rect": cam.R.tolist(),
                "P_rect": cam.P.tolist(),
                "std": {k.split(".", 1)[1]: _f(v) for k, v in self.std.items()
                        if k.startswith(side + ".")},
                "coverage": _f(mono.coverage),
                "n_views": len(mono.used_views),
            }

        q = self.quality
        return {
            "left": cam_block(rig.left, self.left, "left"),
            "right": cam_block(rig.right, self.right, "right"),
            "stereo": {
                "rms_px": _f(self.rms_px),
                "R": rig.R.tolist(),
                "T": rig.T.tolist(),
                "baseline": _f(rig.baseline),
                "rotation_deg": _f(np.degrees(np.linalg.norm(_rvec(rig.R)))),
                "std": {k: _f(v) for k, v in self.std.items()
                        if not k.startswith(("left.", "right."))},
                "epipolar_error_px": _f(q.epipolar_error_px),
                "epipolar_error_max_px": _f(q.epipolar_error_max_px),
                "rectified_dy_mean_px": _f(q.rectified_dy_mean_px),
                "rectified_dy_max_px": _f(q.rectified_dy_max_px),
                "square_measured": {"mean": _f(q.square_measured_mean),
                                    "std": _f(q.square_measured_std), "n": q.n_points},
                "Q": None if rig.Q is None else rig.Q.tolist(),
                "alpha": self.alpha,
                "method": self.method,
                "fix_intrinsics": self.fix_intrinsics,
                "n_pairs_used": sum(1 for v in self.views if v.used and v.paired),
                "outlier_threshold_px": _f(self.outlier_threshold_px),
                "outliers": [v.name for v in self.views if v.outlier],
                "rejected": list(self.rejected),
                "options": self.options.to_dict(),
            },
            "views": [v.to_dict() for v in self.views],
        }

    def side_rms(self, side: str) -> float:
        """RMS of one camera's residuals in the joint fit, pixels."""
        key = "left_residuals" if side == "left" else "right_residuals"
        res = [getattr(v, key) for v in self.views if v.used and getattr(v, key) is not None]
        if not res:
            return float("nan")
        allres = np.concatenate(res)
        return float(np.sqrt(np.mean(np.sum(allres ** 2, axis=1))))


class _Bundle:
    """Joint least squares over both cameras' intrinsics, distortion, the extrinsic and the
    per-view board poses (in the left camera frame), with analytic Jacobians from
    ``cv2.projectPoints`` and ``cv2.composeRT``."""

    def __init__(self, K: list[np.ndarray], dist: list[np.ndarray], ext_rvec: np.ndarray,
                 ext_tvec: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]],
                 obs: list[list[tuple[np.ndarray, np.ndarray] | None]],
                 options: CalibrationOptions, fix_intrinsics: bool) -> None:
        self.nd = options.n_dist
        self.nc = 4 + self.nd
        self.nv = len(poses)
        self.obs = obs  # obs[v][c] = (object (N,3), image (N,2)) or None
        self.aspect = [float(k[0, 0] / k[1, 1]) for k in K]
        self.fix_aspect = options.fix_aspect
        x = []
        for c in range(2):
            x.extend([K[c][0, 0], K[c][1, 1], K[c][0, 2], K[c][1, 2]])
            x.extend(np.asarray(dist[c], dtype=np.float64).ravel()[:self.nd])
        x.extend(ext_rvec)
        x.extend(ext_tvec)
        for r, t in poses:
            x.extend(r)
            x.extend(t)
        self.x0 = np.asarray(x, dtype=np.float64)
        free = np.ones(self.x0.size, dtype=bool)
        cam_free = (np.zeros(self.nc, dtype=bool) if fix_intrinsics
                    else options.free_intrinsics())
        free[:self.nc] = cam_free
        free[self.nc:2 * self.nc] = cam_free
        self.free = free
        self.ext0 = 2 * self.nc
        self.pose0 = self.ext0 + 6
        self.m = 2 * sum(o[0].shape[0] for view in obs for o in view if o is not None)

    def camera(self, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
        p = x[c * self.nc:(c + 1) * self.nc]
        fy = p[0] / self.aspect[c] if self.fix_aspect else p[1]
        K = np.array([[p[0], 0.0, p[2]], [0.0, fy, p[3]], [0.0, 0.0, 1.0]])
        return K, p[4:].copy()

    def evaluate(self, x: np.ndarray, jac: bool = True
                 ) -> tuple[np.ndarray, Any, list[list[np.ndarray | None]]]:
        """Residuals (projected - observed), the sparse Jacobian (CSR, all parameters) and the
        per-view residuals (observed - projected) of each camera."""
        r = np.empty(self.m)
        rows_l: list[np.ndarray] = []
        cols_l: list[np.ndarray] = []
        vals_l: list[np.ndarray] = []

        def put(row0: int, block: np.ndarray, cols: np.ndarray) -> None:
            nr = block.shape[0]
            rows_l.append(np.repeat(np.arange(row0, row0 + nr), cols.size))
            cols_l.append(np.tile(cols, nr))
            vals_l.append(block.ravel())

        per_view: list[list[np.ndarray | None]] = []
        row = 0
        er, et = x[self.ext0:self.ext0 + 3], x[self.ext0 + 3:self.ext0 + 6]
        ext_cols = np.arange(self.ext0, self.ext0 + 6)
        cams = [self.camera(x, 0), self.camera(x, 1)]
        for v in range(self.nv):
            pv = self.pose0 + 6 * v
            vr, vt = x[pv:pv + 3], x[pv + 3:pv + 6]
            pose_cols = np.arange(pv, pv + 6)
            out: list[np.ndarray | None] = [None, None]
            for c in range(2):
                o = self.obs[v][c]
                if o is None:
                    continue
                obj, img = o
                n = obj.shape[0]
                if c == 0:
                    rr, tt = vr, vt
                else:
                    comp = cv2.composeRT(vr, vt, er, et)
                    rr, tt = comp[0].ravel(), comp[1].ravel()
                K, d = cams[c]
                proj, jp = cv2.projectPoints(obj.reshape(-1, 1, 3), rr, tt, K, d)
                res = proj.reshape(-1, 2) - img
                out[c] = -res
                r[row:row + 2 * n] = res.ravel()
                if jac:
                    Jrt = jp[:, 0:6]
                    Jf, Jc, Jd = jp[:, 6:8], jp[:, 8:10], jp[:, 10:10 + self.nd]
                    base = c * self.nc
                    if self.fix_aspect:
                        Jf = np.column_stack([Jf[:, 0] + Jf[:, 1] / self.aspect[c],
                                              np.zeros(Jf.shape[0])])
                    put(row, np.hstack([Jf, Jc, Jd]), np.arange(base, base + self.nc))
                    if c == 0:
                        put(row, Jrt, pose_cols)
                    else:
                        _, _, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = comp
                        Jr, Jt = Jrt[:, :3], Jrt[:, 3:]
                        put(row, np.hstack([Jr @ dr3dr1 + Jt @ dt3dr1, Jr @ dr3dt1 + Jt @ dt3dt1]),
                            pose_cols)
                        put(row, np.hstack([Jr @ dr3dr2 + Jt @ dt3dr2, Jr @ dr3dt2 + Jt @ dt3dt2]),
                            ext_cols)
                row += 2 * n
            per_view.append(out)
        J = None
        if jac:
            J = csr_matrix((np.concatenate(vals_l), (np.concatenate(rows_l),
                                                     np.concatenate(cols_l))),
                           shape=(self.m, x.size))
        return r, J, per_view

    def _normal(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r, J, _ = self.evaluate(x, jac=True)
        Jf = J[:, self.free]
        return r, np.asarray((Jf.T @ Jf).todense()), np.asarray(Jf.T @ r).ravel()

    def solve(self, max_iterations: int = 100) -> tuple[np.ndarray, np.ndarray]:
        """Levenberg-Marquardt (Marquardt's diagonal scaling) on the normal equations.

        The Jacobian is sparse (each board pose touches only its own rows); the normal matrix
        has the size of the parameter vector, so hundreds of views stay cheap.

        Returns:
            ``(x, covariance)``: all parameters, and the covariance over all parameters (zero
            rows/columns for fixed ones).
        """
        x = self.x0.copy()
        free = self.free
        r, A, g = self._normal(x)
        cost = float(r @ r)
        lam = 1e-3
        for _ in range(max_iterations):
            diag = np.diag(A).copy()
            diag[diag <= 0] = 1.0
            step = None
            while lam < 1e16:
                try:
                    M = A + lam * np.diag(diag)
                    step = -scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), g)
                except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
                    lam *= 10.0
                    continue
                x_try = x.copy()
                x_try[free] += step
                r_try = self.evaluate(x_try, jac=False)[0]
                cost_try = float(r_try @ r_try)
                if np.isfinite(cost_try) and cost_try < cost:
                    break
                lam *= 10.0
                step = None
            if step is None:
                break
            improvement = (cost - cost_try) / max(cost, 1e-300)
            x, cost = x_try, cost_try
            lam = max(lam / 10.0, 1e-12)
            r, A, g = self._normal(x)
            if improvement < 1e-12 or np.linalg.norm(step) < 1e-12 * (1 + np.linalg.norm(x[free])):
                break
        return x, self._covariance(r, A)

    def _covariance(self, r: np.ndarray, A: np.ndarray) -> np.ndarray:
        n_free = int(self.free.sum())
        dof = max(1, r.size - n_free)
        sigma2 = float(r @ r) / dof
        try:
            cov = np.linalg.inv(A) * sigma2
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(A) * sigma2
        full = np.zeros((self.x0.size, self.x0.size))
        idx = np.flatnonzero(self.free)
        full[np.ix_(idx, idx)] = cov
        return full

    def covariance(self, x: np.ndarray) -> np.ndarray:
        """Covariance of all parameters at ``x`` (sigma^2 (J^T J)^-1 over the free ones)."""
        r, A, _ = self._normal(x)
        return self._covariance(r, A)


def _align_symmetric(board: BoardSpec | None, ld: BoardDetection, rd: BoardDetection
                     ) -> BoardDetection:
    """Flip the right detection of a symmetric chessboard when its order opposes the left's."""
    if board is None or board.kind != "chessboard" or (board.cols + board.rows) % 2 == 1:
        return rd
    if ld.n_corners != rd.n_corners or ld.n_corners < 2:
        return rd
    dl = ld.corners[-1] - ld.corners[0]
    dr = rd.corners[-1] - rd.corners[0]
    return rd.reversed() if float(dl @ dr) < 0 else rd


def calibrate_stereo(left: Sequence[BoardDetection], right: Sequence[BoardDetection],
                     left_names: Sequence[str] | None = None,
                     right_names: Sequence[str] | None = None, *,
                     board: BoardSpec | None = None,
                     options: CalibrationOptions = CalibrationOptions(),
                     method: str = "bundle", fix_intrinsics: bool = False, alpha: float = 0.0,
                     reject_outliers: bool = False, outlier_threshold_px: float | None = None,
                     min_views: int = 3, max_rejection_rounds: int = 3) -> StereoCalibration:
    """Calibrate a stereo rig: each camera alone, then everything jointly, then rectify.

    1. Each camera is calibrated alone (:func:`calibrate_camera`) on every image where it saw
       the board.
    2. The extrinsic is initialised as the average of the per-pair ``right_T_left``.
    3. Joint refinement. ``method="bundle"`` (default): Levenberg-Marquardt over both cameras'
       intrinsics and distortion, the extrinsic and every board pose, using all views (pairs
       where only one camera saw the board still constrain that camera), analytic Jacobians.
       ``method="opencv"``: ``cv2.stereoCalibrate`` with ``CALIB_USE_INTRINSIC_GUESS`` on the
       paired views only. Intrinsics are free unless ``fix_intrinsics``.
    4. Rectification (``cv2.stereoRectify`` with ``alpha``), then the quality checks
       (:func:`stereo_quality`) and per-pair errors; pairs above the outlier threshold are
       flagged and, with ``reject_outliers``, dropped and everything recomputed.

    Args:
        left: detections in the left images.
        right: detections in the right images, pair i being ``(left[i], right[i])``.
        left_names, right_names: image names for the report.
        board: the board (used for the square-length check and symmetric-board ordering).
        options: which intrinsic parameters to estimate.
        method: ``"bundle"`` or ``"opencv"``.
        fix_intrinsics: keep the mono intrinsics and distortion in the joint step.
        alpha: rectification free scaling in [0, 1] (0: only valid pixels, 1: all pixels).
        reject_outliers: drop flagged pairs and recompute.
        outlier_threshold_px: fixed per-pair RMS threshold instead of the robust rule.
        min_views: fewest usable pairs (board in both images) accepted.
        max_rejection_rounds: rejection rounds at most.

    Returns:
        The :class:`StereoCalibration`.

    Raises:
        CalibrationError: different numbers of left and right images, image sizes that differ,
            fewer than ``min_views`` usable pairs, or a solver failure.
        InputError: unknown method, alpha out of range.
    """
    if method not in STEREO_METHODS:
        raise InputError(f"method: expected one of {', '.join(STEREO_METHODS)}, got {method!r}")
    if not (0.0 <= float(alpha) <= 1.0):
        raise InputError(f"alpha: expected a value in [0, 1], got {alpha}")
    if len(left) != len(right):
        raise CalibrationError(f"stereo: {len(left)} left image(s) but {len(right)} right "
                               "image(s); they must pair up one to one")
    lnames = _names(left, left_names, "left")
    rnames = _names(right, right_names, "right")
    right = [_align_symmetric(board, ld, rd) if ld.found and rd.found else rd
             for ld, rd in zip(left, right, strict=True)]
    found_l = [d for d in left if d.found]
    found_r = [d for d in right if d.found]
    if found_l and found_r and tuple(found_l[0].image_size) != tuple(found_r[0].image_size):
        raise CalibrationError(
            f"stereo: left images are {found_l[0].image_size[0]}x{found_l[0].image_size[1]} but "
            f"right images are {found_r[0].image_size[0]}x{found_r[0].image_size[1]}")
    active = [i for i in range(len(left)) if _usable(left[i]) or _usable(right[i])]
    rejected: list[int] = []
    for _round in range(max(0, int(max_rejection_rounds)) + 1):
        result = _stereo_once(left, right, lnames, rnames, active, board, options, method,
                              fix_intrinsics, float(alpha), outlier_threshold_px, min_views,
                              rejected)
        flagged = [i for i, v in zip(range(len(left)), result.views, strict=False)
                   if v.used and v.outlier]
        paired_left = sum(1 for i, v in enumerate(result.views)
                          if v.used and v.paired and i not in flagged)
        if not (reject_outliers and flagged) or _round == max_rejection_rounds \
                or paired_left < min_views:
            return result
        rejected.extend(flagged)
        active = [i for i in active if i not in flagged]
    return result  # pragma: no cover - the loop always returns


def _stereo_once(left: Sequence[BoardDetection], right: Sequence[BoardDetection],
                 lnames: list[str], rnames: list[str], active: list[int],
                 board: BoardSpec | None, options: CalibrationOptions, method: str,
                 fix_intrinsics: bool, alpha: float, thr_abs: float | None, min_views: int,
                 rejected: list[int]) -> StereoCalibration:
    """One round of :func:`calibrate_stereo` over the ``active`` views: each camera alone,
    the extrinsic's start, the joint solve, rectification, per-view results and the
    parameters' standard deviations."""
    n = len(left)
    missing = BoardDetection.missing((0, 0), "", "not used")
    ldets = [left[i] if i in active else missing for i in range(n)]
    rdets = [right[i] if i in active else missing for i in range(n)]
    paired = [i for i in active if _usable(left[i]) and _usable(right[i])
              and _pair_points(left[i], right[i])[0].size >= MIN_POINTS_PER_VIEW]
    if len(paired) < max(1, int(min_views)):
        raise CalibrationError(
            f"stereo: only {len(paired)} pair(s) with the board in both images of {n}, "
            f"need at least {min_views}")
    mono_l = calibrate_camera(ldets, lnames, options=options, min_views=min_views,
                              camera_name="left", max_rejection_rounds=0)
    mono_r = calibrate_camera(rdets, rnames, options=options, min_views=min_views,
                              camera_name="right", max_rejection_rounds=0)
    # a used view has its pose (cam_T_board is None only for views left out)
    pose_l = {v.index: v.cam_T_board for v in mono_l.views
              if v.used and v.cam_T_board is not None}
    pose_r = {v.index: v.cam_T_board for v in mono_r.views
              if v.used and v.cam_T_board is not None}
    rels = [pose_r[i] @ np.linalg.inv(pose_l[i]) for i in paired if i in pose_l and i in pose_r]
    if not rels:
        raise CalibrationError("stereo: no pair has a board pose in both cameras")
    r_T_l = average_transforms(rels)
    size = mono_l.camera.size
    start = _JointStart([np.array(mono_l.camera.K), np.array(mono_r.camera.K)],
                        [np.array(mono_l.camera.dist), np.array(mono_r.camera.dist)],
                        _rvec(r_T_l[:3, :3]), r_T_l[:3, 3].copy(), [], [], [])
    if method == "opencv":
        start = _opencv_start(start, left, right, paired, size, options, fix_intrinsics)
    else:
        start = _bundle_start(start, left, right, active, pose_l, pose_r)
    bundle = _Bundle(start.K, start.dist, start.ext_r, start.ext_t, start.poses, start.obs,
                     options, fix_intrinsics)
    if method == "bundle":
        x, cov = bundle.solve()
    else:
        x = bundle.x0
        cov = bundle.covariance(x)
    res_all, _, per_view = bundle.evaluate(x, jac=False)
    rms = float(np.sqrt(np.sum(res_all ** 2) / (res_all.size / 2)))
    cams = []
    for c, mono in enumerate((mono_l, mono_r)):
        Kc, dc = bundle.camera(x, c)
        cams.append(CameraModel(K=Kc, dist=dc, width=size[0], height=size[1],
                                distortion_model=options.distortion_model, name=mono.camera.name))
    Rx = _as_pose(x[bundle.ext0:bundle.ext0 + 3], np.zeros(3))[:3, :3]
    Tx = x[bundle.ext0 + 3:bundle.ext0 + 6].copy()
    rig = StereoRig(left=cams[0], right=cams[1], R=Rx, T=Tx).rectified(alpha)
    views, thr = _view_results(left, right, lnames, rnames, start.views_in, per_view, paired,
                               rejected, thr_abs)
    std = _standard_deviations(bundle, cov, Tx, options, fix_intrinsics)
    quality = stereo_quality(rig, [(left[i], right[i]) for i in paired], board)
    return StereoCalibration(rig=rig, left=mono_l, right=mono_r, rms_px=rms, views=tuple(views),
                             std=std, quality=quality, method=method, alpha=alpha,
                             outlier_threshold_px=thr,
                             rejected=tuple(lnames[i] for i in rejected), options=options,
                             fix_intrinsics=fix_intrinsics)


@dataclass
class _JointStart:
    """Where the joint solve starts: both cameras' ``K`` and ``dist``, the extrinsic (Rodrigues
    vector, translation), and for each view in it (``views_in``) its board pose (rvec, tvec)
    and its observations ``[(object points, pixels) or None per camera]``; the mono start
    has no views yet."""

    K: list[np.ndarray]
    dist: list[np.ndarray]
    ext_r: np.ndarray
    ext_t: np.ndarray
    views_in: list[int]
    poses: list[tuple[np.ndarray, np.ndarray]]
    obs: list[list[tuple[np.ndarray, np.ndarray] | None]]


def _opencv_start(start: _JointStart, left: Sequence[BoardDetection],
                  right: Sequence[BoardDetection], paired: list[int], size: tuple[int, int],
                  options: CalibrationOptions, fix_intrinsics: bool) -> _JointStart:
    """``method="opencv"``: ``cv2.stereoCalibrate`` from the mono start on the paired views;
    its result is the (unrefined) joint solution."""
    K, dist, ext_r, ext_t = start.K, start.dist, start.ext_r, start.ext_t
    obj, pl, pr = [], [], []
    for i in paired:
        _, o, a, b = _pair_points(left[i], right[i])
        obj.append(o.astype(np.float32))
        pl.append(a.astype(np.float32).reshape(-1, 1, 2))
        pr.append(b.astype(np.float32).reshape(-1, 1, 2))
    flags = options.cv_flags() | (cv2.CALIB_FIX_INTRINSIC if fix_intrinsics
                                  else cv2.CALIB_USE_INTRINSIC_GUESS)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    try:
        out = cv2.stereoCalibrateExtended(
            obj, pl, pr, K[0], dist[0], K[1], dist[1], size, _as_pose(ext_r, ext_t)[:3, :3],
            ext_t.reshape(3, 1), flags=flags | cv2.CALIB_USE_EXTRINSIC_GUESS,
            criteria=criteria)
    except cv2.error as exc:
        raise CalibrationError(f"cv2.stereoCalibrate failed: {str(exc).strip()}") from exc
    _, K0, d0, K1, d1, Rx, Tx = out[:7]
    rvecs, tvecs = out[9], out[10]
    poses = [(np.asarray(rvecs[k]).ravel(), np.asarray(tvecs[k]).ravel())
             for k in range(len(paired))]
    obs: list[list[tuple[np.ndarray, np.ndarray] | None]] = [[(o, a), (o, b)] for o, a, b in
           ((_pair_points(left[i], right[i])[1], _pair_points(left[i], right[i])[2],
             _pair_points(left[i], right[i])[3]) for i in paired)]
    return _JointStart(
        [np.asarray(K0), np.asarray(K1)],
        [np.asarray(d0).ravel()[:options.n_dist], np.asarray(d1).ravel()[:options.n_dist]],
        _rvec(Rx), np.asarray(Tx, dtype=np.float64).ravel(), list(paired), poses, obs)


def _bundle_start(start: _JointStart, left: Sequence[BoardDetection],
                  right: Sequence[BoardDetection], active: list[int],
                  pose_l: dict[int, np.ndarray], pose_r: dict[int, np.ndarray]) -> _JointStart:
    """``method="bundle"``: every active view that either camera saw, its board pose the left
    camera's (or the right's carried over by the start extrinsic)."""
    views_in: list[int] = []
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    obs: list[list[tuple[np.ndarray, np.ndarray] | None]] = []
    r_T_l_now = _as_pose(start.ext_r, start.ext_t)
    for i in active:
        has_l, has_r = i in pose_l, i in pose_r
        if not (has_l or has_r):
            continue
        T = pose_l[i] if has_l else np.linalg.inv(r_T_l_now) @ pose_r[i]
        views_in.append(i)
        poses.append((_rvec(T[:3, :3]), T[:3, 3].copy()))
        obs.append([(left[i].object_points, left[i].corners) if has_l else None,
                    (right[i].object_points, right[i].corners) if has_r else None])
    return _JointStart(start.K, start.dist, start.ext_r, start.ext_t, views_in, poses, obs)


def _view_results(left: Sequence[BoardDetection], right: Sequence[BoardDetection],
                  lnames: list[str], rnames: list[str], views_in: list[int],
                  per_view: list[list[np.ndarray | None]], paired: list[int],
                  rejected: list[int], thr_abs: float | None
                  ) -> tuple[list[StereoViewResult], float]:
    """Every view's result (its residuals and RMS where it was in the solve) and the outlier
    threshold over the RMS of the views in it."""
    n = len(left)
    view_rms = {}
    res_of: dict[int, list[np.ndarray | None]] = {}
    for k, i in enumerate(views_in):
        parts = [p for p in per_view[k] if p is not None]
        allres = np.concatenate(parts)
        view_rms[i] = float(np.sqrt(np.mean(np.sum(allres ** 2, axis=1))))
        res_of[i] = per_view[k]
    thr = outlier_threshold(np.array(list(view_rms.values())), thr_abs)
    views = []
    for i in range(n):
        used = i in view_rms
        vr = view_rms.get(i, float("nan"))
        lr, rr = res_of.get(i, [None, None])
        npts = sum(p.shape[0] for p in (lr, rr) if p is not None)
        views.append(StereoViewResult(
            name=lnames[i], right_name=rnames[i], left_found=bool(left[i].found),
            right_found=bool(right[i].found), n_points=npts, rms_px=vr, used=used,
            paired=i in paired, outlier=(used and vr > thr) or i in rejected,
            left_residuals=lr, right_residuals=rr))
    return views, thr


def _standard_deviations(bundle: _Bundle, cov: np.ndarray, Tx: np.ndarray,
                         options: CalibrationOptions, fix_intrinsics: bool) -> dict[str, float]:
    """Standard deviations of each camera's parameters, the extrinsic and the baseline."""
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    names_c = list(_INTRINSIC_NAMES) + list(_DIST_NAMES[:options.n_dist])
    std: dict[str, float] = {}
    for c, side in enumerate(("left", "right")):
        for k, nm in enumerate(names_c):
            std[f"{side}.{nm}"] = float(sd[c * bundle.nc + k])
        if options.fix_aspect and not fix_intrinsics:
            std[f"{side}.fy"] = std[f"{side}.fx"] / bundle.aspect[c]
    e0 = bundle.ext0
    for k, nm in enumerate(("R.rx", "R.ry", "R.rz", "T.x", "T.y", "T.z")):
        std[nm] = float(sd[e0 + k])
    covT = cov[e0 + 3:e0 + 6, e0 + 3:e0 + 6]
    g = Tx / np.linalg.norm(Tx)
    std["baseline"] = float(np.sqrt(max(0.0, g @ covT @ g)))
    return std
