"""bag_recorder (``eye-in-hand record``) in-process: late topics, --all, QoS, duration, storage."""
from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

from eye_in_hand.errors import BagError, ConfigError  # noqa: E402
from eye_in_hand.io.bags import bag_info, deserialize, iter_messages  # noqa: E402
from eye_in_hand.nodes.bag_recorder import BagRecorder, spin_recorder  # noqa: E402


def _recorder(ros_context, output: Path, topics: list[str] | None = None, **params
              ) -> BagRecorder:
    overrides = [Parameter("output", value=str(output)),
                 Parameter("discovery_period", value=0.05)]
    if topics:
        overrides.append(Parameter("topics", Parameter.Type.STRING_ARRAY, topics))
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return BagRecorder(context=ros_context, parameter_overrides=overrides)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_records_topics_that_appear_later(tmp_path, ros_context, executor, spin_until,
                                          namespace, storage) -> None:
    from std_msgs.msg import String

    topic = f"{namespace}/late"
    rec = _recorder(ros_context, tmp_path / "bag", [topic, f"{namespace}/never"],
                    storage=storage, compression="zstd")
    executor.add_node(rec)
    assert rec.missing_topics == [topic, f"{namespace}/never"]
    # the publisher appears after the recorder started
    pub_node = Node("late_publisher", context=ros_context)
    pub = pub_node.create_publisher(String, topic, 10)
    executor.add_node(pub_node)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 15.0)
    sent = [String(data=f"late {i}") for i in range(10)]
    for msg in sent:
        pub.publish(msg)
    assert spin_until(executor, lambda: rec.received.get(topic, 0) == 10, 15.0)
    assert rec.missing_topics == [f"{namespace}/never"]
    status = rec.diag.build_status()
    values = {kv.key: kv.value for kv in status.values}
    assert values["messages"] == "10" and values["missing_topics"] == "1"
    assert status.level == bytes([1]) and "missing_topics = 1 > 0" in status.message
    rec.close()
    info = bag_info(tmp_path / "bag")
    assert info.storage == storage
    assert {t: i.count for t, i in info.topics.items()} == {topic: 10}
    rows = list(iter_messages(tmp_path / "bag"))
    assert [deserialize(r, m).data for _t, m, _s, r in rows] == [m.data for m in sent]
    # the stored bytes are what DDS delivered: the CDR of the message, zero-padded to 4 bytes
    raw0 = serialize_message(sent[0])
    assert rows[0][3][: len(raw0)] == raw0 and set(rows[0][3][len(raw0):]) <= {0}
    stamps = [s for _t, _m, s, _r in rows]
    assert stamps == sorted(stamps)


def test_all_topics_qos_and_latched_data(tmp_path, ros_context, executor, spin_until,
                                         namespace) -> None:
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import String

    pub_node = Node("qos_publisher", context=ros_context)
    latched = pub_node.create_publisher(String, f"{namespace}/latched", QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    sensor = pub_node.create_publisher(PointStamped, f"{namespace}/sensor", QoSProfile(
        depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
    pub_node.create_publisher(String, f"{namespace}/_hidden/internal", 10)
    latched.publish(String(data="calibration"))  # before the recorder exists
    executor.add_node(pub_node)
    rec = _recorder(ros_context, tmp_path / "bag", **{"all": True})
    executor.add_node(rec)
    assert spin_until(executor, lambda: rec.received.get(f"{namespace}/latched", 0) == 1
                      and sensor.get_subscription_count() > 0, 15.0)
    point = PointStamped()
    point.point.x = 1.5
    assert spin_until(executor, lambda: (sensor.publish(point), rec.received.get(
        f"{namespace}/sensor", 0) >= 3)[1], 15.0)
    rec.close()
    info = bag_info(tmp_path / "bag")
    assert info.topics[f"{namespace}/latched"].offered_qos[0].durability == "transient_local"
    assert info.topics[f"{namespace}/sensor"].offered_qos[0].reliability == "best_effort"
    assert info.topics[f"{namespace}/sensor"].msgtype == "geometry_msgs/msg/PointStamped"
    assert "/rosout" in info.topics  # --all records every topic, like ros2 bag record -a,
    assert f"{namespace}/_hidden/internal" not in info.topics  # except hidden ones


def test_duration_ends_recording_with_a_valid_bag(tmp_path, ros_context, executor,
                                                  namespace) -> None:
    rec = _recorder(ros_context, tmp_path / "bag", [f"{namespace}/x"])
    assert spin_recorder(rec, 0.3, executor) == 0
    assert rec.writer.closed
    info = bag_info(tmp_path / "bag")
    assert info.message_count == 0 and info.topics == {}


def test_bad_parameters(tmp_path, ros_context) -> None:
    with pytest.raises(ConfigError, match="'output' is required"):
        BagRecorder(context=ros_context, parameter_overrides=[
            Parameter("topics", Parameter.Type.STRING_ARRAY, ["/a"])])
    with pytest.raises(ConfigError, match="'topics'"):
        _recorder(ros_context, tmp_path / "a")
    with pytest.raises(ConfigError, match="storage"):
        _recorder(ros_context, tmp_path / "b", ["/a"], storage="rosbag1")
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match="exists already"):
        _recorder(ros_context, tmp_path / "exists", ["/a"])
