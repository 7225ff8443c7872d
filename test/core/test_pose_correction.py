"""The robot pose correction of the systematic model: its formula, its file block, and the
localizer that applies it (the one used by the hand_eye node and by process)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.handeye import calibrate_hand_eye
from eye_in_hand.core.localization import Localizer, LocalizerConfig
from eye_in_hand.core.pose_correction import (
    RobotPoseCorrection,
    exp_rotations,
    log_rotations,
)
from eye_in_hand.core.transforms import from_rotvec, invert
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.io.config import HandEyeCalibration, load_hand_eye, save_hand_eye

from .test_handeye_systematic import A_R, A_T, X_TRUE, Y_TRUE, _problem

R_REF = Rotation.from_rotvec([np.pi, 0.0, 0.2]).as_matrix()
CORR = RobotPoseCorrection(A_R, A_T, R_REF)


def _reported(seed: int, n: int = 6) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([from_rotvec(Rotation.from_matrix(R_REF).as_rotvec()
                                 + rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.5, 0.5, 3))
                     for _ in range(n)])


def test_correction_is_the_documented_formula() -> None:
    """true = reported @ [exp(A_r r) | A_t r], r = log(R_ref^T R), computed independently."""
    poses = _reported(1)
    got = CORR.apply(poses)
    for G, C in zip(poses, got, strict=True):
        r = Rotation.from_matrix(R_REF.T @ G[:3, :3]).as_rotvec()
        want = G @ from_rotvec(A_R @ r, A_T @ r)
        assert np.allclose(C, want, atol=1e-12)
        assert np.allclose(CORR.apply(G), want, atol=1e-12)      # one pose: (4, 4)
    assert CORR.apply(poses[0]).shape == (4, 4)
    # one pose takes a scalar path: the same numbers as the batch, at every angle from R_ref
    for angle in (0.0, 1e-8, 1.0, 2.99, 3.01, np.pi - 1e-6):
        G = np.eye(4)
        G[:3, :3] = R_REF @ Rotation.from_rotvec(angle * np.array([0.6, -0.64, 0.48])).as_matrix()
        assert np.allclose(CORR.apply(G), CORR.apply(G[None])[0], atol=1e-13), angle
    # no correction at the reference orientation, whatever the position
    at_ref = np.eye(4)
    at_ref[:3, :3], at_ref[:3, 3] = R_REF, [0.3, -0.2, 0.5]
    assert np.allclose(CORR.apply(at_ref), at_ref, atol=1e-15)
    assert not CORR.is_zero
    assert RobotPoseCorrection(np.zeros((3, 3)), np.zeros((3, 3)), R_REF).is_zero


@pytest.mark.parametrize("angle", [1e-9, 0.3, 2.9, 3.05, np.pi - 1e-7, np.pi])
def test_rotation_log_and_exp_match_scipy_up_to_a_half_turn(angle: float) -> None:
    axes = np.array([[1.0, 0.0, 0.0], [0.2, -0.7, 0.5], [-0.3, 0.1, -0.9]])
    w = angle * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    R = exp_rotations(w)
    assert np.allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    back = log_rotations(R)
    if angle < np.pi - 1e-6:
        assert np.allclose(back, w, atol=1e-7)
    else:   # at a half turn +w and -w are the same rotation
        assert np.allclose(exp_rotations(back), R, atol=1e-9)
        assert np.allclose(np.linalg.norm(back, axis=1), angle, atol=1e-7)


def test_systematic_fit_and_its_correction_are_one_rule() -> None:
    samples = _problem(12, 5, A_R, A_T)
    res = calibrate_hand_eye(samples)       # the default model: systematic
    assert res.selected == "refined_systematic"
    corr = res.pose_correction
    assert corr is not None
    bte = np.stack([s.base_T_ee for s in samples])
    assert np.array_equal(corr.apply(bte), res.correct_robot_pose(bte))
    assert res.robot_pose_noise == {"translation_sigma_m": res.systematic.sigmas["robot_t"],
                                    "rotation_sigma_rad": res.systematic.sigmas["robot_r"]}
    # the per-pose model has no correction
    assert calibrate_hand_eye(samples, robot_model="per_pose").pose_correction is None


@pytest.mark.parametrize("bad, match", [
    (dict(A_r=np.zeros((2, 3))), "A_r must be 3x3"),
    (dict(A_t=np.full((3, 3), np.nan)), "A_t has NaN"),
    (dict(R_ref=2.0 * np.eye(3)), "R_ref is not a rotation"),
])
def test_a_malformed_correction_is_refused(bad, match) -> None:
    args = dict(A_r=A_R, A_t=A_T, R_ref=R_REF) | bad
    with pytest.raises(InputError, match=match):
        RobotPoseCorrection(**args)


def _calibration(**kw) -> HandEyeCalibration:
    return HandEyeCalibration(setup="eye_in_hand", parent_frame="tool0",
                              child_frame="camera_left_optical_frame", transform=X_TRUE,
                              method="refined_systematic", **kw)


def test_hand_eye_yaml_round_trip_of_the_correction(tmp_path) -> None:
    path = save_hand_eye(tmp_path / "hand_eye.yaml", _calibration(robot_pose_correction=CORR))
    back = load_hand_eye(path).robot_pose_correction
    assert back is not None
    assert np.array_equal(back.A_r, CORR.A_r) and np.array_equal(back.A_t, CORR.A_t)
    assert np.allclose(back.R_ref, CORR.R_ref, atol=1e-14)
    poses = _reported(2)
    assert np.allclose(back.apply(poses), CORR.apply(poses), atol=1e-13)
    # without the block: no correction (files of earlier releases)
    path2 = save_hand_eye(tmp_path / "plain.yaml", _calibration())
    assert load_hand_eye(path2).robot_pose_correction is None
    assert "robot_pose_correction" not in path2.read_text()


def _block() -> dict:
    return _calibration(robot_pose_correction=CORR).to_dict()


@pytest.mark.parametrize("edit, match", [
    (lambda d: d["robot_pose_correction"].update(model="kinematic"),
     r"robot_pose_correction.model: only 'flange_orientation_linear' is known"),
    (lambda d: d["robot_pose_correction"].pop("translation_m_per_rad"),
     "must be a mapping with exactly the keys"),
    (lambda d: d["robot_pose_correction"].update(rotation_rad_per_rad=[[0, 0, 0], [0, 0, 0]]),
     r"robot_pose_correction.rotation_rad_per_rad must be 3x3 .* got shape \(2, 3\)"),
    (lambda d: d["robot_pose_correction"].update(
        translation_m_per_rad=[[0, 0, float("nan")], [0, 0, 0], [0, 0, 0]]),
     "translation_m_per_rad contains NaN"),
    (lambda d: d["robot_pose_correction"].update(reference_quat_xyzw=[0, 0, 0, 2]),
     "reference_quat_xyzw is not a unit quaternion"),
    (lambda d: d.update(setup="eye_to_hand", parent_frame="base_link"),
     "'robot_pose_correction' is for eye_in_hand calibrations"),
])
def test_a_bad_correction_block_names_the_key(tmp_path, edit, match) -> None:
    import yaml

    data = _block()
    edit(data)
    path = tmp_path / "hand_eye.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=match) as info:
        load_hand_eye(path)
    assert str(path) in str(info.value)


def test_localizer_applies_the_correction_at_the_image_stamp() -> None:
    """The target in the base frame is corrected_pose @ X @ p, the pose interpolated first."""
    poses = _reported(3, 2)
    p_cam = np.array([0.01, -0.02, 0.4])
    plain = Localizer(X_TRUE, config=LocalizerConfig(max_gap_ns=10**9))
    fixed = Localizer(X_TRUE, config=LocalizerConfig(max_gap_ns=10**9), pose_correction=CORR)
    for loc in (plain, fixed):
        loc.add_robot_pose(0, poses[0])
        loc.add_robot_pose(10**8, poses[0])
    a, b = plain.locate(5 * 10**7, p_cam), fixed.locate(5 * 10**7, p_cam)
    want = CORR.apply(poses[0]) @ X_TRUE @ np.append(p_cam, 1.0)
    assert np.allclose(b.point_base, want[:3], atol=1e-12)
    assert np.allclose(b.base_T_ee, CORR.apply(poses[0]), atol=1e-12)
    assert np.allclose(a.point_base, (poses[0] @ X_TRUE @ np.append(p_cam, 1.0))[:3])
    assert np.linalg.norm(a.point_base - b.point_base) > 1e-3    # the correction matters


def test_calibrated_correction_locates_unseen_poses_better(tmp_path) -> None:
    """Calibrate with the systematic model, write hand_eye.yaml, and locate the board origin
    from poses the calibration never saw: with the file's correction the error is a fraction
    of what the reported poses give."""
    train = _problem(14, 7, A_R, A_T, noise_mm=0.05, noise_deg=0.005)
    res = calibrate_hand_eye(train, robot_model="systematic")
    assert res.pose_correction is not None
    path = save_hand_eye(tmp_path / "hand_eye.yaml", _calibration(
        robot_pose_correction=res.pose_correction))
    calib = load_hand_eye(path)
    # unseen poses: same arm (the same R_ref-relative law), no per-pose noise
    rng = np.random.default_rng(11)
    from .test_handeye_systematic import _poses

    rep = _poses(8, rng)
    R_ref = res.pose_correction.R_ref
    err_with, err_without = [], []
    for G in rep:
        r = Rotation.from_matrix(R_ref.T @ G[:3, :3]).as_rotvec()
        true = G @ from_rotvec(A_R @ r, A_T @ r)
        board_in_cam = invert(X_TRUE) @ invert(true) @ Y_TRUE
        p_cam = board_in_cam[:3, 3]
        for corr, errs in ((calib.robot_pose_correction, err_with), (None, err_without)):
            loc = Localizer(res.X, config=LocalizerConfig(max_gap_ns=10**9),
                            pose_correction=corr)
            loc.add_robot_pose(0, G)
            loc.add_robot_pose(10, G)
            errs.append(np.linalg.norm(loc.locate(5, p_cam).point_base - Y_TRUE[:3, 3]))
    rms_with = float(np.sqrt(np.mean(np.square(err_with))))
    rms_without = float(np.sqrt(np.mean(np.square(err_without))))
    assert rms_with < 0.3 * rms_without, (rms_with, rms_without)
