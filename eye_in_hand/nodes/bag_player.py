"""``bag_player``: publish a rosbag2 bag's messages over DDS at the recorded pace.

Every message goes out as the CDR bytes stored in the bag (no decode/re-encode), on its
recorded topic with its recorded type. Types whose Python message package is not installed are
skipped with one warning each. Timing follows the bag's log times, scaled by ``rate``: each
message is due at ``start + (t - t_first) / rate`` on the monotonic clock, so timing does not
drift: a slow publish delays only the messages that fall due while it runs (they then go out at
once), never the schedule of the rest.
A reader thread decodes the bag ahead of the publisher (at most 256 messages and 64 MiB), so
storage I/O and decompression do not delay publishing either.

Diagnostics (``diagnostics``, 1 Hz): ``published`` counter (and ``published <topic>`` per
topic, to reconcile with what the receiving nodes count), ``late_ms`` (how late the last
message went out), ``state``, ``loops``, and ``skipped_topics`` (WARN while > 0; each skipped
topic is also logged once), ``problem: type_mismatch:<topic>`` when the bag recorded a type
hash (metadata >= 7) that differs from the installed definition (logged once; the topic still
plays, as with ``ros2 bag play``). Damaged parts of the bag (a chunk that cannot be read, a
truncated tail) are skipped and play goes on: each is logged once (file, where, topics, time
range, messages lost) and reported at WARN as ``problem: damaged:<where>``, and the counters
``damaged_regions`` and ``messages_lost`` count them (also in :attr:`BagPlayer.damage`). A
bag that cannot be opened is reported at ERROR and ends playback.

Like ``ros2 bag play``, the player does not wait for subscribers by default: messages published
before DDS discovery completes are lost. ``wait_for_subscribers`` (seconds) waits until every
topic has at least one subscriber, or the time is up, before the first message; with
``wait_for_topics`` it also waits until each of those topics (the downstream hops of a
pipeline, e.g. ``/target/point`` and ``/target/pose``) has a publisher and a subscriber, so
nothing of the first frames is lost to a node or listener still starting up.

Parameters (all read-only): ``bag`` (path), ``rate`` (> 0), ``loop``, ``clock`` (publish
``/clock``), ``clock_hz``, ``topics`` (empty: all), ``start_offset`` (s), ``wait_for_subscribers``
(s, 0: do not wait), ``wait_for_topics`` (downstream topics, with ``wait_for_subscribers``).

Run: ``ros2 run eye_in_hand bag_player --ros-args -p bag:=/path/to/bag -p rate:=2.0``
or ``eye-in-hand play /path/to/bag --rate 2``.
"""
from __future__ import annotations

import sys
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock

from eye_in_hand.errors import BagError, ConfigError, EyeInHandError
from eye_in_hand.io.bags import (
    BagInfo,
    Damage,
    DamageLog,
    OfferedQos,
    bag_info,
    iter_messages,
    types_from_definition,
)
from eye_in_hand.ros.dds import use_large_data_profile
from eye_in_hand.ros.diagnostics import ERROR, NodeDiagnostics
from eye_in_hand.ros.msgtypes import import_message_type as _import_message_type
from eye_in_hand.ros.msgtypes import message_definition
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.node_main import guard, run_with_executor, sigterm_as_interrupt
from eye_in_hand.ros.params import Param, declare_params
from eye_in_hand.ros.tf import TF_STATIC_TOPIC

__all__ = [
    "parameter_names",
    "NODE_PARAMETERS",
    "PlayerConfig",
    "BagPlayer",
    "import_message_type",
    "installed_type_hash",
    "playback_qos",
    "spin_player",
    "main",
]

#: Pause after every topic has a subscriber, before the first message (wait mode only): the
#: subscribers must match the player's writers too, and on a loaded 2-core machine with nodes
#: still starting that took more than 0.5 s (the first robot poses of a replay were lost).
DISCOVERY_SETTLE_S = 1.5

_END = object()
_NOTHING = object()


def import_message_type(msgtype: str) -> Any:
    """The Python message class for ``pkg/msg/Type``, or None when it is not an installed ROS
    interface type; see :func:`eye_in_hand.ros.msgtypes.import_message_type` (a bag's type
    name never imports an arbitrary Python package)."""
    return _import_message_type(msgtype)


_HASHES: dict[str, str | None] = {}


def installed_type_hash(msgtype: str) -> str | None:
    """The RIHS01 type hash of the installed message class, or None when unknown.

    Computed from the class's fields (see :func:`eye_in_hand.nodes.bag_recorder.
    message_definition`), so it can be compared with the hash a bag recorded (metadata >= 7).
    """
    if msgtype not in _HASHES:
        try:
            store = get_typestore(Stores.EMPTY)
            store.register(types_from_definition(
                msgtype, MessageDefinitionFormat.MSG, message_definition(msgtype)))
            _HASHES[msgtype] = store.hash_rihs01(msgtype)
        except (EyeInHandError, ValueError, KeyError):
            _HASHES[msgtype] = None
    return _HASHES[msgtype]


#: Message types replayed at least :data:`LARGE_DEPTH` deep (a second of a 30 Hz camera); every
#: other, smaller type is offered keep-last :data:`SMALL_DEPTH`, so that a reliable subscriber
#: that is busy for a moment (a robot pose stream at 125-500 Hz) misses nothing the writer
#: already dropped.
LARGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage",
                         "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan"})
SMALL_DEPTH = 1000
LARGE_DEPTH = 30
#: How long playback waits at its end for reliable subscribers to acknowledge every message (s)
ACK_TIMEOUT_S = 10.0


def playback_qos(offered: Sequence[OfferedQos], msgtype: str = "") -> QoSProfile:
    """The QoS to offer when replaying a topic, from what its recorded publishers offered.

    Like ``ros2 bag play``: when every recorded publisher offered the same reliability and
    durability, offer that (so a transient-local topic such as a calibration stays latched, and
    a best-effort camera stays best effort); otherwise, or when the bag has no QoS metadata,
    offer reliable, volatile, keep-last 10. A reliable offer is received by reliable and by
    best-effort (sensor-data) subscribers alike.

    Args:
        offered: the recorded profiles (:attr:`TopicInfo.offered_qos`).

    A reliable keep-last writer drops a message that a slow subscriber has not acknowledged
    once ``depth`` newer ones are written: images and other :data:`LARGE_TYPES` are offered at
    least :data:`LARGE_DEPTH` deep (a second of a 30 Hz camera: 27 MB of 640x480 colour images),
    small messages at least :data:`SMALL_DEPTH`.

    Returns:
        An rclpy ``QoSProfile`` (keep-last; depth from the recording, at least 10; with
        ``msgtype``, at least :data:`LARGE_DEPTH` or :data:`SMALL_DEPTH`).
    """
    depth = 10
    reliability = ReliabilityPolicy.RELIABLE
    durability = DurabilityPolicy.VOLATILE
    rel = {q.reliability for q in offered}
    dur = {q.durability for q in offered}
    if offered and len(rel) == 1 and len(dur) == 1:
        if rel == {"best_effort"}:
            reliability = ReliabilityPolicy.BEST_EFFORT
        if dur == {"transient_local"}:
            durability = DurabilityPolicy.TRANSIENT_LOCAL
        depth = max([depth] + [q.depth for q in offered if q.history == "keep_last"])
    if msgtype:
        depth = max(depth, LARGE_DEPTH if msgtype in LARGE_TYPES else SMALL_DEPTH)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                      durability=durability)


def static_tf_playback_qos(count: int) -> QoSProfile:
    """QoS of a replayed ``/tf_static``: reliable and transient local whatever the bag
    recorded (tf2 listeners subscribe transient local and match nothing else), deep enough
    (the bag's message count, 1..1000) that a late subscriber still gets every recorded
    publisher's static transforms."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1, min(int(count), 1000)),
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class PlayerConfig:
    """Validated ``bag_player`` parameters."""

    bag: str
    rate: float
    loop: bool
    clock: bool
    clock_hz: float
    topics: tuple[str, ...]
    start_offset: float
    wait_for_subscribers: float
    wait_for_topics: tuple[str, ...] = ()


#: The node's parameters (declared at start-up; the keys its parameter file may hold).
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("bag", "", "bag directory or .mcap/.db3 file"),
    Param("rate", 1.0, "playback speed factor (2.0: twice as fast)", range=(0.001, 1000.0)),
    Param("loop", False, "restart at the end"),
    Param("clock", False, "publish rosgraph_msgs/Clock on /clock (for use_sim_time)"),
    Param("clock_hz", 40.0, "/clock publishing frequency", range=(0.1, 1000.0)),
    Param("topics", (), "topics to play (empty: all)", type="str[]"),
    Param("start_offset", 0.0, "seconds into the bag to start from", range=(0.0, 1e9)),
    Param("wait_for_subscribers", 0.0, "wait up to this many seconds for a subscriber on "
          "every topic (0: do not wait)", range=(0.0, 3600.0)),
    Param("wait_for_topics", (), "with wait_for_subscribers: also wait until each of these "
          "topics has a publisher and a subscriber (the downstream hops of a pipeline)",
          type="str[]"),
)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in NODE_PARAMETERS]


class BagPlayer(Node):
    """Publishes a bag's messages; call :meth:`start`, then spin until :attr:`finished`.

    Args:
        node_name: default ``bag_player``.
        **kwargs: passed to ``rclpy.node.Node`` (``context``, ``namespace``,
            ``parameter_overrides``, ...).

    Raises:
        ConfigError: a parameter is missing or out of range (names it).
        BagError: the bag cannot be read, or a requested topic is not in it.
    """

    def __init__(self, node_name: str = "bag_player", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            self.config = self._declare_parameters()
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            raise ConfigError(f"{self.get_name()}: bad parameter: {exc}") from exc
        self.info: BagInfo = bag_info(self.config.bag)
        self._stop = threading.Event()
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._error: BaseException | None = None
        self.published: dict[str, int] = {}
        self.damage = _ReportedDamage(self)
        self.skipped_types: dict[str, str] = {}
        self.type_mismatches: dict[str, str] = {}
        self.loops_done = 0
        # playback time: (monotonic start, bag time at that instant); None before the start
        self._timebase: tuple[float, int] | None = None

        wanted = self.config.topics or tuple(self.info.topics)
        unknown = [t for t in wanted if t not in self.info.topics]
        if unknown:
            raise BagError(f"bag {self.info.path} has no topic {', '.join(unknown)}; it has: "
                           f"{', '.join(self.info.topics) or 'no topics'}")
        self.diag = NodeDiagnostics(self, hardware_id=str(self.info.path))
        self.diag.declare_counter("published", "damaged_regions", "messages_lost")
        self._topic_pubs: dict[str, Any] = {}
        for name in wanted:
            topic = self.info.topics[name]
            problem = topic_name_problem(name)
            if problem is not None:  # a damaged or crafted bag: never crash on it
                self.skipped_types[name] = topic.msgtype
                self.diag.report(f"bad_topic_name:{name}",
                                 f"skipping topic {name!r}: not a valid topic name ({problem})")
                continue
            cls = import_message_type(topic.msgtype)
            if cls is None:
                self.skipped_types[name] = topic.msgtype
                self.diag.report(f"type_not_installed:{name}",
                                 f"skipping topic {name}: message type {topic.msgtype} is not "
                                 "an installed ROS interface type")
                continue
            if topic.type_hash and installed_type_hash(topic.msgtype) not in (
                    None, topic.type_hash):
                self.type_mismatches[name] = topic.msgtype
                self.diag.report(
                    f"type_mismatch:{name}",
                    f"topic {name}: the bag's {topic.msgtype} ({topic.type_hash}) is not the "
                    "installed definition; subscribers may misread it (playing it anyway)")
            qos = playback_qos(topic.offered_qos, topic.msgtype)
            if name == TF_STATIC_TOPIC:
                qos = static_tf_playback_qos(topic.count)
            self._topic_pubs[name] = self.create_publisher(cls, name, qos)
            self.published[name] = 0
        self._clock_pub = None
        self._clock_timer = None
        if self.config.clock:
            self._clock_msg = Clock
            self._clock_pub = self.create_publisher(
                Clock, "/clock", QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
            self._clock_timer = self.create_timer(1.0 / self.config.clock_hz, self._publish_clock)
        self.diag.gauge("skipped_topics", len(self.skipped_types))
        self.diag.warn_above("skipped_topics", 0)
        self.diag.gauge("state", "waiting")
        first = self.info.start_ns + int(round(self.config.start_offset * 1e9))
        self._first_ns = first

    # -- parameters ---------------------------------------------------------------------------

    def _declare_parameters(self) -> PlayerConfig:
        v = declare_params(self, NODE_PARAMETERS)
        bag, rate, loop, clock, clock_hz = (v["bag"], v["rate"], v["loop"], v["clock"],
                                            v["clock_hz"])
        topics, offset, wait = v["topics"], v["start_offset"], v["wait_for_subscribers"]
        downstream = v["wait_for_topics"]
        if not bag:
            raise ConfigError("parameter 'bag' is required (a bag directory or .mcap file)")
        return PlayerConfig(bag=str(bag), rate=float(rate), loop=bool(loop), clock=bool(clock),
                            clock_hz=float(clock_hz), topics=tuple(str(t) for t in topics),
                            start_offset=float(offset), wait_for_subscribers=float(wait),
                            wait_for_topics=tuple(self.resolve_topic_name(str(t))
                                                  for t in downstream))

    # -- control ------------------------------------------------------------------------------

    @property
    def finished(self) -> bool:
        """True when playback has ended (end of bag without loop, stop, or error)."""
        return self._done.is_set()

    @property
    def error(self) -> BaseException | None:
        """The error that ended playback early, if any."""
        return self._error

    def start(self) -> None:
        """Start playback in a background thread (returns at once)."""
        if self._threads:
            return
        self.get_logger().info(
            f"playing {self.info.path}: {len(self._topic_pubs)} topic(s), "
            f"{sum(self.info.topics[t].count for t in self._topic_pubs)} message(s), "
            f"{self.info.duration_ns / 1e9:.3f} s at rate {self.config.rate:g}"
            f"{', looping' if self.config.loop else ''}")
        thread = threading.Thread(target=self._run, name="bag_player", daemon=True)
        thread.start()
        self._threads.append(thread)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop playback and join the threads."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout_s)
        self._done.set()

    def destroy_node(self) -> None:
        self.stop()
        super().destroy_node()

    # -- playback -----------------------------------------------------------------------------

    def _now_bag_ns(self) -> int | None:
        with self._lock:
            base = self._timebase
        if base is None:
            return None
        mono0, bag0 = base
        return bag0 + int((time.monotonic() - mono0) * self.config.rate * 1e9)

    def _publish_clock(self) -> None:
        if self._done.is_set() or self._clock_pub is None:
            return
        now = self._now_bag_ns()
        if now is None:
            now = self._first_ns
        msg = self._clock_msg()
        msg.clock.sec, msg.clock.nanosec = divmod(now, 1_000_000_000)
        self._clock_pub.publish(msg)

    def _wait_for_subscribers(self) -> None:
        deadline = time.monotonic() + self.config.wait_for_subscribers
        while not self._stop.is_set():
            waiting = [t for t, p in self._topic_pubs.items() if p.get_subscription_count() == 0]
            waiting += [t for t in self.config.wait_for_topics
                        if self.count_publishers(t) == 0 or self.count_subscribers(t) == 0]
            if not waiting:
                # This side sees the subscriptions first; give the subscribers time to match
                # our writers too, or the first (best-effort, volatile) messages are lost.
                self._stop.wait(DISCOVERY_SETTLE_S)
                return
            if time.monotonic() >= deadline:
                self.get_logger().warning(
                    f"no subscriber after {self.config.wait_for_subscribers:g} s on "
                    f"{', '.join(waiting)}; playing anyway")
                return
            self._stop.wait(0.02)

    def _reader(self, out: _Prefetch) -> None:
        try:
            for item in iter_messages(self.info.path, topics=list(self._topic_pubs),
                                      start_ns=self._first_ns, damage=self.damage):
                if not out.put(item, len(item[3])):
                    return  # the pass ended (stop, or the publisher gave up)
            out.put(_END, 0)
        except BaseException as exc:  # handed to the publishing thread, which re-raises it
            out.put(exc, 0)

    def _run(self) -> None:
        try:
            if self.config.wait_for_subscribers > 0:
                self._wait_for_subscribers()
            self.diag.gauge("state", "playing")
            while not self._stop.is_set():
                self._play_once()
                self.loops_done += 1
                self.diag.gauge("loops", self.loops_done)
                if not self.config.loop or not self._topic_pubs:
                    break
        except BaseException as exc:
            if self._stop.is_set() or not self.context.ok():
                return  # stopped (Ctrl-C shuts the context down under a publish): not an error
            self._error = exc
            self.diag.gauge("state", "error")
            self.diag.report("playback_error", f"playback stopped: {exc}", level=ERROR)
        finally:
            if self._error is None:
                self.diag.gauge("state", "finished")
            total = sum(self.published.values())
            if self._error is None and self.context.ok():
                self._wait_for_acks()
            if self.context.ok():
                self.get_logger().info(f"published {total} message(s)")
                if self.damage:
                    self.get_logger().warning(f"damaged bag: {self.damage.summary()}")
            self._done.set()

    def _wait_for_acks(self) -> None:
        """Before playback counts as finished (and the process may exit, taking its writers'
        undelivered messages with it), wait up to :data:`ACK_TIMEOUT_S` until every reliable
        subscriber has acknowledged every message; say which topics it did not."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + ACK_TIMEOUT_S
        late = []
        for name, pub in self._topic_pubs.items():
            left = max(0.0, deadline - time.monotonic())
            try:
                if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                    late.append(name)
            except Exception:  # noqa: BLE001 - a publisher destroyed by a shutdown: not ours
                return
        if late:
            self.get_logger().warning(
                f"{', '.join(late)}: not acknowledged by every subscriber within "
                f"{ACK_TIMEOUT_S:g} s of the end: a slow subscriber may miss the last messages")

    def _play_once(self) -> None:
        buffer = _Prefetch()
        reader = threading.Thread(target=self._reader, args=(buffer,), daemon=True,
                                  name="bag_reader")
        reader.start()
        try:
            rate = self.config.rate
            mono0 = time.monotonic()
            with self._lock:
                self._timebase = (mono0, self._first_ns)
            while not self._stop.is_set():
                item = buffer.get(timeout_s=0.1)
                if item is _NOTHING:
                    continue
                if item is _END:
                    return
                if isinstance(item, BaseException):
                    raise item
                topic, _msgtype, stamp, raw = item
                due = mono0 + (stamp - self._first_ns) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
                self._topic_pubs[topic].publish(raw)
                self.published[topic] += 1
                self.diag.count("published")
                self.diag.count(f"published {topic}")  # to reconcile with the receivers
                self.diag.gauge("late_ms", round(max(0.0, time.monotonic() - due) * 1e3, 3))
        finally:
            buffer.close()
            reader.join(5.0)


class _ReportedDamage(DamageLog):
    """The player's damage log: each damaged region is also logged and reported once (per
    region: a looping player meets the same damage every pass) and counted on diagnostics."""

    def __init__(self, player: Any) -> None:
        super().__init__()
        self._player = player

    def add(self, damage: Damage) -> None:
        before = len(self)
        super().add(damage)
        diag = getattr(self._player, "diag", None)
        if diag is None or len(self) == before:      # met again (a later loop): counted once
            return
        diag.count("damaged_regions")
        diag.count("messages_lost", damage.messages or 0)
        diag.report(f"damaged:{damage.file}:{damage.where}",
                    f"damaged bag, skipped: {damage.describe()}")


class _Prefetch:
    """Hand-over from the reader thread to the publisher, bounded in messages and bytes.

    At most ``max_items`` messages and ``max_bytes`` bytes wait (one message always fits), so
    reading ahead smooths storage I/O and decompression without holding a bag of images in
    memory. :meth:`close` ends the hand-over: a blocked :meth:`put` returns False.
    """

    def __init__(self, max_items: int = 256, max_bytes: int = 64 << 20) -> None:
        self._cv = threading.Condition()
        self._items: deque[tuple[Any, int]] = deque()
        self._bytes = 0
        self._closed = False
        self.max_items = max_items
        self.max_bytes = max_bytes

    def put(self, item: Any, size: int) -> bool:
        """Queue ``item`` (``size`` bytes), waiting for room; False once closed."""
        with self._cv:
            while not self._closed and self._items and (
                    len(self._items) >= self.max_items or self._bytes + size > self.max_bytes):
                self._cv.wait()
            if self._closed:
                return False
            self._items.append((item, size))
            self._bytes += size
            self._cv.notify_all()
            return True

    def get(self, timeout_s: float) -> Any:
        """The next item, or ``_NOTHING`` when none arrived within ``timeout_s``."""
        with self._cv:
            if not self._items:
                self._cv.wait(timeout_s)
            if not self._items:
                return _NOTHING
            item, size = self._items.popleft()
            self._bytes -= size
            self._cv.notify_all()
            return item

    def close(self) -> None:
        """Drop what is queued and release a waiting :meth:`put`."""
        with self._cv:
            self._closed = True
            self._items.clear()
            self._bytes = 0
            self._cv.notify_all()


def spin_player(node: BagPlayer, executor: Any | None = None) -> int:
    """Start ``node`` and spin it until playback ends; the exit code (0, or 1 on error).

    Raises:
        EyeInHandError: the error that ended playback (bag read failure).
    """
    own = executor is None
    ex = executor or SingleThreadedExecutor(context=node.context)
    try:
        ex.add_node(node)
        node.start()
        while not node.finished and node.context.ok():
            ex.spin_once(timeout_sec=0.1)
    finally:
        ex.remove_node(node)
        node.stop()
        if own:  # before the context goes: a garbage-collected executor can crash rclpy
            ex.shutdown()
    if node.error is not None:
        if isinstance(node.error, EyeInHandError):
            raise node.error
        raise BagError(f"playback of {node.config.bag} failed: {node.error}") from node.error
    return 0


def main(args: list[str] | None = None) -> None:
    """Console-script entry point (``ros2 run eye_in_hand bag_player --ros-args -p bag:=...``)."""
    sigterm_as_interrupt()
    use_large_data_profile()  # large images over shared memory (see ros/dds.py)
    sys.exit(guard("bag_player", lambda: run_with_executor(BagPlayer, spin_player, args),
                   args))

if __name__ == "__main__":
    main()
