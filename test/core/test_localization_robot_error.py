"""The robot-pose share of the base-frame covariance against the simulator's kinematic errors.

A small Monte Carlo of what the localization benchmark measures at full size: arms drawn from
the simulator's default robot error model (link lengths, twists, joint zeros: systematic, not
white), each reporting its nominal flange pose; a point in front of the camera is mapped into
the base frame through the reported pose, and its error against the true arm's mapping is
whitened with the full 3x3 covariance of :func:`target_in_base`.

The robot sigmas are chosen as ``process`` and the ``hand_eye`` node choose them
(:func:`robot_pose_sigmas`): the stated accuracy of the arm model (here the per-axis RMS flange
error of *other* arms of the same model, at other poses: what a datasheet gives), raised by
the calibration's estimate. The calibration's estimate is emulated as what a calibration can
see: the scatter of each arm's reported poses at 15 calibration poses about the best common
error on either side (``true = E_base @ reported @ E_flange``: a calibration takes the
base-side error into the board's pose and the flange-side one into the hand-eye transform).
That scatter alone is far too small.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from eye_in_hand.core.localization import robot_pose_sigmas, target_in_base
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import InputError
from eye_in_hand.sim import World
from eye_in_hand.sim.robot_error import RobotErrorSpec, draw_true_arm
from eye_in_hand.sim.scenarios import calibration_poses

K95 = chi2.ppf(0.95, 3)


def _flange_errors(nominal, true_arm, qs) -> np.ndarray:
    """(K, 6): ``[d_t, d_r]`` with ``true = reported @ [exp(d_r) | d_t]`` (flange frame)."""
    out = []
    for q in qs:
        B_rep, B_true = nominal.fk(q), true_arm.fk(q)
        D = np.linalg.solve(B_rep, B_true)
        out.append(np.r_[D[:3, 3], Rotation.from_matrix(D[:3, :3]).as_rotvec()])
    return np.array(out)


@pytest.fixture(scope="module")
def world_and_poses():
    world = World.default()
    cal = calibration_poses(world, 15, seed=3)
    loc = calibration_poses(world, 15, seed=4)[:6]
    return world, cal, loc


def _stated_accuracy(world, qs) -> tuple[float, float]:
    """Per-axis RMS flange error of 12 arms of the model (seeds 1000+) at the poses ``qs``."""
    spec = RobotErrorSpec.default()
    errs = np.concatenate([_flange_errors(world.arm, draw_true_arm(
        world.arm, spec, np.random.default_rng(1000 + k)), qs) for k in range(12)])
    return (float(np.sqrt(np.mean(errs[:, :3] ** 2))),
            float(np.sqrt(np.mean(errs[:, 3:] ** 2))))


def _scatter(nominal, true_arm, qs) -> dict[str, float]:
    """Per-axis RMS of the reported poses' errors about the best common base- and flange-side
    errors (what a calibration at the poses ``qs`` can see of this arm)."""
    B_rep = np.stack([nominal.fk(q) for q in qs])
    B_true = np.stack([true_arm.fk(q) for q in qs])

    def residuals(x: np.ndarray) -> np.ndarray:
        Eb, Ef = from_rotvec(x[:3], x[3:6]), from_rotvec(x[6:9], x[9:])
        D = np.linalg.solve(Eb @ B_rep @ Ef, B_true)
        return np.concatenate([D[:, :3, 3], Rotation.from_matrix(D[:, :3, :3]).as_rotvec()],
                              axis=1).ravel()

    r = least_squares(residuals, np.zeros(12), x_scale=1e-3).fun.reshape(-1, 6)
    return {"translation_sigma_m": float(np.sqrt(np.mean(r[:, :3] ** 2))),
            "rotation_sigma_rad": float(np.sqrt(np.mean(r[:, 3:] ** 2)))}


def _nees(world, cal, loc, stated, *, arms: int = 40) -> tuple[np.ndarray, float, float]:
    spec = RobotErrorSpec.default()
    p_cam = np.array([0.02, -0.01, 0.45])
    X = world.ee_T_cam
    m2 = []
    err, sig = [], []
    for k in range(arms):
        true_arm = draw_true_arm(world.arm, spec, np.random.default_rng(k))
        s_pos, s_rot = robot_pose_sigmas(*stated, _scatter(world.arm, true_arm, cal))
        for q in loc:
            B_rep, B_true = world.arm.fk(q), true_arm.fk(q)
            p, cov = target_in_base(B_rep, X, p_cam, robot_sigma_pos_m=s_pos,
                                    robot_sigma_rot_rad=s_rot)
            e = p - (B_true @ X @ np.r_[p_cam, 1.0])[:3]
            m2.append(float(e @ np.linalg.solve(cov, e)))
            err.append(float(e @ e))
            sig.append(float(np.trace(cov)))
    return np.array(m2), float(np.sqrt(np.mean(err))), float(np.sqrt(np.mean(sig)))


def test_stated_accuracy_gives_an_honest_base_frame_covariance(world_and_poses) -> None:
    world, cal, loc = world_and_poses
    stated = _stated_accuracy(world, calibration_poses(world, 8, seed=5))
    m2, rms, sigma = _nees(world, cal, loc, stated)
    # consistent: mean NEES within [0.5, 2] x 3, 95 % ellipsoid coverage 85-99 %
    assert 1.5 <= m2.mean() <= 6.0, (m2.mean(), rms, sigma)
    assert 0.85 <= np.mean(m2 <= K95) <= 0.99, np.mean(m2 <= K95)
    # and not absurdly large: the reported sigma within 2x of the actual RMS error
    assert 0.5 * rms < sigma < 2.0 * rms, (rms, sigma)


def test_the_calibration_scatter_alone_is_far_too_small(world_and_poses) -> None:
    """Why the stated accuracy is needed: with it at 0, only the calibration's view remains."""
    world, cal, loc = world_and_poses
    m2, _, _ = _nees(world, cal, loc, (0.0, 0.0), arms=15)
    assert m2.mean() > 12.0, m2.mean()      # measured 26; consistent would be <= 6


def test_robot_pose_sigmas_take_the_larger_of_each() -> None:
    est = {"translation_sigma_m": 2e-4, "rotation_sigma_rad": 1e-5}
    assert robot_pose_sigmas(1.5e-4, 4e-4, est) == (2e-4, 4e-4)
    assert robot_pose_sigmas(1.5e-4, 4e-4, None) == (1.5e-4, 4e-4)
    assert robot_pose_sigmas(0.0, 0.0, est) == (2e-4, 1e-5)
    with pytest.raises(InputError, match="robot_sigma_rot_rad"):
        robot_pose_sigmas(1e-4, -1.0, None)
    with pytest.raises(InputError, match="robot_pose_noise.translation_sigma_m"):
        robot_pose_sigmas(1e-4, 1e-4, {"translation_sigma_m": float("nan"),
                                       "rotation_sigma_rad": 0.0})
    with pytest.raises(InputError, match="missing rotation_sigma_rad"):
        robot_pose_sigmas(1e-4, 1e-4, {"translation_sigma_m": 0.0})
