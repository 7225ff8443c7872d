"""Reading bags in log-time order: opening (indexed, scanned or damaged files), ``bag_info``,
``iter_messages``, ``check_bag``."""
from __future__ import annotations

import copy
import functools
import heapq
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, cast

import yaml

from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.bags.formats import FORMATS, SUFFIXES, format_of
from eye_in_hand.io.bags.records import (
    BagInfo,
    BagMessage,
    Damage,
    DamageLog,
    OfferedQos,
    TopicInfo,
)


def _bag_error(path: Path, exc: BaseException, doing: str = "read") -> BagError:
    text = str(exc).strip() or type(exc).__name__
    return BagError(f"cannot {doing} bag {path}: {text}")


def metadata_problem(bag_dir: Path) -> str | None:
    """Why ``bag_dir/metadata.yaml`` cannot be used (empty, not UTF-8, not YAML, not a
    rosbag2 metadata mapping), or None when it can."""
    try:
        raw = (bag_dir / "metadata.yaml").read_bytes()
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if not raw.strip():
        return "is empty"
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        return f"is not UTF-8 text (byte {raw[exc.start]:#04x} at offset {exc.start})"
    return _parsed_metadata(text)[0]


@functools.lru_cache(maxsize=16)
def _parsed_metadata(text: str) -> tuple[str | None, dict[str, Any] | None]:
    """A metadata.yaml's text: :func:`metadata_problem`'s answer, and its
    ``rosbag2_bagfile_information`` when usable (shared: callers copy before changing it).
    Kept per text: a command opens one bag several times (its summary, its storage checks,
    its type store, its camera_info, the pass), and parsing the YAML costs 2-10 ms a time."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        return (f"is not valid YAML{where} "
                f"({getattr(exc, 'problem', None) or 'parse error'})"), None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        return "has no 'rosbag2_bagfile_information' mapping", None
    files = info.get("relative_file_paths")
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        return "has no list of storage files ('relative_file_paths')", None
    if not isinstance(info.get("storage_identifier"), str) or \
            not isinstance(info.get("topics_with_message_count", []), list):
        return "has no storage identifier or topic list", None
    return None, info


def _storage_paths(path: Path, notes: list[str] | None = None) -> list[Path]:
    """What to hand to ``rosbags.rosbag2.Reader`` for ``path`` (one entry per reader).

    A bag directory whose ``metadata.yaml`` is damaged is read by its storage files, as one
    without it, with a note (in ``notes``) that says what was wrong."""
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    if path.is_dir():
        meta = path / "metadata.yaml"
        problem = metadata_problem(path) if meta.is_file() else None
        if meta.is_file() and problem is None:
            return [path]
        files = sorted(p for p in path.iterdir() if p.suffix in SUFFIXES and p.is_file())
        if not files:
            kinds = " or ".join(SUFFIXES)
            raise BagError(
                f"bag {path} has no metadata.yaml and no {kinds} storage file"
                if problem is None else
                f"bag {path}: metadata.yaml {problem}, and there is no {kinds} storage "
                "file to read instead")
        if problem is not None and notes is not None:
            notes.append(f"{meta}: damaged: {problem}; ignored, the bag is read from its "
                         f"storage file(s) ({', '.join(f.name for f in files)})")
        return files
    if path.suffix not in SUFFIXES:
        raise BagError(
            f"bag {path} is neither a bag directory nor a {' / '.join(SUFFIXES)} storage file")
    return [path]


_READER_CLASS: Any = None


class _RepeatedSafeYAML:
    """Marks the class :func:`_repeated_safe_yaml` makes."""


@functools.lru_cache(maxsize=32)
def _safe_yaml_of(yaml_class: Any, text: str) -> Any:
    """``yaml_class(typ="safe").load(text)``, kept per text (exceptions are not kept)."""
    return yaml_class(typ="safe").load(text)


def _repeated_safe_yaml(yaml_class: Any) -> Any:
    """``ruamel.yaml``'s ``YAML`` class as ``rosbags`` uses it to read a bag directory's
    ``metadata.yaml`` (and the QoS strings in it), whose safe ``load`` of a text parsed
    before returns a copy of the first parse instead of parsing it again: a command opens
    one bag several times (its summary, its storage checks, its type store, its camera_info,
    the pass; six times for ``process``), and the pure-Python parser takes 3-5 ms a time,
    on the start-up path. The same text gives the same objects (a deep copy each time: the
    reader owns what it gets); any other use (a dump, another ``typ``, a stream) is
    ``yaml_class``'s own."""

    class RepeatedSafeYAML(yaml_class, _RepeatedSafeYAML):  # type: ignore[misc]
        def load(self, stream: Any) -> Any:
            if self.typ == ["safe"] and not self.pure and isinstance(stream, str):
                return copy.deepcopy(_safe_yaml_of(yaml_class, stream))
            return super().load(stream)

    RepeatedSafeYAML.__name__ = RepeatedSafeYAML.__qualname__ = yaml_class.__name__
    return RepeatedSafeYAML


def _reader_class() -> Any:
    """``rosbags.rosbag2.Reader`` whose storage plugins (of files and of bag directories)
    are those of :data:`eye_in_hand.io.bags.formats.FORMATS`."""
    global _READER_CLASS
    if _READER_CLASS is not None:
        return _READER_CLASS
    # local: rosbags.rosbag2 costs ~40 ms at CLI start-up (every command loads io.bags)
    import rosbags.rosbag2.metadata as rosbags_metadata
    import rosbags.rosbag2.reader as rosbags_reader
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.reader import DirectoryReader

    # the YAML of metadata.yaml (and its QoS strings), parsed once per text
    for module in (rosbags_reader, rosbags_metadata):
        yaml_class: Any = module.__dict__["YAML"]
        if not issubclass(yaml_class, _RepeatedSafeYAML):
            module.__dict__["YAML"] = _repeated_safe_yaml(yaml_class)

    class FormatsDirectoryReader(DirectoryReader):
        STORAGE_PLUGINS = {name: f.reader_class() for name, f in FORMATS.items()}

    class FormatsReader(Reader):
        STORAGE_PLUGINS = {"dir": FormatsDirectoryReader,
                           **{f.suffix: f.reader_class() for f in FORMATS.values()}}

    _READER_CLASS = FormatsReader
    return FormatsReader


def _scan(path: Path) -> Any | None:
    """A scanning reader of a storage file (see ``StorageFormat.scan``), or None."""
    fmt = format_of(path)
    return None if fmt is None else fmt.scan(path)


class _OpenBag:
    """The rosbags readers of one bag, opened; a context manager."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.readers: list[Any] = []
        self.notes: list[str] = []
        targets = _storage_paths(self.path, self.notes)
        reader_class = _reader_class()

        try:
            for target in targets:
                try:
                    reader: Any = reader_class(target)
                    reader.open()
                except Exception as exc:
                    # a storage file without summary (recording interrupted, file truncated):
                    # scan it, also when it belongs to a bag directory with metadata.yaml
                    files = [target] if target.is_file() else sorted(
                        f for suffix in SUFFIXES for f in target.glob(f"*{suffix}")
                        if f.is_file())
                    scanned_all = [_scan(f) for f in files]
                    if not scanned_all or any(x is None for x in scanned_all):
                        raise
                    expected = _expected_counts(target) if len(files) == 1 else None
                    for scanned in scanned_all:
                        assert scanned is not None
                        if expected is not None:
                            scanned.expected, scanned.expected_end = expected
                        self.readers.append(scanned)
                        self.notes.append(scanned.note(exc))
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
    # local: rosbags.interfaces costs ~10 ms at CLI start-up and at each `process` worker's
    # start-up (every command loads io.bags)
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
                    storages.add(SUFFIXES[Path(reader.path).suffix].name)
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


def _expected_counts(target: Path) -> tuple[dict[str, int], int | None] | None:
    """Per-topic message counts and the end time (ns) that ``metadata.yaml`` of the bag
    directory ``target`` states, when it is usable and describes one storage file; else
    None."""
    if not target.is_dir() or metadata_problem(target) is not None:
        return None
    try:
        meta = _read_metadata(target)
        if len(meta.get("relative_file_paths") or []) != 1:
            return None
        counts = {str(t["topic_metadata"]["name"]): int(t["message_count"])
                  for t in meta.get("topics_with_message_count") or []}
        start = meta.get("starting_time", {}).get("nanoseconds_since_epoch")
        duration = meta.get("duration", {}).get("nanoseconds")
        end = int(start) + int(duration) if start is not None and duration is not None \
            else None
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    return counts, end


def _read_metadata(bag_dir: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a usable metadata.yaml (a copy)."""
    problem, info = _parsed_metadata((bag_dir / "metadata.yaml").read_text(encoding="utf-8"))
    if info is None:
        raise KeyError(f"metadata.yaml {problem}")
    return copy.deepcopy(info)


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
    are merged by log time; ties keep storage order. A storage format with its own reader
    (``StorageFormat.direct_messages``: indexed MCAP files, memory-mapped and read without
    copies by :mod:`eye_in_hand.io.bags.mcap_chunks`) is read by it; other storage goes through
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




def memory_mappable(path: str | Path) -> bool:
    """Whether every storage file of a bag is read as views of the file itself (indexed MCAP
    files with uncompressed chunks: ``StorageFormat.mappable``), i.e. whether
    ``iter_messages(..., views=True)`` yields views of the files themselves."""
    with _OpenBag(path) as bag:
        for reader in bag.readers:
            inner = reader.storage
            if getattr(inner, "metadata", None) is not None and \
                    getattr(inner.metadata, "compression_mode", "") == "message":
                return False
            for part in (list(inner.storages) if hasattr(inner, "storages") else [inner]):
                fmt = format_of(part)
                if fmt is None or not fmt.mappable(part):
                    return False
    return True


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
    name = Path(getattr(storage, "path", "")).name
    fmt = format_of(storage)

    if not per_message_zstd and fmt is not None and fmt.reads_directly(storage):
        chunks = fmt.direct_messages(storage, conns, start, stop, verify_crc=verify_crc,
                                     on_damage=None if damage is None else damage.add)
        for order, (conn, stamp, view) in enumerate(chunks):
            # views: the memoryview itself, read as bytes by the callers that ask for it
            raw = cast(bytes, view) if views else bytes(view)
            yield stamp, stream, order, conn.topic, conn.msgtype, raw
        return
    zstd = _zstd_module() if per_message_zstd else None
    source = _messages(storage, conns, start, stop, damage)
    read: dict[int, int] = {}
    last = start
    at_last = 0          # messages read so far with log time ``last``
    reading_on = False   # past a failure (StorageFormat.read_on: a damaged sqlite3 page)
    order = 0
    while True:
        try:
            item = next(source, None)
        except Exception as exc:
            if damage is None:
                raise
            rest = None if reading_on or fmt is None else fmt.read_on(
                storage, conns, start, stop, last=last, at_last=at_last, read=read,
                damage=damage, name=name, error=exc)
            if rest is not None:
                # e.g. a damaged sqlite3 page: read on past it, row by row; it costs only its
                # rows
                reading_on = True
                source = rest
                continue
            # the storage fails part-way: the rest of the file is lost
            damage.add(_rest_lost(name, conns, start, stop, read, order, last, exc))
            return
        if item is None:
            return
        conn, stamp, raw = item
        stamp = int(stamp)
        at_last = at_last + 1 if stamp == last else 1
        last = stamp
        read[conn.id] = read.get(conn.id, 0) + 1
        if zstd is not None:
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


def _zstd_module() -> Any:
    """The zstd module of the standard library (Python >= 3.14) or of its backport."""
    try:  # local: an optional module, needed only for per-message zstd bags
        from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
    except ImportError:
        from backports import zstd
    return zstd


def _messages(storage: Any, conns: list[Any], start: int | None, stop: int | None,
              damage: DamageLog | None) -> Iterator[tuple[Any, int, Any]]:
    """``(connection, log time, data)`` of a storage file through its ``rosbags`` reader (or
    the reader :meth:`StorageFormat.scan` made, which reports damage as it goes)."""
    if getattr(storage, "scanned", False):     # a reader from StorageFormat.scan
        return cast(Iterator[tuple[Any, int, Any]], storage.messages(
            conns, start, stop, on_damage=damage.add if damage is not None else None))
    return cast(Iterator[tuple[Any, int, Any]], storage.messages(conns, start, stop))


def _rest_lost(name: str, conns: list[Any], start: int | None, stop: int | None,
               read: dict[int, int], order: int, last: int | None,
               exc: BaseException) -> Damage:
    """The damage of a storage file that fails part-way: the rest of it, after ``order``
    messages (``read`` by channel id, the last at log time ``last``); the messages lost by
    topic when the whole file was asked for."""
    lost = {c.topic: int(c.msgcount) - read.get(c.id, 0) for c in conns
            if start is None and stop is None and int(c.msgcount) > read.get(c.id, 0)}
    return Damage(name, "the rest of the file",
                  f"reading stopped after {order} message(s): "
                  f"{str(exc) or type(exc).__name__}", lost, last, None,
                  sum(lost.values()) if lost else None)
