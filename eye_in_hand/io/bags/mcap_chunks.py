"""Fast message reading of indexed MCAP files: memory-mapped, zero-copy, chunks decompressed ahead.

``rosbags`` reads an MCAP chunk into memory, wraps it in a ``BytesIO`` and copies every message
out of it: two copies of every byte, about 0.8 GB/s here, which is all the time a 30 Hz 1280x720
stereo bag allows at 5x real time. This reader uses the chunk index ``rosbags`` has already
parsed (the file's summary section) and

* maps the file (``mmap``): a message of an uncompressed chunk is a ``memoryview`` of the file's
  pages, never copied (the page cache is read at memory speed);
* decompresses zstd / lz4 chunks on a small thread pool a few chunks ahead of the consumer
  (the decompressors release the GIL), each message then a view of its decompressed chunk
  (offline processing has worker processes open compressed chunks instead:
  :mod:`eye_in_hand.io.bags.mcap_tasks`);
* checks chunk CRCs unless told not to (``verify_crc=False``, what offline processing uses: the
  MCAP reference readers skip them by default too, and CRC-32 runs at ~0.35 GB/s here).

Order is the one ``rosbags`` gives: log time, ties by chunk position in the file, then by record
order inside the chunk; chunks that overlap in time are merged.

Files it cannot read this way (no summary, no chunk index) are left to ``rosbags``:
:func:`supports` says which. Like ``rosbags``' indexed reader, it reads the messages inside
chunks; a writer that puts messages outside chunks while also writing a chunk index is not
known to exist.

While a file is being read, :func:`file_location` tells where in it a view of an uncompressed
message lies, so that another process can map the same pages instead of receiving a copy
(offline processing hands images to worker processes this way).
"""
from __future__ import annotations

import heapq
import mmap
import threading
import zlib
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.io.bags.mcap_records import (
    OP_CHUNK,
    RECORD,
    DamagedRecords,
    Found,
    chunk_head,
)
from eye_in_hand.io.bags.mcap_records import chunk_messages as _chunk_records
from eye_in_hand.io.pages import drop_pages

__all__ = ["supports", "chunk_messages", "file_location", "ChunkDamage", "chunk_damage",
           "zstd_binding"]

_MAPPED: dict[int, tuple[int, int, str]] = {}     # id -> (base address, length, path)
_MAPPED_LOCK = threading.Lock()


def _address(buffer: Any) -> int:
    return int(np.frombuffer(buffer, dtype=np.uint8, count=1).ctypes.data) if len(buffer) else 0




def file_location(array: Any) -> tuple[str, int] | None:
    """``(path, byte offset)`` of a buffer (a numpy array or memoryview of message data) that
    lies in an MCAP file being read by :func:`chunk_messages`; None otherwise (a decompressed
    chunk, or a file whose iteration has ended)."""
    arr = np.asarray(array) if not isinstance(array, memoryview) else \
        np.frombuffer(array, dtype=np.uint8)
    if arr.nbytes == 0:
        return None
    start = int(arr.__array_interface__["data"][0])
    with _MAPPED_LOCK:
        for base, length, path in _MAPPED.values():
            if base <= start and start + arr.nbytes <= base + length:
                return path, start - base
    return None


def supports(storage: Any) -> bool:
    """Whether ``storage`` (a ``rosbags`` storage reader) is an indexed MCAP file read here."""
    path = getattr(storage, "path", None)
    chunks = getattr(storage, "chunks", None)
    if path is None or not chunks or Path(path).suffix != ".mcap":
        return False
    first = chunks[0]
    return all(hasattr(first, name) for name in (
        "message_start_time", "message_end_time", "chunk_start_offset", "chunk_length",
        "compression", "compressed_size", "uncompressed_size"))


def _zstd_decompressor() -> Callable[[Any, int], Any]:
    """zstd decompression of a whole chunk whose uncompressed size is known.

    The binding is ``zstandard`` (a declared dependency): its one-shot decompression of a
    frame whose size is known measured 0.55-0.61 GB of output per CPU-second on the noisy
    1280x720 chunks of ``benchmarks/bench_localization.py`` (a loaded machine), against
    0.21-0.27 for the standard library's ``compression.zstd`` (Python >= 3.14) / its backport
    ``backports.zstd`` given the size (``max_length``) and the same libzstd 1.5.7
    (``benchmarks/bench_bags.py --zstd``). Those are the fallback where ``zstandard`` is
    missing (a ROS install without the pip dependencies). Neither decompresses into a
    caller's buffer.
    """
    try:  # local: which of the optional zstd modules is installed is the question here
        import zstandard

        def decompress(data: Any, size: int) -> Any:
            # the frame header's size is checked first: a corrupt one allocates nothing
            framed = zstandard.frame_content_size(data)
            if framed >= 0 and framed != size:
                raise ValueError(f"zstd data decompress to {framed} bytes, "
                                 + ("more than" if framed > size else "not") +
                                 f" the {size} bytes announced")
            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
            if len(out) != size:
                raise ValueError(f"zstd data decompress to {len(out)} bytes, not the {size} "
                                 "bytes announced")
            return out

        return decompress
    except ImportError:
        pass
    try:  # local: the fallback zstd modules, optional as well
        from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
    except ImportError:
        from backports import zstd

    def decompress_std(data: Any, size: int) -> Any:
        d = zstd.ZstdDecompressor()
        out = d.decompress(data, max_length=size)
        if not d.eof:
            raise ValueError(f"zstd data decompress to more than the {size} bytes announced "
                             "or end before the frame does")
        return out

    return decompress_std


_DECOMPRESSORS: dict[str, Callable[[Any, int], Any]] = {}


def zstd_binding() -> str:
    """Which module decompresses zstd chunks, with its version (for benchmarks and reports)."""
    # local: importlib.metadata costs ~40 ms of CPU; only benchmarks and reports ask this
    from importlib.metadata import version

    try:  # local: the optional zstd modules, as in _zstd_decompressor
        import zstandard

        return f"zstandard {zstandard.__version__} (libzstd {zstandard.ZSTD_VERSION[0]}." \
            f"{zstandard.ZSTD_VERSION[1]}.{zstandard.ZSTD_VERSION[2]})"
    except ImportError:
        pass
    try:
        from compression import zstd  # noqa: F401

        return "compression.zstd"
    except ImportError:
        return f"backports.zstd {version('backports.zstd')}"


def _decompressor(compression: str) -> Callable[[Any, int], Any]:
    fn = _DECOMPRESSORS.get(compression)
    if fn is not None:
        return fn
    if compression == "zstd":
        fn = _zstd_decompressor()
    elif compression == "lz4":
        import lz4.frame  # local: an optional module, needed only for lz4 chunks

        def fn(data: Any, _size: int) -> Any:
            return lz4.frame.decompress(data)
    else:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    _DECOMPRESSORS[compression] = fn
    return fn


class _Chunk:
    """One chunk record of the mapped file: where its records are, and how to get them."""

    # one per chunk of the file while it is read (18000 on a 10-minute bag): no __dict__, and
    # not the index's ChunkInfo (1.4 kB with its dicts), only the fields read here
    __slots__ = ("offset", "length", "start_time", "end_time", "size", "crc", "compression",
                 "data")

    def __init__(self, info: Any, file_view: memoryview) -> None:
        self.offset = int(info.chunk_start_offset)
        self.length = int(info.chunk_length)
        self.start_time = int(info.message_start_time)
        self.end_time = int(info.message_end_time)
        start = self.offset
        end = start + self.length
        if self.length < 9 + 40:
            raise ValueError(f"chunk at byte {start}: the index gives a length of "
                             f"{self.length} bytes, shorter than a chunk record")
        if end > len(file_view):
            raise ValueError(f"chunk at byte {start}: extends past the end of the file "
                             f"({end} > {len(file_view)} bytes)")
        op, length = RECORD.unpack_from(file_view, start)
        if op != OP_CHUNK or 9 + length != int(info.chunk_length):
            raise ValueError(f"chunk at byte {start}: the index points at a record with opcode "
                             f"{op:#04x} and length {length}, not a chunk")
        body = file_view[start + 9:end]
        try:
            head = chunk_head(body)
        except ValueError as exc:
            raise ValueError(f"chunk at byte {start}: {exc}") from exc
        self.size, self.crc, self.compression = head.size, head.crc, head.compression
        self.data = body[head.data_at:head.data_at + head.data_size]

    def records(self, verify_crc: bool) -> memoryview:
        """The chunk's uncompressed records (a view of the file when not compressed)."""
        if self.compression == "":
            raw: Any = self.data
        else:
            decompress = _decompressor(self.compression)
            try:
                raw = decompress(self.data, self.size)
            except Exception as exc:  # each binding has its own error type
                raise ValueError(f"chunk at byte {self.offset}: {self.compression} data do not "
                                 f"decompress ({str(exc) or type(exc).__name__})") from exc
        if len(raw) != self.size:
            raise ValueError(f"chunk at byte {self.offset}: {len(raw)} bytes after "
                             f"decompression, the chunk says {self.size}")
        if verify_crc and self.crc:
            crc = zlib.crc32(raw)
            if crc != self.crc:
                raise ValueError(f"chunk at byte {self.offset}: CRC mismatch (corrupt data: "
                                 f"CRC-32 {crc:#010x}, the chunk says {self.crc:#010x})")
        return memoryview(raw)


def _messages_of(chunk: _Chunk, records: memoryview, channels: dict[int, Any], lo: int,
                 hi: int) -> list[Found]:
    """(log time, chunk offset, index, connection, data view) of the wanted messages
    (:func:`eye_in_hand.io.bags.mcap_records.chunk_messages` over the chunk's records, with
    its time range from the chunk index).

    Raises:
        DamagedRecords: records that stop making sense; it carries the messages before.
    """
    return _chunk_records(records, chunk.offset, chunk.start_time, chunk.end_time, channels,
                          lo, hi)


@dataclass(frozen=True)
class ChunkDamage:
    """A chunk (or the rest of one) whose messages could not be read.

    Attributes:
        offset: byte offset of the chunk record in the file.
        reason: what was wrong.
        start_ns, end_ns: the chunk's message log-time range, from the file's chunk index.
        lost: channel id -> number of wanted messages lost, from the chunk's message index;
            None when the file has no message index (the number is unknown).
    """

    offset: int
    reason: str
    start_ns: int
    end_ns: int
    lost: dict[int, int] | None


def _lost(info: Any, channels: dict[int, Any],
          kept: Sequence[Found] = ()) -> dict[int, int] | None:
    """Messages of ``channels`` the chunk's index announces, less the ones ``kept``."""
    counts = getattr(info, "channel_count", None)
    if not counts or not getattr(info, "message_index_offsets", None):
        return None
    lost = {cid: int(counts.get(cid, 0)) for cid in channels if counts.get(cid, 0)}
    for m in kept:
        cid = m[3].id
        if cid in lost:
            lost[cid] = max(0, lost[cid] - 1)
    return {cid: n for cid, n in lost.items() if n}


def chunk_damage(info: Any, exc: BaseException, channels: dict[int, Any],
                 kept: Sequence[Found] = ()) -> ChunkDamage:
    """The :class:`ChunkDamage` of a chunk that failed with ``exc`` (``kept``: the messages
    read before a bad record; ``channels``: the wanted ones, by channel id)."""
    offset = int(info.chunk_start_offset)
    text = str(exc) or type(exc).__name__
    if not text.startswith("chunk at byte"):
        text = f"chunk at byte {offset}: {text}"
    return ChunkDamage(offset, text, int(info.message_start_time), int(info.message_end_time),
                       _lost(info, channels, kept))


def _may_hold(info: Any, channels: dict[int, Any]) -> bool:
    """Whether a chunk may hold messages of ``channels``: by its message index when it has one
    (a writer may leave message indexes out: ``noMessageIndex``; then every chunk is read)."""
    counts = getattr(info, "channel_count", None)
    if not counts or not getattr(info, "message_index_offsets", None):
        return True
    return any(counts.get(cid, 0) for cid in channels)


def chunk_messages(storage: Any, connections: Sequence[Any], start: int | None = None,
                   stop: int | None = None, *, verify_crc: bool = True, threads: int = 2,
                   on_damage: Callable[[ChunkDamage], None] | None = None,
                   ) -> Iterator[tuple[Any, int, memoryview]]:
    """``(connection, log_time_ns, data)`` of an indexed MCAP file, in log-time order.

    Args:
        storage: a ``rosbags`` MCAP storage reader, opened (:func:`supports` is True).
        connections: the storage's connections to read (their ``id`` is the channel id).
        start, stop: log-time window ``[start, stop)``; None: unbounded.
        verify_crc: check each chunk's CRC-32 when the file has one.
        threads: decompression threads (compressed chunks only).
        on_damage: called with a :class:`ChunkDamage` for each chunk that cannot be read
            (record not where the index says, data that do not decompress, wrong size, CRC
            mismatch, records that stop making sense: then the messages before the bad
            record are still yielded); the other chunks are read on. None: raise instead.

    Yields:
        Messages whose data is a read-only ``memoryview`` (of the mapped file, or of a
        decompressed chunk); it stays valid after the iteration ends.

    Raises:
        ValueError: an inconsistent index or chunk (names the chunk's byte offset), when
            ``on_damage`` is None.
    """
    channels = {c.id: c for c in connections}
    lo = 0 if start is None else start
    hi = 2**64 if stop is None else stop
    infos, starts, compressed = _pick(storage.chunks, channels, lo, hi)
    if not starts or not channels:
        return
    with open(storage.path, "rb") as fh:
        mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    file_view = memoryview(mapped)
    key = id(file_view)
    with _MAPPED_LOCK:
        _MAPPED[key] = (_address(file_view), len(file_view), str(Path(storage.path).resolve()))
    reader = _ChunkReader(infos, file_view, channels, lo, hi, compressed, verify_crc=verify_crc,
                          threads=threads, on_damage=on_damage,
                          release=lambda start, length: drop_pages(mapped, start, length))
    try:
        chunks = reader.open()
        pending: list[tuple[int, int, int, Any, memoryview]] = []
        for i in range(len(chunks)):
            old = chunks[i - 2] if i >= 2 else None
            if old is not None:
                if not old.compression:
                    # read two chunks ago: its pages out of this process's resident set
                    # (views still in use map them again from the page cache), so that it
                    # stays flat however long the bag is
                    drop_pages(mapped, old.offset, old.length)
                chunks[i - 2] = None              # read: its record goes too
            t0 = starts[i]
            while pending and pending[0][0] < t0:     # nothing later can come before these
                m = heapq.heappop(pending)
                yield m[3], m[0], m[4]
            msgs = reader.messages(i)
            if msgs is None:                          # no chunk there, or it does not read
                continue
            if not pending and (i + 1 == len(chunks)
                                or not msgs or msgs[-1][0] < starts[i + 1]):
                for m in msgs:                        # the common case: chunks in time order
                    yield m[3], m[0], m[4]
                continue
            for m in msgs:
                heapq.heappush(pending, m)
        while pending:
            m = heapq.heappop(pending)
            yield m[3], m[0], m[4]
    finally:
        with _MAPPED_LOCK:
            _MAPPED.pop(key, None)
        reader.close()
        try:          # views handed out keep the mapping alive; it is unmapped when they go
            file_view.release()
            mapped.close()
        except BufferError:
            pass


#: Chunk headers read between two releases of their pages (:meth:`_ChunkReader.open`).
_RELEASE_EVERY = 256
#: Bytes of a chunk record read to check it: the record prefix and the chunk's header fields.
_HEADER_BYTES = 4096


def _pick(index: Sequence[Any], channels: dict[int, Any], lo: int, hi: int
          ) -> tuple[_Picked, list[int], bool]:
    """The chunks of ``index`` that may hold messages of ``channels`` in ``[lo, hi)``, in
    reading order (log time, then file offset), as positions in the index (a ``ChunkTable``
    makes each ``ChunkInfo`` when asked: a list of all of them would hold 1.4 kB a chunk while
    reading); their start times; whether any is compressed."""
    picked: list[tuple[int, int, int]] = []
    compressed = False
    for k, c in enumerate(index):
        if c.message_end_time >= lo and c.message_start_time < hi and _may_hold(c, channels):
            picked.append((c.message_start_time, c.chunk_start_offset, k))
            compressed = compressed or bool(c.compression)
    picked.sort()
    return (_Picked(index, [k for _t, _o, k in picked]), [t for t, _o, _k in picked],
            compressed)


class _Picked:
    """Chunks of an index (a ``ChunkTable`` or a list) by their positions in it, each
    ``ChunkInfo`` fetched when it is asked for."""

    __slots__ = ("_index", "_picked")

    def __init__(self, index: Sequence[Any], picked: list[int]) -> None:
        self._index, self._picked = index, picked

    def __len__(self) -> int:
        return len(self._picked)

    def __getitem__(self, i: int) -> Any:
        return self._index[self._picked[i]]

    def __iter__(self) -> Iterator[Any]:
        index = self._index
        return (index[k] for k in self._picked)


class _ChunkReader:
    """The chunks of one :func:`chunk_messages` call, in reading order: each one's messages,
    compressed chunks decompressed a few ahead on a thread pool, damage reported (or raised)
    as the call was told."""

    def __init__(self, infos: _Picked, file_view: memoryview, channels: dict[int, Any],
                 lo: int, hi: int, compressed: bool, *, verify_crc: bool, threads: int,
                 on_damage: Callable[[ChunkDamage], None] | None,
                 release: Callable[[int, int], None] | None = None) -> None:
        self.infos, self.file_view, self.channels = infos, file_view, channels
        self.release = release
        self.lo, self.hi, self.verify_crc, self.on_damage = lo, hi, verify_crc, on_damage
        self.pool = ThreadPoolExecutor(max(1, threads), thread_name_prefix="mcap-chunk") \
            if compressed and threads > 0 else None
        self.ahead = 2 * max(1, threads)
        self.chunks: list[_Chunk | None] = []
        self.futures: dict[int, Future[memoryview]] = {}

    def damage(self, info: Any, exc: BaseException, kept: Sequence[Found] = ()) -> None:
        record = chunk_damage(info, exc, self.channels, kept)
        if self.on_damage is None:
            raise ValueError(record.reason) from exc
        self.on_damage(record)

    def open(self) -> list[_Chunk | None]:
        """Every chunk's record checked against the index (None for one that is not there).

        Reading a chunk's header maps the pages around it (:mod:`eye_in_hand.io.pages`): on a
        long bag, the headers of all its chunks would map most of the file into this process
        before the first message (1.2 GB of a 2.8 GB bag of 18000 chunks, to read one
        camera_info). With ``release``, the headers read are released every
        :data:`_RELEASE_EVERY` chunks, in the same order of checks and damage reports."""
        span: list[int] = []
        for k, info in enumerate(self.infos):
            try:
                self.chunks.append(_Chunk(info, self.file_view))
            except ValueError as exc:
                self.damage(info, exc)
                self.chunks.append(None)
            if self.release is not None:
                span.append(int(info.chunk_start_offset))
                if len(span) == _RELEASE_EVERY or k + 1 == len(self.infos):
                    self.release(min(span), max(span) - min(span) + _HEADER_BYTES)
                    span.clear()
        return self.chunks

    def records(self, i: int) -> memoryview:
        """Chunk ``i``'s records; the next compressed ones submitted for decompression."""
        chunks, futures = self.chunks, self.futures
        chunk = chunks[i]
        assert chunk is not None
        if self.pool is None or not chunk.compression:
            return chunk.records(self.verify_crc)
        for j in range(i, min(i + self.ahead, len(chunks))):
            cj = chunks[j]
            if j not in futures and cj is not None and cj.compression:
                futures[j] = self.pool.submit(cj.records, self.verify_crc)
        return futures.pop(i).result()

    def messages(self, i: int) -> list[Found] | None:
        """Chunk ``i``'s wanted messages (those before a bad record when it has one); None
        for a chunk that is not there or does not read (its damage reported)."""
        chunk = self.chunks[i]
        if chunk is None:
            return None
        try:
            return _messages_of(chunk, self.records(i), self.channels, self.lo, self.hi)
        except DamagedRecords as exc:
            self.damage(self.infos[i], exc, exc.kept)
            return exc.kept
        except Exception as exc:  # decompression, size, CRC
            self.damage(self.infos[i], exc)
            return None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
