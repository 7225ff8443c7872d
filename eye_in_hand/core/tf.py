"""A transform tree over time (our tf2 buffer): chained, interpolated lookups at a stamp.

What ``/tf`` and ``/tf_static`` carry: each transform is an edge ``parent -> child`` (a
``parent_T_child``, stamped), every frame has at most one parent, and the frames form a forest.
:class:`TfBuffer` keeps, per child frame, either one static transform (``/tf_static``: valid at
every time) or a bounded, time-ordered history (``/tf``, a
:class:`~eye_in_hand.core.sync.PoseBuffer`). :meth:`TfBuffer.lookup` returns ``a_T_b`` at a
stamp for any two connected frames: it walks both frames up to their common ancestor and
composes the edges on the way, each dynamic edge interpolated at the stamp (slerp + lerp)
between the two samples that bracket it. It never extrapolates and refuses a bracket wider than
``max_gap_ns``, exactly as :class:`PoseBuffer` does for a single pose stream, so the ``tf``
robot-pose source follows the same rules as ``ee_pose`` and ``joint_states``.

:class:`TfPoseView` presents one chain (``base_frame -> ee_frame``) of a buffer with the
:class:`PoseBuffer` interface (``lookup``, ``newest_ns``, ...), so a
:class:`~eye_in_hand.core.localization.Localizer` can take its robot poses from TF.

Pure numpy: no rclpy, no messages (conversion from TFMessage is in ``eye_in_hand.ros.tf``).
Frame ids are compared without a leading ``/`` (tf2 does the same).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.transforms import as_transform, invert
from eye_in_hand.errors import InputError, LocalizationError

__all__ = ["TfBuffer", "TfPoseView", "TfStats", "STATIC_NEWEST_NS", "normalize_frame"]

#: ``newest_ns`` of a chain made only of static transforms: valid at every stamp.
STATIC_NEWEST_NS = 2 ** 63 - 1

#: Longest chain followed before the tree is declared to have a loop.
_MAX_DEPTH = 256


def normalize_frame(frame_id: str, what: str = "frame_id") -> str:
    """A frame id without its leading '/' (tf2's convention); InputError when empty."""
    if not isinstance(frame_id, str):
        raise InputError(f"{what}: expected a string, got {type(frame_id).__name__}")
    name = frame_id.lstrip("/")
    if not name:
        raise InputError(f"{what}: empty frame id")
    return name


@dataclass
class TfStats:
    """Counters of a :class:`TfBuffer`.

    Attributes:
        transforms: transforms accepted (dynamic and static).
        static: of which static.
        rejected: transforms refused (bad matrix, self-parent, would close a loop).
        reparented: transforms that moved a child frame to a new parent (the old edge is
            forgotten, as tf2 does).
    """

    transforms: int = 0
    static: int = 0
    rejected: int = 0
    reparented: int = 0


class _Edge:
    """The transform from a child frame's parent: static, or a stamped history."""

    __slots__ = ("parent", "static", "history")

    def __init__(self, parent: str, static: np.ndarray | None, history: PoseBuffer | None):
        self.parent = parent
        self.static = static
        self.history = history

    def at(self, stamp_ns: int, max_gap_ns: int) -> np.ndarray:
        if self.static is not None:
            return self.static
        assert self.history is not None
        return self.history.lookup(stamp_ns, max_gap_ns)

    def newest_ns(self) -> int | None:
        if self.static is not None:
            return STATIC_NEWEST_NS
        assert self.history is not None
        return self.history.newest_ns


class TfBuffer:
    """A forest of frames with static and time-stamped edges (see the module docstring).

    Args:
        capacity: samples kept per dynamic edge (>= 2); the oldest are evicted first.

    Raises:
        InputError: capacity below 2.
    """

    def __init__(self, capacity: int = 1000) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) \
                or capacity < 2:
            raise InputError(f"capacity: must be an int >= 2, got {capacity!r}")
        self._capacity = int(capacity)
        self._edges: dict[str, _Edge] = {}
        self.stats = TfStats()

    @property
    def capacity(self) -> int:
        """Samples kept per dynamic edge."""
        return self._capacity

    def frames(self) -> list[str]:
        """Every frame id seen (parents and children), sorted."""
        names = set(self._edges)
        names.update(e.parent for e in self._edges.values())
        return sorted(names)

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame``, or None for a root or an unknown frame."""
        edge = self._edges.get(normalize_frame(frame))
        return edge.parent if edge is not None else None

    def is_static(self, frame: str) -> bool:
        """Whether ``frame``'s edge to its parent is static (False when it has none)."""
        edge = self._edges.get(normalize_frame(frame))
        return edge is not None and edge.static is not None

    def clear(self, *, keep_static: bool = True) -> None:
        """Forget the dynamic histories (e.g. after a jump back in time); static edges stay
        unless ``keep_static`` is False (tf2 keeps /tf_static the same way)."""
        if keep_static:
            self._edges = {c: e for c, e in self._edges.items() if e.static is not None}
        else:
            self._edges.clear()

    def set_transform(self, parent: str, child: str, stamp_ns: int, parent_T_child: ArrayLike,
                      *, static: bool = False) -> None:
        """Add one transform ``parent -> child`` (a ``/tf`` or ``/tf_static`` entry).

        A static transform replaces whatever the child had. A dynamic transform joins the
        child's history when the parent is unchanged; a new parent starts a new history.

        Args:
            parent: the header frame id.
            child: the child frame id.
            stamp_ns: the transform's stamp (int ns; ignored for static transforms).
            parent_T_child: array-like, shape (4, 4).
            static: from ``/tf_static``.

        Raises:
            InputError: empty frame ids, parent == child, a bad stamp or matrix, or an edge
                that would close a loop. Counted in ``stats.rejected``; the buffer is unchanged.
        """
        try:
            p = normalize_frame(parent, "parent frame_id")
            c = normalize_frame(child, "child_frame_id")
            if p == c:
                raise InputError(f"transform {p!r} -> {c!r}: a frame cannot be its own parent")
            edge = self._edges.get(c)
            same_parent = edge is not None and edge.parent == p
            if not same_parent and self._is_ancestor(c, p):
                raise InputError(f"transform {p!r} -> {c!r} would close a loop ({c!r} is "
                                 f"already above {p!r})")
            if static:
                T = as_transform(parent_T_child, f"transform {p} -> {c}").copy()
                T.setflags(write=False)
                self._edges[c] = _Edge(p, T, None)
                self.stats.static += 1
            elif same_parent and edge is not None and edge.history is not None:
                edge.history.add(stamp_ns, parent_T_child)   # validates stamp and matrix
            else:
                history = PoseBuffer(self._capacity, name=f"{p} -> {c}")
                history.add(stamp_ns, parent_T_child)      # validate before replacing
                self._edges[c] = _Edge(p, None, history)
            if edge is not None and not same_parent:
                self.stats.reparented += 1
        except InputError:
            self.stats.rejected += 1
            raise
        self.stats.transforms += 1

    def _is_ancestor(self, frame: str, of: str) -> bool:
        """Whether ``frame`` is ``of`` or lies above it."""
        node: str | None = of
        for _ in range(_MAX_DEPTH):
            if node is None:
                return False
            if node == frame:
                return True
            edge = self._edges.get(node)
            node = edge.parent if edge is not None else None
        return True

    def _path_up(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to its root."""
        path = [frame]
        while path[-1] in self._edges:
            path.append(self._edges[path[-1]].parent)
            if len(path) > _MAX_DEPTH:
                raise LocalizationError(f"the TF tree above {frame!r} has a loop")
        return path

    def chain(self, target: str, source: str) -> tuple[list[str], list[str]]:
        """The frames from ``target`` and from ``source`` up to their common ancestor.

        Returns:
            ``(up_from_target, up_from_source)``: each starts at the frame and ends at the
            common ancestor (both end with the same frame).

        Raises:
            LocalizationError: an unknown frame, or frames in two unconnected trees.
        """
        t, s = normalize_frame(target, "target frame"), normalize_frame(source, "source frame")
        known = set(self._edges) | {e.parent for e in self._edges.values()}
        for name in (t, s):
            if name not in known:
                raise LocalizationError(f"frame {name!r} is not in the TF tree (known: "
                                        f"{', '.join(sorted(known)) or 'none'})")
        up_t, up_s = self._path_up(t), self._path_up(s)
        common = set(up_t) & set(up_s)
        if not common:
            raise LocalizationError(f"frames {t!r} and {s!r} are not connected in the TF tree "
                                    f"(roots {up_t[-1]!r} and {up_s[-1]!r})")
        ancestor = next(f for f in up_t if f in common)
        return up_t[:up_t.index(ancestor) + 1], up_s[:up_s.index(ancestor) + 1]

    def _up_transform(self, path: list[str], stamp_ns: int, max_gap_ns: int) -> np.ndarray:
        """``ancestor_T_frame`` along ``path`` (frame first, ancestor last)."""
        T = np.eye(4)
        for child in path[:-1]:
            T = self._edges[child].at(stamp_ns, max_gap_ns) @ T
        return T

    def lookup(self, target: str, source: str, stamp_ns: int, max_gap_ns: int) -> np.ndarray:
        """``target_T_source`` at ``stamp_ns`` (maps points in ``source`` into ``target``).

        Args:
            target: the frame to express in (e.g. ``base_link``).
            source: the frame whose pose is wanted (e.g. ``tool0``).
            stamp_ns: the query stamp (int ns), typically an image stamp.
            max_gap_ns: the widest accepted bracket of two samples of any dynamic edge on the
                chain (>= 0); a sample at exactly ``stamp_ns`` needs no bracket.

        Returns:
            A new float64 array, shape (4, 4).

        Raises:
            InputError: a bad stamp or frame id, or a negative ``max_gap_ns``.
            LocalizationError: unknown or unconnected frames, or an edge with no sample
                bracketing the stamp within ``max_gap_ns`` (before its oldest sample, after its
                newest: no extrapolation).
        """
        if isinstance(max_gap_ns, bool) or not isinstance(max_gap_ns, (int, np.integer)) \
                or max_gap_ns < 0:
            raise InputError(f"max_gap_ns: must be an int >= 0, got {max_gap_ns!r}")
        up_t, up_s = self.chain(target, source)
        ancestor_T_source = self._up_transform(up_s, stamp_ns, max_gap_ns)
        ancestor_T_target = self._up_transform(up_t, stamp_ns, max_gap_ns)
        return invert(ancestor_T_target) @ ancestor_T_source

    def newest_ns(self, target: str, source: str) -> int | None:
        """The newest stamp every dynamic edge between the two frames has reached (the time up
        to which :meth:`lookup` can answer without waiting), ``STATIC_NEWEST_NS`` for an
        all-static chain, None when the frames are not (yet) connected."""
        try:
            up_t, up_s = self.chain(target, source)
        except (LocalizationError, InputError):
            return None
        newest = STATIC_NEWEST_NS
        for child in up_t[:-1] + up_s[:-1]:
            n = self._edges[child].newest_ns()
            if n is None:
                return None
            newest = min(newest, n)
        return newest

    def oldest_ns(self, target: str, source: str) -> int | None:
        """The oldest stamp every dynamic edge between the frames still covers (None when not
        connected; 0 for an all-static chain)."""
        try:
            up_t, up_s = self.chain(target, source)
        except (LocalizationError, InputError):
            return None
        oldest = 0
        for child in up_t[:-1] + up_s[:-1]:
            edge = self._edges[child]
            if edge.history is not None:
                o = edge.history.oldest_ns
                if o is None:
                    return None
                oldest = max(oldest, o)
        return oldest


class TfPoseView:
    """One chain of a :class:`TfBuffer` with the :class:`PoseBuffer` interface.

    ``lookup(stamp_ns, max_gap_ns)`` is ``buffer.lookup(base_frame, ee_frame, ...)``;
    ``newest_ns`` / ``oldest_ns`` cover the whole chain. Poses are added to the buffer, not to
    the view (:meth:`add` raises).

    The staleness rules of :class:`PoseBuffer` hold for the chain too. The feeder calls
    :meth:`check_jump` before adding a dynamic transform and :meth:`received` after: each time
    the chain's newest stamp advances, its receive time is recorded, so :meth:`lookup` with
    ``now_ns`` and ``max_age_ns`` refuses (``stale_pose``) a chain last covered by transforms
    received too long ago; a transform stamped (or received) more than ``jump_back_ns`` before
    the newest clears the dynamic transforms (``resets["time_jump"]``: a bag loop or replay);
    :meth:`expire` clears them when the stream stopped or the clock went back.

    Args:
        buffer: the TF buffer.
        base_frame: the frame the pose is expressed in (``base_link``).
        ee_frame: the frame whose pose is wanted (``tool0``).
        jump_back_ns: see :class:`PoseBuffer`; None: no time-jump rule.
    """

    def __init__(self, buffer: TfBuffer, base_frame: str, ee_frame: str, *,
                 jump_back_ns: int | None = None) -> None:
        self.buffer = buffer
        self.base_frame = normalize_frame(base_frame, "base_frame")
        self.ee_frame = normalize_frame(ee_frame, "ee_frame")
        self._jump_back = jump_back_ns
        # the chain's newest stamp each time it advanced, with its receive time (identity poses)
        self._receipts = PoseBuffer(max(2, buffer.capacity), name=f"{self.base_frame} -> "
                                    f"{self.ee_frame}", jump_back_ns=jump_back_ns)
        self._last_newest: int | None = None
        #: Clears per cause, as :attr:`PoseBuffer.resets`.
        self.resets = self._receipts.resets

    def __len__(self) -> int:
        newest = self.newest_ns
        return 0 if newest is None else 1

    @property
    def capacity(self) -> int:
        return self.buffer.capacity

    @property
    def newest_ns(self) -> int | None:
        """See :meth:`TfBuffer.newest_ns`."""
        return self.buffer.newest_ns(self.base_frame, self.ee_frame)

    @property
    def oldest_ns(self) -> int | None:
        """See :meth:`TfBuffer.oldest_ns`."""
        return self.buffer.oldest_ns(self.base_frame, self.ee_frame)

    @property
    def newest_received_ns(self) -> int | None:
        """Receive time of the transforms that last advanced the chain (None: not recorded)."""
        return self._receipts.newest_received_ns

    def clear(self) -> None:
        """Forget the dynamic transforms (static ones stay) and their receive times."""
        self.buffer.clear(keep_static=True)
        self._receipts.clear()
        self._last_newest = None

    def add(self, stamp_ns: int, pose: ArrayLike, *, received_ns: int | None = None,
            checked: bool = False) -> bool:
        """Refused: the robot poses of this view come from TF (the arguments are
        :meth:`PoseBuffer.add <eye_in_hand.core.sync.PoseBuffer.add>`'s)."""
        raise InputError(f"robot poses come from TF ({self.base_frame} -> {self.ee_frame}): "
                         "add transforms to the TfBuffer")

    def check_jump(self, stamp_ns: int, received_ns: int | None = None) -> bool:
        """Before a dynamic transform stamped ``stamp_ns`` (received at ``received_ns``) is
        added: clear the dynamic transforms when time jumped back (see the class).

        Returns:
            True when they were cleared.
        """
        if self._jump_back is None:
            return False
        newest, recv = self.newest_ns, self._receipts.newest_received_ns
        if (newest is not None and newest - int(stamp_ns) > self._jump_back) or (
                received_ns is not None and recv is not None
                and recv - int(received_ns) > self._jump_back):
            self.clear()
            self.resets["time_jump"] += 1
            return True
        return False

    def received(self, received_ns: int) -> None:
        """After transforms were added: record ``received_ns`` if the chain's newest advanced."""
        newest = self.newest_ns
        if newest is not None and newest != self._last_newest:
            self._receipts.add(newest, np.eye(4), received_ns=received_ns)
            self._last_newest = newest

    def expire(self, now_ns: int, max_age_ns: int) -> str | None:
        """As :meth:`PoseBuffer.expire`; a clear forgets the dynamic transforms too."""
        cause = self._receipts.expire(now_ns, max_age_ns)
        if cause is not None:
            self.buffer.clear(keep_static=True)
            self._last_newest = None
        return cause

    def lookup(self, stamp_ns: int, max_gap_ns: int, *, now_ns: int | None = None,
               max_age_ns: int | None = None) -> np.ndarray:
        """``base_T_ee`` at ``stamp_ns``: see :meth:`TfBuffer.lookup`; with ``now_ns`` and
        ``max_age_ns`` also the receive-age rule of :meth:`PoseBuffer.lookup`."""
        T = self.buffer.lookup(self.base_frame, self.ee_frame, stamp_ns, max_gap_ns)
        self._receipts.check_age(stamp_ns, now_ns, max_age_ns)
        return T
