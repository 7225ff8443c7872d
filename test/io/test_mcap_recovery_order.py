"""An interrupted MCAP recording, read by scanning, yields each chunk's messages in log-time order.

A recorder writes messages as they arrive, so inside one chunk their log times need not increase
(two topics delivered by different threads, a late message). The indexed reader orders them by
time; the scanning reader for a file without summary promises the same within each chunk.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_scanned_chunks_yield_messages_in_log_time_order(tmp_path: Path,
                                                         compression: str | None) -> None:
    rng = np.random.default_rng(5)
    # stamps written out of order in pairs: 1, 0, 3, 2, ... (ms); ~60 kB each so several
    # chunks close before the cut
    order = [i ^ 1 for i in range(60)]
    payload = {i: bytes(rng.integers(0, 256, 60_000, dtype=np.uint8)) for i in order}
    with BagWriter(tmp_path / "bag", "mcap", compression) as bag:
        bag.add_topic("/a", "std_msgs/msg/UInt8MultiArray")
        for i in order:
            bag.write("/a", T0 + i * MS, _uint8_array(payload[i]))
    mcap = tmp_path / "bag" / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.7)])  # killed while writing
    (tmp_path / "bag" / "metadata.yaml").unlink()

    info = bag_info(tmp_path / "bag")
    assert info.notes and "interrupted" in info.notes[0]
    stamps = [t for _topic, _type, t, _raw in iter_messages(tmp_path / "bag")]
    n = len(stamps)
    assert 10 <= n < 60
    # whole chunks survive, so the pairs written out of order come back complete and sorted
    assert stamps == sorted(stamps)
    assert stamps == [T0 + i * MS for i in range(n)]


def _uint8_array(data: bytes) -> bytes:
    """CDR of a std_msgs/UInt8MultiArray holding ``data`` (empty layout)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    s = store.types
    msg = s["std_msgs/msg/UInt8MultiArray"](
        layout=s["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
        data=np.frombuffer(data, dtype=np.uint8))
    return bytes(store.serialize_cdr(msg, "std_msgs/msg/UInt8MultiArray"))


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_chunks_written_out_of_time_order_are_read_in_time_order(tmp_path: Path,
                                                                 compression: str | None) -> None:
    """A writer may close a chunk of earlier messages after later ones (a late topic flushed
    after the others); the indexed reader still yields log-time order. Each message here is
    larger than a chunk, so each is a chunk of its own: chunks at t = 0, 2, 3, 1, 4, 5 ms."""
    rng = np.random.default_rng(6)
    order = [0, 2, 3, 1, 4, 5]
    payload = bytes(rng.integers(0, 256, 1_100_000, dtype=np.uint8))
    with BagWriter(tmp_path / "bag", "mcap", compression) as bag:
        bag.add_topic("/a", "std_msgs/msg/UInt8MultiArray")
        for i in order:
            bag.write("/a", T0 + i * MS, _uint8_array(payload))
    for views in (False, True):
        stamps = [t for _topic, _type, t, _raw in iter_messages(tmp_path / "bag", views=views)]
        assert stamps == [T0 + i * MS for i in range(6)]
