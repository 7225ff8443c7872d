"""``bag_recorder``: record topics into a rosbag2 bag (MCAP or sqlite3) with ``rosbags``.

Each topic is subscribed with its advertised type as a raw (serialized) subscription, so the
stored bytes are exactly what the publisher sent. Log time = receive time from the node clock
(int ns; simulated time when ``use_sim_time`` is set, as ``ros2 bag record --use-sim-time``).
Topics that do not exist yet are picked up as soon as a publisher appears (discovery is polled
every ``discovery_period`` seconds). With ``all`` every topic seen is recorded.

The QoS of each subscription adapts to the publishers, like ``ros2 bag record``: reliable when
every publisher offers reliable (else best effort, which matches any publisher), transient local
when every publisher offers it. The publishers' offered QoS is stored in the bag, so ``play``
offers the same again. Message definitions are stored too (MCAP schemas / the sqlite3
definitions table): from the ROS 2 Jazzy type store, or, for other types, generated from the
installed Python message class.

Callbacks only stamp and queue each message; a writer thread writes them, so disk and
compression never stall the executor. At most ``max_cache_mb`` MiB wait; beyond that new
messages are dropped, counted and reported (as ``ros2 bag record`` does when its cache is full).

Diagnostics (``diagnostics``, 1 Hz): ``messages``, ``dropped`` and ``write_errors`` counters
(a write error is logged once per topic and reported at ERROR), ``topics`` recorded, and
``missing_topics`` (WARN while a requested topic has no publisher yet).

The bag is always left valid: :meth:`BagRecorder.close` writes ``metadata.yaml``; ``main`` and
``eye-in-hand record`` call it on Ctrl-C, SIGTERM (rclpy turns it into a shutdown) and at the end
of ``--duration``.

Parameters (read-only): ``output`` (bag directory to create), ``topics`` (string array),
``all`` (bool), ``storage`` (``mcap``/``sqlite3``), ``compression`` (``""``/``zstd``),
``discovery_period`` (s), ``max_cache_mb`` (MiB), ``duration`` (s, 0: until stopped; used by
``main``).

Run: ``ros2 run eye_in_hand bag_recorder --ros-args -p output:=run1 -p "topics:=[/a, /b]"``
or ``eye-in-hand record -o run1 /a /b``.
"""
from __future__ import annotations

import sys
import threading
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from eye_in_hand.errors import BagError, ConfigError
from eye_in_hand.io.bags import STORAGES, BagWriter, OfferedQos, default_typestore
from eye_in_hand.nodes.bag_recorder_writer import WriterThread
from eye_in_hand.ros.diagnostics import ERROR, NodeDiagnostics
from eye_in_hand.ros.msgtypes import import_message_type, message_definition
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.node_main import (
    guard,
    prepare_process,
    run_with_executor,
    sigterm_as_interrupt,
)
from eye_in_hand.ros.params import Param, declare_params
from eye_in_hand.ros.qos import policy_name, subscription_qos
from eye_in_hand.ros.spin import spin_node

__all__ = [
    "parameter_names",
    "NODE_PARAMETERS",
    "BagRecorder",
    "offered_qos",
    "spin_recorder",
    "main",
]


def _is_hidden(topic: str) -> bool:
    """Hidden topics (a name component starting with ``_``: service events, action internals)
    are left out of ``all``, as ``ros2 bag record -a`` does; name them to record them."""
    return any(part.startswith("_") for part in topic.split("/"))


def offered_qos(endpoints: Sequence[Any]) -> list[OfferedQos]:
    """The offered QoS of publishers (rclpy ``TopicEndpointInfo``) as :class:`OfferedQos`."""
    out = []
    for ep in endpoints:
        q = ep.qos_profile
        out.append(OfferedQos(reliability=policy_name(q.reliability),
                              durability=policy_name(q.durability),
                              history=policy_name(q.history), depth=int(q.depth)))
    return out


#: The node's parameters (declared at start-up; the keys its parameter file may hold).
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("output", "", "bag directory to create"),
    Param("topics", (), "topics to record", type="str[]"),
    Param("all", False, "record every topic"),
    Param("storage", "mcap", "storage plugin: mcap or sqlite3"),
    Param("compression", "", "'' (none) or zstd"),
    Param("discovery_period", 0.2, "seconds between topic discovery polls", range=(0.01, 60.0)),
    Param("max_cache_mb", 512.0, "MiB of received messages that may wait for the disk before "
          "new ones are dropped", range=(1.0, 65536.0)),
    Param("duration", 0.0, "stop after this many seconds (0: until stopped)", range=(0.0, 1e9)),
)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in NODE_PARAMETERS]


class BagRecorder(Node):
    """Records topics into a bag; call :meth:`close` (or destroy the node) to finish it.

    Args:
        node_name: default ``bag_recorder``.
        **kwargs: passed to ``rclpy.node.Node``.

    Raises:
        ConfigError: a parameter is missing or invalid (names it).
        BagError: the output bag cannot be created (exists already, not writable).
    """

    def __init__(self, node_name: str = "bag_recorder", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            self._declare_parameters()
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            raise ConfigError(f"{self.get_name()}: bad parameter: {exc}") from exc
        self._lock = threading.Lock()
        self._topic_subs: dict[str, Any] = {}
        self.received: dict[str, int] = {}
        self.dropped: dict[str, int] = {}
        self.write_errors = 0
        self.diag = NodeDiagnostics(self, hardware_id=self.output)
        self.diag.declare_counter("messages", "write_errors", "dropped")
        self._bag = WriterThread(self.output, self.storage, self.compression,
                                 int(self.max_cache_mb * (1 << 20)), self._written)
        self.writer: BagWriter = self._bag.writer
        self.diag.gauge("missing_topics", len(self.wanted))
        self.diag.warn_above("missing_topics", 0)
        self._timer = self.create_timer(self.discovery_period, self.discover)
        self.discover()
        what = "all topics" if self.record_all else ", ".join(self.wanted)
        self.get_logger().info(f"recording {what} into {self.output} ({self.storage})")

    def _declare_parameters(self) -> None:
        v = declare_params(self, NODE_PARAMETERS)
        self.output = str(v["output"])
        topics = list(v["topics"])
        self.record_all = bool(v["all"])
        self.storage = str(v["storage"])
        self.compression = str(v["compression"])
        self.discovery_period = float(v["discovery_period"])
        self.max_cache_mb = float(v["max_cache_mb"])
        self.duration = float(v["duration"])
        if not self.output:
            raise ConfigError("parameter 'output' is required (the bag directory to create)")
        if self.storage not in STORAGES:
            raise ConfigError(f"parameter 'storage' must be one of {', '.join(STORAGES)}, "
                              f"got {self.storage!r}")
        if self.compression not in ("", "zstd"):
            raise ConfigError(f"parameter 'compression' must be '' or 'zstd', "
                              f"got {self.compression!r}")
        if not topics and not self.record_all:
            raise ConfigError("give parameter 'topics' (a list of topic names) or set 'all'")
        for t in topics:
            problem = topic_name_problem(t)
            if problem is not None:
                raise ConfigError(f"parameter 'topics': {t!r} is not a valid topic name "
                                  f"({problem})")
        self.wanted = [self.resolve_topic_name(t) for t in topics]

    @property
    def missing_topics(self) -> list[str]:
        """Requested topics not subscribed yet (no publisher seen)."""
        return [t for t in self.wanted if t not in self._topic_subs]

    def discover(self) -> None:
        """Subscribe to requested topics that have appeared since the last call."""
        if self._bag.closed:
            return
        for name, types in self.get_topic_names_and_types():
            if name in self._topic_subs:
                continue
            if name in self.wanted or (self.record_all and not _is_hidden(name)):
                self._try_subscribe(name, types)
        self.diag.gauge("missing_topics", len(self.missing_topics))
        self.diag.gauge("topics", len(self._topic_subs))

    def _warn_once(self, key: str, text: str) -> None:
        self.diag.report(key, text)

    def _try_subscribe(self, name: str, types: list[str]) -> None:
        publishers = self.get_publishers_info_by_topic(name)
        if not publishers:
            return  # only subscribers so far: wait for a publisher and its QoS
        msgtype = types[0]
        if len(types) > 1:
            self._warn_once(f"types:{name}", f"topic {name} has several types {types}; "
                            f"recording {msgtype}")
        cls = import_message_type(msgtype)
        if cls is None:
            self._warn_once(f"import:{name}", f"cannot record {name}: message type {msgtype} "
                            "is not installed")
            return
        msgdef = None if msgtype in default_typestore().types else message_definition(msgtype)
        self._bag.add_topic(name, msgtype, msgdef=msgdef, qos=offered_qos(publishers))
        with self._lock:
            self.received[name] = 0
        self._topic_subs[name] = self.create_subscription(
            cls, name, partial(self._on_message, name), subscription_qos(publishers), raw=True)
        self.get_logger().info(f"subscribed to {name} ({msgtype})")

    def _on_message(self, topic: str, raw: bytes) -> None:
        """Stamp and queue (the writer thread writes); drop when the queue is over budget."""
        stamp = self.get_clock().now().nanoseconds
        if not self._bag.put(topic, stamp, raw):
            if self._bag.closed:
                return  # arrived while closing: the bag is complete without it
            with self._lock:
                self.dropped[topic] = self.dropped.get(topic, 0) + 1
            self.diag.count("dropped")
            self.diag.report(f"queue_full:{topic}",
                             f"dropping messages of {topic}: more than "
                             f"{self.max_cache_mb:g} MiB wait to be written (disk too slow?)")

    def _written(self, topic: str, error: BagError | None) -> None:
        """Count a message the writer thread wrote, or report why it could not."""
        if error is not None:
            self.write_errors += 1
            self.diag.count("write_errors")
            self.diag.report(f"write_error:{topic}",
                             f"cannot write a message of {topic}: {error}", level=ERROR)
            return
        with self._lock:
            self.received[topic] += 1
        self.diag.count("messages")

    def close(self) -> None:
        """Stop recording, write what is queued, and finish the bag (writes metadata.yaml).

        Idempotent.

        Raises:
            BagError: the bag could not be finished.
        """
        if self._bag.closed:
            return
        self._timer.cancel()
        for sub in self._topic_subs.values():
            self.destroy_subscription(sub)
        self._topic_subs.clear()
        self._bag.close()  # writes what is queued, then finishes the bag
        total = sum(self.received.values())
        dropped = sum(self.dropped.values())
        text = f"wrote {total} message(s) to {self.output}" + (
            f" ({dropped} dropped: the write queue was full)" if dropped else "")
        if self.context.ok():
            self.get_logger().info(text)
        else:  # after Ctrl-C the context is gone and /rosout with it
            print(f"[bag_recorder] {text}", file=sys.stderr)

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


def spin_recorder(node: BagRecorder, duration_s: float = 0.0, executor: Any | None = None) -> int:
    """Spin ``node`` until ``duration_s`` passes (0: until shutdown), then close the bag.

    The bag is closed (valid) whatever ends the spin: the duration, Ctrl-C, SIGTERM.
    """
    spin_node(node, lambda: True, node.close, executor=executor, duration_s=duration_s)
    return 0


def main(args: list[str] | None = None) -> None:
    """Console-script entry point (``ros2 run eye_in_hand bag_recorder --ros-args ...``)."""
    sigterm_as_interrupt()
    prepare_process()  # large images over shared memory, reused memory blocks
    sys.exit(guard("bag_recorder", lambda: run_with_executor(
        BagRecorder, lambda node, ex: spin_recorder(node, node.duration, ex), args), args))

if __name__ == "__main__":
    main()
