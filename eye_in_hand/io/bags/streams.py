"""Message streams of offline processing: a reader thread, or worker processes that open
compressed MCAP chunks.

:func:`decoded_stream` is what ``process`` reads: ``(topic, log time, message)`` in log-time
order, images as views that are never copied, from a reader thread
(:func:`decoded_on_thread`), or, for a compressed MCAP bag and a ``submit`` to worker
processes, from :func:`decoded_in_workers`.

:func:`worker_readable` says whether a bag is one indexed MCAP file with zstd or lz4 chunks;
:func:`iter_in_workers` then reads it through
:func:`eye_in_hand.io.bags.mcap_tasks.worker_messages`: the same messages, in the same order,
with the same damage records as ``iter_messages(path, topics, views=True, damage=...)``,
images as :class:`eye_in_hand.io.bags.mcap_tasks.ImageRef` (decoded where they are used,
never copied between processes) and other messages as CDR bytes.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, cast

from eye_in_hand.errors import BagError, ConversionError
from eye_in_hand.io.bags.decoding import deserialize
from eye_in_hand.io.bags.formats import format_of
from eye_in_hand.io.bags.reading import _OpenBag, iter_messages
from eye_in_hand.io.bags.records import DamageLog
from eye_in_hand.io.bags.storage import StorageFormat
from eye_in_hand.io.cdr import image_from_cdr, is_image_type

__all__ = ["decoded_stream", "decoded_on_thread", "worker_readable", "iter_in_workers",
           "decoded_in_workers"]

def _storage(bag: _OpenBag) -> tuple[Any, StorageFormat] | None:
    """The bag's one storage file and its format, when the format reads it in worker
    processes (``StorageFormat.worker_readable``: an indexed MCAP file with chunk
    compression)."""
    parts: list[Any] = []
    for reader in bag.readers:
        inner = reader.storage
        if getattr(getattr(inner, "metadata", None), "compression_mode", "") == "message":
            return None
        parts.extend(list(inner.storages) if hasattr(inner, "storages") else [inner])
    if len(parts) != 1:
        return None
    fmt = format_of(parts[0])
    if fmt is None or not fmt.worker_readable(parts[0]):
        return None
    return parts[0], fmt


def worker_readable(path: str | Path) -> bool:
    """Whether the bag is one indexed MCAP storage file whose chunks are zstd or lz4
    compressed (what :func:`iter_in_workers` reads)."""
    try:
        with _OpenBag(path) as bag:
            return _storage(bag) is not None
    except BagError:
        return False


def iter_in_workers(path: str | Path, topics: Iterable[str], submit: Any, *,
                    image_topics: tuple[str, str], verify_crc: bool = False,
                    damage: DamageLog | None = None) -> Iterator[tuple[str, str, int, Any]]:
    """``(topic, msgtype, log_time_ns, payload)`` of a :func:`worker_readable` bag, in log-time
    order, chunks opened by ``submit``'s workers (see
    :func:`eye_in_hand.io.bags.mcap_tasks.worker_messages`).

    Args:
        topics: the topics to read.
        submit: ``submit(group, "module:function", args) -> (future, worker) | None``.
        image_topics: the (left, right) ``sensor_msgs/Image`` topics: their messages come as
            ``ImageRef`` (or a ``ConversionError``, or bytes when not plain CDR).
        verify_crc: check chunk CRCs.
        damage: where damaged chunks go (None: a damaged chunk raises ``BagError``).

    Raises:
        BagError: the bag cannot be opened or is not :func:`worker_readable`; a damaged chunk
            without ``damage``.
    """
    wanted = set(topics)
    with _OpenBag(path) as bag:
        found = _storage(bag)
        if found is None:
            raise BagError(f"{path}: not one MCAP file with compressed chunks")
        storage, fmt = found
        conns = [c for c in storage.connections if c.topic in wanted]
        images = {c.id for c in conns if c.topic in image_topics and is_image_type(c.msgtype)}
        ids = [next((c.id for c in conns if c.topic == t), None) for t in image_topics]
        pair = cast(tuple[int, int] | None, (ids[0], ids[1]) if None not in ids else None)
        index = 0
        try:
            for conn, stamp, payload in fmt.worker_messages(
                    storage, conns, submit, image_channels=images, pair_channels=pair,
                    verify_crc=verify_crc, on_damage=None if damage is None else damage.add):
                yield conn.topic, conn.msgtype, stamp, payload
                index += 1
        except BagError:
            raise
        except ValueError as exc:
            raise BagError(f"cannot read bag {bag.path} after message {index}: "
                           f"{str(exc) or type(exc).__name__}") from exc


def decoded_in_workers(path: str | Path, topics: Iterable[str], typestore: Any, submit: Any, *,
                       image_topics: tuple[str, str], verify_crc: bool = False,
                       damage: DamageLog | None = None) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time_ns, message)`` of :func:`iter_in_workers`: images as ``ImageRef``,
    other messages deserialized; a message that does not decode is handed on as its
    exception (``BagError`` / ``ConversionError``), for the consumer to count.

    Raises:
        BagError: as :func:`iter_in_workers`.
    """
    for topic, msgtype, t_ns, payload in iter_in_workers(
            path, topics, submit, image_topics=image_topics, verify_crc=verify_crc,
            damage=damage):
        msg = payload
        if isinstance(payload, (bytes, bytearray, memoryview)):
            try:
                msg = deserialize(payload, msgtype, typestore)
            except (BagError, ConversionError) as exc:
                msg = exc
        yield topic, t_ns, msg


_END = object()


def decoded_on_thread(path: str | Path, topics: list[str], typestore: Any,
                      verify_crc: bool = False, damage: Any = None
                      ) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time, message), produced on a reader thread (bounded queue).

    The bag is read without copies (memory-mapped MCAP) and images are decoded straight from
    their CDR bytes into views (:func:`eye_in_hand.io.cdr.image_from_cdr`); other messages go
    through the generic deserializer. A message that does not decode is handed on as its
    exception (the consumer counts it and goes on); damaged parts of the bag go to ``damage``
    (a ``DamageLog``) and are skipped; an unreadable bag ends the iteration with the error.
    """
    errors: list[BaseException] = []
    q: queue.Queue[Any] = queue.Queue(maxsize=16)
    stop = threading.Event()

    def decode(raw: Any, msgtype: str) -> Any:
        if is_image_type(msgtype):
            img = image_from_cdr(raw)
            if img is not None:
                return img
        return deserialize(raw, msgtype, typestore)

    def reader() -> None:
        try:
            for topic, msgtype, t_ns, raw in iter_messages(path, topics, views=True,
                                                           verify_crc=verify_crc,
                                                           damage=damage):
                if stop.is_set():
                    return
                try:
                    msg = decode(raw, msgtype)
                except (BagError, ConversionError) as exc:
                    msg = exc
                q.put((topic, t_ns, msg))
        except BaseException as exc:  # handed to the consumer, re-raised there
            errors.append(exc)
        finally:
            q.put(_END)

    th = threading.Thread(target=reader, name="bag-reader", daemon=True)
    th.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                break
            yield item
    finally:
        stop.set()
        while th.is_alive():
            try:
                q.get(timeout=0.05)
            except queue.Empty:
                pass
        th.join()
    if errors:
        raise errors[0]


def decoded_stream(path: str | Path, topics: list[str], typestore: Any, *,
                   verify_crc: bool = False, damage: DamageLog | None = None,
                   image_topics: tuple[str, str] = ("", ""), submit: Any = None,
                   ) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time_ns, message)`` of a bag for offline processing: from worker
    processes (:func:`decoded_in_workers`) when ``submit`` is given (the bag must be
    :func:`worker_readable`), else from a reader thread (:func:`decoded_on_thread`).

    Raises:
        BagError: the bag cannot be read (at the point where it stops).
    """
    if submit is not None:
        return decoded_in_workers(path, topics, typestore, submit, image_topics=image_topics,
                                  verify_crc=verify_crc, damage=damage)
    return decoded_on_thread(path, topics, typestore, verify_crc, damage)
