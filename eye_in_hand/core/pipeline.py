"""The one localization pipeline: stamped camera points and robot poses in, base-frame points
out, in stamp order, with every refusal by reason.

The ``hand_eye`` node and ``process`` (:mod:`eye_in_hand.offline`) both feed a
:class:`LocalizationPipeline` and publish or write what it emits, so each rule exists once:

* **pose waiting**: a point (or a frame of targets) whose image stamp is newer than the newest
  robot pose waits, up to ``max_pose_wait_s`` on the wait clock (None: until a pose comes or
  :meth:`LocalizationPipeline.flush`), for a robot pose at or after its stamp; a wait that ran
  out ends only as :class:`~eye_in_hand.core.sync.InputWaits` says (the consumer had a turn at
  its queue). Output is FIFO, in arrival (stamp) order: a point never overtakes an older one;
* **a frame of targets** waits up to ``max_target_wait_s`` for its targets' points, then the
  missing ones are refused (``no_point``);
* **staleness and interpolation**: the robot pose at the image stamp comes from the localizer
  (:class:`~eye_in_hand.core.localization.Localizer`: interpolated, never extrapolated, no gap
  over ``max_pose_gap_s``, poses received within ``max_pose_age_s`` of the point's arrival on
  the age clock: wall or simulated time live, the bag's log time offline);
* **robot poses from any source**: ``ee_pose`` (:meth:`~LocalizationPipeline.add_pose`),
  joint states through the chain's :class:`~eye_in_hand.core.kinematics.JointIndex`
  (:meth:`~LocalizationPipeline.add_joint_state`), or a TF view that replaces the localizer's
  pose buffer (:meth:`~LocalizationPipeline.pose_arrived` after each update);
* **eye-to-hand** (an :class:`~eye_in_hand.core.eye_to_hand.EyeToHandLocalizer`): nothing
  waits for a robot pose.

What it emits goes to sinks (:class:`PointSink` for single points, :class:`FrameSink` for
frames of targets), called in output order, with no result object built per point. Refusal
reasons: those of :class:`~eye_in_hand.errors.LocalizationError` (``no_pose``,
``before_buffer``, ``no_newer_pose``, ``pose_gap``, ``stale_pose``), ``bad_point_cov`` (a
malformed point or covariance), ``no_point`` (a listed target's point never came) and
``pending_overflow`` (the queue was full: the oldest was dropped); :attr:`refused` counts them.

Pure Python and numpy: no rclpy, no messages, and the clocks are passed in.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
from eye_in_hand.core.localization import Localizer, LocalizerConfig
from eye_in_hand.core.sync import InputWaits
from eye_in_hand.errors import InputError, LocalizationError

__all__ = ["LocalizationPipeline", "PipelineRules", "WaitingPoint", "WaitingFrame",
           "PointSink", "FrameSink", "CarriedTarget", "localizer_config",
           "DEFAULT_MAX_WAITING_POINTS", "DEFAULT_MAX_WAITING_FRAMES",
           "DEFAULT_MAX_STORED_TARGET_POINTS"]

#: Points (frames) that may wait at once live; the oldest is refused (``pending_overflow``).
DEFAULT_MAX_WAITING_POINTS, DEFAULT_MAX_WAITING_FRAMES = 1000, 200
#: Target points kept for frames not yet listed; the oldest is dropped as an orphan.
DEFAULT_MAX_STORED_TARGET_POINTS = 4000
#: Covariances kept for points not yet arrived (target/point_cov before target/point).
_MAX_EARLY_COVS = 200


@dataclass
class WaitingPoint:
    """A camera point (the first target) waiting for its robot pose (and covariance).

    Attributes:
        stamp_ns: the image stamp.
        point: (3,) in the camera frame.
        cov: (3, 3) triangulation covariance, or None (not yet, or none).
        arrived: the wait clock at its arrival (s).
        received_ns: the age clock at its arrival (int ns; None: no receive-age rule).
    """

    stamp_ns: int
    point: np.ndarray
    cov: np.ndarray | None
    arrived: float
    received_ns: int | None


@dataclass
class WaitingFrame:
    """A frame of targets waiting for its targets' points and its robot pose.

    Attributes:
        stamp_ns: the image stamp.
        targets: the feeder's target objects, each with an ``id`` (live: the spheres of
            ``targets/markers``; offline: the frame's :class:`CarriedTarget` results).
        arrived: the wait clock at its arrival (s).
        received_ns: the age clock at its arrival (int ns; None: no receive-age rule).
        carried: the targets carry their points (``point_cam``, ``cov_cam``); else the points
            come through :meth:`LocalizationPipeline.add_target_point`.
        tag: the feeder's object for this frame (offline: its ``FrameResult``).
    """

    stamp_ns: int
    targets: Sequence[Any]
    arrived: float
    received_ns: int | None
    carried: bool = False
    tag: Any = None


class CarriedTarget(Protocol):
    """A target whose camera point comes with its frame (``process``'s located targets)."""

    id: str
    point_cam: np.ndarray
    cov_cam: np.ndarray | None


class PointSink(Protocol):
    """Where the pipeline's single points go, in output order."""

    def point_located(self, item: WaitingPoint, point_base: np.ndarray,
                      cov_base: np.ndarray) -> None:
        """``item`` in the base frame: (3,) and its (3, 3) covariance."""

    def point_refused(self, item: WaitingPoint, reason: str, detail: str) -> None:
        """``item`` gives no base-frame point: ``reason`` (see the module), ``detail`` why."""


class FrameSink(Protocol):
    """Where the pipeline's frames of targets go: each target, then the frame, in order."""

    def target_located(self, frame: WaitingFrame, target: Any, point_base: np.ndarray,
                       cov_base: np.ndarray) -> None:
        """A target of ``frame`` in the base frame."""

    def target_refused(self, frame: WaitingFrame, target: Any, reason: str,
                       detail: str) -> None:
        """A target of ``frame`` that gives no base-frame point (``reason``: the module's)."""

    def frame_done(self, frame: WaitingFrame) -> None:
        """Every target of ``frame`` went out (located or refused)."""

    def orphan_points(self, n: int) -> None:
        """``n`` target points that no frame listed were dropped."""


@dataclass(frozen=True)
class PipelineRules:
    """The waiting rules of :class:`LocalizationPipeline`.

    Attributes:
        max_pose_wait_s: how long a point or frame waits for a robot pose newer than its stamp
            (s, on the wait clock); None: until one comes or :meth:`~LocalizationPipeline.flush`
            (``process``: a bag's poses are all read before its end).
        max_target_wait_s: how long a frame waits for its targets' points (s).
        max_waiting_points, max_waiting_frames: the most items waiting at once; the oldest is
            refused (``pending_overflow``) to make room. None: no limit.
        max_stored_target_points: target points kept for frames not yet listed.
    """

    max_pose_wait_s: float | None = 0.2
    max_target_wait_s: float = 0.2
    max_waiting_points: int | None = DEFAULT_MAX_WAITING_POINTS
    max_waiting_frames: int | None = DEFAULT_MAX_WAITING_FRAMES
    max_stored_target_points: int = DEFAULT_MAX_STORED_TARGET_POINTS

    def __post_init__(self) -> None:
        for name in ("max_pose_wait_s", "max_target_wait_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name}: must be finite and >= 0, got {v}")
        for name in ("max_waiting_points", "max_waiting_frames", "max_stored_target_points"):
            v = getattr(self, name)
            if v is not None and v < 1:
                raise InputError(f"{name}: must be >= 1, got {v}")


def localizer_config(*, max_pose_gap_s: float, max_pose_age_s: float | None,
                     pose_jump_back_s: float | None, buffer_size: int,
                     robot_sigma_pos_m: float, robot_sigma_rot_rad: float) -> LocalizerConfig:
    """The :class:`~eye_in_hand.core.localization.LocalizerConfig` of the ``hand_eye`` node and
    of ``process`` from their settings in seconds (:class:`~eye_in_hand.core.defaults.PoseRules`
    names), converted to int ns here, once.

    Raises:
        InputError: a setting out of range.
    """
    return LocalizerConfig(
        max_gap_ns=int(max_pose_gap_s * 1e9), buffer_size=buffer_size,
        robot_sigma_pos_m=robot_sigma_pos_m, robot_sigma_rot_rad=robot_sigma_rot_rad,
        max_age_ns=None if max_pose_age_s is None else int(max_pose_age_s * 1e9),
        jump_back_ns=None if pose_jump_back_s is None else int(pose_jump_back_s * 1e9))


class LocalizationPipeline:
    """Camera points and robot poses in, base-frame points out (see the module).

    Args:
        localizer: a :class:`~eye_in_hand.core.localization.Localizer` (eye-in-hand: its
            ``poses`` may be replaced by a TF view) or an
            :class:`~eye_in_hand.core.eye_to_hand.EyeToHandLocalizer` (nothing waits for a
            robot pose).
        rules: :class:`PipelineRules`.
        wait_clock: the clock of the waits (s; live: a monotonic clock, so waits end also
            while simulated time stands still).
        points: where single points go (:meth:`add_point`); None: no single points are fed.
        frames: where frames of targets go (:meth:`add_frame`); None: none are fed.
        cov_expected: whether a point without a covariance should wait for one (a detector
            publishes them); asked only then. None: never.
        kinematics: a chain with ``joint_names`` and ``fk(q)`` for :meth:`add_joint_state`.
    """

    def __init__(self, localizer: Localizer | EyeToHandLocalizer, rules: PipelineRules, *,
                 wait_clock: Callable[[], float], points: PointSink | None = None,
                 frames: FrameSink | None = None,
                 cov_expected: Callable[[], bool] | None = None,
                 kinematics: Any = None) -> None:
        self.localizer = localizer
        self.rules = rules
        #: eye-in-hand: points wait for a robot pose at or after their stamp
        self.needs_pose = not isinstance(localizer, EyeToHandLocalizer)
        self._clock = wait_clock
        #: where single points and frames go (may be set after construction)
        self.point_sink = points
        self.frame_sink = frames
        #: called before a point or a frame is queued and at each check of the waits: a live
        #: robot pose source that takes its poses only when they are needed gives them here
        #: (``hand_eye``'s lazy ``ee_pose`` / ``joint_states``); None: poses come by themselves
        self.pull_poses: Callable[[], None] | None = None
        self._cov_expected = cov_expected
        self._kinematics = kinematics
        self._joints: Any = None
        if kinematics is not None:
            # local: core.kinematics loads SciPy's optimizer, which `process` defers; only
            # joint states need it
            from eye_in_hand.core.kinematics import JointIndex

            self._joints = JointIndex(kinematics.joint_names)
        self.waits = InputWaits(math.inf if rules.max_pose_wait_s is None
                                else rules.max_pose_wait_s, rules.max_target_wait_s)
        #: single points waiting, oldest first
        self.points: deque[WaitingPoint] = deque()
        #: frames of targets waiting, oldest first
        self.frames: deque[WaitingFrame] = deque()
        self._covs: dict[int, np.ndarray] = {}      # covariances before their point
        # (target id, image stamp) -> (point (3,), covariance (3, 3)), in arrival order
        self._target_points: dict[tuple[str, int], tuple[np.ndarray, np.ndarray | None]] = {}
        #: refusals by reason (single points and targets alike)
        self.refused: dict[str, int] = {}

    # -- robot poses ------------------------------------------------------------------------
    @property
    def newest_pose_ns(self) -> int | None:
        """The newest robot pose stamp (None: none yet, or eye-to-hand)."""
        if not self.needs_pose:
            return None
        newest: int | None = self.localizer.poses.newest_ns     # type: ignore[union-attr]
        return newest

    def add_pose(self, stamp_ns: int, base_T_ee: np.ndarray, *,
                 received_ns: int | None = None, checked: bool = False) -> bool:
        """Buffer a robot pose (``ee_pose``, or any ``base_T_ee`` (4, 4)) received at
        ``received_ns`` on the age clock. Waiting items are not emitted until :meth:`drain`.
        ``checked``: ``base_T_ee`` is :func:`~eye_in_hand.ros.geometry.pose_to_matrix`'s (see
        :meth:`PoseBuffer.add <eye_in_hand.core.sync.PoseBuffer.add>`).

        Returns:
            True when the pose buffer was cleared first (time jumped back).

        Raises:
            InputError: a bad stamp or not a rigid transform; eye-to-hand (no robot pose).
        """
        if not isinstance(self.localizer, Localizer):
            raise InputError("eye-to-hand: no robot pose is used")
        jumped = self.localizer.add_robot_pose(stamp_ns, base_T_ee, received_ns=received_ns,
                                               checked=checked)
        self.waits.pose_arrived()
        return jumped

    def add_joint_state(self, stamp_ns: int, names: Sequence[str], position: Sequence[float],
                        *, received_ns: int | None = None) -> bool:
        """A robot pose from one joint state message: the chain's joints by name (any order,
        extras ignored), forward kinematics, then :meth:`add_pose`.

        Raises:
            InputError: missing or non-finite joints (``MissingJointsError``), a bad stamp;
                no kinematics given.
        """
        if self._joints is None:
            raise InputError("joint_states: no kinematics given")
        q = self._joints.positions(names, position)
        return self.add_pose(stamp_ns, self._kinematics.fk(q), received_ns=received_ns)

    def pose_arrived(self) -> None:
        """The pose source (a TF view in the localizer) reached a newer stamp."""
        self.waits.pose_arrived()

    # -- single points ----------------------------------------------------------------------
    def add_point(self, stamp_ns: int, point: np.ndarray, cov: np.ndarray | None, *,
                  received_ns: int | None = None) -> None:
        """Queue a camera point (and its covariance, or one that came first) until its robot
        pose is there; the oldest waiting point is refused when the queue is full. Then
        :meth:`drain`."""
        if self.pull_poses is not None:
            self.pull_poses()
        cap = self.rules.max_waiting_points
        if cap is not None and len(self.points) >= cap:
            self._refuse_point(self.points.popleft(), "pending_overflow",
                               f"more than {cap} points wait for robot poses")
        if cov is None and self._covs:
            cov = self._covs.pop(stamp_ns, None)
        self.points.append(WaitingPoint(stamp_ns, point, cov, self._clock(), received_ns))
        self.drain()

    def add_point_cov(self, stamp_ns: int, cov: np.ndarray) -> None:
        """The covariance (3, 3) of the point with this stamp (waiting, or still to come).
        Then :meth:`drain`."""
        for item in self.points:
            if item.stamp_ns == stamp_ns:
                item.cov = cov
                break
        else:
            self._covs[stamp_ns] = cov
            while len(self._covs) > _MAX_EARLY_COVS:
                self._covs.pop(next(iter(self._covs)))
        self.drain()

    # -- frames of targets ------------------------------------------------------------------
    def target_point_arrived(self) -> None:
        """A target's point arrived (also one that could not be used): the point wait's
        bookkeeping (:class:`~eye_in_hand.core.sync.InputWaits`)."""
        self.waits.point_arrived()

    def add_target_point(self, target_id: str, stamp_ns: int, point: np.ndarray,
                         cov: np.ndarray | None) -> None:
        """Keep a target's camera point for its frame (listed before or after it)."""
        self.waits.point_arrived()
        store = self._target_points
        store[(target_id, stamp_ns)] = (point, cov)
        dropped = 0
        while len(store) > self.rules.max_stored_target_points:
            store.pop(next(iter(store)))
            dropped += 1
        if dropped and self.frame_sink is not None:
            self.frame_sink.orphan_points(dropped)

    def add_frame(self, stamp_ns: int, targets: Sequence[Any], *,
                  received_ns: int | None = None, carried: bool = False,
                  tag: Any = None) -> None:
        """Queue a frame of targets (each with an ``id``; ``carried``: with their points,
        see :class:`CarriedTarget`) until its points and robot pose are there; when the queue
        is full, the oldest frame's targets are refused. Then :meth:`drain`."""
        if self.pull_poses is not None:
            self.pull_poses()
        cap = self.rules.max_waiting_frames
        if cap is not None and len(self.frames) >= cap:
            old = self.frames.popleft()
            for t in old.targets:
                self._refuse_target(old, t, "pending_overflow",
                                    f"more than {cap} frames wait: the oldest was dropped")
        self.frames.append(WaitingFrame(stamp_ns, targets, self._clock(), received_ns,
                                        carried, tag))
        self.drain()

    # -- the decision rules -----------------------------------------------------------------
    def _point_ready(self, item: WaitingPoint, newest: int | None, now: float) -> bool:
        """Whether a waiting point can be located now (or must be, its wait being over)."""
        if self.waits.pose_wait_over(now - item.arrived):
            return True
        if self.needs_pose and (newest is None or item.stamp_ns > newest):
            return False  # wait for a robot pose at or after the image stamp
        # wait for the triangulation covariance when a detector publishes one
        return item.cov is not None or self._cov_expected is None or not self._cov_expected()

    def _frame_ready(self, f: WaitingFrame, newest: int | None, now: float) -> bool:
        """Whether a waiting frame can go out now (or must, a wait being over)."""
        if not f.carried:
            store = self._target_points
            if not all((t.id, f.stamp_ns) in store for t in f.targets):
                return self.waits.point_wait_over(now - f.arrived)
        if not self.needs_pose or not f.targets:
            return True
        return (newest is not None and f.stamp_ns <= newest) \
            or self.waits.pose_wait_over(now - f.arrived)

    def drain(self) -> None:
        """Emit every waiting point and frame that is ready, oldest first (FIFO: output stays
        in arrival order, a later item waits behind an earlier one)."""
        if not (self.points or self.frames):
            return
        newest = self.newest_pose_ns
        now = self._clock()
        while self.points and self._point_ready(self.points[0], newest, now):
            self._locate_point(self.points.popleft())
        while self.frames and self._frame_ready(self.frames[0], newest, now):
            self._locate_frame(self.frames.popleft())

    def tick(self) -> bool:
        """The periodic check of the waits (live: every few tens of ms while something waits):
        feeds :class:`~eye_in_hand.core.sync.InputWaits` with the longest wait, emits what is
        ready. Returns whether anything still waits (False: the check may stop)."""
        if self.pull_poses is not None:
            self.pull_poses()
        now = self._clock()
        oldest = now
        if self.points:
            oldest = self.points[0].arrived     # FIFO queues: the first item waited longest
        if self.frames:
            oldest = min(oldest, self.frames[0].arrived)
        self.waits.tick(now - oldest)
        self.drain()
        if self.points or self.frames:
            return True
        self.waits.tick(0.0)          # as an idle check would: nothing waits
        return False

    def flush(self) -> None:
        """The end of the input: every waiting item is emitted now (located if it can be,
        else refused by reason)."""
        while self.points:
            self._locate_point(self.points.popleft())
        while self.frames:
            self._locate_frame(self.frames.popleft())

    @property
    def waiting(self) -> bool:
        """Whether a point or a frame waits."""
        return bool(self.points or self.frames)

    @property
    def targets_waiting(self) -> int:
        """Targets of the waiting frames."""
        return sum(len(f.targets) for f in self.frames)

    # -- emitting -----------------------------------------------------------------------------
    def _count(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def _refuse_point(self, item: WaitingPoint, reason: str, detail: str) -> None:
        self._count(reason)
        if self.point_sink is not None:
            self.point_sink.point_refused(item, reason, detail)

    def _refuse_target(self, frame: WaitingFrame, target: Any, reason: str,
                       detail: str) -> None:
        self._count(reason)
        if self.frame_sink is not None:
            self.frame_sink.target_refused(frame, target, reason, detail)

    def _locate_point(self, item: WaitingPoint) -> None:
        try:
            res = self.localizer.locate(item.stamp_ns, item.point, item.cov,
                                        now_ns=item.received_ns)
        except LocalizationError as exc:
            self._refuse_point(item, exc.reason, str(exc))
            return
        except InputError as exc:
            self._refuse_point(item, "bad_point_cov", str(exc))
            return
        if self.point_sink is not None:
            self.point_sink.point_located(item, res.point_base, res.covariance)

    def _locate_frame(self, f: WaitingFrame) -> None:
        """Every target of a frame into the base frame, then the frame itself."""
        sink = self.frame_sink
        store = self._target_points
        for t in f.targets:
            if f.carried:
                point, cov = t.point_cam, t.cov_cam
            else:
                data = store.pop((t.id, f.stamp_ns), None)
                if data is None:
                    self._refuse_target(f, t, "no_point", f"the point at {f.stamp_ns} ns did "
                                        f"not arrive within {self.rules.max_target_wait_s} s")
                    continue
                point, cov = data
            try:
                res = self.localizer.locate(f.stamp_ns, point, cov, now_ns=f.received_ns)
            except LocalizationError as exc:
                self._refuse_target(f, t, exc.reason, str(exc))
                continue
            except InputError as exc:
                self._refuse_target(f, t, "bad_point_cov", str(exc))
                continue
            if sink is not None:
                sink.target_located(f, t, res.point_base, res.covariance)
        if store:
            # points of this stamp (or older) that no frame listed are never used
            old = [k for k in store if k[1] <= f.stamp_ns]
            for key in old:
                del store[key]
            if old and sink is not None:
                sink.orphan_points(len(old))
        if sink is not None:
            sink.frame_done(f)
