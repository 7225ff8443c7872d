"""The simulator's robot error model: true arm vs reported nominal arm."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.errors import ConfigError
from eye_in_hand.sim import World
from eye_in_hand.sim.robot_error import (
    RobotErrorSpec,
    draw_true_arm,
    flange_errors,
    flange_poses,
    pose_error,
    reported_joints,
)
from eye_in_hand.sim.scenarios import calibration_poses


@pytest.fixture(scope="module")
def poses(world) -> np.ndarray:
    return np.array(calibration_poses(world, 6, seed=0))


def test_ideal_spec_gives_the_nominal_arm(world, poses):
    spec = RobotErrorSpec.parse("0")
    assert spec.is_ideal and spec == RobotErrorSpec.none()
    ideal = world.with_robot_error(spec)
    assert ideal.true_arm is ideal.arm
    q = poses[0]
    np.testing.assert_array_equal(reported_joints(q, spec, np.random.default_rng(0)), q)
    tr = ideal.truth(q)
    np.testing.assert_array_equal(tr.base_T_ee, tr.base_T_ee_reported)


def test_default_true_arm_is_seeded_and_within_the_documented_range(world, poses):
    spec = RobotErrorSpec.default()
    assert world.robot_error == spec                    # the default world has it on
    a, b = draw_true_arm(world.arm, spec), draw_true_arm(world.arm, spec)
    np.testing.assert_array_equal(a.d, b.d)             # reproducible
    other = draw_true_arm(world.arm, RobotErrorSpec(**{**spec.to_dict(), "seed": 2}))
    assert not np.allclose(other.a, a.a)
    # link and joint-zero errors of the right size, names and limits kept
    assert 0 < np.abs(a.a - world.arm.a).max() < 5 * spec.link_sigma_m
    assert 0 < np.abs(a.theta_offset).max() < 5 * spec.joint_offset_sigma_rad
    assert a.joint_names == world.arm.joint_names
    dt, dr = flange_errors(world.arm, world.true_arm, poses)
    # documented (docs/simulator.md): ~0.27 mm and ~0.038 deg per pose for the default arm
    assert np.all((0.15e-3 < dt) & (dt < 0.5e-3)), dt
    assert np.all((0.02 < np.degrees(dr)) & (np.degrees(dr) < 0.06)), np.degrees(dr)
    # the scale acts on every part; scale 0 is ideal
    assert spec.scaled(2).link_sigma_m == 2 * spec.link_sigma_m
    assert spec.scaled(0).is_ideal
    dt2, _ = flange_errors(world.arm, draw_true_arm(world.arm, spec.scaled(2)), poses)
    np.testing.assert_allclose(dt2, 2 * dt, rtol=0.05)  # first order in the errors


def test_encoder_noise_and_flange_poses(world, poses):
    spec = RobotErrorSpec.parse("encoder_sigma_rad=1e-3,link_sigma_m=0", RobotErrorSpec.none())
    assert spec.link_sigma_m == 0 and spec.encoder_sigma_rad == 1e-3
    rng = np.random.default_rng(3)
    qr = reported_joints(np.repeat(poses[:1], 4000, axis=0), spec, rng)
    assert np.std(qr - poses[0]) == pytest.approx(1e-3, rel=0.05)
    T_true, T_rep = flange_poses(world.arm, world.true_arm, poses[0], qr[0])
    np.testing.assert_allclose(T_true, world.true_arm.fk(poses[0]))
    np.testing.assert_allclose(T_rep, world.arm.fk(qr[0]))
    assert pose_error(T_true, T_true) == (0.0, 0.0)


def test_parse_and_world_yaml(tmp_path):
    base = RobotErrorSpec.default()
    assert RobotErrorSpec.parse("default") == base
    assert RobotErrorSpec.parse("2").joint_offset_sigma_rad == 2 * base.joint_offset_sigma_rad
    s = RobotErrorSpec.parse("1,time_offset_s=0.004,seed=5")
    assert (s.time_offset_s, s.seed, s.link_sigma_m) == (0.004, 5, base.link_sigma_m)
    for bad, msg in (("nope", "key=value"), ("link=1", "unknown key"),
                     ("link_sigma_m=abc", "bad value"), ("link_sigma_m=-1", ">= 0"),
                     ("", "empty")):
        with pytest.raises(ConfigError, match=msg):
            RobotErrorSpec.parse(bad)
    w = World.default().with_robot_error(s)
    back = World.from_yaml(w.to_yaml(tmp_path / "w.yaml"))
    assert back.robot_error == s
    assert World.from_dict({**w.to_dict(), "robot_error": 0}).robot_error.is_ideal
    with pytest.raises(ConfigError, match="robot_error: unknown key"):
        World.from_dict({**w.to_dict(), "robot_error": {"links": 1}}, "w.yaml")


def test_simulate_command_robot_error_option(tmp_path, capsys):
    from eye_in_hand.cli import main

    assert main(["simulate", "--scenario", "localization", "-o", str(tmp_path / "a"),
                 "--frames", "2", "--size", "160x120", "--quiet", "--robot-error", "0"]) == 0
    assert "robot error: none" in capsys.readouterr().out
    assert main(["simulate", "--scenario", "localization", "-o", str(tmp_path / "b"),
                 "--frames", "2", "--size", "160x120", "--quiet"]) == 0
    assert "robot error: links 0.15 mm" in capsys.readouterr().out
    assert main(["simulate", "--scenario", "localization", "-o", str(tmp_path / "c"),
                 "--frames", "2", "--quiet", "--robot-error", "seed=x"]) == 1
    err = capsys.readouterr().err
    assert "--robot-error: bad value for seed" in err and "Traceback" not in err


def test_time_offset_moves_the_true_pose_along_the_motion(tmp_path, small_world):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from eye_in_hand.core.transforms import from_xyz_quat, transform_distance
    from eye_in_hand.sim.output import TOPICS, RenderOptions, write_bag

    def poses(path, topic):
        out = {}
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            for conn, t, raw in reader.messages([c for c in reader.connections
                                                 if c.topic == topic]):
                p = reader.deserialize(raw, conn.msgtype).pose
                out[t] = from_xyz_quat([p.position.x, p.position.y, p.position.z],
                                       [p.orientation.x, p.orientation.y, p.orientation.z,
                                        p.orientation.w])
        return out

    gaps = []
    for name, spec in (("a", RobotErrorSpec.none()),
                       ("b", RobotErrorSpec(time_offset_s=0.05))):
        path = tmp_path / name
        write_bag(small_world.with_robot_error(spec), path, scenario="localization", frames=3,
                  seed=2, render=RenderOptions(noise_sigma=0.0, supersample=1))
        true_T = poses(path, TOPICS["gt_ee_pose"])
        rep_T = poses(path, TOPICS["gt_ee_pose_reported"])
        assert len(true_T) == len(rep_T) == 3
        gaps.append(max(transform_distance(true_T[t], rep_T[t])[0] for t in true_T))
    assert gaps[0] < 1e-9                  # ideal arm: true = reported
    assert gaps[1] > 2e-3                  # 50 ms of a moving camera: millimetres
