"""The ``bag_recorder`` node's writer thread: the one thread that touches the bag.

:class:`WriterThread` is a part of :class:`eye_in_hand.nodes.bag_recorder.BagRecorder`, built
with explicit arguments. It owns the bag (sqlite3 connections are bound to their thread): it
creates the :class:`~eye_in_hand.io.bags.BagWriter`, runs calls on it on request
(``add_topic``) and writes the messages the node's callbacks queue
(:class:`~eye_in_hand.ros.bag_queues.WriteQueue`, bounded in bytes: a callback never waits for
the disk), until :meth:`WriterThread.close` finishes the bag.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from eye_in_hand.errors import BagError
from eye_in_hand.io.bags import BagWriter
from eye_in_hand.ros.bag_queues import WriteQueue

__all__ = ["WriterThread"]


class WriterThread:
    """A bag written by its own thread.

    Args:
        output: the bag directory to create.
        storage: ``mcap`` or ``sqlite3``.
        compression: ``""`` (none) or ``zstd``.
        max_bytes: bytes of messages that may wait for the disk; beyond that :meth:`put`
            drops.
        written: called in the writer thread after each message, with its topic and None, or
            the :class:`~eye_in_hand.errors.BagError` that kept it out of the bag.

    Raises:
        BagError: the bag cannot be created (exists already, not writable).
    """

    def __init__(self, output: str, storage: str, compression: str, max_bytes: int,
                 written: Callable[[str, BagError | None], None]) -> None:
        self.output = output
        self._written = written
        self._queue = WriteQueue(max_bytes)
        self._close_error: BaseException | None = None
        ready: Future = Future()
        self._thread = threading.Thread(target=self._main, args=(ready, storage, compression),
                                        name="bag_writer", daemon=True)
        self._thread.start()
        self.writer: BagWriter = ready.result()  # re-raises BagError (exists, not writable)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` began: nothing more is accepted."""
        return self._queue.closed

    def put(self, topic: str, stamp: int, raw: bytes) -> bool:
        """Queue one message; False (dropped) when closed or over the byte budget."""
        return self._queue.put(("msg", topic, stamp, raw), len(raw))

    def add_topic(self, name: str, msgtype: str, **kwargs: Any) -> None:
        """:meth:`BagWriter.add_topic <eye_in_hand.io.bags.BagWriter.add_topic>`, run in the
        writer thread (raises what it raises)."""
        self._call(self.writer.add_topic, name, msgtype, **kwargs)

    def _call(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """Run ``fn(*args, **kwargs)`` in the writer thread, wait, and return its result."""
        done: Future = Future()
        if not self._queue.put(("call", fn, args, kwargs, done), 0, force=True):
            raise BagError(f"bag {self.output} is closed")
        return done.result()

    def close(self) -> None:
        """Accept nothing more, write what is queued, and finish the bag (metadata.yaml).

        Raises:
            BagError: the bag could not be finished.
        """
        self._queue.close()
        self._thread.join()  # writes what is queued, then closes the bag
        if self._close_error is not None:
            error, self._close_error = self._close_error, None
            raise BagError(f"cannot finish bag {self.output}: {error}") from error

    def _main(self, ready: Future, storage: str, compression: str) -> None:
        """Create the bag, then run calls and write messages until closed."""
        try:
            writer = BagWriter(self.output, storage=storage, compression=compression or None)
        except BaseException as exc:
            ready.set_exception(exc)
            return
        ready.set_result(writer)
        try:
            while (batch := self._queue.get_batch(timeout_s=0.1)) is not None:
                for item in batch:
                    if item[0] == "call":
                        _, fn, args, kwargs, done = item
                        try:
                            done.set_result(fn(*args, **kwargs))
                        except BaseException as exc:  # handed to the waiting caller
                            done.set_exception(exc)
                    else:
                        self._write(writer, *item[1:])
        finally:
            try:
                writer.close()
            except BaseException as exc:  # re-raised by close() in the caller's thread
                self._close_error = exc

    def _write(self, writer: BagWriter, topic: str, stamp: int, raw: bytes) -> None:
        try:
            writer.write(topic, stamp, raw)
        except BagError as exc:
            self._written(topic, exc)
            return
        self._written(topic, None)
