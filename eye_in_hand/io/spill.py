"""A list that keeps its newest items in memory and the older ones in a temporary file.

``process`` keeps the outcome of every stereo pair until the whole bag has been read: the
ground truth is matched to the target ids over the run (medians of each id's positions),
then the output bag, ``results.csv`` and ``summary.json`` are written. In memory, a pair's
outcome costs about 2 kB (its arrays, the result objects): 36 MB for a 10-minute bag at
30 Hz, 220 MB for an hour. :class:`SpillList` keeps at most ``keep`` items in memory; the
settled ones beyond that (:meth:`SpillList.settle`: items that will not change any more) go
to an anonymous temporary file in pickled batches, and every pass over the list reads them
back in order. A bag of up to ``keep`` pairs never touches the file.

The file is made by :func:`tempfile.TemporaryFile` (in ``TMPDIR``, else ``/tmp``): it has no
name, so nothing is left behind when the process ends, however it ends. It takes about
0.55 kB a pair. When it cannot be made or written (no space, no writable folder), the items
stay in memory from then on and :attr:`SpillList.problem` says why; nothing is lost.
"""
from __future__ import annotations

import os
import pickle
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import IO, TypeVar, overload

__all__ = ["SpillList", "apply_to"]

T = TypeVar("T")

#: items kept in memory (2 min 16 s of stereo pairs at 30 Hz, about 5 MB of frames): shorter
#: runs pay nothing for the file; beyond, each item costs about 70 us of CPU (pickled once,
#: read back by the two passes of ``process``'s outputs)
KEEP = 4096
#: items written to the file together (one pickle: arrays shared between them stay shared)
BATCH = 512


class SpillList(Sequence[T]):
    """A list of items in order: the newest in memory, settled ones beyond ``keep`` (default
    :data:`KEEP`) in a temporary file, ``batch`` (:data:`BATCH`) to a pickle (module
    docstring). Items must pickle.

    Reading gives the items back in order (iteration, ``len``, indexing); an item read back
    from the file is a new object each time, so a change to it is lost: change items with
    :meth:`apply`. Items are only appended.
    """

    def __init__(self, items: Iterable[T] = (), *, keep: int | None = None,
                 batch: int | None = None) -> None:
        keep = KEEP if keep is None else keep      # the module's, read now
        batch = BATCH if batch is None else batch
        if batch < 1 or keep < 0:
            raise ValueError(f"SpillList: batch must be >= 1 and keep >= 0 (got batch={batch}, "
                             f"keep={keep})")
        self._keep, self._batch = keep, batch
        self._items: list[T] = list(items)
        self._file: IO[bytes] | None = None
        self._spans: list[tuple[int, int]] = []   # (offset, size) of each batch in the file
        self._end = 0                              # the file's size
        self._spilled = 0                          # items in the file
        self._fixes: list[Callable[[T], object]] = []
        #: why items stay in memory beyond ``keep`` (the file could not be made or written)
        self.problem: str | None = None

    def append(self, item: T) -> None:
        self._items.append(item)

    def __len__(self) -> int:
        return self._spilled + len(self._items)

    @property
    def spilled(self) -> int:
        """Items in the file."""
        return self._spilled

    def settle(self, before: T | None = None) -> None:
        """The items before ``before`` (an item in memory, compared by identity), or every
        item when None, will not change any more: while more than ``keep`` items are in
        memory, whole batches of settled ones are written to the file.

        Raises:
            ValueError: ``before`` is not among the items in memory.
        """
        items = self._items
        if len(items) <= self._keep or self.problem is not None:
            return
        if before is None:
            settled = len(items)
        else:
            settled = next((i for i, x in enumerate(items) if x is before), -1)
            if settled < 0:
                raise ValueError("SpillList.settle: the given item is not in memory")
        spill = min(settled, len(items) - self._keep) // self._batch * self._batch
        if spill <= 0:
            return
        written = 0
        try:
            if self._file is None:
                self._file = tempfile.TemporaryFile(prefix="eye_in_hand-spill-")
            for start in range(0, spill, self._batch):
                data = pickle.dumps(items[start:start + self._batch],
                                    protocol=pickle.HIGHEST_PROTOCOL)
                if os.pwrite(self._file.fileno(), data, self._end) != len(data):
                    raise OSError(f"short write at byte {self._end}")
                self._spans.append((self._end, len(data)))
                self._end += len(data)
                written = start + self._batch
        except OSError as exc:
            self.problem = (f"a temporary file in {tempfile.gettempdir()} could not be "
                            f"written ({exc})")
        del items[:written]
        self._spilled += written

    def apply(self, fix: Callable[[T], object]) -> None:
        """``fix(item)`` changes an item in place: now for the items in memory, and for each
        item read back from the file from now on (in the order the fixes were given)."""
        for item in self._items:
            fix(item)
        if self._spans:
            self._fixes.append(fix)

    def _read(self, span: tuple[int, int]) -> list[T]:
        assert self._file is not None
        offset, size = span
        data = os.pread(self._file.fileno(), size, offset)
        if len(data) != size:
            raise OSError(f"SpillList: the temporary file ended at {offset + len(data)} bytes, "
                          f"before the batch at {offset} ({size} bytes)")
        batch: list[T] = pickle.loads(data)
        for fix in self._fixes:
            for item in batch:
                fix(item)
        return batch

    def __iter__(self) -> Iterator[T]:
        for span in list(self._spans):
            yield from self._read(span)
        yield from list(self._items)

    @overload
    def __getitem__(self, index: int) -> T: ...

    @overload
    def __getitem__(self, index: slice) -> list[T]: ...

    def __getitem__(self, index: int | slice) -> T | list[T]:
        """An item or a list of items (from the file: every item is read, in order)."""
        if not self._spans:
            return self._items[index]
        return list(self)[index]

    def close(self) -> None:
        """Give the file back (the items in it are gone; the ones in memory stay)."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self._spans.clear()
        self._spilled = 0


def apply_to(items: Iterable[T], fix: Callable[[T], object]) -> None:
    """``fix(item)`` on every item in place: a :class:`SpillList`'s :meth:`~SpillList.apply`,
    else each item of ``items`` (a list) in turn."""
    if isinstance(items, SpillList):
        items.apply(fix)
        return
    for item in items:
        fix(item)
