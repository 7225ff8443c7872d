"""Writing bags: ``BagWriter`` over rosbags, through the storage formats' writers (MCAP with
real CRCs), with ``ros_distro: jazzy``."""
from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.bags.decoding import serialize, types_from_definition
from eye_in_hand.io.bags.formats import FORMATS, STORAGES
from eye_in_hand.io.bags.reading import _bag_error
from eye_in_hand.io.bags.records import COMPRESSIONS, OfferedQos


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


_WRITER_CLASS: Any = None


def _rosbags_writer() -> Any:
    """``rosbags.rosbag2.Writer`` whose storage plugins are those of the writable formats
    (:data:`eye_in_hand.io.bags.formats.FORMATS`: MCAP files with CRCs) and whose metadata
    names the distribution.

    ``rosbags`` writes ``ros_distro: rosbags`` in the metadata; here ``metadata.yaml`` and the
    copy inside the storage file say ``ros_distro: jazzy``.
    """
    global _WRITER_CLASS
    if _WRITER_CLASS is not None:
        return _WRITER_CLASS
    # local: the rosbags writer (rosbag2 + storage_mcap) costs ~55 ms at CLI start-up (every
    # command loads io.bags), and only commands that write bags need it
    from rosbags.rosbag2 import Writer

    def jazzy(metadata: str) -> str:
        return metadata.replace("ros_distro: rosbags", f"ros_distro: {ROS_DISTRO}")

    class FormatsWriter(Writer):
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS,
                           **dict(f.writer_plugin() for f in FORMATS.values() if f.writable)}

        def close(self) -> None:
            storage = self.storage
            if storage is not None:
                close = storage.close
                # the storage's own close, with this package's ros_distro in its metadata
                storage.close = lambda version, metadata: close(  # type: ignore[method-assign]
                    version, jazzy(metadata))
            super().close()
            meta = Path(self.metapath)
            if meta.is_file():
                meta.write_text(jazzy(meta.read_text("utf8")), "utf8")

    _WRITER_CLASS = FormatsWriter
    return FormatsWriter


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
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
        from rosbags.typesys import Stores, get_typestore

        self.storage = storage
        self.compression = compression
        self._store = typestore if typestore is not None else get_typestore(Stores.ROS2_JAZZY)
        self._lock = threading.Lock()
        self._topics: dict[str, _Topic] = {}
        self._closed = False
        fmt = FORMATS[storage]
        try:
            plugin, _writer_class = fmt.writer_plugin()
            self._writer = _rosbags_writer()(self.path, version=9, storage_plugin=plugin)
            if compression == "zstd":
                mode = CompressionMode[fmt.zstd_mode.upper()]
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
