"""sqlite3 storage (``ros2 bag record -s sqlite3``, rosbag2's default before Jazzy):
``rosbags``' reader and writer, and reading on past damaged database pages."""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from eye_in_hand.io.bags.records import Damage, DamageLog
from eye_in_hand.io.bags.storage import StorageFormat

__all__ = ["Sqlite3Format"]


class Sqlite3Format(StorageFormat):
    """sqlite3 (a ``.db3`` database per storage file)."""

    name = "sqlite3"
    suffix = ".db3"
    writable = True
    zstd_mode = "message"        # per-message zstd (``--compression-mode message``)

    def reader_class(self) -> Any:
        # local: rosbags.rosbag2.storage_sqlite3 is loaded with rosbags.rosbag2.Reader (the
        # caller's), which costs ~40 ms at CLI start-up (every command loads io.bags)
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

        return Sqlite3Reader

    def read_on(self, storage: Any, connections: Sequence[Any], start: int | None,
                stop: int | None, *, last: int | None, at_last: int, read: dict[int, int],
                damage: Any, name: str, error: BaseException,
                ) -> Iterator[tuple[Any, int, bytes]] | None:
        if getattr(storage, "dbconn", None) is None:
            return None
        return _read_on(storage, list(connections), start, stop, last, at_last, read, damage,
                        name, error)

    def writer_plugin(self) -> tuple[Any, Any]:
        # local: the rosbags writer costs ~55 ms at CLI start-up (see storage_mcap)
        from rosbags.rosbag2.enums import StoragePlugin
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer

        return StoragePlugin.SQLITE3, Sqlite3Writer


def _read_on(storage: Any, conns: list[Any], start: int | None, stop: int | None,
                    last: int | None, at_last: int, read: dict[int, int],
                    damage: DamageLog, name: str, first_error: BaseException,
                    ) -> Iterator[tuple[Any, int, bytes]]:
    """The rest of a sqlite3 storage file whose time-ordered read failed on a damaged page.

    Rows are looked up by their id (the table's B-tree key), in blocks, and one by one in a
    block that fails: a damaged page then costs only the rows stored on it. The rows still
    to come (log time after ``last``; at ``last``, after the ``at_last`` already read) are
    read in log-time order. What could not be read becomes one :class:`Damage` record with
    its per-topic count: the topic's count in the file's topic table less the messages read.
    """
    db = storage.dbconn
    by_id = {c.id: c for c in conns}

    def rows(sql: str, args: tuple[Any, ...]) -> list[tuple[Any, ...]] | None:
        try:
            return list(db.execute(sql, args))
        except Exception:  # noqa: BLE001 - a damaged page: the caller narrows it down
            return None

    top = rows("SELECT max(id) FROM messages", ())
    expected = sum(int(c.msgcount) for c in getattr(storage, "connections", conns))
    hi_id = max(int(top[0][0]) if top and top[0][0] is not None else 0, expected)
    found: list[tuple[int, int, int]] = []    # (log time, row id, topic id)
    unreadable = 0
    block = 256
    for lo_id in range(1, hi_id + 1, block):
        span = (lo_id, min(hi_id, lo_id + block - 1))
        got = rows("SELECT id, topic_id, timestamp FROM messages WHERE id BETWEEN ? AND ?",
                   span)
        if got is None:
            got = []
            for rid in range(span[0], span[1] + 1):
                one = rows("SELECT id, topic_id, timestamp FROM messages WHERE id = ?",
                           (rid,))
                if one is None:
                    unreadable += 1
                else:
                    got.extend(one)
        for rid, tid, stamp in got:
            if tid in by_id and (start is None or stamp >= start) and \
                    (stop is None or stamp < stop):
                found.append((int(stamp), int(rid), int(tid)))
    found.sort()
    skip = at_last
    damaged_stamps: list[int] = []
    for stamp, rid, tid in found:
        if last is not None and stamp < last:
            continue
        if last is not None and stamp == last and skip > 0:
            skip -= 1
            continue
        data = rows("SELECT data FROM messages WHERE id = ?", (rid,))
        if not data:
            damaged_stamps.append(stamp)
            continue
        yield by_id[tid], stamp, bytes(data[0][0])    # the caller counts it in ``read``
    windowed = start is not None or stop is not None
    lost = {c.topic: int(c.msgcount) - read.get(c.id, 0) for c in conns
            if not windowed and int(c.msgcount) > read.get(c.id, 0)}
    if lost or damaged_stamps or unreadable:
        known = not windowed
        damage.add(Damage(
            name, "damaged pages",
            f"{str(first_error) or type(first_error).__name__}; read on past them row by row "
            f"({unreadable} row(s) unreadable, {len(damaged_stamps)} with unreadable data)",
            lost, min(damaged_stamps) if damaged_stamps else last,
            max(damaged_stamps) if damaged_stamps else None,
            sum(lost.values()) if known else None))
