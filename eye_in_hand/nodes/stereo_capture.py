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

The sources are :mod:`eye_in_hand.io.frame_sources` (files, videos, cameras) and
:mod:`eye_in_hand.sim.frame_source` (the simulator); the parameters are in
:mod:`~eye_in_hand.nodes.stereo_capture_params` and the ``sim`` source's robot side (robot
state, TF, followed joint states) in :mod:`~eye_in_hand.nodes.stereo_capture_sim`.
"""
from __future__ import annotations

import queue
import threading
from typing import TYPE_CHECKING, Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.errors import EyeInHandError
from eye_in_hand.io.frame_sources import (
    CaptureSource,
    FrameNotReady,
    FramePair,
    FrameReadError,
    FrameSource,
    ImageFilesSource,
)
from eye_in_hand.nodes.stereo_capture_params import NODE_PARAMETERS, parameter_names
from eye_in_hand.ros.camera_info import image_camera_info
from eye_in_hand.ros.diagnostics import ERROR, WARN, NodeDiagnostics
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.params import declare_params
from eye_in_hand.ros.stamps import make_header

if TYPE_CHECKING:  # imported where used: the simulator only loads with source: sim
    from eye_in_hand.nodes.stereo_capture_sim import SimRobotState
    from eye_in_hand.sim.world import World

__all__ = ["StereoCaptureNode", "parameter_names", "main"]

NODE_NAME = "stereo_capture"

#: Publisher QoS of the image and camera_info topics.
IMAGE_PUB_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)


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
        self.sim_robot: SimRobotState | None = None
        if self._world is not None:
            self._setup_sim_robot(self._world)
        self._queue: queue.Queue[FramePair] = queue.Queue(maxsize=self.cfg["queue_depth"])
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
        from eye_in_hand.sim.frame_source import SimSource
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

    def _setup_sim_robot(self, world: World) -> None:
        """The robot side of source 'sim': follow the joint states received, or publish the
        robot state of each pair."""
        # local: the simulator (SciPy); only source 'sim' gets here
        from eye_in_hand.nodes.stereo_capture_sim import FollowedJoints, SimRobotState

        if self.cfg["sim.follow_joint_states"]:
            self.followed_joints = FollowedJoints(
                self, world.arm.joint_names, self.cfg["sim.joint_states_topic"], self.diag,
                self.source.set_joints)  # type: ignore[attr-defined]
        else:
            self.sim_robot = SimRobotState(self, world, self.cfg)

    # -- worker ---------------------------------------------------------------------------
    def _produce(self) -> None:
        while not self._stop.is_set():
            try:
                pair = self.source.read()
            except FrameNotReady:
                self._stop.wait(0.5 / self.cfg["rate_hz"])
                continue
            except FrameReadError as exc:
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
                info = image_camera_info(model, img.shape[1], img.shape[0], header)
                pub.publish(msg)
                info_pub.publish(info)
        except EyeInHandError as exc:
            self.diag.count("read_failures")
            self.diag.report("bad_frame", f"frame {pair.index}: {exc}")
            return
        if self.sim_robot is not None and pair.q is not None:
            self.sim_robot.publish(pair.q, stamp_ns)
        self.diag.count("pairs")
        self.diag.gauge("source_index", int(pair.index))

    def destroy_node(self) -> None:
        """Stop the worker and release the source before destroying the node."""
        self._stop.set()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)
        self.source.close()
        super().destroy_node()


def _image_type() -> Any:
    return Image


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand stereo_capture``."""
    run_node(NODE_NAME, StereoCaptureNode, args)


if __name__ == "__main__":
    main()
