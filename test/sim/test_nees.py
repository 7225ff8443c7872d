"""Fast NEES checks against the simulator's truth: the camera-frame point covariance
(``target/point_cov``: per-detection centre sigmas through the triangulation) across and along
the line of sight, and the base-frame covariance (plus robot pose noise) with the robot error
off and at the realistic default.

The full figures are benchmarks/bench_point_cov.py (camera frame, true rig, 90 + 25 views) and
benchmarks/bench_localization.py --consistency-only (base frame, calibrations from a bag, 90
frames); these are the same chains on a few frames with the true rig and mount.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.offline import ProcessOptions
from eye_in_hand.sim import World
from eye_in_hand.sim.robot_error import RobotErrorSpec
from eye_in_hand.sim.scenarios import localization_trajectory

CONFIG = Path(__file__).resolve().parents[2] / "config" / "eye_in_hand.yaml"


@pytest.mark.parametrize("blur", [0.0, 1.0], ids=["sharp", "blur-1px"])
def test_camera_frame_nees_is_consistent_sideways_and_in_depth(blur):
    """The benchmark's orbit (seed 22) at 5 Hz, true rig. Without the threshold-cut term (the
    centre error common to both images that the edge fit cannot see) the lateral NEES was 5.5
    with 62 % of the views inside the 95 % ellipse (3-dof NEES 6.7): the sideways sigma was
    about half the sideways error. With it: 3.4, lateral 2.5 (100 %), depth 1.6.

    Blurred by 1 px (Gaussian), the shading and threshold-cut shifts grow about fourfold and
    threefold; with those terms as measured without blur the NEES was 20.1 (lateral 16.6 with
    19 % of the views in the ellipse, depth 7.4). Scaled by the detector's blur estimate from
    the edge width (``Detection.blur_px``): 3.2, lateral 2.3 (100 %), depth 1.2."""
    world = World.default().with_robot_error(RobotErrorSpec.none())
    loc = StereoLocator(world.rig.rectified(), load_locator_config(CONFIG))
    m2, lat, dep, est = [], [], [], []
    for k, (_, q) in enumerate(localization_trajectory(world, 3.0, 5.0, seed=22)):
        f = world.render(q, seed=k, noise_sigma=1.0, supersample=3, blur_sigma=blur)
        t = loc.locate(f.left, f.right).first
        assert t is not None
        est += [t.left.blur_px, t.right.blur_px]
        p, P = f.truth.targets_cam[0], t.covariance
        e = t.point_m - p
        z = p / np.linalg.norm(p)                       # line of sight
        a = np.cross(z, [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        B = np.stack([a, np.cross(z, a)])               # across it
        x = B @ e
        m2.append(float(e @ np.linalg.solve(P, e)))
        lat.append(float(x @ np.linalg.solve(B @ P @ B.T, x)))
        dep.append(float((z @ e) ** 2 / (z @ P @ z)))
    assert len(m2) >= 14
    assert 1.5 <= np.mean(m2) <= 6.0, m2                # [0.5, 2] x 3 dof
    assert 1.0 <= np.mean(lat) <= 4.0, lat              # [0.5, 2] x 2 dof
    assert np.mean(np.array(lat) <= 5.9915) >= 0.8, lat  # 95 % ellipse (chi-square, 2 dof)
    assert 0.5 <= np.mean(dep) <= 2.0, dep              # depth stays right: [0.5, 2] x 1 dof
    assert abs(np.mean(est) - blur) < 0.3, est          # the blur the detector sees


@pytest.mark.parametrize("spec, robot_sigmas", [
    (RobotErrorSpec.none(), (0.0, 0.0)),        # ideal arm: exact poses
    (RobotErrorSpec.default(), (ProcessOptions.robot_sigma_pos_m,
                                ProcessOptions.robot_sigma_rot_rad)),   # the documented defaults
], ids=["robot-error-0", "robot-error-default"])
def test_base_frame_nees_is_consistent(spec, robot_sigmas):
    world = World.default().with_robot_error(spec)     # 1280x720, as the benchmark
    loc = StereoLocator(world.rig.rectified(), load_locator_config(CONFIG))
    m2, err = [], []
    for k, (_, q) in enumerate(localization_trajectory(world, 2.0, 3.0, seed=4)):
        f = world.render(q, seed=k, noise_sigma=1.0, supersample=3)
        t = loc.locate(f.left, f.right).first
        assert t is not None
        # the robot reports the nominal arm; the images come from the true one
        p, C = target_in_base(f.truth.base_T_ee_reported, world.ee_T_cam, t.point_m,
                              cov_cam=t.covariance, robot_sigma_pos_m=robot_sigmas[0],
                              robot_sigma_rot_rad=robot_sigmas[1])
        e = p - f.truth.targets_base[0]
        m2.append(float(e @ np.linalg.solve(C, e)))
        err.append(float(np.linalg.norm(e)))
    nees = float(np.mean(m2))
    assert len(m2) >= 7
    assert 1.5 <= nees <= 6.0, (nees, m2)              # [0.5, 2] x 3 dof
    if not spec.is_ideal:
        assert np.sqrt(np.mean(np.square(err))) > 0.15e-3   # the robot error is really there
