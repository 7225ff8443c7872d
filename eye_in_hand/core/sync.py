"""Time alignment: approximate-time stereo pairing and a stamped pose buffer.

Two independent tools, both pure Python/numpy (no rclpy), stamps as int nanoseconds:

* :class:`ApproximateStereoSync` pairs left and right frames whose stamps agree within a
  ``slop``. Frames with equal stamps (a hardware-triggered rig, or our own capture node) pair
  at once. Otherwise a pair is emitted only when it is final: each frame is the other's nearest
  neighbour and no later frame can be nearer (the same decision rule as ``message_filters``'
  ApproximateTime policy for two topics). Frames that can no longer be paired are dropped and
  counted per side and per cause.
* :class:`PoseBuffer` keeps a bounded, time-ordered history of stamped poses ``(stamp_ns,
  a_T_b)`` and returns the pose at an image stamp, interpolated with
  :func:`eye_in_hand.core.transforms.interpolate` (slerp + lerp), never extrapolated. Each
  pose may carry the time it was *received* (on the consumer's clock); a lookup can then refuse
  poses older than a receive age (``max_age_ns``), and the buffer clears itself when stamps or
  the receive clock jump backwards (a bag replayed again, simulated time reset) or when the
  stream stops (:meth:`PoseBuffer.expire`): never a pose from a stale stream.
* :class:`InputWaits` decides when a wait for a robot pose (or a target's point) is over on a
  consumer that may fall behind: never while the awaited messages may still sit in its queue.
"""
from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from eye_in_hand.core.transforms import as_transform, interpolate_unchecked
from eye_in_hand.errors import InputError, LocalizationError

__all__ = [
    "StereoPair",
    "SyncStats",
    "ApproximateStereoSync",
    "PoseBuffer",
    "InputWaits",
]

T = TypeVar("T")


def _as_stamp(stamp_ns: Any, name: str = "stamp_ns") -> int:
    """Validate an int nanosecond stamp (Python or numpy integer, not bool, not float)."""
    if isinstance(stamp_ns, (bool, np.bool_)) or not isinstance(stamp_ns, (int, np.integer)):
        raise InputError(f"{name}: expected an int nanosecond stamp, got "
                         f"{type(stamp_ns).__name__}")
    return int(stamp_ns)


@dataclass(frozen=True)
class StereoPair(Generic[T]):
    """A left and a right frame paired by :class:`ApproximateStereoSync`.

    Attributes:
        left_stamp_ns: stamp of the left frame (int ns).
        right_stamp_ns: stamp of the right frame (int ns).
        left: the left payload (whatever was pushed, e.g. an Image message or an array).
        right: the right payload.
    """

    left_stamp_ns: int
    right_stamp_ns: int
    left: T
    right: T

    @property
    def stamp_ns(self) -> int:
        """The pair's stamp: the left frame's stamp (results are in the left optical frame)."""
        return self.left_stamp_ns

    @property
    def skew_ns(self) -> int:
        """``right_stamp_ns - left_stamp_ns`` (0 for an exactly synchronised pair)."""
        return self.right_stamp_ns - self.left_stamp_ns


@dataclass
class SyncStats:
    """Counters of :class:`ApproximateStereoSync` (cumulative since construction or reset).

    Attributes:
        pairs: pairs emitted.
        exact_pairs: pairs whose stamps were equal.
        dropped_left / dropped_right: frames dropped per side, all causes.
        dropped_unmatched: frames dropped because no frame of the other side lies within the slop
            (or a nearer frame took their partner).
        dropped_overflow: frames dropped because their side's queue was full.
        dropped_stale: frames that arrived with a stamp not after the last frame of their side
            (out of order or repeated).
        max_abs_skew_ns: the largest ``|skew|`` of an emitted pair.
    """

    pairs: int = 0
    exact_pairs: int = 0
    dropped_left: int = 0
    dropped_right: int = 0
    dropped_unmatched: int = 0
    dropped_overflow: int = 0
    dropped_stale: int = 0
    max_abs_skew_ns: int = 0

    @property
    def dropped(self) -> int:
        """Total frames dropped on both sides."""
        return self.dropped_left + self.dropped_right


class ApproximateStereoSync(Generic[T]):
    """Pair left and right frames by stamp, within a slop.

    Decision rule, applied whenever a frame arrives (``a`` is the older of the two queue heads,
    ``b`` the head of the other side, stamps increase within a side):

    1. equal stamps: emit the pair at once;
    2. ``b - a > slop``: no frame of the other side can ever come nearer to ``a``: drop ``a``;
    3. else ``b`` is ``a``'s nearest partner for good; if the next frame ``a2`` on ``a``'s side
       is known, emit ``(a, b)`` when ``|b - a| <= |a2 - b|``, else drop ``a`` (``a2`` is the
       better partner); if ``a2`` is not known yet, wait for it (one frame of latency, only for
       unequal stamps).

    Queues are bounded by ``queue_size`` per side (oldest dropped when full), so a dead camera
    cannot grow memory. Stamps that do not increase on their side are dropped as stale.

    Args:
        slop_ns: largest accepted ``|right_stamp - left_stamp|`` in ns (0: exact pairing only).
        queue_size: frames kept per side while waiting for a partner (>= 1).

    Raises:
        InputError: negative slop or queue size below 1.
    """

    def __init__(self, slop_ns: int, queue_size: int = 5) -> None:
        slop = _as_stamp(slop_ns, "slop_ns")
        if slop < 0:
            raise InputError(f"slop_ns: must be >= 0, got {slop}")
        if isinstance(queue_size, bool) or not isinstance(queue_size, (int, np.integer)) \
                or queue_size < 1:
            raise InputError(f"queue_size: must be an int >= 1, got {queue_size!r}")
        self._slop = slop
        self._queue_size = int(queue_size)
        self._queues: tuple[deque[tuple[int, T]], deque[tuple[int, T]]] = (deque(), deque())
        self._last_in: list[int | None] = [None, None]
        self.stats = SyncStats()

    @property
    def slop_ns(self) -> int:
        """The slop in ns."""
        return self._slop

    @property
    def queue_size(self) -> int:
        """Frames kept per side."""
        return self._queue_size

    @property
    def pending(self) -> tuple[int, int]:
        """Frames waiting for a partner: (left, right)."""
        return len(self._queues[0]), len(self._queues[1])

    @property
    def last_stamps(self) -> tuple[int | None, int | None]:
        """The newest stamp pushed on each side: (left, right), None before the first."""
        return self._last_in[0], self._last_in[1]

    def reset(self) -> None:
        """Forget queued frames and the stamp history (e.g. after a clock jump); keep counters."""
        for q in self._queues:
            q.clear()
        self._last_in = [None, None]

    def push_left(self, stamp_ns: int, item: T) -> list[StereoPair[T]]:
        """Add a left frame.

        Args:
            stamp_ns: the frame's stamp (int ns).
            item: the payload, returned unchanged in the pair.

        Returns:
            The pairs that became final, oldest first (usually zero or one).
        """
        return self._push(0, stamp_ns, item)

    def push_right(self, stamp_ns: int, item: T) -> list[StereoPair[T]]:
        """Add a right frame. See :meth:`push_left`."""
        return self._push(1, stamp_ns, item)

    # -- internals -------------------------------------------------------------------------

    def _drop(self, side: int, cause: str) -> None:
        self._queues[side].popleft()
        self._count_drop(side, cause)

    def _count_drop(self, side: int, cause: str) -> None:
        if side == 0:
            self.stats.dropped_left += 1
        else:
            self.stats.dropped_right += 1
        if cause == "unmatched":
            self.stats.dropped_unmatched += 1
        elif cause == "overflow":
            self.stats.dropped_overflow += 1
        else:
            self.stats.dropped_stale += 1

    def _push(self, side: int, stamp_ns: int, item: T) -> list[StereoPair[T]]:
        stamp = _as_stamp(stamp_ns)
        last_side = self._last_in[side]
        if last_side is not None and stamp <= last_side:
            self._count_drop(side, "stale")
            return []
        self._last_in[side] = stamp
        queue = self._queues[side]
        if len(queue) >= self._queue_size:
            self._drop(side, "overflow")
        queue.append((stamp, item))
        return self._match()

    def _emit(self, out: list[StereoPair[T]]) -> None:
        (ls, li), (rs, ri) = self._queues[0].popleft(), self._queues[1].popleft()
        pair = StereoPair(ls, rs, li, ri)
        self.stats.pairs += 1
        if ls == rs:
            self.stats.exact_pairs += 1
        self.stats.max_abs_skew_ns = max(self.stats.max_abs_skew_ns, abs(rs - ls))
        out.append(pair)

    def _match(self) -> list[StereoPair[T]]:
        out: list[StereoPair[T]] = []
        left, right = self._queues
        while left and right:
            ls, rs = left[0][0], right[0][0]
            if ls == rs:
                self._emit(out)
                continue
            a_side = 0 if ls < rs else 1
            a_q = self._queues[a_side]
            a, b = (ls, rs) if a_side == 0 else (rs, ls)
            gap = b - a
            if gap > self._slop:
                self._drop(a_side, "unmatched")
                continue
            if len(a_q) < 2:
                break  # wait for the next frame on a's side: it might be nearer to b
            a2 = a_q[1][0]
            if gap <= abs(a2 - b):
                self._emit(out)
            else:
                self._drop(a_side, "unmatched")
        return out


class PoseBuffer:
    """Bounded, time-ordered buffer of stamped poses with interpolated lookup.

    Poses may arrive slightly out of order (they are inserted in stamp order); a pose with a
    stamp already present replaces the old one. When full, the oldest pose is evicted.

    Staleness (all optional): :meth:`add` may record each pose's receive time (int ns on the
    consumer's clock: wall time, or simulated time under ``use_sim_time``, or a bag's log time
    offline). Then

    * :meth:`lookup` with ``now_ns`` and ``max_age_ns`` refuses (``reason="stale_pose"``) a
      bracket whose older pose was received more than ``max_age_ns`` before ``now_ns``, or
      after ``now_ns`` (the clock went backwards);
    * :meth:`add` clears the buffer first when the new stamp is more than ``jump_back_ns``
      before the newest one, or its receive time more than ``jump_back_ns`` before the newest
      receive time (a bag loop or replay, a simulated-time reset): ``resets["time_jump"]``;
    * :meth:`expire` clears the buffer when the newest pose was received more than
      ``max_age_ns`` ago (the stream stopped: ``resets["stream_stopped"]``) or the clock went
      back more than ``jump_back_ns`` (``resets["clock_jump"]``).

    Args:
        capacity: the most poses kept (>= 2).
        name: what the poses are (e.g. ``"base_T_ee"``), used in error messages.
        jump_back_ns: a stamp (or receive time) this far behind the newest is a time jump that
            clears the buffer; None: never (poses older than the buffer are then simply
            inserted in order).

    Raises:
        InputError: capacity below 2, or a negative ``jump_back_ns``.
    """

    def __init__(self, capacity: int = 1000, *, name: str = "pose",
                 jump_back_ns: int | None = None) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) \
                or capacity < 2:
            raise InputError(f"capacity: must be an int >= 2, got {capacity!r}")
        if jump_back_ns is not None and _as_stamp(jump_back_ns, "jump_back_ns") < 0:
            raise InputError(f"jump_back_ns: must be >= 0, got {jump_back_ns}")
        self._capacity = int(capacity)
        self._name = name
        self._jump_back = None if jump_back_ns is None else int(jump_back_ns)
        self._stamps: list[int] = []
        self._poses: list[np.ndarray] = []
        self._received: list[int | None] = []
        self._newest_received: int | None = None
        #: the last interpolation: (stamp, the two poses it used, the pose at the stamp); a
        #: consumer looks the same image stamp up once per output (hand_eye: its first
        #: target's pose, then the same target in its frame)
        self._interpolated: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
        #: Buffer clears per cause: ``time_jump``, ``stream_stopped``, ``clock_jump``.
        self.resets: dict[str, int] = {"time_jump": 0, "stream_stopped": 0, "clock_jump": 0}

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def capacity(self) -> int:
        """The most poses kept."""
        return self._capacity

    @property
    def oldest_ns(self) -> int | None:
        """Stamp of the oldest pose, or None when empty."""
        return self._stamps[0] if self._stamps else None

    @property
    def newest_ns(self) -> int | None:
        """Stamp of the newest pose, or None when empty."""
        return self._stamps[-1] if self._stamps else None

    @property
    def newest_received_ns(self) -> int | None:
        """Receive time of the most recently received pose, or None (none, or not recorded)."""
        return self._newest_received

    def clear(self) -> None:
        """Remove every pose (e.g. after a clock jump back in simulation time)."""
        self._stamps.clear()
        self._poses.clear()
        self._received.clear()
        self._newest_received = None
        self._interpolated = None

    def _reset(self, cause: str) -> None:
        self.clear()
        self.resets[cause] += 1

    def add(self, stamp_ns: int, pose: ArrayLike, *, received_ns: int | None = None,
            checked: bool = False) -> bool:
        """Insert a stamped pose.

        Args:
            stamp_ns: int ns.
            pose: array-like, shape (4, 4), a rigid transform.
            received_ns: when the pose was received (int ns on the consumer's clock), for the
                receive-age rule of :meth:`lookup`; None: not recorded (no age check).
            checked: ``pose`` is a float64 (4, 4) array that the caller built as a rigid
                transform from checked parts (:func:`eye_in_hand.ros.geometry.pose_to_matrix`
                of a message: a unit quaternion's rotation, a finite translation), which
                :func:`~eye_in_hand.core.transforms.as_transform` could not reject: not
                checked again (on the live node's path for every robot pose).

        Returns:
            True when the buffer was cleared first because time jumped back (see the class).

        Raises:
            InputError: bad stamp or not a rigid transform.
        """
        stamp = _as_stamp(stamp_ns)
        recv = None if received_ns is None else _as_stamp(received_ns, "received_ns")
        if checked:
            T = np.array(pose, dtype=np.float64)
        else:
            T = as_transform(pose, f"{self._name} at {stamp} ns").copy()
        T.setflags(write=False)
        jumped = False
        if self._jump_back is not None and self._stamps and (
                self._stamps[-1] - stamp > self._jump_back
                or (recv is not None and self._newest_received is not None
                    and self._newest_received - recv > self._jump_back)):
            self._reset("time_jump")
            jumped = True
        if recv is not None:
            self._newest_received = recv
        i = bisect.bisect_left(self._stamps, stamp)
        if i < len(self._stamps) and self._stamps[i] == stamp:
            self._poses[i] = T
            self._received[i] = recv
            return jumped
        if len(self._stamps) >= self._capacity:
            if i == 0:
                return jumped  # older than everything in a full buffer: evicted at once
            del self._stamps[0]
            del self._poses[0]
            del self._received[0]
            i -= 1
        self._stamps.insert(i, stamp)
        self._poses.insert(i, T)
        self._received.insert(i, recv)
        return jumped

    def expire(self, now_ns: int, max_age_ns: int) -> str | None:
        """Clear the buffer when its poses can only be stale.

        Args:
            now_ns: the consumer's clock now (int ns, the clock of ``received_ns``).
            max_age_ns: the receive age after which the stream counts as stopped.

        Returns:
            The cause when the buffer was cleared (``"stream_stopped"``: no pose received for
            over ``max_age_ns``; ``"clock_jump"``: ``now_ns`` is over ``jump_back_ns`` before
            the newest receive time), else None. An empty buffer or poses without receive
            times are left alone.
        """
        now = _as_stamp(now_ns, "now_ns")
        newest = self._newest_received
        if newest is None or not self._stamps:
            return None
        if self._jump_back is not None and newest - now > self._jump_back:
            self._reset("clock_jump")
            return "clock_jump"
        if now - newest > max_age_ns:
            self._reset("stream_stopped")
            return "stream_stopped"
        return None

    def _check_age(self, stamp: int, indices: tuple[int, ...], now_ns: int | None,
                   max_age_ns: int | None) -> None:
        if now_ns is None or max_age_ns is None:
            return
        now = _as_stamp(now_ns, "now_ns")
        received = [r for r in (self._received[j] for j in indices) if r is not None]
        if not received:
            return
        oldest = min(received)
        if now - oldest > max_age_ns:
            raise LocalizationError(
                f"{self._name} at {stamp} ns: the robot pose was received "
                f"{(now - oldest) / 1e9:.3f} s ago, over the receive age limit of "
                f"{max_age_ns / 1e9:.3f} s (a stale stream, e.g. poses of an earlier replay)",
                reason="stale_pose")
        if max(received) - now > (self._jump_back or 0):
            raise LocalizationError(
                f"{self._name} at {stamp} ns: the robot pose was received "
                f"{(max(received) - now) / 1e9:.3f} s after now: the clock went backwards",
                reason="stale_pose")

    def check_age(self, stamp_ns: int, now_ns: int | None, max_age_ns: int | None) -> None:
        """The receive-age rule of :meth:`lookup` alone, for the poses that bracket
        ``stamp_ns`` (the nearest one when the stamp is outside the buffer; nothing when it is
        empty). Raises LocalizationError (``stale_pose``) as :meth:`lookup` does."""
        if not self._stamps:
            return
        stamp = _as_stamp(stamp_ns)
        i = bisect.bisect_left(self._stamps, stamp)
        if i < len(self._stamps) and self._stamps[i] == stamp:
            indices: tuple[int, ...] = (i,)
        else:
            indices = tuple(j for j in (i - 1, i) if 0 <= j < len(self._stamps))
        self._check_age(stamp, indices, now_ns, max_age_ns)

    def lookup(self, stamp_ns: int, max_gap_ns: int, *, now_ns: int | None = None,
               max_age_ns: int | None = None) -> np.ndarray:
        """The pose at ``stamp_ns``, interpolated between the two poses that bracket it.

        Args:
            stamp_ns: the query stamp (int ns), typically an image stamp.
            max_gap_ns: the largest accepted time between the two bracketing poses (>= 0). A
                stamp equal to a buffered pose's stamp needs no bracket and is always accepted.
            now_ns: the consumer's clock now (the clock of :meth:`add`'s ``received_ns``).
            max_age_ns: with ``now_ns``: the largest accepted receive age of the poses used.

        Returns:
            A new float64 array, shape (4, 4).

        Raises:
            InputError: bad stamp or negative ``max_gap_ns``.
            LocalizationError: the buffer is empty (``reason`` ``no_pose``), the stamp is before
                the oldest (``before_buffer``) or after the newest pose (``no_newer_pose``: no
                extrapolation), the bracketing gap exceeds ``max_gap_ns`` (``pose_gap``), or a
                pose used was received too long ago or in the clock's future (``stale_pose``).
        """
        stamp = _as_stamp(stamp_ns)
        gap_limit = _as_stamp(max_gap_ns, "max_gap_ns")
        if gap_limit < 0:
            raise InputError(f"max_gap_ns: must be >= 0, got {gap_limit}")
        if not self._stamps:
            raise LocalizationError(f"no {self._name} received yet (lookup at {stamp} ns)",
                                    reason="no_pose")
        i = bisect.bisect_left(self._stamps, stamp)
        if i < len(self._stamps) and self._stamps[i] == stamp:
            self._check_age(stamp, (i,), now_ns, max_age_ns)
            return np.array(self._poses[i])
        if i == 0:
            raise LocalizationError(
                f"{self._name} at {stamp} ns is older than the buffer (oldest "
                f"{self._stamps[0]} ns, {(self._stamps[0] - stamp) / 1e6:.3f} ms later)",
                reason="before_buffer")
        if i == len(self._stamps):
            raise LocalizationError(
                f"{self._name} at {stamp} ns is newer than the newest pose "
                f"({self._stamps[-1]} ns, {(stamp - self._stamps[-1]) / 1e6:.3f} ms earlier): "
                f"no extrapolation", reason="no_newer_pose")
        s0, s1 = self._stamps[i - 1], self._stamps[i]
        if s1 - s0 > gap_limit:
            raise LocalizationError(
                f"{self._name} at {stamp} ns: the bracketing poses are {(s1 - s0) / 1e6:.3f} ms "
                f"apart, over the limit of {gap_limit / 1e6:.3f} ms", reason="pose_gap")
        self._check_age(stamp, (i - 1, i), now_ns, max_age_ns)
        p0, p1 = self._poses[i - 1], self._poses[i]
        last = self._interpolated
        # the same stamp between the same two poses (read-only arrays, replaced, never
        # changed, when a pose arrives again): the same pose, not computed again
        if last is None or last[0] != stamp or last[1] is not p0 or last[2] is not p1:
            last = self._interpolated = (stamp, p0, p1, interpolate_unchecked(stamp, s0, p0,
                                                                               s1, p1))
        out: np.ndarray = last[3].copy()
        return out

    def forget_before(self, stamp_ns: int) -> int:
        """Drop the poses that no lookup at or after ``stamp_ns`` uses: every pose older than
        the newest one at or before it (which brackets it, and stays). A consumer that knows
        it will not look further back bounds the buffer by time this way (``process`` keeps
        a window of bag time). Returns how many poses were dropped."""
        i = bisect.bisect_right(self._stamps, _as_stamp(stamp_ns)) - 1
        if i <= 0:
            return 0
        del self._stamps[:i]
        del self._poses[:i]
        del self._received[:i]
        return i

    def between(self, lo_ns: int, hi_ns: int) -> list[np.ndarray]:
        """The buffered poses stamped in ``[lo_ns, hi_ns]``, oldest first (read-only)."""
        a = bisect.bisect_left(self._stamps, _as_stamp(lo_ns, "lo_ns"))
        b = bisect.bisect_right(self._stamps, _as_stamp(hi_ns, "hi_ns"))
        return self._poses[a:b]


class InputWaits:
    """When a wait for inputs is over, on a consumer that may fall behind its inputs.

    A point waits up to ``pose_wait_s`` for a robot pose newer than its stamp, and a frame of
    targets up to ``point_wait_s`` for its targets' points, measured on a monotonic clock from
    the point's (frame's) arrival. On a busy machine a wait can run out while the very messages
    it waits for sit in the subscription's queue: an executor that fell behind runs the timer
    that checks the waits before the callbacks of what arrived meanwhile, and the point was
    refused with its robot pose already received. So a wait that ran out ends only at a
    :meth:`tick` that follows an earlier tick at which some wait had run out, with no message of
    that kind (a robot pose; a target's point) arriving in between: the executor has then had a
    turn at every message waiting for it. A stream that keeps coming without ever covering the
    stamp holds a wait at most ``cap_s`` (default: twice the wait plus 0.5 s).

    Pure bookkeeping: the consumer calls :meth:`pose_arrived` / :meth:`point_arrived` for each
    message, :meth:`tick` from its periodic check, and asks :meth:`pose_wait_over` /
    :meth:`point_wait_over` with the time an item has waited.
    """

    def __init__(self, pose_wait_s: float, point_wait_s: float) -> None:
        self.pose_wait_s = float(pose_wait_s)
        self.point_wait_s = float(point_wait_s)
        self._seq = {"pose": 0, "point": 0}
        self._mark: dict[str, int | None] = {"pose": None, "point": None}
        self._over = {"pose": False, "point": False}

    def pose_arrived(self) -> None:
        self._arrived("pose")

    def point_arrived(self) -> None:
        self._arrived("point")

    def _arrived(self, kind: str) -> None:
        self._seq[kind] += 1
        self._over[kind] = False

    def tick(self, longest_wait_s: float) -> None:
        """The periodic check; ``longest_wait_s``: how long the oldest waiting item has waited
        (0 when none waits)."""
        for kind, limit in (("pose", self.pose_wait_s), ("point", self.point_wait_s)):
            if longest_wait_s <= limit:
                self._mark[kind], self._over[kind] = None, False
            elif self._mark[kind] == self._seq[kind]:
                self._over[kind] = True     # a whole turn passed with nothing of this kind
            else:
                self._mark[kind], self._over[kind] = self._seq[kind], False

    def _wait_over(self, kind: str, limit: float, waited_s: float) -> bool:
        return waited_s > limit and (self._over[kind] or waited_s > 2.0 * limit + 0.5)

    def pose_wait_over(self, waited_s: float) -> bool:
        """Whether an item that waited ``waited_s`` for a robot pose waits no longer."""
        return self._wait_over("pose", self.pose_wait_s, waited_s)

    def point_wait_over(self, waited_s: float) -> bool:
        """Whether a frame that waited ``waited_s`` for its targets' points waits no longer."""
        return self._wait_over("point", self.point_wait_s, waited_s)
