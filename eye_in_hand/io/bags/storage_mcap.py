"""MCAP storage: ``rosbags``' reader and writer, with this package's memory-mapped reader
(:mod:`~eye_in_hand.io.bags.mcap_chunks`), chunk workers
(:mod:`~eye_in_hand.io.bags.mcap_tasks`), the scan of an interrupted file
(:mod:`~eye_in_hand.io.bags.mcap_scan`) and real CRCs in written files."""
from __future__ import annotations

import hashlib
import os
import struct
import threading
import zlib
from collections import OrderedDict, defaultdict
from collections.abc import Iterator, Sequence
from io import BytesIO
from pathlib import Path
from typing import Any

from eye_in_hand.errors import BagError
from eye_in_hand.io.bags import mcap_records as rec
from eye_in_hand.io.bags.chunk_table import ChunkTable
from eye_in_hand.io.bags.mcap_scan import ScannedMcap
from eye_in_hand.io.bags.records import Damage
from eye_in_hand.io.bags.storage import OnDamage, StorageFormat

__all__ = ["McapFormat", "chunk_damage_record"]

_WORKER_COMPRESSIONS = ("zstd", "lz4")

#: The parsed summaries (schemas, channels, chunk index, statistics) of the MCAP files used
#: last in this process, by real path, each with a digest of the bytes it was parsed from (the
#: header record, and everything from the summary section to the end of the file): a file
#: opened again whose bytes there are the same is not parsed again. Opening a bag parses its
#: chunk index, about 0.1 s of CPU on a 10-minute bag of 18000 chunks, and ``process`` opens
#: it six times; hashing the bytes again (about 2.4 MB there) takes 2-3 ms, and the digest
#: keeps the cache from holding them (130 bytes a chunk). Least recently used
#: out first, beyond :data:`_INDEX_CACHE_FILES` files or :data:`_INDEX_CACHE_CHUNKS` chunks
#: in all (the newest file always stays): the files of a bag split by size fit, and the
#: index held stays within about 5 MB (a :class:`~eye_in_hand.io.bags.chunk_table.ChunkTable`,
#: about 125 bytes a chunk, shared with the open readers).
_INDEX_CACHE: OrderedDict[str, tuple[int, bytes, dict[str, Any]]] = OrderedDict()
_INDEX_CACHE_FILES = 64
_INDEX_CACHE_CHUNKS = 40_000
_INDEX_LOCK = threading.Lock()
_INDEXED_READER: Any = None


def _copied(value: Any) -> Any:
    """A list, dict or chunk table copied (the rosbags reader clears its own in place at
    ``close``)."""
    if isinstance(value, ChunkTable):
        return value.copy()
    return type(value)(value) if isinstance(value, (list, dict)) else value


def _compressions(storage: Any) -> set[str]:
    """The compressions of a reader's chunks ("" for none)."""
    chunks = storage.chunks
    if isinstance(chunks, ChunkTable):
        return chunks.compressions()
    return {c.compression for c in chunks}


def _read_range(bio: Any, start: int, end: int) -> bytes:
    bio.seek(start)
    data: bytes = bio.read(end - start)
    return data


def _digest(bio: Any, data_start: int, data_end: int, size: int) -> bytes:
    """A digest of the bytes an index is parsed from: the file's start up to ``data_start``
    and everything from ``data_end`` (the summary section) to its ``size``."""
    h = hashlib.blake2b(digest_size=32)
    h.update(_read_range(bio, 0, data_start))
    h.update(size.to_bytes(8, "little"))
    h.update(_read_range(bio, data_end, size))
    return h.digest()


def _indexed_reader() -> Any:
    """``rosbags``' ``McapReader`` that keeps the parsed summary of the files it opened
    (:data:`_INDEX_CACHE`) and takes it from there when the same bytes are opened again.
    A file read without a summary (scanned: an unfinished recording) is parsed every time."""
    global _INDEXED_READER
    if _INDEXED_READER is not None:
        return _INDEXED_READER
    # local: rosbags.rosbag2.storage_mcap costs ~40 ms at CLI start-up (every command loads
    # io.bags); rosbags.rosbag2.Reader, which the caller has loaded, imports it anyway
    from rosbags.rosbag2.storage_mcap import McapReader

    class IndexedMcapReader(McapReader):
        _scanned = False

        def meta_scan(self) -> None:
            self._scanned = True
            super().meta_scan()

        def _open(self) -> None:
            bio = self.bio
            assert bio is not None             # McapReader.open opened it
            key = os.path.realpath(str(self.path))
            size = os.fstat(bio.fileno()).st_size
            with _INDEX_LOCK:
                hit = _INDEX_CACHE.get(key)
                if hit is not None:
                    _INDEX_CACHE.move_to_end(key)      # used last (if it still matches)
            if hit is not None:
                hit_size, digest, state = hit
                if hit_size == size and _digest(bio, state["data_start"], state["data_end"],
                                                size) == digest:
                    for k, v in state.items():
                        setattr(self, k, _copied(v))
                    # each connection names the reader it belongs to
                    self.connections = [c._replace(owner=self) for c in state["connections"]]
                    return
                bio.seek(0)
            # held compactly (about 125 bytes a chunk instead of 1.4 kB, chunk_table), each
            # chunk put in the table as rosbags parses it (read_index appends to self.chunks)
            self.chunks = ChunkTable.building()  # type: ignore[assignment]
            super()._open()
            if self._scanned:
                return
            if not isinstance(self.chunks, ChunkTable):  # a rosbags that made its own list
                self.chunks = ChunkTable.of(self.chunks)  # type: ignore[assignment]
            state = {k: _copied(v) for k, v in vars(self).items() if k not in ("bio", "path")}
            entry = (size, _digest(bio, self.data_start, self.data_end, size), state)
            with _INDEX_LOCK:
                _INDEX_CACHE[key] = entry
                _INDEX_CACHE.move_to_end(key)
                while len(_INDEX_CACHE) > 1 and (
                        len(_INDEX_CACHE) > _INDEX_CACHE_FILES
                        or sum(len(e[2]["chunks"]) for e in _INDEX_CACHE.values())
                        > _INDEX_CACHE_CHUNKS):
                    _INDEX_CACHE.popitem(last=False)

    _INDEXED_READER = IndexedMcapReader
    return IndexedMcapReader


def chunk_damage_record(file: str, by_id: dict[int, Any], cd: Any) -> Damage:
    """The :class:`Damage` record of an MCAP chunk that could not be read (``cd``: an
    :class:`eye_in_hand.io.bags.mcap_chunks.ChunkDamage`; ``by_id``: the connections read, by
    channel id)."""
    topics: dict[str, int] = {}
    for cid, n in (cd.lost or {}).items():
        topic = by_id[cid].topic
        topics[topic] = topics.get(topic, 0) + n
    where = f"chunk at byte {cd.offset}"
    reason = cd.reason[len(where) + 2:] if cd.reason.startswith(where + ": ") else cd.reason
    return Damage(file, where, reason, topics, cd.start_ns, cd.end_ns,
                  None if cd.lost is None else sum(topics.values()))


def _on_chunk_damage(storage: Any, connections: Sequence[Any], on_damage: OnDamage) -> Any:
    """``on_damage`` for :class:`~eye_in_hand.io.bags.mcap_chunks.ChunkDamage` records."""
    if on_damage is None:
        return None
    name = Path(getattr(storage, "path", "")).name
    by_id = {c.id: c for c in connections}
    report = on_damage
    return lambda cd: report(chunk_damage_record(name, by_id, cd))


class McapFormat(StorageFormat):
    """MCAP (``ros2 bag record``'s default on Jazzy)."""

    name = "mcap"
    suffix = ".mcap"
    writable = True
    zstd_mode = "storage"        # zstd-compressed chunks

    def reader_class(self) -> Any:
        return _indexed_reader()

    def scan(self, path: Path) -> Any | None:
        return ScannedMcap.try_open(path)

    def reads_directly(self, storage: Any) -> bool:
        # local: io.bags.mcap_chunks costs ~8 ms at CLI start-up and at each `process` worker's
        # start
        from eye_in_hand.io.bags import mcap_chunks

        return mcap_chunks.supports(storage)

    def direct_messages(self, storage: Any, connections: Sequence[Any], start: int | None,
                        stop: int | None, *, verify_crc: bool, on_damage: OnDamage,
                        ) -> Iterator[tuple[Any, int, Any]]:
        # local: as in reads_directly (~8 ms)
        from eye_in_hand.io.bags import mcap_chunks

        return mcap_chunks.chunk_messages(
            storage, connections, start, stop, verify_crc=verify_crc,
            on_damage=_on_chunk_damage(storage, connections, on_damage))

    def mappable(self, storage: Any) -> bool:
        return self.reads_directly(storage) and not any(_compressions(storage))

    def worker_readable(self, storage: Any) -> bool:
        if not self.reads_directly(storage):
            return False
        comp = _compressions(storage)
        return bool(comp & set(_WORKER_COMPRESSIONS)) and comp <= {"", *_WORKER_COMPRESSIONS}

    def worker_messages(self, storage: Any, connections: Sequence[Any], submit: Any, *,
                        image_channels: set[int], pair_channels: tuple[int, int] | None,
                        verify_crc: bool, on_damage: OnDamage,
                        ) -> Iterator[tuple[Any, int, Any]]:
        # local: io.bags.mcap_tasks costs ~14 ms at CLI start-up and at each `process`
        # worker's start (as mcap_chunks, and io.cdr)
        from eye_in_hand.io.bags.mcap_tasks import worker_messages

        return worker_messages(storage, connections, submit, image_channels=image_channels,
                               pair_channels=pair_channels, verify_crc=verify_crc,
                               on_damage=_on_chunk_damage(storage, connections, on_damage))

    def writer_plugin(self) -> tuple[Any, Any]:
        # local: rosbags.rosbag2.enums is loaded with the rosbags writer (see _crc_writer)
        from rosbags.rosbag2.enums import StoragePlugin

        return StoragePlugin.MCAP, _crc_writer()


class _CrcFile:
    """A write-only file that keeps the CRC-32 of everything written through it."""

    def __init__(self, fh: Any, crc: int) -> None:
        self._fh = fh
        self.crc = crc

    def write(self, data: Any) -> int:
        self.crc = zlib.crc32(data, self.crc)
        written: int = self._fh.write(data)
        return written

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


_WRITER_CLASS: Any = None


#: A message record's opcode and length, then its channel id, sequence (0), log and publish
#: time (both the stamp), as rosbags' ``McapWriter.write`` writes them field by field
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = 2 + 4 + 8 + 8


def _crc_writer() -> Any:
    """``rosbags``' MCAP writer, with CRCs.

    ``rosbags`` writes 0 (not computed) in every CRC field of an MCAP file. Here each chunk
    gets the CRC-32 of its uncompressed records, the data-end record the CRC-32 of the data
    section, and the footer the CRC-32 of the summary section, as the MCAP specification
    defines them, so that corruption can be detected (``--verify-crc``).

    Long because: the class subclasses ``rosbags``' ``McapWriter``, which is imported here
    and nowhere earlier (it costs ~55 ms at CLI start-up), so it is defined inside this
    function; and its ``close_chunk`` is ``rosbags``' own, statement for statement, with the
    chunk's CRC-32 written instead of 0 (its buffer named ``out``), so that it can be
    compared with the upstream method at each ``rosbags`` release. Cut into parts it would
    no longer read against upstream.
    """
    global _WRITER_CLASS
    if _WRITER_CLASS is not None:
        return _WRITER_CLASS
    # local: the rosbags writer (rosbag2 + storage_mcap) costs ~55 ms at CLI start-up (every
    # command loads io.bags), and only commands that write bags need it
    from rosbags.rosbag2.storage_mcap import (
        McapWriter,
        PendingChunk,
        write_record,
        write_string,
        write_uint16,
        write_uint32,
        write_uint64,
    )

    class CrcMcapWriter(McapWriter):
        def __init__(self, path: Path, compression: Any) -> None:
            super().__init__(path, compression)
            self.bio.flush()
            head = self.path.read_bytes()[:self.bio.tell()]     # magic and header record
            self.crc_file = _CrcFile(self.bio, zlib.crc32(head))
            # the writer's file, wrapped: every byte written goes through the CRC
            self.bio = self.crc_file  # type: ignore[assignment]

        def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
            # rosbags' write, the record's head packed at once: the same bytes, in a third
            # of the time (about 13 messages a frame in `process`'s output bag)
            self.message_start_time = min(timestamp, self.message_start_time)
            self.message_end_time = max(timestamp, self.message_end_time)
            cid = connection.id
            self.channel_stats[cid] += 1
            chunk = self.chunk
            chunk.message_start_time = min(timestamp, chunk.message_start_time)
            chunk.message_end_time = max(timestamp, chunk.message_end_time)
            bio = chunk.bio
            chunk.msgs[cid].append((timestamp, bio.tell()))
            bio.write(_MESSAGE_HEAD.pack(rec.OP_MESSAGE, _MESSAGE_FIELDS + len(data), cid, 0,
                                         timestamp, timestamp))
            bio.write(data)
            if bio.tell() > 2**20:
                self.close_chunk()

        def close_chunk(self) -> None:
            # rosbags' close_chunk, with the CRC-32 of the uncompressed records
            out = BytesIO()
            write_uint64(out, self.chunk.message_start_time)
            write_uint64(out, self.chunk.message_end_time)
            write_uint64(out, self.chunk.bio.tell())
            write_uint32(out, zlib.crc32(self.chunk.bio.getbuffer()))
            compressed = self.compressor(self.chunk.bio.getvalue())
            write_string(out, self.compression)
            write_uint64(out, len(compressed))
            out.write(compressed)
            chunk_start = self.bio.tell()
            write_record(self.bio, rec.OP_CHUNK, out)
            chunk_end = self.bio.tell()
            offsets: list[tuple[int, int]] = []
            for cid, msgs in self.chunk.msgs.items():
                offsets.append((cid, self.bio.tell()))
                out = BytesIO()
                write_uint16(out, cid)
                write_uint32(out, len(msgs) * 16)
                for ts, offset in msgs:
                    write_uint64(out, ts)
                    write_uint64(out, offset)
                write_record(self.bio, 0x07, out)        # message index
            out = BytesIO()
            write_uint64(out, self.chunk.message_start_time)
            write_uint64(out, self.chunk.message_end_time)
            write_uint64(out, chunk_start)
            write_uint64(out, chunk_end - chunk_start)
            write_uint32(out, len(offsets) * 10)
            for cid, offset in offsets:
                write_uint16(out, cid)
                write_uint64(out, offset)
            write_uint64(out, self.bio.tell() - chunk_end)
            write_string(out, self.compression)
            write_uint64(out, len(compressed))
            write_uint64(out, self.chunk.bio.tell())
            self.chunks.append(out)
            self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

        def close(self, version: int, metadata: str) -> None:
            if self.chunk.bio.tell():
                self.close_chunk()
            pos, crc = self.bio.tell(), self.crc_file.crc
            super().close(version, metadata)
            _patch_mcap_crcs(self.path, pos, crc)

    _WRITER_CLASS = CrcMcapWriter
    return CrcMcapWriter


def _patch_mcap_crcs(path: Path, pos: int, crc: int) -> None:
    """Write the data-section and summary CRCs of a finished MCAP file.

    ``crc`` is the CRC-32 of the file's first ``pos`` bytes (everything up to the end of the
    last chunk and its message indexes); the rest of the data section (the metadata record)
    and the summary are read back, they are small.
    """
    with open(path, "r+b") as fh:
        fh.seek(0, 2)
        size = fh.tell()
        footer = size - 8 - 29
        fh.seek(footer)
        tail = fh.read(29)
        if tail[0] != rec.OP_FOOTER:
            raise BagError(f"{path}: no MCAP footer where expected (byte {footer})")
        summary_start = int.from_bytes(tail[9:17], "little")
        data_end = (summary_start or footer) - 13
        fh.seek(pos)
        rest = fh.read(data_end - pos)
        end_rec = fh.read(13)
        if end_rec[0] != rec.OP_DATA_END:
            raise BagError(f"{path}: no MCAP data-end record where expected (byte {data_end})")
        fh.seek(data_end + 9)
        fh.write(zlib.crc32(rest, crc).to_bytes(4, "little"))
        if summary_start:
            fh.seek(summary_start)
            summary = fh.read(footer + 25 - summary_start)
            fh.seek(footer + 25)
            fh.write(zlib.crc32(summary).to_bytes(4, "little"))
