"""The ``bag_player`` node's pacing: the bag read ahead on a thread, each message handed out at
its due time.

:class:`PacedPlayback` is a part of :class:`eye_in_hand.nodes.bag_player.BagPlayer`, built with
explicit arguments; the node publishes what it hands out, and the damaged regions its reader
skips are reported on the node's diagnostics (:class:`ReportedDamage`). Each message is due at
``start + (t - t_first) / rate`` on the monotonic clock, so timing does not drift: a slow
publish delays only the messages that fall due while it runs, never the schedule of the rest.
A reader thread decodes the bag ahead (at most 256 messages and 64 MiB,
:class:`~eye_in_hand.ros.bag_queues.PrefetchQueue`), so storage I/O and decompression do not
delay publishing either.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from eye_in_hand.io.bags import Damage, DamageLog, iter_messages
from eye_in_hand.ros.bag_queues import NOTHING, PrefetchQueue

__all__ = ["PacedPlayback", "ReportedDamage"]

_END = object()


class PacedPlayback:
    """Passes over a bag's messages at the recorded pace, scaled by ``rate``.

    Args:
        path: the bag directory or storage file.
        topics: the topics to read.
        first_ns: bag time of the first message to play (the bag's start + ``start_offset``).
        rate: playback speed factor (2.0: twice as fast).
        damage: where the reader records the damaged regions it skips.
        stop: set to end a pass early.
    """

    def __init__(self, path: str | Path, topics: Sequence[str], first_ns: int, rate: float,
                 damage: DamageLog, stop: threading.Event) -> None:
        self.path = path
        self.topics = list(topics)
        self.first_ns = first_ns
        self.rate = rate
        self._damage = damage
        self._stop = stop
        self._lock = threading.Lock()
        # playback time: (monotonic start, bag time at that instant); None before the start
        self._timebase: tuple[float, int] | None = None

    @property
    def timebase(self) -> tuple[float, int] | None:
        """(monotonic time, bag time) at the start of the current pass; None before the
        first."""
        with self._lock:
            return self._timebase

    def now_bag_ns(self) -> int | None:
        """The bag time playback has reached (None before the first pass starts)."""
        base = self.timebase
        if base is None:
            return None
        mono0, bag0 = base
        return bag0 + int((time.monotonic() - mono0) * self.rate * 1e9)

    def play_once(self, publish: Callable[[str, bytes, float], None]) -> None:
        """One pass: ``publish(topic, raw, due)`` for each message once it is due (``due`` on
        the monotonic clock); returns at the end of the bag or when ``stop`` is set.

        Raises:
            BaseException: what ended the reader (a bag read failure), re-raised here.
        """
        buffer = PrefetchQueue()
        reader = threading.Thread(target=self._read, args=(buffer,), daemon=True,
                                  name="bag_reader")
        reader.start()
        try:
            rate = self.rate
            mono0 = time.monotonic()
            with self._lock:
                self._timebase = (mono0, self.first_ns)
            while not self._stop.is_set():
                item = buffer.get(timeout_s=0.1)
                if item is NOTHING:
                    continue
                if item is _END:
                    return
                if isinstance(item, BaseException):
                    raise item
                topic, _msgtype, stamp, raw = item
                due = mono0 + (stamp - self.first_ns) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
                publish(topic, raw, due)
        finally:
            buffer.close()
            reader.join(5.0)

    def _read(self, out: PrefetchQueue) -> None:
        try:
            for item in iter_messages(self.path, topics=self.topics, start_ns=self.first_ns,
                                      damage=self._damage):
                if not out.put(item, len(item[3])):
                    return  # the pass ended (stop, or the publisher gave up)
            out.put(_END, 0)
        except BaseException as exc:  # handed to the publishing thread, which re-raises it
            out.put(exc, 0)


class ReportedDamage(DamageLog):
    """The player's damage log: each damaged region is also logged and reported once (per
    region: a looping player meets the same damage every pass) and counted on diagnostics.

    Args:
        diag: the node's diagnostics (counters ``damaged_regions``, ``messages_lost``; cause
            ``damaged:<file>:<where>``).
    """

    def __init__(self, diag: Any) -> None:
        super().__init__()
        self._diag = diag

    def add(self, damage: Damage) -> None:
        before = len(self)
        super().add(damage)
        if len(self) == before:      # met again (a later loop): counted once
            return
        self._diag.count("damaged_regions")
        self._diag.count("messages_lost", damage.messages or 0)
        self._diag.report(f"damaged:{damage.file}:{damage.where}",
                          f"damaged bag, skipped: {damage.describe()}")
