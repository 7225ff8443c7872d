"""Hand-overs between the bag nodes' DDS side and their bag I/O threads, bounded in bytes.

Bag messages are often images: a queue of them is bounded by what it holds, not only by how
many. :class:`WriteQueue` carries messages from ``bag_recorder``'s callbacks to its writer
thread (a full queue drops, so that a callback never blocks the executor). One message always
fits, however large.

No rclpy: plain threads.
"""
from __future__ import annotations

import threading
from typing import Any

__all__ = ["WriteQueue"]

class WriteQueue:
    """Messages waiting for a writer thread; bounded in bytes, never blocks the callback.

    One message always fits (so a single huge image is never dropped for its size alone).
    """

    def __init__(self, max_bytes: int) -> None:
        self._cv = threading.Condition()
        self._items: list[tuple[Any, ...]] = []
        self._bytes = 0
        self.max_bytes = max_bytes
        self.closed = False

    def put(self, item: tuple[Any, ...], size: int, *, force: bool = False) -> bool:
        """Queue ``item``; False (not queued) when closed or, unless ``force``, over budget."""
        with self._cv:
            if self.closed or (not force and self._items
                               and self._bytes + size > self.max_bytes):
                return False
            self._items.append(item)
            self._bytes += size
            self._cv.notify()
            return True

    def get_batch(self, timeout_s: float) -> list[tuple[Any, ...]] | None:
        """Everything queued (possibly empty after ``timeout_s``); None once closed and empty."""
        with self._cv:
            if not self._items and not self.closed:
                self._cv.wait(timeout_s)
            if not self._items:
                return None if self.closed else []
            batch, self._items, self._bytes = self._items, [], 0
            return batch

    def close(self) -> None:
        """Accept nothing more; :meth:`get_batch` still returns what is queued."""
        with self._cv:
            self.closed = True
            self._cv.notify_all()
