"""``eye-in-hand calibrate handeye``: hand-eye calibration (AX = XB) from a dataset, pose pairs
or a bag, with every solver, a joint refinement and a report of its own error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.errors import ConfigError, HandEyeError, InputError
from eye_in_hand.io.atomic import atomic_output_dir, check_output_dir
from eye_in_hand.report.handeye import write_outputs

HELP = "hand-eye calibration (AX = XB) from a dataset, pose pairs or a bag"

_METHOD_CHOICES = ("all", "tsai", "park", "horaud", "daniilidis", "andreff", "kronecker",
                   "average", "refined_exact", "refined")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    src = parser.add_argument_group("input (exactly one)")
    src.add_argument("dataset", nargs="?", metavar="DATASET_DIR",
                     help="dataset folder with dataset.yaml (images + robot poses)")
    src.add_argument("--pairs", metavar="FILE",
                     help="JSON list of [base_T_ee, cam_T_board] 4x4 row-major pairs (metres)")
    src.add_argument("--bag", metavar="BAG", help="rosbag2 bag with images and robot poses")
    bag = parser.add_argument_group("bag input")
    bag.add_argument("--board", metavar="SPEC",
                     help="board spec for --bag, e.g. chessboard:9x6:0.025")
    bag.add_argument("--calibration", metavar="PATH",
                     help="camera calibration for --bag: a camera YAML (mono) or a folder "
                          "with left.yaml, right.yaml [, stereo.yaml] (stereo); default: the "
                          "bag's camera_info")
    bag.add_argument("--image-topic", default=None,
                     help="image topic (left camera for stereo); a suffix such as "
                          "left/image_raw matches /stereo/left/image_raw (default: the only "
                          "image topic, or the one with 'left' in its name)")
    bag.add_argument("--right-image-topic", default=None,
                     help="right image topic for a stereo rig (default: the left topic with "
                          "'left' replaced by 'right', when the bag has it)")
    bag.add_argument("--pose-topic", default=None,
                     help="geometry_msgs/PoseStamped robot pose topic (default: /ee_pose when "
                          "the bag has it, else /tf)")
    bag.add_argument("--joint-topic", default=None,
                     help="sensor_msgs/JointState topic, with --kinematics")
    bag.add_argument("--kinematics", default=None,
                     help="kinematic chain for --joint-topic: 'ur5e', a URDF file "
                          "(--base-frame to --ee-frame) or a DH YAML file (or a world.yaml)")
    bag.add_argument("--tf", action="store_true",
                     help="take the robot pose from /tf (--base-frame to --ee-frame)")
    bag.add_argument("--base-frame", default="base_link", help="(default: %(default)s)")
    bag.add_argument("--ee-frame", default="tool0", help="(default: %(default)s)")
    bag.add_argument("--still-window", type=float, default=0.1, metavar="S",
                     help="the robot must be still this long (s) around an image "
                          "(default: %(default)s)")
    bag.add_argument("--still-translation", type=float, default=0.0005, metavar="M",
                     help="largest robot translation within the window, m (default: "
                          "%(default)s)")
    bag.add_argument("--still-rotation", type=float, default=0.05, metavar="DEG",
                     help="largest robot rotation within the window, deg (default: "
                          "%(default)s)")
    opt = parser.add_argument_group("calibration")
    opt.add_argument("--setup", choices=("eye_in_hand", "eye_to_hand"), default=None,
                     help="camera on the flange (X = ee_T_cam) or fixed (X = base_T_cam); "
                          "default: the dataset's, else eye_in_hand")
    opt.add_argument("--method", choices=_METHOD_CHOICES, default="all",
                     help="the method whose X is written to hand_eye.yaml; 'all' = the one "
                          "that best predicts the held-out samples in leave-one-out (default: "
                          "%(default)s); every method is always in report.json")
    opt.add_argument("--average-solver", choices=("tsai", "kronecker"), default=None,
                     help="per-pair solver of the 'average' method (X from each pair of "
                          "motions, averaged; default: tsai)")
    opt.add_argument("--no-refine", action="store_true",
                     help="skip the joint refinements (refined, refined_exact)")
    opt.add_argument("--no-outlier-rejection", action="store_true",
                     help="keep every sample")
    opt.add_argument("--outlier-threshold", type=float, default=5.0, metavar="K",
                     help="reject a sample whose leave-one-out board pose deviation exceeds K "
                          "times the median (default: %(default)s)")
    opt.add_argument("--parent-frame", default=None,
                     help="parent frame id of X (default: tool0 eye-in-hand, base_link "
                          "eye-to-hand)")
    opt.add_argument("--child-frame", default="camera_left_optical_frame",
                     help="camera frame id (default: %(default)s)")
    opt.add_argument("--no-html", action="store_true", help="do not write report.html")
    parser.add_argument("-o", "--output", required=True, metavar="OUT_DIR",
                        help="output folder: hand_eye.yaml, report.json, report.html; written "
                             "whole or not at all (must not exist, or give --overwrite)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing OUT_DIR (whole, once the new one is complete)")


def _load_inputs(args: argparse.Namespace) -> dict[str, Any]:
    """Return samples, views, setup, skipped list and an input description."""
    # local: core.handeye and core.calibration load SciPy and OpenCV (~0.45 s at CLI
    # start-up), io.datasets ~90 ms
    from eye_in_hand.core.calibration import BoardSpec
    from eye_in_hand.core.handeye import HandEyeSample
    from eye_in_hand.core.handeye.observe import observe_sample, rig_views
    from eye_in_hand.io.datasets import load_dataset, load_pose_pairs

    given = [x for x in (args.dataset, args.pairs, args.bag) if x]
    if len(given) != 1:
        raise InputError("give exactly one input: DATASET_DIR, --pairs FILE or --bag BAG")
    if args.pairs:
        pairs = load_pose_pairs(args.pairs)
        samples = [HandEyeSample(f"pair{i:03d}", a, b) for i, (a, b) in enumerate(pairs)]
        return {"samples": samples, "views": None, "setup": args.setup or "eye_in_hand",
                "skipped": [], "notes": [], "input": {"type": "pairs", "path": args.pairs,
                                                      "count": len(samples)}}
    if args.bag:
        return _load_bag(args)
    # local: io.images loads OpenCV (~25 ms at CLI start-up)
    from eye_in_hand.io.images import read_image_file

    ds = load_dataset(args.dataset)
    board = BoardSpec.parse(ds.board)
    views = rig_views(ds.camera, ds.rig)
    samples, skipped, notes = [], [], []
    for s in ds.samples:
        images = {}
        for key, path in s.images.items():
            try:
                img = read_image_file(path)
            except InputError as exc:
                raise InputError(f"sample {s.name!r}: {exc}") from exc
            images["image" if key == "image" else key] = img
        obs = observe_sample(s.name, images, s.base_T_ee, board, views)
        notes.extend(obs.notes)
        if obs.sample is None:
            skipped.append({"name": s.name, "reason": obs.reason})
        else:
            samples.append(obs.sample)
    return {"samples": samples, "views": views, "setup": args.setup or ds.setup,
            "skipped": skipped, "notes": notes, "ground_truth": dict(ds.ground_truth),
            "input": {"type": "dataset", "path": str(ds.root), "board": ds.board,
                      "stereo": ds.is_stereo, "count": len(ds.samples)}}


def _load_bag(args: argparse.Namespace) -> dict[str, Any]:
    """Still robot stops of a bag -> detected boards -> samples."""
    # local: as in _load_inputs (SciPy and OpenCV, ~0.45 s at CLI start-up)
    from eye_in_hand.core.calibration import BoardSpec
    from eye_in_hand.core.camera import CameraModel, StereoRig
    from eye_in_hand.core.handeye.observe import observe_sample, rig_views
    from eye_in_hand.io.datasets import read_bag_samples

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
    # local: io.kinematics loads scipy.optimize (~0.3 s); only --kinematics needs it
    from eye_in_hand.io.kinematics import load_kinematics

    kin = (load_kinematics(args.kinematics, args.base_frame, args.ee_frame)
           if args.kinematics else None)
    found = read_bag_samples(
        args.bag, image_topic=args.image_topic, right_image_topic=args.right_image_topic,
        pose_topic=args.pose_topic, joint_topic=args.joint_topic, kinematics=kin,
        use_tf=args.tf, base_frame=args.base_frame, ee_frame=args.ee_frame,
        stereo=None if args.calibration is None else rig is not None,
        still_window_s=args.still_window, still_translation_m=args.still_translation,
        still_rotation_deg=args.still_rotation)
    if camera is None and rig is None:
        camera, rig = found.camera, found.rig
        if camera is None and rig is None:
            raise ConfigError(f"{args.bag}: no camera_info for {dict(found.image_topics)}: give "
                              "--calibration")
    views = rig_views(camera, rig)
    if {v.name for v in views} != set(found.image_topics):
        raise ConfigError(f"--calibration is {'stereo' if rig else 'mono'} but the bag's images "
                          f"are {sorted(found.image_topics)}")
    samples, skipped, notes = [], [], []
    for s in found.samples:
        obs = observe_sample(s.name, s.images, s.base_T_ee, board, views)
        notes.extend(obs.notes)
        if obs.sample is None:
            skipped.append({"name": s.name, "reason": obs.reason})
        else:
            samples.append(obs.sample)
    moving = sum(1 for s in found.skipped if s["reason"] == "robot moving")
    notes.append(f"bag: {found.n_images} images, {len(found.samples)} still stops, {moving} "
                 f"images with the robot moving; robot pose from {found.pose_source}")
    skipped.extend(s for s in found.skipped if "name" in s)
    if found.damage:        # damaged chunks and unusable messages, skipped: named and counted
        notes.append(f"damaged bag: {found.damage.summary()}")
        notes.extend(f"damaged: {line}" for line in found.damage.lines())
    return {"samples": samples, "views": views, "setup": args.setup or "eye_in_hand",
            "skipped": skipped, "notes": notes, "ground_truth": dict(found.ground_truth),
            "input": {"type": "bag", "path": str(args.bag), "board": args.board,
                      "stereo": rig is not None, "count": len(found.samples),
                      "image_topics": dict(found.image_topics),
                      "pose_source": found.pose_source,
                      "damage": found.damage.to_dict() if found.damage is not None else None}}


def run(args: argparse.Namespace) -> int:
    """Run the calibration and write hand_eye.yaml, report.json and report.html."""
    # local: core.handeye loads SciPy (~0.45 s at CLI start-up); core.transforms ~3 ms
    from eye_in_hand.core.handeye import FRAMES, calibrate_hand_eye
    from eye_in_hand.core.transforms import matrix_to_quat_xyzw

    check_output_dir(args.output, overwrite=args.overwrite,  # refuse now, not after the work
                     inputs=[args.dataset, args.pairs, args.bag, args.calibration,
                             args.kinematics])
    inputs = _load_inputs(args)
    samples = inputs["samples"]
    setup = inputs["setup"]
    for note in inputs["notes"]:
        print(f"warning: {note}", file=sys.stderr)
    for s in inputs["skipped"]:
        print(f"warning: sample {s['name']!r} skipped: {s['reason']}", file=sys.stderr)
    if len(samples) < 3:
        raise HandEyeError(f"only {len(samples)} usable samples (of {inputs['input']['count']};"
                           f" {len(inputs['skipped'])} skipped): need at least 3")
    result = calibrate_hand_eye(
        samples, setup, cameras=inputs["views"], method=args.method,
        refine=not args.no_refine, reject_outliers=not args.no_outlier_rejection,
        outlier_threshold=args.outlier_threshold,
        **({} if args.average_solver is None else {"average_solver": args.average_solver}))
    parent = args.parent_frame or FRAMES[setup][0]
    out = Path(args.output)
    with atomic_output_dir(out, overwrite=args.overwrite) as tmp:
        write_outputs(tmp, result, samples, setup=setup, parent_frame=parent,
                      child_frame=args.child_frame, input_meta=inputs["input"],
                      skipped=inputs["skipped"], notes=inputs["notes"],
                      ground_truth=inputs.get("ground_truth"), html=not args.no_html)
    sel = result.methods[result.selected]
    calib_quat = matrix_to_quat_xyzw(result.X[:3, :3])
    t = sel.X[:3, 3]
    print(f"hand-eye ({setup}, {result.selected}, {len(result.sample_names)} samples): "
          f"{parent} -> {args.child_frame} translation [{t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}] m, "
          f"quat_xyzw {[round(v, 6) for v in calib_quat.tolist()]}")
    print(f"selected {result.selected}: {result.selection_reason}")
    if np.isfinite(sel.std_mm):
        print(f"1-sigma uncertainty: {sel.std_mm:.3f} mm, {sel.std_deg:.4f} deg")
    avg = result.methods["average"].average if "average" in result.methods else None
    if avg is not None:
        print(f"average ({avg['solver']} per pair): {avg['n_pairs_used']} pairs of motions used "
              f"of {avg['n_pairs_candidates']}, spread {avg['spread']['rot_std_deg']:.4f} deg / "
              f"{avg['spread']['trans_std_mm']:.3f} mm RMS")
    noise = result.robot_pose_noise
    if noise is not None:
        print(f"robot pose noise (estimated, 1 sigma per axis): "
              f"{1000 * noise['translation_sigma_m']:.3f} mm, "
              f"{np.degrees(noise['rotation_sigma_rad']):.4f} deg")
    budget = result.error_budget
    if budget is not None:
        parts = ", ".join(f"{k[:-3].replace('_', ' ')} {budget[k]:.2f}"
                          for k in ("camera_mm", "robot_mm", "estimate_mm")
                          if budget.get(k) is not None)
        print(f"error budget (held-out board position {budget['held_out_mm']:.2f} mm RMS): "
              f"{parts} mm; {budget['advice']}")
    rejected = {f"sample {r.name!r} rejected: {r.reason}" for r in result.rejected}
    for r in result.rejected:
        print(f"rejected sample {r.name!r}: {r.reason}")
    for w in result.warnings:
        if w not in rejected:
            print(f"warning: {w}", file=sys.stderr)
    print(f"wrote {out / 'hand_eye.yaml'}, {out / 'report.json'}"
          + ("" if args.no_html else f", {out / 'report.html'}"))
    return 0
