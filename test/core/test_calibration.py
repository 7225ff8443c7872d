"""Mono and stereo calibration on synthetic corners with known ground truth, and error cases."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from eye_in_hand.core.calibration import (
    BoardDetection,
    BoardSpec,
    CalibrationOptions,
    calibrate_camera,
    calibrate_stereo,
    coverage,
    detect_board,
    outlier_threshold,
)
from eye_in_hand.errors import CalibrationError, InputError

BOARD = BoardSpec.parse("chessboard:9x6:0.025")
SIZE = (1280, 720)
K_L = np.array([[910.0, 0, 641.5], [0, 908.0, 358.2], [0, 0, 1]])
K_R = np.array([[905.0, 0, 633.0], [0, 904.0, 362.5], [0, 0, 1]])
D_L = np.array([-0.12, 0.08, 0.0007, -0.0004, -0.02])
D_R = np.array([-0.11, 0.07, -0.0003, 0.0005, -0.015])


def _right_T_left() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    T[:3, 3] = [-0.06, 0.0005, 0.001]
    return T


def _poses(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Board poses in the left camera frame with the whole board in both images."""
    center = np.array([4 * BOARD.square, 2.5 * BOARD.square, 0.0])
    poses: list[np.ndarray] = []
    rT = _right_T_left()
    while len(poses) < n:
        z = rng.uniform(0.25, 0.55)
        rvec = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(-0.3, 0.3)])
        R = cv2.Rodrigues(rvec)[0]
        u, v = rng.uniform(0.15, 0.85) * SIZE[0], rng.uniform(0.15, 0.85) * SIZE[1]
        off = z * np.linalg.solve(K_L, np.array([u, v, 1.0]))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = off - R @ center
        ok = True
        for K, d, X in ((K_L, D_L, T), (K_R, D_R, rT @ T)):
            pts = _project(K, d, X)
            if (pts.min() < 10 or pts[:, 0].max() > SIZE[0] - 10
                    or pts[:, 1].max() > SIZE[1] - 10):
                ok = False
        if ok:
            poses.append(T)
    return poses


def _project(K: np.ndarray, d: np.ndarray, cam_T_board: np.ndarray) -> np.ndarray:
    rvec = cv2.Rodrigues(cam_T_board[:3, :3])[0]
    pts, _ = cv2.projectPoints(BOARD.object_points(), rvec, cam_T_board[:3, 3], K, d)
    return pts.reshape(-1, 2)


def _det(px: np.ndarray) -> BoardDetection:
    return BoardDetection(True, px, BOARD.object_points(), np.arange(BOARD.n_corners), SIZE,
                          "synthetic")


def _views(seed: int, n: int, sigma: float = 0.2):
    rng = np.random.default_rng(seed)
    poses = _poses(rng, n)
    rT = _right_T_left()
    left = [_det(_project(K_L, D_L, T) + rng.normal(0, sigma, (BOARD.n_corners, 2)))
            for T in poses]
    right = [_det(_project(K_R, D_R, rT @ T) + rng.normal(0, sigma, (BOARD.n_corners, 2)))
             for T in poses]
    return left, right


def test_mono_recovers_intrinsics() -> None:
    left, _ = _views(seed=3, n=24)
    cal = calibrate_camera(left, [f"v{i}" for i in range(24)], camera_name="left")
    cam = cal.camera
    # focal length: measured |f/f_true - 1| max 0.0021 over seeds 0-31 (this seed 0.0006); 1.5x
    assert abs(cam.fx / K_L[0, 0] - 1) < 0.003 and abs(cam.fy / K_L[1, 1] - 1) < 0.003
    # 0.2 px per axis: the 2-D RMS is 0.2 * sqrt(2) less the fitted degrees of freedom
    assert 0.25 < cal.rms_px < 0.29
    # the reported standard deviations are small and consistent with the actual errors
    for name, value, true in (("fx", cam.fx, K_L[0, 0]), ("fy", cam.fy, K_L[1, 1]),
                              ("cx", cam.cx, K_L[0, 2]), ("cy", cam.cy, K_L[1, 2])):
        assert 0 < cal.std[name] < 1.5, name
        assert abs(value - true) < 4 * cal.std[name], name
    assert all(v.used and not v.outlier for v in cal.views)
    assert 0.3 < cal.coverage <= 1.0
    report = cal.to_dict()
    assert report["camera"]["rms_px"] == pytest.approx(cal.rms_px)
    assert len(report["views"]) == 24 and np.array(report["camera"]["K"]).shape == (3, 3)


def test_mono_options_are_honoured() -> None:
    left, _ = _views(seed=4, n=12)
    opts = CalibrationOptions(zero_tangent=True, fix_k3=True, fix_aspect=True)
    cam = calibrate_camera(left, options=opts).camera
    assert cam.dist[2] == 0 and cam.dist[3] == 0 and cam.dist[4] == 0
    assert cam.fx == pytest.approx(cam.fy)
    rational = calibrate_camera(left, options=CalibrationOptions(rational=True)).camera
    assert rational.distortion_model == "rational_polynomial" and rational.dist.shape == (8,)


def test_outlier_view_is_flagged_and_rejected() -> None:
    left, _ = _views(seed=5, n=12)
    rng = np.random.default_rng(55)
    bad = left[4]
    left[4] = _det(bad.corners + rng.normal(0, 2.5, bad.corners.shape))
    names = [f"img{i}.png" for i in range(12)]
    flagged = calibrate_camera(left, names)
    assert [v.name for v in flagged.views if v.outlier] == ["img4.png"]
    assert flagged.rms_px > 0.5
    cleaned = calibrate_camera(left, names, reject_outliers=True)
    assert cleaned.rejected == ("img4.png",)
    assert cleaned.rms_px < 0.29
    view4 = cleaned.views[4]
    assert not view4.used and view4.outlier and view4.rms_px > 2.0
    assert outlier_threshold(np.array([0.2, 0.21, 0.19, 0.2])) == pytest.approx(0.4)
    assert outlier_threshold(np.array([0.2, 0.3]), 1.5) == 1.5


def test_stereo_bundle_recovers_rig() -> None:
    left, right = _views(seed=6, n=20)
    cal = calibrate_stereo(left, right, board=BOARD)
    rig = cal.rig
    true = _right_T_left()
    # measured over seeds 0-31 (n=20 views, 0.2 px noise): baseline error max 0.051 mm (this
    # seed 0.041), T per axis max 0.26 mm (this seed), |f/f_true - 1| max 0.0013, board square
    # max 0.060 mm; tolerances 1.5x those
    assert abs(rig.baseline - np.linalg.norm(true[:3, 3])) < 0.00008
    assert np.abs(rig.T - true[:3, 3]).max() < 0.0004
    angle = np.linalg.norm(cv2.Rodrigues(rig.R @ true[:3, :3].T)[0])
    assert angle < 4 * np.linalg.norm([cal.std["R.rx"], cal.std["R.ry"], cal.std["R.rz"]])
    for cam, K in ((rig.left, K_L), (rig.right, K_R)):
        assert abs(cam.fx / K[0, 0] - 1) < 0.002 and abs(cam.fy / K[1, 1] - 1) < 0.002
    assert 0.25 < cal.rms_px < 0.29
    q = cal.quality
    # noise floor: |dy| of two independent 0.2 px errors has mean 0.2*sqrt(2)*sqrt(2/pi) = 0.226
    floor = 0.2 * np.sqrt(2) * np.sqrt(2 / np.pi)
    assert q.rectified_dy_mean_px < 1.1 * floor and q.epipolar_error_px < 1.1 * floor
    assert abs(q.square_measured_mean - BOARD.square) < 0.00009
    assert 0 < cal.std["baseline"] < 0.0005
    # reported uncertainty covers the actual baseline error
    assert abs(rig.baseline - np.linalg.norm(true[:3, 3])) < 5 * cal.std["baseline"]
    report = cal.to_dict()
    for key in ("rms_px", "R", "T", "baseline", "epipolar_error_px", "rectified_dy_mean_px"):
        assert key in report["stereo"]
    assert set(report["stereo"]["square_measured"]) >= {"mean", "std"}
    assert report["views"][0].keys() >= {"file", "rms_px", "used"}
    assert rig.is_rectified and rig.left.P[0, 3] == 0 and rig.right.P[0, 3] < 0


def test_stereo_bundle_uses_one_sided_views_and_matches_opencv() -> None:
    left, right = _views(seed=7, n=14)
    for i in (0, 1, 2):  # the right camera missed these boards
        right[i] = BoardDetection.missing(SIZE, "classic", "not found")
    bundle = calibrate_stereo(left, right, board=BOARD, method="bundle")
    opencv = calibrate_stereo(left, right, board=BOARD, method="opencv")
    assert [v.paired for v in bundle.views[:4]] == [False, False, False, True]
    assert bundle.views[0].used and not opencv.views[0].used
    true_b = np.linalg.norm(_right_T_left()[:3, 3])
    # baseline error measured over seeds 0-31 (n=14, three one-sided): bundle max 0.104 mm,
    # OpenCV max 0.102 mm (this seed 0.059 / 0.070 mm); 1.5x margin
    assert abs(bundle.rig.baseline - true_b) < 0.00016
    assert abs(opencv.rig.baseline - true_b) < 0.00016


def test_stereo_fix_intrinsics_keeps_mono_results() -> None:
    left, right = _views(seed=8, n=10)
    cal = calibrate_stereo(left, right, board=BOARD, fix_intrinsics=True, alpha=1.0)
    np.testing.assert_allclose(cal.rig.left.K, cal.left.camera.K)
    np.testing.assert_allclose(cal.rig.right.dist, cal.right.camera.dist)
    assert cal.std["left.fx"] == 0.0 and cal.std["T.x"] > 0


def test_errors() -> None:
    left, right = _views(seed=9, n=4)
    with pytest.raises(CalibrationError, match="3 left image.*4 right"):
        calibrate_stereo(left[:3], right)
    with pytest.raises(CalibrationError, match="only 2 usable"):
        calibrate_camera(left[:2] + [BoardDetection.missing(SIZE, "classic", "x")])
    odd = BoardDetection(True, right[0].corners, right[0].object_points, right[0].ids,
                         (640, 480), "synthetic")
    with pytest.raises(CalibrationError, match="differ in size"):
        calibrate_camera(left[:3] + [odd], ["a", "b", "c", "d"])
    with pytest.raises(CalibrationError, match="left images are 1280x720 but right"):
        calibrate_stereo(left, [odd] * 4)
    with pytest.raises(CalibrationError, match="only 1 pair"):
        calibrate_stereo(left, [right[0]] + [BoardDetection.missing(SIZE, "sb", "x")] * 3)
    with pytest.raises(InputError, match="method"):
        calibrate_stereo(left, right, method="magic")
    with pytest.raises(InputError, match="alpha"):
        calibrate_stereo(left, right, alpha=2.0)


def test_coverage_map() -> None:
    frac, counts = coverage([np.array([[0, 0], [639, 0], [639, 479], [0, 479]], float)],
                            (640, 480))
    assert frac == pytest.approx(1.0, abs=0.01) and counts.max() == 1
    frac, _ = coverage([np.array([[0, 0], [320, 0], [320, 240], [0, 240]], float)] * 2,
                       (640, 480))
    assert frac == pytest.approx(0.25, abs=0.02)


def _charuco_views(board: BoardSpec, K: np.ndarray, n: int, seed: int,
                   size: tuple[int, int] = (800, 600)) -> list[np.ndarray]:
    """Pinhole (no distortion) renders of a ChArUco board by homography warping."""
    ppm = 2000.0  # board image pixels per metre
    w_px = int(round((board.cols + 1) * board.square * ppm))
    h_px = int(round((board.rows + 1) * board.square * ppm))
    art = board.charuco_board().generateImage((w_px, h_px), marginSize=0)
    art = cv2.copyMakeBorder(art, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=255)
    # board-art pixel -> board frame (origin at the first inner corner)
    A = np.array([[1 / ppm, 0, -board.square - 40 / ppm], [0, 1 / ppm, -board.square - 40 / ppm],
                  [0, 0, 1]])
    rng = np.random.default_rng(seed)
    center = np.array([(board.cols - 1) * board.square / 2,
                       (board.rows - 1) * board.square / 2, 0])
    images = []
    for k in range(n):
        R = cv2.Rodrigues(np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6),
                                    rng.uniform(-0.4, 0.4)]))[0]
        shift = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), 0.0])
        if k == n - 1:
            shift[0] = 0.22  # board partly out of the image: a subset of the corners
        t = np.array([0.0, 0.0, rng.uniform(0.45, 0.6)]) + shift - R @ center
        H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ A
        images.append(cv2.warpPerspective(art, H, size, flags=cv2.INTER_AREA,
                                          borderValue=100))
    return images


def test_charuco_calibration_with_partial_views() -> None:
    board = BoardSpec.parse("charuco:8x6:0.03:0.022:DICT_4X4_50")
    K = np.array([[700.0, 0, 401.0], [0, 700.0, 298.0], [0, 0, 1]])
    images = _charuco_views(board, K, 12, seed=21)
    dets = [detect_board(img, board) for img in images]
    assert all(d.found for d in dets)
    assert dets[-1].n_corners < board.n_corners  # the partial view
    cal = calibrate_camera(dets, options=CalibrationOptions(fix_k3=True))
    assert abs(cal.camera.fx / 700.0 - 1) < 0.005 and abs(cal.camera.cx - 401.0) < 2.0
    assert cal.rms_px < 0.3 and len(cal.used_views) == 12


def test_stereo_rejects_outlier_pair() -> None:
    left, right = _views(seed=10, n=12)
    rng = np.random.default_rng(100)
    right[5] = _det(right[5].corners + rng.normal(0, 2.0, right[5].corners.shape))
    names = [f"l{i}" for i in range(12)]
    flagged = calibrate_stereo(left, right, names, board=BOARD)
    assert [v.name for v in flagged.views if v.outlier] == ["l5"]
    cleaned = calibrate_stereo(left, right, names, board=BOARD, reject_outliers=True)
    assert cleaned.rejected == ("l5",) and not cleaned.views[5].used
    assert cleaned.rms_px < 0.29 < flagged.rms_px
    assert abs(cleaned.rig.baseline - np.linalg.norm(_right_T_left()[:3, 3])) < 0.0003
