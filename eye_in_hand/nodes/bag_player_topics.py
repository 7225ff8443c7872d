"""The ``bag_player`` node's topics: one publisher per playable topic of the bag.

:class:`PlayedTopics` is a part of :class:`eye_in_hand.nodes.bag_player.BagPlayer`, built with
explicit arguments. A topic whose name is not valid or whose type is not an installed ROS
interface type is skipped and reported once; a type recorded with another definition (its
type hash) is reported and played anyway, as with ``ros2 bag play``. Each topic is offered
the QoS its recorded publishers offered (:func:`eye_in_hand.ros.qos.playback_qos`;
``/tf_static``: :func:`~eye_in_hand.ros.qos.static_tf_playback_qos`).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from eye_in_hand.io.bags import BagInfo
from eye_in_hand.ros.msgtypes import import_message_type, installed_type_hash
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.qos import playback_qos, static_tf_playback_qos
from eye_in_hand.ros.tf import TF_STATIC_TOPIC

__all__ = ["PlayedTopics"]


class PlayedTopics:
    """The publishers of the topics played, and what they published.

    Args:
        node: the rclpy node that owns the publishers.
        info: the bag's summary.
        wanted: the topics to play (all in ``info``).
        diag: the node's diagnostics (causes ``bad_topic_name:<topic>``,
            ``type_not_installed:<topic>``, ``type_mismatch:<topic>``; counters
            ``published`` and ``published <topic>``).

    Attributes:
        publishers: topic -> rclpy publisher, for every topic played.
        published: topic -> messages published.
        skipped_types: topic -> message type, for every topic skipped.
        type_mismatches: topic -> message type, for topics whose recorded type hash is not
            the installed definition's.
    """

    def __init__(self, node: Any, info: BagInfo, wanted: Sequence[str], diag: Any) -> None:
        self._diag = diag
        self.publishers: dict[str, Any] = {}
        self.published: dict[str, int] = {}
        self.skipped_types: dict[str, str] = {}
        self.type_mismatches: dict[str, str] = {}
        for name in wanted:
            topic = info.topics[name]
            problem = topic_name_problem(name)
            if problem is not None:  # a damaged or crafted bag: never crash on it
                self.skipped_types[name] = topic.msgtype
                diag.report(f"bad_topic_name:{name}",
                            f"skipping topic {name!r}: not a valid topic name ({problem})")
                continue
            cls = import_message_type(topic.msgtype)
            if cls is None:
                self.skipped_types[name] = topic.msgtype
                diag.report(f"type_not_installed:{name}",
                            f"skipping topic {name}: message type {topic.msgtype} is not "
                            "an installed ROS interface type")
                continue
            if topic.type_hash and installed_type_hash(topic.msgtype) not in (
                    None, topic.type_hash):
                self.type_mismatches[name] = topic.msgtype
                diag.report(
                    f"type_mismatch:{name}",
                    f"topic {name}: the bag's {topic.msgtype} ({topic.type_hash}) is not the "
                    "installed definition; subscribers may misread it (playing it anyway)")
            qos = playback_qos(topic.offered_qos, topic.msgtype)
            if name == TF_STATIC_TOPIC:
                qos = static_tf_playback_qos(topic.count)
            self.publishers[name] = node.create_publisher(cls, name, qos)
            self.published[name] = 0

    def publish(self, topic: str, raw: bytes) -> None:
        """Publish one message (its CDR bytes) and count it."""
        self.publishers[topic].publish(raw)
        self.published[topic] += 1
        self._diag.count("published")
        self._diag.count(f"published {topic}")  # to reconcile with the receivers
