"""``eye-in-hand calibrate handeye``: hand-eye calibration (AX = XB) from a dataset, pose pairs
or a bag, with every solver, a joint refinement and a report of its own error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from eye_in_hand.commands.calibration_inputs import (
    add_handeye_calibration_arguments,
    add_handeye_input_arguments,
    solve_handeye_inputs,
)
from eye_in_hand.commands.common import add_output_argument
from eye_in_hand.core.handeye import FRAMES
from eye_in_hand.core.transforms import matrix_to_quat_xyzw
from eye_in_hand.io.atomic import atomic_output_dir, check_output_dir
from eye_in_hand.report.handeye import write_outputs

HELP = "hand-eye calibration (AX = XB) from a dataset, pose pairs or a bag"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    add_handeye_input_arguments(parser)
    opt = parser.add_argument_group("calibration")
    add_handeye_calibration_arguments(
        opt, method_help="the method whose X is written to hand_eye.yaml; 'all' = the one "
                         "that best predicts the held-out samples in leave-one-out (default: "
                         "%(default)s); every method is always in report.json")
    opt.add_argument("--parent-frame", default=None,
                     help="parent frame id of X (default: tool0 eye-in-hand, base_link "
                          "eye-to-hand)")
    opt.add_argument("--child-frame", default="camera_left_optical_frame",
                     help="camera frame id (default: %(default)s)")
    opt.add_argument("--no-html", action="store_true", help="do not write report.html")
    add_output_argument(parser, metavar="OUT_DIR",
                        help="output folder: hand_eye.yaml, report.json, report.html; written "
                             "whole or not at all (must not exist, or give --overwrite)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing OUT_DIR (whole, once the new one is complete)")


def run(args: argparse.Namespace) -> int:
    """Run the calibration and write hand_eye.yaml, report.json and report.html."""
    check_output_dir(args.output, overwrite=args.overwrite,  # refuse now, not after the work
                     inputs=[args.dataset, args.pairs, args.bag, args.calibration,
                             args.kinematics])
    inputs, result = solve_handeye_inputs(args)
    samples = inputs["samples"]
    setup = inputs["setup"]
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
    corr = result.pose_correction if setup == "eye_in_hand" else None
    if corr is not None:
        used = set(result.sample_names)
        d = corr.delta(np.stack([s.base_T_ee for s in samples if s.name in used]))
        print(f"robot pose correction (systematic model) in hand_eye.yaml: up to "
              f"{1000 * float(np.max(np.linalg.norm(d[:, :3], axis=1))):.2f} mm, "
              f"{float(np.degrees(np.max(np.linalg.norm(d[:, 3:], axis=1)))):.3f} deg over the "
              "samples; the hand_eye node and process apply it (/tf_static carries X alone)")
    rejected = {f"sample {r.name!r} rejected: {r.reason}" for r in result.rejected}
    for r in result.rejected:
        print(f"rejected sample {r.name!r}: {r.reason}")
    for w in result.warnings:
        if w not in rejected:
            print(f"warning: {w}", file=sys.stderr)
    print(f"wrote {out / 'hand_eye.yaml'}, {out / 'report.json'}"
          + ("" if args.no_html else f", {out / 'report.html'}"))
    return 0
