"""Kinematics: UR5e DH forward kinematics, URDF chains against the DH model, numerical IK."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.core.kinematics import DHChain, UrdfChain, solve_ik
from eye_in_hand.core.transforms import from_rotvec, invert, rotation_angle
from eye_in_hand.errors import InputError, KinematicsError

URDF = Path(__file__).resolve().parents[1] / "data" / "urdf" / "ur5e.urdf"
# ur_description: base_link is rotated by pi about z from the DH base frame ("base").
BASE_LINK_T_DH_BASE = np.diag([-1.0, -1.0, 1.0, 1.0])


def test_ur5e_zero_pose_matches_published_geometry():
    arm = DHChain.ur5e()
    assert (arm.base_frame, arm.dh_frame) == ("base_link", "base")
    np.testing.assert_array_equal(arm.base_T_dh, BASE_LINK_T_DH_BASE)
    T_dh = invert(arm.base_T_dh) @ arm.fk(np.zeros(6))      # in UR's controller frame base
    # at q = 0 the UR arm is stretched along -x of base: x = a2 + a3, y = -(d4 + d6),
    # z = d1 - d5 (so along +x of base_link)
    np.testing.assert_allclose(T_dh[:3, 3], [-0.425 - 0.3922, -(0.1333 + 0.0996),
                                             0.1625 - 0.0997], atol=1e-12)
    # the alphas compose to Rx(pi/2) at q = 0
    np.testing.assert_allclose(T_dh[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    frames = arm.fk_frames(np.zeros(6))
    assert len(frames) == 6 and np.allclose(frames[-1], arm.fk(np.zeros(6)))
    # the frames round-trip through the world.yaml mapping
    back = DHChain.from_dict(arm.to_dict())
    assert back.dh_frame == "base"
    np.testing.assert_allclose(back.base_T_dh, arm.base_T_dh, atol=1e-15)
    # a DH mapping without base_T_dh: identity, DH frame 0 = base_frame
    plain = DHChain.from_dict({k: v for k, v in arm.to_dict().items()
                               if k not in ("dh_frame", "base_T_dh")})
    np.testing.assert_allclose(plain.fk(np.zeros(6)), T_dh, atol=1e-12)
    assert plain.dh_frame == plain.base_frame == "base_link"


def test_urdf_chain_equals_dh_model_in_ur_description_frames():
    dh = DHChain.ur5e()
    urdf = UrdfChain.from_file(URDF, "base_link", "tool0")
    assert urdf.joint_names == dh.joint_names
    rng = np.random.default_rng(11)
    for _ in range(20):
        q = rng.uniform(-math.pi, math.pi, 6)
        # the same base_link -> tool0 as ur_description's URDF: a UR bag and the simulator agree
        np.testing.assert_allclose(urdf.fk(q), dh.fk(q), atol=1e-12)
    # the "base" link of the URDF is the DH base frame itself
    base = UrdfChain.from_file(URDF, "base_link", "base")
    np.testing.assert_allclose(base.fk(np.zeros(0)), BASE_LINK_T_DH_BASE, atol=1e-12)
    np.testing.assert_allclose(base.fk(np.zeros(0)), dh.base_T_dh, atol=1e-12)
    assert dh.dh_frame == "base"
    # intermediate frames compose to the tip
    T = np.eye(4)
    for _, _, A in urdf.fk_frames(q):
        T = T @ A
    np.testing.assert_allclose(T, urdf.fk(q), atol=1e-12)


def test_urdf_prismatic_continuous_and_errors():
    text = """<robot name="r">
      <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
      <joint name="slide" type="prismatic"><parent link="a"/><child link="b"/>
        <origin xyz="0 0 1" rpy="0 0 0"/><axis xyz="1 0 0"/>
        <limit lower="-0.5" upper="0.5"/></joint>
      <joint name="spin" type="continuous"><parent link="b"/><child link="c"/>
        <axis xyz="0 0 1"/></joint>
      <joint name="fix" type="fixed"><parent link="c"/><child link="d"/>
        <origin xyz="1 0 0"/></joint>
    </robot>"""
    chain = UrdfChain.from_string(text, "a", "d")
    assert chain.joint_names == ("slide", "spin")
    assert chain.lower[0] == -0.5 and math.isinf(chain.upper[1])
    T = chain.fk([0.25, math.pi / 2])
    np.testing.assert_allclose(T[:3, 3], [0.25, 1.0, 1.0], atol=1e-12)
    with pytest.raises(KinematicsError, match="tip link 'zz' not found"):
        UrdfChain.from_string(text, "a", "zz")
    with pytest.raises(KinematicsError, match="not below"):
        UrdfChain.from_string(text, "d", "a")
    with pytest.raises(KinematicsError, match="unsupported joint type 'floating'"):
        UrdfChain.from_string(text.replace('type="continuous"', 'type="floating"'), "a", "d")
    with pytest.raises(KinematicsError, match="needs a <limit>"):
        UrdfChain.from_string(text.replace('<limit lower="-0.5" upper="0.5"/>', ""), "a", "d")
    with pytest.raises(InputError, match="expected 2 joint values"):
        chain.fk([0.0])


def test_ik_recovers_reachable_poses_within_limits():
    arm = DHChain.ur5e()
    rng = np.random.default_rng(5)
    for _ in range(6):
        q = rng.uniform(-2.5, 2.5, 6)
        target = arm.fk(q)
        seed = q + rng.normal(0, 0.3, 6)
        sol = arm.ik(target, seed)
        T = arm.fk(sol)
        assert np.linalg.norm(T[:3, 3] - target[:3, 3]) < 1e-6
        assert rotation_angle(T[:3, :3].T @ target[:3, :3]) < 1e-6
        assert np.all(sol >= arm.lower) and np.all(sol <= arm.upper)
    # deterministic
    np.testing.assert_array_equal(arm.ik(target, seed), arm.ik(target, seed))


def test_ik_rejects_unreachable_poses_and_respects_limits():
    arm = DHChain.ur5e()
    far = from_rotvec([0, 0, 0], [1.5, 0.2, 0.3])
    with pytest.raises(KinematicsError, match="beyond the arm's reach"):
        arm.ik(far)
    # reachable with the full range, but not with the shoulder pan locked near 0
    q = np.array([2.0, -1.2, 1.3, -1.6, -1.5, 0.2])
    locked = DHChain.from_dict({**arm.to_dict(), "lower": [-0.1, -6.3, -6.3, -6.3, -6.3, -6.3],
                                "upper": [0.1, 6.3, 6.3, 6.3, 6.3, 6.3]})
    with pytest.raises(KinematicsError, match="not reachable within the joint limits"):
        solve_ik(locked, arm.fk(q), np.zeros(6), attempts=3)


def test_dh_dict_round_trip_and_validation():
    arm = DHChain.ur5e()
    again = DHChain.from_dict(arm.to_dict())
    q = np.array([0.1, -0.5, 0.7, 0.2, -0.3, 0.4])
    np.testing.assert_allclose(again.fk(q), arm.fk(q))
    with pytest.raises(InputError, match="missing key 'alpha'"):
        DHChain.from_dict({"d": [0.1], "a": [0.0]})
    with pytest.raises(InputError, match="lower joint limit"):
        DHChain.from_dict({**arm.to_dict(), "lower": [1.0] * 6, "upper": [0.0] * 6})
    assert invert(arm.fk(q)).shape == (4, 4)


def test_joint_index_picks_the_chains_joints_in_any_order():
    """One rule for joint_states (hand_eye node, process, calibrate handeye --bag): extra
    joints ignored, any order, and a message whose names change (same count, new order) is
    indexed again, not read through the previous message's index."""
    from eye_in_hand.core.kinematics import JointIndex, MissingJointsError
    from eye_in_hand.errors import InputError

    idx = JointIndex(("a", "b", "c"))
    assert idx.positions(["c", "x", "a", "b"], [3.0, 9.0, 1.0, 2.0]).tolist() == [1.0, 2.0, 3.0]
    # same count, another order: must not reuse the first index
    assert idx.positions(["b", "a", "x", "c"], [2.0, 1.0, 9.0, 3.0]).tolist() == [1.0, 2.0, 3.0]
    assert idx.positions(("a", "b", "c"), (1.0, 2.0, 3.0)).tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(MissingJointsError, match=r"lacks joint\(s\) c \(has a, b, x\)"):
        idx.positions(["a", "b", "x"], [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="2 positions for 3 names"):
        idx.positions(["a", "b", "c"], [1.0, 2.0])
    with pytest.raises(InputError, match="not finite"):
        idx.positions(["a", "b", "c"], [1.0, float("nan"), 3.0])
    # a NaN in a joint the chain does not use is no error
    assert idx.positions(["a", "b", "c", "x"], [1.0, 2.0, 3.0, float("nan")]).tolist() == [
        1.0, 2.0, 3.0]
