"""drop_pages: a file read once through a mapping leaves the resident set, data unchanged."""
from __future__ import annotations

import mmap
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.io.pages import drop_pages

ROOT = Path(__file__).resolve().parents[2]


def test_dropped_pages_read_back_the_same_bytes(tmp_path):
    """madvise DONTNEED on a read-only mapping never changes what a view reads, with ranges
    that are not page-aligned."""
    data = np.random.default_rng(3).integers(0, 256, 5 * mmap.PAGESIZE + 123,
                                             dtype=np.uint8).tobytes()
    path = tmp_path / "f.bin"
    path.write_bytes(data)
    with open(path, "rb") as fh:
        mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    view = memoryview(mapped)[mmap.PAGESIZE + 7:4 * mmap.PAGESIZE + 11]
    before = bytes(view)
    for start, length in ((mmap.PAGESIZE + 7, 3 * mmap.PAGESIZE), (0, len(data)),
                          (len(data) - 5, 100), (10, 0)):
        drop_pages(mapped, start, length)
        assert bytes(view) == before
        assert bytes(mapped[:]) == data
    view.release()
    mapped.close()


def _resident_kib(path: str) -> int:
    """Rss (KiB) of this process's mappings of ``path`` (/proc/self/smaps)."""
    total, inside = 0, False
    with open("/proc/self/smaps") as fh:
        for line in fh:
            head = line.split()
            if "-" in head[0] and len(head) >= 5 and head[0][0] in "0123456789abcdef" \
                    and ":" in head[3]:
                inside = len(head) >= 6 and head[5] == path
            elif inside and head[0] == "Rss:":
                total += int(head[1])
    return total


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps")
def test_a_file_read_once_in_records_leaves_the_resident_set(tmp_path):
    """Records read one after another, each dropped once read (as a worker reads a bag's
    chunks): the mapping's resident pages stay within a few blocks, not the file's size.
    Records of 100 KiB + 333 bytes, so that their ends fall inside the pages and folios the
    kernel maps around a read one, past the record."""
    record = 100 * 1024 + 333
    n = 120
    path = tmp_path / "bag.bin"
    path.write_bytes(np.random.default_rng(4).integers(0, 256, record * n, dtype=np.uint8)
                     .tobytes())                  # written now: in the page cache
    with open(path, "rb") as fh:
        mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        view = np.frombuffer(mapped, dtype=np.uint8)
        checksum = 0
        for k in range(n):
            checksum += int(view[k * record:(k + 1) * record:512].sum())   # touch every page
            drop_pages(mapped, k * record, record)
        resident = _resident_kib(str(path))
        assert checksum > 0
        # releasing each record's own pages only left about 1.6 MB here (Linux 6.18, ext4)
        assert resident <= 512, \
            f"{resident} KiB of a {record * n // 1024} KiB file still resident"
        del view
    finally:
        mapped.close()


_CHURN = """
import resource, sys
from eye_in_hand.io.pages import keep_freed_heap
if sys.argv[1] == "keep":
    assert keep_freed_heap()
def churn():
    for _ in range(20):      # four chunks of 3 MiB decompressed and freed, again and again
        blocks = [bytearray(3 << 20) for _ in range(4)]
        del blocks
churn()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
churn()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_heap_that_keeps_freed_memory_faults_no_page_in_again():
    """keep_freed_heap: blocks of megabytes freed and allocated in turn (a worker's
    decompressed chunks) reuse the heap's pages instead of faulting new ones in each time."""
    def faults(mode: str) -> int:
        run = subprocess.run([sys.executable, "-c", _CHURN, mode], capture_output=True,
                             text=True, timeout=60, cwd=ROOT)
        assert run.returncode == 0, run.stderr
        return int(run.stdout.split()[-1])

    plain, kept = faults("plain"), faults("keep")
    assert plain > 20 * 4 * 500 and kept < plain / 20, (plain, kept)
