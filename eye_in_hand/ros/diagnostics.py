"""Node diagnostics: counters, gauges and level rules published as ``DiagnosticArray``.

A :class:`NodeDiagnostics` attaches to a node the way tf2's ``TransformListener`` does and
publishes one ``diagnostic_msgs/DiagnosticStatus`` on the relative topic ``diagnostics`` every
``period_s`` (default 1 s)::

    self.diag = NodeDiagnostics(self, hardware_id="stereo_left")
    self.diag.expect_rate("frames", min_hz=5.0)          # WARN when input slows or stops
    self.diag.warn_above("latency_ms", 50.0)
    ...
    self.diag.count("frames")                             # in a callback
    self.diag.gauge("latency_ms", 3.1)
    self.diag.report("bad_encoding", f"left/image_raw: {exc}")  # logs once, counts the rest

The status level is the highest of the rules' verdicts and of the levels of the problems
reported since the previous publication (so a burst of bad messages shows as WARN for one
period, and the status returns to OK when they stop). Values list every counter (total and rate
over the last period), every gauge, and the count of every reported cause.

:class:`OncePerCause` is the "log once per cause" helper on its own: it logs the first
occurrence of each distinct cause at warning level and only counts the rest, so a node fed a
stream of bad messages neither floods its log nor hides the problem.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType

from eye_in_hand.errors import ConfigError
from eye_in_hand.ros.qos import RESULT_QOS

__all__ = [
    "OK",
    "WARN",
    "ERROR",
    "STALE",
    "LEVEL_NAMES",
    "Snapshot",
    "Rule",
    "OncePerCause",
    "NodeDiagnostics",
]

#: Levels of ``diagnostic_msgs/DiagnosticStatus`` as ints.
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES: dict[int, str] = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}


def _check_level(level: int) -> int:
    if level not in LEVEL_NAMES:
        raise ValueError(f"level: expected one of {sorted(LEVEL_NAMES)}, got {level!r}")
    return int(level)


@dataclass(frozen=True)
class Snapshot:
    """What the level rules see at one publication.

    Attributes:
        counters: counter totals since start.
        deltas: counter increments since the previous publication.
        rates: ``deltas / period`` in Hz (period = wall time since the previous publication).
        gauges: last value of every gauge.
        causes: number of occurrences of every reported cause since start.
        ages: seconds since each counter or gauge was last updated.
        uptime_s: seconds since the helper was created.
    """

    counters: Mapping[str, int]
    deltas: Mapping[str, int]
    rates: Mapping[str, float]
    gauges: Mapping[str, float | str]
    causes: Mapping[str, int]
    ages: Mapping[str, float]
    uptime_s: float

    def age(self, key: str) -> float:
        """Seconds since ``key`` was last updated (``inf`` when never)."""
        return self.ages.get(key, math.inf)


#: A level rule: returns ``(level, message)`` when it has something to say, else None.
Rule = Callable[[Snapshot], "tuple[int, str] | None"]


class OncePerCause:
    """Log the first occurrence of each distinct cause, count every occurrence.

    Args:
        logger: an rclpy logger (``node.get_logger()``) or anything with ``warning`` / ``error``.
    """

    def __init__(self, logger: Any) -> None:
        self._logger = logger
        self._counts: dict[str, int] = {}
        self._lock = threading.Lock()

    @property
    def counts(self) -> dict[str, int]:
        """Occurrences per cause (a copy)."""
        with self._lock:
            return dict(self._counts)

    def report(self, cause: str, message: str, *, level: int = WARN) -> bool:
        """Record one occurrence of ``cause``; log ``message`` if it is the first.

        Args:
            cause: a short stable key (``"bad_encoding"``, ``"no_pose_at_stamp"``); distinct
                causes are logged separately.
            message: what happened and where (topic, stamp, field).
            level: WARN (default) logs at warning level, ERROR at error level.

        Returns:
            True when this was the first occurrence (and it was logged).
        """
        _check_level(level)
        with self._lock:
            n = self._counts.get(cause, 0) + 1
            self._counts[cause] = n
        if n == 1:
            text = f"{message} [further '{cause}' occurrences are counted on diagnostics]"
            # Two call sites: rclpy's logger refuses one site logging at two severities.
            if level >= ERROR:
                self._logger.error(text)
            else:
                self._logger.warning(text)
        return n == 1


@dataclass
class _Entry:
    value: Any = 0
    last_update: float = -math.inf


@dataclass
class _PeriodProblems:
    # cause -> (highest level this period, latest message)
    messages: dict[str, tuple[int, str]] = field(default_factory=dict)


class NodeDiagnostics:
    """Counters, gauges and level rules of one node, published on ``diagnostics``.

    Thread-safe: counters and gauges may be updated from any callback group.

    Args:
        node: the ``rclpy.node.Node`` to attach to (publisher and timer are created on it).
        name: status name (default: the node's name).
        hardware_id: ``hardware_id`` of the status (e.g. the camera's serial).
        period_s: publication period in seconds of steady (wall) time, also under
            ``use_sim_time``; ``0`` disables the timer (call :meth:`publish` yourself).
        topic: relative topic name, default ``diagnostics``.
        qos: publisher QoS (default: reliable, keep last 10).
        clock: monotonic seconds source for rates and ages (tests may inject one).

    Raises:
        ConfigError: a negative or non-finite period.
    """

    def __init__(self, node: Any, *, name: str | None = None, hardware_id: str = "",
                 period_s: float = 1.0, topic: str = "diagnostics", qos: Any = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not (math.isfinite(period_s) and period_s >= 0):
            raise ConfigError(f"diagnostics period_s: expected >= 0 s, got {period_s}")
        self._node = node
        self.name = name or node.get_name()
        self.hardware_id = hardware_id
        self._clock = clock
        self._lock = threading.Lock()
        self._counters: dict[str, _Entry] = {}
        self._gauges: dict[str, _Entry] = {}
        self._last_totals: dict[str, int] = {}
        self._rules: list[Rule] = []
        self._problems = _PeriodProblems()
        self._once = OncePerCause(node.get_logger())
        self._start = clock()
        self._last_publish = self._start
        self._pub = node.create_publisher(DiagnosticArray, topic, qos or RESULT_QOS)
        #: the publication's timer (None without a period): a node awake anyway may run it
        #: early (eye_in_hand.ros.executor.run_due_timers)
        self.timer: Any = None
        if period_s > 0:
            # Steady time: diagnostics keep coming while simulated time (use_sim_time) stands
            # still, which is exactly when "no frames" must be reported.
            self.timer = node.create_timer(period_s, self.publish,
                                           clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.published = 0

    # -- updates ---------------------------------------------------------------------------
    def count(self, key: str, n: int = 1) -> None:
        """Add ``n`` to counter ``key`` (created at 0 on first use)."""
        now = self._clock()
        with self._lock:
            entry = self._counters.setdefault(key, _Entry(0))
            entry.value += int(n)
            entry.last_update = now

    def declare_counter(self, *keys: str) -> None:
        """Create counters at 0 so they appear (and rate rules apply) before the first event."""
        with self._lock:
            for key in keys:
                self._counters.setdefault(key, _Entry(0))

    def gauge(self, key: str, value: float | int | str) -> None:
        """Set gauge ``key`` to ``value`` (a number or a short text)."""
        now = self._clock()
        with self._lock:
            entry = self._gauges.setdefault(key, _Entry(0))
            entry.value = value
            entry.last_update = now

    def report(self, cause: str, message: str, *, level: int = WARN) -> bool:
        """Report a problem (bad message, failed step): log once per cause, count, raise level.

        The status is at least ``level`` at the next publication, with ``message`` in it.

        Returns:
            True when this cause occurred for the first time (the message was logged).
        """
        first = self._once.report(cause, message, level=level)
        with self._lock:
            previous = self._problems.messages.get(cause, (OK, ""))[0]
            self._problems.messages[cause] = (max(previous, level), message)
        return first

    @property
    def causes(self) -> dict[str, int]:
        """Occurrences of every reported cause since start."""
        return self._once.counts

    def counter(self, key: str) -> int:
        """Current total of counter ``key`` (0 if never counted)."""
        with self._lock:
            entry = self._counters.get(key)
            return int(entry.value) if entry else 0

    # -- rules -----------------------------------------------------------------------------
    def add_rule(self, rule: Rule) -> None:
        """Add a level rule evaluated at every publication."""
        self._rules.append(rule)

    def expect_rate(self, key: str, min_hz: float, *, level: int = WARN) -> None:
        """``level`` when counter ``key`` grew slower than ``min_hz`` over the last period."""
        _check_level(level)
        self.declare_counter(key)

        def rule(s: Snapshot) -> tuple[int, str] | None:
            rate = s.rates.get(key, 0.0)
            return (level, f"{key} at {rate:.2f} Hz < {min_hz:g} Hz") if rate < min_hz else None

        self.add_rule(rule)

    def warn_above(self, key: str, threshold: float, *, level: int = WARN) -> None:
        """``level`` when numeric gauge ``key`` exceeds ``threshold``."""
        _check_level(level)

        def rule(s: Snapshot) -> tuple[int, str] | None:
            v = s.gauges.get(key)
            if isinstance(v, (int, float)) and v > threshold:
                return level, f"{key} = {v:g} > {threshold:g}"
            return None

        self.add_rule(rule)

    def warn_below(self, key: str, threshold: float, *, level: int = WARN) -> None:
        """``level`` when numeric gauge ``key`` is below ``threshold``."""
        _check_level(level)

        def rule(s: Snapshot) -> tuple[int, str] | None:
            v = s.gauges.get(key)
            if isinstance(v, (int, float)) and v < threshold:
                return level, f"{key} = {v:g} < {threshold:g}"
            return None

        self.add_rule(rule)

    def stale_after(self, key: str, seconds: float, *, level: int = WARN) -> None:
        """``level`` when counter or gauge ``key`` was not updated for ``seconds``.

        Before the first update the age counts from the helper's creation.
        """
        _check_level(level)

        def rule(s: Snapshot) -> tuple[int, str] | None:
            age = min(s.age(key), s.uptime_s)
            if age > seconds:
                return level, f"no {key} for {age:.1f} s"
            return None

        self.add_rule(rule)

    # -- evaluation and publication --------------------------------------------------------
    def snapshot(self, *, advance: bool = False) -> Snapshot:
        """The current figures; with ``advance`` a new rate period starts."""
        now = self._clock()
        with self._lock:
            period = max(now - self._last_publish, 1e-9)
            totals = {k: int(e.value) for k, e in self._counters.items()}
            deltas = {k: v - self._last_totals.get(k, 0) for k, v in totals.items()}
            ages = {k: now - e.last_update for k, e in self._counters.items()}
            ages.update({k: now - e.last_update for k, e in self._gauges.items()})
            gauges = {k: e.value for k, e in self._gauges.items()}
            if advance:
                self._last_totals = totals
                self._last_publish = now
        return Snapshot(counters=totals, deltas=deltas,
                        rates={k: d / period for k, d in deltas.items()}, gauges=gauges,
                        causes=self._once.counts, ages=ages, uptime_s=now - self._start)

    def evaluate(self, snapshot: Snapshot | None = None, *,
                 consume_problems: bool = False) -> tuple[int, str]:
        """The status level and message for ``snapshot`` (default: now).

        Raises:
            ValueError: a rule returned an invalid level.
        """
        s = snapshot or self.snapshot()
        verdicts: list[tuple[int, str]] = []
        for rule in self._rules:
            out = rule(s)
            if out is not None:
                verdicts.append((_check_level(out[0]), str(out[1])))
        with self._lock:
            problems = self._problems
            if consume_problems:
                self._problems = _PeriodProblems()
        for cause, (level, message) in problems.messages.items():
            verdicts.append((level, f"{cause}: {message}"))
        verdicts = [v for v in verdicts if v[0] > OK]
        if not verdicts:
            return OK, "OK"
        ordered = sorted(verdicts, key=lambda v: -v[0])  # stable: rules first, then causes
        return ordered[0][0], "; ".join(m for _, m in ordered)

    def build_status(self, *, advance: bool = False) -> Any:
        """A ``diagnostic_msgs.msg.DiagnosticStatus`` with the current level, message, values."""
        s = self.snapshot(advance=advance)
        level, message = self.evaluate(s, consume_problems=advance)
        values = []
        for key in sorted(s.counters):
            values.append(KeyValue(key=key, value=str(s.counters[key])))
            values.append(KeyValue(key=f"{key} rate (Hz)", value=f"{s.rates[key]:.3f}"))
        for key in sorted(s.gauges):
            v = s.gauges[key]
            values.append(KeyValue(key=key, value=f"{v:.6g}" if isinstance(v, float) else str(v)))
        for cause, n in sorted(s.causes.items()):
            values.append(KeyValue(key=f"problem: {cause}", value=str(n)))
        return DiagnosticStatus(level=bytes([level]), name=self.name, message=message,
                                hardware_id=self.hardware_id, values=values)

    def publish(self) -> Any:
        """Publish one ``DiagnosticArray`` now (the timer calls this) and start a new period.

        Returns:
            The published message.
        """
        if self._pub is None:
            raise RuntimeError(f"diagnostics of {self.name}: publish() after destroy()")
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = [self.build_status(advance=True)]
        self._pub.publish(msg)
        self.published += 1
        return msg

    def destroy(self) -> None:
        """Remove the timer and the publisher from the node."""
        if self.timer is not None:
            self._node.destroy_timer(self.timer)
            self.timer = None
        if self._pub is not None:
            self._node.destroy_publisher(self._pub)
            self._pub = None
