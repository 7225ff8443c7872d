"""``eye-in-hand process``: the localization pipeline over a bag, offline, no DDS.

Example::

    eye-in-hand process bags/localization --calibration calib/ --hand-eye hand_eye.yaml -o out

Runs the same core code as the live ``detect_triangulate`` and ``hand_eye`` nodes on the bag's
messages, as fast as the CPU allows, and writes ``OUT`` as a rosbag2 bag with
``/target/point``, ``/target/pose`` and ``/target/pose_cov`` plus ``OUT/results.csv`` (one row per
stereo pair) and ``OUT/summary.json``, all under a temporary name renamed into place at the
end (an existing OUT is refused unless ``--overwrite``). When the bag carries
``/ground_truth/target`` it prints the base-frame error statistics (RMS, p95, max, in mm).
Every located target is in the outputs (one CSV row per pair and target); with two or more
targets it prints the pairwise distance table (against the ground truth, or ``--truth FILE``
of known distances). With an eye-to-hand calibration (a fixed camera, ``base_T_cam``) no
robot pose is read.
"""
from __future__ import annotations

import argparse
import math
import shutil
import struct
import sys
import time
from pathlib import Path

import numpy as np

from eye_in_hand.commands.common import (
    MAX_WORKERS,
    add_image_topic_arguments,
    add_output_argument,
    add_robot_pose_arguments,
    apply_overrides,
    bounded,
)
from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.distances import distance_table
from eye_in_hand.core.localization import robot_pose_sigmas
from eye_in_hand.core.locator_params import load_parameter_file, locator_config_from_params
from eye_in_hand.core.triangulation import METHODS as TRIANGULATION_METHODS
from eye_in_hand.errors import ConfigError, ConversionError, InputError
from eye_in_hand.io.atomic import atomic_output_dir, check_output_dir
from eye_in_hand.io.bags import STORAGES, DamageLog, bag_info, default_typestore, iter_messages
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.io.pages import keep_freed_heap
from eye_in_hand.io.results import (
    load_known_distances,
    prepare_output_types,
    prepare_truth_matching,
    run_figures,
)
from eye_in_hand.nodes.parameters import check_parameter_file_keys
from eye_in_hand.offline import (
    ProcessOptions,
    process_bag,
    top_reasons,
    write_results,
)
from eye_in_hand.ros.markers import sphere_style
from eye_in_hand.ros.outputs import (
    DEFAULT_RGBA,
    MARKER_DIAMETER_M,
    MARKER_LIFETIME_S,
    RIGHT_CAMERA_FRAME,
    TARGET_FRAME_PREFIX,
    OutputSettings,
    marker_lifetime_ns,
)

HELP = "run detection, triangulation and localization over a bag offline (no DDS)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand process``."""
    parser.add_argument("bag", metavar="BAG", help="input bag directory or .mcap file")
    add_output_argument(parser, metavar="OUT",
                        help="output bag directory, written whole or not at all (must not "
                             "exist, or give --overwrite)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing OUT (whole, once the new one is complete)")
    parser.add_argument("--hand-eye", required=True, metavar="FILE",
                        help="hand_eye.yaml (eye_in_hand: tool0 -> left optical frame; "
                             "eye_to_hand: base_link -> left optical frame, no robot pose "
                             "needed)")
    parser.add_argument("--truth", metavar="FILE",
                        help="YAML of known distances between targets "
                             "(distances: [{a: ID, b: ID, m: METRES}]); the distance table's "
                             "error is against these instead of the bag's ground truth")
    parser.add_argument("--calibration", metavar="DIR",
                        help="directory with left.yaml and right.yaml (ROS camera_calibration "
                             "files; stereo.yaml optional); default: the bag's camera_info")
    parser.add_argument("--params", metavar="FILE",
                        help="ROS parameter file with detect_triangulate (detector, sync) and "
                             "optionally hand_eye (max_pose_gap_s, max_pose_age_s, "
                             "pose_jump_back_s, robot sigmas) sections; "
                             "default: built-in red sphere")
    parser.add_argument("--radius", type=bounded(0, 10, "m", lo_open=True), metavar="R",
                        help="sphere radius of the first target in metres, (0, 10] "
                             "(default: the --params file's, else 0.02)")
    parser.add_argument("--method", choices=TRIANGULATION_METHODS,
                        help="triangulation method (default: the --params file's, else dlt)")
    add_image_topic_arguments(parser, left_help="left image topic",
                              right_help="right image topic",
                              default_left="/stereo/left/image_raw",
                              default_right="/stereo/right/image_raw")
    parser.add_argument("--left-info-topic", metavar="TOPIC",
                        default="/stereo/left/camera_info",
                        help="left camera_info topic (without --calibration)")
    parser.add_argument("--right-info-topic", metavar="TOPIC",
                        default="/stereo/right/camera_info",
                        help="right camera_info topic (without --calibration)")
    add_robot_pose_arguments(
        parser, default_source="ee_pose",
        source_help="robot pose source: ee_pose (--ee-pose-topic), joint_states "
                    "(--joint-states-topic + --kinematics) or tf (--tf-topic + "
                    "--tf-static-topic, --base-frame -> --ee-frame at each image stamp)",
        base_help="robot base frame: the frame of the results, the root of the /tf chain and "
                  "of a URDF chain (default: hand_eye base_frame in --params, else base_link)",
        ee_help="flange (tool) frame: the tip of the /tf chain and of a URDF chain (default: "
                "hand_eye ee_frame in --params, else the hand-eye file's parent frame)",
        default_base=None, default_ee=None)
    parser.add_argument("--ground-truth-topic", metavar="TOPIC", default="/ground_truth/target",
                        help="geometry_msgs/PointStamped true target position, when the bag "
                             "has it: the error statistics are against it")
    parser.add_argument("--storage", choices=STORAGES, default=STORAGES[0],
                        help="output bag storage (default mcap)")
    parser.add_argument("--task-timeout", type=bounded(0, 3600, "s", lo_open=True), default=20.0,
                        metavar="S",
                        help="deadline of a worker process for one stereo pair, (0, 3600] s "
                             "(default 20 s): "
                             "a worker that gives no result for this long (stopped, hung) is "
                             "killed and its pairs are located again in the main process")
    parser.add_argument("--workers", type=bounded(1, MAX_WORKERS, integer=True), metavar="N",
                        help=f"processes locating stereo pairs, 1 to {MAX_WORKERS} (default: "
                             "one per CPU; 1 = all in this process)")
    parser.add_argument("--verify-crc", action="store_true",
                        help="check MCAP chunk CRCs while reading (slower: CRC-32 of every image)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar and no estimate line")
    parser.add_argument("--force", action="store_true",
                        help="start even when the estimate says the outputs do not fit on the "
                             "disk")


def _image_head(raw: bytes) -> tuple[int, int, str] | None:
    """(width, height, frame_id) of a CDR ``sensor_msgs/Image`` without decoding its pixels."""

    try:
        little = raw[1] == 1
        fmt = "<" if little else ">"
        pos = 4 + 8                                   # encapsulation, header stamp
        (n,) = struct.unpack_from(fmt + "I", raw, pos)
        frame = bytes(raw[pos + 4:pos + 4 + n]).rstrip(b"\0").decode("utf-8", "replace")
        pos += 4 + n
        pos += -(pos - 4) % 4                         # CDR alignment (from after encapsulation)
        height, width = struct.unpack_from(fmt + "II", raw, pos)
    except (struct.error, IndexError):
        return None
    return int(width), int(height), frame


def check_calibration_against_bag(rig, calibration: str, bag: str,
                                  sides: dict[str, str], *, hand_eye_file: str = "",
                                  camera_frame: str = "") -> list[str]:
    """Refuse a calibration whose image sizes disagree with each other or with the bag's first
    image on each side (an Image topic), naming the file and the fields.

    Returns:
        Warnings: the bag's left images in another frame than ``camera_frame`` (hand_eye.yaml's
        child frame): the numbers are the same offline, but the live ``hand_eye`` node, whose
        ``camera_frame`` is that frame, would refuse the points of such a camera.

    Raises:
        ConfigError: ``DIR/left.yaml: image_width x image_height 640x360 ...``.
    """

    models = {"left": rig.left, "right": rig.right}
    if rig.left.size != rig.right.size:
        raise ConfigError(
            f"{Path(calibration) / 'right.yaml'}: image_width x image_height "
            f"{rig.right.width}x{rig.right.height} disagrees with left.yaml's "
            f"{rig.left.width}x{rig.left.height}")
    seen: set[str] = set()
    notes: list[str] = []
    for topic, msgtype, t_ns, raw in iter_messages(bag, list(sides), damage=DamageLog()):
        if topic in seen or msgtype != "sensor_msgs/msg/Image":
            continue
        head = _image_head(bytes(raw[:4096]))
        if head is None:
            continue
        size, frame = head[:2], head[2]
        seen.add(topic)
        side = sides[topic]
        model = models[side]
        if side == "left" and camera_frame and frame and frame.lstrip("/") != camera_frame:
            notes.append(f"{hand_eye_file}: child_frame {camera_frame!r} is not the frame of "
                         f"the bag's {topic} images ({frame!r}): the numbers are the same "
                         "here, but the live hand_eye node (camera_frame) would refuse that "
                         "camera's points; check that the calibration is of this camera")
        if size != (model.width, model.height):
            raise ConfigError(
                f"{Path(calibration) / f'{side}.yaml'}: image_width x image_height "
                f"{model.width}x{model.height} disagrees with the bag's {topic} images, "
                f"{size[0]}x{size[1]} (first image at {t_ns} ns): a calibration of another "
                "camera or resolution")
        if len(seen) == len(sides):
            break
    return notes


def _node_params(path: str | None, node: str) -> dict:
    """Flattened parameters of ``node`` in a parameter file ({} when the file has none)."""
    if path is None:
        return {}
    try:
        return load_parameter_file(path, node)
    except ConfigError as exc:
        if "no parameters for node" in str(exc):
            return {}
        raise


def output_settings(detect: dict, hand_eye: dict, config, calib, *, camera_parent: str):
    """The live nodes' output settings from their parameters (defaults: the nodes'), so that
    the output bag holds the messages they would publish: markers (lifetimes, each target's
    sphere), /tf names, /tf_static (the hand-eye transform, and the stereo extrinsic of
    hand_eye's ``stereo_calibration_dir``)."""

    diameter = float(detect.get("markers.diameter_m", MARKER_DIAMETER_M))
    styles = {t.name: sphere_style(t.radius_m, t.color, diameter)
              for t in config.detector.targets}
    stereo_dir = str(hand_eye.get("stereo_calibration_dir", ""))
    stereo_T = (np.linalg.inv(StereoRig.load(stereo_dir).right_T_left) if stereo_dir
                else None)
    lifetimes = {"detect_triangulate markers.lifetime_s":
                 float(detect.get("markers.lifetime_s", MARKER_LIFETIME_S)),
                 "hand_eye marker_lifetime_s":
                 float(hand_eye.get("marker_lifetime_s", MARKER_LIFETIME_S))}
    for name, value in lifetimes.items():   # before the work, not at the first output frame
        try:
            marker_lifetime_ns(value)
        except ConversionError as exc:
            raise ConfigError(f"--params: {name}: {exc}") from None
    return OutputSettings(
        target_frame_prefix=str(hand_eye.get("target_frame_prefix", TARGET_FRAME_PREFIX)),
        target_frame=str(hand_eye.get("target_frame", "")),
        publish_tf=bool(hand_eye.get("publish_tf", True)),
        right_camera_frame=str(hand_eye.get("right_camera_frame", RIGHT_CAMERA_FRAME)),
        camera_markers_lifetime_s=lifetimes["detect_triangulate markers.lifetime_s"],
        target_markers_lifetime_s=lifetimes["hand_eye marker_lifetime_s"],
        styles=styles, default_style=(diameter, DEFAULT_RGBA),
        camera_parent=camera_parent,
        hand_eye_T=calib.transform, stereo_T=stereo_T)


# The cost model of the estimate printed before the work (measured here: a 20 s 640x480 bag of
# 600 pairs took 2.6-3.0 s with two workers, a 1280x720 zstd one ~5 s; outputs ~2.5 KB a pair)
_START_S = 1.5              # interpreter, imports and worker start-up (s)
_S_PER_PAIR = 0.005         # per stereo pair, two workers (s)
_BYTES_PER_PAIR = 4096      # results.csv row(s), the output bag's poses, markers and /tf
_BYTES_FIXED = 1 << 16      # summary.json, metadata


def estimate(pairs: int, out: Path, *, force: bool = False) -> str:
    """The run's estimated time and disk as one line; refuses (``InputError``) a run whose
    outputs cannot fit on the disk of ``out``, unless ``force``."""

    seconds = _START_S + pairs * _S_PER_PAIR
    disk = _BYTES_FIXED + pairs * _BYTES_PER_PAIR
    parent = out.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    line = (f"process: {pairs} stereo pairs: about {seconds:.0f} s, about "
            f"{disk / 1e6:,.1f} MB of outputs ({free / 1e6:,.0f} MB free)")
    if disk > free and not force:
        raise InputError(f"{line}: the outputs do not fit on the disk of {parent} (free some "
                         "space, or give --force to try anyway)")
    return line


def _options(args: argparse.Namespace, detect: dict, hand_eye_params: dict, config,
             calib, ee_frame: str, base_frame: str):
    """The ``ProcessOptions`` of a run: the flags, then a ``--params`` file's
    ``detect_triangulate`` and ``hand_eye`` sections, then the nodes' defaults."""
    fixed = calib.setup == "eye_to_hand"
    noise = calib.robot_pose_noise
    kinematics = None
    if args.robot_pose == "joint_states":
        if not args.kinematics:
            raise InputError("--kinematics: required with --robot-pose joint_states")
        # local: the URDF reader costs ~4 ms at start-up, and only this robot pose source
        from eye_in_hand.io.kinematics import load_kinematics

        kinematics = load_kinematics(
            args.kinematics,
            args.urdf_base_link or hand_eye_params.get("urdf_base_link", base_frame),
            args.urdf_tip_link or hand_eye_params.get("urdf_tip_link", ee_frame))
    try:
        robot_sigmas = robot_pose_sigmas(
            float(hand_eye_params.get("robot_sigma_pos_m", ProcessOptions.robot_sigma_pos_m)),
            float(hand_eye_params.get("robot_sigma_rot_rad", ProcessOptions.robot_sigma_rot_rad)),
            noise)
        opts = ProcessOptions(
            left_topic=args.left_topic, right_topic=args.right_topic,
            left_info_topic=args.left_info_topic, right_info_topic=args.right_info_topic,
            robot_pose_source=args.robot_pose, ee_pose_topic=args.ee_pose_topic,
            joint_states_topic=args.joint_states_topic, kinematics=kinematics,
            tf_topic=args.tf_topic, tf_static_topic=args.tf_static_topic,
            ee_frame=ee_frame, ground_truth_topic=args.ground_truth_topic,
            base_frame=base_frame,
            camera_frame=calib.child_frame,
            sync_slop_s=float(detect.get("sync.slop_s", ProcessOptions.sync_slop_s)),
            sync_queue_size=int(detect.get("sync.queue_size", ProcessOptions.sync_queue_size)),
            # a --params file's hand_eye section, else the node's defaults (POSE_RULES)
            **{k: float(hand_eye_params.get(k, getattr(ProcessOptions, k)))
               for k in ("max_pose_gap_s", "max_pose_age_s", "pose_jump_back_s")},
            # the arm's stated accuracy (hand_eye parameters), raised to hand_eye.yaml's
            # robot_pose_noise where that is larger (core.localization.robot_pose_sigmas)
            robot_sigma_pos_m=robot_sigmas[0], robot_sigma_rot_rad=robot_sigmas[1],
            verify_crc=args.verify_crc, workers=args.workers,
            task_timeout_s=args.task_timeout, setup=calib.setup,
            outputs=output_settings(detect, hand_eye_params, config, calib,
                                    camera_parent=calib.parent_frame if fixed else ee_frame))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{args.params}: {exc}") from exc
    return opts


#: what the output bag and the ground-truth matching load once, done while `process` waits
#: for its worker processes
_IDLE_WORK = (default_typestore, prepare_output_types, prepare_truth_matching)


def run(args: argparse.Namespace) -> int:
    """Process the bag and write the results; prints counts and error statistics."""

    if args.params:  # a mistyped key would run on its default, as the live node refuses it
        check_parameter_file_keys(args.params, used=["detect_triangulate", "hand_eye"])
    detect = _node_params(args.params, "detect_triangulate")
    hand_eye_params = _node_params(args.params, "hand_eye")
    config = apply_overrides(locator_config_from_params(
        {k: v for k, v in detect.items() if not k.startswith("sync.")
         and k not in ("calibration_dir", "frame_id") and not k.startswith("debug_image.")}),
        radius=args.radius, method=args.method)
    calib = load_hand_eye(args.hand_eye)
    fixed = calib.setup == "eye_to_hand"
    known = load_known_distances(args.truth) if args.truth else []
    rig = StereoRig.load(args.calibration) if args.calibration else None
    ee_frame = str(args.ee_frame or hand_eye_params.get("ee_frame", calib.parent_frame))
    base_frame = str(args.base_frame or (calib.parent_frame if fixed else
                                         hand_eye_params.get("base_frame", "base_link")))
    opts = _options(args, detect, hand_eye_params, config, calib, ee_frame, base_frame)
    check_output_dir(args.output, overwrite=args.overwrite,  # refuse now, not after the work
                     inputs=[args.bag, args.hand_eye, args.calibration, args.params,
                             args.kinematics, args.truth])
    info = bag_info(args.bag)
    if rig is not None:   # before the work: a calibration of another camera locates nothing
        for note in check_calibration_against_bag(
                rig, args.calibration, args.bag,
                {opts.left_topic: "left", opts.right_topic: "right"},
                hand_eye_file=str(args.hand_eye), camera_frame=calib.child_frame):
            print(f"warning: {note}", file=sys.stderr)
    line = estimate(info.topics[opts.left_topic].count if opts.left_topic in info.topics
                    else 0, Path(args.output), force=args.force)
    if not args.quiet:
        print(line, file=sys.stderr, flush=True)
    total = sum(info.topics[t].count for t in {opts.left_topic, opts.right_topic,
                                               opts.ground_truth_topic} | (
                    set() if fixed else {opts.pose_topic})
                | ({opts.tf_static_topic} if opts.robot_pose_source == "tf" else set())
                if t in info.topics)
    bar = None
    if not args.quiet:
        from tqdm import tqdm  # local: ~18 ms at start-up with its importlib.metadata

        class _Bar(tqdm):
            # tqdm's monitor thread would keep process_bag from forking its workers
            # (workers.fork_is_safe); update() is called for every message anyway
            monitor_interval = 0

        bar = _Bar(total=total, unit="msg", desc="processing", file=sys.stderr)
    # this process decompresses chunks too (all of them with --workers 1): its heap keeps
    # freed memory for the next one, as the workers' do (io.pages.keep_freed_heap)
    keep_freed_heap()
    t0 = time.perf_counter()
    try:
        result = process_bag(args.bag, hand_eye_T=calib.transform, locator_config=config,
                             rig=rig, hand_eye_cov=calib.covariance, options=opts,
                             progress=None if bar is None else bar.update,
                             pose_correction=calib.robot_pose_correction, info=info,
                             idle=_IDLE_WORK)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    # the bag, results.csv and summary.json appear together (temporary folder, then rename)
    extra, pairs, stats_by_target, unmatched = run_figures(result, known)
    if args.truth:
        extra["distances_truth"] = str(args.truth)
    extra["loss"] = result.loss
    extra["notes"] = list(result.notes)
    with atomic_output_dir(args.output, overwrite=args.overwrite, create=False) as tmp:
        written = write_results(tmp, result, opts, storage=args.storage, summary_extra=extra)
    out = Path(args.output)
    paths = {"bag": out, "csv": out / written["csv"].name,
             "summary": out / written["summary"].name}
    _report(args, result, wall, known, pairs, stats_by_target, unmatched, extra["error"])
    print(f"wrote {paths['bag']} (bag), {paths['csv']}, {paths['summary']}")
    if not any(t.status == "ok" for f in result.frames for t in f.targets):
        print(f"eye-in-hand: error: nothing located in the base frame in {args.bag}: "
              + _nothing_reasons(result.counts, result.loss, result), file=sys.stderr)
        return EXIT_NOTHING_LOCATED
    return 0


def _report(args: argparse.Namespace, result, wall: float, known: list, pairs: list,
            stats_by_target: list, unmatched: list, stats: dict[str, float] | None) -> None:
    """What a run printed: the counts, why pairs gave nothing, the losses, the damage, the
    error against the ground truth (``stats``: :func:`eye_in_hand.io.results.error_figures`)
    and the distances between targets."""
    c = result.counts
    speed = result.duration_s / wall if wall > 0 else math.inf
    print(f"processed {c['pairs']} stereo pairs in {wall:.2f} s ({speed:.1f}x real time): "
          f"{c['located']} located, {c['localized']} in the base frame, {c['no_target']} "
          f"without target, {c['no_robot_pose']} without robot pose, {c['bad_messages']} bad "
          "messages")
    ok, n = c["localized"], len(result.frames)   # localized: the frames of status ok
    if n and ok < n / 2:                       # few located: say why, not only in the csv
        print(f"why {n - ok} of {n} stereo pairs have no "
              "result in the base frame (top reasons):")
        for count, status, example in top_reasons(result.frames):
            print(f"  {count} {status}: {example}")
    refused = {k[len("refused."):]: v for k, v in c.items() if k.startswith("refused.") and v}
    loss = result.loss
    if loss.get("total") or not loss.get("complete", True):
        print(_loss_line(loss, refused))
    for note in result.notes:
        print(f"warning: {note}", file=sys.stderr)
    if result.damage:
        print(f"damaged bag: {result.damage.summary()}")
        for line in result.damage.lines():
            print(f"warning: damaged: {line}", file=sys.stderr)
    if stats is not None:
        print(f"error against {args.ground_truth_topic} over {stats['frames']} frames: "
              f"RMS {stats['rms_mm']:.3f} mm, p95 {stats['p95_mm']:.3f} mm, max "
              f"{stats['max_mm']:.3f} mm")
    if len(result.target_ids) > 1:
        print(f"{len(result.target_ids)} targets; distances over the frames where both were "
              "located" + (f", truth from {args.truth}" if known else
                           ", truth from " + args.ground_truth_topic
                           if any(p.truth_source for p in pairs) else ""))
        for line in distance_table(pairs, stats_by_target):
            print("  " + line)
    for a, b, _m in unmatched:
        print(f"warning: {args.truth}: no measured distance {a} - {b} (targets located: "
              f"{', '.join(result.target_ids)})", file=sys.stderr)


#: Exit code of a ``process`` run that wrote its outputs but located no target in the base
#: frame (the reasons are on stderr and in summary.json).
EXIT_NOTHING_LOCATED = 3


def _loss_line(loss: dict, refused: dict[str, int]) -> str:
    """``losses: N in total: ...``, every cause of the loss total with its count."""
    b = loss["by_cause"]
    parts = [f"{b['unpaired_left']} left and {b['unpaired_right']} right images without a "
             "partner" + (f" ({loss['of_which_stale_stamp']} of them with a stamp not after "
                          "the previous one: stale_stamp)" if loss["of_which_stale_stamp"]
                          else "")]
    if b["bad_pairs"]:
        parts.append(f"{b['bad_pairs']} pairs that could not be used")
    if b["no_robot_pose"]:
        parts.append(f"{b['no_robot_pose']} pairs without robot pose" + (
            " (" + ", ".join(f"{v} {k}" for k, v in refused.items()) + ")" if refused else ""))
    if b["bad_messages"]:
        parts.append(f"{b['bad_messages']} other messages that could not be read")
    if b["damaged"] is None:
        parts.append("an unknown number of images in damaged regions of the bag")
    elif b["damaged"]:
        parts.append(f"{b['damaged']} images in damaged regions of the bag")
    total = f"{loss['total']}" + ("" if loss.get("complete", True) else " or more")
    return f"losses: {total} in total: " + "; ".join(parts)


def _nothing_reasons(c: dict, loss: dict, result) -> str:
    """Why nothing was located, from the counters and the first note."""
    reasons = [f"{c['pairs']} stereo pairs"]
    for key, text in (("no_target", "without target"), ("no_robot_pose", "without robot pose"),
                      ("bad_pairs", "that could not be used")):
        if c.get(key):
            reasons.append(f"{c[key]} {text}")
    if loss.get("total"):
        reasons.append(f"{loss['total']} inputs lost")
    if c.get("located") and not c.get("localized"):
        reasons.append("targets were seen but no robot pose could place them")
    if result.notes:
        reasons.append(f"first note: {result.notes[0]}")
    return ", ".join(reasons)
