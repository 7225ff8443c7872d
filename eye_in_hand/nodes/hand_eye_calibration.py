"""The ``hand_eye`` node's calibration mode (``mode: calibration``), see docs/handeye.md.

:class:`CalibrationMode`, a part of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode`, wires the
ROS-free :class:`eye_in_hand.core.handeye.session.CalibrationSession` to ``left/image_raw`` and
``right/image_raw`` (or mono ``image_raw``: a frame is the images of one stamp, decoded only
when a capture uses it) and to the node's robot pose; its services, topics and files are parts
of their own (:mod:`~eye_in_hand.nodes.hand_eye_calibration_services`, ``_outputs``,
``_files``). No service blocks the executor: capture waits for its frame and robot poses as a
coroutine, and board detection, compute, planning and the debug image run on worker threads
(:class:`eye_in_hand.ros.handoff.WorkerHandoff`).
"""
from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.task import Future
from sensor_msgs.msg import Image

from eye_in_hand.core.handeye import HandEyeResult
from eye_in_hand.core.handeye.session import (
    CalibrationSession,
    CaptureOutcome,
    SampleRecord,
    SessionStatus,
    receive_age_rule,
)
from eye_in_hand.errors import ConversionError, EyeInHandError, InputError
from eye_in_hand.io.config import HandEyeCalibration
from eye_in_hand.nodes.hand_eye_calibration_files import CalibrationFiles
from eye_in_hand.nodes.hand_eye_calibration_outputs import CalibrationOutputs
from eye_in_hand.nodes.hand_eye_calibration_services import CalibrationServices
from eye_in_hand.ros.handoff import WorkerHandoff
from eye_in_hand.ros.images import calibration_image
from eye_in_hand.ros.qos import SENSOR_QOS
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["CalibrationMode"]


class CalibrationMode:
    """Calibration mode of the ``hand_eye`` node (see the module docstring).

    Args:
        node: the rclpy node (subscriptions, services, publishers, timers, log).
        config: the node's configuration (:class:`~eye_in_hand.nodes.hand_eye_params.
            HandEyeNodeConfig`: the session's rules, board, cameras, frames, output folder).
        diag: the node's diagnostics.
        poses: the robot pose source (the node's localizer's ``poses``: a pose buffer, or
            the TF view).
        now_ns: the node's clock (sim time under ``use_sim_time``).
        publish_static_tf: republishes the node's /tf_static with this X (or only the rest).
    """

    def __init__(self, node: Any, config: Any, diag: Any, poses: Any,
                 now_ns: Callable[[], int],
                 publish_static_tf: Callable[[np.ndarray | None], None]) -> None:
        self._log = node.get_logger()
        cfg = self.config = config
        self.diag = diag
        self._now_ns = now_ns
        self._publish_static_tf = publish_static_tf
        self.files = CalibrationFiles(cfg)
        self.board, self.views = self.files.board_and_views()
        self.session = CalibrationSession(
            cfg.session_config(), self.board, self.views, poses, self._decode,
            pose_kwargs=lambda req: receive_age_rule(req, now_ns(), cfg.max_pose_age_s))
        self._lock = threading.Lock()            # the session: executor thread and workers
        # captures (board detection, next poses) and computes on their own threads: a capture
        # never waits behind a compute of several seconds
        self.handoff = WorkerHandoff(node, {"capture": "hand_eye_capture",
                                            "compute": "hand_eye_compute",
                                            "debug": "hand_eye_debug_image"})
        self._waiters: dict[int, Future] = {}
        self.suggestions: tuple[np.ndarray, ...] = ()   # the newest next poses and estimate
        self._estimate: HandEyeResult | None = None
        self._loaded: tuple[np.ndarray, np.ndarray | None, str] | None = None
        self._refresh_gen = 0
        resolved = []
        for view in self.views:
            topic = "image_raw" if view.name == "image" else f"{view.name}/image_raw"
            sub = node.create_subscription(Image, topic,
                                           lambda m, name=view.name: self._on_image(name, m),
                                           SENSOR_QOS)
            resolved.append(sub.topic_name)
        self.session.image_topics = ", ".join(resolved)   # refusals name the real topics
        self.outputs = CalibrationOutputs(node, cfg, diag, self.board, self.views, self.handoff)
        self.services = CalibrationServices(node, cfg, self, self.outputs)
        node.create_timer(0.02, self.poll, clock=Clock(clock_type=ClockType.STEADY_TIME))
        diag.declare_counter("captures", "captures_refused")
        diag.gauge("samples", 0)
        self.publish_status()

    # -- frames -----------------------------------------------------------------------------
    def _on_image(self, name: str, msg: Image) -> None:
        try:
            stamp = header_stamp_ns(msg)
        except ConversionError as exc:
            self.diag.report("bad_image", f"{name}/image_raw: {exc}")
            return
        self.diag.count(f"{name}_images")
        with self._lock:
            frame = self.session.add_image(name, stamp, msg, self._now_ns())
        if frame is not None:
            self.outputs.debug_image(stamp, frame, len(self.session.records))
            self.poll()

    def _decode(self, frame: dict[str, Image]) -> dict[str, np.ndarray]:
        try:
            return {k: calibration_image(m) for k, m in frame.items()}
        except ConversionError as exc:
            raise InputError(f"image: {exc}") from exc

    def shutdown(self) -> None:
        self.handoff.shutdown()

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

            self.handoff.submit("capture", job, functools.partial(self._captured, req.id))

    def _captured(self, rid: int, out: CaptureOutcome | None, err: BaseException | None) -> None:
        fut = self._waiters.pop(rid, None)
        if err is not None or out is None:
            out = CaptureOutcome(rid, False, "error", f"capture failed: {err}")
            self._log.error(out.message)
        if out.ok:
            self.diag.count("captures")
            self._log.info(out.message)
            self._refresh()
        else:
            self.diag.count("captures_refused")
            self.diag.count(f"captures_refused.{out.reason}")
            self._log.warning(f"capture refused ({out.reason}): {out.message}")
        self.diag.gauge("samples", len(self.session.records))
        self.publish_status()
        if fut is not None and not fut.done():
            fut.set_result(out)

    async def capture(self) -> CaptureOutcome:
        """Ask for a sample from the next frame; answered when its robot poses are in."""
        with self._lock:
            req = self.session.request_capture(time.monotonic(), self._now_ns())
        fut = Future()
        self._waiters[req.id] = fut
        self.poll()
        return await fut

    # -- samples -----------------------------------------------------------------------------
    def samples(self) -> tuple[list[SampleRecord], list[tuple[str, str]]]:
        """The samples taken and the captures refused ``(name, reason)``, now."""
        with self._lock:
            return list(self.session.records), list(self.session.skipped)

    def remove(self, index: int | None, name: str | None) -> tuple[SampleRecord, int]:
        """Remove one sample by index or name: it and the samples left.

        Raises:
            InputError: no such sample.
        """
        with self._lock:
            rec = self.session.remove(index=index, name=name)
            n = len(self.session.records)
        self.diag.gauge("samples", n)
        self._refresh()
        return rec, n

    def reset(self) -> int:
        """Forget every sample, estimate and waiting capture; how many samples there were."""
        with self._lock:
            n = self.session.reset()
        for fut in self._waiters.values():
            fut.set_result(CaptureOutcome(-1, False, "error", "the samples were reset"))
        self._waiters.clear()
        self._estimate, self.suggestions = None, ()
        self._refresh_gen += 1
        self.diag.gauge("samples", 0)
        self.publish_status()
        return n

    # -- compute -----------------------------------------------------------------------------
    async def compute(self) -> tuple[HandEyeResult | None, str]:
        """Solve on a snapshot of the samples (on the worker): the result, or why none."""
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
                self.publish_status()
                fut.set_result((res, ""))
            else:
                msg = str(err) if isinstance(err, EyeInHandError) else \
                    f"{type(err).__name__}: {err}"
                fut.set_result((None, f"compute failed: {msg}"))

        self.handoff.submit("compute", lambda: self.session.compute(snap), then)
        return await fut

    # -- status, plan ------------------------------------------------------------------------
    def _refresh(self) -> None:
        """Recompute the estimate for the status and the plan (on the worker, newest only)."""
        self._refresh_gen += 1
        gen = self._refresh_gen
        with self._lock:
            snap = list(self.session.samples)
        if len(snap) < 3:
            self._estimate, self.suggestions = None, ()
            self.outputs.publish_next(self.suggestions, self._estimate)
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
            self._estimate, self.suggestions = out
            self.publish_status()
            self.outputs.publish_next(self.suggestions, self._estimate)

        self.handoff.submit("compute", job, then)

    def _plan(self, samples: list[Any], X: np.ndarray) -> tuple[np.ndarray, ...]:
        try:
            return self.session.next_poses(samples, X, self.config.plan_config())
        except EyeInHandError as exc:
            self.diag.report("plan", f"next poses: {exc}")
            return ()

    def status(self) -> SessionStatus:
        with self._lock:
            return self.session.status(result=self._estimate, suggestions=self.suggestions)

    def status_message(self) -> Any:
        """CalibrationStatus now (``~/calibration/get_status``)."""
        return self.outputs.status_message(self.status(), self._loaded)

    def publish_status(self) -> None:
        self.outputs.publish_status(self.status(), self._loaded)

    # -- save / load ---------------------------------------------------------------------------
    def save(self, path: str, overwrite: bool) -> tuple[bool, str, list[str]]:
        """Write the last compute's files to ``path`` (default ``output_dir``): success, one
        line, the files (:meth:`CalibrationFiles.save`)."""
        res = self.session.result
        if res is None:
            return False, ("nothing to save: call compute first (the samples changed since "
                           "the last compute)" if self._estimate is not None else
                           "nothing to save: call compute first"), []
        records, skipped = self.samples()
        return self.files.save(path, overwrite, res, [r.sample for r in records], skipped)

    def load(self, path: str) -> tuple[Path, HandEyeCalibration]:
        """Show a saved calibration (a ``hand_eye.yaml`` or its folder) as the estimate and
        on /tf_static: the file read and its calibration.

        Raises:
            EyeInHandError: it cannot be read, or calibrates another setup.
        """
        file, calib = self.files.load(path)
        self._loaded = (calib.transform, calib.covariance, f"loaded:{calib.method}")
        self._estimate = None
        self._publish_static_tf(calib.transform)
        self.publish_status()
        return file, calib
