"""The calibration board drawn on a camera image: corners, axes and a line of text.

The ``hand_eye`` node's ``~/debug_image`` in calibration mode (what a person watches while
moving the robot between captures).
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from eye_in_hand.core.calibration import detect_board
from eye_in_hand.core.handeye.observe import board_pose_pnp

__all__ = ["board_debug_image"]


def board_debug_image(image: np.ndarray, board: Any, model: Any, n_samples: int) -> np.ndarray:
    """A copy of ``image`` (BGR) with the board found in it drawn.

    Args:
        image: the camera image, BGR uint8.
        board: :class:`eye_in_hand.core.calibration.BoardSpec`.
        model: the camera's :class:`eye_in_hand.core.camera.CameraModel` (the axes' PnP).
        n_samples: the samples taken so far (written on the image).

    Returns:
        The image with the corners and the board's axes (three squares long) drawn and, in
        green, ``board: N corners, PnP x px | n samples``, or in red why the board was not
        found.
    """
    det = detect_board(image, board)
    out = np.ascontiguousarray(image.copy())
    if det.found:
        cv2.drawChessboardCorners(out, (det.corners.shape[0], 1),
                                  det.corners.reshape(-1, 1, 2).astype(np.float32), True)
        T, rms = board_pose_pnp(model, det.object_points, det.corners)
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        cv2.drawFrameAxes(out, np.asarray(model.K, np.float64), np.asarray(model.dist, np.float64),
                          rvec, T[:3, 3], float(board.square) * 3, 2)
        text = f"board: {det.n_corners} corners, PnP {rms:.2f} px"
    else:
        text = f"board not found ({det.reason})"
    cv2.putText(out, f"{text} | {n_samples} samples", (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.7,
                (0, 255, 0) if det.found else (0, 0, 255), 2, cv2.LINE_AA)
    return out
