"""The storage interface: what the bag layer asks of a storage format (MCAP, sqlite3).

A bag is a directory of storage files (or one file) in one format. :mod:`eye_in_hand.io.bags`
opens, reads, recovers and writes them through one :class:`StorageFormat` per format,
registered in :data:`eye_in_hand.io.bags.formats.FORMATS`, like ``rosbags``'
``Reader.STORAGE_PLUGINS``. The base class is the format ``rosbags`` reads and writes with
nothing added; a format overrides what it does better:

* opening: :meth:`~StorageFormat.reader_class` (the ``rosbags`` reader plugin of its files)
  and :meth:`~StorageFormat.scan` (a reader for a file ``rosbags`` cannot open: an
  interrupted recording);
* reading: :meth:`~StorageFormat.reads_directly` / :meth:`~StorageFormat.direct_messages`
  (its own reader, e.g. memory-mapped and zero-copy), :meth:`~StorageFormat.mappable`,
  :meth:`~StorageFormat.read_on` (the rest of a file whose reading failed part-way);
* worker processes: :meth:`~StorageFormat.worker_readable` /
  :meth:`~StorageFormat.worker_messages` (parts of the file opened by ``process``'s workers);
* writing: :attr:`~StorageFormat.writable`, :meth:`~StorageFormat.writer_plugin` (the
  ``rosbags`` writer plugin) and :attr:`~StorageFormat.zstd_mode` (what ``BagWriter``'s
  ``compression="zstd"`` means for it).

Connections, messages and damage are the ``rosbags`` reader's and this package's
(:class:`eye_in_hand.io.bags.records.Damage`): ``(connection, log_time_ns, data)`` in log-time
order.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from eye_in_hand.io.bags.records import Damage

__all__ = ["StorageFormat", "OnDamage"]

#: where a reader reports a damaged part it skips (None: it raises instead)
OnDamage = Callable[[Damage], None] | None


class StorageFormat:
    """A rosbag2 storage format. Subclass it per format (``storage_<name>.py``) and register
    an instance in :data:`eye_in_hand.io.bags.formats.FORMATS`.

    Attributes:
        name: the rosbag2 storage identifier (``metadata.yaml``'s ``storage_identifier``,
            ``BagInfo.storage``, the ``--storage`` choice).
        suffix: the storage files' suffix (``.mcap``).
        writable: whether :class:`eye_in_hand.io.bags.BagWriter` writes it (then it is in
            :data:`eye_in_hand.io.bags.STORAGES`).
        zstd_mode: the rosbag2 compression mode of ``compression="zstd"`` (``"storage"``:
            inside the storage file, ``"message"``: per message).
    """

    name: str = ""
    suffix: str = ""
    writable: bool = False
    zstd_mode: str = "message"

    # -- opening
    def reader_class(self) -> Any:
        """The ``rosbags`` reader plugin class of this format's storage files (what
        ``rosbags.rosbag2.Reader`` and ``DirectoryReader`` open them with)."""
        raise NotImplementedError(f"{self.name}: no reader")

    def scan(self, path: Path) -> Any | None:
        """A reader for a storage file that the ``rosbags`` reader cannot open (no summary:
        an interrupted recording), or None (the error stands).

        It offers the ``rosbags`` reader attributes :mod:`eye_in_hand.io.bags.reading` uses
        (``path``, ``connections``, ``message_count``, ``start_time``, ``end_time``,
        ``compression_format``, ``compression_mode``, ``storage``, ``close()``) and
        ``scanned = True``, ``expected`` / ``expected_end`` (the counts and end time that
        ``metadata.yaml`` states, set by the caller), ``note(error)`` (what ``bag info``
        says about the file) and ``messages(connections, start, stop, on_damage)``.
        """
        return None

    # -- reading
    def reads_directly(self, storage: Any) -> bool:
        """Whether :meth:`direct_messages` reads this opened storage file (else the
        ``rosbags`` reader's ``messages`` does)."""
        return False

    def direct_messages(self, storage: Any, connections: Sequence[Any], start: int | None,
                        stop: int | None, *, verify_crc: bool, on_damage: OnDamage,
                        ) -> Iterator[tuple[Any, int, Any]]:
        """``(connection, log_time_ns, data)`` in ``[start, stop)``, log-time order (ties in
        storage order); data as read-only buffers (``bytes`` or ``memoryview``) that stay
        valid after the iteration. A damaged part goes to ``on_damage`` (None: raise)."""
        raise NotImplementedError(f"{self.name}: no direct reader")

    def mappable(self, storage: Any) -> bool:
        """Whether :meth:`direct_messages` yields views of the file itself (no copy, no
        decompression)."""
        return False

    def read_on(self, storage: Any, connections: Sequence[Any], start: int | None,
                stop: int | None, *, last: int | None, at_last: int, read: dict[int, int],
                damage: Any, name: str, error: BaseException,
                ) -> Iterator[tuple[Any, int, bytes]] | None:
        """The rest of a file whose ``rosbags`` reading failed with ``error`` after the
        messages counted in ``read`` (channel id -> count; the last at log time ``last``,
        ``at_last`` of them at that time), in log-time order, what cannot be read recorded
        in ``damage`` (a :class:`~eye_in_hand.io.bags.records.DamageLog`); None: the rest of
        the file is lost."""
        return None

    # -- worker processes (offline processing)
    def worker_readable(self, storage: Any) -> bool:
        """Whether :meth:`worker_messages` reads this opened storage file (worth it: parts
        that cost CPU to open, e.g. compressed chunks)."""
        return False

    def worker_messages(self, storage: Any, connections: Sequence[Any], submit: Any, *,
                        image_channels: set[int], pair_channels: tuple[int, int] | None,
                        verify_crc: bool, on_damage: OnDamage,
                        ) -> Iterator[tuple[Any, int, Any]]:
        """``(connection, log_time_ns, payload)`` as :meth:`direct_messages` gives them, the
        file's parts opened by ``submit``'s worker processes
        (``submit(group, "module:function", args) -> (future, worker) | None``); images of
        ``image_channels`` as references decoded where they are used."""
        raise NotImplementedError(f"{self.name}: no worker reader")

    # -- writing
    def writer_plugin(self) -> tuple[Any, Any]:
        """``(rosbags StoragePlugin, writer class)``: what ``rosbags.rosbag2.Writer`` writes
        this format with (a format it cannot write is not :attr:`writable`)."""
        raise NotImplementedError(f"{self.name}: not writable")
