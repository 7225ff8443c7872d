"""Keeping a long bag read through a file mapping out of the resident set.

A bag is read once, front to back, through ``mmap``: every page read stays mapped into the
process (its resident set, ``RssFile``) until the mapping goes, so a 10-minute bag would count
its whole size against the process. :func:`drop_pages` releases a range once it is read.

:func:`keep_freed_heap` keeps a worker that decompresses chunk after chunk from giving each
one's memory back to the kernel and faulting it in again for the next.

This module imports nothing but ``mmap``: worker processes use it without loading the rest of
``eye_in_hand.io``.
"""
from __future__ import annotations

import mmap
from typing import Any

__all__ = ["DROP_BLOCK_BYTES", "drop_pages", "keep_freed_heap"]

#: A read page fault maps more than the page read: Linux maps the cached pages around it
#: ("fault-around"), and on current kernels the page cache holds files in large folios (up to
#: the 2 MiB of a page-table leaf), mapped whole. Reading ``[start, end)`` can so map pages
#: outside the range, up to the 2 MiB-aligned blocks that hold it: those are released too.
#: Measured on Linux 6.18, ext4, a 12 MB file read in 100 KiB records, each released after it
#: is read: 1.6 MB stayed resident releasing whole pages, 1.5 MB with 64 KiB blocks (the
#: classic ``fault_around_bytes``), nothing with 1 MiB or 2 MiB blocks.
DROP_BLOCK_BYTES = max(mmap.PAGESIZE, 2 * 1024 * 1024)


def drop_pages(mapped: Any, start: int, length: int) -> None:
    """Release this process's resident pages of a read-only file mapping around ``[start,
    start + length)`` (``madvise(MADV_DONTNEED)`` over the :data:`DROP_BLOCK_BYTES` blocks
    that hold it), so that a long bag read once does not stay in the resident set.

    The data are not affected: a page read again (by a view still in use, or a neighbouring
    record in the same block) is mapped again from the page cache or the file. Widening the
    range to the blocks matters: releasing only the range's own pages left what the kernel had
    mapped around them resident, about 200 MB per worker process after two thirds of a
    10-minute 640x480 bag of 168 KB zstd chunks. Does nothing where ``madvise`` is not
    available.
    """
    if length <= 0:
        return
    lo = start - start % DROP_BLOCK_BYTES
    hi = min(len(mapped), -(-(start + length) // DROP_BLOCK_BYTES) * DROP_BLOCK_BYTES)
    try:
        mapped.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
    except (AttributeError, OSError, ValueError):
        pass


#: glibc ``mallopt`` parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_heap(nbytes: int = 64 << 20) -> bool:
    """Let this process's C heap keep up to ``nbytes`` of freed memory instead of giving it
    back to the kernel at once (glibc ``mallopt``: allocations below 32 MiB from the heap,
    trimmed beyond ``nbytes`` free), for a process that frees and allocates blocks of
    megabytes in turn: a chunk decompression worker, whose chunks leave its cache as soon as
    their images are read. Without it every decompressed chunk faulted its pages in anew
    (about 100 000 more page faults, 0.1-0.16 s of system time, on 1203 chunks of 2.8 MB).
    The heap then stays at the most the process held at once, not at ``nbytes`` more.
    Returns whether the allocator took the settings (False off glibc)."""
    try:
        import ctypes  # local: only the worker processes that decompress chunks call this

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, 32 << 20)) and bool(mallopt(_M_TRIM_THRESHOLD,
                                                                      int(nbytes)))
