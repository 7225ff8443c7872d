"""The bag nodes' hand-overs: bounded in bytes, one message always fits, closing releases."""
from __future__ import annotations

import threading

from eye_in_hand.ros.bag_queues import NOTHING, PrefetchQueue, WriteQueue


def test_prefetch_is_bounded_in_bytes_and_releases_on_close() -> None:
    buf = PrefetchQueue(max_items=10, max_bytes=100)
    assert buf.put("a", 60) and buf.put("b", 30)  # 90 bytes queued
    results: list[bool] = []
    t = threading.Thread(target=lambda: results.append(buf.put("c", 50)))
    t.start()
    t.join(0.2)
    assert t.is_alive()  # 140 bytes would exceed the budget: put waits
    assert buf.get(0.1) == "a"  # room again: the waiting put goes through
    t.join(5.0)
    assert results == [True]
    assert buf.get(0.1) == "b" and buf.get(0.1) == "c" and buf.get(0.01) is NOTHING
    assert buf.put("big", 1000)  # one message always fits, however large
    t = threading.Thread(target=lambda: results.append(buf.put("d", 1)))
    t.start()
    t.join(0.2)
    assert t.is_alive()
    buf.close()  # releases the blocked put with False
    t.join(5.0)
    assert results == [True, False] and buf.get(0.01) is NOTHING


def test_write_queue_drops_over_budget_and_drains_after_close() -> None:
    q = WriteQueue(max_bytes=100)
    assert q.put(("msg", "/a", 1, b"x" * 80), 80)
    assert not q.put(("msg", "/a", 2, b"x" * 30), 30)  # over budget: dropped, never blocks
    assert q.put(("call", None), 0, force=True)  # calls are never dropped
    assert [i[:3] for i in q.get_batch(0.01)] == [("msg", "/a", 1), ("call", None)]
    assert q.get_batch(0.01) == []  # nothing within the timeout
    big = b"x" * 500
    assert q.put(("msg", "/b", 3, big), len(big))  # one message always fits
    q.close()
    assert not q.put(("msg", "/b", 4, b""), 0) and q.closed
    assert [i[2] for i in q.get_batch(0.01)] == [3]  # queued messages are still written
    assert q.get_batch(0.01) is None  # closed and empty: the writer thread ends
