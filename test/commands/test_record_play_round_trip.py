"""record -> play round trip across separate processes, over DDS.

publisher process -> ``eye-in-hand record`` process (stopped with SIGTERM) -> bag ->
``eye-in-hand play`` process -> subscriber process. The payload bytes and their order per topic
must survive every hop.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from eye_in_hand.io.bags import bag_info, iter_messages  # noqa: E402

N = 30

# Publishes N String and N Image messages as serialized bytes (random payloads from a seeded
# rng) once both topics have a subscriber; writes the expected bytes as hex to argv[2].
PUBLISHER = r"""
import json, sys, time
import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import String

prefix, out, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
rclpy.init()
node = rclpy.create_node("round_trip_publisher")
# transient local with a history that holds every message: a reader whose side of the
# DDS match completes a moment after ours still gets the first messages (volatile would not)
qos = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
pubs = {f"{prefix}/chatter": node.create_publisher(String, f"{prefix}/chatter", qos),
        f"{prefix}/image": node.create_publisher(Image, f"{prefix}/image", qos)}
deadline = time.monotonic() + 30
while any(p.get_subscription_count() == 0 for p in pubs.values()):
    if time.monotonic() > deadline:
        sys.exit("no subscriber")
    rclpy.spin_once(node, timeout_sec=0.02)
rng = np.random.default_rng(7)
sent = {t: [] for t in pubs}
for i in range(n):
    s = serialize_message(String(data="m%d-%s" % (i, rng.integers(1 << 30))))
    img = Image(height=2, width=3, encoding="mono8", step=3,
                data=rng.integers(0, 256, 6, dtype=np.uint8).tobytes())
    img.header.frame_id = "cam"
    img.header.stamp.sec = i
    for topic, raw in ((f"{prefix}/chatter", s), (f"{prefix}/image", serialize_message(img))):
        pubs[topic].publish(raw)
        sent[topic].append(raw.hex())
    time.sleep(0.01)
# stay until everything is acknowledged by the reliable subscribers
for p in pubs.values():
    p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
json.dump(sent, open(out, "w"))
node.destroy_node()
rclpy.shutdown()
"""

# Raw subscriber: collects N messages per topic (or gives up after 40 s), prints JSON hex.
SUBSCRIBER = r"""
import json, sys, time
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import Image
from std_msgs.msg import String

prefix, n = sys.argv[1], int(sys.argv[2])
rclpy.init()
node = rclpy.create_node("round_trip_subscriber")
got = {f"{prefix}/chatter": [], f"{prefix}/image": []}
for topic, cls in ((f"{prefix}/chatter", String), (f"{prefix}/image", Image)):
    node.create_subscription(cls, topic, lambda raw, t=topic: got[t].append(raw.hex()),
                             QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL),
                             raw=True)
deadline = time.monotonic() + 40
while any(len(v) < n for v in got.values()) and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
print(json.dumps(got))
node.destroy_node()
rclpy.shutdown()
"""


def _pad4(hexbytes: str) -> str:
    return hexbytes + "00" * (-(len(hexbytes) // 2) % 4)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "eye_in_hand.cli", *args]


def test_record_then_play_across_processes(tmp_path: Path, ros_env: dict[str, str],
                                           namespace: str) -> None:
    prefix = namespace
    bag = tmp_path / "bag"
    sent_file = tmp_path / "sent.json"
    recorder = subprocess.Popen(
        _cli("record", "-o", str(bag), f"{prefix}/chatter", f"{prefix}/image",
             "--discovery-period", "0.05"),
        env=ros_env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        publisher = subprocess.run(
            [sys.executable, "-c", PUBLISHER, prefix, str(sent_file), str(N)],
            env=ros_env, capture_output=True, text=True, timeout=60)
        assert publisher.returncode == 0, publisher.stderr
    finally:
        recorder.send_signal(signal.SIGTERM)  # the bag must stay valid
        _, rec_err = recorder.communicate(timeout=30)
    assert recorder.returncode == 0, rec_err
    assert "Traceback" not in rec_err
    sent = json.loads(sent_file.read_text())

    info = bag_info(bag)
    assert {t: (i.msgtype, i.count) for t, i in info.topics.items()} == {
        f"{prefix}/chatter": ("std_msgs/msg/String", N),
        f"{prefix}/image": ("sensor_msgs/msg/Image", N)}
    recorded: dict[str, list[str]] = {t: [] for t in sent}
    stamps = []
    for topic, _msgtype, stamp, raw in iter_messages(bag):
        recorded[topic].append(raw.hex())
        stamps.append(stamp)
    # bytes and order; DDS pads each serialized payload with zeros to a multiple of 4 bytes
    assert recorded == {t: [_pad4(h) for h in v] for t, v in sent.items()}
    assert stamps == sorted(stamps) and stamps[-1] - stamps[0] > 0

    subscriber = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, prefix, str(N)],
                                  env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
    try:
        player = subprocess.run(
            _cli("play", str(bag), "--rate", "4", "--wait-for-subscribers", "30"),
            env=ros_env, capture_output=True, text=True, timeout=90)
        assert player.returncode == 0, player.stderr
        assert f"published {2 * N} message(s)" in player.stderr
        out, err = subscriber.communicate(timeout=60)
    finally:
        if subscriber.poll() is None:
            subscriber.kill()
            subscriber.communicate()
    assert subscriber.returncode == 0, err
    assert json.loads(out) == recorded  # exactly the stored bytes, in order
    # the publisher's offer is stored, as ros2 bag record stores it: DDS discovery carries
    # reliability and durability but not history depth (0, history unknown)
    offered = info.topics[f"{prefix}/chatter"].offered_qos
    assert [(q.reliability, q.durability, q.history, q.depth) for q in offered] == [
        ("reliable", "transient_local", "unknown", 0)]
