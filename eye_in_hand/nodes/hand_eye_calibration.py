"""The ``hand_eye`` node's calibration mode (``mode: calibration``).

:class:`CalibrationMixin` is a part of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode`: it
subscribes the camera images and offers the services (std_srvs/Trigger) ``hand_eye/capture``
(newest image + robot pose interpolated at its stamp, refused while the robot moves),
``hand_eye/compute`` (AX = XB with every method, refined), ``hand_eye/save`` (``hand_eye.yaml``,
``report.json``, ``report.html``, the files of ``eye-in-hand calibrate handeye``) and
``hand_eye/reset``. It uses the node's config, diagnostics and robot pose buffer.
"""
from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from eye_in_hand.core.calibration import BoardSpec
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye import calibrate_hand_eye, motion_diagnostics
from eye_in_hand.core.handeye.observe import observe_sample, rig_views
from eye_in_hand.core.transforms import rotation_angle
from eye_in_hand.errors import ConfigError, ConversionError, EyeInHandError, InputError, \
    LocalizationError
from eye_in_hand.io.atomic import atomic_output_dir
from eye_in_hand.report.handeye import write_outputs
from eye_in_hand.ros.conversions import header_stamp_ns, image_to_numpy
from eye_in_hand.ros.qos import SENSOR_QOS

__all__ = ["CalibrationMixin"]


class CalibrationMixin:
    """Calibration-mode part of the ``hand_eye`` node (mixed into a ``rclpy`` ``Node``)."""

    # -- calibration ---------------------------------------------------------------------
    def _setup_calibration(self) -> None:
        cfg = self.config
        try:
            self.board = BoardSpec.parse(cfg.board)
        except EyeInHandError as exc:
            raise ConfigError(f"board: {exc}") from exc
        cdir = Path(cfg.calibration_dir)
        if (cdir / "left.yaml").exists():
            self.views = rig_views(rig=StereoRig.load(cdir))
        elif (cdir / "camera.yaml").exists():
            self.views = rig_views(camera=CameraModel.load_yaml(cdir / "camera.yaml"))
        else:
            raise ConfigError(f"calibration_dir: {cdir} has neither left.yaml + right.yaml "
                              "nor camera.yaml")
        self._images: dict[str, deque[tuple[int, Image]]] = {}
        for view in self.views:
            self._images[view.name] = deque(maxlen=10)
            topic = "image_raw" if view.name == "image" else f"{view.name}/image_raw"
            self.create_subscription(Image, topic,
                                     lambda m, name=view.name: self._on_image(name, m),
                                     SENSOR_QOS)
        self.samples: list[Any] = []
        self.skipped: list[dict[str, str]] = []
        self.result = None
        self._saved_dir: Path | None = None  # what hand_eye/save wrote (it may replace that)
        for name, cb in (("capture", self._srv_capture), ("compute", self._srv_compute),
                         ("save", self._srv_save), ("reset", self._srv_reset)):
            self.create_service(Trigger, f"hand_eye/{name}", cb)
        self.diag.gauge("samples", 0)

    def _on_image(self, name: str, msg: Image) -> None:
        try:
            stamp = header_stamp_ns(msg)
        except ConversionError as exc:
            self.diag.report("bad_image", f"{name}/image_raw: {exc}")
            return
        self._images[name].append((stamp, msg))
        self.diag.count(f"{name}_images")

    def _latest_images(self) -> tuple[int, dict[str, np.ndarray]]:
        ref = self.views[0].name
        if not self._images[ref]:
            raise InputError(f"no {ref} image received yet")
        for stamp, msg in reversed(self._images[ref]):
            images = {ref: msg}
            for view in self.views[1:]:
                match = [m for s, m in self._images[view.name] if s == stamp]
                if match:
                    images[view.name] = match[-1]
            if len(images) == len(self.views):
                break
        else:
            raise InputError("no left/right image pair with equal stamps received yet")
        decoded = {k: image_to_numpy(m, desired_encoding="bgr8" if m.encoding not in
                                     ("mono8", "mono16") else None) for k, m in images.items()}
        return stamp, decoded

    def _robot_still(self, stamp: int) -> tuple[np.ndarray, str]:
        """Robot pose at ``stamp`` and '' if still, else a reason."""
        cfg = self.config
        gap = int(cfg.max_pose_gap_s * 1e9)
        age = {"now_ns": self._now_ns(), "max_age_ns": int(cfg.max_pose_age_s * 1e9)}
        T = self.localizer.poses.lookup(stamp, gap, **age)
        w = int(cfg.still_window_s * 1e9)
        if w > 0:
            for s in (stamp - w, stamp + w):
                try:
                    Ts = self.localizer.poses.lookup(s, gap, **age)
                except LocalizationError as exc:
                    return T, f"cannot check that the robot is still: {exc}"
                dt = abs(s - stamp) / 1e9
                v = np.linalg.norm(Ts[:3, 3] - T[:3, 3]) / dt
                wv = rotation_angle(Ts[:3, :3].T @ T[:3, :3]) / dt
                if v > cfg.still_max_speed_m_s or wv > cfg.still_max_rot_speed_rad_s:
                    return T, (f"the robot is moving ({1000 * v:.1f} mm/s, "
                               f"{np.degrees(wv):.2f} deg/s): wait until it is still")
        return T, ""

    def _srv_capture(self, request: Trigger.Request, response: Trigger.Response):
        try:
            stamp, images = self._latest_images()
            base_T_ee, moving = self._robot_still(stamp)
            if moving:
                response.success, response.message = False, f"refused: {moving}"
                return response
            name = f"sample_{len(self.samples) + len(self.skipped):03d}"
            obs = observe_sample(name, images, base_T_ee, self.board, self.views)
        except (EyeInHandError, LocalizationError) as exc:
            response.success, response.message = False, f"capture failed: {exc}"
            return response
        if obs.sample is None:
            self.skipped.append({"name": name, "reason": obs.reason})
            response.success, response.message = False, f"{name} not taken: {obs.reason}"
            return response
        self.samples.append(obs.sample)
        self._update_motion_diag()
        notes = f" ({'; '.join(obs.notes)})" if obs.notes else ""
        response.success = True
        response.message = f"captured {name} at {stamp} ns: {len(self.samples)} samples{notes}"
        return response

    def _update_motion_diag(self) -> None:
        self.diag.gauge("samples", len(self.samples))
        if len(self.samples) >= 2:
            try:
                md = motion_diagnostics(np.stack([s.base_T_ee for s in self.samples]),
                                        "eye_in_hand")
                for k, v in md.to_dict().items():
                    if isinstance(v, (int, float)) and not isinstance(v, bool):
                        self.diag.gauge(f"motion.{k}", round(float(v), 4))
            except EyeInHandError as exc:
                self.diag.gauge("motion.problem", str(exc))

    def _srv_compute(self, request: Trigger.Request, response: Trigger.Response):
        try:
            self.result = calibrate_hand_eye(self.samples, "eye_in_hand", cameras=self.views)
        except EyeInHandError as exc:
            response.success, response.message = False, f"compute failed: {exc}"
            return response
        self._publish_static_tf(self.result.X)
        sel = self.result.methods[self.result.selected]
        t = self.result.X[:3, 3]
        response.success = True
        response.message = (f"{self.result.selected} from {len(self.result.sample_names)} "
                            f"samples: translation [{t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}] m, "
                            f"1-sigma {sel.std_mm:.3f} mm / {sel.std_deg:.4f} deg, "
                            f"{len(self.result.rejected)} rejected")
        return response

    def _srv_save(self, request: Trigger.Request, response: Trigger.Response):
        if self.result is None:
            response.success, response.message = False, "nothing to save: call hand_eye/compute"
            return response
        out = Path(self.config.output_dir)
        own = self._saved_dir is not None and out.absolute() == self._saved_dir
        try:  # written whole under a temporary name, then renamed into place
            with atomic_output_dir(out, overwrite=self.config.overwrite_output or own,
                                   option="parameter 'output_dir'",
                                   hint="set overwrite_output:=true to replace it") as tmp:
                paths = write_outputs(
                    tmp, self.result, self.samples, setup="eye_in_hand",
                    parent_frame=self.config.ee_frame, child_frame=self.config.camera_frame,
                    input_meta={"source": "hand_eye node", "count": len(self.samples)
                                + len(self.skipped)}, skipped=self.skipped)
        except (EyeInHandError, OSError) as exc:
            response.success, response.message = False, f"save failed: {exc}"
            return response
        self._saved_dir = out.absolute()
        response.success = True
        response.message = "wrote " + ", ".join(str(out / p.name) for p in paths)
        return response

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        n = len(self.samples)
        self.samples.clear()
        self.skipped.clear()
        self.result = None
        self.diag.gauge("samples", 0)
        response.success, response.message = True, f"forgot {n} samples"
        return response
