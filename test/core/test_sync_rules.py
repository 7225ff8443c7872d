"""Rules promised by the docstring of :class:`ApproximateStereoSync`, one test per rule.

Each test is built so that flipping the rule it names changes the output: the tie rule
(``|b - a| <= |a2 - b|`` keeps the older frame), the drop of a repeated stamp on one side, and
the drop of a stamp older than the side's last one.
"""
from __future__ import annotations

import numpy as np

from eye_in_hand.core.sync import ApproximateStereoSync


def test_tie_between_two_candidates_keeps_the_older_frame():
    # left 0 and left 20 are both 10 ns from right 10: the rule pairs (0, 10) and drops 20 later
    sync: ApproximateStereoSync[str] = ApproximateStereoSync(slop_ns=15)
    assert sync.push_left(0, "L0") == []
    assert sync.push_right(10, "R10") == []  # waits: left's next frame might be nearer
    pairs = sync.push_left(20, "L20")
    assert [(p.left, p.right) for p in pairs] == [("L0", "R10")]
    assert sync.stats.dropped_left == 0
    assert sync.pending == (1, 0)


def test_strictly_nearer_later_frame_wins_over_the_older():
    # the other side of the tie: one ns nearer and the later frame takes the partner
    sync: ApproximateStereoSync[str] = ApproximateStereoSync(slop_ns=15)
    sync.push_left(0, "L0")
    sync.push_right(10, "R10")
    assert sync.push_left(19, "L19") == []  # L0 dropped; R10 now waits for its own next frame
    assert sync.stats.dropped_left == 1 and sync.stats.dropped_unmatched == 1
    pairs = sync.push_right(40, "R40")
    assert [(p.left, p.right) for p in pairs] == [("L19", "R10")]


def test_tie_rule_is_symmetric_between_sides():
    sync: ApproximateStereoSync[str] = ApproximateStereoSync(slop_ns=15)
    sync.push_right(0, "R0")
    sync.push_left(10, "L10")
    pairs = sync.push_right(20, "R20")
    assert [(p.left, p.right) for p in pairs] == [("L10", "R0")]


def test_repeated_stamp_on_one_side_is_dropped_as_stale_and_keeps_the_first():
    sync: ApproximateStereoSync[str] = ApproximateStereoSync(slop_ns=0)
    assert sync.push_left(100, "first") == []
    assert sync.push_left(100, "repeat") == []
    assert sync.stats.dropped_stale == 1 and sync.stats.dropped_left == 1
    assert sync.pending == (1, 0)
    pairs = sync.push_right(100, "R")
    assert [(p.left, p.right) for p in pairs] == [("first", "R")]


def test_older_stamp_on_one_side_is_dropped_as_stale():
    sync: ApproximateStereoSync[str] = ApproximateStereoSync(slop_ns=0)
    sync.push_right(200, "R200")
    assert sync.push_right(150, "R150") == []
    assert sync.stats.dropped_stale == 1 and sync.stats.dropped_right == 1
    assert sync.pending == (0, 1)


def _reference_pairs(left: list[int], right: list[int], slop: int) -> list[tuple[int, int]]:
    """The docstring's rule written out over whole streams (both fully known, unbounded queues)."""
    lq, rq, out = list(left), list(right), []
    while lq and rq:
        if lq[0] == rq[0]:
            out.append((lq.pop(0), rq.pop(0)))
            continue
        a_q, b_q = (lq, rq) if lq[0] < rq[0] else (rq, lq)
        a, b = a_q[0], b_q[0]
        if b - a > slop:
            a_q.pop(0)
            continue
        if len(a_q) < 2:
            break
        if b - a <= abs(a_q[1] - b):
            pair = (a_q.pop(0), b_q.pop(0))
            out.append(pair if a_q is lq else pair[::-1])
        else:
            a_q.pop(0)
    return out


def test_streams_with_many_ties_match_the_written_rule():
    rng = np.random.default_rng(3)
    for _ in range(50):
        # stamps on a coarse grid so that ties and equal stamps are frequent
        left = sorted(set(int(v) for v in rng.integers(0, 40, 15) * 5))
        right = sorted(set(int(v) for v in rng.integers(0, 40, 15) * 5))
        sync: ApproximateStereoSync[int] = ApproximateStereoSync(slop_ns=10, queue_size=100)
        got: list[tuple[int, int]] = []
        events = sorted([(s, 0) for s in left] + [(s, 1) for s in right])
        for stamp, side in events:
            pairs = sync.push_left(stamp, stamp) if side == 0 else sync.push_right(stamp, stamp)
            got += [(p.left, p.right) for p in pairs]
        assert got == _reference_pairs(left, right, 10)[: len(got)]
        assert len(_reference_pairs(left, right, 10)) - len(got) <= 1  # at most the last waits
