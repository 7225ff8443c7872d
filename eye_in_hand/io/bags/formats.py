"""The storage formats the bag layer reads and writes: the registry of
:class:`~eye_in_hand.io.bags.storage.StorageFormat` implementations, and what derives from it.

A new format is a ``storage_<name>.py`` module with a ``StorageFormat`` subclass and one entry
in :data:`FORMATS` (docs/architecture.md, "Where to add a storage format").
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from eye_in_hand.io.bags.storage import StorageFormat
from eye_in_hand.io.bags.storage_mcap import McapFormat
from eye_in_hand.io.bags.storage_sqlite3 import Sqlite3Format

__all__ = ["FORMATS", "STORAGES", "SUFFIXES", "format_of"]

FORMATS: dict[str, StorageFormat] = {f.name: f for f in (McapFormat(), Sqlite3Format())}
"""Storage identifier -> format, the default (what ``ros2 bag record`` writes on Jazzy) first."""

STORAGES: tuple[str, ...] = tuple(name for name, f in FORMATS.items() if f.writable)
"""Storage plugins :class:`~eye_in_hand.io.bags.BagWriter` can write (every format is
readable)."""

SUFFIXES: dict[str, StorageFormat] = {f.suffix: f for f in FORMATS.values()}
"""Storage file suffix (``.mcap``) -> format."""


def format_of(path: Any) -> StorageFormat | None:
    """The format of a storage file (a path, or an opened reader with a ``path``), by its
    suffix; None for anything else (a bag directory)."""
    return SUFFIXES.get(Path(getattr(path, "path", path) or "").suffix)
