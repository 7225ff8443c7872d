"""Fast NEES check: the base-frame covariance (per-detection centre sigmas + robot pose noise)
against the simulator's truth, with the robot error off and at the realistic default.

The full figure (calibrations from a bag, 90 frames) is benchmarks/bench_localization.py
--consistency-only; this is the same chain on a few frames with the true rig and mount.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.locator import StereoLocator, load_locator_config
from eye_in_hand.offline import ProcessOptions
from eye_in_hand.sim import World
from eye_in_hand.sim.robot_error import RobotErrorSpec
from eye_in_hand.sim.scenarios import localization_trajectory

CONFIG = Path(__file__).resolve().parents[2] / "config" / "eye_in_hand.yaml"


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
