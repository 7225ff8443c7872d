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
from collections.abc import Mapping
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from eye_in_hand.errors import BagError, EyeInHandError
from eye_in_hand.io.bags import BagInfo, bag_info
from eye_in_hand.nodes.bag_player_config import NODE_PARAMETERS, declare_player_config
from eye_in_hand.nodes.bag_player_pacing import PacedPlayback, ReportedDamage
from eye_in_hand.nodes.bag_player_topics import PlayedTopics
from eye_in_hand.ros.diagnostics import ERROR, NodeDiagnostics
from eye_in_hand.ros.node_main import (
    guard,
    prepare_process,
    run_with_executor,
    sigterm_as_interrupt,
)
from eye_in_hand.ros.spin import spin_node

__all__ = [
    "parameter_names",
    "BagPlayer",
    "spin_player",
    "main",
]

#: Pause after every topic has a subscriber, before the first message (wait mode only): the
#: subscribers must match the player's writers too, and on a loaded 2-core machine with nodes
#: still starting that took more than 0.5 s (the first robot poses of a replay were lost).
DISCOVERY_SETTLE_S = 1.5

#: How long playback waits at its end for reliable subscribers to acknowledge every message (s)
ACK_TIMEOUT_S = 10.0


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
        self.config = declare_player_config(self)
        self.info: BagInfo = bag_info(self.config.bag)
        self._stop = threading.Event()
        self._done = threading.Event()
        self._threads: list[threading.Thread] = []
        self._error: BaseException | None = None
        self.loops_done = 0

        wanted = self.config.topics or tuple(self.info.topics)
        unknown = [t for t in wanted if t not in self.info.topics]
        if unknown:
            raise BagError(f"bag {self.info.path} has no topic {', '.join(unknown)}; it has: "
                           f"{', '.join(self.info.topics) or 'no topics'}")
        self.diag = NodeDiagnostics(self, hardware_id=str(self.info.path))
        self.diag.declare_counter("published", "damaged_regions", "messages_lost")
        self.damage = ReportedDamage(self.diag)
        self.topics = PlayedTopics(self, self.info, wanted, self.diag)
        self.published = self.topics.published
        self.skipped_types = self.topics.skipped_types
        self.type_mismatches = self.topics.type_mismatches
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
        self.playback = PacedPlayback(self.info.path, list(self.topics.publishers), first,
                                       self.config.rate, self.damage, self._stop)

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
            f"playing {self.info.path}: {len(self.topics.publishers)} topic(s), "
            f"{sum(self.info.topics[t].count for t in self.topics.publishers)} message(s), "
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

    def _publish_clock(self) -> None:
        if self._done.is_set() or self._clock_pub is None:
            return
        now = self.playback.now_bag_ns()
        if now is None:
            now = self.playback.first_ns
        msg = self._clock_msg()
        msg.clock.sec, msg.clock.nanosec = divmod(now, 1_000_000_000)
        self._clock_pub.publish(msg)

    def _wait_for_subscribers(self) -> None:
        deadline = time.monotonic() + self.config.wait_for_subscribers
        while not self._stop.is_set():
            waiting = [t for t, p in self.topics.publishers.items()
                       if p.get_subscription_count() == 0]
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

    def _run(self) -> None:
        try:
            if self.config.wait_for_subscribers > 0:
                self._wait_for_subscribers()
            self.diag.gauge("state", "playing")
            while not self._stop.is_set():
                self.playback.play_once(self._publish)
                self.loops_done += 1
                self.diag.gauge("loops", self.loops_done)
                if not self.config.loop or not self.topics.publishers:
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
        for name, pub in self.topics.publishers.items():
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

    def _publish(self, topic: str, raw: bytes, due: float) -> None:
        """Publish one message of the bag, due at ``due`` (monotonic clock)."""
        self.topics.publish(topic, raw)
        self.diag.gauge("late_ms", round(max(0.0, time.monotonic() - due) * 1e3, 3))


def spin_player(node: BagPlayer, executor: Any | None = None) -> int:
    """Start ``node`` and spin it until playback ends; the exit code (0, or 1 on error).

    Raises:
        EyeInHandError: the error that ended playback (bag read failure).
    """
    spin_node(node, lambda: not node.finished, node.stop, executor=executor, start=node.start)
    if node.error is not None:
        if isinstance(node.error, EyeInHandError):
            raise node.error
        raise BagError(f"playback of {node.config.bag} failed: {node.error}") from node.error
    return 0


def main(args: list[str] | None = None) -> None:
    """Console-script entry point (``ros2 run eye_in_hand bag_player --ros-args -p bag:=...``)."""
    sigterm_as_interrupt()
    prepare_process()  # large images over shared memory, reused memory blocks
    sys.exit(guard("bag_player", lambda: run_with_executor(BagPlayer, spin_player, args),
                   args))

if __name__ == "__main__":
    main()
