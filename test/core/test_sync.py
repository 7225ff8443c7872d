"""Tests of eye_in_hand.core.sync: stereo pairing and the stamped pose buffer."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.sync import ApproximateStereoSync, PoseBuffer
from eye_in_hand.core.transforms import from_rotvec, rotation_angle
from eye_in_hand.errors import InputError, LocalizationError

MS = 1_000_000


def _feed(sync, events):
    """events: list of (side, stamp_ns). Returns the emitted pairs as (l, r) stamp tuples."""
    out = []
    for side, stamp in events:
        push = sync.push_left if side == "L" else sync.push_right
        out += [(p.left_stamp_ns, p.right_stamp_ns) for p in push(stamp, (side, stamp))]
    return out


def test_exact_stamps_pair_immediately_in_either_order():
    sync = ApproximateStereoSync(slop_ns=0, queue_size=3)
    assert sync.push_left(100, "l0") == []
    pairs = sync.push_right(100, "r0")
    assert len(pairs) == 1 and pairs[0].left == "l0" and pairs[0].right == "r0"
    assert pairs[0].skew_ns == 0 and pairs[0].stamp_ns == 100
    pairs = sync.push_right(200, "r1") + sync.push_left(200, "l1")
    assert [(p.left, p.right) for p in pairs] == [("l1", "r1")]
    assert sync.stats.pairs == 2 and sync.stats.exact_pairs == 2 and sync.stats.dropped == 0


def test_exact_only_drops_unmatched_frames_with_counts():
    sync = ApproximateStereoSync(slop_ns=0, queue_size=5)
    got = _feed(sync, [("L", 100), ("R", 101), ("L", 200), ("R", 200)])
    assert got == [(200, 200)]
    assert sync.stats.dropped_left == 1 and sync.stats.dropped_right == 1
    assert sync.stats.dropped_unmatched == 2


def test_approximate_pairs_nearest_partner_and_waits_for_final_decision():
    sync = ApproximateStereoSync(slop_ns=10 * MS, queue_size=5)
    # left at 0, 33, 66 ms; right offset by +8 ms: every left pairs with the right 8 ms later.
    events = []
    for k in range(4):
        events += [("L", k * 33 * MS), ("R", k * 33 * MS + 8 * MS)]
    got = _feed(sync, events)
    assert got == [(k * 33 * MS, k * 33 * MS + 8 * MS) for k in range(3)]
    assert sync.pending == (1, 1)  # the last pair waits for the next left frame
    assert sync.stats.max_abs_skew_ns == 8 * MS and sync.stats.dropped == 0


def test_a_nearer_later_frame_takes_the_partner():
    sync = ApproximateStereoSync(slop_ns=10 * MS, queue_size=5)
    # L0 = 0 ms, R = 8 ms, L1 = 10 ms: R is nearer to L1, L0 must be dropped, not mispaired.
    got = _feed(sync, [("L", 0), ("R", 8 * MS), ("L", 10 * MS), ("L", 40 * MS)])
    assert got == []  # R8 is older than L10: it waits for the next right frame
    got = _feed(sync, [("R", 41 * MS)])
    assert got == [(10 * MS, 8 * MS)]
    assert sync.stats.dropped_left == 1 and sync.stats.dropped_unmatched == 1


def test_frames_outside_slop_never_pair():
    sync = ApproximateStereoSync(slop_ns=5 * MS, queue_size=5)
    got = _feed(sync, [("L", 0), ("R", 20 * MS), ("L", 40 * MS), ("R", 60 * MS)])
    assert got == []
    assert sync.stats.dropped == 3  # L0, R20, L40; R60 still waits
    assert sync.pending == (0, 1)


def test_queue_overflow_and_stale_frames_are_counted():
    sync = ApproximateStereoSync(slop_ns=1 * MS, queue_size=2)
    _feed(sync, [("L", 10), ("L", 20), ("L", 30)])  # right camera silent
    assert sync.pending == (2, 0) and sync.stats.dropped_overflow == 1
    _feed(sync, [("L", 25)])  # out of order on the left
    assert sync.stats.dropped_stale == 1 and sync.stats.dropped_left == 2
    assert _feed(sync, [("R", 30)]) == [(30, 30)]


def test_random_jittered_streams_pair_one_to_one():
    rng = np.random.default_rng(3)
    period = 33 * MS
    stamps = np.arange(200) * period
    jitter = rng.integers(-2 * MS, 2 * MS, size=200)
    events = [("L", int(s)) for s in stamps]
    events += [("R", int(s + j)) for s, j in zip(stamps, jitter, strict=True)]
    # deliver in arrival order (by stamp, right delayed by a random transport latency)
    arrival = [s + (int(rng.integers(0, 5 * MS)) if side == "R" else 0) for side, s in events]
    order = np.argsort(arrival, kind="stable")
    sync = ApproximateStereoSync(slop_ns=5 * MS, queue_size=4)
    got = _feed(sync, [events[i] for i in order])
    assert len(got) >= 199
    for left, right in got:
        assert abs(right - left) <= 2 * MS and left % period == 0
    assert sync.stats.dropped == 0


def test_bad_arguments_raise():
    with pytest.raises(InputError, match="slop_ns"):
        ApproximateStereoSync(slop_ns=-1)
    with pytest.raises(InputError, match="queue_size"):
        ApproximateStereoSync(slop_ns=0, queue_size=0)
    with pytest.raises(InputError, match="stamp_ns"):
        ApproximateStereoSync(slop_ns=0).push_left(1.5, None)


def _pose(rng):
    return from_rotvec(rng.normal(size=3) * 0.5, rng.normal(size=3))


def test_pose_buffer_interpolates_between_brackets():
    rng = np.random.default_rng(7)
    T0, T1 = _pose(rng), _pose(rng)
    buf = PoseBuffer(capacity=10, name="base_T_ee")
    buf.add(1_000, T0)
    buf.add(2_000, T1)
    assert np.allclose(buf.lookup(1_000, 0), T0)
    mid = buf.lookup(1_500, 1_000)
    assert np.allclose(mid[:3, 3], 0.5 * (T0[:3, 3] + T1[:3, 3]))
    half = rotation_angle(T0[:3, :3].T @ T1[:3, :3]) / 2
    assert rotation_angle(T0[:3, :3].T @ mid[:3, :3]) == pytest.approx(half, abs=1e-9)
    # a slerp at 1/4: rotation from T0 by a quarter of the relative rotation
    q = buf.lookup(1_250, 1_000)
    rel = Rotation.from_matrix(T0[:3, :3].T @ T1[:3, :3]).as_rotvec()
    assert np.allclose(T0[:3, :3] @ Rotation.from_rotvec(rel / 4).as_matrix(), q[:3, :3])


def test_the_same_stamp_looked_up_again_is_the_same_pose_until_a_bracket_changes():
    """A stamp looked up again (hand_eye: once per output) gives the same pose, a new array
    each time (changing one changes nothing else); a bracketing pose that arrives again with
    other values, or a new pose between, gives the new interpolation, as on a fresh buffer."""
    from eye_in_hand.core.transforms import interpolate_unchecked

    rng = np.random.default_rng(8)
    T0, T1, T2, T3 = (_pose(rng) for _ in range(4))
    buf = PoseBuffer(capacity=10)
    buf.add(1_000, T0)
    buf.add(2_000, T1)
    first = buf.lookup(1_400, 1_000)
    first[:] = 0.0                                       # the caller's own array
    again = buf.lookup(1_400, 1_000)
    assert again is not first
    assert again.tobytes() == interpolate_unchecked(1_400, 1_000, T0, 2_000, T1).tobytes()
    buf.add(2_000, T2)                                   # the later bracket again, other values
    assert buf.lookup(1_400, 1_000).tobytes() == \
        interpolate_unchecked(1_400, 1_000, T0, 2_000, T2).tobytes()
    buf.add(1_000, T3)                                   # the earlier one again
    assert buf.lookup(1_400, 1_000).tobytes() == \
        interpolate_unchecked(1_400, 1_000, T3, 2_000, T2).tobytes()
    buf.add(1_200, T1)                                   # a pose between: a new bracket
    assert buf.lookup(1_400, 1_000).tobytes() == \
        interpolate_unchecked(1_400, 1_200, T1, 2_000, T2).tobytes()
    buf.clear()
    buf.add(1_000, T0)
    buf.add(2_000, T1)
    assert buf.lookup(1_400, 1_000).tobytes() == again.tobytes()


def test_a_checked_pose_is_kept_as_its_own_copy_and_looks_up_as_a_checked_one():
    """``checked=True`` (a matrix the caller built as a rigid transform) skips the check, not
    the copy: the buffer keeps its own read-only pose, and every lookup is the unchecked
    buffer's to the bit."""
    rng = np.random.default_rng(12)
    poses = [_pose(rng) for _ in range(6)]
    plain, checked = PoseBuffer(capacity=10), PoseBuffer(capacity=10)
    for k, T in enumerate(poses):
        given = T.copy()
        plain.add(1_000 * k, T, received_ns=5 + k)
        checked.add(1_000 * k, given, received_ns=5 + k, checked=True)
        given[:3, 3] += 1.0                     # the caller reuses its array
    for stamp in (0, 400, 1_000, 2_750, 5_000):
        a = plain.lookup(stamp, 1_000, now_ns=10, max_age_ns=100)
        b = checked.lookup(stamp, 1_000, now_ns=10, max_age_ns=100)
        assert a.tobytes() == b.tobytes()
    with pytest.raises(InputError):             # unchecked, a bad pose is refused as before
        checked.add(9_000, np.eye(4) * 2.0)


def test_pose_buffer_out_of_order_insert_replace_and_capacity():
    rng = np.random.default_rng(8)
    poses = [_pose(rng) for _ in range(5)]
    buf = PoseBuffer(capacity=3)
    for stamp, T in zip([30, 10, 20, 40], poses[:4], strict=True):
        buf.add(stamp, T)
    assert len(buf) == 3 and buf.oldest_ns == 20 and buf.newest_ns == 40
    buf.add(30, poses[4])  # replaces
    assert np.allclose(buf.lookup(30, 0), poses[4])
    buf.add(5, poses[1])  # older than a full buffer: ignored
    assert buf.oldest_ns == 20


def test_forget_before_keeps_every_lookup_at_or_after_the_stamp():
    rng = np.random.default_rng(9)
    stamps = list(range(0, 10_000, 100))
    full, pruned = PoseBuffer(capacity=1000), PoseBuffer(capacity=1000)
    for t in stamps:
        T = _pose(rng)
        full.add(t, T, received_ns=t + 7)
        pruned.add(t, T, received_ns=t + 7)
    assert pruned.forget_before(5_050) == 50      # 0 .. 4900 go; 5000 brackets 5050
    assert pruned.oldest_ns == 5_000 and len(pruned) == 50
    assert pruned.forget_before(5_050) == 0 and pruned.forget_before(0) == 0
    for q in (5_000, 5_050, 5_099, 7_333, 9_900):
        np.testing.assert_array_equal(pruned.lookup(q, 100), full.lookup(q, 100))
        pruned.check_age(q, q + 200, 1_000)
    with pytest.raises(LocalizationError, match="older than the buffer"):
        pruned.lookup(4_999, 100)
    pruned.add(4_000, np.eye(4))                  # an older pose is still inserted in order
    assert pruned.oldest_ns == 4_000


def test_pose_buffer_errors_name_the_reason():
    buf = PoseBuffer(capacity=4, name="base_T_ee")
    with pytest.raises(LocalizationError, match="no base_T_ee received"):
        buf.lookup(0, 10)
    buf.add(100, np.eye(4))
    buf.add(300, np.eye(4))
    with pytest.raises(LocalizationError, match="older than the buffer"):
        buf.lookup(50, 1_000)
    with pytest.raises(LocalizationError, match="no extrapolation"):
        buf.lookup(400, 1_000)
    with pytest.raises(LocalizationError, match="over the limit"):
        buf.lookup(200, 199)
    assert np.allclose(buf.lookup(200, 200), np.eye(4))
    with pytest.raises(InputError):
        buf.add(500, np.ones((4, 4)))
    with pytest.raises(InputError, match="capacity"):
        PoseBuffer(capacity=1)


# -- staleness: receive age, time jumps, stopped streams --------------------------------------
S = 1_000_000_000


def _moving(t_ns: int) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = t_ns / S
    return T


def test_pose_buffer_refuses_poses_received_longer_ago_than_the_age_limit():
    buf = PoseBuffer(100, name="base_T_ee", jump_back_ns=S)
    for k in range(10):                           # 100 Hz stream, received as stamped
        buf.add(k * 10 * MS, _moving(k * 10 * MS), received_ns=5 * S + k * 10 * MS)
    now = 5 * S + 95 * MS                         # just after the last pose: accepted
    T = buf.lookup(45 * MS, 20 * MS, now_ns=now, max_age_ns=S)
    assert T[0, 3] == pytest.approx(0.045)
    # the same stamps, looked up seconds later (images of a second replay): refused
    with pytest.raises(LocalizationError, match="received 2.0") as err:
        buf.lookup(45 * MS, 20 * MS, now_ns=7 * S + 40 * MS, max_age_ns=S)
    assert err.value.reason == "stale_pose"
    # an exact stamp match is checked too
    with pytest.raises(LocalizationError) as err:
        buf.lookup(40 * MS, 20 * MS, now_ns=7 * S, max_age_ns=S)
    assert err.value.reason == "stale_pose"
    # a clock that went backwards (simulated time restarted) is refused as stale as well
    with pytest.raises(LocalizationError, match="clock went backwards"):
        buf.lookup(45 * MS, 20 * MS, now_ns=2 * S, max_age_ns=S)
    # without now_ns the age is not checked (old behaviour)
    assert buf.lookup(45 * MS, 20 * MS)[0, 3] == pytest.approx(0.045)


def test_pose_buffer_resets_when_stamps_or_the_receive_clock_jump_back():
    buf = PoseBuffer(100, jump_back_ns=S)
    for k in range(300):
        buf.add(10 * S + k * 10 * MS, _moving(k), received_ns=k * 10 * MS)
    assert len(buf) == 100 and buf.resets["time_jump"] == 0
    # the bag starts again: stamps 3 s back -> everything of the first pass is forgotten
    assert buf.add(10 * S, np.eye(4), received_ns=3 * S + 10 * MS) is True
    assert len(buf) == 1 and buf.resets["time_jump"] == 1
    # a slightly out-of-order pose is not a jump
    buf.add(10 * S + 20 * MS, np.eye(4), received_ns=3 * S + 20 * MS)
    assert buf.add(10 * S + 10 * MS, np.eye(4), received_ns=3 * S + 30 * MS) is False
    assert len(buf) == 3
    # the receive clock going back (sim time reset with the same stamps) is a jump too
    assert buf.add(10 * S + 30 * MS, np.eye(4), received_ns=1 * S) is True
    assert buf.resets["time_jump"] == 2 and len(buf) == 1
    # without jump_back_ns: no reset (the plain buffer of before)
    plain = PoseBuffer(10)
    plain.add(10 * S, np.eye(4))
    assert plain.add(0, np.eye(4)) is False and len(plain) == 2


def test_pose_buffer_expires_a_stopped_stream_and_a_clock_jump():
    buf = PoseBuffer(100, jump_back_ns=S)
    buf.add(0, np.eye(4), received_ns=10 * S)
    buf.add(10 * MS, np.eye(4), received_ns=10 * S + 10 * MS)
    assert buf.expire(10 * S + 500 * MS, S) is None and len(buf) == 2
    assert buf.expire(11 * S + 11 * MS, S) == "stream_stopped" and len(buf) == 0
    assert buf.resets["stream_stopped"] == 1
    assert buf.expire(20 * S, S) is None              # empty: nothing to do
    buf.add(0, np.eye(4), received_ns=10 * S)
    assert buf.expire(5 * S, S) == "clock_jump" and len(buf) == 0
    with pytest.raises(LocalizationError) as err:
        buf.lookup(0, MS)
    assert err.value.reason == "no_pose"
