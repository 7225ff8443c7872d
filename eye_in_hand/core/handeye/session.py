"""A hand-eye calibration session at a live cell: samples, stillness, duplicates, compute, status.

ROS-free: the ``hand_eye`` node's calibration mode feeds it images (a frame once every view's
image of one stamp is in) and the robot pose source and wires its answers to services and
topics; a test drives it with plain numbers.

Capture rule (docs/handeye.md, "Calibrating at a live cell"):

1. :meth:`CalibrationSession.request_capture` remembers the newest frame stamp seen so far and
   the request's time on the data clock (the node's clock: wall time, or ``/clock``). The
   request is answered from the first frame stamped after both, so a capture never uses an
   image taken before the person asked for it (a camera that stamps late, or a simulator that
   renders slowly, cannot hand in an older image).
2. That frame waits until the robot poses cover its stillness window: a pose at or after
   ``stamp + still_window_s`` must exist (poses may arrive later than images; nothing is
   extrapolated). The poses at ``stamp`` and across ``stamp +- still_window_s`` are then looked
   up (interpolated, never across a gap over ``max_pose_gap_s``).
3. The robot is still when no looked-up pose in the window is further than
   ``still_max_speed_m_s * still_window_s`` (and ``still_max_rot_speed_rad_s *
   still_window_s``) from the pose at the image stamp: a motion at the limit speed would
   reach that far by the window's edge, while encoder noise does not.
4. A pose within ``duplicate_translation_m`` and ``duplicate_rotation_rad`` of a sample already
   taken is refused as a duplicate: three captures at one still pose are one sample.
5. The board is detected in the frame's images (:func:`.observe.observe_sample`).

Every refusal has a ``reason`` (:data:`REASONS`) and a sentence that says what to do. A request
with no frame, or with no covering pose, by ``capture_timeout_s`` after it is refused
(``no_image`` / ``no_pose``).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from eye_in_hand.core.transforms import rotation_angle
from eye_in_hand.errors import EyeInHandError, HandEyeError, InputError, LocalizationError

from .calibrate import DEFAULT_ROBOT_MODEL, ROBOT_MODELS, HandEyeResult, calibrate_hand_eye
from .observe import board_pose_pnp, observe_sample
from .plan import PlanConfig, suggest_next_poses
from .samples import MIN_SAMPLES, CameraView, HandEyeSample, motion_diagnostics
from .solvers import SETUPS

__all__ = ["REASONS", "FRAMES_KEPT", "SessionConfig", "PoseSource", "CaptureRequest",
           "CaptureOutcome", "SampleRecord", "SessionStatus", "CalibrationSession",
           "receive_age_rule"]

#: Why a capture gave no sample.
REASONS = ("moving", "no_pose", "no_image", "board_not_seen", "duplicate", "error")
#: Incomplete frames (stamps) kept while they wait for their other images (:meth:`add_image`).
FRAMES_KEPT = 30


@dataclass(frozen=True)
class SessionConfig:
    """Rules of a live calibration session (the node's parameters of the same names).

    Attributes:
        setup: ``eye_in_hand`` (X = ee_T_cam) or ``eye_to_hand`` (X = base_T_cam).
        still_window_s: the robot must be still over +- this around the image stamp (s);
            0 turns the stillness check off (the pose at the stamp is still required).
        still_max_speed_m_s, still_max_rot_speed_rad_s: the speed limits that define still.
        max_pose_gap_s: largest gap between two robot poses bracketing a looked-up stamp (s).
        capture_timeout_s: how long a request waits for a new frame and the poses covering
            it (s, steady time).
        duplicate_translation_m, duplicate_rotation_rad: a pose this close to a sample's
            (both) is the same pose.
        min_samples: samples needed before the set can be good enough.
        min_rotation_deg: the largest rotation between two samples must reach this.
        min_axis_diversity: smallest normalised eigenvalue of the motion-axis scatter needed
            (0: one axis only, 1/3: axes in every direction).
        target_std_mm, target_std_deg: the 1-sigma of X at which the set is good enough.
        robot_model: the robot pose error model of the solve (``calibrate_hand_eye``'s
            ``robot_model``: ``per_pose`` or ``systematic``).
    """

    setup: str = "eye_in_hand"
    still_window_s: float = 0.2
    still_max_speed_m_s: float = 0.002
    still_max_rot_speed_rad_s: float = 0.01
    max_pose_gap_s: float = 0.05
    capture_timeout_s: float = 2.0
    duplicate_translation_m: float = 0.005
    duplicate_rotation_rad: float = math.radians(1.0)
    min_samples: int = 10
    min_rotation_deg: float = 30.0
    min_axis_diversity: float = 0.05
    target_std_mm: float = 0.5
    target_std_deg: float = 0.05
    robot_model: str = DEFAULT_ROBOT_MODEL

    def __post_init__(self) -> None:
        if self.setup not in SETUPS:
            raise InputError(f"setup must be one of {', '.join(SETUPS)}, got {self.setup!r}")
        if self.robot_model not in ROBOT_MODELS:
            raise InputError(f"robot_model must be one of {', '.join(ROBOT_MODELS)}, got "
                             f"{self.robot_model!r}")
        for name in ("still_window_s", "still_max_speed_m_s", "still_max_rot_speed_rad_s",
                     "duplicate_translation_m", "duplicate_rotation_rad", "min_rotation_deg",
                     "min_axis_diversity", "target_std_mm", "target_std_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a finite number >= 0, got {v!r}")
        for name in ("max_pose_gap_s", "capture_timeout_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a finite number > 0, got {v!r}")
        if self.min_samples < MIN_SAMPLES:
            raise InputError(f"min_samples must be >= {MIN_SAMPLES}, got {self.min_samples}")


class PoseSource(Protocol):
    """The robot pose (``base_T_ee``) at a stamp: :class:`eye_in_hand.core.sync.PoseBuffer`,
    :class:`eye_in_hand.core.tf.TfPoseView`, or anything with these two members."""

    @property
    def newest_ns(self) -> int | None: ...

    def lookup(self, stamp_ns: int, max_gap_ns: int, **kwargs: Any) -> np.ndarray: ...


@dataclass
class CaptureRequest:
    """A capture waiting for its frame and poses (internal to the session, exposed for tests).

    Attributes:
        id: request number.
        after_ns: the frame must be newer than this stamp (the newest seen at the request, or
            the request's own time on the data clock, whichever is later).
        deadline_s: steady time by which it is refused.
        frame_stamp_ns: the frame bound to it (None until one arrives).
        frame: that frame (opaque: what :meth:`CalibrationSession.add_frame` was given).
        frame_received_ns: when that frame arrived (data clock), or None.
    """

    id: int
    after_ns: int | None
    deadline_s: float
    frame_stamp_ns: int | None = None
    frame: Any = None
    frame_received_ns: int | None = None


def receive_age_rule(req: CaptureRequest, now_ns: int, max_pose_age_s: float
                     ) -> dict[str, int]:
    """The receive-age rule of a capture's pose lookups (``poses.lookup``'s ``now_ns`` and
    ``max_age_ns``; :class:`CalibrationSession`'s ``pose_kwargs``).

    The poses may have been received up to ``max_pose_age_s`` before the frame's stamp (on
    the data clock), however late the frame then arrived (a camera that renders or transfers
    slowly) and however long the capture waited for the poses after it; none may come from
    the clock's future.

    Args:
        req: the request (its frame's stamp and arrival, when bound).
        now_ns: the data clock now (the node's clock: wall time, or ``/clock``).
        max_pose_age_s: the largest receive age of a robot pose before the frame (s).
    """
    since = req.frame_received_ns if req.frame_received_ns is not None else now_ns
    if req.frame_stamp_ns is not None:
        since = min(since, req.frame_stamp_ns)
    waited = max(now_ns - since, 0)
    return {"now_ns": now_ns, "max_age_ns": int(max_pose_age_s * 1e9) + waited}


@dataclass(frozen=True)
class SampleRecord:
    """A sample with what the capture saw (for list, status and the services)."""

    sample: HandEyeSample
    stamp_ns: int
    corners: int
    reprojection_px: float
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class CaptureOutcome:
    """The answer to one capture request.

    Attributes:
        request_id: the request.
        ok: a sample was taken.
        reason: '' when ok, else one of :data:`REASONS`.
        message: one line for a person.
        record: the new sample (ok only).
        index: its index in the sample list (-1 when refused).
    """

    request_id: int
    ok: bool
    reason: str
    message: str
    record: SampleRecord | None = None
    index: int = -1


@dataclass(frozen=True)
class SessionStatus:
    """What ``~/calibration_status`` shows."""

    setup: str
    samples: int
    skipped: int
    min_samples: int
    rotation_spread_deg: float
    axis_spread_deg: float
    axis_diversity: float
    result: HandEyeResult | None
    std_mm: float
    std_deg: float
    good_enough: bool
    problems: tuple[str, ...]
    suggestions: tuple[np.ndarray, ...] = field(default_factory=tuple)


class CalibrationSession:
    """Samples of one calibration, the capture rule, compute and the status (module docstring).

    Args:
        config: the rules.
        board: :class:`eye_in_hand.core.calibration.BoardSpec`.
        views: the rig's cameras (:func:`.observe.rig_views`).
        poses: the robot pose source.
        decode: turns a frame given to :meth:`add_frame` into images by view name; called only
            for the frame a capture uses (images are decoded once per capture, not per frame).
        pose_kwargs: extra keyword arguments of ``poses.lookup`` (``now_ns``, ``max_age_ns``):
            a callable given the request, returning them, called per capture (the node
            measures the poses' receive age from the frame's arrival, not from when the poses
            after it came in).
        observe: detects the board and builds the sample (:func:`.observe.observe_sample`,
            the default; a test may give its own).
    """

    def __init__(self, config: SessionConfig, board: Any, views: Sequence[CameraView],
                 poses: PoseSource, decode: Callable[[Any], Mapping[str, np.ndarray]], *,
                 pose_kwargs: Callable[[CaptureRequest], dict[str, Any]] | None = None,
                 observe: Callable[..., Any] = observe_sample) -> None:
        self.config = config
        self.board = board
        self.views = list(views)
        self.poses = poses
        self.decode = decode
        self.pose_kwargs = pose_kwargs or (lambda req: {})
        self.observe = observe
        #: the image topics, as refusals name them (the node sets its resolved names)
        self.image_topics = ", ".join("image_raw" if v.name == "image" else
                                      f"{v.name}/image_raw" for v in self.views)
        self.records: list[SampleRecord] = []
        self.skipped: list[tuple[str, str]] = []     # (name, reason sentence)
        self.result: HandEyeResult | None = None
        self._requests: list[CaptureRequest] = []
        self._partial: dict[int, dict[str, Any]] = {}     # stamp -> the views' images so far
        self._newest_frame_ns: int | None = None
        self._next_id = 0
        self._names = 0

    # -- frames and requests -------------------------------------------------------------
    @property
    def samples(self) -> list[HandEyeSample]:
        return [r.sample for r in self.records]

    @property
    def pending(self) -> list[CaptureRequest]:
        return list(self._requests)

    def add_image(self, view: str, stamp_ns: int, image: Any, received_ns: int | None = None
                  ) -> dict[str, Any] | None:
        """One view's image (opaque: decoded only for the frame a capture uses), arrived at
        ``received_ns`` (data clock).

        Returns:
            The frame (images by view name) when this image completes it: it then goes to
            :meth:`add_frame`; else None. The newest :data:`FRAMES_KEPT` incomplete frames
            wait for their other images.
        """
        frame = self._partial.setdefault(stamp_ns, {})
        frame[view] = image
        while len(self._partial) > FRAMES_KEPT:
            self._partial.pop(next(iter(self._partial)))
        if len(frame) < len(self.views):
            return None
        del self._partial[stamp_ns]
        self.add_frame(stamp_ns, frame, received_ns)
        return frame

    def add_frame(self, stamp_ns: int, frame: Any, received_ns: int | None = None) -> None:
        """A new image frame (pair), arrived at ``received_ns`` (data clock): binds it to every
        request still waiting for a frame."""
        if self._newest_frame_ns is None or stamp_ns > self._newest_frame_ns:
            self._newest_frame_ns = stamp_ns
        for req in self._requests:
            if req.frame_stamp_ns is None and (req.after_ns is None or stamp_ns > req.after_ns):
                req.frame_stamp_ns, req.frame = stamp_ns, frame
                req.frame_received_ns = received_ns

    def request_capture(self, now_s: float, now_ns: int | None = None) -> CaptureRequest:
        """Ask for a sample from the next frame.

        Args:
            now_s: steady time (s): the timeout runs on it.
            now_ns: the request's time on the data clock (the frames' stamps); None: only
                the newest frame seen so far bounds the frame taken.
        """
        after = self._newest_frame_ns
        if now_ns is not None:
            after = now_ns if after is None else max(after, now_ns)
        req = CaptureRequest(self._next_id, after, now_s + self.config.capture_timeout_s)
        self._next_id += 1
        self._requests.append(req)
        return req

    def ready(self, now_s: float) -> list[CaptureRequest]:
        """The requests that can be answered now (their window covered, or timed out); they
        leave the waiting list and go to :meth:`complete`."""
        out: list[CaptureRequest] = []
        keep: list[CaptureRequest] = []
        window = int(self.config.still_window_s * 1e9)
        newest = self.poses.newest_ns
        for req in self._requests:
            covered = (req.frame_stamp_ns is not None and newest is not None
                       and newest >= req.frame_stamp_ns + window)
            (out if covered or now_s >= req.deadline_s else keep).append(req)
        self._requests = keep
        return out

    # -- answering a request ------------------------------------------------------------
    def _refuse(self, req: CaptureRequest, reason: str, message: str,
                name: str | None = None) -> CaptureOutcome:
        self.skipped.append((name or f"request_{req.id}", f"{reason}: {message}"))
        return CaptureOutcome(req.id, False, reason, message)

    def complete(self, req: CaptureRequest) -> CaptureOutcome:
        """Answer a request from :meth:`ready`: :meth:`check`, :meth:`detect`, :meth:`commit`.

        The node runs the three steps apart: :meth:`check` on the executor thread as soon as
        the request is ready (the robot poses are looked up while they are fresh), the board
        detection (tens of ms on a 720p pair) on a worker thread, and :meth:`commit` under its
        lock.
        """
        base_T_ee, refused = self.check(req)
        if refused is not None:
            return refused
        assert base_T_ee is not None
        return self.commit(req, base_T_ee, self.detect(req, base_T_ee))

    def check(self, req: CaptureRequest) -> tuple[np.ndarray | None, CaptureOutcome | None]:
        """The robot pose of a ready request, or its refusal: no frame, no pose, moving,
        duplicate. Fast (pose lookups only)."""
        cfg = self.config
        if req.frame_stamp_ns is None:
            return None, self._refuse(
                req, "no_image", f"no image pair stamped after the request arrived within "
                f"{cfg.capture_timeout_s:g} s: check the camera topics ({self.image_topics}), "
                "and that the camera stamps with this node's clock (use_sim_time when "
                "replaying)")
        stamp = req.frame_stamp_ns
        window = int(cfg.still_window_s * 1e9)
        newest = self.poses.newest_ns
        if newest is None or newest < stamp + window:
            have = "no robot pose at all" if newest is None else (
                f"the newest is {(stamp - newest) / 1e6:.0f} ms before the image")
            return None, self._refuse(
                req, "no_pose", f"no robot pose {cfg.still_window_s:g} s after the image at "
                f"{stamp} ns arrived within {cfg.capture_timeout_s:g} s ({have}); check the "
                "robot pose topic, or raise capture_timeout_s if poses come late")
        try:
            base_T_ee, moving = self._still_pose(req)
        except LocalizationError as exc:
            return None, self._refuse(req, "no_pose", f"no robot pose around the image at "
                                      f"{stamp} ns: {exc}")
        if moving:
            return None, self._refuse(req, "moving", moving)
        dup = self._duplicate_of(base_T_ee)
        if dup:
            return None, self._refuse(req, "duplicate", dup)
        return base_T_ee, None

    def detect(self, req: CaptureRequest, base_T_ee: np.ndarray) -> Any:
        """Detect the board in the request's frame (no session state is read or changed).

        Returns:
            An :class:`.observe.Observation`, or an exception to report (a bad image).
        """
        name = f"sample_{self._names:03d}"
        try:
            images = self.decode(req.frame)
            return self.observe(name, images, base_T_ee, self.board, self.views)
        except EyeInHandError as exc:
            return exc

    def commit(self, req: CaptureRequest, base_T_ee: np.ndarray, obs: Any) -> CaptureOutcome:
        """Take the detected sample (or refuse it): a duplicate is checked again, since
        another capture may have been taken meanwhile."""
        name = f"sample_{self._names:03d}"
        if isinstance(obs, BaseException):
            return self._refuse(req, "error", f"{name}: {obs}", name)
        if obs.sample is None:
            return self._refuse(req, "board_not_seen", f"{obs.reason}: make the whole board "
                                "visible, well lit and sharp", name)
        dup = self._duplicate_of(base_T_ee)
        if dup:
            return self._refuse(req, "duplicate", dup)
        sample = obs.sample
        if sample.name != name:     # named when detected; the next free name now
            sample = HandEyeSample(name, sample.base_T_ee, sample.cam_T_board,
                                   sample.observations)
        self._names += 1
        ref = sample.observations[0]
        _, rms = board_pose_pnp(self.views[0].model, ref.object_points, ref.image_points)
        record = SampleRecord(sample, req.frame_stamp_ns or 0,
                              int(sum(o.image_points.shape[0] for o in sample.observations)),
                              rms, obs.notes)
        self.records.append(record)
        self.result = None
        n = len(self.records)
        notes = f" ({'; '.join(obs.notes)})" if obs.notes else ""
        return CaptureOutcome(req.id, True, "", f"captured {name} at {record.stamp_ns} ns: {n} "
                              f"sample{'s' if n != 1 else ''}{notes}", record, n - 1)

    def _still_pose(self, req: CaptureRequest) -> tuple[np.ndarray, str]:
        """The robot pose at ``stamp`` and '' when still over the window, else why not.

        Raises:
            LocalizationError: a pose in the window cannot be looked up (gap, no pose
                before it, stale).
        """
        cfg = self.config
        stamp = req.frame_stamp_ns
        assert stamp is not None
        gap = int(cfg.max_pose_gap_s * 1e9)
        kw = self.pose_kwargs(req)
        T = self.poses.lookup(stamp, gap, **kw)
        w = cfg.still_window_s
        if w <= 0:
            return T, ""
        worst_m, worst_rad = 0.0, 0.0
        for f in np.linspace(-1.0, 1.0, 9):
            if f == 0.0:
                continue
            Ts = self.poses.lookup(stamp + int(round(f * w * 1e9)), gap, **kw)
            worst_m = max(worst_m, float(np.linalg.norm(Ts[:3, 3] - T[:3, 3])))
            worst_rad = max(worst_rad, rotation_angle(Ts[:3, :3].T @ T[:3, :3]))
        lim_m, lim_rad = cfg.still_max_speed_m_s * w, cfg.still_max_rot_speed_rad_s * w
        if worst_m > lim_m or worst_rad > lim_rad:
            return T, (f"the robot moved {1000 * worst_m:.2f} mm and "
                       f"{math.degrees(worst_rad):.3f} deg within +-{w:g} s of the image "
                       f"(still means at most {1000 * lim_m:.2f} mm and "
                       f"{math.degrees(lim_rad):.3f} deg: still_max_speed_m_s and "
                       f"still_max_rot_speed_rad_s x still_window_s); wait until it stops")
        return T, ""

    def _duplicate_of(self, base_T_ee: np.ndarray) -> str:
        cfg = self.config
        for r in self.records:
            d = float(np.linalg.norm(r.sample.base_T_ee[:3, 3] - base_T_ee[:3, 3]))
            a = rotation_angle(r.sample.base_T_ee[:3, :3].T @ base_T_ee[:3, :3])
            if d <= cfg.duplicate_translation_m and a <= cfg.duplicate_rotation_rad:
                return (f"this pose was already taken as {r.sample.name} ({1000 * d:.2f} mm, "
                        f"{math.degrees(a):.3f} deg away; a new pose must differ by more than "
                        f"{1000 * cfg.duplicate_translation_m:g} mm or "
                        f"{math.degrees(cfg.duplicate_rotation_rad):.3g} deg): move the robot to "
                        "the next pose")
        return ""

    # -- samples ----------------------------------------------------------------------
    def remove(self, index: int | None = None, name: str | None = None) -> SampleRecord:
        """Remove one sample by index or name.

        Raises:
            InputError: no such sample.
        """
        if name:
            for i, r in enumerate(self.records):
                if r.sample.name == name:
                    index = i
                    break
            else:
                have = ", ".join(r.sample.name for r in self.records) or "none"
                raise InputError(f"no sample named {name!r} (samples: {have})")
        if index is None or not 0 <= index < len(self.records):
            raise InputError(f"no sample at index {index} ({len(self.records)} samples: "
                             f"0..{len(self.records) - 1})" if self.records else
                             f"no sample at index {index}: there are no samples")
        self.result = None
        return self.records.pop(index)

    def reset(self) -> int:
        """Forget every sample (and pending request); returns how many samples there were."""
        n = len(self.records)
        self.records.clear()
        self.skipped.clear()
        self._requests.clear()
        self.result = None
        return n

    def add_samples(self, samples: Sequence[HandEyeSample]) -> None:
        """Add samples taken elsewhere (loaded): they count as captured."""
        for s in samples:
            self.records.append(SampleRecord(s, 0, int(sum(o.image_points.shape[0]
                                                           for o in s.observations)),
                                             float("nan")))
            self._names += 1
        self.result = None

    # -- compute and status ------------------------------------------------------------
    def compute(self, samples: Sequence[HandEyeSample] | None = None) -> HandEyeResult:
        """Solve with every method and select (:func:`.calibrate.calibrate_hand_eye`).

        Args:
            samples: a snapshot of the samples (default: the current ones). The node passes a
                snapshot, so that captures during a compute do not change its input.

        Raises:
            HandEyeError: too few or degenerate samples (the message says what to add).
        """
        snap = list(self.samples if samples is None else samples)
        if len(snap) < MIN_SAMPLES:
            raise HandEyeError(f"{len(snap)} sample(s): need at least {MIN_SAMPLES} (capture "
                               "more poses)")
        result = calibrate_hand_eye(snap, self.config.setup, cameras=self.views,
                                    robot_model=self.config.robot_model)
        if samples is None or [s.name for s in snap] == [s.name for s in self.samples]:
            self.result = result
        return result

    def next_poses(self, samples: Sequence[HandEyeSample], X: np.ndarray,
                   plan: PlanConfig | None) -> tuple[np.ndarray, ...]:
        """The flange poses (``base_T_ee``, 4x4) to take next, best first, for ``samples`` and
        their estimate ``X`` (:func:`.plan.suggest_next_poses`); none when ``plan`` is None.

        Raises:
            EyeInHandError: the samples give no plan.
        """
        if plan is None:
            return ()
        found = suggest_next_poses(list(samples), X, self.config.setup, self.views, config=plan)
        return tuple(s.base_T_ee for s in found.suggestions)

    def status(self, result: HandEyeResult | None = None,
               suggestions: Sequence[np.ndarray] = ()) -> SessionStatus:
        """The status: motion diversity, the estimate and whether the set is good enough.

        Args:
            result: the estimate to show (default: the last compute on the current samples).
            suggestions: suggested next flange poses (4, 4), best first.
        """
        cfg = self.config
        result = self.result if result is None else result
        n = len(self.records)
        problems: list[str] = []
        rot = axis = div = float("nan")
        if n >= 2:
            try:
                md = motion_diagnostics(np.stack([s.base_T_ee for s in self.samples]),
                                        cfg.setup)
                rot, axis, div = md.rotation_deg[2], md.axis_spread_deg, md.axis_eigenvalues[2]
            except EyeInHandError as exc:
                problems.append(f"motion: {exc}")
        if n < cfg.min_samples:
            problems.append(f"{n} of {cfg.min_samples} samples: capture "
                            f"{cfg.min_samples - n} more")
        if not (rot >= cfg.min_rotation_deg):
            problems.append(f"largest rotation between samples {rot:.1f} deg < "
                            f"{cfg.min_rotation_deg:g} deg: tilt the camera more between poses")
        if not (div >= cfg.min_axis_diversity):
            problems.append(f"rotation axes too alike (diversity {div:.3f} < "
                            f"{cfg.min_axis_diversity:g}): rotate about other axes too")
        std_mm = std_deg = float("nan")
        if result is not None:
            sel = result.methods[result.selected]
            std_mm, std_deg = float(sel.std_mm), float(sel.std_deg)
            if not (std_mm <= cfg.target_std_mm and std_deg <= cfg.target_std_deg):
                problems.append(f"uncertainty {std_mm:.3f} mm / {std_deg:.4f} deg (1 sigma) "
                                f"above the target {cfg.target_std_mm:g} mm / "
                                f"{cfg.target_std_deg:g} deg: take the suggested poses")
        elif n >= MIN_SAMPLES:
            problems.append("no estimate yet: compute")
        return SessionStatus(cfg.setup, n, len(self.skipped), cfg.min_samples, rot, axis, div,
                             result, std_mm, std_deg, not problems, tuple(problems),
                             tuple(np.asarray(s) for s in suggestions))
