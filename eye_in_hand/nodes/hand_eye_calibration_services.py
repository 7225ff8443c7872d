"""The ``hand_eye`` node's calibration services (docs/handeye.md "Calibrating at a live cell").

:class:`CalibrationServices` is a part of the calibration mode
(:class:`eye_in_hand.nodes.hand_eye_calibration.CalibrationMode`), built with explicit
arguments: it offers std_srvs/Trigger ``hand_eye/capture``, ``hand_eye/compute``,
``hand_eye/save`` and ``hand_eye/reset`` (one line each, for a shell) and, when
eye_in_hand_interfaces is built, the typed ``~/calibration/capture``, ``list_samples``,
``remove_sample``, ``compute``, ``save``, ``load`` and ``get_status``; each handler turns its
request into a call of the calibration mode and its answer into the response. Capture and
compute are coroutines in a reentrant callback group: one may wait while others run.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.callback_groups import ReentrantCallbackGroup
from std_srvs.srv import Trigger

from eye_in_hand.errors import EyeInHandError, InputError
from eye_in_hand.ros.handeye_msgs import (
    fill_compute_response,
    have_interfaces,
    iface_srv,
    sample_message,
    transform_message,
)

__all__ = ["CalibrationServices"]


class CalibrationServices:
    """The calibration mode's services (see the module docstring).

    Args:
        node: the rclpy node (the services, its clock).
        config: the node's configuration (``setup``, ``base_frame``, ``ee_frame``,
            ``camera_frame``: the frames of X).
        mode: the :class:`~eye_in_hand.nodes.hand_eye_calibration.CalibrationMode` whose
            ``capture``, ``compute``, ``samples``, ``remove``, ``reset``, ``save``, ``load``,
            ``publish_status`` and ``status_message`` answer the requests.
        outputs: its :class:`~eye_in_hand.nodes.hand_eye_calibration_outputs.
            CalibrationOutputs` (the suggested poses of a capture's response).
    """

    def __init__(self, node: Any, config: Any, mode: Any, outputs: Any) -> None:
        self._clock = node.get_clock()
        self.config = config
        self.mode = mode
        self.outputs = outputs
        group = ReentrantCallbackGroup()   # coroutines: one may wait while others run
        for name, cb in (("capture", self._trigger_capture), ("compute", self._trigger_compute),
                         ("save", self._trigger_save), ("reset", self._trigger_reset)):
            node.create_service(Trigger, f"hand_eye/{name}", cb, callback_group=group)
        if have_interfaces():
            for name, typ, cb in (
                    ("capture", iface_srv.Capture, self._srv_capture),
                    ("list_samples", iface_srv.ListSamples, self._srv_list),
                    ("remove_sample", iface_srv.RemoveSample, self._srv_remove),
                    ("compute", iface_srv.Compute, self._srv_compute),
                    ("save", iface_srv.Save, self._srv_save),
                    ("load", iface_srv.Load, self._srv_load),
                    ("get_status", iface_srv.GetStatus, self._srv_status)):
                node.create_service(typ, f"~/calibration/{name}", cb, callback_group=group)

    def _transform_msg(self, X: np.ndarray) -> TransformStamped:
        """X as ``parent -> camera_frame`` (parent: ``ee_frame``, or ``base_frame``
        eye-to-hand), stamped now."""
        cfg = self.config
        return transform_message(X, self._clock.now().to_msg(), cfg.base_frame if
                                 cfg.setup == "eye_to_hand" else cfg.ee_frame, cfg.camera_frame)

    # -- capture -----------------------------------------------------------------------------
    async def _trigger_capture(self, request: Any, response: Any) -> Any:
        out = await self.mode.capture()
        response.success = out.ok
        response.message = out.message if out.ok else f"refused ({out.reason}): {out.message}"
        return response

    async def _srv_capture(self, request: Any, response: Any) -> Any:
        out = await self.mode.capture()
        response.success, response.message, response.reason = out.ok, out.message, out.reason
        response.index = out.index
        if out.record is not None:
            response.sample = sample_message(out.index, out.record)
        response.next_poses = self.outputs.pose_array(self.mode.suggestions)
        return response

    # -- samples -----------------------------------------------------------------------------
    def _srv_list(self, request: Any, response: Any) -> Any:
        records, skipped = self.mode.samples()
        response.samples = [sample_message(i, r) for i, r in enumerate(records)]
        response.skipped = [f"{name}: {why}" for name, why in skipped]
        return response

    def _srv_remove(self, request: Any, response: Any) -> Any:
        try:
            rec, n = self.mode.remove(index=None if request.name else int(request.index),
                                      name=request.name or None)
        except InputError as exc:
            response.success, response.message = False, str(exc)
        else:
            response.success = True
            response.message = f"removed {rec.sample.name}: {n} samples"
        response.samples = len(self.mode.samples()[0])
        self.mode.publish_status()
        return response

    def _trigger_reset(self, request: Any, response: Any) -> Any:
        n = self.mode.reset()
        response.success, response.message = True, f"forgot {n} samples"
        return response

    # -- compute -----------------------------------------------------------------------------
    async def _trigger_compute(self, request: Any, response: Any) -> Any:
        res, problem = await self.mode.compute()
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
        res, problem = await self.mode.compute()
        if res is None:
            response.success, response.message = False, problem
            return response
        return fill_compute_response(response, res, self._transform_msg(res.X))

    # -- status, save, load --------------------------------------------------------------------
    def _srv_status(self, request: Any, response: Any) -> Any:
        response.status = self.mode.status_message()
        return response

    def _trigger_save(self, request: Any, response: Any) -> Any:
        response.success, response.message, _ = self.mode.save("", False)
        return response

    def _srv_save(self, request: Any, response: Any) -> Any:
        response.success, response.message, response.files = self.mode.save(request.path,
                                                                             request.overwrite)
        return response

    def _srv_load(self, request: Any, response: Any) -> Any:
        try:
            path, calib = self.mode.load(request.path)
        except EyeInHandError as exc:
            response.success, response.message = False, f"load failed: {exc}"
            return response
        response.success = True
        response.message = f"loaded {path} ({calib.method}, {calib.sample_count} samples)"
        response.transform = self._transform_msg(calib.transform)
        return response
