"""The ``hand_eye`` node's calibration mode (``mode: calibration``), see docs/handeye.md.

:class:`CalibrationMode` attaches to the node (as tf2's ``TransformListener`` does) and wires
the ROS-free :class:`eye_in_hand.core.handeye.session.CalibrationSession` to topics and
services:

* subscribes ``left/image_raw`` and ``right/image_raw`` (stereo rig) or ``image_raw`` (mono);
  a frame is a set of images with one stamp, kept undecoded until a capture uses it;
* the robot pose comes from the node (``ee_pose``, ``joint_states`` + kinematics, or ``/tf``);
* typed services (eye_in_hand_interfaces, when built): ``~/calibration/capture``,
  ``~/calibration/list_samples``, ``~/calibration/remove_sample``, ``~/calibration/compute``,
  ``~/calibration/save``, ``~/calibration/load``, ``~/calibration/get_status``;
* std_srvs/Trigger for one-line shell use: ``hand_eye/capture``, ``hand_eye/compute``,
  ``hand_eye/save``, ``hand_eye/reset``;
* ``~/calibration_status`` (CalibrationStatus, latched), ``~/next_poses`` (PoseArray of the
  suggested flange poses, latched), ``~/next_pose_markers`` (MarkerArray) and
  ``~/debug_image`` (the board's corners and axes drawn on the left image, only while someone
  subscribes, at most ``debug_image_rate_hz``).

No service blocks the executor: capture waits for its frame and robot poses as a coroutine,
and board detection, compute, planning and the debug image run on worker threads; images,
robot poses and diagnostics keep flowing meanwhile.
"""
from __future__ import annotations

import functools
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from geometry_msgs.msg import PoseArray, TransformStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.task import Future
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from eye_in_hand.core.calibration import BoardSpec, detect_board
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye import HandEyeResult
from eye_in_hand.core.handeye.observe import board_pose_pnp, rig_views
from eye_in_hand.core.handeye.plan import Plan, PlanConfig, suggest_next_poses
from eye_in_hand.core.handeye.session import (
    CalibrationSession,
    CaptureOutcome,
    SampleRecord,
    SessionConfig,
    SessionStatus,
)
from eye_in_hand.errors import ConfigError, ConversionError, EyeInHandError, InputError
from eye_in_hand.io.atomic import atomic_output_dir
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.report.handeye import write_outputs
from eye_in_hand.ros.geometry import matrix_to_pose, matrix_to_transform
from eye_in_hand.ros.images import image_to_numpy, numpy_to_image
from eye_in_hand.ros.markers import marker_classes
from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS, SENSOR_QOS
from eye_in_hand.ros.stamps import header_stamp_ns, ns_to_stamp

iface_msg: Any
iface_srv: Any
try:  # built into the venv by tools/build_interfaces.py; a colcon package on a ROS install
    from eye_in_hand_interfaces import msg as iface_msg
    from eye_in_hand_interfaces import srv as iface_srv
except ImportError:  # pragma: no cover - the Trigger services remain
    iface_msg = iface_srv = None

__all__ = ["CalibrationMode", "have_interfaces"]

#: Frames (stamps) kept while they wait for their other images or for a capture.
FRAMES_KEPT = 30


def have_interfaces() -> bool:
    """Whether eye_in_hand_interfaces is importable (the typed services exist)."""
    return iface_srv is not None


def _nan(v: float | None) -> float:
    return float("nan") if v is None else float(v)


def _cov36(cov: np.ndarray | None) -> list[float]:
    return [0.0] * 36 if cov is None else [float(v) for v in np.asarray(cov).ravel()]


def _std_from_cov(cov: np.ndarray | None) -> tuple[float, float]:
    if cov is None:
        return float("nan"), float("nan")
    c = np.asarray(cov)
    return (1000.0 * math.sqrt(max(float(np.trace(c[:3, :3])), 0.0)),
            math.degrees(math.sqrt(max(float(np.trace(c[3:, 3:])), 0.0))))


class CalibrationMode:
    """Calibration mode of the ``hand_eye`` node (see the module docstring).

    Args:
        node: the ``hand_eye`` node: its parameters (``config``), diagnostics (``diag``),
            logger, clock, robot pose source (``localizer.poses``) and static TF publisher.
        publish_static_tf: republishes the node's /tf_static with this X (or only the rest).
    """

    def __init__(self, node: Any, publish_static_tf: Callable[[np.ndarray | None], None]
                 ) -> None:
        self.node = node
        cfg = self.config = node.config
        self.diag = node.diag
        self._publish_static_tf = publish_static_tf
        try:
            self.board = BoardSpec.parse(cfg.board)
        except EyeInHandError as exc:
            raise ConfigError(f"board: {exc}") from exc
        cdir = Path(cfg.calibration_dir)
        try:
            if (cdir / "left.yaml").exists():
                self.views = rig_views(rig=StereoRig.load(cdir))
            elif (cdir / "camera.yaml").exists():
                self.views = rig_views(camera=CameraModel.load_yaml(cdir / "camera.yaml"))
            else:
                raise ConfigError(f"calibration_dir: {cdir} has neither left.yaml + right.yaml "
                                  "nor camera.yaml")
        except ConfigError:
            raise
        except EyeInHandError as exc:
            raise ConfigError(f"calibration_dir: {exc}") from exc
        try:
            self.session_config = SessionConfig(
                setup=cfg.setup, still_window_s=cfg.still_window_s,
                still_max_speed_m_s=cfg.still_max_speed_m_s,
                still_max_rot_speed_rad_s=cfg.still_max_rot_speed_rad_s,
                max_pose_gap_s=cfg.max_pose_gap_s, capture_timeout_s=cfg.capture_timeout_s,
                duplicate_translation_m=cfg.duplicate_translation_m,
                duplicate_rotation_rad=cfg.duplicate_rotation_rad,
                min_samples=cfg.min_samples, min_rotation_deg=cfg.min_rotation_deg,
                min_axis_diversity=cfg.min_axis_diversity, target_std_mm=cfg.target_std_mm,
                target_std_deg=cfg.target_std_deg, robot_model=cfg.robot_model)
        except InputError as exc:
            raise ConfigError(str(exc)) from exc
        self.session = CalibrationSession(
            self.session_config, self.board, self.views, node.localizer.poses, self._decode,
            pose_kwargs=self._pose_age_rule)
        self._lock = threading.Lock()            # the session: executor thread and workers
        # captures (board detection, next poses) and computes on their own threads: a capture
        # never waits behind a compute of several seconds
        self._work = ThreadPoolExecutor(1, thread_name_prefix="hand_eye_capture")
        self._compute_pool = ThreadPoolExecutor(1, thread_name_prefix="hand_eye_compute")
        self._debug = ThreadPoolExecutor(1, thread_name_prefix="hand_eye_debug_image")
        self._debug_busy = False
        self._debug_last = 0.0
        self._done: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._wake = node.create_guard_condition(self._run_done)
        self._waiters: dict[int, Future] = {}
        self._frames: dict[int, dict[str, Image]] = {}
        self._suggestions: tuple[np.ndarray, ...] = ()
        self._estimate: HandEyeResult | None = None     # newest estimate (status, plan)
        self._loaded: tuple[np.ndarray, np.ndarray | None, str] | None = None
        self._refresh_gen = 0
        self._saved_dir: Path | None = None   # what save wrote (it may replace that)

        resolved = []
        for view in self.views:
            topic = "image_raw" if view.name == "image" else f"{view.name}/image_raw"
            sub = node.create_subscription(Image, topic,
                                           lambda m, name=view.name: self._on_image(name, m),
                                           SENSOR_QOS)
            resolved.append(sub.topic_name)
        self.session.image_topics = ", ".join(resolved)   # refusals name the real topics
        group = ReentrantCallbackGroup()   # coroutines: one may wait while others run
        for name, cb in (("capture", self._trigger_capture), ("compute", self._trigger_compute),
                         ("save", self._trigger_save), ("reset", self._trigger_reset)):
            node.create_service(Trigger, f"hand_eye/{name}", cb, callback_group=group)
        if iface_srv is not None:
            for name, typ, cb in (
                    ("capture", iface_srv.Capture, self._srv_capture),
                    ("list_samples", iface_srv.ListSamples, self._srv_list),
                    ("remove_sample", iface_srv.RemoveSample, self._srv_remove),
                    ("compute", iface_srv.Compute, self._srv_compute),
                    ("save", iface_srv.Save, self._srv_save),
                    ("load", iface_srv.Load, self._srv_load),
                    ("get_status", iface_srv.GetStatus, self._srv_status)):
                node.create_service(typ, f"~/calibration/{name}", cb, callback_group=group)
            self.pub_status = node.create_publisher(iface_msg.CalibrationStatus,
                                                    "~/calibration_status", LATCHED_QOS)
        else:
            self.pub_status = None
            node.get_logger().warning(
                "eye_in_hand_interfaces is not installed: only the std_srvs/Trigger services "
                "(hand_eye/capture, compute, save, reset) are offered (run 'make venv')")
        self.pub_next = node.create_publisher(PoseArray, "~/next_poses", LATCHED_QOS)
        self.pub_markers = node.create_publisher(marker_classes()[1], "~/next_pose_markers",
                                                 LATCHED_QOS)
        self.pub_debug = node.create_publisher(Image, "~/debug_image", RESULT_QOS)
        node.create_timer(0.02, self.poll, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.diag.declare_counter("captures", "captures_refused")
        self.diag.gauge("samples", 0)
        self._publish_status()

    def _pose_age_rule(self, req: Any) -> dict[str, int]:
        """The receive-age rule of the capture's pose lookups: the poses may have been received
        up to ``max_pose_age_s`` before the frame's stamp (on the node's clock), however late
        the frame then arrived (a camera that renders or transfers slowly) and however long the
        capture waited for the poses after it; none may come from the clock's future."""
        now = self.node._now_ns()
        since = req.frame_received_ns if req.frame_received_ns is not None else now
        if req.frame_stamp_ns is not None:
            since = min(since, req.frame_stamp_ns)
        waited = max(now - since, 0)
        return {"now_ns": now, "max_age_ns": int(self.config.max_pose_age_s * 1e9) + waited}

    # -- frames -----------------------------------------------------------------------------
    def _on_image(self, name: str, msg: Image) -> None:
        try:
            stamp = header_stamp_ns(msg)
        except ConversionError as exc:
            self.diag.report("bad_image", f"{name}/image_raw: {exc}")
            return
        self.diag.count(f"{name}_images")
        frame = self._frames.setdefault(stamp, {})
        frame[name] = msg
        while len(self._frames) > FRAMES_KEPT:
            self._frames.pop(next(iter(self._frames)))
        if len(frame) == len(self.views):
            del self._frames[stamp]
            with self._lock:
                self.session.add_frame(stamp, frame, self.node._now_ns())
            self._maybe_debug_image(stamp, frame)
            self.poll()

    def _decode(self, frame: dict[str, Image]) -> dict[str, np.ndarray]:
        try:
            return {k: image_to_numpy(m, desired_encoding=None if m.encoding in
                                      ("mono8", "mono16") else "bgr8") for k, m in frame.items()}
        except ConversionError as exc:
            raise InputError(f"image: {exc}") from exc

    # -- worker threads -> executor ------------------------------------------------------
    def _run_done(self) -> None:
        """Guard-condition callback (executor thread): finish what the workers did."""
        while True:
            try:
                fn = self._done.get_nowait()
            except queue.Empty:
                return
            fn()

    def _submit(self, job: Callable[[], Any], then: Callable[[Any, BaseException | None], None],
                pool: ThreadPoolExecutor | None = None) -> None:
        """Run ``job`` on a worker thread (the capture one by default), then
        ``then(result, error)`` on the executor thread."""
        def run() -> None:
            try:
                res, err = job(), None
            except BaseException as exc:  # noqa: BLE001 - handed to the executor thread
                res, err = None, exc
            self._done.put(lambda: then(res, err))
            self._wake.trigger()

        (pool or self._work).submit(run)

    def shutdown(self) -> None:
        self._work.shutdown(wait=False, cancel_futures=True)
        self._compute_pool.shutdown(wait=False, cancel_futures=True)
        self._debug.shutdown(wait=False, cancel_futures=True)

    # -- capture ---------------------------------------------------------------------------
    def poll(self) -> None:
        """Answer the capture requests whose frame and robot poses are in, or that timed out."""
        if not self._waiters:
            return
        with self._lock:
            ready = self.session.ready(time.monotonic())
            # the robot poses are looked up now, while they are fresh (receive-age rule)
            checked = [(req, *self.session.check(req)) for req in ready]
        for req, base_T_ee, refused in checked:
            if refused is not None:
                self._captured(req.id, refused, None)
                continue

            def job(req: Any = req, T: Any = base_T_ee) -> CaptureOutcome:
                obs = self.session.detect(req, T)       # tens of ms: off the executor
                with self._lock:
                    return self.session.commit(req, T, obs)

            self._submit(job, functools.partial(self._captured, req.id))

    def _captured(self, rid: int, out: CaptureOutcome | None, err: BaseException | None) -> None:
        fut = self._waiters.pop(rid, None)
        if err is not None or out is None:
            out = CaptureOutcome(rid, False, "error", f"capture failed: {err}")
            self.node.get_logger().error(out.message)
        if out.ok:
            self.diag.count("captures")
            self.node.get_logger().info(out.message)
            self._refresh()
        else:
            self.diag.count("captures_refused")
            self.diag.count(f"captures_refused.{out.reason}")
            self.node.get_logger().warning(f"capture refused ({out.reason}): {out.message}")
        self.diag.gauge("samples", len(self.session.records))
        self._publish_status()
        if fut is not None and not fut.done():
            fut.set_result(out)

    async def _capture(self) -> CaptureOutcome:
        with self._lock:
            req = self.session.request_capture(time.monotonic(), self.node._now_ns())
        fut = Future()
        self._waiters[req.id] = fut
        self.poll()
        return await fut

    async def _trigger_capture(self, request: Any, response: Any) -> Any:
        out = await self._capture()
        response.success = out.ok
        response.message = out.message if out.ok else f"refused ({out.reason}): {out.message}"
        return response

    async def _srv_capture(self, request: Any, response: Any) -> Any:
        out = await self._capture()
        response.success, response.message, response.reason = out.ok, out.message, out.reason
        response.index = out.index
        if out.record is not None:
            response.sample = self._sample_msg(out.index, out.record)
        response.next_poses = self._pose_array(self._suggestions)
        return response

    # -- samples -----------------------------------------------------------------------------
    def _sample_msg(self, index: int, r: SampleRecord) -> Any:
        return iface_msg.HandEyeSample(
            index=index, name=r.sample.name, stamp=ns_to_stamp(r.stamp_ns),
            robot_pose=matrix_to_pose(r.sample.base_T_ee),
            board_pose=matrix_to_pose(r.sample.cam_T_board), corners=r.corners,
            reprojection_error_px=float(r.reprojection_px))

    def _srv_list(self, request: Any, response: Any) -> Any:
        with self._lock:
            records = list(self.session.records)
            skipped = list(self.session.skipped)
        response.samples = [self._sample_msg(i, r) for i, r in enumerate(records)]
        response.skipped = [f"{name}: {why}" for name, why in skipped]
        return response

    def _srv_remove(self, request: Any, response: Any) -> Any:
        try:
            with self._lock:
                rec = self.session.remove(index=None if request.name else int(request.index),
                                          name=request.name or None)
                n = len(self.session.records)
        except InputError as exc:
            response.success, response.message = False, str(exc)
        else:
            response.success = True
            response.message = f"removed {rec.sample.name}: {n} samples"
            self.diag.gauge("samples", n)
            self._refresh()
        response.samples = len(self.session.records)
        self._publish_status()
        return response

    def _trigger_reset(self, request: Any, response: Any) -> Any:
        with self._lock:
            n = self.session.reset()
        for fut in self._waiters.values():
            fut.set_result(CaptureOutcome(-1, False, "error", "the samples were reset"))
        self._waiters.clear()
        self._estimate, self._suggestions = None, ()
        self._refresh_gen += 1
        self.diag.gauge("samples", 0)
        self._publish_status()
        response.success, response.message = True, f"forgot {n} samples"
        return response

    # -- compute -----------------------------------------------------------------------------
    async def _compute(self) -> tuple[HandEyeResult | None, str]:
        with self._lock:
            snap = list(self.session.samples)
        fut = Future()

        def then(res: Any, err: BaseException | None) -> None:
            if err is None:
                with self._lock:
                    if [s.name for s in self.session.samples] == [s.name for s in snap]:
                        self.session.result = res
                self._estimate = res
                self._loaded = None
                self._publish_static_tf(res.X)
                self._publish_status()
                fut.set_result((res, ""))
            else:
                msg = str(err) if isinstance(err, EyeInHandError) else \
                    f"{type(err).__name__}: {err}"
                fut.set_result((None, f"compute failed: {msg}"))

        self._submit(lambda: self.session.compute(snap), then, self._compute_pool)
        return await fut

    async def _trigger_compute(self, request: Any, response: Any) -> Any:
        res, problem = await self._compute()
        if res is None:
            response.success, response.message = False, problem
            return response
        sel = res.methods[res.selected]
        t = res.X[:3, 3]
        response.success = True
        response.message = (f"{res.selected} from {len(res.sample_names)} samples: translation "
                            f"[{t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}] m, 1-sigma "
                            f"{sel.std_mm:.3f} mm / {sel.std_deg:.4f} deg, "
                            f"{len(res.rejected)} rejected")
        return response

    async def _srv_compute(self, request: Any, response: Any) -> Any:
        res, problem = await self._compute()
        if res is None:
            response.success, response.message = False, problem
            return response
        sel = res.methods[res.selected]
        response.success = True
        response.message = (f"{res.selected} from {len(res.sample_names)} samples, 1-sigma "
                            f"{sel.std_mm:.3f} mm / {sel.std_deg:.4f} deg")
        response.transform = self._transform_msg(res.X)
        response.covariance = _cov36(res.covariance)
        response.std_mm, response.std_deg = float(sel.std_mm), float(sel.std_deg)
        response.selected_method = res.selected
        response.selection_reason = res.selection_reason
        scores = []
        for name, mr in res.methods.items():
            ho = mr.held_out.summary() if mr.held_out is not None else {}
            scores.append(iface_msg.MethodScore(
                method=name, score=_nan(res.selection_scores.get(name)),
                held_out_px=_nan(ho.get("px_rms")), held_out_mm=_nan(ho.get("mm_rms")),
                std_mm=float(mr.std_mm), std_deg=float(mr.std_deg)))
        response.scores = scores
        response.rejected_samples = [f"{r.name}: {r.reason}" for r in res.rejected]
        response.warnings = list(res.warnings)
        return response

    def _transform_msg(self, X: np.ndarray) -> TransformStamped:
        cfg = self.config
        msg = TransformStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = cfg.base_frame if cfg.setup == "eye_to_hand" else cfg.ee_frame
        msg.child_frame_id = cfg.camera_frame
        msg.transform = matrix_to_transform(X)
        return msg

    # -- status, plan ------------------------------------------------------------------------
    def _refresh(self) -> None:
        """Recompute the estimate for the status and the plan (on the worker, newest only)."""
        self._refresh_gen += 1
        gen = self._refresh_gen
        with self._lock:
            snap = list(self.session.samples)
        if len(snap) < 3:
            self._estimate, self._suggestions = None, ()
            self._publish_next()
            return

        def job() -> tuple[HandEyeResult, tuple[np.ndarray, ...]] | None:
            if gen != self._refresh_gen:
                return None                       # a newer refresh is queued
            res = self.session.compute(snap)
            return res, self._plan(snap, res.X)

        def then(out: Any, err: BaseException | None) -> None:
            if gen != self._refresh_gen or out is None:
                return
            if err is not None:
                self.diag.report("estimate", f"status estimate: {err}")
                return
            self._estimate, self._suggestions = out
            self._publish_status()
            self._publish_next()

        self._submit(job, then, self._compute_pool)

    def _plan(self, samples: list[Any], X: np.ndarray) -> tuple[np.ndarray, ...]:
        cfg = self.config
        if cfg.suggest_count == 0:
            return ()
        try:
            plan: Plan = suggest_next_poses(
                samples, X, cfg.setup, self.views, config=PlanConfig(
                    count=cfg.suggest_count, robot_sigma_pos_m=cfg.robot_sigma_pos_m,
                    robot_sigma_rot_rad=cfg.robot_sigma_rot_rad))
        except EyeInHandError as exc:
            self.diag.report("plan", f"next poses: {exc}")
            return ()
        return tuple(s.base_T_ee for s in plan.suggestions)

    def _pose_array(self, poses: tuple[np.ndarray, ...]) -> PoseArray:
        msg = PoseArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = self.config.base_frame
        msg.poses = [matrix_to_pose(T) for T in poses]
        return msg

    def _publish_next(self) -> None:
        arr = self._pose_array(self._suggestions)
        self.pub_next.publish(arr)
        Marker, MarkerArray = marker_classes()
        markers = [Marker(header=arr.header, action=Marker.DELETEALL)]
        est = self._estimate
        if est is not None:   # the board where the estimate puts it (Y: base or flange frame)
            cfg = self.config
            b = self.board
            w, h = (b.cols + 1) * b.square, (b.rows + 1) * b.square
            centre = np.eye(4)
            centre[:3, 3] = [(b.cols - 1) * b.square / 2, (b.rows - 1) * b.square / 2, 0.002]
            m = Marker(header=arr.header, ns="board", id=0, type=Marker.CUBE,
                       action=Marker.ADD, pose=matrix_to_pose(est.methods[est.selected].Y
                                                              @ centre))
            m.header.frame_id = cfg.ee_frame if cfg.setup == "eye_to_hand" else cfg.base_frame
            m.scale.x, m.scale.y, m.scale.z = w, h, 0.004
            m.color.r = m.color.g = m.color.b = 0.85
            m.color.a = 0.8
            markers.append(m)
        for k, pose in enumerate(arr.poses):
            m = Marker(header=arr.header, ns="next_pose", id=k, type=Marker.ARROW,
                       action=Marker.ADD, pose=pose)
            m.scale.x, m.scale.y, m.scale.z = 0.1, 0.01, 0.01
            m.color.r, m.color.g, m.color.b, m.color.a = 0.1, 0.9 - 0.25 * k, 0.2, 1.0
            markers.append(m)
            t = Marker(header=arr.header, ns="next_pose_rank", id=k, type=Marker.TEXT_VIEW_FACING,
                       action=Marker.ADD, pose=pose, text=str(k + 1))
            t.scale.z = 0.04
            t.color.r = t.color.g = t.color.b = t.color.a = 1.0
            markers.append(t)
        self.pub_markers.publish(MarkerArray(markers=markers))

    def status(self) -> SessionStatus:
        with self._lock:
            return self.session.status(result=self._estimate, suggestions=self._suggestions)

    def _status_msg(self) -> Any:
        st = self.status()
        msg = iface_msg.CalibrationStatus(
            setup=st.setup, samples=st.samples, skipped=st.skipped, min_samples=st.min_samples,
            rotation_spread_deg=float(st.rotation_spread_deg),
            axis_spread_deg=float(st.axis_spread_deg), axis_diversity=float(st.axis_diversity),
            good_enough=st.good_enough, problems=list(st.problems),
            std_mm=float(st.std_mm), std_deg=float(st.std_deg))
        msg.stamp = self.node.get_clock().now().to_msg()
        est = None
        if st.result is not None:
            est = (st.result.X, st.result.covariance, st.result.selected)
        elif self._loaded is not None:
            est = self._loaded
            msg.std_mm, msg.std_deg = _std_from_cov(self._loaded[1])
        if est is not None:
            msg.has_estimate = True
            msg.estimate = matrix_to_transform(est[0])
            msg.covariance = _cov36(est[1])
            msg.method = est[2]
        msg.next_poses = self._pose_array(st.suggestions)
        return msg

    def _publish_status(self) -> None:
        st = None
        if self.pub_status is not None:
            msg = self._status_msg()
            self.pub_status.publish(msg)
            good, problems = msg.good_enough, list(msg.problems)
        else:
            st = self.status()
            good, problems = st.good_enough, list(st.problems)
        self.diag.gauge("good_enough", bool(good))
        self.diag.gauge("problems", "; ".join(problems))

    def _srv_status(self, request: Any, response: Any) -> Any:
        response.status = self._status_msg()
        return response

    # -- save / load ---------------------------------------------------------------------------
    def _save(self, path: str, overwrite: bool) -> tuple[bool, str, list[str]]:
        res = self.session.result
        if res is None:
            return False, ("nothing to save: call compute first (the samples changed since "
                           "the last compute)" if self._estimate is not None else
                           "nothing to save: call compute first"), []
        out = Path(path or self.config.output_dir)
        own = self._saved_dir is not None and out.absolute() == self._saved_dir
        cfg = self.config
        eye_to_hand = cfg.setup == "eye_to_hand"
        try:  # written whole under a temporary name, then renamed into place
            with atomic_output_dir(out, overwrite=overwrite or cfg.overwrite_output or own,
                                   option="the save path" if path else "parameter 'output_dir'",
                                   hint="call save with overwrite: true (or set "
                                   "overwrite_output:=true) to replace it") as tmp:
                with self._lock:
                    samples = list(self.session.samples)
                    skipped = [{"name": n, "reason": r} for n, r in self.session.skipped]
                paths = write_outputs(
                    tmp, res, samples, setup=cfg.setup,
                    parent_frame=cfg.base_frame if eye_to_hand else cfg.ee_frame,
                    child_frame=cfg.camera_frame,
                    input_meta={"source": "hand_eye node", "count": len(samples) + len(skipped)},
                    skipped=skipped)
        except (EyeInHandError, OSError) as exc:
            return False, f"save failed: {exc}", []
        self._saved_dir = out.absolute()
        files = [str(out / p.name) for p in paths]
        return True, "wrote " + ", ".join(files), files

    def _trigger_save(self, request: Any, response: Any) -> Any:
        response.success, response.message, _ = self._save("", False)
        return response

    def _srv_save(self, request: Any, response: Any) -> Any:
        response.success, response.message, response.files = self._save(request.path,
                                                                        request.overwrite)
        return response

    def _srv_load(self, request: Any, response: Any) -> Any:
        path = Path(request.path)
        if path.is_dir():
            path = path / "hand_eye.yaml"
        try:
            calib = load_hand_eye(path)
            if calib.setup != self.config.setup:
                raise ConfigError(f"{path}: setup {calib.setup}, but this node calibrates "
                                  f"{self.config.setup} (parameter 'setup')")
        except EyeInHandError as exc:
            response.success, response.message = False, f"load failed: {exc}"
            return response
        self._loaded = (calib.transform, calib.covariance, f"loaded:{calib.method}")
        self._estimate = None
        self._publish_static_tf(calib.transform)
        self._publish_status()
        response.success = True
        response.message = f"loaded {path} ({calib.method}, {calib.sample_count} samples)"
        response.transform = self._transform_msg(calib.transform)
        return response

    # -- debug image ----------------------------------------------------------------------------
    def _maybe_debug_image(self, stamp: int, frame: dict[str, Image]) -> None:
        rate = self.config.debug_image_rate_hz
        now = time.monotonic()
        if (rate <= 0 or self._debug_busy or now - self._debug_last < 1.0 / rate
                or self.pub_debug.get_subscription_count() == 0):
            return
        self._debug_busy, self._debug_last = True, now
        msg = frame[self.views[0].name]
        n = len(self.session.records)
        self._debug.submit(self._draw_debug, stamp, msg, n)

    def _draw_debug(self, stamp: int, msg: Image, n_samples: int) -> None:
        try:
            img = image_to_numpy(msg, desired_encoding="bgr8")
            view = self.views[0]
            det = detect_board(img, self.board)
            out = np.ascontiguousarray(img.copy())
            if det.found:
                cv2.drawChessboardCorners(out, (det.corners.shape[0], 1),
                                          det.corners.reshape(-1, 1, 2).astype(np.float32),
                                          True)
                T, rms = board_pose_pnp(view.model, det.object_points, det.corners)
                rvec, _ = cv2.Rodrigues(T[:3, :3])
                cv2.drawFrameAxes(out, np.asarray(view.model.K, np.float64),
                                  np.asarray(view.model.dist, np.float64), rvec, T[:3, 3],
                                  float(self.board.square) * 3, 2)
                text = f"board: {det.n_corners} corners, PnP {rms:.2f} px"
            else:
                text = f"board not found ({det.reason})"
            cv2.putText(out, f"{text} | {n_samples} samples", (10, 25),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 255, 0) if det.found else
                        (0, 0, 255), 2, cv2.LINE_AA)
            self.pub_debug.publish(numpy_to_image(out, "bgr8", stamp_ns=stamp,
                                                  frame_id=msg.header.frame_id))
        except Exception as exc:  # noqa: BLE001 - a debug image must never stop the node
            self.diag.report("debug_image", f"debug image: {exc}")
        finally:
            self._debug_busy = False
