"""``eye-in-hand calibrate stereo``: calibrate a stereo rig from board image pairs.

Each camera is calibrated alone first, then everything (both cameras' intrinsics and
distortion, the extrinsic, every board pose) is refined jointly, the rig is rectified, and its
quality is checked (epipolar error, rectified row difference, board square measured back by
triangulation). Inputs are two file globs paired in sorted order (``--left GLOB --right GLOB``)
or two image topics of a bag paired by identical header stamps (``--bag BAG --left-topic T
--right-topic T [--every N]``). OUT_DIR receives ``left.yaml``, ``right.yaml``, ``stereo.yaml``,
``report.json`` and ``report.html``, all or nothing.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from eye_in_hand.commands.calibration_inputs import (
    Frame,
    add_common_arguments,
    atomic_output_dir,
    bag_count,
    check_common_arguments,
    detect_files,
    expand_glob,
    iter_bag_pairs,
    options_from_args,
    progress,
    read_image,
    report_damage,
    report_skipped,
    view_entries,
    write_json,
)
from eye_in_hand.commands.common import add_image_topic_arguments, bounded
from eye_in_hand.core.calibration import (
    STEREO_METHODS,
    BoardSpec,
    calibrate_stereo,
    detect_board,
)
from eye_in_hand.core.calibration.board_check import BoardCheck
from eye_in_hand.errors import BagError, CalibrationError, InputError
from eye_in_hand.io.bags import DamageLog
from eye_in_hand.report.calibration import stereo_report

__all__ = ["HELP", "add_arguments", "run"]

HELP = "calibrate a stereo rig (both cameras jointly, rectification, quality report)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``calibrate stereo``."""
    parser.add_argument("--left", metavar="GLOB", help="left image files, e.g. 'calib/left*.png'")
    parser.add_argument("--right", metavar="GLOB",
                        help="right image files; paired with --left in sorted order")
    add_image_topic_arguments(
        parser, left_help="bag input: left image topic (no default: needed with --bag)",
        right_help="bag input: right image topic (no default: needed with --bag)")
    add_common_arguments(parser)
    parser.add_argument("--alpha", type=bounded(0, 1), default=0.0,
                        help="rectification free scaling: 0 keeps only valid pixels, 1 keeps "
                             "every source pixel; default 0")
    parser.add_argument("--fix-intrinsics", action="store_true",
                        help="keep each camera's own calibration in the joint step (only the "
                             "extrinsic and board poses are refined)")
    parser.add_argument("--method", choices=STEREO_METHODS, default="bundle",
                        help="joint refinement: bundle (all views, both cameras, our "
                             "Levenberg-Marquardt) or opencv (cv2.stereoCalibrate on the pairs "
                             "seen by both cameras); default bundle")
    parser.epilog = ("Writes OUT_DIR/left.yaml, right.yaml, stereo.yaml, report.json, "
                     "report.html. Either --left/--right or --bag with "
                     "--left-topic/--right-topic.")


def _gather(args: argparse.Namespace, board) -> tuple[list[Frame], list[Frame], str, int]:
    files_mode = bool(args.left or args.right)
    if files_mode == bool(args.bag):
        raise InputError("give either --left GLOB --right GLOB or --bag BAG --left-topic T "
                         "--right-topic T")
    if files_mode:
        if not (args.left and args.right):
            raise InputError("--left and --right must both be given")
        lfiles = expand_glob(args.left, "--left")
        rfiles = expand_glob(args.right, "--right")
        if len(lfiles) != len(rfiles):
            raise CalibrationError(f"{len(lfiles)} left image(s) ({args.left}) but "
                                   f"{len(rfiles)} right image(s) ({args.right}); they pair up "
                                   "one to one in sorted order")
        left = detect_files(lfiles, board, args, "left")
        right = detect_files(rfiles, board, args, "right")
        ls = left[0].detection.image_size
        rs = right[0].detection.image_size
        if tuple(ls) != tuple(rs):
            raise CalibrationError(f"left images are {ls[0]}x{ls[1]} ({lfiles[0].name}) but right "
                                   f"images are {rs[0]}x{rs[1]} ({rfiles[0].name})")
        return left, right, f"files {args.left} + {args.right}", 0
    if not (args.left_topic and args.right_topic):
        raise InputError("--bag needs --left-topic and --right-topic")
    total = -(-min(bag_count(args.bag, args.left_topic), bag_count(args.bag, args.right_topic))
              // args.every)
    left = []
    right = []
    stats: dict[str, int] = {}
    size = None
    args.bag_damage = DamageLog()   # damaged chunks and images: skipped, named, counted
    check = BoardCheck(board, f"pairs' left images ({args.left_topic})")  # a wrong board: early
    with progress(total, "stereo pairs") as bar:
        for stamp, (ln, li), (rn, ri) in iter_bag_pairs(args.bag, args.left_topic,
                                                        args.right_topic, args.every, stats,
                                                        damage=args.bag_damage):
            shapes = ((li.shape[1], li.shape[0]), (ri.shape[1], ri.shape[0]))
            if shapes[0] != shapes[1]:
                raise CalibrationError(f"left image {ln} is {shapes[0][0]}x{shapes[0][1]} but "
                                       f"right image {rn} is {shapes[1][0]}x{shapes[1][1]}")
            if size is None:
                size = shapes[0]
            elif shapes[0] != size:
                raise CalibrationError(f"image size changes from {size[0]}x{size[1]} to "
                                       f"{shapes[0][0]}x{shapes[0][1]} at {ln}")
            kw = dict(subpix_window=args.subpix_window, fallback=not args.no_fallback)
            left.append(Frame(ln, detect_board(li, board, args.detector, **kw), None, stamp))
            right.append(Frame(rn, detect_board(ri, board, args.detector, **kw), None, stamp))
            check.add(li, left[-1].detection.found or right[-1].detection.found)
            bar.update(1)
    check.finish()
    if not left:
        raise BagError(f"bag {args.bag}: no image pairs with identical header stamps on "
                       f"{args.left_topic} and {args.right_topic}")
    desc = f"bag {args.bag} {args.left_topic} + {args.right_topic} (every {args.every})"
    return left, right, desc, int(stats.get("unmatched", 0))


def _pair_image(args: argparse.Namespace, left: list[Frame], right: list[Frame], cal
                ) -> tuple[tuple[np.ndarray, np.ndarray] | None, tuple | None, str]:
    """One used pair's raw images and corners for the rectified-pair figure."""
    idx = next((i for i, v in enumerate(cal.views) if v.used and v.paired and not v.outlier),
               None)
    if idx is None:
        return None, None, ""
    corners = (left[idx].detection.corners, right[idx].detection.corners)
    name = f"{left[idx].name} / {right[idx].name}"
    if args.left:
        lf = expand_glob(args.left, "--left")[idx]
        rf = expand_glob(args.right, "--right")[idx]
        return (read_image(lf), read_image(rf)), corners, name
    for k, (_stamp, (_ln, li), (_rn, ri)) in enumerate(   # damage was reported in the first pass
            iter_bag_pairs(args.bag, args.left_topic, args.right_topic, args.every,
                           damage=DamageLog())):
        if k == idx:
            return (li, ri), corners, name
    return None, None, ""


def run(args: argparse.Namespace) -> int:
    """Run ``calibrate stereo``; returns the exit code."""
    check_common_arguments(args)
    board = BoardSpec.parse(args.board)
    options = options_from_args(args)
    left, right, description, unmatched = _gather(args, board)
    skipped = report_skipped(left, "left") + report_skipped(right, "right")
    damage = report_damage(getattr(args, "bag_damage", None))
    if unmatched:
        print(f"eye-in-hand: stereo: {unmatched} image(s) had no partner with the same header "
              "stamp and were ignored", file=sys.stderr)
    cal = calibrate_stereo([f.detection for f in left], [f.detection for f in right],
                           [f.name for f in left], [f.name for f in right], board=board,
                           options=options, method=args.method, fix_intrinsics=args.fix_intrinsics,
                           alpha=args.alpha, reject_outliers=args.reject_outliers,
                           outlier_threshold_px=args.outlier_threshold_px,
                           min_views=args.min_views)
    report = cal.to_dict()
    by_left = {v["file"]: v for v in report["views"]}
    views = []
    for lf, rf in zip(left, right, strict=True):
        entry = dict(by_left[lf.name])
        if not lf.detection.found:
            entry["left_reason"] = lf.detection.reason
        if not rf.detection.found:
            entry["right_reason"] = rf.detection.reason
        views.append(entry)
    report["views"] = views
    report["left"]["views"] = view_entries(left, cal.left.views)
    report["right"]["views"] = view_entries(right, cal.right.views)
    report["board"] = str(board)
    report["input"] = {"source": description, "pairs": len(left), "skipped": skipped,
                       "unmatched": unmatched, "detector": args.detector}
    if damage is not None:
        report["input"]["damage"] = damage
    with atomic_output_dir(args.output, overwrite=args.overwrite) as tmp:
        cal.rig.save(tmp)
        write_json(tmp / "report.json", report)
        if not args.no_html:
            images, corners, pair_name = _pair_image(args, left, right, cal)
            names = [(lf.name, rf.name) for lf, rf in zip(left, right, strict=True)]
            stereo_report(cal, names, board, description, skipped, images, corners, pair_name
                          ).save(tmp / "report.html")
    q = cal.quality
    st = report["stereo"]
    print(f"stereo: joint RMS {cal.rms_px:.4f} px over {st['n_pairs_used']} pairs "
          f"({len(skipped)} image(s) skipped"
          f"{', outliers: ' + ', '.join(st['outliers']) if st['outliers'] else ''})")
    print(f"  baseline {cal.rig.baseline:.6g} (std {cal.std['baseline']:.2g}), "
          f"T {np.array2string(cal.rig.T, precision=5)}, rotation {st['rotation_deg']:.3f} deg")
    print(f"  epipolar error {q.epipolar_error_px:.4f} px, rectified |dy| mean "
          f"{q.rectified_dy_mean_px:.4f} px (max {q.rectified_dy_max_px:.3f}), square measured "
          f"{q.square_measured_mean:.6g} +- {q.square_measured_std:.2g} (board {board.square:g})")
    for side, cam in (("left", cal.rig.left), ("right", cal.rig.right)):
        print(f"  {side}: fx {cam.fx:.3f} fy {cam.fy:.3f} cx {cam.cx:.3f} cy {cam.cy:.3f} "
              f"dist {np.array2string(cam.dist, precision=4)}")
    print(f"  wrote {args.output}/")
    return 0
