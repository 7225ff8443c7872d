"""The drop-oldest hand-over between a node's executor thread and its worker."""
from __future__ import annotations

import pytest

from eye_in_hand.errors import InputError
from eye_in_hand.ros.queues import DropOldestQueue


def test_queue_of_one_keeps_only_the_newest():
    slot = DropOldestQueue(1)
    assert slot.put("a") is False and slot.put("b") is True
    assert slot.take(0.0) == "b" and slot.dropped == 1 and slot.take(0.0) is None


def test_queue_rides_out_a_stall_then_drops_the_oldest():
    q = DropOldestQueue(3)
    assert [q.put(x) for x in "abc"] == [False, False, False] and len(q) == 3
    assert q.put("d") is True and q.dropped == 1          # full: "a" goes
    assert [q.take(0.0) for _ in range(4)] == ["b", "c", "d", None]
    with pytest.raises(InputError, match="depth"):
        DropOldestQueue(0)


def test_stop_wakes_a_waiting_take():
    import threading

    q: DropOldestQueue[str] = DropOldestQueue(1)
    got: list[str | None] = []
    t = threading.Thread(target=lambda: got.append(q.take(30.0)))
    t.start()
    q.stop()
    t.join(5.0)
    assert not t.is_alive() and got == [None] and q.stopped
