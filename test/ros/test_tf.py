"""eye_in_hand.ros.tf: TFMessage <-> TfBuffer, the built tf2_msgs type, arm edges for /tf."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.tf import TfBuffer
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.ros.tf import add_tf_message, chain_tf_edges, have_tf2_msgs, make_tf_message

needs_tf2 = pytest.mark.skipif(not have_tf2_msgs(), reason="tf2_msgs not built (make venv)")


@needs_tf2
def test_built_tf2_msgs_has_jazzy_type_hash(ros_context):
    """The venv-built TFMessage is Jazzy's type: real tf2 nodes and bags interoperate."""
    import rclpy
    from rosbags.typesys import Stores, get_typestore
    from tf2_msgs.msg import TFMessage

    node = rclpy.create_node("tf_hash", context=ros_context)
    try:
        node.create_publisher(TFMessage, "tf_hash_check", 1)
        topic = f"{node.get_namespace().rstrip('/')}/tf_hash_check"
        info = node.get_publishers_info_by_topic(topic)
        want = get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage")
        assert str(info[0].topic_type_hash) == want
    finally:
        node.destroy_node()


@needs_tf2
def test_message_round_trip_through_cdr_and_rosbags():
    """make_tf_message -> CDR (rclpy) -> rosbags message -> add_tf_message gives the same
    transforms: what a bag of /tf carries is what the buffer gets."""
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_typestore

    A = from_rotvec([0.1, 0.2, -0.3], (0.5, -0.1, 0.2))
    B = from_rotvec([-0.4, 0.0, 0.1], (0.0, 0.3, 0.0))
    msg = make_tf_message([("base_link", "link1", 1_000_000_123, A),
                           ("link1", "tool0", 1_000_000_123, B)])
    ts = get_typestore(Stores.ROS2_JAZZY)
    decoded = ts.deserialize_cdr(serialize_message(msg), "tf2_msgs/msg/TFMessage")
    buf = TfBuffer()
    added, problems = add_tf_message(buf, decoded, static=False)
    assert (added, problems) == (2, [])
    np.testing.assert_allclose(buf.lookup("base_link", "tool0", 1_000_000_123, 0), A @ B,
                               atol=1e-12)


def test_bad_entries_are_skipped_and_named():
    from types import SimpleNamespace as NS

    def tr(parent, child, w):
        return NS(header=NS(frame_id=parent, stamp=NS(sec=1, nanosec=0)), child_frame_id=child,
                  transform=NS(translation=NS(x=0.0, y=0.0, z=0.0),
                               rotation=NS(x=0.0, y=0.0, z=0.0, w=w)))

    buf = TfBuffer()
    added, problems = add_tf_message(
        buf, NS(transforms=[tr("a", "b", 1.0), tr("b", "c", 0.0), tr("c", "c", 1.0)]),
        static=True)
    assert added == 1 and len(problems) == 2
    assert "transforms[1] (b -> c)" in problems[0] and "rotation" in problems[0]
    assert "transforms[2]" in problems[1] and "own parent" in problems[1]
    assert add_tf_message(buf, NS(), static=False)[0] == 0


def test_chain_edges_compose_to_forward_kinematics():
    chain = DHChain.ur5e()
    q = np.array([0.3, -1.1, 1.4, -0.2, 0.7, -0.5])
    edges = chain_tf_edges(chain, q)
    assert [e[0] for e in edges][0] == chain.base_frame
    # ur_description's fixed base_link -> base (Rz(pi)) first, then one edge per joint
    assert [e[1] for e in edges] == [chain.dh_frame, *chain.link_names]
    buf = TfBuffer()
    for p, c, T in edges:
        buf.set_transform(p, c, 7, T)
    np.testing.assert_allclose(buf.lookup(chain.base_frame, chain.tip_frame, 7, 0), chain.fk(q),
                               atol=1e-12)
