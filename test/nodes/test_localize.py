"""The composed chain (``localize``: detect_triangulate + hand_eye in one process, the located
points handed over in memory) publishes what the two separate nodes publish over DDS.

The same three stereo pairs (two targets, one leaving the view) and robot poses go through the
nodes as ``eye-in-hand launch`` lays them out (detect_triangulate in ``<ns>/stereo``, its
outputs remapped to the root), once as two nodes talking over DDS and once as
:class:`~eye_in_hand.nodes.localize.LocalizationChain`; every output of hand_eye is compared
field by field, and the two hand_eyes' counters are equal.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from eye_in_hand.launcher import NODES, Launcher, node_command, node_ros_args  # noqa: E402
from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode  # noqa: E402
from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402
from eye_in_hand.nodes.localize import LocalizationChain  # noqa: E402
from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS  # noqa: E402

from .test_every_target import (  # noqa: E402
    BOTH,
    CAM,
    PERIOD_NS,
    RED_ONLY,
    RIG,
    T0,
    TARGETS,
    _hand_eye_file,
    _robot_pose,
)

SPECS = {s.name: s for s in NODES}
#: hand_eye's outputs, relative to the root namespace
OUTPUTS = [(PoseStamped, "target/pose"), (PoseWithCovarianceStamped, "target/pose_cov"),
           (PoseArray, "target/poses"), (MarkerArray, "target/markers")] + [
    (t, f"target/{n}/{s}") for n in TARGETS
    for t, s in ((PoseStamped, "pose"), (PoseWithCovarianceStamped, "pose_cov"))]


def _parameters(tmp_path) -> dict[str, list[Parameter]]:
    RIG.save(tmp_path / "calib")
    return {
        "detect_triangulate": [
            Parameter("calibration_dir", value=str(tmp_path / "calib")),
            Parameter("frame_id", value=CAM), Parameter("sync.slop_s", value=0.0),
            Parameter("target_names", value=["red", "green"]),
            Parameter("targets.green.lower", value=[45, 120, 70]),
            Parameter("targets.green.upper", value=[75, 255, 255])],
        "hand_eye": [
            Parameter("hand_eye_file", value=str(_hand_eye_file(tmp_path))),
            Parameter("robot_sigma_pos_m", value=0.0005),
            Parameter("robot_sigma_rot_rad", value=0.001),
            Parameter("target_frame", value="target"),
            Parameter("discovery_period_s", value=0.1)]}


def _run(composed: bool, tmp_path, context, executor, ns, spin_until):
    """Replay the pairs through one layout; hand_eye's outputs by topic, and its counters."""
    params = _parameters(tmp_path)
    if composed:
        chain = LocalizationChain(ns, parameters=params, context=context)
        nodes = list(chain.nodes)
        detect, hand_eye = chain.detect, chain.hand_eye
    else:
        def cli(name):
            return ["--ros-args", *node_ros_args(SPECS[name], root_namespace=ns)]
        detect = DetectTriangulateNode(context=context, cli_args=cli("detect_triangulate"),
                                       parameter_overrides=params["detect_triangulate"])
        hand_eye = HandEyeNode(context=context, cli_args=cli("hand_eye"),
                               parameter_overrides=params["hand_eye"])
        nodes = [detect, hand_eye]
    io = Node("io", context=context, namespace=ns)
    for n in (*nodes, io):
        executor.add_node(n)
    pub_l = io.create_publisher(Image, "stereo/left/image_raw", SENSOR_QOS)
    pub_r = io.create_publisher(Image, "stereo/right/image_raw", SENSOR_QOS)
    pub_ee = io.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
    got: dict[str, list] = {topic: [] for _, topic in OUTPUTS}
    for msg_type, topic in OUTPUTS:
        io.create_subscription(msg_type, topic,
                               lambda m, t=topic: got[t].append(m),
                               RESULT_QOS)
    def ready() -> bool:
        return bool(pub_l.get_subscription_count() and pub_ee.get_subscription_count()
                    and all(io.count_publishers(t) for _, t in OUTPUTS)
                    and (composed or set(hand_eye.targets.subs) == set(TARGETS)))

    assert spin_until(executor, ready, 15.0)
    spin_until(executor, lambda: False, 0.3)    # every subscription matched both ways
    frames = [BOTH, RED_ONLY, BOTH]
    for k, (left, right) in enumerate(frames):
        stamp = T0 + k * PERIOD_NS
        for dt in (-10_000_000, 10_000_000):
            pub_ee.publish(matrix_to_pose_stamped(_robot_pose(stamp + dt), stamp_ns=stamp + dt,
                                                  frame_id="base_link"))
        pub_l.publish(numpy_to_image(left, "bgr8", stamp_ns=stamp, frame_id=CAM))
        pub_r.publish(numpy_to_image(right, "bgr8", stamp_ns=stamp, frame_id=CAM))
        assert spin_until(executor, lambda k=k: len(got["target/poses"]) == k + 1, 15.0), (
            detect.diag.snapshot().counters, hand_eye.diag.snapshot().counters)
    spin_until(executor, lambda: False, 0.3)    # anything extra would arrive now
    counters = dict(hand_eye.diag.snapshot().counters)
    for n in (*nodes, io):
        executor.remove_node(n)
    if composed:
        chain.destroy()
    else:
        for n in nodes:
            n.destroy_node()
    io.destroy_node()
    return got, counters


def test_composed_chain_publishes_what_the_separate_nodes_publish(
        tmp_path, ros_context, executor, namespace, spin_until):
    separate, sep_counters = _run(False, tmp_path, ros_context, executor, namespace + "_s",
                                  spin_until)
    composed, comp_counters = _run(True, tmp_path, ros_context, executor, namespace + "_c",
                                   spin_until)
    assert [len(separate[t]) for _, t in OUTPUTS] == [3, 3, 3, 3, 3, 3, 2, 2]
    for _, topic in OUTPUTS:     # every field equal (the CDR padding bytes are not defined)
        assert composed[topic] == separate[topic], topic
    assert comp_counters == sep_counters
    assert comp_counters["poses_published"] == 3
    assert comp_counters["target_poses_published"] == 5


def test_composed_chain_refuses_points_in_another_frame(tmp_path, ros_context, executor,
                                                       namespace, spin_until):
    """The in-memory hand-off keeps hand_eye's checks: points in another camera frame are
    refused and counted, as they are from the topics."""
    params = _parameters(tmp_path)
    params["hand_eye"].append(Parameter("camera_frame", value="other_frame"))
    chain = LocalizationChain(namespace, parameters=params, context=ros_context)
    io = Node("io", context=ros_context, namespace=namespace)
    for n in (*chain.nodes, io):
        executor.add_node(n)
    pub_l = io.create_publisher(Image, "stereo/left/image_raw", SENSOR_QOS)
    pub_r = io.create_publisher(Image, "stereo/right/image_raw", SENSOR_QOS)
    assert spin_until(executor, lambda: pub_l.get_subscription_count() > 0, 15.0)
    pub_l.publish(numpy_to_image(BOTH[0], "bgr8", stamp_ns=T0, frame_id=CAM))
    pub_r.publish(numpy_to_image(BOTH[1], "bgr8", stamp_ns=T0, frame_id=CAM))
    counters = chain.hand_eye.diag.snapshot().counters
    assert spin_until(executor, lambda: chain.hand_eye.diag.snapshot().counters.get(
        "targets_rejected", 0) == 2, 15.0), counters
    c = chain.hand_eye.diag.snapshot().counters
    assert c["points"] == 1 and c["refused.point_frame"] == 1 and c["rejected"] == 1
    assert c["target_refused.point_frame"] == 2 and c.get("poses_published", 0) == 0
    assert "bad_target_point" in chain.hand_eye.diag.causes   # each target's point refused too
    assert np.isfinite(list(c.values())).all()
    for n in (*chain.nodes, io):
        executor.remove_node(n)
    chain.destroy()
    io.destroy_node()


def test_launcher_runs_the_pair_as_one_process(tmp_path):
    """``--composed``: one process for detect_triangulate + hand_eye, stereo_capture as it was,
    the string overrides passed through; asking for it without both nodes is refused."""
    params = tmp_path / "p.yaml"
    params.write_text("{}\n")
    launcher = Launcher(params, composed=True, overrides={
        "detect_triangulate": [("calibration_dir", "/c d")],
        "hand_eye": [("hand_eye_file", "/h")]})
    assert [s.name for s in launcher.specs] == ["stereo_capture", "localize"]
    cmd = node_command(launcher.specs[1], params, root_namespace="/r",
                       composed_overrides=launcher.overrides)
    assert cmd[1:] == ["-u", "-m", "eye_in_hand.nodes.localize", "--namespace", "/r",
                       "--set", "detect_triangulate.calibration_dir:=/c d",
                       "--set", "hand_eye.hand_eye_file:=/h",
                       "--ros-args", "--params-file", str(params)]
    with pytest.raises(Exception, match="needs both detect_triangulate and hand_eye"):
        Launcher(params, ["stereo_capture", "hand_eye"], composed=True)
    bad = subprocess.run([sys.executable, "-m", "eye_in_hand.nodes.localize", "--set", "x=1"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "expected NODE.NAME:=VALUE" in bad.stderr
