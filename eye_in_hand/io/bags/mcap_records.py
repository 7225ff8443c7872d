"""The MCAP record parser: the byte layout of the records this package reads (MCAP
specification, https://mcap.dev/spec), in one place.

Every reader of MCAP bytes goes through it: the memory-mapped indexed reader
(:mod:`eye_in_hand.io.bags.mcap_chunks`), the chunk workers
(:mod:`eye_in_hand.io.bags.mcap_tasks`), the scan of a file without summary
(:mod:`eye_in_hand.io.bags.mcap_scan`) and the CRC patch of written files
(:mod:`eye_in_hand.io.bags.storage_mcap`). ``rosbags`` parses the summary section (the chunk
index, channels and schemas of an indexed file); this module parses the data section: record
headers, schema, channel and message records, chunk headers and the records inside a chunk.

Buffers are anything ``struct.unpack_from`` reads (``bytes``, ``memoryview`` of a mapped
file); message data come back as slices of the buffer given (views, no copies, for a
``memoryview``).
"""
from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

__all__ = ["MAGIC", "OP_FOOTER", "OP_SCHEMA", "OP_CHANNEL", "OP_MESSAGE", "OP_CHUNK",
           "OP_DATA_END", "OP_MAX", "RECORD", "MESSAGE", "ChunkHead", "DamagedRecords",
           "string", "schema", "channel", "message", "chunk_head", "chunk_start",
           "chunk_messages"]

MAGIC = b"\x89MCAP0\r\n"
"""The magic bytes at the start (and end) of an MCAP file (major version 0)."""

OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_DATA_END = 0x0F
OP_MAX = 0x0F
"""The largest opcode the specification defines."""

RECORD = struct.Struct("<BQ")           # opcode, record length (the body's, in bytes)
MESSAGE = struct.Struct("<HIQQ")        # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQI")    # start, end, uncompressed size, uncompressed crc
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")

#: a message found in a chunk: (log time, chunk offset, index among the wanted messages of the
#: chunk, connection, data)
Found = tuple[int, int, int, Any, Any]


def string(buf: Any, pos: int) -> tuple[str, int]:
    """The length-prefixed UTF-8 string at ``pos`` and the position after it."""
    (n,) = _U32.unpack_from(buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def schema(body: Any) -> tuple[int, str, str, str]:
    """A schema record's ``(id, name, encoding, data)``."""
    (sid,) = _U16.unpack_from(body, 0)
    name, pos = string(body, 2)
    enc, pos = string(body, pos)
    (n,) = _U32.unpack_from(body, pos)
    return sid, name, enc, bytes(body[pos + 4:pos + 4 + n]).decode()


def channel(body: Any) -> tuple[int, int, str, str, bytes]:
    """A channel record's ``(id, schema id, topic, message encoding, metadata bytes)``."""
    cid, schema_id = struct.unpack_from("<HH", body, 0)
    topic, pos = string(body, 4)
    enc, pos = string(body, pos)
    (n,) = _U32.unpack_from(body, pos)
    return cid, schema_id, topic, enc, bytes(body[pos + 4:pos + 4 + n])


def message(body: Any) -> tuple[int, int, Any]:
    """A message record's ``(channel id, log time, data)`` (data: a slice of ``body``)."""
    cid, _seq, log_time, _pub = MESSAGE.unpack_from(body, 0)
    return cid, log_time, body[MESSAGE.size:]


class ChunkHead(NamedTuple):
    """A chunk record's header; its compressed records are ``body[data_at:data_at +
    data_size]``."""

    start: int          # message start time
    end: int            # message end time
    size: int           # uncompressed size of the records
    crc: int            # CRC-32 of the uncompressed records (0: not computed)
    compression: str    # "" (none), "zstd", "lz4"
    data_at: int
    data_size: int


def chunk_head(body: Any) -> ChunkHead:
    """The header of a chunk record's body.

    Raises:
        ValueError: a header that does not parse, or compressed data longer than the record.
    """
    try:
        t0, t1, size, crc = _CHUNK_HEAD.unpack_from(body, 0)
        (n,) = _U32.unpack_from(body, 28)
        compression = bytes(body[32:32 + n]).decode()
        (csize,) = _U64.unpack_from(body, 32 + n)
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"malformed chunk header ({exc})") from exc
    data_at = 32 + n + 8
    if data_at + csize > len(body):
        raise ValueError(f"compressed data of {csize} bytes exceeds its record")
    return ChunkHead(t0, t1, size, crc, compression, data_at, csize)


def chunk_start(buf: Any, body_at: int) -> int:
    """The message start time of the chunk record whose body starts at ``body_at`` (its
    first field: readable from a chunk whose record is cut short)."""
    (t0,) = _U64.unpack_from(buf, body_at)
    return int(t0)


class DamagedRecords(ValueError):
    """Records of a chunk stop making sense part-way; the messages before that are kept.

    ``str()``: ``chunk at byte <offset>: <detail>``; :attr:`detail` without the prefix."""

    def __init__(self, offset: int, detail: str, kept: list[Found]) -> None:
        super().__init__(f"chunk at byte {offset}: {detail}")
        self.detail = detail
        self.kept = kept


def chunk_messages(records: Any, offset: int, t_lo: int, t_hi: int,
                   channels: Mapping[int, Any] | None, lo: int = 0, hi: int = 2**64,
                   on_record: Callable[[int, Any], None] | None = None) -> list[Found]:
    """The messages among a chunk's uncompressed records, sorted by log time, then record
    order.

    Args:
        records: the chunk's uncompressed records.
        offset: the chunk record's byte offset in its file (named in errors; the second
            field of each message, which orders chunks with equal log times).
        t_lo, t_hi: the chunk's message time range (from its header or the chunk index):
            a message outside it is damage.
        channels: wanted channel id -> connection (the fourth field of each message); None:
            every message, the fourth field its channel id.
        lo, hi: only messages with ``lo <= log time < hi``.
        on_record: called with ``(opcode, body)`` for each schema and channel record.

    Raises:
        DamagedRecords: a record that cannot be in a valid chunk (truncated, longer than the
            chunk, an opcode that chunks do not hold, a message shorter than its header or
            outside the chunk's time range); it carries the wanted messages read before it.
    """
    out: list[Found] = []
    pos, end, index = 0, len(records), 0

    def damaged(text: str) -> DamagedRecords:
        out.sort(key=lambda m: (m[0], m[2]))
        return DamagedRecords(offset, text, out)

    while pos < end:
        if pos + 9 > end:
            raise damaged(f"truncated record at {pos}")
        op, length = RECORD.unpack_from(records, pos)
        body_at, pos = pos + 9, pos + 9 + length
        if pos > end:
            raise damaged(f"record at {body_at - 9} is longer than the chunk")
        if op in (OP_SCHEMA, OP_CHANNEL):
            if on_record is not None:
                on_record(op, records[body_at:pos])
            continue
        if op != OP_MESSAGE:
            raise damaged(f"record at {body_at - 9} has opcode {op:#04x}, which a chunk "
                          "does not hold")
        if length < MESSAGE.size:
            raise damaged(f"message record of {length} bytes")
        cid, _seq, log_time, _pub = MESSAGE.unpack_from(records, body_at)
        if not t_lo <= log_time <= t_hi:
            raise damaged(f"message at {body_at - 9} has log time {log_time}, outside the "
                          f"chunk's [{t_lo}, {t_hi}]")
        conn = cid if channels is None else channels.get(cid)
        if conn is not None and lo <= log_time < hi:
            out.append((log_time, offset, index, conn, records[body_at + MESSAGE.size:pos]))
            index += 1
    out.sort(key=lambda m: (m[0], m[2]))
    return out
