"""The systematic robot error model (refined_systematic) and the k-fold held-out figures, on
synthetic poses with a known pose-dependent error and on the real Franka capture."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from eye_in_hand.core.calibration import BoardSpec, detect_board
from eye_in_hand.core.camera import CameraModel
from eye_in_hand.core.handeye import (
    CLOSED_FORM_METHODS,
    CameraView,
    CornerObservation,
    HandEyeSample,
    calibrate_hand_eye,
)
from eye_in_hand.core.handeye.kfold import (
    classic_fit,
    fold_indices,
    kfold_held_out,
    predict_view,
    rms,
)
from eye_in_hand.core.handeye.observe import board_pose_pnp
from eye_in_hand.core.handeye.systematic import fit_systematic, refine_systematic
from eye_in_hand.core.transforms import from_rotvec, invert, transform_distance
from eye_in_hand.errors import HandEyeError

DATA = Path(__file__).resolve().parents[1] / "data" / "franka_eye_in_hand"

X_TRUE = from_rotvec(np.array([0.02, -0.03, 1.6]), np.array([0.048, 0.008, -0.038]))
Y_TRUE = from_rotvec(np.array([np.pi, 0.0, 0.1]), np.array([0.5, 0.0, -0.05]))


def _poses(n: int, rng: np.random.Generator) -> np.ndarray:
    """Reported flange poses looking down at the board from 0.3-0.4 m, tilted up to 30 deg."""
    out = []
    for _ in range(n):
        tilt = Rotation.from_rotvec(rng.uniform(-0.5, 0.5, 3) * np.array([1, 1, 0.8]))
        R = tilt.as_matrix() @ Rotation.from_rotvec([np.pi, 0, 0]).as_matrix()
        t = np.array([0.45, 0.0, 0.3]) + rng.uniform(-0.08, 0.08, 3)
        out.append(from_rotvec(Rotation.from_matrix(R).as_rotvec(), t))
    return np.stack(out)


def _problem(n: int, seed: int, A_r: np.ndarray, A_t: np.ndarray, noise_mm: float = 0.1,
             noise_deg: float = 0.01):
    """Samples whose true flange pose is the reported one times the model's correction (the
    correction taken relative to the reported poses' mean orientation) and a little noise."""
    rng = np.random.default_rng(seed)
    rep = _poses(n, rng)
    R_ref = Rotation.from_matrix(rep[:, :3, :3]).mean().as_matrix()
    samples = []
    for k, G in enumerate(rep):
        r = Rotation.from_matrix(R_ref.T @ G[:3, :3]).as_rotvec()
        true = G @ from_rotvec(A_r @ r, A_t @ r)
        true = true @ from_rotvec(rng.normal(scale=np.radians(noise_deg), size=3),
                                  rng.normal(scale=noise_mm / 1000.0, size=3))
        C = invert(X_TRUE) @ invert(true) @ Y_TRUE
        samples.append(HandEyeSample(f"{k:02d}", G, C))
    return samples


def _arrays(samples):
    return (np.stack([s.base_T_ee for s in samples]), np.stack([s.cam_T_board for s in samples]))


A_R = np.array([[0.02, -0.015, 0.0], [0.015, -0.01, -0.008], [-0.005, 0.002, 0.002]])
A_T = np.array([[0.004, 0.002, 0.0], [-0.003, 0.001, 0.002], [0.0, 0.003, -0.002]])


def test_systematic_error_is_recovered_and_beats_the_closed_form() -> None:
    samples = _problem(14, 3, A_R, A_T)
    bte, ctb = _arrays(samples)
    X0, Y0 = classic_fit(CLOSED_FORM_METHODS["tsai"], samples, "eye_in_hand")
    fit = refine_systematic(X0, Y0, bte, ctb, "eye_in_hand")
    assert fit.level > 0.0                       # chosen by held-out prediction
    assert fit.level_scores[fit.level] < fit.level_scores[0.0]
    mm_sys, rad_sys = transform_distance(fit.X, X_TRUE)
    mm_cf, rad_cf = transform_distance(X0, X_TRUE)
    assert 1000 * mm_sys < 0.5 * 1000 * mm_cf
    assert rad_sys < 0.5 * rad_cf
    assert np.max(np.abs(fit.A_r - A_R)) < 0.004
    # the model's correction brings the reported poses to the true ones
    true = np.stack([Y_TRUE @ invert(c) @ invert(X_TRUE) for c in ctb])
    err_rep = np.degrees(np.linalg.norm(Rotation.from_matrix(
        np.einsum("nji,njk->nik", bte[:, :3, :3], true[:, :3, :3])).as_rotvec(), axis=1))
    cor = fit.correct(bte)
    err_cor = np.degrees(np.linalg.norm(Rotation.from_matrix(
        np.einsum("nji,njk->nik", cor[:, :3, :3], true[:, :3, :3])).as_rotvec(), axis=1))
    assert np.sqrt(np.mean(err_cor ** 2)) < 0.2 * np.sqrt(np.mean(err_rep ** 2))


def test_without_systematic_error_the_model_stays_small() -> None:
    samples = _problem(14, 4, np.zeros((3, 3)), np.zeros((3, 3)), noise_mm=0.3, noise_deg=0.03)
    bte, ctb = _arrays(samples)
    X0, Y0 = classic_fit(CLOSED_FORM_METHODS["tsai"], samples, "eye_in_hand")
    fit = refine_systematic(X0, Y0, bte, ctb, "eye_in_hand")
    assert np.max(np.abs(fit.A_r)) < 0.01
    mm, _ = transform_distance(fit.X, X_TRUE)
    assert 1000 * mm < 1.0
    # its covariance is of the size of the actual error (not 100x off either way)
    sd = np.sqrt(np.trace(fit.covariance[:3, :3]))
    assert 0.05 < mm / sd < 5.0


def test_the_systematic_model_is_written_only_where_it_predicts_better() -> None:
    """The default robot model computes refined_systematic and writes it where the poses
    carry a systematic error (held-out prediction significantly better than refined's);
    without one refined stays written; per_pose does not compute it."""
    samples = _problem(12, 5, A_R, A_T)
    default = calibrate_hand_eye(samples, robot_model="per_pose")
    assert "refined_systematic" not in default.methods
    assert np.allclose(default.correct_robot_pose(samples[0].base_T_ee), samples[0].base_T_ee)
    res = calibrate_hand_eye(samples)
    assert res.robot_model == "systematic"
    assert res.selected == "refined_systematic", res.selection_reason
    assert "significantly below refined" in res.selection_reason
    assert res.systematic is not None and res.systematic.level > 0
    # its X holds with corrected poses, the others' with the reported ones: they differ by the
    # mean systematic error by design, which is no disagreement to warn of
    assert not [w for w in res.warnings if "disagree" in w], res.warnings
    # no systematic error: computed, scored, not written (refined is the reference)
    flat = calibrate_hand_eye(_problem(12, 6, np.zeros((3, 3)), np.zeros((3, 3)),
                                       noise_mm=0.3, noise_deg=0.03))
    assert "refined_systematic" in flat.methods and flat.selected != "refined_systematic", \
        flat.selection_reason
    assert flat.pose_correction is None
    report = res.to_report()
    assert report["robot_model"] == "systematic" and report["systematic"]["level"] > 0
    b = report["error_budget"]
    assert b["robot_systematic_mm"] > 0.5 and b["largest"] in ("camera_mm", "robot_mm",
                                                               "estimate_mm")
    assert default.to_report()["error_budget"]["robot_systematic_mm"] is None
    for bud in (b, default.error_budget):          # the parts add up to the held-out error
        parts = sum(bud[k] ** 2 for k in ("robot_mm", "estimate_mm"))  # no corners: no camera
        assert bud["camera_mm"] is None
        # parts add to the held-out total, unless the in-sample scatter alone exceeds it
        assert bud["estimate_mm"] == 0.0 or parts == pytest.approx(bud["held_out_mm"] ** 2,
                                                                   rel=1e-3)
        assert bud["robot_mm"] > 0.0
    cor = res.correct_robot_pose(samples[0].base_T_ee)
    assert not np.allclose(cor, samples[0].base_T_ee)
    with pytest.raises(HandEyeError, match="robot model"):
        calibrate_hand_eye(samples, robot_model="kinematic")


def test_fold_indices_and_bad_k() -> None:
    folds = fold_indices(12, 6)
    assert sorted(np.concatenate(folds).tolist()) == list(range(12))
    assert all(len(f) == 2 for f in folds)
    with pytest.raises(HandEyeError, match="k-fold"):
        fold_indices(5, 6)


# -- the real Franka capture ------------------------------------------------------------------

def _franka():
    b = yaml.safe_load((DATA / "board.yaml").read_text())
    board = BoardSpec("charuco", b["squares_x"] - 1, b["squares_y"] - 1, b["square_size_m"],
                      b["marker_size_m"], b["dictionary"])
    intr = yaml.safe_load((DATA / "intrinsics.yaml").read_text())
    cam = CameraModel(K=np.array(intr["K"]), dist=np.array(intr["dist"]), width=1280,
                      height=720, name="image")
    offsets = yaml.safe_load((DATA / "crops.yaml").read_text())["offsets_xy"]
    poses = yaml.safe_load((DATA / "poses.yaml").read_text())["poses"]
    samples = []
    for i, (off, pose) in enumerate(zip(offsets, poses, strict=True)):
        img = cv2.imread(str(DATA / "images" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE)
        det = detect_board(img, board)
        assert det.found and det.n_corners >= 20, f"image {i}: {det.reason}"
        px = det.corners + np.asarray(off, dtype=np.float64)
        C, pnp_rms = board_pose_pnp(cam, det.object_points, px)
        assert pnp_rms < 0.5, f"image {i}: PnP RMS {pnp_rms:.3f} px"
        samples.append(HandEyeSample(f"{i:03d}", np.array(pose), C,
                                     (CornerObservation("image", det.object_points, px),)))
    return samples, [CameraView("image", cam)]


@pytest.fixture(scope="module")
def franka():
    return _franka()


def test_real_capture_systematic_model_predicts_held_out_views_better(franka) -> None:
    """3-fold on the real capture at a fixed prior level: the systematic model predicts the
    held-out views (their poses corrected by it) better than every classic closed form, in
    the base frame and in the image (6-fold figures: benchmarks/bench_handeye_real.py)."""
    samples, views = franka

    def fit(train):
        sols = {k: classic_fit(CLOSED_FORM_METHODS[k], train, "eye_in_hand")
                for k in ("tsai", "park", "horaud", "daniilidis", "andreff")}
        bte, ctb = _arrays(train)
        X0, Y0 = sols["tsai"]
        f = fit_systematic(X0, Y0, bte, ctb, "eye_in_hand", 0.01)
        sols["systematic"] = (f.X, f.Y, f.correct)
        sols["systematic_raw_poses"] = (f.X, f.Y)
        return sols, {}

    folds = kfold_held_out(samples, fit, k=3, cameras=views)
    mm = {m: rms([v.mm for f in folds for v in f.errors[m]]) for m in folds[0].errors}
    px = {m: rms([v.px for f in folds for v in f.errors[m]]) for m in folds[0].errors}
    classic = ("tsai", "park", "horaud", "daniilidis", "andreff")
    best_mm = min(mm[m] for m in classic)
    best_px = min(px[m] for m in classic)
    assert mm["systematic"] < 0.9 * best_mm, mm
    assert px["systematic"] < 0.9 * best_px, px
    # its X is meant for the corrected poses: with the reported ones the image is worse
    assert px["systematic_raw_poses"] > px["systematic"]


def test_predict_view_is_zero_for_a_consistent_sample(franka) -> None:
    samples, views = franka
    s = samples[0]
    X = X_TRUE
    Y = s.base_T_ee @ X @ s.cam_T_board
    v = predict_view(X, Y, s, views, "eye_in_hand")
    assert np.max(v.mm) < 1e-9
    assert v.px.shape == (s.observations[0].image_points.shape[0],)


def test_error_budget_parts_with_corners_add_in_squares() -> None:
    """With corners the camera's part is measured, and camera, robot and estimate add in
    squares to the held-out error (the robot's part is the in-sample scatter less the camera)."""
    from eye_in_hand.core.handeye.synthetic import make_problem

    prob = make_problem(12, seed=3, noise_px=0.5, robot_noise_mm=0.5, robot_noise_deg=0.05)
    b = calibrate_hand_eye(prob.samples, cameras=prob.views).error_budget
    assert b["camera_mm"] is not None and b["camera_mm"] > 0
    total = b["camera_mm"] ** 2 + b["robot_mm"] ** 2 + b["estimate_mm"] ** 2
    assert b["estimate_mm"] > 0, b
    assert total == pytest.approx(b["held_out_mm"] ** 2, rel=2e-3), b
