"""Writing bags: ``BagWriter`` over rosbags, with real MCAP CRCs and ``ros_distro: jazzy``."""
from __future__ import annotations

import threading
import zlib
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import Any

from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.bags.decoding import serialize, types_from_definition
from eye_in_hand.io.bags.reading import _bag_error
from eye_in_hand.io.bags.records import COMPRESSIONS, STORAGES, OfferedQos


def _to_rosbags_qos(qos: OfferedQos) -> Any:
    # local: rosbags costs ~25 ms at CLI start-up (every command loads io.bags)
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

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
        written: int = self._fh.write(data)
        return written

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
    # local: the rosbags writer (rosbag2 + storage_mcap) costs ~55 ms at CLI start-up (every
    # command loads io.bags), and only commands that write bags need it
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.rosbag2.storage_mcap import (
        McapWriter,
        PendingChunk,
        write_record,
        write_string,
        write_uint16,
        write_uint32,
        write_uint64,
    )

    def jazzy(metadata: str) -> str:
        return metadata.replace("ros_distro: rosbags", f"ros_distro: {ROS_DISTRO}")

    class CrcMcapWriter(McapWriter):
        def __init__(self, path: Path, compression: Any) -> None:
            super().__init__(path, compression)
            self.bio.flush()
            head = self.path.read_bytes()[:self.bio.tell()]     # magic and header record
            self.crc_file = _CrcFile(self.bio, zlib.crc32(head))
            # the writer's file, wrapped: every byte written goes through the CRC
            self.bio = self.crc_file  # type: ignore[assignment]

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
            pos, crc = self.bio.tell(), self.crc_file.crc
            super().close(version, jazzy(metadata))
            _patch_mcap_crcs(self.path, pos, crc)

    class CrcWriter(Writer):
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: CrcMcapWriter}

        def close(self) -> None:
            storage = self.storage
            if storage is not None and not isinstance(storage, CrcMcapWriter):
                close = storage.close
                # the storage's own close, with this package's ros_distro in its metadata
                storage.close = lambda version, metadata: close(  # type: ignore[method-assign]
                    version, jazzy(metadata))
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

    def __init__(self, path: str | Path, storage: str = "mcap",
                 compression: str | None = None, *, typestore: Any = None) -> None:
        if storage not in STORAGES:
            raise InputError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
        if compression not in COMPRESSIONS:
            raise InputError(f"compression must be None or 'zstd', got {compression!r}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"cannot write bag {self.path}: it exists already")
        # local: rosbags.rosbag2 and rosbags.typesys cost ~50 ms at CLI start-up (see above)
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
                    # local: see _to_rosbags_qos
                    from rosbags.interfaces import MessageDefinitionFormat

                    self._store.register(types_from_definition(
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
