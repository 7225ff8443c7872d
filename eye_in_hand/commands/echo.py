"""``eye-in-hand echo TOPIC``: print a topic's messages, like ``ros2 topic echo``."""
from __future__ import annotations

import argparse
import array
import json
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import yaml

from eye_in_hand.commands.common import bounded
from eye_in_hand.errors import EyeInHandError, InputError

HELP = "print a topic's messages as YAML (or JSON lines), like ros2 topic echo"

__all__ = ["HELP", "add_arguments", "run", "message_to_dict"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand echo``."""
    parser.add_argument("topic", help="topic name (relative names are taken from /)")
    parser.add_argument("msgtype", nargs="?", default=None,
                        help="message type, e.g. std_msgs/msg/String (default: the type the "
                             "topic is advertised with; the command waits for it to appear)")
    parser.add_argument("-n", "--count", type=bounded(0, 1e9, integer=True), default=0,
                        metavar="N",
                        help="exit after N messages, 0 to 1e9 (default 0: until Ctrl-C)")
    parser.add_argument("-t", "--timeout", type=bounded(0, 86400, "s"), default=0.0, metavar="S",
                        help="exit with an error when no message arrived within S seconds, "
                             "0 to 86400 (default 0: wait forever)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object per message and line instead of YAML")
    parser.add_argument("--truncate-length", type=bounded(0, 1e6, integer=True), default=128,
                        metavar="N",
                        help="print at most N items of arrays and N characters of strings, "
                             "0 to 1e6 "
                             "(default 128, as ros2 topic echo; 0: everything)")


def _truncate(seq: list, limit: int) -> list:
    if limit and len(seq) > limit:
        return seq[:limit] + ["..."]
    return seq


def message_to_dict(msg: Any, truncate_length: int = 0) -> Any:
    """A ROS message (rclpy) as plain Python data: dicts in field order, lists, numbers, str.

    Args:
        msg: an rclpy message instance (or a field value inside one).
        truncate_length: cut sequences and strings longer than this (0: never); a cut
            sequence ends with ``"..."``, a cut string with ``...``.

    Returns:
        dict / list / int / float / bool / str, suitable for YAML and JSON.
    """
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: message_to_dict(getattr(msg, name), truncate_length)
                for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (bytes, bytearray)):
        return _truncate(list(msg), truncate_length)
    if isinstance(msg, str):
        if truncate_length and len(msg) > truncate_length:
            return msg[:truncate_length] + "..."
        return msg
    if isinstance(msg, (list, tuple, array.array)) or type(msg).__module__ == "numpy":
        if hasattr(msg, "tolist"):
            items = msg.tolist()
            if not isinstance(items, list):  # numpy scalar
                return items
        else:
            items = list(msg)
        return _truncate([message_to_dict(x, truncate_length) for x in items], truncate_length)
    return msg


def _json_default(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    raise TypeError(f"cannot encode {type(value).__name__}")


def run(args: argparse.Namespace) -> int:
    """Echo until ``--count`` messages, ``--timeout`` without any, or Ctrl-C."""
    if args.count < 0:
        raise InputError(f"--count must be >= 0, got {args.count}")
    if not args.timeout >= 0:
        raise InputError(f"--timeout must be >= 0, got {args.timeout}")
    if args.truncate_length < 0:
        raise InputError(f"--truncate-length must be >= 0, got {args.truncate_length}")
    # local: ros.names loads rclpy (~50 ms at CLI start-up)
    from eye_in_hand.ros.names import check_topic_name

    check_topic_name(args.topic, "echo TOPIC")
    # local: rclpy (and the ROS glue on it) cost ~50-80 ms at CLI start-up
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    from eye_in_hand.ros.msgtypes import import_message_type
    from eye_in_hand.ros.qos import subscription_qos

    rclpy.init(args=[])
    node = None
    executor = None
    try:
        executor = SingleThreadedExecutor()  # first: one interrupted in its constructor spews
        node = Node("eye_in_hand_echo")
        executor.add_node(node)
        topic = node.resolve_topic_name(args.topic if args.topic.startswith("/")
                                        else "/" + args.topic)
        deadline = time.monotonic() + args.timeout if args.timeout > 0 else None

        def expired() -> bool:
            return deadline is not None and time.monotonic() >= deadline

        msgtype, publishers = _wait_for_topic(node, executor, topic, args, expired)
        cls = import_message_type(msgtype)
        if cls is None:
            raise InputError(f"message type {msgtype} of topic {topic} is not installed")
        # 100 deep: a burst of results is not lost while this process is busy printing
        qos = subscription_qos(publishers, depth=100) if publishers else QoSProfile(depth=100)
        printer = _Printer(args.count, args.truncate_length, args.json)
        node.create_subscription(cls, topic, printer, qos)
        while not (args.count and printer.received >= args.count):
            if printer.received == 0 and expired():
                raise EyeInHandError(
                    f"no message received on {topic} within {args.timeout:g} s")
            executor.spin_once(timeout_sec=0.05)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def _wait_for_topic(node: Any, executor: Any, topic: str, args: argparse.Namespace,
                    expired: Callable[[], bool]) -> tuple[str, list]:
    """Spin until ``topic`` has a type (``args.msgtype`` or the advertised one) and a
    publisher (or the type was given): ``(msgtype, publishers' info)``."""
    msgtype = args.msgtype
    publishers: list = []
    while True:  # wait for the topic (and its type) to appear
        types = dict(node.get_topic_names_and_types())
        publishers = node.get_publishers_info_by_topic(topic)
        if msgtype is None and topic in types:
            msgtype = types[topic][0]
        if msgtype is not None and (publishers or args.msgtype):
            return msgtype, publishers
        if expired():
            raise EyeInHandError(f"topic {topic} did not appear within {args.timeout:g} s")
        executor.spin_once(timeout_sec=0.05)


class _Printer:
    """The subscription's callback: each message as YAML (or a JSON line) on stdout, up to
    ``count`` of them (0: no limit); ``received`` counts the ones printed."""

    def __init__(self, count: int, truncate_length: int, as_json: bool) -> None:
        self.count, self.truncate_length, self.as_json = count, truncate_length, as_json
        self.received = 0

    def __call__(self, msg: Any) -> None:
        if self.count and self.received >= self.count:
            return
        self.received += 1
        data = message_to_dict(msg, self.truncate_length)
        if self.as_json:
            sys.stdout.write(json.dumps(data, default=_json_default) + "\n")
        else:
            sys.stdout.write(yaml.safe_dump(data, default_flow_style=False,
                                            sort_keys=False, allow_unicode=True,
                                            width=10**9) + "---\n")
        sys.stdout.flush()
