"""Offline processing of a bag: the live pipeline's core code, with no DDS, as fast as the CPU
allows.

One pass over the bag in log-time order:

* robot poses (``/ee_pose`` PoseStamped, or ``/joint_states`` + kinematics) go into the
  :class:`~eye_in_hand.core.localization.Localizer`'s pose buffer; with ``robot_pose_source:
  tf``, ``/tf`` and ``/tf_static`` go into a :class:`~eye_in_hand.core.tf.TfBuffer` whose
  ``base_frame -> ee_frame`` chain is looked up at each image stamp (as the live node does);
* left/right images are paired by :class:`~eye_in_hand.core.sync.ApproximateStereoSync` and
  located by :class:`~eye_in_hand.core.locator.StereoLocator`, exactly as ``detect_triangulate``
  does;
* each located pair waits in the :class:`~eye_in_hand.core.pipeline.LocalizationPipeline`, the
  one the live ``hand_eye`` node feeds, until a robot pose at or after its stamp has been read
  (or the bag ends), then its targets are mapped into the base frame by the same rules.

The bag is read without copying pixels: uncompressed MCAP chunks are memory-mapped and images
decoded straight from their CDR bytes into views; compressed chunks are decompressed a few
chunks ahead on threads. Reading runs on a thread, and stereo pairs are located by worker
processes that map the same file pages (threads for images that live only in this process's
memory), results taken back in stamp order. With ``selection: nearest`` the locator runs in the
main thread, in stamp order, so its state evolves as in the live node. The live and offline
paths therefore give the same numbers on the same bag.
"""
from __future__ import annotations

import math
import mmap
import os
import re
import sys
import threading
from array import array
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.defaults import DEFAULT_SYNC_QUEUE_SIZE, DEFAULT_SYNC_SLOP_S, POSE_RULES
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import LocatorConfig
from eye_in_hand.errors import BagError, ConversionError, InputError
from eye_in_hand.io.pages import drop_pages, keep_freed_heap

if TYPE_CHECKING:
    from eye_in_hand.core.localization import Localizer
    from eye_in_hand.core.pipeline import WaitingFrame
    from eye_in_hand.core.pose_correction import RobotPoseCorrection
    from eye_in_hand.core.sync import ApproximateStereoSync
    from eye_in_hand.io.bags import BagInfo
    from eye_in_hand.io.results import FrameResult, ProcessResult
    from eye_in_hand.ros.outputs import OutputSettings

# A `process` worker process imports this module for _worker_init and _worker_locate, which
# need OpenCV, numpy and the locator only. What the reading process alone uses is imported
# where it is used (marked `# local: reader only`): the bag reader, the results, the output
# messages, the robot-pose buffers (io.bags, io.results with ros.outputs and core.distances,
# core.pipeline with core.localization, core.eye_to_hand and core.sync: about 0.1 s of CPU at
# each worker's start).

__all__ = ["ProcessOptions", "process_bag", "loss_total", "error_stats", "top_reasons",
           "write_results"]


def _output_settings() -> OutputSettings:
    from eye_in_hand.ros.outputs import OutputSettings  # local: reader only

    return OutputSettings()


@dataclass(frozen=True)
class ProcessOptions:
    """Topics and settings of :func:`process_bag` (defaults: the simulator's bags).

    Attributes:
        left_topic, right_topic: image topics (sensor_msgs/Image).
        left_info_topic, right_info_topic: camera_info topics, used when no rig is given.
        robot_pose_source: ``"ee_pose"``, ``"joint_states"`` or ``"tf"``.
        ee_pose_topic: PoseStamped topic (base -> tool).
        joint_states_topic: JointState topic (with ``kinematics``).
        kinematics: a chain with ``joint_names`` and ``fk(q)`` (joint_states source only).
        tf_topic, tf_static_topic: TFMessage topics (tf source).
        ee_frame: the tool frame looked up from ``base_frame`` (tf source).
        ground_truth_topic: PointStamped of the targets in the base frame (optional in the bag).
        base_frame: frame id of the output poses.
        camera_frame: frame id of the output points.
        sync_slop_s, sync_queue_size: stereo pairing, as ``detect_triangulate``'s ``sync.*``.
        max_pose_gap_s, robot_sigma_pos_m, robot_sigma_rot_rad: as the ``hand_eye`` node's.
        max_pose_age_s, pose_jump_back_s: the ``hand_eye`` node's staleness rule, on the bag's
            log time: the robot poses used for a pair must have been recorded within
            ``max_pose_age_s`` before the pair's image (log time), and the pose buffer (and the
            stereo pairing) restart when stamps jump back more than ``pose_jump_back_s``.
        workers: processes (or threads, see :class:`_PairPool`) locating stereo pairs; 1 =
            in the calling thread; None: one per CPU this process may run on. Results are
            consumed in stamp order; with ``selection: nearest`` (which depends on the previous
            frame) one is used whatever this says, so the numbers never depend on it.
        task_timeout_s: deadline of a worker process for one stereo pair (s): a worker that
            gives no result for this long (stopped with SIGSTOP, hung) is killed and its pairs
            are located again in this process, so ``process`` never hangs.
        verify_crc: check MCAP chunk CRCs (off by default, as in the MCAP reference readers:
            CRC-32 costs about 16 ms per 1280x720 colour stereo pair here).
        setup: ``"eye_in_hand"``, or ``"eye_to_hand"``: the hand-eye transform is
            ``base_T_cam`` of a fixed camera; no robot topic is read.
        outputs: what the live nodes' parameters decide about the output messages (their
            frames, markers and transforms), so that the output bag holds the messages the
            live nodes would publish (:class:`eye_in_hand.ros.outputs.OutputSettings`).
    """

    left_topic: str = "/stereo/left/image_raw"
    right_topic: str = "/stereo/right/image_raw"
    left_info_topic: str = "/stereo/left/camera_info"
    right_info_topic: str = "/stereo/right/camera_info"
    robot_pose_source: str = "ee_pose"
    ee_pose_topic: str = "/ee_pose"
    joint_states_topic: str = "/joint_states"
    kinematics: Any = None
    tf_topic: str = "/tf"
    tf_static_topic: str = "/tf_static"
    ee_frame: str = "tool0"
    ground_truth_topic: str = "/ground_truth/target"
    base_frame: str = "base_link"
    camera_frame: str = "camera_left_optical_frame"
    sync_slop_s: float = DEFAULT_SYNC_SLOP_S
    sync_queue_size: int = DEFAULT_SYNC_QUEUE_SIZE
    max_pose_gap_s: float = POSE_RULES.max_pose_gap_s
    robot_sigma_pos_m: float = POSE_RULES.robot_sigma_pos_m
    robot_sigma_rot_rad: float = POSE_RULES.robot_sigma_rot_rad
    max_pose_age_s: float = POSE_RULES.max_pose_age_s
    pose_jump_back_s: float = POSE_RULES.pose_jump_back_s
    workers: int | None = None
    task_timeout_s: float = 20.0
    verify_crc: bool = False
    setup: str = "eye_in_hand"
    outputs: OutputSettings = field(default_factory=_output_settings)

    def __post_init__(self) -> None:
        if self.setup not in ("eye_in_hand", "eye_to_hand"):
            raise InputError(f"setup: expected eye_in_hand or eye_to_hand, got {self.setup!r}")
        if self.workers is not None and int(self.workers) < 1:
            raise InputError(f"workers: must be >= 1, got {self.workers}")
        if not self.task_timeout_s > 0:
            raise InputError(f"task_timeout_s: must be > 0, got {self.task_timeout_s}")
        if self.robot_pose_source not in ("ee_pose", "joint_states", "tf"):
            raise InputError(f"robot_pose_source: expected ee_pose, joint_states or tf, got "
                             f"{self.robot_pose_source!r}")
        if self.robot_pose_source == "joint_states" and self.kinematics is None:
            raise InputError("kinematics: required when robot_pose_source is joint_states")

    @property
    def pose_topic(self) -> str:
        if self.robot_pose_source == "tf":
            return self.tf_topic
        return self.ee_pose_topic if self.robot_pose_source == "ee_pose" else \
            self.joint_states_topic


def error_stats(frames: Iterable[FrameResult]) -> dict[str, float] | None:
    """RMS, p95 and max error in mm over frames with a result and ground truth (None if none;
    :func:`eye_in_hand.io.results.error_figures`)."""
    from eye_in_hand.io.results import error_figures  # local: reader only

    return error_figures(np.array([f.error_m for f in frames if math.isfinite(f.error_m)]))


_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def top_reasons(frames: Iterable[FrameResult], top: int = 3) -> list[tuple[int, str, str]]:
    """Why frames have no base-frame result, most frequent first: ``(count, status, example)``.

    Reasons that differ only in their numbers (``depth 566.1 m``, ``depth 570.4 m``) count as
    one; the example is the first frame's reason, as results.csv has it.
    """
    groups: dict[tuple[str, str], list[Any]] = {}
    for f in frames:
        if f.status == "ok":
            continue
        reason = f.reason or "no reason given"
        key = (f.status, _NUMBER.sub("#", reason))
        groups.setdefault(key, [0, reason])[0] += 1
    ranked = sorted(groups.items(), key=lambda kv: -kv[1][0])
    return [(count, status, example) for (status, _), (count, example) in ranked[:top]]


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask; the CPU count where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def process_bag(path: str | Path, *, hand_eye_T: np.ndarray, locator_config: LocatorConfig,
                rig: StereoRig | None = None, hand_eye_cov: np.ndarray | None = None,
                options: ProcessOptions | None = None,
                progress: Callable[[int], object] | None = None,
                pose_correction: RobotPoseCorrection | None = None,
                info: BagInfo | None = None,
                idle: Sequence[Callable[[], object]] = ()) -> ProcessResult:
    """Run detection, triangulation and localization over a bag.

    Args:
        path: bag directory or ``.mcap`` file.
        hand_eye_T: ``ee_T_cam``, shape (4, 4) (``base_T_cam`` with ``setup: eye_to_hand``).
        locator_config: detector/triangulation settings (``load_locator_config``).
        rig: the stereo calibration; None: built from the bag's camera_info topics.
        hand_eye_cov: optional (6, 6) covariance of ``hand_eye_T``.
        options: topics and settings.
        progress: called with the number of messages read since the last call.
        pose_correction: the calibration's correction of the reported robot poses
            (``hand_eye.yaml``'s ``robot_pose_correction``; eye-in-hand only), applied by the
            :class:`~eye_in_hand.core.localization.Localizer` as in the live node.
        info: the bag's :func:`~eye_in_hand.io.bags.bag_info`, when the caller has it
            already (read again otherwise).
        idle: work for this process while it would otherwise wait for its worker processes,
            each run once (the first times it waits; any left at the end of the pass then):
            what the caller needs next, e.g. ``process`` loads the type definitions of its
            output bag, which would cost the same time after the pass.

    Returns:
        Every stereo pair's :class:`FrameResult`, in stamp order, and counters.

    Raises:
        BagError: the bag cannot be read or lacks a required topic.
        InputError: malformed settings.
    """
    # local: reader only (see _BagPass.read)
    from eye_in_hand.io.bags import memory_mappable
    from eye_in_hand.io.bags.streams import worker_readable

    opts = options or ProcessOptions()
    path = Path(path)
    # the bag's summary and topics checked first: a bag that cannot be read fails here
    run = _BagPass(path, opts, rig, hand_eye_T, hand_eye_cov, pose_correction, info)
    # a locator whose results depend on earlier frames (tracked blob-set ids,
    # LocatorConfig.stateful where it exists) sees the stream in order, in one thread; the
    # rig (given, or read from the bag) goes to the pool by use_rig, after its workers start
    pool = _PairPool(None, locator_config, 1 if getattr(locator_config, "stateful", False)
                     else opts.workers or available_cpus(), task_timeout_s=opts.task_timeout_s)
    pool.idle.extend(idle)
    try:
        # worker processes for pairs in mapped files (uncompressed MCAP) or for compressed
        # chunks they open, started before the rig is read: they import while this process
        # builds the bag's type store and reads its camera_info, and are initialised with it
        in_workers = False
        if pool.parallel:
            mappable = memory_mappable(path)
            in_workers = not mappable and worker_readable(path)
            if mappable or in_workers:
                pool.start_processes()
        pool.use_rig(run.load_rig())
        run.read(pool, progress, in_workers)
        pool.run_idle(len(pool.idle))
        # the worker processes exit (8-10 ms each) while this one resolves the end of the bag
        pool.stop()
        run.settle([t.name for t in locator_config.detector.targets])
    finally:
        pool.close()
    return run.finish(pool)


#: Robot poses ``process`` keeps before the stamp of the frame it takes (s): a frame that needs
#: an older one would be a stereo pair read a minute after a later pair. The buffer is bounded
#: by time instead of holding every pose of the bag (about 1.2 kB a stereo pair at 125 Hz).
POSE_HISTORY_S = 60.0
#: frames taken between two prunings of the pose buffer (:meth:`_BagPass._forget_poses`)
_FORGET_EVERY = 256


def _no_wait_clock() -> float:
    """The pipeline's wait clock offline: waits never run out (the bag's end flushes them)."""
    return 0.0


class _BagPass:
    """One pass of :func:`process_bag` over a bag, and the state its steps share: the bag's
    topics, the localizer and the live node's pipeline, the stereo pairing, the result with
    its counts and ledger. :meth:`read` feeds every message in log-time order, :meth:`finish`
    resolves what still waits and totals the losses."""

    def __init__(self, path: Path, opts: ProcessOptions, rig: StereoRig | None,
                 hand_eye_T: np.ndarray, hand_eye_cov: np.ndarray | None,
                 pose_correction: RobotPoseCorrection | None, info: BagInfo | None) -> None:
        # local: reader only (see the imports at the top); the ros message modules add ~12 ms
        from eye_in_hand.core.pipeline import LocalizationPipeline, PipelineRules
        from eye_in_hand.core.sync import ApproximateStereoSync
        from eye_in_hand.io.bags import DamageLog, bag_info, require_topics
        from eye_in_hand.io.results import ProcessResult, TruthTable
        from eye_in_hand.io.spill import SpillList

        self.path, self.opts = path, opts
        info = self.info = info if info is not None else bag_info(path)
        fixed = self.fixed = opts.setup == "eye_to_hand"   # a fixed camera: no robot pose read
        required = [opts.left_topic, opts.right_topic] + ([] if fixed else [opts.pose_topic])
        require_topics(info, required + ([opts.left_info_topic, opts.right_info_topic]
                                         if rig is None else []))
        self.topics = list(required) + ([opts.ground_truth_topic]
                                        if opts.ground_truth_topic in info.topics else [])
        use_tf = opts.robot_pose_source == "tf" and not fixed
        if use_tf and opts.tf_static_topic in info.topics:
            self.topics.append(opts.tf_static_topic)
        n_poses = 0 if fixed else info.topics[opts.pose_topic].count
        self.localizer = _make_localizer(opts, fixed, n_poses, hand_eye_T, hand_eye_cov,
                                         pose_correction)
        self.tf_buffer = _use_tf(self.localizer, opts, n_poses) if use_tf else None
        self.sync: ApproximateStereoSync[Any] = ApproximateStereoSync(
            int(round(opts.sync_slop_s * 1e9)), opts.sync_queue_size)
        # every pair's outcome until the outputs are written, the older ones of a long bag in
        # a temporary file (settled by take: the frames before the oldest one still waiting)
        self.frames: SpillList[FrameResult] = SpillList()
        result = self.result = ProcessResult(frames=self.frames,
                                             duration_s=info.duration_ns / 1e9, rig=rig,
                                             damage=DamageLog())
        result.notes.extend(info.notes)   # a damaged metadata.yaml, a file read by scanning
        counts = self.counts = result.counts
        for key in ("pairs", "located", "localized", "no_target", "no_robot_pose",
                    "bad_messages"):
            counts[key] = 0
        self.ledger = _Ledger(counts, int(opts.pose_jump_back_s * 1e9))
        self.typestore: Any = None
        self.rig = rig            # None: read from the bag's camera_info by load_rig
        self.truth = TruthTable()
        # what the ground-truth matching reads of the frames, gathered as they are taken and
        # located (the frames in the temporary file are not read for it): target name ->
        # ids, and each id's base-frame positions (_FrameResults.located)
        self.seen: dict[str, set[str]] = {}
        self.sink = _FrameResults(counts, self.ledger)
        # the live node's pipeline: a pair waits for a robot pose at or after its stamp,
        # however long (the bag's poses are all read before its end: no wait clock), FIFO,
        # unbounded (every frame is kept in result.frames anyway); receive ages on the bag's
        # log time
        self.pipeline = LocalizationPipeline(
            self.localizer, PipelineRules(max_pose_wait_s=None, max_waiting_frames=None),
            wait_clock=_no_wait_clock, frames=self.sink,
            kinematics=opts.kinematics if not fixed and opts.robot_pose_source == "joint_states"
            else None)

    def load_rig(self) -> StereoRig:
        """The rig: the one given, else the bag's camera_info's (read now, once)."""
        if self.rig is None:
            self.rig = self._rig_from_bag()
        return self.rig

    def _rig_from_bag(self) -> StereoRig:
        """The rig from the bag's camera_info, read with the type store of the main pass."""
        from eye_in_hand.io.bags import typestore_for  # local: reader only

        info, opts = self.info, self.opts
        # one type store for the camera_info and the main pass (building the whole Jazzy
        # store for camera_info alone cost ~0.1-0.15 s of CPU at every start)
        try:
            self.typestore = typestore_for(self.path, {
                info.topics[t].msgtype for t in self.topics} | {
                info.topics[t].msgtype for t in (opts.left_info_topic, opts.right_info_topic)})
        except BagError:
            self.typestore = None       # as before: the main pass names the problem
        rig = _rig_from_camera_info(self.path, opts, self.result.damage, self.typestore)
        self.result.rig = rig
        return rig

    def note(self, text: str) -> None:
        if len(self.result.notes) < 20:
            self.result.notes.append(text)

    def take(self, frame: FrameResult) -> None:
        """One located (or not) pair, in stamp order: counted, and into the pipeline (every
        :data:`_FORGET_EVERY` frames, old robot poses are forgotten and the frames the pipeline
        is done with settled, see :meth:`_forget_poses`)."""
        frames = self.frames
        if (len(frames) + 1) % _FORGET_EVERY == 0:
            self._forget_poses(frame.stamp_ns)
            waiting = self.pipeline.frames     # FIFO: the oldest frame still waiting first
            frames.settle(waiting[0].tag if waiting else None)
        frames.append(frame)
        seen = self.seen
        for t in frame.targets:                 # target_order's input, without reading frames
            ids = seen.get(t.name)
            if ids is None:
                ids = seen[t.name] = set()
            ids.add(t.id)
        t_arrival = self.ledger.arrival(frame.stamp_ns)     # taken for every frame, in order
        if frame.status == "bad_image":
            self.counts["bad_messages"] += 1
            self.ledger.count("bad_pairs")
            self.note(f"stereo pair at {frame.stamp_ns} ns: {frame.reason}")
            return
        self.counts["located" if frame.status == "located" else "no_target"] += 1
        if frame.targets:
            self.pipeline.add_frame(frame.stamp_ns, frame.targets, received_ns=t_arrival,
                                    carried=True, tag=frame)

    def _forget_poses(self, stamp_ns: int) -> None:
        """Robot poses more than :data:`POSE_HISTORY_S` of stamps before the frame taken now
        leave the buffer (the newest one at or before that point stays), so that it does not
        grow with the bag (ee_pose and joint_states; a TF view keeps its own history).

        A frame still waiting in the pipeline is older, but it waits because no pose newer
        than its stamp has been read: the newest pose read is at or before its stamp, and it
        stays."""
        poses = getattr(self.localizer, "poses", None)
        forget = getattr(poses, "forget_before", None)
        if forget is not None:
            forget(stamp_ns - int(POSE_HISTORY_S * 1e9))

    def read(self, pool: _PairPool, progress: Callable[[int], object] | None,
             in_workers: bool) -> None:
        """Every message of the bag in log-time order: robot poses and ground truth into the
        pipeline, images paired and handed to ``pool``, its results taken in stamp order
        (``in_workers``: compressed chunks opened by the pool's worker processes)."""
        # local: reader only; io.bags.streams loads io.bags.mcap_chunks and io.bags.mcap_tasks
        # (~20 ms more at each `process` worker's start-up, which does not use them)
        from eye_in_hand.io.bags import typestore_for
        from eye_in_hand.io.bags.streams import decoded_stream
        from eye_in_hand.ros.geometry import point_to_xyz, pose_to_matrix
        from eye_in_hand.ros.stamps import header_stamp_ns

        path, opts, info = self.path, self.opts, self.info
        if self.typestore is None:
            self.typestore = typestore_for(path, {info.topics[t].msgtype for t in self.topics})
        source = decoded_stream(path, self.topics, self.typestore, verify_crc=opts.verify_crc,
                                damage=self.result.damage, image_topics=(opts.left_topic,
                                                                         opts.right_topic),
                                submit=pool.submit_chunks if in_workers else None)
        tf_buffer, pipeline, sync, ledger = self.tf_buffer, self.pipeline, self.sync, self.ledger
        counts, truth, note, take = self.counts, self.truth, self.note, self.take
        for topic, _t, msg in source:
            if progress is not None:
                progress(1)
            try:
                if isinstance(msg, Exception):
                    raise msg
                if tf_buffer is not None and topic in (opts.tf_topic, opts.tf_static_topic):
                    _add_tf(tf_buffer, msg, topic == opts.tf_static_topic, topic, _t, counts,
                            note)
                    pipeline.pose_arrived()
                    pipeline.drain()
                elif topic == opts.pose_topic:
                    stamp = header_stamp_ns(msg)
                    if opts.robot_pose_source == "ee_pose":
                        pipeline.add_pose(stamp, pose_to_matrix(msg.pose), received_ns=_t,
                                          checked=True)
                    else:
                        pipeline.add_joint_state(stamp, msg.name, msg.position, received_ns=_t)
                    pipeline.drain()
                elif topic == opts.ground_truth_topic:
                    truth.add(header_stamp_ns(msg), point_to_xyz(msg.point))
                elif topic in (opts.left_topic, opts.right_topic):
                    stamp = header_stamp_ns(msg)
                    left = topic == opts.left_topic
                    ledger.frame(sync, left, stamp)
                    push = sync.push_left if left else sync.push_right
                    for pair in push(stamp, msg):
                        counts["pairs"] += 1
                        ledger.submitted(pair.stamp_ns, _t)
                        pool.submit(pair)
                    for frame in pool.ready():
                        take(frame)
            except (BagError, ConversionError, InputError) as exc:
                counts["bad_messages"] += 1
                note(f"{topic} at {_t} ns: {exc}")
        for frame in pool.ready(wait=True):
            take(frame)

    def settle(self, target_names: list[str]) -> None:
        """End of bag, once every pair is located: the last waiting pairs resolved, the
        ground truth matched to the located ids."""
        from eye_in_hand.io.results import assign_truth, target_order  # local: reader only

        result, counts = self.result, self.counts
        # the pool's counts keep their place in summary.json (before the end-of-bag ones);
        # finish sets them once the pool is closed
        counts["worker_timeouts"] = counts["pairs_relocated"] = 0
        self.pipeline.flush()  # end of bag: the last points are resolved (or refused) now
        self.ledger.close(self.sync, None if self.fixed else self.localizer)
        result.target_ids = target_order(result.frames, target_names, seen=self.seen)
        result.truth_match = assign_truth(result.frames, self.truth, result.target_ids,
                                          located=self.sink.located)
        counts["ground_truth"] = len(self.truth)

    def finish(self, pool: _PairPool) -> ProcessResult:
        """After :meth:`settle` and the pool's close: the pool's counts and notes, and the
        loss total."""
        result, counts, opts = self.result, self.counts, self.opts
        frames = self.frames
        if frames.problem is not None:          # nothing lost: more memory than planned
            result.notes.append(f"{frames.problem}: {len(frames) - frames.spilled} of the "
                                f"{len(frames)} frames were kept in memory (set TMPDIR to "
                                "a folder with space)")
        result.located_in_processes = pool.in_processes
        result.workers_forked = pool.forked
        result.notes.extend(pool.notes)
        counts["worker_timeouts"] = pool.timeouts        # their pairs were located again here
        counts["pairs_relocated"] = pool.relocated
        counts["damaged_regions"] = len(result.damage)
        counts["messages_lost"] = result.damage.messages_lost
        result.loss = loss_total(counts, result.damage, (opts.left_topic, opts.right_topic))
        counts["lost"] = result.loss["total"]
        return result


def _make_localizer(opts: ProcessOptions, fixed: bool, n_poses: int, hand_eye_T: np.ndarray,
                    hand_eye_cov: np.ndarray | None,
                    pose_correction: RobotPoseCorrection | None) -> Any:
    """A fixed camera's localizer, or the hand_eye node's with a pose buffer for every robot
    pose of the bag (``n_poses``)."""
    # local: reader only (see the imports at the top)
    from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
    from eye_in_hand.core.localization import Localizer
    from eye_in_hand.core.pipeline import localizer_config

    if fixed:
        return EyeToHandLocalizer(hand_eye_T, hand_eye_cov)
    return Localizer(
        hand_eye_T, hand_eye_cov, localizer_config(
            max_pose_gap_s=opts.max_pose_gap_s, max_pose_age_s=opts.max_pose_age_s,
            pose_jump_back_s=opts.pose_jump_back_s, buffer_size=max(2, n_poses + 2),
            robot_sigma_pos_m=opts.robot_sigma_pos_m,
            robot_sigma_rot_rad=opts.robot_sigma_rot_rad),
        pose_correction=pose_correction)


class _FrameResults:
    """The pipeline's frame sink offline: each target's outcome into its
    :class:`~eye_in_hand.io.results.FrameResult`; the first target of a located pair also
    fills the frame and the counts (``localized``, ``no_robot_pose``, ``refused.<reason>``)."""

    def __init__(self, counts: dict[str, int], ledger: _Ledger) -> None:
        self._counts = counts
        self._ledger = ledger
        #: id -> the coordinates of its base-frame positions, one after the other
        self.located: dict[str, array[float]] = {}

    def target_located(self, f: WaitingFrame, target: Any, point_base: np.ndarray,
                       cov_base: np.ndarray) -> None:
        frame = f.tag
        target.status, target.point_base, target.cov_base = "ok", point_base, cov_base
        xyz = self.located.get(target.id)
        if xyz is None:
            xyz = self.located[target.id] = array("d")
        xyz.extend(point_base.tolist())
        if target is frame.targets[0] and frame.status == "located":
            frame.point_base, frame.cov_base = point_base, cov_base
            self._counts["localized"] += 1

    def target_refused(self, f: WaitingFrame, target: Any, reason: str, detail: str) -> None:
        frame = f.tag
        target.status, target.reason = "no_robot_pose", detail
        if target is frame.targets[0] and frame.status == "located":
            frame.status, frame.reason = "no_robot_pose", detail
            self._counts["no_robot_pose"] += 1
            self._ledger.refused(reason)

    def frame_done(self, f: WaitingFrame) -> None:
        frame = f.tag     # every target resolved: a frame located in the camera is done
        if frame.status == "located":
            frame.status = "ok"

    def orphan_points(self, n: int) -> None:
        pass             # the targets come with their frame: none


def _use_tf(localizer: Localizer, opts: ProcessOptions, n_messages: int) -> Any:
    """A TF buffer whose ``base_frame -> ee_frame`` chain becomes the localizer's robot pose."""
    # local: core.tf adds ~3 ms to each `process` worker's start-up; only TF robot poses
    from eye_in_hand.core.tf import TfBuffer, TfPoseView

    view = TfPoseView(TfBuffer(max(2, n_messages + 2)), opts.base_frame, opts.ee_frame,
                      jump_back_ns=int(opts.pose_jump_back_s * 1e9))
    localizer.poses = view  # type: ignore[assignment]
    return view


def _add_tf(view: Any, msg: Any, static: bool, topic: str, t_ns: int,
            counts: dict[str, int], note: Callable[[str], None]) -> None:
    """One TFMessage into the buffer (received at its log time); each bad transform counts as
    a bad message, a jump back in time as ``time_jumps``."""
    # local: ros.tf adds ~4 ms to each `process` worker's start-up; only TF robot poses
    from eye_in_hand.ros.tf import feed_tf_message

    _, problems, jumped = feed_tf_message(view, msg, static=static, received_ns=t_ns)
    if jumped:
        counts["time_jumps"] = counts.get("time_jumps", 0) + 1
    for text in problems:
        counts["bad_messages"] += 1
        note(f"{topic} at {t_ns} ns: {text}")


class _Ledger:
    """Counts every frame that does not become a result (``summary.json``'s ``counts``)::

        left_frames  = pairs + unpaired_left     (every image that entered the stereo pairing)
        right_frames = pairs + unpaired_right
        pairs        = localized + no_target + no_robot_pose + bad_pairs
        no_robot_pose = sum of refused.<reason>  (no_pose, before_buffer, no_newer_pose,
                                                  pose_gap, stale_pose)

    Images that do not decode are in ``bad_messages`` (before pairing). It also keeps each
    pair's arrival (the log time of the image that completed it): the clock of the receive-age
    rule, so the result never depends on how fast workers return pairs.
    """

    def __init__(self, counts: dict[str, int], jump_back_ns: int) -> None:
        self.counts = counts
        self.jump_back_ns = jump_back_ns
        self._arrivals: dict[int, deque[int]] = {}   # stamp -> arrivals (a replay repeats)
        for key in ("left_frames", "right_frames", "unpaired_left", "unpaired_right",
                    "bad_pairs", "refused.stale_pose", "pose_buffer_resets", "time_jumps"):
            counts.setdefault(key, 0)

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def frame(self, sync: ApproximateStereoSync, left: bool, stamp: int) -> None:
        """An image about to be pushed; a stamp far behind its side's last one restarts the
        pairing (a bag that jumps back in time), its waiting frames counted as unpaired."""
        self.count("left_frames" if left else "right_frames")
        last = sync.last_stamps[0 if left else 1]
        if last is not None and last - stamp > self.jump_back_ns:
            pl, pr = sync.pending
            self.count("unpaired_left", pl)
            self.count("unpaired_right", pr)
            sync.reset()
            self.count("time_jumps")

    def submitted(self, stamp: int, t_ns: int) -> None:
        self._arrivals.setdefault(stamp, deque()).append(t_ns)

    def arrival(self, stamp: int) -> int | None:
        """The log time at which the (oldest unfinished) pair with this stamp was complete."""
        times = self._arrivals.get(stamp)
        if not times:
            return None
        t = times.popleft()
        if not times:
            del self._arrivals[stamp]
        return t

    def refused(self, reason: str) -> None:
        self.count(f"refused.{reason}")

    def close(self, sync: ApproximateStereoSync, localizer: Localizer | None) -> None:
        """End of bag: frames still waiting for a partner are unpaired; sync drops counted."""
        pl, pr = sync.pending
        self.count("unpaired_left", sync.stats.dropped_left + pl)
        self.count("unpaired_right", sync.stats.dropped_right + pr)
        # of which: a stamp not after its side's previous one (a replay's repeated stamps)
        self.count("stale_stamp", sync.stats.dropped_stale)
        if localizer is not None:
            self.count("pose_buffer_resets", sum(localizer.poses.resets.values()))


def loss_total(counts: dict[str, int], damage: Any = None,
               image_topics: tuple[str, ...] = ()) -> dict[str, Any]:
    """The one loss total of a run: every input that did not become a result, by cause.

    ``unpaired_left``/``unpaired_right`` (images without a partner; ``stale_stamp`` ones, a
    stamp not after the previous image of their side, are among them and shown on their own
    as ``of_which_stale_stamp``), ``bad_pairs`` and ``no_robot_pose`` (pairs),
    ``bad_messages`` (other messages that do not read: an image without a valid stamp, a robot
    pose; ``counts['bad_messages']`` less the bad pairs) and ``damaged`` (images lost in damaged
    regions of the bag; ``None`` when a region's count is unknown). ``no_target`` (a pair
    looked at, with no target in view) is a result, not a loss.
    """
    by_cause = {k: int(counts.get(k, 0)) for k in (
        "unpaired_left", "unpaired_right", "bad_pairs", "no_robot_pose")}
    # bad_messages counts the bad pairs too: here only the other messages that did not read
    by_cause["bad_messages"] = int(counts.get("bad_messages", 0)) - by_cause["bad_pairs"]
    damaged: int | None = 0
    if damage is not None and len(damage):
        damaged = sum(int(n) for t, n in damage.by_topic().items() if t in image_topics)
        if getattr(damage, "unknown", 0):
            damaged = None
    total = sum(by_cause.values()) + (damaged or 0)
    return {"total": total, "by_cause": {**by_cause, "damaged": damaged},
            "of_which_stale_stamp": int(counts.get("stale_stamp", 0)),
            "complete": damaged is not None}


def _rig_from_camera_info(path: Path, opts: ProcessOptions, damage: Any = None,
                          typestore: Any = None) -> StereoRig:
    """The stereo rig from the first readable camera_info message of each side (damaged and
    undecodable ones are skipped, recorded in ``damage`` when given); ``typestore``: as for
    :func:`eye_in_hand.io.bags.deserialize` (None: the Jazzy definitions)."""
    # local: reader only (see the imports at the top); the ros message modules add ~12 ms too
    from eye_in_hand.io.bags import DamageLog, deserialize, iter_messages
    from eye_in_hand.ros.camera_info import camera_info_to_model

    infos: dict[str, Any] = {}
    log = DamageLog()           # the main pass reads these chunks again and records them
    first_error: str = ""
    for topic, msgtype, t_ns, raw in iter_messages(path, [opts.left_info_topic,
                                                          opts.right_info_topic], damage=log):
        if topic not in infos:
            try:
                infos[topic] = camera_info_to_model(deserialize(raw, msgtype, typestore))
            except (BagError, ConversionError) as exc:
                first_error = first_error or f"{topic} at {t_ns} ns: {exc}"
                if damage is not None:
                    damage.bad_message(topic, t_ns, str(exc))
        if len(infos) == 2:
            break
    if len(infos) < 2:
        missing = [t for t in (opts.left_info_topic, opts.right_info_topic) if t not in infos]
        raise BagError(f"{path}: no readable camera_info on {', '.join(missing)}"
                       + (f" (first error: {first_error})" if first_error else "")
                       + (f"; {log.summary()}" if log else ""))
    return StereoRig.from_ros_pair(infos[opts.left_info_topic], infos[opts.right_info_topic],
                                   source=f"{path} {opts.right_info_topic}")


def _locate_values(locator: StereoLocator, stamp_ns: int, left_msg: Any,
                   right_msg: Any) -> tuple[Any, ...]:
    """Locate one stereo pair; the outcome as plain values (what a worker process sends back,
    without importing the result classes): ``(stamp_ns, status, reason, targets, missing)``,
    each target ``(id, name, point, covariance, residual_px, left_px, right_px)``, the first
    target first. :func:`_frame_of` makes the :class:`FrameResult`."""
    # local: ros.images alone (not every message family's module: ~10 ms at a worker's start)
    from eye_in_hand.ros.images import image_to_numpy

    try:
        left = image_to_numpy(left_msg, desired_encoding="bgr8")
        right = image_to_numpy(right_msg, desired_encoding="bgr8")
        res = locator.locate(left, right)
    except (ConversionError, InputError) as exc:
        return (stamp_ns, "bad_image", str(exc), [], {})
    first = res.first
    targets = [(t.id, t.name, np.asarray(t.point_m), np.asarray(t.covariance),
                float(t.residual_px), np.asarray(t.left_px), np.asarray(t.right_px))
               for t in sorted(res.targets, key=lambda t: t is not first)]  # the first first
    missing = {name: res.messages.get(name, reason) for name, reason in res.rejected.items()}
    if first is None:
        return (stamp_ns, "no_target",
                res.messages.get(res.first_name, res.rejected.get(res.first_name, "")),
                targets, missing)
    return (stamp_ns, "located", "", targets, missing)


def _frame_of(values: tuple[Any, ...]) -> FrameResult:
    """The :class:`FrameResult` of :func:`_locate_values`' outcome."""
    from eye_in_hand.io.results import FrameResult, TargetResult  # local: reader only

    stamp_ns, status, reason, located, missing = values
    if status == "bad_image":
        return FrameResult(stamp_ns, "bad_image", reason)
    # every frame is kept until the outputs are written: each array copied into one that owns
    # its data (one unpickled from a worker is a view of its pickle buffer through two more
    # objects: 3.4 instead of 1.3 kB a frame of one target, with the result classes' slots),
    # ids shared between frames
    targets = [TargetResult(sys.intern(tid), sys.intern(name), np.array(point), np.array(cov),
                            residual, np.array(left), np.array(right))
               for tid, name, point, cov, residual, left, right in located]
    if status == "no_target":
        return FrameResult(stamp_ns, "no_target", reason, targets=targets, missing=missing)
    t0 = targets[0]
    return FrameResult(stamp_ns, "located", point_cam=t0.point_cam, cov_cam=t0.cov_cam,
                       residual_px=t0.residual_px, left_px=t0.left_px, right_px=t0.right_px,
                       targets=targets, missing=missing)


def _locate_pair(locator: StereoLocator, stamp_ns: int, left_msg: Any,
                 right_msg: Any) -> FrameResult:
    return _frame_of(_locate_values(locator, stamp_ns, left_msg, right_msg))


# -- worker processes ------------------------------------------------------------------------
@dataclass(frozen=True)
class _MappedImage:
    """Where an image's pixels lie in a bag file, with the fields needed to decode them."""

    path: str
    offset: int
    nbytes: int
    height: int
    width: int
    step: int
    encoding: str
    is_bigendian: int

    @classmethod
    def of(cls, msg: Any) -> _MappedImage | None:
        # local: io.bags.mcap_chunks adds ~14 ms to each `process` worker's start-up
        from eye_in_hand.io.bags.mcap_chunks import file_location

        data = getattr(msg, "data", None)
        if not isinstance(data, np.ndarray):
            return None
        where = file_location(data)
        if where is None:
            return None
        return cls(where[0], where[1], int(data.nbytes), int(msg.height), int(msg.width),
                   int(msg.step), str(msg.encoding), int(msg.is_bigendian))


class _ImageView:
    """Duck-typed ``sensor_msgs/Image`` over a mapped file (what ``image_to_numpy`` reads)."""

    def __init__(self, ref: _MappedImage, mapped: Any) -> None:
        self.height, self.width, self.step = ref.height, ref.width, ref.step
        self.encoding, self.is_bigendian = ref.encoding, ref.is_bigendian
        self.data = np.frombuffer(mapped, dtype=np.uint8, count=ref.nbytes, offset=ref.offset)


_WORKER: dict[str, Any] = {}


def _worker_init(rig: StereoRig, config: LocatorConfig) -> None:
    cv2.setNumThreads(1)      # one process per core already: no thread pools inside
    keep_freed_heap()         # chunks decompressed and freed in turn: no page faults anew
    _WORKER["locator"] = StereoLocator(rig, config)
    _WORKER["maps"] = {}


def _worker_locate(stamp_ns: int, left: _MappedImage, right: _MappedImage
                   ) -> tuple[Any, ...]:
    maps: dict[str, Any] = _WORKER["maps"]

    def view(ref: Any) -> Any:
        if not isinstance(ref, _MappedImage):
            return ref             # an image of a compressed chunk this process opened
        mapped = maps.get(ref.path)
        if mapped is None:
            with open(ref.path, "rb") as fh:
                mapped = maps[ref.path] = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        return _ImageView(ref, mapped)

    values = _locate_values(_WORKER["locator"], stamp_ns, view(left), view(right))
    for ref in (left, right):   # read once: out of the resident set (flat on a long bag)
        if isinstance(ref, _MappedImage):
            drop_pages(maps[ref.path], ref.offset, ref.nbytes)
    return values


class _PairPool:
    """Locate stereo pairs on workers, handing results back in submission order.

    * ``selection: nearest`` (each frame depends on the previous one) or one worker: in the
      calling thread.
    * Otherwise, pairs whose pixels lie in a memory-mapped bag file (uncompressed MCAP chunks)
      go to worker *processes* (:class:`eye_in_hand.workers.ProcessPool`), each with its own
      locator, which map the same file pages: no pixel is copied or pickled, and the Python
      parts of detection run truly in parallel. Other pairs (compressed chunks, sqlite3), and
      every pair until a process is up (a few tenths of a second), go to a pool of threads
      (OpenCV releases the GIL; Python does not).

    The locators keep no state between frames under these selections, so where a pair was
    located does not change its result.
    """

    def __init__(self, rig: StereoRig | None, config: LocatorConfig, workers: int,
                 task_timeout_s: float | None = 20.0) -> None:
        # local: concurrent.futures costs ~3 ms at `import eye_in_hand.offline`
        from concurrent.futures import ThreadPoolExecutor

        self._task_timeout_s = task_timeout_s
        self._rig: StereoRig | None = None
        self._config = config
        self.parallel = workers > 1 and config.detector.selection != "nearest"
        self._workers = workers if self.parallel else 1
        self._local = threading.local()
        self._inline: StereoLocator | None = None
        self._threads = (ThreadPoolExecutor(self._workers, thread_name_prefix="locate")
                         if self.parallel else None)
        self._procs: Any = None
        self._procs_waiting = False     # started, waiting for the rig (use_rig) to initialise
        self._tried_processes = False
        self.in_processes = 0
        self.relocated = 0
        self.notes: list[str] = []
        #: work for the calling thread while it waits for a worker (process_bag's ``idle``)
        self.idle: list[Callable[[], object]] = []
        self._inflight: deque[Any] = deque()
        if rig is not None:
            self.use_rig(rig)

    def use_rig(self, rig: StereoRig) -> None:
        """The rig the pairs are located with (given at construction, or once known: worker
        processes started before it are initialised with it now)."""
        if rig is self._rig:
            return
        if self._rig is not None:
            raise ValueError("_PairPool.use_rig: the pool locates with its first rig already")
        self._rig = rig
        if not self.parallel:
            self._inline = StereoLocator(rig, self._config)
        elif self._procs_waiting:
            self._procs_waiting = False
            self._procs.initialize(rig, self._config)

    @property
    def forked(self) -> bool:
        """Whether the worker processes were forked from this one (see ProcessPool's fork)."""
        return self._forked

    def start_processes(self) -> None:
        """Start the worker processes now (else: at the first pair that lies in a mapped file),
        initialised at once when the rig is known, else when it is (:meth:`use_rig`). Does
        nothing when pairs are located in the calling thread."""
        if not self.parallel or self._tried_processes:
            return
        # local: workers costs ~11 ms at `import eye_in_hand.offline`; only a process pool
        from eye_in_hand.workers import ProcessPool

        self._tried_processes = True
        try:
            self._procs = ProcessPool(self._workers, "eye_in_hand.offline:_worker_init",
                                      (self._rig, self._config),
                                      env={"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
                                      task_timeout_s=self._task_timeout_s,
                                      defer_init=self._rig is None, fork=True)
        except OSError as exc:
            self.notes.append(f"worker processes unavailable ({exc}): pairs located on threads")
            return
        self._procs_waiting = self._rig is None
        self._forked = bool(self._procs.forked)

    def _locator(self) -> StereoLocator:
        loc = getattr(self._local, "locator", None)
        if loc is None:
            assert self._rig is not None, "use_rig before locating"
            loc = self._local.locator = StereoLocator(self._rig, self._config)
        return loc

    def _work(self, pair: Any) -> FrameResult:
        return _locate_pair(self._locator(), pair.stamp_ns, pair.left, pair.right)

    def submit_chunks(self, group: int, fn: str, args: tuple[Any, ...]) -> Any:
        """Open compressed chunks (:mod:`eye_in_hand.io.bags.mcap_tasks`) on worker ``group``
        (modulo): ``(future, worker)``, or None (no worker: the caller opens them)."""
        return None if self._procs is None else self._procs.try_submit_to(group, fn, *args,
                                                                          wait_s=10.0)

    def _to_process(self, pair: Any) -> Any:
        """A process future for the pair, or None (not mapped, or no process ready)."""
        from eye_in_hand.workers import WorkerError  # local: as ProcessPool (~11 ms)

        owner = getattr(pair.left, "owner", None)    # an ImageRef: the worker that opened it
        if owner is not None and self._procs is not None:
            got = self._procs.try_submit_to(owner, "eye_in_hand.offline:_worker_locate",
                                            pair.stamp_ns, pair.left, pair.right)
            self.in_processes += got is not None
            return got and got[0]
        left = _MappedImage.of(pair.left)
        right = _MappedImage.of(pair.right) if left is not None else None
        if left is None or right is None:
            return None
        if not self._tried_processes:
            self.start_processes()
        if self._procs is None or not self._procs.ready():
            if self._procs is not None and not self._procs.alive():
                self.notes.append("worker processes exited: pairs located on threads")
                self._close_processes()
            return None
        try:
            fut = self._procs.submit("eye_in_hand.offline:_worker_locate", pair.stamp_ns, left,
                                     right)
        except WorkerError:
            return None
        self.in_processes += 1
        return fut

    def submit(self, pair: Any) -> None:
        from concurrent.futures import wait  # local: as in __init__ (~3 ms)

        if not self.parallel:
            assert self._inline is not None, "use_rig before submit"
            self._inflight.append((_locate_pair(self._inline, pair.stamp_ns, pair.left,
                                                pair.right), pair))
            return
        if len(self._inflight) >= 3 * self._workers:   # bounded: keep memory flat
            self._before_waiting(self._inflight[0][0])
            wait([self._inflight[0][0]])
        fut = self._to_process(pair)
        if fut is None:
            assert self._threads is not None
            fut = self._threads.submit(self._work, pair)
        self._inflight.append((fut, pair))

    def _before_waiting(self, fut: Any) -> None:
        """One item of :attr:`idle`, when ``fut`` is not done (the caller waits for it next)."""
        if self.idle and not fut.done():
            self.run_idle(1)

    def run_idle(self, n: int) -> None:
        """Run the first ``n`` items of :attr:`idle` (each once)."""
        for _ in range(min(n, len(self.idle))):
            self.idle.pop(0)()

    def _result(self, fut: Any, pair: Any) -> FrameResult:
        from eye_in_hand.workers import WorkerError  # local: as ProcessPool (~11 ms)

        try:
            got = fut.result()
        except WorkerError as exc:
            # a worker died (or its task failed in the worker): locate the pair here, where
            # a real problem with it raises normally
            self.in_processes -= 1
            self.relocated += 1
            if not any(n.startswith("a worker process failed") for n in self.notes):
                first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "no reason"
                self.notes.append(f"a worker process failed ({first}); its pairs were located "
                                  "again in this process")
            return self._work(pair)
        return got if not isinstance(got, tuple) else _frame_of(got)   # a worker's values

    def ready(self, wait: bool = False) -> Iterator[FrameResult]:
        """Finished results at the head of the queue (all of them with ``wait``), in order."""
        from eye_in_hand.io.results import FrameResult  # local: reader only

        while self._inflight:
            head, pair = self._inflight[0]
            if isinstance(head, FrameResult):
                self._inflight.popleft()
                yield head
            elif wait or head.done():
                self._before_waiting(head)
                self._inflight.popleft()
                yield self._result(head, pair)
            else:
                return

    @property
    def timeouts(self) -> int:
        """Worker processes killed for missing the task deadline."""
        return self._timeouts + (self._procs.timeouts if self._procs is not None else 0)

    _timeouts = 0
    _forked = False

    def _close_processes(self) -> None:
        """Close the worker processes; a note for each that ended on its own and was not
        named in a note yet (one that died between two pairs fails none of them, but the
        pass ran with one worker less from then on)."""
        self._procs.close()
        self._timeouts += self._procs.timeouts
        for pid, line in self._procs.ended():
            if not any(f"worker process {pid} " in n for n in self.notes):
                self.notes.append(f"{line} during the pass; the other workers and this "
                                  "process located the pairs left")
        self._procs = None

    def stop(self) -> None:
        """Every pair is located: the worker processes may exit (:meth:`close` waits)."""
        if self._procs is not None:
            self._procs.stop()

    def close(self) -> None:
        from eye_in_hand.io.bags.mcap_tasks import release  # local: ~14 ms, as mcap_chunks

        if self._threads is not None:
            self._threads.shutdown(wait=True, cancel_futures=True)
        if self._procs is not None:
            self._close_processes()
        release()          # chunks this process opened for pairs located here


def write_results(out: str | Path, result: ProcessResult, opts: ProcessOptions | None = None,
                  *, storage: str = "mcap", summary_extra: dict[str, Any] | None = None
                  ) -> dict[str, Path]:
    """Write ``OUT`` as a bag with ``OUT/results.csv`` and ``OUT/summary.json``
    (:func:`eye_in_hand.io.results.write_results`), the first target's ``error`` statistics
    in the summary.

    Raises:
        BagError: OUT exists or cannot be written.
    """
    from eye_in_hand.io.results import write_results as _write_results  # local: reader only

    extra = dict(summary_extra or {})
    if "error" not in extra:         # run_figures has it (the same figures)
        extra["error"] = error_stats(result.frames)
    return _write_results(out, result, opts or ProcessOptions(), storage=storage,
                          summary_extra=extra)
