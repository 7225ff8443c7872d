"""Inputs and outputs shared by the ``calibrate`` commands: for ``calibrate camera`` and
``calibrate stereo`` the common options, image files and bag topics as board views, report
entries and JSON files; for ``calibrate handeye`` and ``calibrate plan`` the hand-eye input
options and samples (dataset, pose pairs or bag)."""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from eye_in_hand.commands.common import (
    add_image_topic_arguments,
    add_output_argument,
    add_robot_pose_arguments,
    bounded,
    deprecated_alias,
)
from eye_in_hand.core.calibration import DETECTORS, BoardSpec, CalibrationOptions, detect_board
from eye_in_hand.core.calibration.board_check import BoardCheck
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye import METHODS, SETUPS, HandEyeSample, calibrate_hand_eye
from eye_in_hand.core.handeye.average import AVERAGE_SOLVERS
from eye_in_hand.core.handeye.calibrate import DEFAULT_ROBOT_MODEL, ROBOT_MODELS
from eye_in_hand.core.handeye.observe import observe_sample, rig_views
from eye_in_hand.errors import (
    BagError,
    CalibrationError,
    ConfigError,
    ConversionError,
    HandEyeError,
    InputError,
)
from eye_in_hand.io.atomic import atomic_output_dir, check_output_dir
from eye_in_hand.io.bag_samples import read_bag_samples
from eye_in_hand.io.bags import bag_info, deserialize, iter_messages, require_topics
from eye_in_hand.io.datasets import load_dataset
from eye_in_hand.io.images import read_image_file
from eye_in_hand.io.kinematics import load_kinematics
from eye_in_hand.io.pose_pairs import load_pose_pairs
from eye_in_hand.ros.images import calibration_image
from eye_in_hand.ros.stamps import header_stamp_ns
from eye_in_hand.yamlfile import printable

__all__ = [
    "IMAGE_EXTENSIONS",
    "add_common_arguments",
    "options_from_args",
    "check_common_arguments",
    "Frame",
    "ImageSource",
    "progress",
    "expand_glob",
    "read_image",
    "detect_files",
    "iter_bag_frames",
    "bag_count",
    "iter_bag_pairs",
    "write_json",
    "report_damage",
    "report_skipped",
    "view_entries",
    "atomic_output_dir",
    "add_handeye_input_arguments",
    "add_handeye_calibration_arguments",
    "load_handeye_inputs",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


# ------------------------------------------------------------------------------------------------
# arguments
# ------------------------------------------------------------------------------------------------
def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``calibrate camera`` and ``calibrate stereo``."""
    parser.add_argument("--board", required=True, metavar="SPEC",
                        help="board: chessboard:COLSxROWS:SQUARE (inner corners, square in m) or "
                             "charuco:SQUARESXxSQUARESY:SQUARE:MARKER[:DICT][:legacy]")
    add_output_argument(parser, metavar="OUT_DIR", type=Path,
                        help="output folder, written whole or not at all (must not exist, or "
                             "give --overwrite)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing OUT_DIR (whole, once the new one is complete)")
    parser.add_argument("--bag", type=Path, metavar="BAG", help="read images from this bag")
    parser.add_argument("--every", type=bounded(1, 1e6, integer=True), default=1, metavar="N",
                        help="bag input: use every N-th frame (or stereo pair); default 1")
    parser.add_argument("--detector", choices=DETECTORS, default="auto",
                        help="chessboard detector: classic (findChessboardCorners + "
                             "cornerSubPix), sb (findChessboardCornersSB), auto (classic, "
                             "falling back to sb per image); default auto")
    parser.add_argument("--no-fallback", action="store_true",
                        help="do not try the other chessboard detector when one finds nothing")
    parser.add_argument("--subpix-window", type=bounded(1, 50, "px", integer=True), default=5,
                        metavar="PX",
                        help="half size of the cornerSubPix window (classic); default 5")
    parser.add_argument("--rational", action="store_true",
                        help="8-coefficient rational_polynomial distortion model")
    parser.add_argument("--fix-k3", action="store_true", help="keep k3 = 0")
    parser.add_argument("--zero-tangent", action="store_true", help="keep p1 = p2 = 0")
    parser.add_argument("--fix-aspect", action="store_true", help="keep fx / fy = 1")
    parser.add_argument("--fix-principal-point", action="store_true",
                        help="keep (cx, cy) at the image centre")
    parser.add_argument("--reject-outliers", action="store_true",
                        help="drop views whose RMS is above the outlier threshold and recompute")
    px = parser.add_argument(
        "--outlier-threshold-px", type=bounded(0, 1000, "px", lo_open=True), default=None,
        metavar="PX",
        help="per-view RMS (px) above which a view is an outlier; default: max(2 x median, "
             "median + 4 x MAD) of the per-view RMS")
    deprecated_alias(parser, "--outlier-threshold", px)
    parser.add_argument("--min-views", type=bounded(1, 10000, integer=True), default=5,
                        metavar="N",
                        help="fewest usable views accepted; default 5")
    parser.add_argument("--no-html", action="store_true", help="skip report.html")


def options_from_args(args: argparse.Namespace):
    """The :class:`CalibrationOptions` selected on the command line."""
    return CalibrationOptions(rational=args.rational, fix_k3=args.fix_k3,
                              zero_tangent=args.zero_tangent, fix_aspect=args.fix_aspect,
                              fix_principal_point=args.fix_principal_point)


def check_common_arguments(args: argparse.Namespace) -> None:
    """Validate values argparse cannot check; raises InputError naming the option."""
    if args.every < 1:
        raise InputError(f"--every must be >= 1, got {args.every}")
    if args.subpix_window < 1:
        raise InputError(f"--subpix-window must be >= 1, got {args.subpix_window}")
    if args.min_views < 1:
        raise InputError(f"--min-views must be >= 1, got {args.min_views}")
    if args.outlier_threshold_px is not None and not args.outlier_threshold_px > 0:
        raise InputError(f"--outlier-threshold-px must be > 0, got {args.outlier_threshold_px}")
    globs = [getattr(args, k, None) for k in ("images", "left", "right")]
    inputs = [args.bag] + [g if os.path.isdir(g) else os.path.dirname(g) or "."
                           for g in globs if g]
    # refuse now, not after the work
    check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)


# ------------------------------------------------------------------------------------------------
# inputs
# ------------------------------------------------------------------------------------------------
@dataclass
class Frame:
    """One input image: its name, the detection, and (optionally) the pixels kept for the
    report."""

    name: str
    detection: Any
    image: np.ndarray | None = None
    stamp_ns: int | None = None


@dataclass
class ImageSource:
    """What the frames came from, for the report."""

    kind: str  # "files" or "bag"
    description: str
    frames: list[Frame] = field(default_factory=list)
    unmatched: int = 0
    damage: Any = None      # eye_in_hand.io.bags.DamageLog of a bag source


def progress(total: int | None, desc: str):
    """A tqdm progress bar on stderr (silent when stderr is not a terminal)."""
    return tqdm(total=total, desc=desc, unit="img", file=sys.stderr, disable=None,
                dynamic_ncols=True, leave=False)


def expand_glob(pattern: str, option: str) -> list[Path]:
    """Files matching ``pattern`` (sorted); a folder means every image file inside it.

    Raises:
        InputError: nothing matches.
    """
    path = Path(pattern)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
    else:
        files = sorted(Path(p) for p in glob.glob(os.path.expanduser(pattern))
                       if Path(p).is_file())
    if not files:
        shown = pattern.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise InputError(f"{option} '{shown}': no image files match")
    return files


def read_image(path: Path) -> np.ndarray:
    """Read an image file (any depth, colour kept).

    Raises:
        InputError: the file cannot be read or decoded.
    """
    return read_image_file(path)


def detect_files(files: Sequence[Path], board, args: argparse.Namespace, desc: str,
                 keep: Callable[[int], bool] = lambda i: False) -> list[Frame]:
    """Read every file and look for the board, with a progress bar.

    Args:
        files: image files.
        board: the :class:`BoardSpec`.
        args: parsed options (detector, subpix window, fallback).
        desc: progress-bar label.
        keep: which frame indices keep their pixels (for the report).

    Raises:
        InputError: an unreadable file.
        CalibrationError: images of different sizes (naming two of them).
    """
    frames: list[Frame] = []
    first: tuple[str, tuple[int, int]] | None = None
    check = BoardCheck(board, f"{desc} images")   # a wrong board: say so after a few images
    with progress(len(files), desc) as bar:
        for i, path in enumerate(files):
            image = read_image(path)
            size = (int(image.shape[1]), int(image.shape[0]))
            if first is None:
                first = (path.name, size)
            elif size != first[1]:
                raise CalibrationError(
                    f"{desc}: images differ in size: {first[0]} is {first[1][0]}x{first[1][1]}, "
                    f"{path} is {size[0]}x{size[1]}")
            det = detect_board(image, board, args.detector, subpix_window=args.subpix_window,
                               fallback=not args.no_fallback)
            check.add(image, det.found)
            # the name as text every report can hold (a non-UTF-8 byte as \xNN)
            frames.append(Frame(printable(path.name), det, image if keep(i) else None))
            bar.update(1)
    check.finish()
    return frames


def _decode(msgtype: str, raw: bytes, topic: str, stamp: int) -> tuple[np.ndarray, int]:
    msg = deserialize(raw, msgtype)
    try:
        image = calibration_image(msg)
    except ConversionError as exc:
        raise ConversionError(f"{topic} message at log time {stamp} ns: {exc}") from exc
    return image, header_stamp_ns(msg)


_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


def _bag_topics(bag: Path, topics: Sequence[str]) -> dict[str, Any]:
    info = bag_info(bag)
    require_topics(info, topics)
    for t in topics:
        if info.topics[t].msgtype not in _IMAGE_TYPES:
            raise BagError(f"bag {bag}: topic {t} has type {info.topics[t].msgtype}, expected "
                           "sensor_msgs/msg/Image or CompressedImage")
    return dict(info.topics)


def iter_bag_frames(bag: Path, topic: str, every: int, damage: Any = None
                    ) -> Iterator[tuple[str, int, np.ndarray]]:
    """Every ``every``-th image of ``topic``: ``(name, header_stamp_ns, image)``.

    With ``damage`` (a :class:`eye_in_hand.io.bags.DamageLog`), damaged chunks and messages
    that do not decode (a truncated image) are skipped and recorded there, naming topic and
    stamp; without it they raise.

    Raises:
        BagError: the bag cannot be read, lacks the topic, or the topic is not an image topic.
        ConversionError: a message cannot be decoded (naming topic and log time).
    """
    _bag_topics(bag, [topic])
    for k, (t, msgtype, log_ns, raw) in enumerate(iter_messages(bag, [topic], damage=damage)):
        if k % every:
            continue
        try:
            image, stamp = _decode(msgtype, raw, t, log_ns)
        except (BagError, ConversionError) as exc:
            if damage is None:
                raise
            damage.bad_message(t, log_ns, str(exc))
            continue
        yield f"{t}@{stamp}", stamp, image


def bag_count(bag: Path, topic: str) -> int:
    """Number of messages on ``topic``."""
    return int(_bag_topics(bag, [topic])[topic].count)


def iter_bag_pairs(bag: Path, left_topic: str, right_topic: str, every: int,
                   stats: dict[str, int] | None = None, max_pending: int = 64,
                   damage: Any = None,
                   ) -> Iterator[tuple[int, tuple[str, np.ndarray], tuple[str, np.ndarray]]]:
    """Stereo pairs of a bag, matched by identical header stamps; every ``every``-th pair.

    Messages are decoded lazily (the raw bytes wait until a partner with the same header
    stamp arrives; at most ``max_pending`` per side). ``stats['unmatched']`` counts images
    that found no partner. With ``damage``, damaged chunks and images that do not decode are
    skipped and recorded there (a pair with a damaged image is dropped); without it they raise.

    Yields:
        ``(stamp_ns, (left_name, left_image), (right_name, right_image))``.

    Raises:
        BagError, ConversionError: as :func:`iter_bag_frames`.
    """
    if left_topic == right_topic:
        raise InputError(f"--left-topic and --right-topic are both {left_topic}")
    _bag_topics(bag, [left_topic, right_topic])
    pending: dict[str, dict[int, tuple[str, bytes, int]]] = {left_topic: {}, right_topic: {}}
    stats = stats if stats is not None else {}
    stats.setdefault("unmatched", 0)
    pair_index = 0
    for topic, msgtype, log_ns, raw in iter_messages(bag, [left_topic, right_topic],
                                                     damage=damage):
        # the header stamp only: deserialising twice is cheap next to image decoding
        try:
            stamp = header_stamp_ns(deserialize(raw, msgtype))
        except (BagError, ConversionError) as exc:
            if damage is None:
                raise
            damage.bad_message(topic, log_ns, str(exc))
            continue
        other = right_topic if topic == left_topic else left_topic
        if stamp in pending[other]:
            o_type, o_raw, o_log = pending[other].pop(stamp)
            if pair_index % every == 0:
                images: dict[str, np.ndarray] = {}
                for t, mt, r, lg in ((topic, msgtype, raw, log_ns), (other, o_type, o_raw, o_log)):
                    try:
                        images[t], _ = _decode(mt, r, t, lg)
                    except (BagError, ConversionError) as exc:
                        if damage is None:
                            raise
                        damage.bad_message(t, stamp, str(exc))
                if len(images) < 2:
                    pair_index += 1
                    continue
                yield stamp, (f"{left_topic}@{stamp}", images[left_topic]), \
                    (f"{right_topic}@{stamp}", images[right_topic])
            pair_index += 1
        else:
            mine = pending[topic]
            mine[stamp] = (msgtype, raw, log_ns)
            while len(mine) > max_pending:
                mine.pop(next(iter(mine)))
                stats["unmatched"] += 1
    stats["unmatched"] += sum(len(p) for p in pending.values())


# ------------------------------------------------------------------------------------------------
# outputs
# ------------------------------------------------------------------------------------------------
def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON (NaN/inf become null)."""
    path.write_text(json.dumps(_clean(data), indent=2) + "\n", encoding="utf-8")


def _clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def report_damage(damage: Any) -> dict | None:
    """Print a bag's damage records as warnings (stderr); their dict for the report (None when
    there is no log)."""
    if damage is None:
        return None
    if damage:
        print(f"eye-in-hand: warning: damaged bag: {damage.summary()}", file=sys.stderr)
        for line in damage.lines():
            print(f"eye-in-hand: warning: damaged: {line}", file=sys.stderr)
    return damage.to_dict()


def report_skipped(frames: Sequence[Frame], label: str) -> list[dict]:
    """Print one line per image without a board on stderr; returns them for the report."""
    skipped = []
    for f in frames:
        if not f.detection.found:
            print(f"eye-in-hand: {label}: skipped {f.name}: {f.detection.reason}", file=sys.stderr)
            skipped.append({"file": f.name, "reason": f.detection.reason})
    return skipped


def view_entries(frames: Sequence[Frame], cal_views: Sequence[Any]) -> list[dict]:
    """Per-image entries for report.json: detection outcome merged with calibration results."""
    by_name = {v.name: v for v in cal_views}
    out = []
    for f in frames:
        entry: dict[str, Any] = {"file": f.name, "found": bool(f.detection.found),
                                 "detector": f.detection.detector}
        if not f.detection.found:
            entry.update({"reason": f.detection.reason, "rms_px": None, "used": False,
                          "outlier": False, "n_points": 0})
        else:
            v = by_name.get(f.name)
            entry.update(v.to_dict() if v is not None else
                         {"rms_px": None, "used": False, "outlier": False,
                          "n_points": f.detection.n_corners, "reason": "too few corners"})
            entry["file"] = f.name
        out.append(entry)
    return out


# ------------------------------------------------------------------------------------------------
# hand-eye inputs (calibrate handeye, calibrate plan)
# ------------------------------------------------------------------------------------------------
def add_handeye_input_arguments(parser: argparse.ArgumentParser, *, pairs: bool = True) -> None:
    """The input options of the hand-eye commands: a dataset, pose pairs (``pairs``) or a
    bag, and the bag's topics, robot pose source and stillness test."""
    src = parser.add_argument_group("input (exactly one)")
    src.add_argument("dataset", nargs="?", metavar="DATASET_DIR",
                     help="dataset folder with dataset.yaml (images + robot poses)")
    if pairs:
        src.add_argument("--pairs", metavar="FILE",
                         help="JSON list of [base_T_ee, cam_T_board] 4x4 row-major pairs "
                              "(metres)")
    src.add_argument("--bag", metavar="BAG", help="rosbag2 bag with images and robot poses")
    bag = parser.add_argument_group("bag input")
    bag.add_argument("--board", metavar="SPEC",
                     help="board spec for --bag, e.g. chessboard:9x6:0.025")
    bag.add_argument("--calibration", metavar="PATH",
                     help="camera calibration for --bag: a camera YAML (mono) or a folder "
                          "with left.yaml, right.yaml [, stereo.yaml] (stereo); default: the "
                          "bag's camera_info")
    topics = add_image_topic_arguments(
        bag, left_help="image topic (the left camera's for stereo); a suffix such as "
                       "left/image_raw matches /stereo/left/image_raw (default: the only image "
                       "topic, or the one with 'left' in its name)",
        right_help="right image topic for a stereo rig (default: the left topic with 'left' "
                   "replaced by 'right', when the bag has it)")
    deprecated_alias(bag, "--image-topic", topics["left"])
    deprecated_alias(bag, "--right-image-topic", topics["right"])
    pose = add_robot_pose_arguments(
        bag, default_source=None,
        source_help="robot pose source: ee_pose (--ee-pose-topic), joint_states "
                    "(--joint-states-topic + --kinematics) or tf (--tf-topic + "
                    "--tf-static-topic, --base-frame -> --ee-frame); default: ee_pose when "
                    "the bag has --ee-pose-topic, else tf",
        base_help="robot base frame: the root of the /tf chain and of a URDF chain",
        ee_help="flange (tool) frame: the tip of the /tf chain and of a URDF chain",
        default_base="base_link", default_ee="tool0")
    deprecated_alias(bag, "--pose-topic", pose["ee_pose_topic"],
                     new="--robot-pose ee_pose --ee-pose-topic",
                     sets={"robot_pose": "ee_pose"})
    deprecated_alias(bag, "--joint-topic", pose["joint_states_topic"],
                     new="--robot-pose joint_states --joint-states-topic",
                     sets={"robot_pose": "joint_states"})
    deprecated_alias(bag, "--tf", pose["source"], new="--robot-pose tf", value="tf")
    window = bag.add_argument(
        "--still-window-s", type=bounded(0, 10, "s"), default=0.1, metavar="S",
        help="the robot must be still this long (s) around an image")
    translation = bag.add_argument(
        "--still-translation-m", type=bounded(0, 1, "m"), default=0.0005, metavar="M",
        help="largest robot translation within the window (m)")
    rotation = bag.add_argument(
        "--still-rotation-deg", type=bounded(0, 180, "deg"), default=0.05, metavar="DEG",
        help="largest robot rotation within the window (deg)")
    deprecated_alias(bag, "--still-window", window)
    deprecated_alias(bag, "--still-translation", translation)
    deprecated_alias(bag, "--still-rotation", rotation)


def add_handeye_calibration_arguments(group: Any, *, method_help: str) -> None:
    """The hand-eye calibration options (setup, method, refinement, outlier rejection) into
    ``group`` (a parser or an argument group)."""
    group.add_argument("--setup", choices=SETUPS, default=None,
                       help="camera on the flange (X = ee_T_cam) or fixed (X = base_T_cam); "
                            "default: the dataset's, else eye_in_hand")
    group.add_argument("--method", choices=("all", *METHODS), default="all",
                       help=method_help)
    group.add_argument("--average-solver", choices=AVERAGE_SOLVERS, default=None,
                       help="per-pair solver of the 'average' method (X from each pair of "
                            "motions, averaged; default: tsai)")
    group.add_argument("--no-refine", action="store_true",
                       help="skip the joint refinements (refined, refined_exact)")
    group.add_argument("--no-outlier-rejection", action="store_true",
                       help="keep every sample")
    group.add_argument("--robot-model", choices=ROBOT_MODELS,
                       default=DEFAULT_ROBOT_MODEL,
                       help="robot pose error model: systematic (also a pose-dependent error, "
                            "linear in the flange orientation, fitted with X: candidate "
                            "refined_systematic, written only when it predicts the held-out "
                            "samples significantly better than refined; then hand_eye.yaml "
                            "carries the robot pose correction that the hand_eye node and "
                            "process apply) or per_pose (independent noise per pose only) "
                            "(default: %(default)s)")
    factor = group.add_argument(
        "--outlier-factor", type=bounded(0, 1000, "x the median", lo_open=True), default=5.0,
        metavar="K",
        help="reject a sample whose leave-one-out board pose deviation exceeds K times the "
             "median deviation (a multiple, no unit)")
    deprecated_alias(group, "--outlier-threshold", factor)


def solve_handeye_inputs(args: argparse.Namespace) -> tuple[dict[str, Any], Any]:
    """Load the hand-eye inputs (:func:`load_handeye_inputs`), print their warnings, and solve
    with the calibration options (:func:`add_handeye_calibration_arguments`): what
    ``calibrate handeye`` and ``calibrate plan`` both start from.

    Returns:
        ``(inputs, result)``: the inputs' dict and the
        :class:`eye_in_hand.core.handeye.HandEyeResult`.

    Raises:
        HandEyeError: fewer than 3 usable samples, or the solvers' own refusals.
    """
    inputs = load_handeye_inputs(args)
    samples = inputs["samples"]
    meta = inputs["input"]
    if meta.get("summary"):
        print(f"{meta['type']}: {meta['summary']}; robot pose from {meta['pose_source']}",
              file=sys.stderr)
    for note in inputs["notes"]:
        print(f"warning: {note}", file=sys.stderr)
    for s in inputs["skipped"]:
        print(f"warning: sample {s['name']!r} skipped: {s['reason']}", file=sys.stderr)
    if len(samples) < 3:
        raise HandEyeError(f"only {len(samples)} usable samples (of {inputs['input']['count']};"
                           f" {len(inputs['skipped'])} skipped): need at least 3")
    result = calibrate_hand_eye(
        samples, inputs["setup"], cameras=inputs["views"], method=args.method,
        refine=not args.no_refine, reject_outliers=not args.no_outlier_rejection,
        outlier_threshold=args.outlier_factor, robot_model=args.robot_model,
        **({} if args.average_solver is None else {"average_solver": args.average_solver}))
    return inputs, result


def load_handeye_inputs(args: argparse.Namespace) -> dict[str, Any]:
    """The samples of the hand-eye input options (:func:`add_handeye_input_arguments`).

    Returns:
        ``samples``, ``views`` (None for pose pairs), ``setup``, ``skipped`` (name and reason
        per unusable sample), ``notes`` (warnings), ``input`` (a description for reports) and,
        when the input has it, ``ground_truth``.

    Raises:
        InputError, ConfigError, BagError: no or several inputs, unreadable files, a bag
            without what it needs (each naming the file and the option).
    """
    pairs_file = getattr(args, "pairs", None)      # None: the command takes no pose pairs
    given = [x for x in (args.dataset, pairs_file, args.bag) if x]
    if len(given) != 1:
        raise InputError("give exactly one input: DATASET_DIR, "
                         + ("--pairs FILE or " if hasattr(args, "pairs") else "")
                         + "--bag BAG")
    if pairs_file:
        pairs = load_pose_pairs(pairs_file)
        samples = [HandEyeSample(f"pair{i:03d}", a, b) for i, (a, b) in enumerate(pairs)]
        return {"samples": samples, "views": None, "setup": args.setup or "eye_in_hand",
                "skipped": [], "notes": [], "input": {"type": "pairs", "path": pairs_file,
                                                      "count": len(samples)}}
    if args.bag:
        return _load_handeye_bag(args)
    ds = load_dataset(args.dataset)
    board = BoardSpec.parse(ds.board)
    views = rig_views(ds.camera, ds.rig)
    check = BoardCheck(board, f"samples' {_view_images(views)}",
                       f"{printable(ds.root)}/dataset.yaml board:")
    notes: list[str] = []
    samples, skipped = [], []
    for s in ds.samples:
        images = {}
        for key, path in s.images.items():
            try:
                img = read_image_file(path)
            except InputError as exc:
                raise InputError(f"sample {s.name!r}: {exc}") from exc
            images["image" if key == "image" else key] = img
        obs = observe_sample(s.name, images, s.base_T_ee, board, views)
        check.add(images.get(views[0].name), not obs.reason.startswith("board not found"))
        notes.extend(obs.notes)
        if obs.sample is None:
            skipped.append({"name": s.name, "reason": obs.reason})
        else:
            samples.append(obs.sample)
    check.finish()
    return {"samples": samples, "views": views, "setup": args.setup or ds.setup,
            "skipped": skipped, "notes": notes, "ground_truth": dict(ds.ground_truth),
            "input": {"type": "dataset", "path": str(ds.root), "board": ds.board,
                      "stereo": ds.is_stereo, "count": len(ds.samples)}}


def _view_images(views: Sequence[Any]) -> str:
    """``images`` (mono) or ``left images``: the reference view's images, for messages."""
    return "images" if views[0].name == "image" else f"{views[0].name} images"


def _load_handeye_bag(args: argparse.Namespace) -> dict[str, Any]:
    """Still robot stops of a bag -> detected boards -> samples."""
    if not args.board:
        raise ConfigError("--bag needs --board (e.g. chessboard:9x6:0.025)")
    board = BoardSpec.parse(args.board)
    camera = rig = None
    if args.calibration:
        cal = Path(args.calibration)
        if cal.is_dir():
            rig = StereoRig.load(cal)
        else:
            camera = CameraModel.load_yaml(cal)
    source = args.robot_pose
    if source == "joint_states" and not args.kinematics:
        raise InputError("--kinematics: required with --robot-pose joint_states")
    kin = (load_kinematics(args.kinematics, args.urdf_base_link or args.base_frame,
                           args.urdf_tip_link or args.ee_frame)
           if source == "joint_states" else None)
    # no --robot-pose: /ee_pose when the bag has it, else /tf (read_bag_samples' choice); a
    # --ee-pose-topic of one's own is the pose topic
    pose_topic = args.ee_pose_topic if source == "ee_pose" or (
        source is None and args.ee_pose_topic != "/ee_pose") else None
    found = read_bag_samples(
        args.bag, image_topic=args.left_topic, right_image_topic=args.right_topic,
        pose_topic=pose_topic,
        joint_topic=args.joint_states_topic if source == "joint_states" else None,
        kinematics=kin, use_tf=source == "tf", base_frame=args.base_frame,
        ee_frame=args.ee_frame, stereo=None if args.calibration is None else rig is not None,
        still_window_s=args.still_window_s, still_translation_m=args.still_translation_m,
        still_rotation_deg=args.still_rotation_deg, tf_topic=args.tf_topic,
        tf_static_topic=args.tf_static_topic)
    if camera is None and rig is None:
        camera, rig = found.camera, found.rig
        if camera is None and rig is None:
            raise ConfigError(f"{args.bag}: no camera_info for {dict(found.image_topics)}: give "
                              "--calibration")
    views = rig_views(camera, rig)
    if {v.name for v in views} != set(found.image_topics):
        raise ConfigError(f"--calibration is {'stereo' if rig else 'mono'} but the bag's images "
                          f"are {sorted(found.image_topics)}")
    notes: list[str] = []
    samples, skipped = [], []
    check = BoardCheck(board, f"still stops' {_view_images(views)}")
    for s in found.samples:
        obs = observe_sample(s.name, s.images, s.base_T_ee, board, views)
        check.add(s.images.get(views[0].name), not obs.reason.startswith("board not found"))
        notes.extend(obs.notes)
        if obs.sample is None:
            skipped.append({"name": s.name, "reason": obs.reason})
        else:
            samples.append(obs.sample)
    check.finish()
    moving = sum(1 for s in found.skipped if s["reason"] == "robot moving")
    # what was found, not a warning: images taken while the arm moves are expected
    summary = (f"{found.n_images} images, {len(found.samples)} still stops, {moving} images "
               "with the robot moving")
    skipped.extend(s for s in found.skipped if "name" in s)
    if found.damage:        # damaged chunks and unusable messages, skipped: named and counted
        notes.append(f"damaged bag: {found.damage.summary()}")
        notes.extend(f"damaged: {line}" for line in found.damage.lines())
    return {"samples": samples, "views": views, "setup": args.setup or "eye_in_hand",
            "skipped": skipped, "notes": notes, "ground_truth": dict(found.ground_truth),
            "input": {"type": "bag", "path": str(args.bag), "board": args.board,
                      "stereo": rig is not None, "count": len(found.samples),
                      "image_topics": dict(found.image_topics),
                      "pose_source": found.pose_source, "summary": summary,
                      "damage": found.damage.to_dict() if found.damage is not None else None}}


# ------------------------------------------------------------------------------------------------
# the command
# ------------------------------------------------------------------------------------------------
