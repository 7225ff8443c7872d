"""Tests of eye_in_hand.core.tf: the TF buffer (chains, static frames, interpolation, gaps)."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.localization import Localizer
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.tf import STATIC_NEWEST_NS, TfBuffer, TfPoseView
from eye_in_hand.core.transforms import from_rotvec, interpolate, invert, rotation_angle
from eye_in_hand.errors import InputError, LocalizationError

MS = 1_000_000
GAP = 50 * MS


def _joint(angle: float, axis=(0.0, 0.0, 1.0), t=(0.0, 0.0, 0.1)) -> np.ndarray:
    return from_rotvec(np.asarray(axis, dtype=float) * angle, t)


def _arm(buf: TfBuffer, stamps, static_tool: np.ndarray) -> dict[int, np.ndarray]:
    """A 3-joint arm as robot_state_publisher publishes it: base_link -> link1 -> link2 ->
    flange on /tf (all joints at one stamp), flange -> tool0 on /tf_static. Returns the true
    base_T_tool0 at each stamp."""
    truth = {}
    buf.set_transform("flange", "tool0", 0, static_tool, static=True)
    for s in stamps:
        q = np.array([0.3, -0.2, 0.5]) * np.sin(s / 1e9) + np.array([0.1, 0.2, 0.3])
        e1 = _joint(q[0], (0, 0, 1), (0.0, 0.0, 0.15))
        e2 = _joint(q[1], (0, 1, 0), (0.0, 0.1, 0.3))
        e3 = _joint(q[2], (1, 0, 0), (0.25, 0.0, 0.0))
        buf.set_transform("base_link", "link1", s, e1)
        buf.set_transform("link1", "link2", s, e2)
        buf.set_transform("/link2", "flange", s, e3)        # a leading '/' is ignored
        truth[s] = e1 @ e2 @ e3 @ static_tool
    return truth


TOOL = from_rotvec([0.0, 0.0, np.pi / 2], (0.0, 0.0, 0.05))


def test_chain_through_intermediate_and_static_frames_at_a_sample_stamp():
    buf = TfBuffer()
    truth = _arm(buf, [0, 10 * MS, 20 * MS], TOOL)
    T = buf.lookup("base_link", "tool0", 10 * MS, GAP)
    np.testing.assert_allclose(T, truth[10 * MS], atol=1e-12)
    # the inverse lookup gives the inverse transform
    np.testing.assert_allclose(buf.lookup("tool0", "base_link", 10 * MS, GAP),
                               invert(truth[10 * MS]), atol=1e-12)
    assert buf.parent("tool0") == "flange" and buf.is_static("tool0")
    assert not buf.is_static("flange")
    assert buf.frames() == ["base_link", "flange", "link1", "link2", "tool0"]


def test_interpolates_every_edge_at_the_image_stamp():
    buf = TfBuffer()
    stamps = [0, 10 * MS, 20 * MS]
    _arm(buf, stamps, TOOL)
    s = 13 * MS
    # expected: each edge interpolated between its samples at 10 and 20 ms, then chained
    parts = []
    for parent, child in (("base_link", "link1"), ("link1", "link2"), ("link2", "flange")):
        a = buf.lookup(parent, child, 10 * MS, GAP)
        b = buf.lookup(parent, child, 20 * MS, GAP)
        parts.append(interpolate(s, 10 * MS, a, 20 * MS, b))
    expected = parts[0] @ parts[1] @ parts[2] @ TOOL
    got = buf.lookup("base_link", "tool0", s, GAP)
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # and it is strictly between the two sample poses, not snapped to either
    a = buf.lookup("base_link", "tool0", 10 * MS, GAP)
    b = buf.lookup("base_link", "tool0", 20 * MS, GAP)
    d_a = rotation_angle(a[:3, :3].T @ got[:3, :3])
    d_b = rotation_angle(b[:3, :3].T @ got[:3, :3])
    assert d_a > 1e-6 and d_b > 1e-6


def test_same_answer_as_a_pose_buffer_of_the_composed_chain_on_one_edge():
    """With a single dynamic edge, TF lookup is exactly the PoseBuffer lookup."""
    buf, pb = TfBuffer(), PoseBuffer(100)
    for k, s in enumerate(range(0, 100 * MS, 10 * MS)):
        T = _joint(0.05 * k, (0.3, 0.4, 0.866), (0.01 * k, 0.0, 0.2))
        buf.set_transform("base_link", "tool0", s, T)
        pb.add(s, T)
    for s in (5 * MS, 33 * MS + 7, 90 * MS):
        np.testing.assert_allclose(buf.lookup("base_link", "tool0", s, GAP), pb.lookup(s, GAP),
                                   atol=1e-15)


def test_no_extrapolation_and_gap_limit():
    buf = TfBuffer()
    _arm(buf, [0, 10 * MS, 100 * MS], TOOL)
    with pytest.raises(LocalizationError, match="newer than the newest"):
        buf.lookup("base_link", "tool0", 100 * MS + 1, GAP)
    with pytest.raises(LocalizationError, match="older than the buffer"):
        buf.lookup("base_link", "tool0", -1, GAP)
    # 10 -> 100 ms is a 90 ms bracket: refused at 50 ms, accepted at 100 ms
    with pytest.raises(LocalizationError, match="90.000 ms apart"):
        buf.lookup("base_link", "tool0", 50 * MS, GAP)
    buf.lookup("base_link", "tool0", 50 * MS, 100 * MS)
    # the error names the edge that has the gap
    with pytest.raises(LocalizationError, match="link2 -> flange"):
        buf.lookup("base_link", "tool0", 50 * MS, GAP)


def test_one_stale_edge_blocks_the_chain_and_newest_ns_is_the_slowest_edge():
    buf = TfBuffer()
    _arm(buf, [0, 10 * MS, 20 * MS], TOOL)
    buf.set_transform("base_link", "link1", 30 * MS, _joint(0.4))   # only one edge advances
    assert buf.newest_ns("base_link", "tool0") == 20 * MS
    assert buf.newest_ns("base_link", "link1") == 30 * MS
    assert buf.oldest_ns("base_link", "tool0") == 0
    with pytest.raises(LocalizationError, match="link2 -> flange"):
        buf.lookup("base_link", "tool0", 25 * MS, GAP)
    assert buf.newest_ns("flange", "tool0") == STATIC_NEWEST_NS
    assert buf.newest_ns("base_link", "nowhere") is None


def test_static_only_chain_answers_at_any_stamp():
    buf = TfBuffer()
    buf.set_transform("tool0", "camera_link", 0, TOOL, static=True)
    buf.set_transform("camera_link", "camera_left_optical_frame", 5, _joint(0.2), static=True)
    for s in (-10**12, 0, 10**15):
        np.testing.assert_allclose(buf.lookup("tool0", "camera_left_optical_frame", s, 0),
                                   TOOL @ _joint(0.2), atol=1e-12)


def test_lookup_between_siblings_goes_through_the_common_ancestor():
    buf = TfBuffer()
    A, B = _joint(0.3, t=(1.0, 0, 0)), _joint(-0.7, (1, 0, 0), (0, 2.0, 0))
    buf.set_transform("world", "base_link", 0, A, static=True)
    buf.set_transform("world", "table", 0, B, static=True)
    np.testing.assert_allclose(buf.lookup("base_link", "table", 0, 0), invert(A) @ B,
                               atol=1e-12)


def test_unknown_and_unconnected_frames_are_clear_errors():
    buf = TfBuffer()
    buf.set_transform("base_link", "tool0", 0, np.eye(4), static=True)
    buf.set_transform("map", "odom", 0, np.eye(4), static=True)
    with pytest.raises(LocalizationError, match="'camera' is not in the TF tree"):
        buf.lookup("base_link", "camera", 0, GAP)
    with pytest.raises(LocalizationError, match="not connected"):
        buf.lookup("base_link", "odom", 0, GAP)


def test_bad_transforms_are_refused_and_counted_buffer_unchanged():
    buf = TfBuffer()
    buf.set_transform("base_link", "tool0", 0, np.eye(4))
    bad_rot = np.eye(4)
    bad_rot[0, 0] = 2.0
    for args, match in ((("base_link", "tool0", 1, bad_rot), "orthonormal|rotation"),
                        (("", "tool0", 1, np.eye(4)), "empty frame id"),
                        (("tool0", "tool0", 1, np.eye(4)), "its own parent"),
                        (("tool0", "base_link", 1, np.eye(4)), "close a loop"),
                        (("base_link", "tool0", 1.5, np.eye(4)), "int nanosecond")):
        with pytest.raises(InputError, match=match):
            buf.set_transform(*args)
    assert buf.stats.rejected == 5 and buf.stats.transforms == 1
    np.testing.assert_array_equal(buf.lookup("base_link", "tool0", 0, 0), np.eye(4))
    with pytest.raises(InputError, match="max_gap_ns"):
        buf.lookup("base_link", "tool0", 0, -1)


def test_reparenting_starts_a_new_history_and_clear_keeps_static():
    buf = TfBuffer()
    buf.set_transform("base_link", "tool0", 0, np.eye(4))
    buf.set_transform("base_link", "tool0", 10, np.eye(4))
    buf.set_transform("world", "base_link", 0, np.eye(4), static=True)
    buf.set_transform("world", "tool0", 20, _joint(0.1))
    assert buf.stats.reparented == 1 and buf.parent("tool0") == "world"
    with pytest.raises(LocalizationError):
        buf.lookup("world", "tool0", 10, GAP)   # the old history is gone
    buf.clear()
    assert buf.frames() == ["base_link", "world"]
    assert buf.newest_ns("world", "base_link") == STATIC_NEWEST_NS


def test_capacity_bounds_every_edge():
    buf = TfBuffer(capacity=3)
    for s in range(10):
        buf.set_transform("base_link", "tool0", s * MS, _joint(0.01 * s))
    assert buf.oldest_ns("base_link", "tool0") == 7 * MS
    with pytest.raises(InputError):
        TfBuffer(capacity=1)


def test_pose_view_drives_a_localizer_like_a_pose_buffer():
    """The Localizer's robot pose from TF, at the image stamp, through a chain."""
    buf = TfBuffer()
    truth = _arm(buf, [0, 10 * MS, 20 * MS, 30 * MS], TOOL)
    ee_T_cam = from_rotvec([0.1, -0.2, 0.05], (0.03, 0.0, 0.08))
    loc = Localizer(ee_T_cam)
    loc.poses = TfPoseView(buf, "/base_link", "tool0")
    p_cam = np.array([0.05, -0.02, 0.6])
    res = loc.locate(20 * MS, p_cam)
    expected = (truth[20 * MS] @ ee_T_cam @ np.append(p_cam, 1.0))[:3]
    np.testing.assert_allclose(res.point_base, expected, atol=1e-12)
    assert loc.poses.newest_ns == 30 * MS and len(loc.poses) == 1
    with pytest.raises(LocalizationError):
        loc.locate(31 * MS, p_cam)
    with pytest.raises(InputError, match="come from TF"):
        loc.add_robot_pose(40 * MS, np.eye(4))


def test_newest_ns_covers_moving_frames_on_both_sides_of_the_chain():
    """A mobile manipulator: ``map -> odom -> base_link`` (the base moves) and the arm under
    it; a camera stand ``map -> stand -> camera`` that also moves (a pan unit). A lookup
    ``camera <- tool0`` walks the target's side (camera, stand) and the source's side (tool0
    ... base_link, odom) up to ``map``: its newest stamp is the slowest dynamic edge on either
    side, and a lookup just past it on the target's side fails (no extrapolation)."""
    buf = TfBuffer()
    _arm(buf, [0, 10 * MS, 20 * MS, 30 * MS], TOOL)
    for s in (0, 10 * MS, 20 * MS, 30 * MS, 40 * MS):
        buf.set_transform("map", "odom", s, _joint(0.01 * s / MS, t=(0.1, 0.0, 0.0)))
        buf.set_transform("odom", "base_link", s, _joint(0.0, t=(0.001 * s / MS, 0.0, 0.0)))
    buf.set_transform("map", "stand", 0, _joint(0.0, t=(2.0, 0.0, 1.0)), static=True)
    for s in (0, 10 * MS, 15 * MS):                      # the pan unit lags
        buf.set_transform("stand", "camera", s, _joint(0.02 * s / MS, (0, 1, 0), (0, 0, 0.1)))
    # target side slowest (15 ms), then the arm (30 ms), then the base (40 ms)
    assert buf.newest_ns("camera", "tool0") == 15 * MS
    assert buf.newest_ns("tool0", "camera") == 15 * MS
    assert buf.newest_ns("stand", "tool0") == 30 * MS
    assert buf.newest_ns("map", "base_link") == 40 * MS
    assert buf.newest_ns("base_link", "map") == 40 * MS    # the moving edges on the target side
    assert buf.oldest_ns("camera", "tool0") == 0
    buf.lookup("camera", "tool0", 15 * MS, GAP)
    with pytest.raises(LocalizationError, match="stand -> camera"):
        buf.lookup("camera", "tool0", 16 * MS, GAP)
    # a view from the moving camera: the localizer waits for what newest_ns says
    view = TfPoseView(buf, "camera", "tool0")
    assert view.newest_ns == 15 * MS
