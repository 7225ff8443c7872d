"""Scenarios: diverse reachable calibration poses, localization orbits at 0.3-0.6 m."""
from __future__ import annotations

import math

import numpy as np
import pytest

from eye_in_hand.core.transforms import rotation_angle
from eye_in_hand.errors import InputError, KinematicsError
from eye_in_hand.sim.scenarios import (
    calibration_poses,
    calibration_timeline,
    localization_trajectory,
)


def test_calibration_poses_are_diverse_and_see_the_board(small_world):
    world = small_world
    poses = calibration_poses(world, 12, seed=2)
    assert len(poses) == 12
    cams = [world.base_T_cam(q) for q in poses]
    axes = []
    for q, _T in zip(poses, cams, strict=True):
        tr = world.truth(q)
        assert tr.board_visible_left and tr.board_visible_right
        assert np.all(q >= world.arm.lower) and np.all(q <= world.arm.upper)
    from scipy.spatial.transform import Rotation

    for a, b in zip(cams[:-1], cams[1:], strict=True):
        R = a[:3, :3].T @ b[:3, :3]
        angle = math.degrees(rotation_angle(R))
        assert 20.0 - 1e-6 <= angle <= 40.0 + 1e-6
        axes.append(Rotation.from_matrix(R).as_rotvec() / math.radians(angle))
    for u, v in zip(axes[:-1], axes[1:], strict=True):
        assert abs(float(u @ v)) <= math.cos(math.radians(30.0)) + 1e-9
    again = calibration_poses(world, 12, seed=2)
    assert all(np.array_equal(a, b) for a, b in zip(poses, again, strict=True))
    other = calibration_poses(world, 12, seed=3)
    assert not np.allclose(poses[0], other[0])


def test_calibration_timeline_holds_and_moves(small_world):
    poses = calibration_poses(small_world, 3, seed=0)
    tl = calibration_timeline(poses, hold_s=0.1, move_s=0.5, rate_hz=100.0, start_ns=5)
    stamps = [t for t, _, _ in tl]
    assert stamps[0] == 5 and np.all(np.diff(stamps) == 10_000_000)
    still = [s for _, _, s in tl]
    assert still[:10] == [True] * 10 and not all(still)
    for _t, q, s in tl:
        if s:
            assert min(np.max(np.abs(q - p)) for p in poses) < 1e-12
    steps = np.diff(np.array([q for _, q, _ in tl]), axis=0)
    assert np.max(np.abs(steps)) < 0.1   # continuous motion
    with pytest.raises(InputError):
        calibration_timeline(poses, rate_hz=0.0)
    with pytest.raises(InputError):
        calibration_poses(small_world, 0)


def test_localization_orbit_keeps_range_and_targets_in_view(small_world):
    world = small_world
    traj = localization_trajectory(world, 2.0, 15.0, seed=4)
    assert len(traj) == 31
    stamps = np.array([t for t, _ in traj])
    assert np.all(np.diff(stamps) == round(1e9 / 15.0))
    qs = np.array([q for _, q in traj])
    assert np.max(np.abs(np.diff(qs, axis=0))) < 0.2
    ranges = []
    for _, q in traj:
        tr = world.truth(q)
        ranges.append(np.linalg.norm(tr.targets_cam[0]))
        assert tr.target_visible_left[0] and tr.target_visible_right[0]
    assert 0.3 <= min(ranges) and max(ranges) <= 0.6
    moved = np.linalg.norm(world.base_T_cam(qs[0])[:3, 3] - world.base_T_cam(qs[-1])[:3, 3])
    assert moved > 0.05
    with pytest.raises(InputError):
        localization_trajectory(world, 0.0, 30.0)
    with pytest.raises(KinematicsError, match="no reachable orbit"):
        localization_trajectory(world, 1.0, 10.0, range_m=(3.0, 3.2))
