"""InputWaits: a wait that ran out ends only after the consumer had a turn at its queue."""
from __future__ import annotations

from eye_in_hand.core.sync import InputWaits


def test_a_run_out_wait_ends_at_the_second_tick_without_poses():
    w = InputWaits(0.2, 0.2)
    w.tick(0.1)
    assert not w.pose_wait_over(0.1)
    # the executor fell behind: the first check after 0.5 s finds the wait run out, but the
    # robot poses received meanwhile still sit in the queue: the wait is not over yet
    w.tick(0.5)
    assert not w.pose_wait_over(0.5)
    w.pose_arrived()                      # ... they are delivered after the timer
    w.tick(0.52)
    assert not w.pose_wait_over(0.52)     # a pose came since the last tick: still waiting
    w.tick(0.54)                          # a whole turn with no pose: the stream is quiet
    assert w.pose_wait_over(0.54)
    assert not w.pose_wait_over(0.1)      # an item that has not waited its time yet


def test_a_pose_stream_that_never_covers_the_stamp_holds_a_wait_at_most_the_cap():
    w = InputWaits(0.2, 0.2)
    for k in range(100):
        w.pose_arrived()
        w.tick(0.3 + 0.01 * k)
        assert w.pose_wait_over(0.3 + 0.01 * k) == (0.3 + 0.01 * k > 0.9)


def test_point_and_pose_waits_are_separate():
    w = InputWaits(0.2, 0.1)
    w.tick(0.15)
    w.tick(0.16)
    assert w.point_wait_over(0.16) and not w.pose_wait_over(0.16)
    w.point_arrived()
    assert not w.point_wait_over(0.16)
