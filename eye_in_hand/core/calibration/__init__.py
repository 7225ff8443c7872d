"""Calibration boards, board detection, and camera / stereo calibration (Zhang's method).

Board specification strings (:meth:`BoardSpec.parse`)::

    chessboard:COLSxROWS:SQUARE
        COLS x ROWS inner corners (the corners where four squares meet), SQUARE the side of one
        square in metres (results come out in the same unit; a side above 1 is refused: 25
        would be 25 m, so the message names the spec in metres).
        Example: ``chessboard:9x6:0.025`` (a 10 x 7 squares board, 25 mm squares).

    charuco:SQUARESXxSQUARESY:SQUARE:MARKER[:DICT][:legacy]
        A ChArUco board of SQUARESX x SQUARESY *squares* (so SQUARESX-1 x SQUARESY-1 inner
        corners), square side SQUARE and ArUco marker side MARKER (same unit, MARKER < SQUARE),
        markers from the OpenCV predefined dictionary DICT (default ``DICT_5X5_100``; the
        ``DICT_`` prefix is optional). ``legacy`` selects OpenCV's pre-4.6 layout for boards
        with an even number of rows. Example: ``charuco:7x5:0.04:0.03:DICT_4X4_50``.

Board frame: origin at the first inner corner (OpenCV's corner 0), x along the COLS direction,
y along the ROWS direction, z = x cross y (the board plane is z = 0). Inner corners are numbered
row by row, ``index = row * cols + col``, which is OpenCV's order for both board types (for
ChArUco it is also the corner id).

Detection (:func:`detect_board`) always returns a :class:`BoardDetection`; when no board is found
its ``found`` is False and ``reason`` says why, so callers can list skipped images.

Calibration: :func:`calibrate_camera` (``cv2.calibrateCameraExtended`` with per-view errors,
outlier flags and rejection, coverage, parameter standard deviations) and
:func:`calibrate_stereo` (each camera alone, then a joint bundle adjustment over both cameras'
intrinsics and distortion, the extrinsic and every board pose, then rectification and the
checks of :func:`stereo_quality`).

The package: :mod:`.board` (specification, detections, renderer), :mod:`.detection`,
:mod:`.mono`, :mod:`.stereo` and :mod:`.quality`; every public name is re-exported here.
"""
from __future__ import annotations

from eye_in_hand.core.calibration.board import BoardDetection, BoardSpec, render_board
from eye_in_hand.core.calibration.detection import DETECTORS, detect_board
from eye_in_hand.core.calibration.mono import (
    CalibrationOptions,
    CameraCalibration,
    ViewResult,
    calibrate_camera,
)
from eye_in_hand.core.calibration.quality import (
    StereoQuality,
    coverage,
    outlier_threshold,
    stereo_quality,
)
from eye_in_hand.core.calibration.stereo import (
    STEREO_METHODS,
    StereoCalibration,
    StereoViewResult,
    calibrate_stereo,
)

__all__ = [
    "BoardSpec",
    "BoardDetection",
    "DETECTORS",
    "detect_board",
    "render_board",
    "CalibrationOptions",
    "ViewResult",
    "CameraCalibration",
    "StereoViewResult",
    "StereoQuality",
    "StereoCalibration",
    "STEREO_METHODS",
    "calibrate_camera",
    "calibrate_stereo",
    "stereo_quality",
    "outlier_threshold",
    "coverage",
]
