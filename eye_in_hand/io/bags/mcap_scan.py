"""An MCAP file without summary (a recording that was killed), read by scanning it."""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from eye_in_hand.errors import BagError
from eye_in_hand.io.bags import mcap_records as rec
from eye_in_hand.io.bags.records import Damage

__all__ = ["ScannedMcap"]


class ScannedMcap:
    """An MCAP file whose summary/footer is missing (recording killed), read by a linear scan.

    ``rosbags`` needs the footer; ``ros2 bag`` (the mcap library) falls back to scanning. This
    does the same: records are read in file order up to the first incomplete or invalid one
    (the damaged tail); a chunk whose data cannot be read is skipped (its record length says
    where the next record starts); records inside a chunk are read by the same parser as an
    indexed file's (:func:`eye_in_hand.io.bags.mcap_records.chunk_messages`): messages of
    each chunk sorted by log time (rosbag2 writes chunks in time order), those before a record
    that makes no sense kept. It offers the subset of the ``rosbags`` reader interface
    :mod:`eye_in_hand.io.bags.reading` uses; :attr:`damage` lists what the scan skipped.
    """

    compression_format = None
    compression_mode = None
    scanned = True

    def __init__(self, path: Path) -> None:
        # local: rosbags.interfaces and rosbags.rosbag2.storage_mcap cost ~10 and ~40 ms at CLI
        # start-up (every command loads io.bags); only damaged or unindexed MCAP files need them
        from rosbags.interfaces import Connection, ConnectionExtRosbag2
        from rosbags.rosbag2.storage_mcap import Schema, get_msgdef, get_qos

        self.path = path
        self.storage = self
        #: per-topic counts and end time stated by the bag's metadata.yaml (None: not known);
        #: they give the size and the end of a lost tail
        self.expected: dict[str, int] | None = None
        self.expected_end: int | None = None
        self.stopped_at: int | None = None
        self.stop_reason = ""
        self.damage: list[Damage] = []
        schemas: dict[int, Any] = {}
        counts: dict[int, int] = {}
        conns: dict[int, Any] = {}
        start, end, count = 2**63 - 1, 0, 0
        for kind, item in self._records():
            if kind == rec.OP_SCHEMA:
                schemas[item[0]] = Schema(*item)
            elif kind == rec.OP_CHANNEL:
                cid, schema_id, topic, encoding, meta = item
                schema = schemas.get(schema_id)
                conns[cid] = Connection(
                    cid, topic, schema.name if schema else "", get_msgdef(schema), "", 0,
                    ConnectionExtRosbag2(encoding, get_qos(meta)), self)
            elif kind == -1:
                self.damage.append(item)
            elif kind == rec.OP_MESSAGE:
                cid, stamp, _data = item
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

    def note(self, error: BaseException) -> str:
        """What ``bag info`` says about this file (``error``: why ``rosbags`` could not open
        it)."""
        return (f"{self.path.name}: {error} (no MCAP summary: the recording was interrupted "
                f"or the file is truncated); read by scanning the file{self.tail_note}")

    @classmethod
    def try_open(cls, path: Path) -> ScannedMcap | None:
        """A scanned reader when ``path`` starts like a ros2 MCAP file, else None."""
        if path.suffix != ".mcap":
            return None
        with open(path, "rb") as fh:
            head = fh.read(64)
        if not head.startswith(rec.MAGIC) or len(head) < 18 or head[8] != rec.OP_HEADER:
            return None
        scanned = cls(path)
        return scanned if scanned.connections else None

    def close(self) -> None:
        """Nothing to release (each scan opens and closes the file)."""

    def _records(self) -> Iterator[tuple[int, Any]]:
        """(opcode, parsed) for schemas, channels and messages, chunks expanded; ``(-1,
        Damage)`` for a chunk that cannot be read and for a damaged tail."""
        # local: rosbags.rosbag2.storage_mcap (~40 ms at CLI start-up), as in __init__
        from rosbags.rosbag2.storage_mcap import decompress

        parsers: dict[int, Any] = {rec.OP_SCHEMA: rec.schema, rec.OP_CHANNEL: rec.channel}
        found: list[tuple[int, Any]] = []     # schemas and channels of the current chunk

        def keep(iop: int, ibody: Any) -> None:
            found.append((iop, parsers[iop](ibody)))

        with open(self.path, "rb") as fh:
            data = fh.read()
        pos = len(rec.MAGIC)
        last = [0]

        def tail(at: int, reason: str) -> tuple[int, Any]:
            self.stopped_at, self.stop_reason = at, reason
            # the lost range starts at the cut: the first message time of the chunk that was
            # cut (its header survived), else just after the last message read
            # (the file is in write order, not in time order: an early chunk may hold a whole
            # run's small messages, so the newest message read is not the cut)
            cut = last[0] + 1 if last[0] else None
            if data[at] == rec.OP_CHUNK and at + 9 + 16 <= len(data):
                cut = rec.chunk_start(data, at + 9)
            return -1, Damage(self.path.name, f"file tail from byte {at}",
                              f"{reason} (the file ends at byte {len(data)})",
                              start_ns=cut, end_ns=self.expected_end)

        while pos < len(data):
            if pos + 9 > len(data):
                yield tail(pos, "incomplete record header")
                return
            op, length = rec.RECORD.unpack_from(data, pos)
            if op == 0 or op > rec.OP_MAX:
                yield tail(pos, f"invalid record opcode {op}")
                return
            if pos + 9 + length > len(data):
                yield tail(pos, "incomplete record")
                return
            body = data[pos + 9:pos + 9 + length]
            pos += 9 + length
            if op in (rec.OP_FOOTER, rec.OP_DATA_END):  # the data section is complete
                return
            if op == rec.OP_MESSAGE:
                cid, log_time, view = rec.message(body)
                last[0] = log_time
                yield op, (cid, log_time, view)
                continue
            if op != rec.OP_CHUNK:
                if op in parsers:
                    yield op, parsers[op](body)
                continue
            first, msgs = self._expand_chunk(body, pos - 9 - length, decompress, keep, found)
            yield from first
            if msgs:
                last[0] = msgs[-1][0]   # the end of the chunk read last
            for log_time, _offset, _index, cid, view in msgs:
                yield rec.OP_MESSAGE, (cid, log_time, view)

    def _expand_chunk(self, body: Any, chunk_at: int, decompress: Callable[..., Any],
                      keep: Callable[[int, Any], None], found: list[tuple[int, Any]]
                      ) -> tuple[list[tuple[int, Any]], list[rec.Found]]:
        """A chunk's records: what :meth:`_records` yields before its messages (the chunk's
        schemas and channels, then ``(-1, Damage)`` where records stop making sense; only
        that damage when the chunk cannot be read at all) and its messages, sorted by log
        time (``keep`` puts the schemas and channels in ``found``)."""
        t0 = t1 = None
        try:  # chunk: expand its records, messages sorted by log time
            head = rec.chunk_head(body)
            t0, t1 = head.start, head.end
            inner = decompress(body[head.data_at:head.data_at + head.data_size],
                               head.compression, head.size, head.crc)
        except Exception as exc:
            return [(-1, Damage(self.path.name, f"chunk at byte {chunk_at}",
                                f"{str(exc) or type(exc).__name__}", start_ns=t0,
                                end_ns=t1))], []
        found.clear()
        try:
            msgs = rec.chunk_messages(memoryview(inner), chunk_at, head.start, head.end,
                                      None, on_record=keep)
        except rec.DamagedRecords as exc:
            return list(found) + [(-1, Damage(self.path.name, f"chunk at byte {chunk_at}",
                                              f"{exc.detail}; the messages before it are "
                                              "kept", start_ns=t0, end_ns=t1))], exc.kept
        return list(found), msgs

    def messages(self, connections: Sequence[Any], start: int | None = None,
                 stop: int | None = None, on_damage: Any = None,
                 ) -> Iterator[tuple[Any, int, Any]]:
        """Messages of ``connections`` in ``[start, stop)``; damage to ``on_damage``
        (a damaged chunk without it raises :class:`BagError`; the damaged tail never does,
        it is what scanning is for)."""
        by_id = {c.id: c for c in connections}
        lo = start if start is not None else 0
        hi = stop if stop is not None else 2**63
        for kind, item in self._records():
            if kind == rec.OP_MESSAGE and item[0] in by_id and lo <= item[1] < hi:
                yield by_id[item[0]], item[1], item[2]
            elif kind == -1:
                if item.where.startswith("file tail"):
                    item = self._tail_with_counts(item, connections, start, stop)
                if on_damage is not None:
                    on_damage(item)
                elif not item.where.startswith("file tail"):
                    raise BagError(f"{item.where} of {item.file}: {item.reason}")

    def _tail_with_counts(self, item: Damage, connections: Sequence[Any], start: int | None,
                          stop: int | None) -> Damage:
        """The lost tail with its per-topic counts: what metadata.yaml says each topic holds,
        less what the file still has (for the topics read; without a time window, where
        the counts apply)."""
        if self.expected is None or start is not None or stop is not None:
            return item
        seen: dict[str, int] = {}
        for c in self.connections:
            seen[c.topic] = seen.get(c.topic, 0) + int(c.msgcount)
        topics = {}
        for topic in {c.topic for c in connections}:
            if topic in self.expected:
                lost = self.expected[topic] - seen.get(topic, 0)
                if lost > 0:
                    topics[topic] = lost
        end = item.end_ns if item.end_ns is None or item.start_ns is None or \
            item.end_ns >= item.start_ns else None
        return Damage(item.file, item.where, item.reason + "; counts from metadata.yaml",
                      topics, item.start_ns, end, sum(topics.values()))
