"""eye_in_hand.ros.markers: sphere MarkerArrays and PoseArrays, written and read back."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("visualization_msgs")

from eye_in_hand.errors import ConversionError  # noqa: E402
from eye_in_hand.ros.markers import (  # noqa: E402
    Sphere,
    color_range_rgba,
    points_to_pose_array,
    sphere_marker_array,
    spheres_from_marker_array,
)

STAMP = 1_700_000_000_123_456_789


def test_marker_array_clears_first_then_one_sphere_per_target_and_reads_back():
    from visualization_msgs.msg import Marker

    spheres = [Sphere("red", np.array([0.1, -0.2, 0.5]), 0.04, (1.0, 0.0, 0.0, 0.8)),
               Sphere("red_1", np.array([0.3, 0.0, 0.7]), 0.05)]
    msg = sphere_marker_array(spheres, stamp_ns=STAMP, frame_id="cam", lifetime_s=1.5)
    assert msg.markers[0].action == Marker.DELETEALL
    assert [m.ns for m in msg.markers[1:]] == ["red", "red_1"]
    for m in msg.markers[1:]:
        assert m.type == Marker.SPHERE and m.action == Marker.ADD and m.id == 0
        assert (m.lifetime.sec, m.lifetime.nanosec) == (1, 500_000_000)
        assert m.scale.x == m.scale.y == m.scale.z
    stamp, frame, back = spheres_from_marker_array(msg)
    assert (stamp, frame) == (STAMP, "cam")
    assert [s.id for s in back] == ["red", "red_1"]
    for a, b in zip(spheres, back, strict=True):
        assert np.array_equal(a.xyz, b.xyz) and a.diameter_m == b.diameter_m
        assert np.allclose(a.rgba, b.rgba, atol=1e-6)   # float32 colour fields
    empty = sphere_marker_array([], stamp_ns=STAMP, frame_id="cam")
    assert len(empty.markers) == 1 and spheres_from_marker_array(empty) == (STAMP, "cam", [])


@pytest.mark.parametrize("spheres, match", [
    ([Sphere("a", np.array([0.0, np.nan, 1.0]), 0.04)], "centre"),
    ([Sphere("a", np.zeros(3), 0.0)], "diameter"),
    ([Sphere("a", np.zeros(3), 0.04), Sphere("a", np.ones(3), 0.04)], "one id"),
])
def test_bad_spheres_are_refused_with_the_target_named(spheres, match):
    with pytest.raises(ConversionError, match=match):
        sphere_marker_array(spheres, stamp_ns=STAMP, frame_id="cam")


def test_malformed_marker_arrays_are_refused():
    from visualization_msgs.msg import Marker, MarkerArray

    good = sphere_marker_array([Sphere("a", np.zeros(3), 0.04)], stamp_ns=STAMP,
                               frame_id="cam")
    with pytest.raises(ConversionError, match="empty"):
        spheres_from_marker_array(MarkerArray())
    cube = sphere_marker_array([Sphere("a", np.zeros(3), 0.04)], stamp_ns=STAMP,
                               frame_id="cam")
    cube.markers[1].type = Marker.CUBE
    with pytest.raises(ConversionError, match=r"markers\[1\].*SPHERE"):
        spheres_from_marker_array(cube)
    other = sphere_marker_array([Sphere("a", np.zeros(3), 0.04)], stamp_ns=STAMP + 1,
                                frame_id="cam")
    mixed = MarkerArray(markers=list(good.markers) + [other.markers[1]])
    with pytest.raises(ConversionError, match="stamp or frame"):
        spheres_from_marker_array(mixed)
    elsewhere = sphere_marker_array([Sphere("b", np.zeros(3), 0.04)], stamp_ns=STAMP,
                                    frame_id="base_link")
    two_frames = MarkerArray(markers=list(good.markers) + [elsewhere.markers[1]])
    with pytest.raises(ConversionError, match=r"markers\[2\] \(ns 'b'\): stamp or frame"):
        spheres_from_marker_array(two_frames)
    no_id = sphere_marker_array([Sphere("a", np.zeros(3), 0.04)], stamp_ns=STAMP,
                                frame_id="cam")
    no_id.markers[1].ns = ""
    with pytest.raises(ConversionError, match="empty or repeated"):
        spheres_from_marker_array(no_id)


def test_colour_of_a_range_is_its_middle_hue():
    red = color_range_rgba((170, 120, 70), (10, 255, 255))         # wraps around 0
    green = color_range_rgba((45, 120, 70), (75, 255, 255))
    blue = color_range_rgba((100, 120, 70), (140, 255, 255))
    assert red[:3] == pytest.approx((1.0, 0.0, 0.0))
    assert green[:3] == pytest.approx((0.0, 1.0, 0.0))
    assert blue[:3] == pytest.approx((0.0, 0.0, 1.0))
    assert red[3] == 0.8


def test_pose_array_keeps_the_order_the_stamp_and_the_frame():
    pts = [np.array([0.1, 0.2, 0.3]), np.array([-1.0, 0.0, 2.0])]
    msg = points_to_pose_array(pts, stamp_ns=STAMP, frame_id="base_link")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(STAMP, 10**9)
    assert msg.header.frame_id == "base_link"
    got = [(p.position.x, p.position.y, p.position.z) for p in msg.poses]
    assert got == [tuple(p) for p in pts]
    assert all(p.orientation.w == 1.0 for p in msg.poses)
    with pytest.raises(ConversionError, match=r"points\[0\]"):
        points_to_pose_array([np.array([np.inf, 0.0, 0.0])], stamp_ns=STAMP, frame_id="b")
