"""The ``stereo_capture`` node: stereo pairs from the simulator, image files, videos or cameras.

Publishes (relative names):
    ``left/image_raw``, ``right/image_raw`` (sensor_msgs/Image, bgr8) and ``left/camera_info``,
    ``right/camera_info`` (sensor_msgs/CameraInfo), all four with one shared stamp per pair
    (the node clock when the pair is published). Reliable, keep last 5: matches both
    sensor-data (best effort) and reliable subscribers.
    ``joint_states`` (sensor_msgs/JointState) and ``ee_pose`` (geometry_msgs/PoseStamped,
    ``base_frame`` -> ``tool_frame``): ``sim`` source only, when ``sim.publish_robot_state``;
    stamped with the image stamp, i.e. the robot pose at which the pair was rendered.
    ``/tf`` (the arm, one transform per moving joint up to the world's tip link, at the image
    stamp) and ``/tf_static`` (its fixed ``base_frame`` -> DH base edge, and with
    ``sim.publish_stereo_tf`` the world's stereo extrinsic ``left_frame_id`` ->
    ``right_frame_id``; once, at the first pair's stamp, transient local), as
    ``robot_state_publisher`` splits them: ``sim`` source with ``sim.publish_tf``, when
    tf2_msgs is installed.
    ``diagnostics``: pairs published, read failures, frames not ready in time, source state.

Sources (parameter ``source``):
    ``sim``: the synthetic world (``sim.world`` YAML or the built-in one) along its
    localization trajectory (``sim.duration_s`` long, looping), rendered live; or, with
    ``sim.follow_joint_states``, at the latest joint vector received on
    ``sim.joint_states_topic`` (e.g. from a bag or a robot driver); a pair then carries the
    stamp of the joint state it shows (the exposure time, as a camera stamps a frame), not
    the time it was published, and a joint state is rendered at most once. While the joints
    stay exactly where the last render was made (the arm stands still), that render is
    published again at ``rate_hz`` with each new joint state's stamp, as a camera keeps
    streaming a still scene (a render takes 0.1-1 s).
    ``images``: ``images.left`` / ``images.right`` folders or glob patterns, in sorted order,
    optionally looping (``images.loop``).
    ``video``: ``video.left`` and ``video.right`` files, or one side-by-side file in
    ``video.left`` with ``side_by_side`` true (split in halves).
    ``v4l2``: ``v4l2.left`` / ``v4l2.right`` device indices or paths (or one side-by-side
    device), through ``cv2.VideoCapture``.

Frames are produced on a worker thread into a bounded drop-oldest queue (rendering a
1280x720 pair takes ~0.4 s); the timer at ``rate_hz`` only publishes the newest ready pair, so
the executor is never blocked. A source that cannot be opened stops the node at start-up with a
message naming it; a frame that cannot be read is counted and reported on ``diagnostics`` and
the node keeps going.
"""
from __future__ import annotations

import glob
import os
import queue
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.errors import ConfigError, ConversionError, EyeInHandError, InputError
from eye_in_hand.io.images import read_image_file
from eye_in_hand.ros.camera_info import model_to_camera_info
from eye_in_hand.ros.diagnostics import ERROR, WARN, NodeDiagnostics
from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.params import Param, declare_params
from eye_in_hand.ros.stamps import header_stamp_ns, make_header
from eye_in_hand.ros.tf import (
    TF_STATIC_TOPIC,
    TF_TOPIC,
    chain_tf_edges,
    have_tf2_msgs,
    make_tf_message,
    tf_message_class,
    tf_qos,
    tf_static_pub_qos,
)

if TYPE_CHECKING:  # imported where used: the simulator only loads with source: sim
    from eye_in_hand.sim.world import World

__all__ = ["NODE_PARAMETERS", "SOURCES", "StereoCaptureNode", "FrameSource", "parameter_names",
           "main"]

NODE_NAME = "stereo_capture"
SOURCES = ("sim", "images", "video", "v4l2")
_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")

#: Publisher QoS of the image and camera_info topics.
IMAGE_PUB_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)

NODE_PARAMETERS: tuple[Param, ...] = (
    Param("source", "sim", "frame source", choices=SOURCES),
    Param("rate_hz", 30.0, "publication rate of stereo pairs (Hz)", range=(0.1, 240.0)),
    Param("left_frame_id", "camera_left_optical_frame", "frame_id of the left image"),
    Param("right_frame_id", "camera_right_optical_frame", "frame_id of the right image"),
    Param("calibration_dir", "", "folder with left.yaml + right.yaml (+ stereo.yaml) for "
          "camera_info; sim: default the world's true rig"),
    Param("left_camera_info", "", "left camera_calibration_parsers YAML (overrides "
          "calibration_dir for the left camera)"),
    Param("right_camera_info", "", "right camera_calibration_parsers YAML"),
    Param("side_by_side", False, "video/v4l2: one source holding left|right side by side"),
    Param("queue_depth", 2, "frames buffered ahead of publication (drop-oldest)",
          range=(1, 30)),
    Param("images.left", "", "images source: left folder or glob pattern"),
    Param("images.right", "", "images source: right folder or glob pattern"),
    Param("images.loop", False, "images source: start again after the last pair"),
    Param("video.left", "", "video source: left file (or the side-by-side file)"),
    Param("video.right", "", "video source: right file (empty when side_by_side)"),
    Param("video.loop", False, "video source: rewind at the end"),
    Param("v4l2.left", "0", "v4l2 source: left device index or path (or side-by-side device)"),
    Param("v4l2.right", "1", "v4l2 source: right device index or path (unused when "
          "side_by_side)"),
    Param("v4l2.width", 0, "v4l2 source: requested frame width per device (0 = driver "
          "default)", range=(0, 10000)),
    Param("v4l2.height", 0, "v4l2 source: requested frame height (0 = driver default)",
          range=(0, 10000)),
    Param("sim.world", "", "sim source: world YAML (empty = built-in default world)"),
    Param("sim.width", 0, "sim source: image width (0 = the world's)", range=(0, 8192)),
    Param("sim.height", 0, "sim source: image height (0 = the world's)", range=(0, 8192)),
    Param("sim.seed", 0, "sim source: seed of the trajectory and the noise",
          range=(0, 2**31 - 1)),
    Param("sim.duration_s", 10.0, "sim source: length of the looping trajectory (s)",
          range=(0.1, 3600.0)),
    Param("sim.noise_sigma", 1.0, "sim source: sensor noise (grey levels)", range=(0.0, 50.0)),
    Param("sim.supersample", 2, "sim source: sub-pixel rays per axis on edges", range=(1, 8)),
    Param("sim.publish_robot_state", True, "sim source: also publish joint_states and "
          "ee_pose at each pair's stamp (not when following joint states)"),
    Param("sim.publish_stereo_tf", False, "sim source with sim.publish_tf: also publish the "
          "world's true stereo extrinsic (left_frame_id -> right_frame_id) on /tf_static; off "
          "by default: hand_eye publishes the calibrated one (stereo_calibration_dir), and a "
          "transform has one publisher"),
    Param("sim.publish_tf", True, "sim source: also publish the arm as "
          "robot_state_publisher would: its joints on /tf, its fixed base edge on /tf_static "
          "(needs tf2_msgs)"),
    Param("sim.follow_joint_states", False, "sim source: render at the joint vector of the "
          "latest message on sim.joint_states_topic instead of the built-in trajectory"),
    Param("sim.joint_states_topic", "joint_states", "sim source: JointState topic followed "
          "when sim.follow_joint_states"),
    Param("base_frame", "base_link", "sim source: frame of ee_pose"),
    Param("diagnostics_period_s", 1.0, "diagnostics publication period (s)",
          range=(0.05, 60.0)),
)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in NODE_PARAMETERS]


class _Pair:
    __slots__ = ("left", "right", "q", "index", "stamp_ns")

    def __init__(self, left: np.ndarray, right: np.ndarray, q: np.ndarray | None = None,
                 index: int = 0, stamp_ns: int | None = None) -> None:
        self.left, self.right, self.q, self.index = left, right, q, index
        self.stamp_ns = stamp_ns   # the time of the arm state shown (None: stamp when published)


class _ReadFailure(Exception):
    """One frame could not be read (the source stays usable)."""


class FrameSource:
    """A producer of stereo pairs. ``read()`` returns a pair, raises :class:`_ReadFailure`
    for one bad frame, or returns None at the end of a non-looping source."""

    name = "source"

    def read(self) -> _Pair | None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        """Release devices and files."""


def _list_images(spec: str, what: str) -> list[str]:
    if not spec:
        raise ConfigError(f"parameter '{what}': images source needs a folder or glob pattern")
    if os.path.isdir(spec):
        files = [str(p) for p in Path(spec).iterdir() if p.suffix.lower() in _IMAGE_EXTS]
    else:
        files = [f for f in glob.glob(spec) if os.path.isfile(f)]
    if not files:
        raise ConfigError(f"parameter '{what}': no images found at {spec!r}")
    return sorted(files)


class ImageFilesSource(FrameSource):
    """Pairs of image files, in sorted order (left i with right i)."""

    def __init__(self, left: str, right: str, loop: bool) -> None:
        self.left = _list_images(left, "images.left")
        self.right = _list_images(right, "images.right")
        if len(self.left) != len(self.right):
            raise ConfigError(f"images source: {len(self.left)} left images ({left!r}) but "
                              f"{len(self.right)} right images ({right!r})")
        self.loop = loop
        self.i = 0
        self.name = f"images {left} | {right}"

    def read(self) -> _Pair | None:
        if self.i >= len(self.left):
            if not self.loop:
                return None
            self.i = 0
        i = self.i
        self.i += 1
        imgs = []
        for path in (self.left[i], self.right[i]):
            try:
                img = read_image_file(path, cv2.IMREAD_COLOR)
            except InputError as exc:
                raise _ReadFailure(str(exc)) from exc
            imgs.append(img)
        return _Pair(imgs[0], imgs[1], index=i)


def _open_capture(spec: str, what: str, width: int = 0, height: int = 0) -> cv2.VideoCapture:
    target: int | str = int(spec) if spec.strip().isdigit() else spec
    cap = cv2.VideoCapture(target)
    if not cap.isOpened():
        raise ConfigError(f"parameter '{what}': cannot open {spec!r}")
    if width > 0:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    if height > 0:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    return cap


class CaptureSource(FrameSource):
    """Two ``cv2.VideoCapture`` streams, or one side-by-side stream split in halves."""

    def __init__(self, left: str, right: str, side_by_side: bool, *, prefix: str,
                 loop: bool = False, width: int = 0, height: int = 0) -> None:
        self.prefix = prefix
        self.loop = loop
        self.side_by_side = side_by_side
        self.caps = [_open_capture(left, f"{prefix}.left",
                                   width * (2 if side_by_side else 1), height)]
        if not side_by_side:
            if not right:
                raise ConfigError(f"parameter '{prefix}.right': needed unless side_by_side")
            try:
                self.caps.append(_open_capture(right, f"{prefix}.right", width, height))
            except ConfigError:
                self.caps[0].release()
                raise
        self.name = f"{prefix} {left}" + ("" if side_by_side else f" | {right}")
        self.index = 0

    def _grab(self) -> list[np.ndarray] | None:
        frames = []
        for cap in self.caps:  # grab both first, then retrieve: closest capture times
            if not cap.grab():
                return None
        for k, cap in enumerate(self.caps):
            ok, img = cap.retrieve()
            if not ok or img is None:
                raise _ReadFailure(f"{self.prefix}: cannot decode frame {self.index} "
                                   f"of stream {k}")
            frames.append(img)
        return frames

    def read(self) -> _Pair | None:
        frames = self._grab()
        if frames is None:
            if self.prefix == "video" and self.loop:
                for cap in self.caps:
                    cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                frames = self._grab()
            if frames is None:
                if self.prefix == "v4l2":
                    raise _ReadFailure(f"v4l2: frame {self.index} could not be grabbed")
                return None
        self.index += 1
        if self.side_by_side:
            img = frames[0]
            w = img.shape[1]
            if w % 2:
                raise _ReadFailure(f"{self.prefix}: side-by-side frame width {w} is odd")
            left, right = img[:, :w // 2], img[:, w // 2:]
        else:
            left, right = frames
        if left.ndim == 2:
            left = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
            right = cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)
        return _Pair(np.ascontiguousarray(left), np.ascontiguousarray(right),
                     index=self.index - 1)

    def close(self) -> None:
        for cap in self.caps:
            cap.release()


class _NotReady(Exception):
    """No frame can be produced yet (e.g. no joint state received); not a failure."""


class SimSource(FrameSource):
    """The synthetic world rendered along its localization trajectory (looping), or at the
    latest joint vector given to :meth:`set_joints` (``follow`` mode)."""

    def __init__(self, world: Any, rate_hz: float, duration_s: float, seed: int,
                 noise_sigma: float, supersample: int, *, follow: bool = False) -> None:
        # local: the simulator loads SciPy (~0.5 s at node start-up); only source 'sim' needs it
        from eye_in_hand.sim.scenarios import localization_trajectory

        self.world = world
        self.follow = follow
        self._lock = threading.Lock()
        self._latest: np.ndarray | None = None
        self._latest_stamp: int | None = None
        self._rendered_stamp: int | None = None
        self._cached: _Pair | None = None      # follow mode: the last render, for a still arm
        self._cached_at = 0.0
        self.period_s = 1.0 / rate_hz
        self.qs: list[np.ndarray] = []
        if not follow:
            try:
                traj = localization_trajectory(world, duration_s, rate_hz, seed)
            except EyeInHandError as exc:
                raise ConfigError(f"sim source: no trajectory ({exc})") from exc
            # ping-pong so that the loop is continuous
            qs = [q for _, q in traj]
            self.qs = qs + qs[-2:0:-1] if len(qs) > 2 else qs
        self.seed = seed
        self.noise_sigma = noise_sigma
        self.supersample = supersample
        self.i = 0
        self.name = "sim (following joint states)" if follow else "sim"

    def set_joints(self, q: np.ndarray, stamp_ns: int | None = None) -> None:
        """Follow mode: render at this joint vector from now on; ``stamp_ns`` (the joint
        state's stamp) becomes the stamp of the pair rendered from it."""
        with self._lock:
            self._latest = np.array(q, dtype=np.float64)
            self._latest_stamp = stamp_ns

    def read(self) -> _Pair:
        stamp = None
        if self.follow:
            with self._lock:
                q = None if self._latest is None else self._latest.copy()
                stamp = self._latest_stamp
            if q is None:
                raise _NotReady("no joint state received yet")
            if stamp is not None and stamp == self._rendered_stamp:
                raise _NotReady("no new joint state since the last pair")
            cached = self._cached
            if cached is not None and cached.q is not None and np.array_equal(cached.q, q):
                # the arm has not moved since the last render: the camera sees the same scene
                # (a render takes ~0.1-1 s; a real camera streams on), at the camera's rate
                now = time.monotonic()
                if now - self._cached_at < self.period_s:
                    raise _NotReady("next frame not due yet")
                self._rendered_stamp, self._cached_at = stamp, now
                k = self.i
                self.i += 1
                return _Pair(cached.left, cached.right, q=q, index=k, stamp_ns=stamp)
            self._rendered_stamp = stamp
        else:
            q = self.qs[self.i % len(self.qs)]
        k = self.i
        self.i += 1
        frame = self.world.render(q, seed=self.seed * 1_000_003 + k,
                                  noise_sigma=self.noise_sigma, supersample=self.supersample)
        pair = _Pair(frame.left, frame.right, q=q, index=k, stamp_ns=stamp)
        if self.follow:
            self._cached, self._cached_at = pair, time.monotonic()
        return pair


class StereoCaptureNode(Node):
    """Publishes stereo pairs from one source (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.cfg = declare_params(self, NODE_PARAMETERS)
        self.diag = NodeDiagnostics(self, period_s=self.cfg["diagnostics_period_s"],
                                    hardware_id=self.cfg["source"])
        self.diag.declare_counter("pairs", "read_failures", "not_ready")
        self.diag.expect_rate("pairs", min_hz=min(1.0, self.cfg["rate_hz"] / 4))
        self._world: World | None = None
        self._encoder_rng: np.random.Generator | None = None
        try:
            self.source = self._open_source()
        except BaseException:
            self.diag.destroy()
            Node.destroy_node(self)
            raise
        try:
            self.rig_models = self._load_models()
        except BaseException:
            self.source.close()
            self.diag.destroy()
            Node.destroy_node(self)
            raise
        self.pub_left = self.create_publisher(_image_type(), "left/image_raw", IMAGE_PUB_QOS)
        self.pub_right = self.create_publisher(_image_type(), "right/image_raw", IMAGE_PUB_QOS)
        self.pub_info_left = self.create_publisher(CameraInfo, "left/camera_info",
                                                   IMAGE_PUB_QOS)
        self.pub_info_right = self.create_publisher(CameraInfo, "right/camera_info",
                                                    IMAGE_PUB_QOS)
        self.pub_joints = self.pub_pose = None
        follow = self._world is not None and self.cfg["sim.follow_joint_states"]
        if follow:
            self.create_subscription(JointState, self.cfg["sim.joint_states_topic"],
                                     self._on_joint_state, 10)
        elif self._world is not None and self.cfg["sim.publish_robot_state"]:
            self.pub_joints = self.create_publisher(JointState, "joint_states", 10)
            self.pub_pose = self.create_publisher(PoseStamped, "ee_pose", 10)
        self.pub_tf: Publisher | None = None
        if self._world is not None and not follow and self.cfg["sim.publish_tf"]:
            self._setup_sim_tf()
        self._queue: queue.Queue[_Pair] = queue.Queue(maxsize=self.cfg["queue_depth"])
        self._stop = threading.Event()
        self._ended = threading.Event()
        self._worker = threading.Thread(target=self._produce, name="stereo_capture_source",
                                        daemon=True)
        self._worker.start()
        self.timer = self.create_timer(1.0 / self.cfg["rate_hz"], self._on_timer)
        self.get_logger().info(f"publishing {self.source.name} at {self.cfg['rate_hz']} Hz")

    # -- set-up ---------------------------------------------------------------------------
    def _open_source(self) -> FrameSource:
        c = self.cfg
        kind = c["source"]
        if kind == "images":
            return ImageFilesSource(c["images.left"], c["images.right"], c["images.loop"])
        if kind == "video":
            return CaptureSource(c["video.left"], c["video.right"], c["side_by_side"],
                                 prefix="video", loop=c["video.loop"])
        if kind == "v4l2":
            return CaptureSource(c["v4l2.left"], c["v4l2.right"], c["side_by_side"],
                                 prefix="v4l2", width=c["v4l2.width"], height=c["v4l2.height"])
        # local: the simulator loads SciPy (~0.5 s at node start-up); only source 'sim' needs it
        from eye_in_hand.sim.world import World

        world = World.from_yaml(c["sim.world"]) if c["sim.world"] else World.default()
        if c["sim.width"] or c["sim.height"]:
            w0, h0 = world.image_size
            world = world.with_image_size(c["sim.width"] or w0, c["sim.height"] or h0)
        self._world = world
        return SimSource(world, c["rate_hz"], c["sim.duration_s"], c["sim.seed"],
                         c["sim.noise_sigma"], c["sim.supersample"],
                         follow=c["sim.follow_joint_states"])

    def _load_models(self) -> tuple[CameraModel | None, CameraModel | None]:
        c = self.cfg
        left = right = None
        if c["calibration_dir"]:
            rig = StereoRig.load(c["calibration_dir"])
            rig = rig if rig.is_rectified else rig.rectified()
            left, right = rig.left, rig.right
        elif self._world is not None:
            rig = self._world.rig.rectified()
            left, right = rig.left, rig.right
        if c["left_camera_info"]:
            left = CameraModel.load_yaml(c["left_camera_info"])
        if c["right_camera_info"]:
            right = CameraModel.load_yaml(c["right_camera_info"])
        return left, right

    def _on_joint_state(self, msg: Any) -> None:
        names = list(msg.name)
        arm = self._world.arm  # type: ignore[union-attr]
        try:
            if names:
                index = {n: i for i, n in enumerate(names)}
                q = np.array([msg.position[index[n]] for n in arm.joint_names], dtype=float)
            else:
                q = np.array(msg.position, dtype=float)
                if q.shape != (len(arm.joint_names),):
                    raise KeyError(f"{q.size} unnamed positions")
        except (KeyError, IndexError) as exc:
            self.diag.report("bad_joint_state", f"{self.cfg['sim.joint_states_topic']}: "
                             f"joints {', '.join(arm.joint_names)} not all present ({exc})")
            return
        if not np.all(np.isfinite(q)):
            self.diag.report("bad_joint_state", "joint state with NaN or infinite positions")
            return
        try:
            stamp = header_stamp_ns(msg) or None   # an unstamped state: stamp when published
        except ConversionError:
            stamp = None
        self.source.set_joints(q, stamp)  # type: ignore[attr-defined]

    # -- worker ---------------------------------------------------------------------------
    def _produce(self) -> None:
        while not self._stop.is_set():
            try:
                pair = self.source.read()
            except _NotReady:
                self._stop.wait(0.5 / self.cfg["rate_hz"])
                continue
            except _ReadFailure as exc:
                self.diag.count("read_failures")
                self.diag.report("read_failure", str(exc))
                self._stop.wait(0.5 / self.cfg["rate_hz"])
                continue
            except Exception as exc:  # keep the node alive; say what happened
                self.diag.count("read_failures")
                self.diag.report("source_error", f"{self.source.name}: {exc!r}", level=ERROR)
                self._stop.wait(1.0 / self.cfg["rate_hz"])
                continue
            if pair is None:
                self._ended.set()
                self.diag.report("end_of_source", f"{self.source.name}: end of input",
                                 level=WARN)
                return
            while not self._stop.is_set():
                try:
                    self._queue.put(pair, timeout=0.1)
                    break
                except queue.Full:
                    continue

    # -- publication ----------------------------------------------------------------------
    def _on_timer(self) -> None:
        try:
            pair = self._queue.get_nowait()
        except queue.Empty:
            if not self._ended.is_set():
                self.diag.count("not_ready")
            return
        # a pair shows the arm at its joint state's stamp (exposure time), not when published
        stamp_ns = pair.stamp_ns if pair.stamp_ns is not None else \
            self.get_clock().now().nanoseconds
        c = self.cfg
        try:
            for img, frame_id, pub, info_pub, model in (
                    (pair.left, c["left_frame_id"], self.pub_left, self.pub_info_left,
                     self.rig_models[0]),
                    (pair.right, c["right_frame_id"], self.pub_right, self.pub_info_right,
                     self.rig_models[1])):
                header = make_header(stamp_ns, frame_id)
                msg = numpy_to_image(img, "bgr8", header=header)
                info = _camera_info(model, img, header)
                pub.publish(msg)
                info_pub.publish(info)
        except EyeInHandError as exc:
            self.diag.count("read_failures")
            self.diag.report("bad_frame", f"frame {pair.index}: {exc}")
            return
        if self.pub_joints is not None and pair.q is not None and self._world is not None:
            js = JointState()
            js.header = make_header(stamp_ns, "")
            # local: the simulator (SciPy); only source 'sim' gets here
            from eye_in_hand.sim.robot_error import reported_joints

            # the images come from the true arm; the robot reports its encoders (with noise)
            # and the nominal arm's FK of them (world.robot_error)
            err = self._world.robot_error
            if self._encoder_rng is None:
                self._encoder_rng = np.random.default_rng([c["sim.seed"], err.seed, 0x5eed])
            q_rep = reported_joints(pair.q, err, self._encoder_rng)
            js.name = list(self._world.arm.joint_names)
            js.position = [float(v) for v in q_rep]
            self.pub_joints.publish(js)
            self.pub_pose.publish(matrix_to_pose_stamped(
                self._world.arm.fk(q_rep), stamp_ns=stamp_ns, frame_id=c["base_frame"]))
            if self.pub_tf is not None:   # robot_state_publisher's view: the reported joints
                self._publish_sim_tf(q_rep, stamp_ns)
        self.diag.count("pairs")
        self.diag.gauge("source_index", int(pair.index))

    # -- sim TF (robot_state_publisher stand-in) ---------------------------------------------
    def _setup_sim_tf(self) -> None:
        """Publishers of /tf (the arm) and /tf_static (sent with the first pair)."""
        if not have_tf2_msgs():
            self.get_logger().warning("tf2_msgs is not installed: no /tf published (run "
                                      "'make venv' to build it)")
            return
        TFMessage = tf_message_class()
        assert self._world is not None
        self.pub_tf = self.create_publisher(TFMessage, TF_TOPIC, tf_qos())
        self.pub_tf_static = self.create_publisher(TFMessage, TF_STATIC_TOPIC,
                                                   tf_static_pub_qos())
        # the fixed base_frame -> DH base edge (ur_description's base_link -> base) and, when
        # asked for, the true stereo extrinsic: static, once, stamped with the first pair
        self._static_sent = False

    def _publish_sim_tf(self, q: np.ndarray, stamp_ns: int) -> None:
        """The arm's moving joints on /tf; its fixed edge (and the stereo extrinsic with
        ``sim.publish_stereo_tf``) on /tf_static at the first pair's stamp, as
        robot_state_publisher splits them."""
        assert self._world is not None and self.pub_tf is not None
        edges = chain_tf_edges(self._world.arm, q, self.cfg["base_frame"])
        arm = self._world.arm
        base = self.cfg["base_frame"] or arm.base_frame
        n_fixed = 1 if (getattr(arm, "dh_frame", "") or base) != base else 0  # chain_tf_edges
        if not self._static_sent:
            static = [(p, ch, stamp_ns, T) for p, ch, T in edges[:n_fixed]]
            if self.cfg["sim.publish_stereo_tf"]:
                static.append((self.cfg["left_frame_id"], self.cfg["right_frame_id"], stamp_ns,
                               self._world.left_T_right))
            if static:
                self.pub_tf_static.publish(make_tf_message(static))
            self._static_sent = True
        self.pub_tf.publish(make_tf_message((p, ch, stamp_ns, T) for p, ch, T in edges[n_fixed:]))

    def destroy_node(self) -> None:
        """Stop the worker and release the source before destroying the node."""
        self._stop.set()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)
        self.source.close()
        super().destroy_node()


def _image_type() -> Any:
    return Image


def _camera_info(model: CameraModel | None, img: np.ndarray, header: Any) -> Any:
    h, w = img.shape[:2]
    if model is None:  # uncalibrated: size only, as camera drivers publish it
        info = CameraInfo()
        info.header = header
        info.width, info.height = w, h
        return info
    if (model.width, model.height) != (w, h):
        raise ConfigError(f"camera_info is {model.width}x{model.height} but the image is "
                          f"{w}x{h}")
    return model_to_camera_info(model, header=header)


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand stereo_capture``."""
    run_node(NODE_NAME, StereoCaptureNode, args)


if __name__ == "__main__":
    main()
