"""``eye-in-hand calibrate camera``: intrinsic calibration of one camera from board images.

Inputs are image files (``--images GLOB``) or an image topic of a rosbag2 bag
(``--bag BAG --left-topic TOPIC [--every N]``). OUT_DIR receives ``camera.yaml``
(camera_calibration_parsers format), ``report.json`` and ``report.html``; everything is built in a
temporary folder next to OUT_DIR and renamed into place at the end
(:mod:`eye_in_hand.io.atomic`), so a failure leaves nothing half-written; an existing OUT_DIR is
refused unless ``--overwrite`` is given, and then replaced whole.

The input/output helpers shared with ``calibrate stereo`` live in
:mod:`eye_in_hand.commands.calibration_inputs`.
"""
from __future__ import annotations

import argparse

import numpy as np

from eye_in_hand.commands.calibration_inputs import (
    Frame,
    ImageSource,
    add_common_arguments,
    bag_count,
    check_common_arguments,
    detect_files,
    expand_glob,
    iter_bag_frames,
    options_from_args,
    progress,
    report_damage,
    report_skipped,
    view_entries,
    write_json,
)
from eye_in_hand.commands.common import add_image_topic_arguments, deprecated_alias
from eye_in_hand.core.calibration import BoardSpec, calibrate_camera, detect_board
from eye_in_hand.core.calibration.board_check import BoardCheck
from eye_in_hand.errors import BagError, CalibrationError, InputError
from eye_in_hand.io.atomic import atomic_output_dir
from eye_in_hand.io.bags import DamageLog
from eye_in_hand.report.calibration import camera_report

__all__ = ["HELP", "add_arguments", "run"]

HELP = "calibrate one camera (intrinsics, distortion) from chessboard/ChArUco images or a bag"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``calibrate camera``."""
    parser.add_argument("--images", metavar="GLOB",
                        help="image files, e.g. 'calib/*.png' (quote it)")
    topics = add_image_topic_arguments(
        parser, left_help="bag input: the camera's image topic (sensor_msgs/Image or "
                          "CompressedImage); a single camera is the left one (no default: "
                          "needed with --bag)")
    deprecated_alias(parser, "--topic", topics["left"])
    add_common_arguments(parser)
    parser.epilog = ("Writes OUT_DIR/camera.yaml, report.json, report.html. Either --images or "
                     "--bag with --left-topic.")


def _gather(args: argparse.Namespace, board) -> ImageSource:
    if bool(args.images) == bool(args.bag):
        raise InputError("give either --images GLOB or --bag BAG --left-topic TOPIC")
    if args.images:
        files = expand_glob(args.images, "--images")
        frames = detect_files(files, board, args, "camera", keep=lambda i: i == 0)
        return ImageSource("files", args.images, frames)
    if not args.left_topic:
        raise InputError("--bag needs --left-topic TOPIC (the image topic)")
    total = -(-bag_count(args.bag, args.left_topic) // args.every)
    frames = []
    size = None
    damage = DamageLog()
    check = BoardCheck(board, f"images of {args.left_topic}")  # a wrong board: say so early
    with progress(total, "camera") as bar:
        for name, stamp, image in iter_bag_frames(args.bag, args.left_topic, args.every,
                                                  damage):
            shape = (image.shape[1], image.shape[0])
            if size is None:
                size = (name, shape)
            elif shape != size[1]:
                raise CalibrationError(
                    f"{args.left_topic}: image size changes from {size[1][0]}x{size[1][1]} to "
                    f"{shape[0]}x{shape[1]} at {name}")
            det = detect_board(image, board, args.detector, subpix_window=args.subpix_window,
                               fallback=not args.no_fallback)
            check.add(image, det.found)
            frames.append(Frame(name, det, image if not frames else None, stamp))
            bar.update(1)
    check.finish()
    if not frames:
        raise BagError(f"bag {args.bag}: no images on {args.left_topic}"
                       + (f" ({damage.summary()})" if damage else ""))
    return ImageSource("bag", f"{args.bag} {args.left_topic} (every {args.every})", frames,
                       damage=damage)


def run(args: argparse.Namespace) -> int:
    """Run ``calibrate camera``; returns the exit code."""
    check_common_arguments(args)
    board = BoardSpec.parse(args.board)
    options = options_from_args(args)
    source = _gather(args, board)
    skipped = report_skipped(source.frames, "camera")
    damage = report_damage(source.damage)
    names = [f.name for f in source.frames]
    cal = calibrate_camera([f.detection for f in source.frames], names, options=options,
                           reject_outliers=args.reject_outliers,
                           outlier_threshold_px=args.outlier_threshold_px,
                           min_views=args.min_views, camera_name="camera")
    report = cal.to_dict()
    report["views"] = view_entries(source.frames, cal.views)
    report["board"] = str(board)
    report["input"] = {"kind": source.kind, "source": source.description,
                       "images": len(source.frames), "skipped": skipped,
                       "detector": args.detector}
    if damage is not None:
        report["input"]["damage"] = damage
    with atomic_output_dir(args.output, overwrite=args.overwrite) as tmp:
        cal.camera.save_yaml(tmp / "camera.yaml")
        write_json(tmp / "report.json", report)
        if not args.no_html:
            sample = next((f for f in source.frames if f.image is not None), None)
            camera_report(cal, source, board, sample_image=None if sample is None
                          else sample.image).save(tmp / "report.html")
    cam = cal.camera
    outl = [v.name for v in cal.views if v.outlier]
    print(f"camera: RMS {cal.rms_px:.4f} px over {len(cal.used_views)} views "
          f"({len(skipped)} skipped{', outliers: ' + ', '.join(outl) if outl else ''})")
    if source.damage:
        print(f"  damaged bag: {source.damage.summary()}")
    print(f"  fx {cam.fx:.3f}  fy {cam.fy:.3f}  cx {cam.cx:.3f}  cy {cam.cy:.3f}  "
          f"(std {cal.std['fx']:.3f} {cal.std['fy']:.3f} {cal.std['cx']:.3f} {cal.std['cy']:.3f})")
    print(f"  dist ({cam.distortion_model}) {np.array2string(cam.dist, precision=5)}")
    print(f"  coverage {100 * cal.coverage:.0f} % of the image; wrote {args.output}/")
    return 0
