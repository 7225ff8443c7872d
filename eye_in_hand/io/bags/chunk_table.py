"""The chunk index of an MCAP file, held compactly.

``rosbags``' MCAP reader parses a file's chunk index into one ``ChunkInfo`` named tuple per
chunk, with two dicts each: about 1.4 kB a chunk, 25 MB for a 10-minute bag recorded with a
chunk per stereo pair, held by every reader of the file and by the index cache of
:mod:`eye_in_hand.io.bags.storage_mcap` for the whole of ``process``. :class:`ChunkTable`
keeps the same values in flat arrays (about 125 bytes a chunk) and makes each ``ChunkInfo``
when it is asked for: equal to the parsed one, field for field and in the order of its dicts'
keys, so that everything reading ``storage.chunks`` (``rosbags`` itself included) reads the
same index. A table can also be filled while ``rosbags`` parses (:meth:`ChunkTable.building`:
each ``ChunkInfo`` it appends goes into the columns and is dropped), so that the parsed list
(25 MB on that bag, a peak that the process's heap then kept) never exists.
"""
from __future__ import annotations

from array import array
from collections.abc import Iterator, Sequence
from typing import Any, overload

__all__ = ["ChunkTable"]

#: the integer fields of a ChunkInfo, in the table's columns
_INTS = ("message_start_time", "message_end_time", "chunk_start_offset", "chunk_length",
         "message_index_length", "compressed_size", "uncompressed_size")


class _Columns:
    """The values of every chunk (shared by the tables made from one parse)."""

    __slots__ = ("make", "ints", "compression", "names", "layout", "layouts", "offsets",
                 "starts", "_name_ids", "_layout_ids")

    def __init__(self, infos: Sequence[Any] = ()) -> None:
        self.make: Any = None
        self.ints = [array("q") for _ in _INTS]
        self.compression = array("H")
        self.names: list[str] = []
        self.layout = array("L")
        # (message index channel ids, in order; channel counts, in order)
        self.layouts: list[tuple[tuple[int, ...], tuple[tuple[int, int], ...]]] = []
        self.offsets = array("q")              # message index offsets, chunk after chunk
        self.starts = array("q", [0])
        self._name_ids: dict[str, int] = {}
        self._layout_ids: dict[Any, int] = {}
        for info in infos:
            self.add(info)

    def __len__(self) -> int:
        return len(self.starts) - 1

    def add(self, info: Any) -> None:
        """One more chunk, after the others."""
        if self.make is None:
            self.make = type(info)
        for col, name in zip(self.ints, _INTS, strict=True):
            col.append(getattr(info, name))
        comp = info.compression
        names = self._name_ids
        if comp not in names:
            names[comp] = len(self.names)
            self.names.append(comp)
        self.compression.append(names[comp])
        mio = info.message_index_offsets
        key = (tuple(mio), tuple(info.channel_count.items()))
        layouts = self._layout_ids
        if key not in layouts:
            layouts[key] = len(self.layouts)
            self.layouts.append(key)
        self.layout.append(layouts[key])
        self.offsets.extend(mio.values())
        self.starts.append(len(self.offsets))

    def info(self, i: int) -> Any:
        start, end, offset, length, mil, csize, usize = (c[i] for c in self.ints)
        keys, counts = self.layouts[self.layout[i]]
        s = self.starts[i]
        assert self.make is not None
        return self.make(start, end, offset, length,
                         dict(zip(keys, self.offsets[s:s + len(keys)], strict=True)), mil,
                         self.names[self.compression[i]], csize, usize, dict(counts))


class ChunkTable(Sequence[Any]):
    """``storage.chunks`` of an indexed MCAP reader: a sequence of ``rosbags``' ``ChunkInfo``,
    each made when it is read (:func:`of` a parsed list). ``clear`` empties this table only
    (``rosbags`` clears its reader's at ``close``); :meth:`copy` is another table of the same
    chunks, sharing their values."""

    __slots__ = ("_cols", "_n")

    def __init__(self, cols: _Columns, n: int) -> None:
        self._cols = cols
        self._n = n

    @classmethod
    def of(cls, infos: Sequence[Any]) -> ChunkTable:
        """The table of ``rosbags``' parsed ``ChunkInfo`` list."""
        return cls(_Columns(infos), len(infos))

    @classmethod
    def building(cls) -> ChunkTable:
        """An empty table to :meth:`append` parsed chunks to."""
        return cls(_Columns(), 0)

    def append(self, info: Any) -> None:
        """One more parsed ``ChunkInfo``, after the others: only on a table that holds every
        chunk of its columns (one being built; not after :meth:`clear`, nor on a
        :meth:`copy` once the table it was copied from has grown)."""
        if self._n != len(self._cols):
            raise ValueError("ChunkTable.append: only a table being built takes chunks")
        self._cols.add(info)
        self._n += 1

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, i: int) -> Any: ...

    @overload
    def __getitem__(self, i: slice) -> list[Any]: ...

    def __getitem__(self, i: int | slice) -> Any:
        if isinstance(i, slice):
            return [self._cols.info(k) for k in range(*i.indices(self._n))]
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError("chunk index out of range")
        return self._cols.info(i)

    def __iter__(self) -> Iterator[Any]:
        info = self._cols.info
        for i in range(self._n):
            yield info(i)

    def clear(self) -> None:
        self._n = 0

    def copy(self) -> ChunkTable:
        return ChunkTable(self._cols, self._n)

    def compressions(self) -> set[str]:
        """The compressions of the chunks ("" for none), without making their infos."""
        cols = self._cols
        return {cols.names[k] for k in set(cols.compression[:self._n])}
