"""hand_eye.yaml's robot_pose_noise: the held-out base-frame scatter the calibration leaves.

A fast version of the localization benchmark's check with an exact arm: a stereo rig whose
right camera is calibrated 1 mrad off (a stereo calibration error the hand-eye data cannot
correct) bends X, and board positions predicted at poses the calibration did not use scatter
from pose to pose, though the fit itself looks exact (the errors-in-variables robot noise
stays at its floor: the corners absorb it). The translation noise written to hand_eye.yaml
must cover it: board centres at new poses, mapped into the base frame as the localization maps
a target, with the full 3x3 covariance of :func:`target_in_base` (camera point from its
corners, hand-eye covariance, robot noise), must give a mean NEES within [0.5, 2] x 3.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.handeye import CameraView, HandEyeSample, calibrate_hand_eye
from eye_in_hand.core.handeye.observe import board_pose_pnp
from eye_in_hand.core.handeye.refine import _project, perturb
from eye_in_hand.core.handeye.select import held_out_position_sigma
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.transforms import from_rotvec

PX = 0.3


def _centre_cov(C0: np.ndarray, s: HandEyeSample, view: CameraView, c: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of the board point ``c`` in the camera from the sample's corners."""
    ob = s.observations[0]
    f0 = _project(view, C0, ob.object_points).ravel()
    J, Jc = np.zeros((f0.size, 6)), np.zeros((3, 6))
    for j in range(6):
        d = np.r_[C0[:3, 3], 0.0, 0.0, 0.0]
        d[j] += 1e-7
        C = perturb(C0, d)
        J[:, j] = (_project(view, C, ob.object_points).ravel() - f0) / 1e-7
        Jc[:, j] = (C[:3, :3] @ c + C[:3, 3] - C0[:3, :3] @ c - C0[:3, 3]) / 1e-7
    return Jc @ (PX ** 2 * np.linalg.inv(J.T @ J)) @ Jc.T


def _prediction_nees(res, view: CameraView, seed: int, robot_t: float) -> np.ndarray:
    Q = make_problem(6, seed=seed, noise_px=PX)
    c = Q.samples[0].observations[0].object_points.mean(axis=0)
    truth = Q.Y[:3, :3] @ c + Q.Y[:3, 3]
    out = []
    for s in Q.samples:
        ob = s.observations[0]
        C, _ = board_pose_pnp(view.model, ob.object_points, ob.image_points)
        p, cov = target_in_base(s.base_T_ee, res.X, C[:3, :3] @ c + C[:3, 3],
                                cov_cam=_centre_cov(C, s, view, c),
                                cov_hand_eye=res.covariance, robot_sigma_pos_m=robot_t,
                                robot_sigma_rot_rad=res.robot_pose_noise["rotation_sigma_rad"])
        e = p - truth
        out.append(float(e @ np.linalg.solve(cov, e)))
    return np.array(out)


@pytest.fixture(scope="module")
def miscalibrated():
    """Two stereo calibrations with exact robot poses and the right camera 1 mrad off."""
    runs = []
    for k in range(2):
        P = make_problem(12, seed=840 + k, noise_px=PX, stereo=True)
        left, right = P.views
        views = [left, CameraView("right", right.model,
                                  from_rotvec([0.0, 1e-3, 0.0]) @ right.view_T_cam)]
        res = calibrate_hand_eye(P.samples, "eye_in_hand", cameras=views)
        runs.append((res, left, 940 + k))
    return runs


def test_written_translation_noise_covers_the_held_out_scatter(miscalibrated) -> None:
    m2 = []
    for res, view, seed in miscalibrated:
        m2.append(_prediction_nees(res, view, seed,
                                   res.robot_pose_noise["translation_sigma_m"]))
    m2 = np.concatenate(m2)
    assert 1.5 <= m2.mean() <= 6.0, m2.mean()
    for res, _, _ in miscalibrated:
        assert res.held_out_sigma_m > 1e-4 > 10 * res.refinement.robot_translation_sigma_m
        assert res.robot_pose_noise["translation_sigma_m"] == res.held_out_sigma_m


def test_the_refinement_estimate_alone_is_too_small(miscalibrated) -> None:
    m2 = np.concatenate([_prediction_nees(res, view, seed,
                                          res.refinement.robot_translation_sigma_m)
                         for res, view, seed in miscalibrated])
    assert m2.mean() > 6.0, m2.mean()


def test_the_views_own_noise_is_not_counted() -> None:
    """Exact camera, exact poses, the true X and Y: the held-out scatter is the board poses'
    measurement noise (PnP on 0.3 px corners), which the localization counts in the camera
    point's covariance; it is taken out."""
    P = make_problem(12, seed=830, noise_px=PX)
    sols = [(P.X, P.Y)] * len(P.samples)   # the truth predicts every sample
    s_t, rms = held_out_position_sigma(sols, P.samples, "eye_in_hand", 0.0, P.views, PX)
    s_raw, _ = held_out_position_sigma(sols, P.samples, "eye_in_hand", 0.0)
    assert s_t < 0.3 * s_raw and rms > 5e-5, (s_t, s_raw, rms)
