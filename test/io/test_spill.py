"""eye_in_hand.io.spill: a list whose settled items beyond a number go to a temporary file."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.io import spill
from eye_in_hand.io.spill import SpillList, apply_to


class Item:
    def __init__(self, n: int) -> None:
        self.n = n
        self.a = np.full(3, float(n))
        self.b = self.a                    # shared with a, as a frame shares its first target's
        self.note = ""


def test_items_come_back_in_order_from_the_file_and_from_memory():
    items = [Item(i) for i in range(10)]
    s = SpillList(keep=3, batch=2)
    for it in items:
        s.append(it)
    s.settle()
    assert s.spilled == 6 and len(s) == 10             # whole batches, 3 or 4 left in memory
    back = list(s)
    assert [x.n for x in back] == list(range(10))
    assert all(x is it for x, it in zip(back[6:], items[6:], strict=True))   # not copied
    np.testing.assert_array_equal(back[2].a, [2.0, 2.0, 2.0])
    assert back[2].b is back[2].a                    # one pickle per batch: sharing kept
    assert s[0].n == 0 and s[-1].n == 9 and [x.n for x in s[4:7]] == [4, 5, 6]
    assert [x.n for x in s] == list(range(10))       # a second pass reads the file again
    assert bool(s) and not SpillList()


def test_only_items_before_the_given_one_are_settled():
    items = [Item(i) for i in range(10)]
    s = SpillList(items, keep=0, batch=1)
    s.settle(items[4])
    assert s.spilled == 4
    items[4].note = "changed after"               # still in memory: the change is kept
    assert s[4].note == "changed after"
    items[0].note = "lost"                       # in the file: the object is no longer its item
    assert s[0].note == ""
    s.settle(items[4])                          # nothing before it is left in memory
    assert s.spilled == 4
    with pytest.raises(ValueError, match="not in memory"):
        s.settle(items[0])


def test_nothing_goes_to_the_file_up_to_keep_items(monkeypatch):
    monkeypatch.setattr(spill, "KEEP", 5)
    s = SpillList(Item(i) for i in range(5))
    s.settle()
    assert s.spilled == 0 and s._file is None
    s.append(Item(5))
    s.settle()
    assert s.spilled == 0        # 6 in memory, but not a whole batch (BATCH) beyond keep
    monkeypatch.setattr(spill, "BATCH", 1)
    t = SpillList(Item(i) for i in range(6))
    t.settle()
    assert t.spilled == 1 and len(t) == 6


def test_a_fix_reaches_items_in_memory_now_and_in_the_file_when_read():
    s = SpillList((Item(i) for i in range(6)), keep=2, batch=2)
    s.settle()
    assert s.spilled == 4

    def mark(x):
        x.note = f"fixed {x.n}"

    apply_to(s, mark)
    assert [x.note for x in s] == [f"fixed {i}" for i in range(6)]
    apply_to(s, lambda x: setattr(x, "note", x.note + "!"))   # in the order given
    assert [x.note for x in s] == [f"fixed {i}!" for i in range(6)]
    plain = [Item(0)]
    apply_to(plain, mark)
    assert plain[0].note == "fixed 0"


def test_close_gives_the_file_back_and_keeps_the_items_in_memory():
    s = SpillList((Item(i) for i in range(4)), keep=1, batch=3)
    s.settle()
    f = s._file
    assert s.spilled == 3 and f is not None
    s.close()
    assert f.closed and len(s) == 1 and [x.n for x in s] == [3]


def test_bad_sizes_are_refused():
    with pytest.raises(ValueError, match="batch must be >= 1"):
        SpillList(batch=0)
    with pytest.raises(ValueError, match="keep >= 0"):
        SpillList(keep=-1)


def test_a_file_that_cannot_be_written_keeps_the_items_in_memory(monkeypatch):
    """No space (or no writable folder): the items stay in memory from then on, the reason
    is given, and nothing is lost, also when the file failed after some batches."""
    items = [Item(i) for i in range(10)]
    s = SpillList(items[:6], keep=2, batch=2)
    s.settle()
    assert s.spilled == 4 and s.problem is None
    real = spill.os.pwrite

    def full(fd, data, offset):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(spill.os, "pwrite", full)
    for it in items[6:]:
        s.append(it)
    s.settle()
    assert s.problem is not None and "No space left on device" in s.problem
    assert s.spilled == 4 and [x.n for x in s] == list(range(10))
    monkeypatch.setattr(spill.os, "pwrite", real)
    s.settle()                                  # no more tries: memory from now on
    assert s.spilled == 4

    def no_file(*_a, **_k):
        raise OSError(13, "Permission denied")

    monkeypatch.setattr(spill.tempfile, "TemporaryFile", no_file)
    t = SpillList((Item(i) for i in range(5)), keep=1, batch=1)
    t.settle()
    assert t.spilled == 0 and "Permission denied" in (t.problem or "")
    assert [x.n for x in t] == list(range(5))
