"""Hand-overs between the bag nodes' DDS side and their bag I/O threads, bounded in bytes.

Bag messages are often images: a queue of them is bounded by what it holds, not only by how
many. :class:`PrefetchQueue` carries messages from ``bag_player``'s reader thread to its
publisher (a full queue makes the reader wait); :class:`WriteQueue` carries messages from
``bag_recorder``'s callbacks to its writer thread (a full queue drops, so that a callback never
blocks the executor). In both, one message always fits, however large.

No rclpy: plain threads.
"""
from __future__ import annotations

import threading
from collections import deque
from typing import Any

__all__ = ["NOTHING", "PrefetchQueue", "WriteQueue"]

#: What :meth:`PrefetchQueue.get` returns when nothing arrived in time.
NOTHING = object()


class PrefetchQueue:
    """Hand-over from a reader thread to a publisher, bounded in messages and bytes.

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
        """The next item, or :data:`NOTHING` when none arrived within ``timeout_s``."""
        with self._cv:
            if not self._items:
                self._cv.wait(timeout_s)
            if not self._items:
                return NOTHING
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
