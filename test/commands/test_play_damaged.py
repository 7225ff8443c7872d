"""bag_player (``eye-in-hand play``) over a bag with a damaged chunk: the rest plays."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from eye_in_hand.io.bags import BagWriter, default_typestore, serialize  # noqa: E402
from eye_in_hand.nodes.bag_player import BagPlayer  # noqa: E402

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
STRING = "std_msgs/msg/String"


def _bag(path: Path, topic: str, n: int = 40) -> list[tuple[int, bytes]]:
    """``n`` 100 kB strings 5 ms apart: about 4 per 1 MiB chunk."""
    store = default_typestore()
    rng = np.random.default_rng(2)
    sent = []
    with BagWriter(path, "mcap", "zstd") as bag:
        bag.add_topic(topic, STRING)
        for i in range(n):
            text = f"{i}:" + rng.integers(97, 123, 250_000, dtype=np.uint8).tobytes().decode()
            raw = serialize(store.types[STRING](data=text), STRING)
            bag.write(topic, T0 + i * 5 * MS, raw)
            sent.append((T0 + i * 5 * MS, raw))
    return sent


def _chunk_data(mcap: Path, k: int) -> tuple[int, int]:
    """(offset, offset of the compressed data) of the ``k``-th chunk record."""
    data = mcap.read_bytes()
    pos, found = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            (n,) = struct.unpack_from("<I", data, pos + 9 + 28)
            found.append((pos, pos + 9 + 32 + n + 8))
        pos += 9 + length
    return found[k]


def test_a_damaged_chunk_is_skipped_logged_and_counted(tmp_path, ros_context, executor,
                                                       spin_until, namespace) -> None:
    topic = f"{namespace}/chatter"
    sent = _bag(tmp_path / "bag", topic)
    mcap = tmp_path / "bag" / "bag.mcap"
    off, data_at = _chunk_data(mcap, 2)
    raw = bytearray(mcap.read_bytes())
    raw[data_at + 30:data_at + 94] = bytes(range(64))
    mcap.write_bytes(bytes(raw))

    got: list[bytes] = []
    collector = Node("collector", context=ros_context)
    collector.create_subscription(
        __import__("std_msgs.msg", fromlist=["String"]).String, topic, got.append,
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    player = BagPlayer(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(tmp_path / "bag")),
        Parameter("wait_for_subscribers", value=10.0)])
    executor.add_node(collector)
    executor.add_node(player)
    player.start()
    assert spin_until(executor, lambda: player.finished, 30.0)
    assert player.error is None
    assert len(player.damage) == 1
    d = player.damage.records[0]
    assert d.where == f"chunk at byte {off}" and d.topics == {topic: d.messages}
    lost = [r for s, r in sent if d.start_ns <= s <= d.end_ns]
    assert d.messages == len(lost) > 0
    assert spin_until(executor, lambda: len(got) == len(sent) - len(lost), 10.0), len(got)
    assert got == [r for s, r in sent if not d.start_ns <= s <= d.end_ns]
    assert player.diag.counter("damaged_regions") == 1
    assert player.diag.counter("messages_lost") == len(lost)
    assert any(c.startswith("damaged:") for c in player.diag.causes)
