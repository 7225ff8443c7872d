"""The bag recorder's hand-over: bounded in bytes, one message always fits, closing drains."""
from __future__ import annotations

from eye_in_hand.ros.bag_queues import WriteQueue


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
