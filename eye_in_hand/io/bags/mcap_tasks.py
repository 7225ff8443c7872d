"""Compressed MCAP chunks opened by worker processes: images never cross a process boundary.

Decompressing a 30 Hz 1280x720 stereo bag costs more CPU than locating its targets, and one
process decompressing everything is the bottleneck of offline processing on a compressed bag.
Here the reading process only plans and merges; the work is done where the images are used:

* the reading process (:func:`worker_messages`) reads the file's chunk index (the summary
  section ``rosbags`` has parsed), groups consecutive chunks (:func:`iter_groups`: about
  ``group_bytes`` of uncompressed records each, ended where the message index says the left
  and right image topics have as many messages, so that a stereo pair rarely spans two
  groups), and hands each group, as file offsets (:class:`ChunkRef`), to a worker process
  a few groups ahead;
* the worker (:func:`open_group`) maps the file, decompresses the group's chunks with their
  known uncompressed size, keeps them in a small least-recently-used cache, and returns the
  chunk's small messages as bytes and each image as an :class:`ImageRef`: its header, size
  fields and where its bytes lie in the decompressed chunk;
* the reading process merges the messages in exactly the order
  :func:`eye_in_hand.io.bags.mcap_chunks.chunk_messages` gives (log time, ties by chunk position,
  then by record order), so pairing and everything after it see the same stream;
* an image is used where its chunk was opened: ``ImageRef.data`` gives the pixels from the
  process's cache, decompressing the chunk again when it is not there (a pair whose images lie
  in two groups, a chunk evicted from the cache, a pair located in the reading process after a
  worker failed). Correctness never depends on the cache, only speed.

Damaged chunks are reported as :class:`eye_in_hand.io.bags.mcap_chunks.ChunkDamage`, the same
records (and the same messages kept before a bad record) as the serial reader.
"""
from __future__ import annotations

import heapq
import mmap
import threading
from array import array
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from eye_in_hand.errors import ConversionError
from eye_in_hand.io.bags.mcap_chunks import (
    ChunkDamage,
    _address,
    _Chunk,
    _may_hold,
    _messages_of,
    chunk_damage,
)
from eye_in_hand.io.bags.mcap_records import DamagedRecords
from eye_in_hand.io.cdr import CdrHeader, image_from_cdr
from eye_in_hand.io.pages import drop_pages

__all__ = ["ChunkRef", "ImageRef", "iter_groups", "open_group", "worker_messages", "release",
           "GROUP_BYTES", "CACHE_BYTES"]

#: uncompressed records per task (a few 1280x720 stereo pairs)
GROUP_BYTES = 12 << 20
#: decompressed chunks a process keeps (least recently used go first)
CACHE_BYTES = 96 << 20


@dataclass(frozen=True, eq=False)
class ChunkRef:
    """A chunk of an MCAP file, as its chunk index describes it (what a worker needs to read
    it; the attribute names are those of ``rosbags``' chunk info)."""

    path: str
    chunk_start_offset: int
    chunk_length: int
    message_start_time: int
    message_end_time: int
    compression: str
    uncompressed_size: int
    channel_count: dict[int, int] = field(default_factory=dict)
    message_index_offsets: dict[int, int] = field(default_factory=dict)

    @classmethod
    def of(cls, path: str, info: Any) -> ChunkRef:
        return cls(path, int(info.chunk_start_offset), int(info.chunk_length),
                   int(info.message_start_time), int(info.message_end_time),
                   str(info.compression), int(info.uncompressed_size),
                   dict(getattr(info, "channel_count", None) or {}),
                   dict(getattr(info, "message_index_offsets", None) or {}))


class _Cache:
    """This process's mapped files and decompressed chunks (thread-safe, bounded in bytes)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._lock = threading.Lock()
        self._files: dict[str, memoryview] = {}
        self._maps: dict[str, mmap.mmap] = {}
        self._chunks: OrderedDict[tuple[str, int], tuple[_Chunk, memoryview]] = OrderedDict()
        self._bytes = 0
        self.decompressed = 0                 # chunks decompressed (for tests and figures)
        # per cached chunk: the starts of its images not read yet (:meth:`expect`)
        self._unread: dict[tuple[str, int], set[int]] = {}

    def file(self, path: str) -> memoryview:
        with self._lock:
            view = self._files.get(path)
            if view is None:
                with open(path, "rb") as fh:
                    mapped = self._maps[path] = mmap.mmap(fh.fileno(), 0,
                                                          access=mmap.ACCESS_READ)
                view = self._files[path] = memoryview(mapped)
            return view

    def records(self, ref: ChunkRef, verify_crc: bool) -> tuple[_Chunk, memoryview]:
        """The chunk and its decompressed records.

        Raises:
            ValueError: the chunk cannot be read (names its byte offset).
        """
        key = (ref.path, ref.chunk_start_offset)
        with self._lock:
            hit = self._chunks.get(key)
            if hit is not None:
                self._chunks.move_to_end(key)
                return hit
        chunk = _Chunk(ref, self.file(ref.path))
        recs = chunk.records(verify_crc)             # decompressors release the GIL
        if chunk.compression:
            # the compressed bytes are not read again (or, for a chunk dropped from the cache,
            # mapped again from the page cache): out of the resident set, which then stays
            # flat however long the bag is
            mapped = self._maps.get(ref.path)
            if mapped is not None:
                drop_pages(mapped, ref.chunk_start_offset, ref.chunk_length)
        with self._lock:
            self.decompressed += 1
            if chunk.compression and key not in self._chunks:
                self._chunks[key] = (chunk, recs)
                self._bytes += len(recs)
                while self._bytes > self.capacity and len(self._chunks) > 1:
                    k, (_c, old) = self._chunks.popitem(last=False)
                    self._bytes -= len(old)
                    self._unread.pop(k, None)
        return chunk, recs

    def expect(self, ref: ChunkRef, starts: set[int]) -> None:
        """The images of a cached chunk that will be read (once each): the chunk leaves the
        cache when the last of them has been (:meth:`read`), not only when it is the least
        recently used, so that a worker holds the chunks of the pairs still ahead of it."""
        key = (ref.path, ref.chunk_start_offset)
        with self._lock:
            if key in self._chunks and starts:
                self._unread[key] = set(starts)

    def read(self, ref: ChunkRef, start: int) -> None:
        """The image at ``start`` of a chunk has been read (see :meth:`expect`)."""
        key = (ref.path, ref.chunk_start_offset)
        with self._lock:
            unread = self._unread.get(key)
            if unread is None:
                return
            unread.discard(start)
            if not unread:
                del self._unread[key]
                hit = self._chunks.pop(key, None)
                if hit is not None:
                    self._bytes -= len(hit[1])

    def clear(self) -> None:
        """Drop the decompressed chunks and unmap the files (views handed out stay valid)."""
        with self._lock:
            self._chunks.clear()
            self._unread.clear()
            self._bytes = 0
            self._files.clear()
            self._maps.clear()


_CACHE = _Cache(CACHE_BYTES)


def release() -> None:
    """Free this process's chunk cache (the reading process calls it once its pairs are
    located; a worker's goes with the worker)."""
    _CACHE.clear()


@dataclass(frozen=True, eq=False)
class ImageRef:
    """A ``sensor_msgs/Image`` inside a chunk: the fields ``image_to_numpy`` reads, with
    ``data`` fetched from this process's chunk cache when asked for (the chunk decompressed
    again when it is not there).

    ``owner``: the worker process that opened the chunk (None: the reading process), where
    locating the pair costs no decompression.
    """

    chunk: ChunkRef
    start: int                 # the message's CDR bytes in the decompressed records
    nbytes: int
    header: CdrHeader
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    verify_crc: bool = False
    owner: int | None = None

    @property
    def data(self) -> np.ndarray:
        """The pixel bytes, a read-only ``uint8`` view (shape (n,)).

        Raises:
            ConversionError: the chunk no longer reads (changed on disk) or the message no
                longer decodes.
        """
        try:
            _chunk, recs = _CACHE.records(self.chunk, self.verify_crc)
        except ValueError as exc:
            raise ConversionError(f"image at chunk byte {self.chunk.chunk_start_offset}: "
                                  f"{exc}") from exc
        img = image_from_cdr(recs[self.start:self.start + self.nbytes])
        _CACHE.read(self.chunk, self.start)     # the view keeps the records while it is used
        if img is None:
            raise ConversionError("image: not little-endian plain CDR")
        return img.data

    def with_owner(self, owner: int | None) -> ImageRef:
        return ImageRef(self.chunk, self.start, self.nbytes, self.header, self.height,
                        self.width, self.encoding, self.is_bigendian, self.step,
                        self.verify_crc, owner)


#: one message of a chunk as a worker returns it: (log time, index in chunk, channel id,
#: payload); payload is bytes (a small message, or an image that is not plain CDR), an
#: ImageRef, or a ConversionError (an image whose fields do not decode)
Message = tuple[int, int, int, Any]


@dataclass(frozen=True)
class _Channel:
    id: int


def _open_chunk(ref: ChunkRef, channels: dict[int, bool], verify_crc: bool,
                cache: _Cache) -> tuple[list[Message], ChunkDamage | None]:
    wanted = {cid: _Channel(cid) for cid in channels}
    try:
        chunk, recs = cache.records(ref, verify_crc)
    except Exception as exc:  # noqa: BLE001 - record, decompression, size, CRC: the chunk
        return [], chunk_damage(ref, exc, wanted)
    damage = None
    try:
        found = _messages_of(chunk, recs, wanted, 0, 2**64)
    except DamagedRecords as exc:
        found = exc.kept
        damage = chunk_damage(ref, exc, wanted, exc.kept)
    base = _address(recs) if len(recs) else 0
    out: list[Message] = []
    for log_time, _offset, index, chan, view in found:
        cid = chan.id
        payload: Any
        if channels[cid]:
            try:
                img = image_from_cdr(view)
            except ConversionError as exc:
                payload = exc
            else:
                if img is None:
                    payload = bytes(view)
                else:
                    start = _address(view) - base if len(view) else 0
                    payload = ImageRef(ref, start, len(view), img.header, img.height,
                                       img.width, img.encoding, img.is_bigendian, img.step,
                                       verify_crc)
        else:
            payload = bytes(view)
        out.append((log_time, index, cid, payload))
    cache.expect(ref, {p.start for *_m, p in out if isinstance(p, ImageRef)})
    return out, damage


def open_group(refs: Sequence[ChunkRef], channels: dict[int, bool], verify_crc: bool = False
               ) -> list[tuple[list[Message], ChunkDamage | None]]:
    """Decompress and index chunks (a worker task; also run in the reading process when no
    worker can).

    Args:
        refs: the chunks, in reading order.
        channels: wanted channel id -> whether it carries ``sensor_msgs/Image``.
        verify_crc: check each chunk's CRC-32.

    Returns:
        Per chunk: its wanted messages (sorted by log time, then record order) and its
        damage (None: read whole; else the messages are those before the bad record).
    """
    return [_open_chunk(ref, channels, verify_crc, _CACHE) for ref in refs]


def iter_groups(infos: Iterable[Any], group_bytes: int = GROUP_BYTES,
                pair_channels: tuple[int, int] | None = None) -> Iterator[list[Any]]:
    """Consecutive chunks in groups of about ``group_bytes`` uncompressed bytes each, each
    group made when it is asked for.

    A group closes once it holds ``group_bytes`` and, when ``pair_channels`` (left, right
    image channel ids) and the chunks' message index counts are known, once its left and right
    counts are equal, so that the images of a stereo pair rarely lie in two groups (a pair
    that does is still read correctly: see the module docstring).
    """
    current: list[Any] = []
    size = 0
    balance = 0
    for info in infos:
        current.append(info)
        size += int(info.uncompressed_size)
        counts = getattr(info, "channel_count", None) or {}
        if pair_channels is not None:
            balance += int(counts.get(pair_channels[0], 0)) - int(counts.get(pair_channels[1],
                                                                              0))
        if size >= group_bytes and (pair_channels is None or balance == 0 or not counts
                                    or size >= 4 * group_bytes):
            yield current
            current, size = [], 0
    if current:
        yield current


#: submit(group index, function name, args) -> (future, worker index) or None (no worker)
Submit = Callable[[int, str, tuple[Any, ...]], "tuple[Any, int] | None"]


def _opened(planned: Iterator[list[ChunkRef]], submit: Submit, kinds: dict[int, bool],
            verify_crc: bool, ahead: int
            ) -> Iterator[tuple[list[ChunkRef], list[tuple[list[Message], ChunkDamage | None]],
                                int | None]]:
    """Each group of ``planned`` with its chunks' messages and the worker that opened it
    (None: opened here), in order; groups up to ``ahead`` past the one yielded are submitted
    to ``submit``'s workers (a group whose task fails is opened in this process)."""
    fn = f"{__name__}:open_group"
    inflight: dict[int, tuple[list[ChunkRef], Future[Any] | None, int | None]] = {}
    launched = 0
    g = 0
    while True:
        while launched <= g + ahead:                 # groups up to g + ahead in flight
            group = next(planned, None)
            if group is None:
                break
            got = submit(launched, fn, (group, kinds, verify_crc))
            inflight[launched] = (group, *((got[0], got[1]) if got is not None
                                           else (None, None)))
            launched += 1
        if g not in inflight:
            return
        group, fut, owner = inflight.pop(g)
        g += 1
        results = None
        if fut is not None:
            try:
                results = fut.result()
            except Exception:  # noqa: BLE001 - the worker failed: open the group here
                results = None
        if results is None:
            results, owner = open_group(group, kinds, verify_crc), None
        yield group, results, owner


def worker_messages(storage: Any, connections: Sequence[Any], submit: Submit, *,
                    image_channels: set[int], pair_channels: tuple[int, int] | None = None,
                    verify_crc: bool = False, ahead: int = 4,
                    group_bytes: int | None = None,
                    on_damage: Callable[[ChunkDamage], None] | None = None,
                    ) -> Iterator[tuple[Any, int, Any]]:
    """``(connection, log_time_ns, payload)`` of an indexed MCAP file, in the order of
    :func:`eye_in_hand.io.bags.mcap_chunks.chunk_messages`, its chunks opened by ``submit``'s
    workers (:func:`open_group`) ``ahead`` groups in advance (groups of ``group_bytes``,
    default :data:`GROUP_BYTES`).

    Payload: bytes, an :class:`ImageRef` (``owner``: the worker that opened it), or a
    :class:`ConversionError` (an image whose fields do not decode). A group whose task fails
    (the worker died or missed its deadline) is opened in this process.

    Raises:
        ValueError: a damaged chunk, when ``on_damage`` is None.
    """
    channels = {c.id: c for c in connections}
    kinds = {cid: cid in image_channels for cid in channels}
    chunks = storage.chunks.copy()   # a table copy shares its values; unaffected by close
    # the chunks' positions in reading order: a compact index (chunk_table) makes each
    # chunk's info when it is read, and it is not kept for the whole pass here
    order = array("q", (i for _t, _o, i in sorted(
        (c.message_start_time, c.chunk_start_offset, i) for i, c in enumerate(chunks)
        if _may_hold(c, channels))))
    if not order or not channels:
        return
    path = str(storage.path)
    # the groups (and their ChunkRefs, about 0.9 kB a chunk) are made as they are launched,
    # ``ahead`` at a time, not for the whole file at once
    planned = iter_groups((ChunkRef.of(path, chunks[i]) for i in order),
                          GROUP_BYTES if group_bytes is None else group_bytes, pair_channels)

    def report(cd: ChunkDamage) -> None:
        if on_damage is None:
            raise ValueError(cd.reason)
        on_damage(cd)

    pending: list[tuple[int, int, int, int, Any]] = []
    for group, results, owner in _opened(planned, submit, kinds, verify_crc, ahead):
        for ref, (msgs, damage) in zip(group, results, strict=True):
            t0 = ref.message_start_time
            while pending and pending[0][0] < t0:     # nothing later can come before these
                m = heapq.heappop(pending)
                yield channels[m[3]], m[0], m[4]
            if damage is not None:
                report(damage)
            if owner is not None:
                msgs = [(t, i, cid, p.with_owner(owner) if isinstance(p, ImageRef) else p)
                        for t, i, cid, p in msgs]
            for t, i, cid, p in msgs:
                heapq.heappush(pending, (t, ref.chunk_start_offset, i, cid, p))
    while pending:
        m = heapq.heappop(pending)
        yield channels[m[3]], m[0], m[4]
