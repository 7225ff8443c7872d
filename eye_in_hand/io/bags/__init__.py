"""rosbag2 bags: inspect, read and write them with ``rosbags`` (no rclpy).

This is the one bag API of the package. Live replay (``eye-in-hand play``), recording, calibration
from a bag, hand-eye from a bag, offline processing and the simulator all go through it.

What it opens:

* a bag directory with ``metadata.yaml`` (rosbag2 metadata versions 1 to 9, storage ``sqlite3``
  or ``mcap``, file/message compression with zstd, MCAP chunks compressed with zstd or lz4,
  split bags with several storage files), as written by ``ros2 bag record``;
* a single ``.mcap`` (or ``.db3``) file without metadata;
* a bag directory whose ``metadata.yaml`` is missing (a recorder that was killed) but which
  holds readable ``.mcap`` / ``.db3`` files: they are read directly.

``rosbags`` does the parsing. On top of it this module adds a log-time-ordered merge across
storage files, time windows, message definitions taken from the bag itself (so types that the
Jazzy type store does not know still decode), and one error type (:class:`BagError`) whose
message names the bag.

Conventions: times are int nanoseconds (log time, i.e. receive time for ``ros2 bag record``);
message types are ``pkg/msg/Type``.

Example::

    info = bag_info("run1")
    require_topics(info, ["/left/image_raw", "/right/image_raw"])
    store = typestore_for("run1")
    for topic, msgtype, stamp_ns, raw in iter_messages("run1", topics=["/left/image_raw"]):
        msg = deserialize(raw, msgtype, store)
    for topic, stamp_ns, msg in iter_decoded("run1", topics=["/right/image_raw"]):
        ...

    with BagWriter("out", storage="mcap", compression="zstd") as bag:
        bag.add_topic("/target/point", "geometry_msgs/msg/PointStamped")
        bag.write("/target/point", stamp_ns, msg_or_cdr_bytes)
"""
from __future__ import annotations

# The package: records (bag and topic information, damage), reading (log-time order, damaged
# and interrupted files), decoding (type stores, definitions, the Jazzy fallback) and writing
# (BagWriter); every public name is re-exported here. Storage formats (MCAP, sqlite3) sit
# behind one interface (storage.StorageFormat), registered in formats.FORMATS.
from eye_in_hand.io.bags.decoding import (
    check_bag,
    default_typestore,
    deserialize,
    iter_decoded,
    require_topics,
    serialize,
    types_from_definition,
    typestore_for,
)
from eye_in_hand.io.bags.formats import STORAGES
from eye_in_hand.io.bags.reading import bag_info, iter_messages, memory_mappable
from eye_in_hand.io.bags.records import (
    COMPRESSIONS,
    BagInfo,
    BagMessage,
    Damage,
    DamageLog,
    OfferedQos,
    TopicInfo,
)
from eye_in_hand.io.bags.writing import BagWriter

__all__ = [
    "STORAGES",
    "COMPRESSIONS",
    "OfferedQos",
    "TopicInfo",
    "BagInfo",
    "BagMessage",
    "Damage",
    "DamageLog",
    "bag_info",
    "check_bag",
    "iter_messages",
    "iter_decoded",
    "memory_mappable",
    "typestore_for",
    "default_typestore",
    "deserialize",
    "serialize",
    "types_from_definition",
    "require_topics",
    "BagWriter",
]

