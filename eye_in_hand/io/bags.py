"""rosbag2 bags: inspect, read and write them with ``rosbags`` (no rclpy).

This is the one bag API of the package. Live replay (``eye-in-hand play``), recording, calibration
from a bag, hand-eye from a bag, offline processing and the simulator all go through it.

What it opens:

* a bag directory with ``metadata.yaml`` (rosbag2 metadata versions 1 to 9, storage ``sqlite3``
  or ``mcap``, file/message compression with zstd, MCAP chunks compressed with zstd or lz4,
  split bags with several storage files), as written by ``ros2 bag record``;
* a single ``.mcap`` (or ``.db3``) file without metadata;
* a bag directory whose ``metadata.yaml`` is missing (a recorder that was killed) but which
  holds readable ``.mcap`` / ``.db3`` files: they are read directly.

``rosbags`` does the parsing. On top of it this module adds a log-time-ordered merge across
storage files, time windows, message definitions taken from the bag itself (so types that the
Jazzy type store does not know still decode), and one error type (:class:`BagError`) whose
message names the bag.

Conventions: times are int nanoseconds (log time, i.e. receive time for ``ros2 bag record``);
message types are ``pkg/msg/Type``.

Example::

    info = bag_info("run1")
    require_topics(info, ["/left/image_raw", "/right/image_raw"])
    store = typestore_for("run1")
    for topic, msgtype, stamp_ns, raw in iter_messages("run1", topics=["/left/image_raw"]):
        msg = deserialize(raw, msgtype, store)
    for topic, stamp_ns, msg in iter_decoded("run1", topics=["/right/image_raw"]):
        ...

    with BagWriter("out", storage="mcap", compression="zstd") as bag:
        bag.add_topic("/target/point", "geometry_msgs/msg/PointStamped")
        bag.write("/target/point", stamp_ns, msg_or_cdr_bytes)
"""
from __future__ import annotations

import heapq
import threading
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Iterable, Iterator, Literal, Mapping, Sequence

from eye_in_hand.errors import BagError, InputError

__all__ = [
    "STORAGES",
    "COMPRESSIONS",
    "OfferedQos",
    "TopicInfo",
    "BagInfo",
    "BagMessage",
    "Damage",
    "DamageLog",
    "bag_info",
    "check_bag",
    "iter_messages",
    "iter_decoded",
    "memory_mappable",
    "typestore_for",
    "default_typestore",
    "deserialize",
    "serialize",
    "require_topics",
    "BagWriter",
]

STORAGES: tuple[str, ...] = ("mcap", "sqlite3")
"""Storage plugins :class:`BagWriter` can write (both are readable)."""

COMPRESSIONS: tuple[str | None, ...] = (None, "zstd")
"""Compression choices of :class:`BagWriter`."""

_STORAGE_SUFFIX = {".mcap": "mcap", ".db3": "sqlite3"}

BagMessage = tuple[str, str, int, bytes]
"""One message as read from a bag: ``(topic, msgtype, log_time_ns, raw_cdr_bytes)``."""


@dataclass(frozen=True)
class OfferedQos:
    """The QoS a publisher offered on a recorded topic (the policies that decide matching).

    Attributes:
        reliability: ``"reliable"``, ``"best_effort"`` or ``"system_default"``.
        durability: ``"volatile"``, ``"transient_local"`` or ``"system_default"``.
        history: ``"keep_last"``, ``"keep_all"`` or ``"system_default"``.
        depth: history depth (0 when unknown).
    """

    reliability: str = "reliable"
    durability: str = "volatile"
    history: str = "keep_last"
    depth: int = 10

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON)."""
        return {"reliability": self.reliability, "durability": self.durability,
                "history": self.history, "depth": self.depth}


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes:
        name: topic name, e.g. ``/left/image_raw``.
        msgtype: message type, e.g. ``sensor_msgs/msg/Image``.
        count: number of messages.
        serialization_format: ``cdr`` for every rosbag2 bag.
        offered_qos: the QoS profiles recorded publishers offered (may be empty).
        type_hash: the RIHS01 type description hash when the bag stores one, else ``""``.
        has_definition: whether the bag carries the message definition for this type.
    """

    name: str
    msgtype: str
    count: int
    serialization_format: str = "cdr"
    offered_qos: tuple[OfferedQos, ...] = ()
    type_hash: str = ""
    has_definition: bool = False

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON)."""
        return {"name": self.name, "type": self.msgtype, "count": self.count,
                "serialization_format": self.serialization_format,
                "offered_qos": [q.to_dict() for q in self.offered_qos],
                "type_hash": self.type_hash}


@dataclass(frozen=True)
class BagInfo:
    """Summary of a bag, like ``ros2 bag info``.

    Attributes:
        path: the bag directory or storage file given.
        storage: ``"sqlite3"`` or ``"mcap"``.
        files: the storage files, in reading order.
        version: rosbag2 metadata version, or None when there is no ``metadata.yaml``.
        start_ns: log time of the first message (0 for an empty bag).
        end_ns: log time of the last message (0 for an empty bag).
        message_count: total number of messages.
        topics: per-topic information keyed by topic name, sorted by name.
        compression_format: ``"zstd"`` or ``""``; compression_mode: ``"file"``, ``"message"``
            or ``""`` (MCAP chunk compression is not a rosbag2 compression mode: it is
            transparent and not shown here).
        ros_distro: the distribution that wrote the bag when recorded (metadata >= 8).
        size_bytes: total size of the storage files.
        notes: problems worked around while reading (e.g. an MCAP file without summary, from
            an interrupted recording, read by scanning).
    """

    path: Path
    storage: str
    files: tuple[Path, ...]
    version: int | None
    start_ns: int
    end_ns: int
    message_count: int
    topics: Mapping[str, TopicInfo]
    compression_format: str = ""
    compression_mode: str = ""
    ros_distro: str = ""
    size_bytes: int = 0
    notes: tuple[str, ...] = ()

    @property
    def duration_ns(self) -> int:
        """Time between the first and the last message, in ns."""
        return self.end_ns - self.start_ns

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for ``--json``)."""
        return {
            "path": str(self.path), "storage": self.storage,
            "files": [str(f) for f in self.files], "version": self.version,
            "start_ns": self.start_ns, "end_ns": self.end_ns, "duration_ns": self.duration_ns,
            "message_count": self.message_count,
            "compression_format": self.compression_format,
            "compression_mode": self.compression_mode, "ros_distro": self.ros_distro,
            "size_bytes": self.size_bytes, "notes": list(self.notes),
            "topics": [t.to_dict() for t in self.topics.values()],
        }


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Damage:
    """A damaged part of a bag that was skipped while reading: a chunk (or the rest of one),
    the tail of a truncated file, or one message.

    Attributes:
        file: the storage file (its name).
        where: what was skipped, e.g. ``chunk at byte 1234``, ``message``, ``file tail``.
        reason: what was wrong with it.
        topics: topic -> number of messages lost on it, for the topics being read; empty
            when the storage does not say (then ``messages`` is None).
        start_ns, end_ns: log-time range of the lost messages (None: unknown).
        messages: messages lost (None: unknown, e.g. the tail of a truncated file).
    """

    file: str
    where: str
    reason: str
    topics: Mapping[str, int] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    messages: int | None = None

    def describe(self) -> str:
        """One line: where, which topics and times, how many messages, why."""
        if self.start_ns is None:
            when = "time unknown"
        elif self.end_ns is None or self.end_ns == self.start_ns:
            when = f"at {self.start_ns} ns" if self.end_ns is not None else \
                f"from {self.start_ns} ns on"
        else:
            when = f"{self.start_ns}..{self.end_ns} ns"
        if self.topics:
            what = ", ".join(f"{n} on {t}" for t, n in sorted(self.topics.items()))
            lost = f"{self.messages} message(s) lost ({what})"
        elif self.messages is not None:
            lost = f"{self.messages} message(s) lost"
        else:
            lost = "an unknown number of messages lost"
        where = f"{self.file}: {self.where}" if self.file else self.where
        return f"{where} ({when}) skipped, {lost}: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON)."""
        return {"file": self.file, "where": self.where, "reason": self.reason,
                "topics": dict(sorted(self.topics.items())), "start_ns": self.start_ns,
                "end_ns": self.end_ns, "messages": self.messages}


class DamageLog:
    """The damage records of one or more reads of a bag (thread-safe).

    Pass one to :func:`iter_messages` / :func:`iter_decoded` (``damage=``): damaged chunks,
    truncated tails and messages that cannot be read are recorded here and skipped, and the
    rest of the bag is read on. Callers also record messages they cannot decode
    (:meth:`bad_message`). Report with :meth:`lines` / :meth:`to_dict`.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.records: list[Damage] = []

    def add(self, damage: Damage) -> None:
        """Record one damaged region.

        The same region met again (a command that reads a bag in several passes, or the
        topics of one chunk read separately) is merged into its first record: topics are
        united, each topic's count is the largest seen, so nothing is counted twice.
        """
        key = self._key(damage)
        with self._lock:
            for i, have in enumerate(self.records):
                if self._key(have) != key:
                    continue
                topics = dict(have.topics)
                for t, n in damage.topics.items():
                    topics[t] = max(n, topics.get(t, 0))
                known = have.messages is not None and damage.messages is not None
                self.records[i] = Damage(
                    have.file, have.where, have.reason, topics, have.start_ns, have.end_ns,
                    sum(topics.values()) if known else None)
                return
            self.records.append(damage)

    @staticmethod
    def _key(d: Damage) -> tuple[Any, ...]:
        if d.where == "message":
            return d.file, d.where, tuple(sorted(d.topics)), d.start_ns
        return d.file, d.where

    def bad_message(self, topic: str, stamp_ns: int, reason: str, file: str = "") -> None:
        """Record one message that was read but cannot be used (does not decode, a truncated
        image, a non-finite pose)."""
        self.add(Damage(file, "message", reason, {topic: 1}, stamp_ns, stamp_ns, 1))

    def __len__(self) -> int:
        with self._lock:
            return len(self.records)

    def __bool__(self) -> bool:
        return len(self) > 0

    @property
    def messages_lost(self) -> int:
        """Messages known to be lost (damage of unknown size counts 0 here)."""
        with self._lock:
            return sum(d.messages or 0 for d in self.records)

    @property
    def unknown(self) -> int:
        """Damaged regions whose number of lost messages is unknown."""
        with self._lock:
            return sum(1 for d in self.records if d.messages is None)

    def by_topic(self) -> dict[str, int]:
        """Topic -> messages lost on it (where known)."""
        out: dict[str, int] = {}
        with self._lock:
            for d in self.records:
                for t, n in d.topics.items():
                    out[t] = out.get(t, 0) + n
        return dict(sorted(out.items()))

    def summary(self) -> str:
        """One line, e.g. ``2 damaged region(s) skipped: 7 message(s) lost (...)``."""
        topics = ", ".join(f"{n} on {t}" for t, n in self.by_topic().items())
        text = f"{len(self)} damaged region(s) skipped: {self.messages_lost} message(s) lost"
        if topics:
            text += f" ({topics})"
        if self.unknown:
            text += f", plus an unknown number in {self.unknown} region(s)"
        return text

    def lines(self, limit: int = 20) -> list[str]:
        """One line per record (at most ``limit``, then one line saying how many more)."""
        with self._lock:
            records = list(self.records)
        out = [d.describe() for d in records[:limit]]
        if len(records) > limit:
            out.append(f"... and {len(records) - limit} more damaged region(s)")
        return out

    def to_dict(self) -> dict[str, Any]:
        """``{"regions", "messages_lost", "unknown_regions", "by_topic", "records"}``."""
        with self._lock:
            records = [d.to_dict() for d in self.records]
        return {"regions": len(records), "messages_lost": self.messages_lost,
                "unknown_regions": self.unknown, "by_topic": self.by_topic(),
                "records": records}



def _bag_error(path: Path, exc: BaseException, doing: str = "read") -> BagError:
    text = str(exc).strip() or type(exc).__name__
    return BagError(f"cannot {doing} bag {path}: {text}")


def _storage_paths(path: Path) -> list[Path]:
    """What to hand to ``rosbags.rosbag2.Reader`` for ``path`` (one entry per reader)."""
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return [path]
        files = sorted(p for p in path.iterdir() if p.suffix in _STORAGE_SUFFIX and p.is_file())
        if not files:
            raise BagError(
                f"bag {path} has no metadata.yaml and no .mcap or .db3 storage file")
        return files
    if path.suffix not in _STORAGE_SUFFIX:
        raise BagError(
            f"bag {path} is neither a bag directory nor a .mcap / .db3 storage file")
    return [path]


_MCAP_MAGIC = b"\x89MCAP0\r\n"


class _ScannedMcap:
    """An MCAP file whose summary/footer is missing (recording killed), read by a linear scan.

    ``rosbags`` needs the footer; ``ros2 bag`` (the mcap library) falls back to scanning. This
    does the same: records are read in file order up to the first incomplete or invalid one
    (the damaged tail); a chunk whose data cannot be read is skipped (its record length says
    where the next record starts). Messages of each chunk are sorted by log time (rosbag2
    writes chunks in time order). It offers the subset of the ``rosbags`` reader interface
    this module uses; :attr:`damage` lists what the scan skipped.
    """

    compression_format = None
    compression_mode = None

    def __init__(self, path: Path) -> None:
        from rosbags.interfaces import Connection, ConnectionExtRosbag2
        from rosbags.rosbag2.storage_mcap import Schema, get_msgdef, get_qos

        self.path = path
        self.storage = self
        self.stopped_at: int | None = None
        self.stop_reason = ""
        self.damage: list[Damage] = []
        schemas: dict[int, Any] = {}
        counts: dict[int, int] = {}
        conns: dict[int, Any] = {}
        start, end, count = 2**63 - 1, 0, 0
        for kind, rec in self._records():
            if kind == 0x03:
                schemas[rec[0]] = Schema(*rec)
            elif kind == 0x04:
                cid, schema_id, topic, encoding, meta = rec
                schema = schemas.get(schema_id)
                conns[cid] = Connection(
                    cid, topic, schema.name if schema else "", get_msgdef(schema), "", 0,
                    ConnectionExtRosbag2(encoding, get_qos(meta)), self)
            elif kind == -1:
                self.damage.append(rec)
            elif kind == 0x05:
                cid, stamp, _data = rec
                counts[cid] = counts.get(cid, 0) + 1
                start, end, count = min(start, stamp), max(end, stamp), count + 1
        self.connections = [c._replace(msgcount=counts.get(c.id, 0)) for c in conns.values()]
        self.message_count = count
        self.start_time = start if count else 2**63 - 1
        self.end_time = end + 1 if count else 0

    @property
    def tail_note(self) -> str:
        text = "" if self.stopped_at is None else \
            f"; stopped at byte {self.stopped_at}: {self.stop_reason}"
        chunks = sum(1 for d in self.damage if d.where.startswith("chunk"))
        if chunks:
            text += f"; {chunks} damaged chunk(s) skipped"
        return text

    @classmethod
    def try_open(cls, path: Path) -> _ScannedMcap | None:
        """A scanned reader when ``path`` starts like a ros2 MCAP file, else None."""
        if path.suffix != ".mcap":
            return None
        with open(path, "rb") as fh:
            head = fh.read(64)
        if not head.startswith(_MCAP_MAGIC) or len(head) < 18 or head[8] != 0x01:
            return None
        scanned = cls(path)
        return scanned if scanned.connections else None

    def close(self) -> None:
        """Nothing to release (each scan opens and closes the file)."""

    def _records(self) -> Iterator[tuple[int, Any]]:
        """(opcode, parsed) for schemas, channels and messages, chunks expanded; ``(-1,
        Damage)`` for a chunk that cannot be read and for a damaged tail."""
        import struct

        from rosbags.rosbag2.storage_mcap import decompress

        def string(buf: bytes, pos: int) -> tuple[str, int]:
            (n,) = struct.unpack_from("<I", buf, pos)
            return buf[pos + 4:pos + 4 + n].decode(), pos + 4 + n

        def parse(op: int, body: bytes) -> tuple[int, Any] | None:
            if op == 0x03:
                (sid,) = struct.unpack_from("<H", body, 0)
                name, pos = string(body, 2)
                enc, pos = string(body, pos)
                (n,) = struct.unpack_from("<I", body, pos)
                return op, (sid, name, enc, body[pos + 4:pos + 4 + n].decode())
            if op == 0x04:
                cid, schema_id = struct.unpack_from("<HH", body, 0)
                topic, pos = string(body, 4)
                enc, pos = string(body, pos)
                (n,) = struct.unpack_from("<I", body, pos)
                return op, (cid, schema_id, topic, enc, body[pos + 4:pos + 4 + n])
            if op == 0x05:
                cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
                return op, (cid, log_time, body[22:])
            return None

        with open(self.path, "rb") as fh:
            data = fh.read()
        pos = 8
        last = [0]

        def tail(at: int, reason: str) -> tuple[int, Any]:
            self.stopped_at, self.stop_reason = at, reason
            return -1, Damage(self.path.name, f"file tail from byte {at}",
                              f"{reason} (the file ends at byte {len(data)})",
                              start_ns=last[0] or None)

        while pos < len(data):
            if pos + 9 > len(data):
                yield tail(pos, "incomplete record header")
                return
            op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
            if op == 0 or op > 0x0F:
                yield tail(pos, f"invalid record opcode {op}")
                return
            if pos + 9 + length > len(data):
                yield tail(pos, "incomplete record")
                return
            body = data[pos + 9:pos + 9 + length]
            pos += 9 + length
            if op in (0x02, 0x0F):  # footer / data end: the data section is complete
                return
            if op != 0x06:
                if (rec := parse(op, body)) is not None:
                    yield rec
                continue
            chunk_at = pos - 9 - length
            t0 = t1 = None
            try:  # chunk: expand its records, messages sorted by log time
                t0, t1, size, crc = struct.unpack_from("<QQQI", body, 0)
                compression, cpos = string(body, 28)
                (n,) = struct.unpack_from("<Q", body, cpos)
                inner = decompress(body[cpos + 8:cpos + 8 + n], compression, size, crc)
            except Exception as exc:
                yield -1, Damage(self.path.name, f"chunk at byte {chunk_at}",
                                 f"{str(exc) or type(exc).__name__}", start_ns=t0, end_ns=t1)
                continue
            ipos, msgs = 0, []
            try:
                while ipos + 9 <= len(inner):
                    iop, ilen = inner[ipos], struct.unpack_from("<Q", inner, ipos + 1)[0]
                    if ipos + 9 + ilen > len(inner) or iop not in (0x03, 0x04, 0x05):
                        raise ValueError(f"record at {ipos} of the chunk makes no sense "
                                         f"(opcode {iop:#04x}, {ilen} bytes)")
                    rec = parse(iop, inner[ipos + 9:ipos + 9 + ilen])
                    ipos += 9 + ilen
                    if rec is not None and iop == 0x05:
                        msgs.append(rec)
                    elif rec is not None:
                        yield rec
            except Exception as exc:
                yield -1, Damage(self.path.name, f"chunk at byte {chunk_at}",
                                 f"{str(exc) or type(exc).__name__}; the messages before it "
                                 "are kept", start_ns=t0, end_ns=t1)
            msgs.sort(key=lambda r: r[1][1])
            if msgs:
                last[0] = max(last[0], msgs[-1][1][1])
            yield from msgs

    def messages(self, connections: Sequence[Any], start: int | None = None,
                 stop: int | None = None, on_damage: Any = None,
                 ) -> Iterator[tuple[Any, int, bytes]]:
        """Messages of ``connections`` in ``[start, stop)``; damage to ``on_damage``
        (a damaged chunk without it raises :class:`BagError`; the damaged tail never does,
        it is what scanning is for)."""
        by_id = {c.id: c for c in connections}
        lo = start if start is not None else 0
        hi = stop if stop is not None else 2**63
        for kind, rec in self._records():
            if kind == 0x05 and rec[0] in by_id and lo <= rec[1] < hi:
                yield by_id[rec[0]], rec[1], rec[2]
            elif kind == -1:
                if on_damage is not None:
                    on_damage(rec)
                elif not rec.where.startswith("file tail"):
                    raise BagError(f"{rec.where} of {rec.file}: {rec.reason}")


class _OpenBag:
    """The rosbags readers of one bag, opened; a context manager."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.readers: list[Any] = []
        targets = _storage_paths(self.path)
        from rosbags.rosbag2 import Reader

        self.notes: list[str] = []
        try:
            for target in targets:
                try:
                    reader: Any = Reader(target)
                    reader.open()
                except Exception as exc:
                    # a storage file without summary (recording interrupted, file truncated):
                    # scan it, also when it belongs to a bag directory with metadata.yaml
                    files = [target] if target.is_file() else \
                        sorted(f for f in target.glob("*.mcap") if f.is_file())
                    scanned_all = [_ScannedMcap.try_open(f) for f in files]
                    if not scanned_all or any(x is None for x in scanned_all):
                        raise
                    for f, scanned in zip(files, scanned_all):
                        assert scanned is not None
                        self.readers.append(scanned)
                        self.notes.append(
                            f"{f.name}: {exc} (no MCAP summary: the recording was interrupted "
                            f"or the file is truncated); read by scanning the file"
                            f"{scanned.tail_note}")
                    continue
                self.readers.append(reader)
        except Exception as exc:
            self.close()
            raise _bag_error(self.path, exc, "open") from exc

    def close(self) -> None:
        readers, self.readers = self.readers, []
        for reader in readers:
            reader.close()

    def __enter__(self) -> _OpenBag:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def connections(self) -> list[Any]:
        return [c for r in self.readers for c in r.connections]


def _qos_name(value: Any) -> str:
    name = getattr(value, "name", str(value)).lower()
    return "best_effort" if name == "best_effort" else name


def _offered(conn: Any) -> tuple[OfferedQos, ...]:
    profiles = getattr(conn.ext, "offered_qos_profiles", None) or []
    return tuple(OfferedQos(reliability=_qos_name(q.reliability),
                            durability=_qos_name(q.durability),
                            history=_qos_name(q.history), depth=int(q.depth))
                 for q in profiles)


def bag_info(path: str | Path) -> BagInfo:
    """Summarise a bag: storage, time range, and per-topic type and message count.

    Args:
        path: a bag directory (with or without ``metadata.yaml``) or a ``.mcap``/``.db3`` file.

    Returns:
        The bag's :class:`BagInfo`.

    Raises:
        BagError: the bag is missing, unreadable, corrupt, or of an unsupported format.
    """
    from rosbags.interfaces import MessageDefinitionFormat

    with _OpenBag(path) as bag:
        try:
            storage_files: list[Path] = []
            storages: set[str] = set()
            version: int | None = None
            compression_format = compression_mode = distro = ""
            start, end, count = 2**63 - 1, 0, 0
            for reader in bag.readers:
                inner = reader.storage
                if hasattr(inner, "storages"):  # DirectoryReader
                    meta = _read_metadata(Path(reader.path))
                    version = int(meta.get("version", 0))
                    storages.add(str(meta.get("storage_identifier", "")))
                    storage_files.extend(Path(reader.path) / Path(str(f)).name
                                         for f in meta.get("relative_file_paths", []))
                    distro = str(meta.get("ros_distro") or "")
                else:
                    storages.add(_STORAGE_SUFFIX[Path(reader.path).suffix])
                    storage_files.append(Path(reader.path))
                compression_format = reader.compression_format or compression_format
                compression_mode = reader.compression_mode or compression_mode
                if reader.message_count:
                    start = min(start, reader.start_time)
                    end = max(end, reader.end_time - 1)
                    count += reader.message_count
            topics: dict[str, TopicInfo] = {}
            for conn in bag.connections():
                have = topics.get(conn.topic)
                if have is not None and have.msgtype == conn.msgtype:
                    topics[conn.topic] = TopicInfo(
                        have.name, have.msgtype, have.count + conn.msgcount,
                        have.serialization_format, have.offered_qos + _offered(conn),
                        have.type_hash or conn.digest, have.has_definition
                        or conn.msgdef.format != MessageDefinitionFormat.NONE)
                    continue
                if have is not None:
                    raise BagError(f"bag {bag.path}: topic {conn.topic} is recorded with two "
                                   f"types, {have.msgtype} and {conn.msgtype}")
                topics[conn.topic] = TopicInfo(
                    conn.topic, conn.msgtype, int(conn.msgcount),
                    getattr(conn.ext, "serialization_format", "cdr"), _offered(conn),
                    conn.digest or "", conn.msgdef.format != MessageDefinitionFormat.NONE)
            size = 0
            for f in storage_files:
                size += f.stat().st_size if f.exists() else 0
        except BagError:
            raise
        except Exception as exc:
            raise _bag_error(bag.path, exc) from exc
    if not count:
        start = end = 0
    return BagInfo(
        path=bag.path, storage="+".join(sorted(storages)), files=tuple(storage_files),
        version=version, start_ns=start, end_ns=end, message_count=count,
        topics=dict(sorted(topics.items())), compression_format=compression_format or "",
        compression_mode=compression_mode or "", ros_distro=distro, size_bytes=size,
        notes=tuple(bag.notes))


def _read_metadata(bag_dir: Path) -> dict[str, Any]:
    import yaml

    with open(bag_dir / "metadata.yaml", encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    return dict(data["rosbag2_bagfile_information"])


def _check_window(start_ns: int | None, end_ns: int | None) -> None:
    for name, value in (("start_ns", start_ns), ("end_ns", end_ns)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(f"{name} must be an int number of nanoseconds, got {value!r}")
    if start_ns is not None and end_ns is not None and end_ns < start_ns:
        raise InputError(f"end_ns {end_ns} is before start_ns {start_ns}")


def iter_messages(path: str | Path, topics: Iterable[str] | None = None,
                  start_ns: int | None = None, end_ns: int | None = None, *,
                  views: bool = False, verify_crc: bool = True,
                  damage: DamageLog | None = None) -> Iterator[BagMessage]:
    """Iterate over a bag's messages in log-time order, as raw CDR bytes.

    Messages of several storage files (split bags, or a directory of loose ``.mcap`` files)
    are merged by log time; ties keep storage order. Indexed MCAP files are memory-mapped and
    read without copies (:mod:`eye_in_hand.io.mcap_chunks`); other storage goes through
    ``rosbags``.

    Args:
        path: a bag directory or a ``.mcap``/``.db3`` file.
        topics: only these topics (None: all). Topics the bag does not have are ignored;
            use :func:`require_topics` to insist on them.
        start_ns: only messages with log time >= start_ns.
        end_ns: only messages with log time <= end_ns (inclusive).
        views: yield read-only ``memoryview`` data where the storage allows (indexed MCAP:
            views of the mapped file or of a decompressed chunk, valid after the iteration)
            instead of ``bytes``; saves copying every image.
        verify_crc: check MCAP chunk CRCs when the file has them (CRC-32 runs at about
            0.35 GB/s here: 16 ms per 1280x720 colour stereo pair).
        damage: where damaged parts go: an MCAP chunk that cannot be read (bad index entry,
            data that do not decompress, CRC mismatch, records that stop making sense: the
            messages before the bad record are kept), the tail of a truncated file, a
            per-message-compressed message that does not decompress, a storage file that
            fails part-way (sqlite3): each becomes a :class:`Damage` record in the log, with
            topics, log-time range and messages lost, and the rest of the bag is read on.
            None: such damage raises :class:`BagError` (as before this option existed).

    Yields:
        ``(topic, msgtype, log_time_ns, raw_cdr_bytes)``.

    Raises:
        BagError: the bag cannot be opened, or (without ``damage``) a part of it cannot be
            read.
        InputError: bad time window.
    """
    _check_window(start_ns, end_ns)
    wanted = None if topics is None else set(topics)
    stop = None if end_ns is None else end_ns + 1
    with _OpenBag(path) as bag:
        streams: list[Iterator[tuple[int, int, int, str, str, bytes]]] = []
        for reader in bag.readers:
            inner = reader.storage
            if hasattr(inner, "storages"):  # a directory: read its storage files directly
                parts = list(inner.storages)
                per_message_zstd = inner.metadata.compression_mode == "message"
            else:
                parts, per_message_zstd = [inner], False
            for part in parts:
                conns = [c for c in part.connections if wanted is None or c.topic in wanted]
                if conns:
                    streams.append(_storage_stream(part, conns, start_ns, stop,
                                                   per_message_zstd, len(streams), views,
                                                   verify_crc, damage))
        if not streams:
            return
        merged = streams[0] if len(streams) == 1 else heapq.merge(*streams)
        index = 0
        try:
            for stamp, _stream, _order, topic, msgtype, raw in merged:
                yield topic, msgtype, stamp, raw
                index += 1
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"cannot read bag {bag.path} after message {index}: "
                           f"{str(exc) or type(exc).__name__}") from exc


def check_bag(path: str | Path, damage: DamageLog) -> dict[str, int]:
    """Read and decode every message of a bag, chunk CRCs checked: what ``bag info --check``
    does.

    Args:
        path: a bag directory or a ``.mcap``/``.db3`` file.
        damage: receives every damaged region and every message that does not decode
            (images: their layout and data length are checked without copying the pixels).

    Returns:
        Topic -> number of messages read and decoded.

    Raises:
        BagError: the bag cannot be opened at all.
    """
    from eye_in_hand.errors import ConversionError
    from eye_in_hand.io.cdr import image_from_cdr, is_image_type

    store = typestore_for(path)
    good: dict[str, int] = {}
    for topic, msgtype, stamp, raw in iter_messages(path, views=True, verify_crc=True,
                                                    damage=damage):
        try:
            img = image_from_cdr(raw) if is_image_type(msgtype) else None
            if img is not None:
                if img.height * img.step > len(img.data):
                    raise ConversionError(f"image data: {len(img.data)} bytes, "
                                          f"height x step needs {img.height * img.step}")
            else:
                deserialize(raw, msgtype, store)
        except (BagError, ConversionError) as exc:
            damage.bad_message(topic, stamp, str(exc))
            continue
        good[topic] = good.get(topic, 0) + 1
    return good


def memory_mappable(path: str | Path) -> bool:
    """Whether every storage file of a bag is an indexed MCAP file with uncompressed chunks,
    i.e. whether ``iter_messages(..., views=True)`` yields views of the files themselves."""
    from eye_in_hand.io import mcap_chunks

    with _OpenBag(path) as bag:
        for reader in bag.readers:
            inner = reader.storage
            if getattr(inner, "metadata", None) is not None and \
                    getattr(inner.metadata, "compression_mode", "") == "message":
                return False
            for part in (list(inner.storages) if hasattr(inner, "storages") else [inner]):
                if not mcap_chunks.supports(part) or any(c.compression for c in part.chunks):
                    return False
    return True


def iter_decoded(path: str | Path, topics: Iterable[str] | None = None,
                 start_ns: int | None = None, end_ns: int | None = None, *,
                 damage: DamageLog | None = None) -> Iterator[tuple[str, int, Any]]:
    """Like :func:`iter_messages`, with each message decoded (for offline processing).

    Types are taken from :func:`typestore_for` (the bag's own definitions, Jazzy for the rest;
    a message that its stored definition does not decode is tried with the Jazzy one).

    Args:
        damage: as :func:`iter_messages`; a message that does not decode is recorded there
            too (:meth:`DamageLog.bad_message`, naming topic and log time) and skipped.

    Yields:
        ``(topic, log_time_ns, message)`` with rosbags message objects (numpy arrays for
        numeric sequences).

    Raises:
        BagError: as :func:`iter_messages`, or (without ``damage``) a message that does not
            decode (names the topic and the log time).
    """
    store = typestore_for(path)
    for topic, msgtype, stamp, raw in iter_messages(path, topics, start_ns, end_ns,
                                                    damage=damage):
        try:
            msg = deserialize(raw, msgtype, store)
        except BagError as exc:
            if damage is None:
                raise BagError(f"bag {Path(path)}, topic {topic} at {stamp} ns: {exc}") from exc
            damage.bad_message(topic, stamp, str(exc))
            continue
        yield topic, stamp, msg


def _storage_stream(storage: Any, conns: list[Any], start: int | None, stop: int | None,
                    per_message_zstd: bool, stream: int, views: bool = False,
                    verify_crc: bool = True, damage: DamageLog | None = None,
                    ) -> Iterator[tuple[int, int, int, str, str, bytes]]:
    """Messages of one storage file, with its own connections.

    ``rosbags``' directory reader matches the connections of ``metadata.yaml`` to those of the
    storage file by topic, type *and* QoS; a bag whose two QoS copies differ in form (durations
    written as 2147483647/4294967295 in one and 9223372036/854775807 in the other, or QoS only
    in one of them) then yields nothing. Reading each storage file with its own connections
    avoids that.

    Damage goes to ``damage`` (see :func:`iter_messages`); without it, it raises.
    """
    from eye_in_hand.io import mcap_chunks

    name = Path(getattr(storage, "path", "")).name
    by_id = {c.id: c for c in conns}

    if not per_message_zstd and mcap_chunks.supports(storage):
        def chunk_damage(cd: mcap_chunks.ChunkDamage) -> None:
            assert damage is not None
            topics: dict[str, int] = {}
            for cid, n in (cd.lost or {}).items():
                topic = by_id[cid].topic
                topics[topic] = topics.get(topic, 0) + n
            where = f"chunk at byte {cd.offset}"
            reason = cd.reason[len(where) + 2:] if cd.reason.startswith(where + ": ") \
                else cd.reason
            damage.add(Damage(name, where, reason, topics,
                              cd.start_ns, cd.end_ns,
                              None if cd.lost is None else sum(topics.values())))

        source = mcap_chunks.chunk_messages(storage, conns, start, stop, verify_crc=verify_crc,
                                            on_damage=None if damage is None else chunk_damage)
        for order, (conn, stamp, view) in enumerate(source):
            yield stamp, stream, order, conn.topic, conn.msgtype, view if views else bytes(view)
        return
    if per_message_zstd:
        try:
            from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
        except ImportError:
            from backports import zstd  # type: ignore[import-not-found,no-redef]
    if isinstance(storage, _ScannedMcap):
        source: Iterator[tuple[Any, int, Any]] = storage.messages(
            conns, start, stop, on_damage=damage.add if damage is not None else None)
    else:
        source = storage.messages(conns, start, stop)
    read: dict[int, int] = {}
    last = start
    order = 0
    while True:
        try:
            item = next(source, None)
        except Exception as exc:
            if damage is None:
                raise
            # the storage fails part-way (a corrupt sqlite3 page): the rest of the file is lost
            lost = {c.topic: int(c.msgcount) - read.get(c.id, 0) for c in conns
                    if start is None and stop is None and int(c.msgcount) > read.get(c.id, 0)}
            damage.add(Damage(name, "the rest of the file",
                              f"reading stopped after {order} message(s): "
                              f"{str(exc) or type(exc).__name__}", lost, last, None,
                              sum(lost.values()) if lost else None))
            return
        if item is None:
            return
        conn, stamp, raw = item
        stamp = int(stamp)
        last = stamp
        read[conn.id] = read.get(conn.id, 0) + 1
        if per_message_zstd:
            try:
                data = zstd.decompress(raw)
            except Exception as exc:
                if damage is None:
                    raise BagError(f"{name}: {conn.topic} message at {stamp} ns does not "
                                   f"decompress: {exc}") from exc
                damage.bad_message(conn.topic, stamp, f"zstd data do not decompress ({exc})",
                                   name)
                continue
        else:
            data = bytes(raw)
        yield stamp, stream, order, conn.topic, conn.msgtype, data
        order += 1


# --------------------------------------------------------------------------------------------
# types
# --------------------------------------------------------------------------------------------

_DEFAULT_STORE: Any = None
_DEFAULT_LOCK = threading.Lock()


def default_typestore() -> Any:
    """A shared ROS 2 Jazzy ``rosbags`` type store (do not register types in it)."""
    global _DEFAULT_STORE
    with _DEFAULT_LOCK:
        if _DEFAULT_STORE is None:
            from rosbags.typesys import Stores, get_typestore

            _DEFAULT_STORE = get_typestore(Stores.ROS2_JAZZY)
        return _DEFAULT_STORE


def _types_from_definition(msgtype: str, fmt: Any, text: str) -> dict[str, Any]:
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    if fmt == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(text, msgtype))
    types: dict[str, Any] = {}
    sep = "=" * 80 + "\n"
    if text.startswith(f"{sep}IDL: "):
        for part in text.split(sep)[1:]:
            _header, idl = part.split("\n", 1)
            types.update(get_types_from_idl(idl))
    else:
        types.update(get_types_from_idl(text))
    return types


def _type_refs(fields: Any) -> Iterator[str]:
    """The message type names a rosbags field list refers to."""
    from rosbags.interfaces import Nodetype

    def walk(node: Any) -> Iterator[str]:
        kind, detail = node
        if kind == Nodetype.NAME:
            yield detail
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            yield from walk(detail[0])

    for _name, node in fields:
        yield from walk(node)


def _type_closure(types: Mapping[str, Any], roots: Iterable[str]) -> tuple[dict[str, Any],
                                                                         set[str]]:
    """``types`` restricted to ``roots`` and the types they use, recursively; and the names
    used but not in ``types``."""
    out: dict[str, Any] = {}
    missing: set[str] = set()
    todo = list(roots)
    while todo:
        name = todo.pop()
        if name in out or name in missing:
            continue
        if name not in types:
            missing.add(name)
            continue
        out[name] = types[name]
        todo.extend(_type_refs(types[name][1]))
    return out, missing


def typestore_for(path: str | Path, msgtypes: Iterable[str] | None = None) -> Any:
    """A type store that can decode every message of a bag (or the types asked for).

    It holds the message definitions stored in the bag (MCAP schemas, the sqlite3
    ``message_definitions`` table of Jazzy bags) and, for every other type, the ROS 2 Jazzy
    definitions. A bag's own definition wins over Jazzy's, so bags from other distributions
    whose types changed still decode; a stored definition that does not parse is replaced by
    the Jazzy one when Jazzy defines the type (and :func:`deserialize` falls back to the Jazzy
    definition for a message the stored one does not decode).

    Args:
        path: a bag directory or a ``.mcap``/``.db3`` file.
        msgtypes: only these types (and the types they use) are registered; None: all. Building
            every type costs ~0.1 s, and loading the Jazzy definitions ~0.15 s more, which is
            skipped when the bag defines everything asked for.

    Returns:
        A ``rosbags.typesys.store.Typestore``; pass it to :func:`deserialize`.

    Raises:
        BagError: the bag cannot be opened, or a stored definition cannot be parsed.
    """
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_typestore

    wanted = None if msgtypes is None else set(msgtypes)
    types: dict[str, Any] = {}
    with _OpenBag(path) as bag:
        for conn in bag.connections():
            # every stored definition is parsed (cheap): a type asked for may be defined only
            # inside another topic's definition; building (register) is what costs
            if conn.msgdef.format == MessageDefinitionFormat.NONE or conn.msgtype in types:
                continue
            try:
                types.update(_types_from_definition(conn.msgtype, conn.msgdef.format,
                                                    conn.msgdef.data))
            except Exception as exc:
                if conn.msgtype in default_typestore().types:
                    continue     # a stored definition that does not parse: Jazzy's is used
                raise BagError(f"bag {bag.path}: cannot parse the stored definition of "
                               f"{conn.msgtype} (topic {conn.topic}): {exc}") from exc
    if wanted is None or _type_closure(types, wanted)[1]:
        for name, fields in default_typestore().fielddefs.items():
            types.setdefault(name, fields)
    if wanted is not None:
        types = _type_closure(types, wanted)[0]
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
    except Exception as exc:
        raise BagError(f"bag {Path(path)}: cannot build types from its definitions: {exc}"
                       ) from exc
    return store


def deserialize(raw: bytes | bytearray | memoryview, msgtype: str, typestore: Any = None) -> Any:
    """Decode CDR bytes into a ``rosbags`` message object.

    Args:
        raw: the serialized message (CDR with its 4-byte encapsulation header).
        msgtype: e.g. ``sensor_msgs/msg/Image``.
        typestore: from :func:`typestore_for`; default: the Jazzy type store. When the
            type store's definition does not decode the bytes and ROS 2 Jazzy defines the
            type, the Jazzy definition is tried before giving up (a bag may store an old or
            wrong definition).

    Returns:
        A rosbags dataclass instance (numpy arrays for numeric sequences).

    Raises:
        BagError: unknown type, or bytes that decode with neither definition.
    """
    store = typestore if typestore is not None else default_typestore()
    jazzy = default_typestore()
    if msgtype not in store.types and msgtype not in jazzy.types:
        raise BagError(f"message type {msgtype} is not known (not in ROS 2 Jazzy and not "
                       "defined by the bag); cannot decode it")
    data = bytes(raw)
    try:
        if msgtype not in store.types:
            raise KeyError(msgtype)
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:
        # the bag's stored definition may be old or wrong (a recorder with another
        # distribution's definition): the Jazzy definition, when there is one, gets a try
        if store is not jazzy and msgtype in jazzy.types:
            try:
                return jazzy.deserialize_cdr(data, msgtype)
            except Exception:
                pass
            raise BagError(f"cannot decode {len(raw)} bytes as {msgtype} with the bag's "
                           f"definition ({exc}) nor with the ROS 2 Jazzy one") from exc
        raise BagError(f"cannot decode {len(raw)} bytes as {msgtype}: {exc}") from exc


def serialize(msg: Any, msgtype: str, typestore: Any = None) -> bytes:
    """Encode a ``rosbags`` message object as CDR bytes (little endian).

    Args:
        msg: a rosbags message instance, e.g. ``store.types['std_msgs/msg/String'](data='x')``.
        msgtype: its type name.
        typestore: default: the Jazzy type store.

    Returns:
        The CDR bytes, with encapsulation header.

    Raises:
        BagError: unknown type, or a message that does not match the type.
    """
    store = typestore if typestore is not None else default_typestore()
    if msgtype not in store.types:
        raise BagError(f"message type {msgtype} is not known; cannot encode it")
    if hasattr(type(msg), "get_fields_and_field_types"):
        raise BagError(f"got an rclpy {type(msg).__name__} for {msgtype}: pass its CDR bytes "
                       "(rclpy.serialization.serialize_message(msg)) or a rosbags message")
    try:
        return bytes(store.serialize_cdr(msg, msgtype))
    except Exception as exc:
        raise BagError(f"cannot encode a {type(msg).__name__} as {msgtype}: {exc}") from exc


def require_topics(info: BagInfo, topics: Iterable[str]) -> None:
    """Check that a bag has every topic in ``topics``, with at least one message.

    Args:
        info: from :func:`bag_info`.
        topics: the topic names needed.

    Raises:
        BagError: naming the missing (or empty) topics and listing what the bag has.
    """
    missing = [t for t in topics if t not in info.topics]
    empty = [t for t in topics if t in info.topics and info.topics[t].count == 0]
    if not missing and not empty:
        return
    have = ", ".join(f"{t.name} ({t.msgtype}, {t.count})" for t in info.topics.values())
    parts = []
    if missing:
        parts.append(f"lacks topic{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    if empty:
        parts.append(f"has no messages on {', '.join(empty)}")
    raise BagError(f"bag {info.path} {' and '.join(parts)}; it has: {have or 'no topics'}")


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------

def _to_rosbags_qos(qos: OfferedQos) -> Any:
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    try:
        return Qos(QosHistory[qos.history.upper()], int(qos.depth),
                   QosReliability[qos.reliability.upper()],
                   QosDurability[qos.durability.upper()], QosTime(0, 0), QosTime(0, 0),
                   QosLiveliness.SYSTEM_DEFAULT, QosTime(0, 0), False)
    except KeyError as exc:
        raise InputError(f"unknown QoS policy value {exc} in {qos}") from exc


ROS_DISTRO = "jazzy"
"""The distribution written bags name in ``metadata.yaml`` (the package targets ROS 2 Jazzy)."""


class _CrcFile:
    """A write-only file that keeps the CRC-32 of everything written through it."""

    def __init__(self, fh: Any, crc: int) -> None:
        self._fh = fh
        self.crc = crc

    def write(self, data: Any) -> int:
        self.crc = zlib.crc32(data, self.crc)
        return self._fh.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


_WRITER_CLASS: Any = None


def _rosbags_writer() -> Any:
    """``rosbags.rosbag2.Writer`` whose MCAP files carry CRCs and whose metadata names the
    distribution.

    ``rosbags`` writes 0 (not computed) in every CRC field of an MCAP file and
    ``ros_distro: rosbags`` in the metadata. Here each chunk gets the CRC-32 of its
    uncompressed records, the data-end record the CRC-32 of the data section, and the footer
    the CRC-32 of the summary section, as the MCAP specification defines them, so that
    corruption can be detected (``--verify-crc``); the metadata (``metadata.yaml`` and the
    copy inside the storage file) says ``ros_distro: jazzy``.
    """
    global _WRITER_CLASS
    if _WRITER_CLASS is not None:
        return _WRITER_CLASS
    from io import BytesIO

    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.rosbag2.storage_mcap import (McapWriter, PendingChunk, write_record,
                                              write_string, write_uint16, write_uint32,
                                              write_uint64)
    from collections import defaultdict

    def jazzy(metadata: str) -> str:
        return metadata.replace("ros_distro: rosbags", f"ros_distro: {ROS_DISTRO}")

    class CrcMcapWriter(McapWriter):  # type: ignore[misc,valid-type]
        def __init__(self, path: Path, compression: Any) -> None:
            super().__init__(path, compression)
            self.bio.flush()
            head = self.path.read_bytes()[:self.bio.tell()]     # magic and header record
            self.bio = _CrcFile(self.bio, zlib.crc32(head))

        def close_chunk(self) -> None:
            # rosbags' close_chunk, with the CRC-32 of the uncompressed records
            rec = BytesIO()
            write_uint64(rec, self.chunk.message_start_time)
            write_uint64(rec, self.chunk.message_end_time)
            write_uint64(rec, self.chunk.bio.tell())
            write_uint32(rec, zlib.crc32(self.chunk.bio.getbuffer()))
            compressed = self.compressor(self.chunk.bio.getvalue())
            write_string(rec, self.compression)
            write_uint64(rec, len(compressed))
            rec.write(compressed)
            chunk_start = self.bio.tell()
            write_record(self.bio, 0x06, rec)
            chunk_end = self.bio.tell()
            offsets: list[tuple[int, int]] = []
            for cid, msgs in self.chunk.msgs.items():
                offsets.append((cid, self.bio.tell()))
                rec = BytesIO()
                write_uint16(rec, cid)
                write_uint32(rec, len(msgs) * 16)
                for ts, offset in msgs:
                    write_uint64(rec, ts)
                    write_uint64(rec, offset)
                write_record(self.bio, 0x07, rec)
            rec = BytesIO()
            write_uint64(rec, self.chunk.message_start_time)
            write_uint64(rec, self.chunk.message_end_time)
            write_uint64(rec, chunk_start)
            write_uint64(rec, chunk_end - chunk_start)
            write_uint32(rec, len(offsets) * 10)
            for cid, offset in offsets:
                write_uint16(rec, cid)
                write_uint64(rec, offset)
            write_uint64(rec, self.bio.tell() - chunk_end)
            write_string(rec, self.compression)
            write_uint64(rec, len(compressed))
            write_uint64(rec, self.chunk.bio.tell())
            self.chunks.append(rec)
            self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

        def close(self, version: int, metadata: str) -> None:
            if self.chunk.bio.tell():
                self.close_chunk()
            pos, crc = self.bio.tell(), self.bio.crc
            super().close(version, jazzy(metadata))
            _patch_mcap_crcs(self.path, pos, crc)

    class CrcWriter(Writer):  # type: ignore[misc,valid-type]
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: CrcMcapWriter}

        def close(self) -> None:
            storage = self.storage
            if storage is not None and not isinstance(storage, CrcMcapWriter):
                close = storage.close
                storage.close = lambda version, metadata: close(version, jazzy(metadata))
            super().close()
            meta = Path(self.metapath)
            if meta.is_file():
                meta.write_text(jazzy(meta.read_text("utf8")), "utf8")

    _WRITER_CLASS = CrcWriter
    return CrcWriter


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
        if tail[0] != 0x02:
            raise BagError(f"{path}: no MCAP footer where expected (byte {footer})")
        summary_start = int.from_bytes(tail[9:17], "little")
        data_end = (summary_start or footer) - 13
        fh.seek(pos)
        rest = fh.read(data_end - pos)
        end_rec = fh.read(13)
        if end_rec[0] != 0x0F:
            raise BagError(f"{path}: no MCAP data-end record where expected (byte {data_end})")
        fh.seek(data_end + 9)
        fh.write(zlib.crc32(rest, crc).to_bytes(4, "little"))
        if summary_start:
            fh.seek(summary_start)
            summary = fh.read(footer + 25 - summary_start)
            fh.seek(footer + 25)
            fh.write(zlib.crc32(summary).to_bytes(4, "little"))


@dataclass
class _Topic:
    connection: Any
    msgtype: str
    count: int = 0


class BagWriter:
    """Write a rosbag2 bag (metadata version 9), readable by ``ros2 bag`` and this module.

    A context manager. The bag is always left valid: ``metadata.yaml`` is written on
    :meth:`close` and also when the ``with`` block ends with an exception, so that whatever was
    written before a failure or Ctrl-C stays readable. Thread-safe: :meth:`write` may be called
    from several threads.

    Args:
        path: the bag directory to create; it must not exist.
        storage: ``"mcap"`` (default, like ``ros2 bag record`` on Jazzy) or ``"sqlite3"``.
        compression: None, or ``"zstd"``: zstd-compressed MCAP chunks for ``mcap``, per-message
            zstd (``--compression-mode message``) for ``sqlite3``.
        typestore: a rosbags type store for definitions and for serializing message objects;
            default: a private copy of the Jazzy store (types added with ``msgdef`` go there).

    Raises:
        InputError: unknown storage or compression.
        BagError: ``path`` exists, or the bag cannot be created.
    """

    def __init__(self, path: str | Path, storage: Literal["mcap", "sqlite3"] = "mcap",
                 compression: Literal["zstd"] | None = None, *, typestore: Any = None) -> None:
        if storage not in STORAGES:
            raise InputError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
        if compression not in COMPRESSIONS:
            raise InputError(f"compression must be None or 'zstd', got {compression!r}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"cannot write bag {self.path}: it exists already")
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
        from rosbags.typesys import Stores, get_typestore

        self.storage = storage
        self.compression = compression
        self._store = typestore if typestore is not None else get_typestore(Stores.ROS2_JAZZY)
        self._lock = threading.Lock()
        self._topics: dict[str, _Topic] = {}
        self._closed = False
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        try:
            self._writer = _rosbags_writer()(self.path, version=9, storage_plugin=plugin)
            if compression == "zstd":
                mode = CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE
                self._writer.set_compression(mode, CompressionFormat.ZSTD)
            self._writer.open()
        except Exception as exc:
            raise _bag_error(self.path, exc, "create") from exc

    @property
    def typestore(self) -> Any:
        """The writer's rosbags type store: build message objects with ``typestore.types``
        (it also knows the types added with ``msgdef``)."""
        return self._store

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type of the topics added so far."""
        return {name: t.msgtype for name, t in self._topics.items()}

    @property
    def counts(self) -> dict[str, int]:
        """Topic name -> number of messages written so far."""
        with self._lock:
            return {name: t.count for name, t in self._topics.items()}

    def add_topic(self, name: str, msgtype: str, *, msgdef: str | None = None,
                  qos: Sequence[OfferedQos] = ()) -> None:
        """Declare a topic before writing to it.

        Args:
            name: topic name (absolute, e.g. ``/left/image_raw``).
            msgtype: ``pkg/msg/Type``.
            msgdef: the ``.msg`` definition of ``msgtype`` (dependencies appended after
                ``====`` / ``MSG: pkg/msg/Dep`` lines, as rosbag2 stores them); needed only for
                types that ROS 2 Jazzy does not define. It is stored in the bag.
            qos: the QoS profiles the recorded publishers offered (stored in metadata and
                used by ``play`` to offer the same).

        Raises:
            InputError: bad name or type string.
            BagError: topic already added with another type, unknown type without ``msgdef``,
                a definition that does not parse, or a closed writer.
        """
        if not isinstance(name, str) or not name:
            raise InputError(f"topic name must be a non-empty string, got {name!r}")
        if not isinstance(msgtype, str) or msgtype.count("/") != 2:
            raise InputError(f"message type must look like 'pkg/msg/Type', got {msgtype!r}")
        with self._lock:
            self._check_open()
            if name in self._topics:
                if self._topics[name].msgtype != msgtype:
                    raise BagError(f"bag {self.path}: topic {name} was added as "
                                   f"{self._topics[name].msgtype}, not {msgtype}")
                return
            if msgtype not in self._store.types:
                if msgdef is None:
                    raise BagError(
                        f"bag {self.path}: message type {msgtype} of topic {name} is not in "
                        "ROS 2 Jazzy; pass its definition (msgdef=...)")
                try:
                    from rosbags.interfaces import MessageDefinitionFormat

                    self._store.register(_types_from_definition(
                        msgtype, MessageDefinitionFormat.MSG, msgdef))
                except Exception as exc:
                    raise BagError(f"bag {self.path}: cannot parse the definition of "
                                   f"{msgtype}: {exc}") from exc
            try:
                conn = self._writer.add_connection(
                    name, msgtype, typestore=self._store,
                    offered_qos_profiles=[_to_rosbags_qos(q) for q in qos])
            except InputError:
                raise
            except Exception as exc:
                raise _bag_error(self.path, exc, "write") from exc
            self._topics[name] = _Topic(conn, msgtype)

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Write one message.

        Args:
            topic: a topic added with :meth:`add_topic`.
            stamp_ns: log time in int nanoseconds (>= 0).
            msg: CDR bytes (``bytes``/``bytearray``/``memoryview``) written as they are, or a
                rosbags message object of the topic's type, serialized here.

        Raises:
            InputError: bad stamp.
            BagError: unknown topic, closed writer, or a message that does not serialize.
        """
        if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, int) or stamp_ns < 0:
            raise InputError(f"stamp_ns must be a non-negative int (ns), got {stamp_ns!r}")
        with self._lock:
            self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                raise BagError(f"bag {self.path}: topic {topic} was not added "
                               f"(have: {', '.join(self._topics) or 'none'})")
            if isinstance(msg, (bytes, bytearray, memoryview)):
                raw = bytes(msg)
            else:
                raw = serialize(msg, entry.msgtype, self._store)
            try:
                self._writer.write(entry.connection, stamp_ns, raw)
            except Exception as exc:
                raise _bag_error(self.path, exc, "write") from exc
            entry.count += 1

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self.path} is closed")

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._closed

    def close(self) -> None:
        """Finish the storage file and write ``metadata.yaml``. Idempotent.

        Raises:
            BagError: the files cannot be written.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.close()
            except Exception as exc:
                raise _bag_error(self.path, exc, "finish") from exc

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"BagWriter({str(self.path)!r}, storage={self.storage!r}, "
                f"compression={self.compression!r}, topics={len(self._topics)})")

