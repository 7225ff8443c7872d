"""A bounded drop-oldest hand-over from a node's executor thread to its worker thread.

``detect_triangulate``'s image callbacks only pair frames and put each stereo pair on a
:class:`DropOldestQueue`; the node's worker takes them off and locates the targets. No rclpy.
"""
from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

from eye_in_hand.errors import InputError

__all__ = ["DropOldestQueue"]

T = TypeVar("T")


class DropOldestQueue(Generic[T]):
    """Bounded drop-oldest hand-over from the executor thread to a worker.

    Holds at most ``depth`` items; putting one into a full queue drops the oldest waiting item.
    ``depth`` 1 keeps only the newest item (lowest latency, drops on any hiccup); a few items
    ride out a stall of the worker (a garbage collection, a burst of DDS deliveries) without
    losing frames, at the cost of a little latency for the frames that waited.

    Raises:
        InputError: ``depth`` below 1.
    """

    def __init__(self, depth: int = 1) -> None:
        if depth < 1:
            raise InputError(f"queue depth must be >= 1, got {depth}")
        self._cond = threading.Condition()
        self._items: deque[T] = deque()
        self._depth = depth
        self._stop = False
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Queue the item; returns True when an unprocessed older item was dropped for it."""
        with self._cond:
            dropped = len(self._items) >= self._depth
            if dropped:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()
        return dropped

    def take(self, timeout_s: float) -> T | None:
        """The oldest waiting item, waiting up to ``timeout_s`` for one (None: none came)."""
        with self._cond:
            if not self._items and not self._stop:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def stop(self) -> None:
        """Wake a waiting :meth:`take`; :attr:`stopped` is True from now on."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()

    @property
    def stopped(self) -> bool:
        return self._stop
