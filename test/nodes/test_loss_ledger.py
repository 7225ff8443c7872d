"""Issue #14: a replay at 10x through detect_triangulate and hand_eye loses nothing uncounted.

A simulated localization bag (24 pairs, 320x240) is played at ten times its rate (the bag_player
node, as ``eye-in-hand play --rate 10``) into ``detect_triangulate`` and ``hand_eye``, in
process. At the end every left image the player published is accounted for by the nodes'
diagnostics counters:

    published  = left_frames (+ lost on the way to detect_triangulate)
    left_frames = sync_pairs + sync_unpaired_left + sync_pending_left
    sync_pairs  = dropped_pairs + queued + no_target + failed_pairs + points_published
    points_published = hand_eye points + lost between the nodes
    hand_eye points  = poses_published + rejected + pending

and every target (issue #12): each located target is published or refused, each marker frame
and target point reaches ``hand_eye``, and each target it lists is located or counted:

    targets_located = target_points_published + targets_refused
    marker_frames   = points_published + no_target = hand_eye target_frames
    target_points   = target_poses_published + targets_rejected + targets_pending
"""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye  # noqa: E402
from eye_in_hand.nodes.bag_player import BagPlayer  # noqa: E402
from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode  # noqa: E402
from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402
from eye_in_hand.sim import World  # noqa: E402
from eye_in_hand.sim.output import write_bag  # noqa: E402

LEFT, RIGHT, EE = "/stereo/left/image_raw", "/stereo/right/image_raw", "/ee_pose"


def ledger(player: BagPlayer, detect: DetectTriangulateNode, hand_eye: HandEyeNode
           ) -> dict[str, int]:
    """Every figure of the reconciliation, from the nodes' diagnostics."""
    d = detect.diag.snapshot()
    h = hand_eye.diag.snapshot()
    c, g = d.counters, d.gauges
    return {
        "published_left": player.published[LEFT], "published_right": player.published[RIGHT],
        "left_frames": c["left_frames"], "right_frames": c["right_frames"],
        "sync_pairs": c["sync_pairs"], "sync_unpaired_left": c["sync_unpaired_left"],
        "sync_unpaired_right": c["sync_unpaired_right"],
        "sync_pending_left": int(g.get("sync_pending_left", 0)),
        "sync_pending_right": int(g.get("sync_pending_right", 0)),
        "dropped_pairs": c["dropped_pairs"], "queued": int(g.get("queued", 0)),
        "no_target": c["no_target"], "failed_pairs": c["failed_pairs"],
        "points_published": c["points_published"], "points_received": h.counters["points"],
        "poses_published": h.counters["poses_published"], "rejected": h.counters["rejected"],
        "pending": len(hand_eye.pipeline.points),
        "published_ee": player.published[EE], "robot_poses": h.counters["robot_poses"],
        **{k: v for k, v in h.counters.items() if k.startswith(("refused.", "pose_buffer"))},
        "targets_located": c["targets_located"],
        "target_points_published": c["target_points_published"],
        "targets_refused": c["targets_refused"], "marker_frames": c["marker_frames"],
        "target_frames": h.counters["target_frames"],
        "target_points": h.counters["target_points"],
        "target_points_received": h.counters["target_points_received"],
        "target_poses_published": h.counters["target_poses_published"],
        "targets_rejected": h.counters["targets_rejected"],
        "targets_pending": hand_eye.pipeline.targets_waiting,
        **{k: v for k, v in h.counters.items() if k.startswith("target_refused.") and v},
    }


def test_replay_at_10x_reconciles(tmp_path, ros_context, executor, namespace, spin_until):
    world = World.default().with_image_size(320, 240)
    bag = tmp_path / "loc"
    summary = write_bag(world, bag, scenario="localization", frames=24, seed=3)
    n = summary.counts[LEFT] if LEFT in summary.counts else summary.n_images
    world.rig.save(tmp_path / "calib")
    he = tmp_path / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    remap = lambda *pairs: ["--ros-args"] + [a for p in pairs for a in ("-r", p)]  # noqa: E731
    detect = DetectTriangulateNode(
        context=ros_context, namespace=namespace,
        parameter_overrides=[Parameter("calibration_dir", value=str(tmp_path / "calib"))],
        cli_args=remap(f"left/image_raw:={LEFT}", f"right/image_raw:={RIGHT}"))
    hand_eye = HandEyeNode(context=ros_context, namespace=namespace,
                           parameter_overrides=[Parameter("hand_eye_file", value=str(he))],
                           cli_args=remap(f"ee_pose:={EE}"))
    player = BagPlayer(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(bag)), Parameter("rate", value=10.0),
        Parameter("topics", Parameter.Type.STRING_ARRAY, [LEFT, RIGHT, EE]),
        Parameter("wait_for_subscribers", value=20.0)])
    for node in (detect, hand_eye, player):
        executor.add_node(node)
    assert spin_until(executor, lambda: detect.count_publishers("target/point") > 0
                      and hand_eye.count_subscribers("target/point") > 0, 10.0)
    assert spin_until(executor, lambda: detect.targets.pub_point.get_subscription_count() > 0,
                      10.0)
    # hand_eye found the per-target topic in the graph and listens to the frame lists
    assert spin_until(executor, lambda: detect.targets.pub_markers.get_subscription_count() > 0
                      and all(cov.get_subscription_count() > 0
                              for _, cov in detect.targets.per_target.values()), 10.0)
    player.start()
    assert spin_until(executor, lambda: player.finished, 60.0)

    def settled():
        s = ledger(player, detect, hand_eye)
        return (s["queued"] == 0 and s["pending"] == 0 and s["left_frames"] == s["sync_pairs"]
                + s["sync_unpaired_left"] + s["sync_pending_left"]
                and s["points_published"] == s["points_received"]
                and s["targets_pending"] == 0 and s["marker_frames"] == s["target_frames"]
                and s["sync_pairs"] == s["dropped_pairs"] + s["no_target"] + s["failed_pairs"]
                + s["points_published"])

    spin_until(executor, settled, 10.0)
    s = ledger(player, detect, hand_eye)
    print("\n10x ledger:", s)
    assert s["published_left"] == s["published_right"] == n
    lost_to_detect = s["published_left"] - s["left_frames"]
    lost_between = s["points_published"] - s["points_received"]
    # every frame accounted for, at each stage
    assert s["left_frames"] == s["sync_pairs"] + s["sync_unpaired_left"] + s["sync_pending_left"]
    assert s["right_frames"] == (s["sync_pairs"] + s["sync_unpaired_right"]
                                 + s["sync_pending_right"])
    assert s["sync_pairs"] == (s["dropped_pairs"] + s["queued"] + s["no_target"]
                               + s["failed_pairs"] + s["points_published"])
    assert s["points_received"] == s["poses_published"] + s["rejected"] + s["pending"]
    # and in total: input pairs = published poses + every counter
    assert n == (s["poses_published"] + s["rejected"] + s["pending"] + lost_between
                 + s["dropped_pairs"] + s["queued"] + s["no_target"] + s["failed_pairs"]
                 + s["sync_unpaired_left"] + s["sync_pending_left"] + lost_to_detect)
    # the reliable hop between the nodes loses nothing, and most frames make it through
    assert lost_between == 0
    assert s["poses_published"] > 0
    # every target: published or refused, nothing lost between the nodes, located or counted
    assert s["targets_located"] == s["target_points_published"] + s["targets_refused"]
    assert s["marker_frames"] == s["points_published"] + s["no_target"] == s["target_frames"]
    assert s["target_points_received"] == s["target_points_published"] == s["target_points"]
    assert s["target_points"] == (s["target_poses_published"] + s["targets_rejected"]
                                  + s["targets_pending"])
    assert s["target_poses_published"] > 0
