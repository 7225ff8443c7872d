"""Write simulated recordings: rosbag2 bags (as a real robot would record them) and on-disk
calibration datasets.

Bag topics (absolute names; message types in parentheses):

=============================== ============================================================
``/stereo/left/image_raw``      (sensor_msgs/Image, bgr8, frame ``camera_left_optical_frame``)
``/stereo/right/image_raw``     (sensor_msgs/Image, bgr8, frame ``camera_right_optical_frame``)
``/stereo/left/camera_info``    (sensor_msgs/CameraInfo, the true rig, rectified R and P)
``/stereo/right/camera_info``   (sensor_msgs/CameraInfo; right P carries -fx * baseline)
``/joint_states``               (sensor_msgs/JointState, robot rate, own stamps)
``/ee_pose``                    (geometry_msgs/PoseStamped, ``base_link`` -> ``tool0``)
``/tf``                         (tf2_msgs/TFMessage: the arm's DH link chain base ->
                                shoulder_link -> ... -> wrist_2_link -> tool0, robot rate)
``/tf_static``                  (tf2_msgs/TFMessage, once: base_link -> base (Rz(pi), as
                                ur_description) and camera_left_optical_frame ->
                                camera_right_optical_frame, the stereo extrinsic)
``/ground_truth/target``        (geometry_msgs/PointStamped in ``base_link``, one per target
                                per image, in ``world.targets`` order, at the image stamp)
``/ground_truth/hand_eye``      (geometry_msgs/TransformStamped tool0 ->
                                camera_left_optical_frame, once at the start)
``/ground_truth/board``         (geometry_msgs/PoseStamped of the board frame in base_link,
                                once at the start)
``/ground_truth/ee_pose``       (geometry_msgs/PoseStamped base_link -> tool0 of the TRUE arm
                                when the image was taken, one per image, at the image stamp)
``/ground_truth/ee_pose_reported`` (geometry_msgs/PoseStamped: what the robot reports at the
                                image stamp: the nominal FK of the reported joints
                                interpolated there)
=============================== ============================================================

Images at ``image_rate_hz`` (30 Hz) with one shared stamp per pair; robot topics at
``robot_rate_hz`` (125 Hz) on their own clock, offset from the image clock, as on a real robot.
The joint vector at an image stamp is the linear interpolation of the robot samples around it.
The tool pose never needs ``/tf_static``: ``/tf`` ends at ``tool0``.

Robot error (``world.robot_error``, :mod:`eye_in_hand.sim.robot_error`): the images come from
the true arm (``world.true_arm``) at the true joints; ``/joint_states`` carry the true joints
plus encoder noise, ``/ee_pose`` and ``/tf`` the nominal arm's FK of those; an image stamped t
shows the arm at ``t + time_offset_s``.
"""
from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.typesys import Stores, get_typestore

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.transforms import to_xyz_quat
from eye_in_hand.errors import InputError
from eye_in_hand.io.bags import BagWriter, OfferedQos
from eye_in_hand.io.images import write_image_file
from eye_in_hand.sim.robot_error import reported_joints
from eye_in_hand.sim.scenarios import (
    calibration_poses,
    calibration_timeline,
    localization_trajectory,
)
from eye_in_hand.sim.world import World, pose_to_dict

__all__ = [
    "TOPICS",
    "FRAMES",
    "RenderOptions",
    "BagSummary",
    "write_bag",
    "recording_counts",
    "write_dataset",
    "joint_samples",
]

#: Topic names written to simulated bags.
TOPICS: dict[str, str] = {
    "left_image": "/stereo/left/image_raw",
    "right_image": "/stereo/right/image_raw",
    "left_info": "/stereo/left/camera_info",
    "right_info": "/stereo/right/camera_info",
    "joint_states": "/joint_states",
    "ee_pose": "/ee_pose",
    "tf": "/tf",
    "tf_static": "/tf_static",
    "gt_target": "/ground_truth/target",
    "gt_hand_eye": "/ground_truth/hand_eye",
    "gt_board": "/ground_truth/board",
    "gt_ee_pose": "/ground_truth/ee_pose",
    "gt_ee_pose_reported": "/ground_truth/ee_pose_reported",
}

#: Frame ids used in simulated bags.
FRAMES: dict[str, str] = {
    "base": "base_link",
    "tool": "tool0",
    "left": "camera_left_optical_frame",
    "right": "camera_right_optical_frame",
}

# images offered reliable (as stereo_capture and most camera drivers): every subscriber matches
_SENSOR_QOS = (OfferedQos("reliable", "volatile", "keep_last", 5),)
_LATCHED = (OfferedQos("reliable", "transient_local", "keep_last", 1),)
_RELIABLE = (OfferedQos("reliable", "volatile", "keep_last", 100),)
#: The topics of a simulated bag, in the order they are added: (key of TOPICS, type, QoS).
_BAG_TOPICS: tuple[tuple[str, str, tuple[OfferedQos, ...]], ...] = (
    ("left_image", "sensor_msgs/msg/Image", _SENSOR_QOS),
    ("right_image", "sensor_msgs/msg/Image", _SENSOR_QOS),
    ("left_info", "sensor_msgs/msg/CameraInfo", _SENSOR_QOS),
    ("right_info", "sensor_msgs/msg/CameraInfo", _SENSOR_QOS),
    ("joint_states", "sensor_msgs/msg/JointState", _RELIABLE),
    ("ee_pose", "geometry_msgs/msg/PoseStamped", _RELIABLE),
    ("tf", "tf2_msgs/msg/TFMessage", _RELIABLE),
    ("tf_static", "tf2_msgs/msg/TFMessage", _LATCHED),
    ("gt_target", "geometry_msgs/msg/PointStamped", _RELIABLE),
    ("gt_hand_eye", "geometry_msgs/msg/TransformStamped", _LATCHED),
    ("gt_board", "geometry_msgs/msg/PoseStamped", _LATCHED),
    ("gt_ee_pose", "geometry_msgs/msg/PoseStamped", _RELIABLE),
    ("gt_ee_pose_reported", "geometry_msgs/msg/PoseStamped", _RELIABLE))

_IMAGE_CLOCK_OFFSET_NS = 3_100_000  # the camera clock is not aligned with the robot clock


@dataclass(frozen=True)
class RenderOptions:
    """Image formation options passed to :meth:`World.render`."""

    noise_sigma: float = 1.0
    supersample: int = 3
    blur_sigma: float = 0.0
    exposure: float = 1.0


@dataclass(frozen=True)
class BagSummary:
    """What :func:`write_bag` wrote."""

    path: Path
    n_images: int
    n_robot: int
    duration_s: float
    counts: dict[str, int]


# -- rosbags message builders --------------------------------------------------------------------
class _Msgs:
    def __init__(self, store: Any) -> None:
        self.t = store.types

    def time(self, ns: int) -> Any:
        return self.t["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000),
                                                     nanosec=int(ns % 1_000_000_000))

    def header(self, ns: int, frame: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=self.time(ns), frame_id=frame)

    def image(self, img: np.ndarray, ns: int, frame: str) -> Any:
        h, w = img.shape[:2]
        return self.t["sensor_msgs/msg/Image"](
            header=self.header(ns, frame), height=h, width=w, encoding="bgr8",
            is_bigendian=0, step=w * 3, data=np.ascontiguousarray(img).reshape(-1))

    def camera_info(self, cam: Any, ns: int, frame: str) -> Any:
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                         width=0, do_rectify=False)
        return self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(ns, frame), height=cam.height, width=cam.width,
            distortion_model=cam.distortion_model, d=np.asarray(cam.dist, float).copy(),
            k=np.asarray(cam.K, float).reshape(9).copy(),
            r=np.asarray(cam.R, float).reshape(9).copy(),
            p=np.asarray(cam.P, float).reshape(12).copy(), binning_x=0, binning_y=0, roi=roi)

    def pose(self, T: np.ndarray) -> Any:
        xyz, q = to_xyz_quat(T)
        return self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))

    def pose_stamped(self, T: np.ndarray, ns: int, frame: str) -> Any:
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(ns, frame),
                                                       pose=self.pose(T))

    def transform_stamped(self, T: np.ndarray, ns: int, parent: str, child: str) -> Any:
        xyz, q = to_xyz_quat(T)
        tr = self.t["geometry_msgs/msg/Transform"](
            translation=self.t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
        return self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(ns, parent), child_frame_id=child, transform=tr)

    def tf(self, transforms: list[Any]) -> Any:
        return self.t["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def joint_state(self, names: Sequence[str], q: np.ndarray, dq: np.ndarray, ns: int) -> Any:
        return self.t["sensor_msgs/msg/JointState"](
            header=self.header(ns, ""), name=list(names), position=np.asarray(q, float).copy(),
            velocity=np.asarray(dq, float).copy(), effort=np.zeros(0))

    def point_stamped(self, xyz: np.ndarray, ns: int, frame: str) -> Any:
        return self.t["geometry_msgs/msg/PointStamped"](
            header=self.header(ns, frame),
            point=self.t["geometry_msgs/msg/Point"](x=float(xyz[0]), y=float(xyz[1]),
                                                    z=float(xyz[2])))


# -- trajectories --------------------------------------------------------------------------------
def joint_samples(world: World, scenario: str, *, frames: int, seed: int,
                  robot_rate_hz: float = 125.0, hold_frames: int = 3,
                  image_rate_hz: float = 30.0, move_s: float = 1.2, settle_s: float = 0.25,
                  duration_s: float | None = None) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Robot samples of a scenario.

    Args:
        scenario: ``"calibration"`` (``frames`` still poses; at each the arm rests
            ``settle_s``, then ``hold_frames`` image periods, then ``settle_s`` again;
            ``move_s`` between poses) or ``"localization"`` (``frames`` images worth of
            continuous motion, or ``duration_s`` seconds).

    Returns:
        ``(stamps_ns, q (K, 6), still (K,) bool)``.
    """
    if scenario == "calibration":
        poses = calibration_poses(world, frames, seed)
        if settle_s < 0:
            raise InputError(f"settle_s must be >= 0, got {settle_s}")
        hold_s = (hold_frames + 0.5) / image_rate_hz + 2.0 * settle_s
        tl = calibration_timeline(poses, hold_s=hold_s, move_s=move_s, rate_hz=robot_rate_hz)
        return ([t for t, _, _ in tl], np.array([q for _, q, _ in tl]),
                np.array([s for _, _, s in tl], dtype=bool))
    if scenario == "localization":
        dur = duration_s if duration_s is not None else frames / image_rate_hz
        traj = localization_trajectory(world, dur, robot_rate_hz, seed)
        return ([t for t, _ in traj], np.array([q for _, q in traj]),
                np.zeros(len(traj), dtype=bool))
    raise InputError(f"unknown scenario {scenario!r} (use calibration or localization)")


def _interp_q(stamps: np.ndarray, qs: np.ndarray, t_ns: int) -> tuple[np.ndarray, bool]:
    i = int(np.searchsorted(stamps, t_ns, side="right")) - 1
    if i < 0 or i >= len(stamps) - 1:
        return qs[min(max(i, 0), len(stamps) - 1)].copy(), False
    s = (t_ns - stamps[i]) / (stamps[i + 1] - stamps[i])
    return qs[i] + (qs[i + 1] - qs[i]) * s, True


def _image_stamps(stamps: np.ndarray, still: np.ndarray, *, scenario: str, frames: int,
                  settle_s: float, image_rate_hz: float,
                  still_images_only: bool) -> list[int]:
    """Stamps of the stereo pairs of a recording whose robot samples are ``stamps``
    (``still``: the arm holds a pose)."""
    # settled windows: [start + settle, end - settle] of every run of still samples
    settle_ns = int(round(settle_s * 1e9))
    windows = []
    k = 0
    while k < len(still):
        if still[k]:
            j = k
            while j + 1 < len(still) and still[j + 1]:
                j += 1
            windows.append((int(stamps[k]) + settle_ns, int(stamps[j]) - settle_ns))
            k = j + 1
        else:
            k += 1
    img_period = int(round(1e9 / image_rate_hz))
    img_stamps = []
    t = int(stamps[0]) + _IMAGE_CLOCK_OFFSET_NS
    while t <= stamps[-1]:
        settled = any(a <= t <= b for a, b in windows)
        if not still_images_only or scenario != "calibration" or settled:
            img_stamps.append(t)
        t += img_period
    if scenario == "localization":
        img_stamps = img_stamps[:frames]
    return img_stamps


def recording_counts(scenario: str, frames: int, *, hold_frames: int = 3, move_s: float = 1.2,
                     settle_s: float = 0.25, still_images_only: bool = False,
                     robot_rate_hz: float = 125.0,
                     image_rate_hz: float = 30.0) -> tuple[int, int]:
    """``(stereo pairs, robot samples)`` that :func:`write_bag` writes for these options,
    without solving a pose or rendering (the time line does not depend on the poses)."""
    if scenario == "calibration":
        hold_s = (hold_frames + 0.5) / image_rate_hz + 2.0 * settle_s
        tl = calibration_timeline([np.zeros(6)] * frames, hold_s=hold_s, move_s=move_s,
                                  rate_hz=robot_rate_hz)
        stamps = np.array([t for t, _, _ in tl], dtype=np.int64)
        still = np.array([s for _, _, s in tl], dtype=bool)
        pairs = len(_image_stamps(stamps, still, scenario=scenario, frames=frames,
                                  settle_s=settle_s, image_rate_hz=image_rate_hz,
                                  still_images_only=still_images_only))
        return pairs, len(stamps)
    return frames, max(1, int(round(frames / image_rate_hz * robot_rate_hz)) + 1)


def write_bag(world: World, out: str | Path, *, scenario: str, frames: int, seed: int = 0,
              storage: str = "mcap", render: RenderOptions = RenderOptions(),
              image_rate_hz: float = 30.0, robot_rate_hz: float = 125.0,
              hold_frames: int = 3, move_s: float = 1.2, settle_s: float = 0.25,
              still_images_only: bool = False, ee_pose: bool = True,
              start_ns: int = 1_700_000_000_000_000_000,
              progress: Callable[[int, int], None] | None = None) -> BagSummary:
    """Simulate a scenario and record it as a rosbag2 bag (zstd-compressed chunks).

    Args:
        world: the world.
        out: bag directory to create (must not exist).
        scenario: ``"calibration"`` or ``"localization"``.
        frames: calibration: number of still poses; localization: number of image pairs.
        seed: seed of poses/trajectory and of the sensor noise.
        storage: ``"mcap"`` or ``"sqlite3"``.
        render: image formation options.
        image_rate_hz, robot_rate_hz: stream rates.
        hold_frames: calibration: image periods of the settled part of each stop.
        move_s: calibration: seconds per move between poses.
        settle_s: calibration: the arm also rests this long before and after those frames.
        still_images_only: calibration: record only the ``hold_frames`` settled images of
            each stop (no images while moving or settling; a much smaller bag).
        ee_pose: write ``/ee_pose``; False records the robot as a real cell does (``/tf``,
            ``/tf_static``, ``/joint_states`` only).
        start_ns: stamp of the first robot sample.
        progress: called with (images done, images total) after each image pair.

    Returns:
        A :class:`BagSummary`.

    Raises:
        InputError: bad arguments. KinematicsError: no reachable scenario for this seed.
        BagError: the bag cannot be written.
    """
    if frames < 1:
        raise InputError(f"frames must be >= 1, got {frames}")
    if image_rate_hz <= 0 or robot_rate_hz <= 0:
        raise InputError("image_rate_hz and robot_rate_hz must be positive")
    stamps_l, qs, still = joint_samples(world, scenario, frames=frames, seed=seed,
                                        robot_rate_hz=robot_rate_hz, hold_frames=hold_frames,
                                        image_rate_hz=image_rate_hz, move_s=move_s,
                                        settle_s=settle_s)
    stamps = np.array(stamps_l, dtype=np.int64) + start_ns
    img_stamps = _image_stamps(stamps, still, scenario=scenario, frames=frames,
                               settle_s=settle_s, image_rate_hz=image_rate_hz,
                               still_images_only=still_images_only)

    rig = world.rig.rectified()
    err = world.robot_error
    # encoder noise: its own stream, so that the images' noise and the poses do not change
    qs_rep = reported_joints(qs, err, np.random.default_rng([seed, err.seed, 0x5eed]))
    store = get_typestore(Stores.ROS2_JAZZY)
    writer = BagWriter(out, storage=storage, compression="zstd",
                       typestore=store)
    with writer:
        m = _Msgs(store)
        for key, typ, qos in _BAG_TOPICS:
            if key == "ee_pose" and not ee_pose:
                continue
            writer.add_topic(TOPICS[key], typ, qos=qos)
        _write_static(writer, m, world, int(stamps[0]))
        _write_robot(writer, m, world, stamps, qs_rep, robot_rate_hz, ee_pose)
        _write_images(writer, m, world, rig, stamps, qs, qs_rep, img_stamps, seed=seed,
                      render=render, progress=progress)
        counts = writer.counts
    return BagSummary(path=Path(out), n_images=len(img_stamps), n_robot=len(stamps),
                      duration_s=(int(stamps[-1]) - int(stamps[0])) / 1e9, counts=counts)


def _write_static(writer: BagWriter, m: _Msgs, world: World, t0: int) -> None:
    """The latched messages at the first stamp: /tf_static and the true hand-eye and board."""
    arm = world.arm
    static = [m.transform_stamped(world.left_T_right, t0, FRAMES["left"], FRAMES["right"])]
    if arm.dh_frame != arm.base_frame:    # ur_description: base_link -> base, Rz(pi)
        static.insert(0, m.transform_stamped(np.array(arm.base_T_dh), t0, arm.base_frame,
                                             arm.dh_frame))
    writer.write(TOPICS["tf_static"], t0, m.tf(static))
    writer.write(TOPICS["gt_hand_eye"], t0, m.transform_stamped(
        world.ee_T_cam, t0, FRAMES["tool"], FRAMES["left"]))
    writer.write(TOPICS["gt_board"], t0, m.pose_stamped(world.base_T_board, t0,
                                                        arm.base_frame))


def _write_robot(writer: BagWriter, m: _Msgs, world: World, stamps: np.ndarray,
                 qs_rep: np.ndarray, robot_rate_hz: float, ee_pose: bool) -> None:
    """The robot streams at every sample: the reported joints (velocities by central
    differences), their /tf chain and (``ee_pose``) the reported flange pose."""
    arm = world.arm
    dt = 1.0 / robot_rate_hz
    frames_names = (arm.dh_frame, *arm.link_names)
    for k, (ns, q) in enumerate(zip(stamps, qs_rep, strict=True)):
        ns = int(ns)
        k0, k1 = max(k - 1, 0), min(k + 1, len(qs_rep) - 1)
        dq = (qs_rep[k1] - qs_rep[k0]) / (max(k1 - k0, 1) * dt)
        writer.write(TOPICS["joint_states"], ns, m.joint_state(arm.joint_names, q, dq, ns))
        link_T = arm.joint_transforms(q)
        writer.write(TOPICS["tf"], ns, m.tf([
            m.transform_stamped(A, ns, frames_names[i], frames_names[i + 1])
            for i, A in enumerate(link_T)]))
        if ee_pose:
            writer.write(TOPICS["ee_pose"], ns, m.pose_stamped(arm.fk(q), ns,
                                                               arm.base_frame))


def _write_images(writer: BagWriter, m: _Msgs, world: World, rig: StereoRig, stamps: np.ndarray,
                  qs: np.ndarray, qs_rep: np.ndarray, img_stamps: Sequence[int], *, seed: int,
                  render: RenderOptions, progress: Callable[[int, int], None] | None) -> None:
    """Each stereo pair rendered from the true arm when exposed, with its camera_info and the
    ground truth at its stamp (the targets, the true and the reported flange pose)."""
    arm = world.arm
    offset_ns = int(round(world.robot_error.time_offset_s * 1e9))
    for n_img, ns in enumerate(img_stamps):
        q, _ = _interp_q(stamps, qs, ns + offset_ns)   # the true arm when exposed
        q_rep, _ = _interp_q(stamps, qs_rep, ns)         # what the robot reports at ns
        frame = world.render(q, seed=seed * 1_000_003 + n_img,
                             noise_sigma=render.noise_sigma,
                             supersample=render.supersample, blur_sigma=render.blur_sigma,
                             exposure=render.exposure)
        writer.write(TOPICS["left_image"], ns, m.image(frame.left, ns, FRAMES["left"]))
        writer.write(TOPICS["right_image"], ns, m.image(frame.right, ns, FRAMES["right"]))
        writer.write(TOPICS["left_info"], ns, m.camera_info(rig.left, ns, FRAMES["left"]))
        writer.write(TOPICS["right_info"], ns, m.camera_info(rig.right, ns,
                                                             FRAMES["right"]))
        for c in frame.truth.targets_base:
            writer.write(TOPICS["gt_target"], ns, m.point_stamped(c, ns, arm.base_frame))
        writer.write(TOPICS["gt_ee_pose"], ns, m.pose_stamped(frame.truth.base_T_ee, ns,
                                                              arm.base_frame))
        writer.write(TOPICS["gt_ee_pose_reported"], ns,
                     m.pose_stamped(arm.fk(q_rep), ns, arm.base_frame))
        if progress is not None:
            progress(n_img + 1, len(img_stamps))


def write_dataset(world: World, out: str | Path, *, frames: int, seed: int = 0,
                  render: RenderOptions = RenderOptions(), overwrite: bool = False,
                  progress: Callable[[int, int], None] | None = None) -> Path:
    """Write an on-disk stereo calibration dataset of ``frames`` still poses.

    Layout (paths relative to ``out``)::

        dataset.yaml        setup, board spec, camera files, samples, ground_truth
        left.yaml right.yaml stereo.yaml   the true rig (camera_calibration_parsers YAML)
        left/0000.png ...   right/0000.png ...

    Returns:
        The path of ``dataset.yaml``.

    Raises:
        InputError: ``out`` exists and is not empty (unless ``overwrite``), or frames < 1.
        KinematicsError: fewer reachable poses than asked.
    """
    root = Path(out)
    if frames < 1:
        raise InputError(f"frames must be >= 1, got {frames}")
    if root.exists() and any(root.iterdir()):
        if not overwrite:
            raise InputError(f"dataset folder {root} exists and is not empty")
        shutil.rmtree(root)
    poses = calibration_poses(world, frames, seed)
    err = world.robot_error
    poses_rep = reported_joints(np.array(poses), err,
                                np.random.default_rng([seed, err.seed, 0x5eed]))
    (root / "left").mkdir(parents=True, exist_ok=True)
    (root / "right").mkdir(parents=True, exist_ok=True)
    world.rig.save(root)
    samples = []
    for i, q in enumerate(poses):
        frame = world.render(q, seed=seed * 1_000_003 + i, noise_sigma=render.noise_sigma,
                             supersample=render.supersample, blur_sigma=render.blur_sigma,
                             exposure=render.exposure)
        for side, img in (("left", frame.left), ("right", frame.right)):
            path = root / side / f"{i:04d}.png"
            write_image_file(path, img)  # through bytes: any file name works
        samples.append({"left": f"left/{i:04d}.png", "right": f"right/{i:04d}.png",
                        "base_T_ee": pose_to_dict(world.arm.fk(poses_rep[i])),
                        "joint_positions": [float(v) for v in poses_rep[i]],
                        "true_base_T_ee": pose_to_dict(frame.truth.base_T_ee)})
        if progress is not None:
            progress(i + 1, len(poses))
    data = {
        "setup": "eye_in_hand",
        "board": str(world.board),
        "left": "left.yaml",
        "right": "right.yaml",
        "stereo": "stereo.yaml",
        "samples": samples,
        "ground_truth": {"ee_T_cam": pose_to_dict(world.ee_T_cam),
                         "base_T_board": pose_to_dict(world.base_T_board)},
        "robot_error": err.to_dict(),
    }
    path = root / "dataset.yaml"
    path.write_text("# eye_in_hand calibration dataset (simulated); paths relative to this "
                    "folder\n" + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path
