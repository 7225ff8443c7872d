"""From images to hand-eye samples: board detection and PnP.

Board detection is :func:`eye_in_hand.core.calibration.detect_board`; the board pose in the
(left) camera frame comes from ``cv2.solvePnP`` (iterative Levenberg-Marquardt from OpenCV's
planar homography start) on the detected corners with the camera's distortion.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.calibration import detect_board
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.errors import HandEyeError

from .samples import CameraView, CornerObservation, HandEyeSample

__all__ = ["Observation", "rig_views", "observe_sample", "board_pose_pnp"]


@dataclass(frozen=True)
class Observation:
    """What one sample's images gave.

    Attributes:
        sample: the hand-eye sample, or None when the board was not found in the reference
            camera.
        reason: why the sample is unusable ('' when usable).
        notes: non-fatal remarks (e.g. board not found in the right image).
    """

    sample: HandEyeSample | None
    reason: str = ""
    notes: tuple[str, ...] = ()


def rig_views(camera: CameraModel | None = None, rig: StereoRig | None = None) -> list[CameraView]:
    """The :class:`CameraView` list of a mono camera (``image``) or a stereo rig (``left``,
    ``right``; the hand-eye camera frame is the left optical frame).

    Raises:
        HandEyeError: neither or both given.
    """
    if (camera is None) == (rig is None):
        raise HandEyeError("give exactly one of a mono camera or a stereo rig")
    if camera is not None:
        return [CameraView("image", camera)]
    assert rig is not None
    return [CameraView("left", rig.left), CameraView("right", rig.right, rig.right_T_left)]


def board_pose_pnp(model: Any, object_points: np.ndarray,
                   image_points: np.ndarray) -> tuple[np.ndarray, float]:
    """Board pose in the camera frame from corners (``cv2.solvePnP``, iterative).

    Args:
        model: camera intrinsics with ``K`` (3, 3) and ``dist``.
        object_points: shape (N, 3), board frame.
        image_points: shape (N, 2), distorted pixels.

    Returns:
        ``(cam_T_board (4, 4), rms reprojection error in px)``.

    Raises:
        HandEyeError: PnP failed or put the board behind the camera.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 1, 2)
    K = np.asarray(model.K, dtype=np.float64)
    dist = np.asarray(model.dist, dtype=np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or not np.all(np.isfinite(tvec)):
        raise HandEyeError("solvePnP failed")
    if float(tvec.ravel()[2]) <= 0:
        raise HandEyeError("solvePnP put the board behind the camera")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rvec.ravel()).as_matrix()
    T[:3, 3] = tvec.ravel()
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2, axis=1))))
    return T, rms


def observe_sample(name: str, images: Mapping[str, np.ndarray], base_T_ee: np.ndarray,
                   board: Any, views: list[CameraView], *,
                   max_pnp_rms_px: float = 5.0) -> Observation:
    """Detect the board in a sample's images and build its :class:`HandEyeSample`.

    The first view is the reference camera (mono, or left): the board must be found there, its
    PnP pose is ``cam_T_board``. Other views (right) add corner observations for the
    refinement when the board is found in them too.

    Args:
        name: sample name.
        images: images by view name, (H, W[, 3]) uint8.
        base_T_ee: robot pose, shape (4, 4).
        board: :class:`eye_in_hand.core.calibration.BoardSpec`.
        views: from :func:`rig_views`.
        max_pnp_rms_px: a PnP fit worse than this marks the detection as unusable.

    Returns:
        The observation (``sample`` is None with a ``reason`` when unusable).
    """
    notes: list[str] = []
    observations: list[CornerObservation] = []
    cam_T_board = None
    for k, view in enumerate(views):
        if view.name not in images:
            raise HandEyeError(f"sample {name!r}: no {view.name!r} image")
        det = detect_board(images[view.name], board)
        if not det.found:
            if k == 0:
                return Observation(None, f"board not found in the {view.name} image "
                                         f"({det.reason})")
            notes.append(f"sample {name!r}: board not found in the {view.name} image "
                         f"({det.reason}); using the {views[0].name} image only")
            continue
        if k == 0:
            try:
                cam_T_board, rms = board_pose_pnp(view.model, det.object_points, det.corners)
            except HandEyeError as exc:
                return Observation(None, f"{view.name} image: {exc}")
            if rms > max_pnp_rms_px:
                return Observation(None, f"{view.name} image: PnP residual {rms:.2f} px > "
                                         f"{max_pnp_rms_px:g} px (wrong intrinsics or "
                                         "mis-detected corners)")
        corners = det.corners
        if k > 0 and det.n_corners == board.n_corners and board.kind == "chessboard":
            # A chessboard seen from another camera may come back in 180-degree-rotated order:
            # keep the order that agrees with the reference camera's pose.
            assert cam_T_board is not None
            T = view.view_T_cam @ cam_T_board
            pred = view.model.project(det.object_points @ T[:3, :3].T + T[:3, 3])
            flipped = det.reversed().corners
            if np.nanmean(np.linalg.norm(pred - flipped, axis=1)) < \
                    np.nanmean(np.linalg.norm(pred - corners, axis=1)):
                corners = flipped
        observations.append(CornerObservation(view.name, det.object_points, corners))
    assert cam_T_board is not None
    return Observation(HandEyeSample(name, np.asarray(base_T_ee, dtype=np.float64), cam_T_board,
                                     tuple(observations)), "", tuple(notes))
