"""Output publishers without per-publisher QoS-event handlers, and one periodic QoS check.

rclpy gives every publisher two event handlers (incompatible QoS, incompatible type) that its
Python executor puts in the wait set it builds at every wake-up: a node of a dozen publishers
pays for 24 handlers on each received message. On the camera-rate nodes (``hand_eye``,
``detect_triangulate``) that was most of the executor's CPU per message beyond the bare wake-up
(`benchmarks/bench_ros_glue.py --wakeups`, docs/localization.md "Live latency").

:class:`OutputPublishers` makes the nodes' output publishers without those handlers and keeps
what they were for: every :data:`QOS_CHECK_PERIOD_S` it looks up the subscriptions on each
publisher's topic and reports one that asks for a QoS the publisher cannot give (a
transient-local subscriber of a volatile topic, a reliable one of a best-effort topic), on the
node's log and ``diagnostics`` (cause ``incompatible_qos``), naming the topic, the subscribing
node and the policy. The subscriber's own side still gets rclpy's warning as before.

This module imports rclpy.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import QoSCompatibility, QoSProfile, qos_check_compatible

__all__ = ["OutputPublishers", "QOS_CHECK_PERIOD_S"]

#: How often the subscriptions of the output topics are checked for an incompatible QoS (s).
QOS_CHECK_PERIOD_S = 2.0


class OutputPublishers:
    """Make a node's output publishers and check their subscribers' QoS periodically.

    Args:
        node: the rclpy node.
        report: ``report(cause, message)``, e.g. ``NodeDiagnostics.report`` (logs once per
            cause, counts, raises the diagnostics level).
        period_s: the check's period (steady time).
    """

    def __init__(self, node: Any, report: Callable[[str, str], Any],
                 period_s: float = QOS_CHECK_PERIOD_S) -> None:
        self._node = node
        self._report = report
        self._publishers: list[Any] = []
        self._reported: set[tuple[str, str]] = set()
        #: the check's timer: a node awake anyway may run it early
        #: (eye_in_hand.ros.executor.run_due_timers)
        self.timer = node.create_timer(period_s, self.check,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def create(self, msg_type: Any, topic: str, qos: QoSProfile) -> Any:
        """``node.create_publisher(msg_type, topic, qos)`` without QoS-event handlers; its
        subscribers are checked by :meth:`check`."""
        pub = self._node.create_publisher(
            msg_type, topic, qos, event_callbacks=PublisherEventCallbacks(
                use_default_callbacks=False))
        self._publishers.append(pub)
        return pub

    def check(self) -> list[str]:
        """Report each subscription (new since the last check) that cannot match its topic's
        publisher; the messages of this check."""
        out = []
        me = (self._node.get_namespace(), self._node.get_name())
        for pub in list(self._publishers):    # the detector adds some on its worker
            topic = pub.topic_name
            # the profile as the middleware completed it (the graph's, as the subscribers'):
            # the requested one leaves liveliness and deadlines to the system default
            mine = [i.qos_profile for i in self._node.get_publishers_info_by_topic(topic)
                    if (i.node_namespace, i.node_name) == me]
            if not mine:
                continue
            for info in self._node.get_subscriptions_info_by_topic(topic):
                compat, reason = qos_check_compatible(mine[0], info.qos_profile)
                if compat != QoSCompatibility.ERROR:
                    continue
                who = (info.node_namespace.rstrip("/") + "/" + info.node_name) or "?"
                if (topic, who) in self._reported:
                    continue
                self._reported.add((topic, who))
                text = (f"{topic}: subscription of {who} requests a QoS this node's publisher "
                        f"does not offer ({reason.strip() or 'incompatible'}): it receives "
                        "nothing; see docs/ros.md (QoS profiles)")
                self._report("incompatible_qos", text)
                out.append(text)
        return out

    def destroy(self) -> None:
        """Stop the periodic check."""
        self._node.destroy_timer(self.timer)
