"""Bag records: compression choices, topic and bag information, damage records."""
from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

COMPRESSIONS: tuple[str | None, ...] = (None, "zstd")
"""Compression choices of :class:`BagWriter`."""

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
