"""``eye-in-hand calibrate plan``: the next robot poses to take for a hand-eye calibration.

Reads the same inputs as ``calibrate handeye`` (a dataset folder or a bag, with the same
options, from :mod:`.calibration_inputs`), calibrates, and prints the predicted 1-sigma of X
now and the flange poses that would most reduce it (:mod:`eye_in_hand.core.handeye.plan`);
``-o FILE`` writes them as YAML.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eye_in_hand.commands.calibration_inputs import (
    add_handeye_calibration_arguments,
    add_handeye_input_arguments,
    solve_handeye_inputs,
)
from eye_in_hand.commands.common import add_output_argument, bounded
from eye_in_hand.core.handeye import suggest_next_poses
from eye_in_hand.core.handeye.plan import CRITERIA, PlanConfig
from eye_in_hand.core.transforms import to_xyz_quat
from eye_in_hand.errors import InputError
from eye_in_hand.io.atomic import OutputError, OutputExistsError, atomic_write_text

HELP = "suggest the next robot poses for a hand-eye calibration (dataset or bag)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options (defaults None: :class:`PlanConfig`'s, applied in
    :func:`run`, so that ``--help`` does not load the numerics)."""
    add_handeye_input_arguments(parser, pairs=False)   # pose pairs have no corners
    add_handeye_calibration_arguments(
        parser.add_argument_group("calibration"),
        method_help="the method whose X the plan starts from; 'all' = the one calibrate "
                    "handeye selects (default: %(default)s)")
    plan = parser.add_argument_group("plan (defaults: core.handeye.plan.PlanConfig's)")
    add = plan.add_argument
    add("--count", type=bounded(1, 20, integer=True), metavar="N",
        help="suggestions, each assuming the earlier ones are taken (default 3)")
    add("--noise-px", type=bounded(0, 100, "px", lo_open=True), metavar="PX",
        help="corner noise, 1 sigma per coordinate (default: the refinement's estimate, else "
             "0.5)")
    add("--robot-sigma-mm", type=bounded(0, 100, "mm"), metavar="MM",
        help="robot flange position noise, 1 sigma per axis (default 0.2)")
    add("--robot-sigma-deg", type=bounded(0, 10, "deg"), metavar="DEG",
        help="robot flange rotation noise, 1 sigma per axis (default 0.0229, i.e. 0.4 mrad)")
    add("--max-tilt", type=bounded(0, 89.9, "deg", lo_open=True), metavar="DEG",
        help="largest angle between the optical axis and the board normal (default 45)")
    add("--distance-margin", type=bounded(0, 0.99), metavar="F",
        help="camera-board distance within the reached range +- this fraction (default 0.2)")
    add("--max-step", type=bounded(0, 10, "m", lo_open=True), metavar="M",
        help="a suggestion's flange position within this of a reached pose (default 0.15)")
    add("--max-step-deg", type=bounded(0, 180, "deg", lo_open=True), metavar="DEG",
        help="... and its flange rotation within this of that pose (default 45)")
    add("--margin-px", type=bounded(0, 10000, "px"), metavar="PX",
        help="every board corner, and the outer squares, this far inside every image "
             "(default 20)")
    add("--candidates", type=bounded(1, 100000, integer=True), metavar="N",
        help="admissible candidate poses scored (default 500)")
    add("--seed", type=bounded(0, 2147483647, integer=True),
        help="random seed of the candidates (default 0)")
    add("--criterion", choices=CRITERIA, default=None,
        help="trace: (std_mm / target_mm)^2 + (std_deg / target_deg)^2; logdet: log det of "
             "the covariance of X (default trace)")
    add("--target-mm", type=bounded(0, 1000, "mm", lo_open=True), metavar="MM",
        help="translation weight of the trace criterion (default 0.3)")
    add("--target-deg", type=bounded(0, 180, "deg", lo_open=True), metavar="DEG",
        help="rotation weight of the trace criterion (default 0.03)")
    add_output_argument(parser, metavar="FILE", required=False,
                        help="write the plan as YAML (must not exist, or give --overwrite; "
                                 "default: print it only)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing FILE")


# option -> PlanConfig field (and the factor from the option's unit to the field's)
_OPTIONS = {"count": ("count", None), "noise_px": ("noise_px", None),
            "robot_sigma_mm": ("robot_sigma_pos_m", 1e-3),
            "robot_sigma_deg": ("robot_sigma_rot_rad", math.pi / 180.0),
            "max_tilt": ("max_tilt_deg", None), "distance_margin": ("distance_margin", None),
            "max_step": ("max_step_m", None), "max_step_deg": ("max_step_deg", None),
            "margin_px": ("margin_px", None), "candidates": ("candidates", None),
            "seed": ("seed", None), "criterion": ("criterion", None),
            "target_mm": ("target_mm", None), "target_deg": ("target_deg", None)}


def _check_output(args: argparse.Namespace) -> Path | None:
    if args.output is None:
        return None
    out = Path(args.output)
    if out.is_dir():
        raise OutputError(f"-o {args.output}: is a folder; give a file name")
    if out.exists() or out.is_symlink():
        real = out.resolve()
        for item in (args.dataset, args.bag, args.calibration, args.kinematics):
            if item and Path(item).resolve() == real:
                raise OutputError(f"-o {args.output}: is the input {item}; choose another "
                                  "output")
        if not args.overwrite:
            raise OutputExistsError(f"-o {args.output}: exists already (give --overwrite to "
                                    "replace it, or choose another output)")
    if not out.parent.is_dir():
        raise OutputError(f"-o {args.output}: the folder {out.parent} does not exist")
    return out


def _config(args: argparse.Namespace, noise_px: float | None = None):
    """The :class:`PlanConfig` of the options given; a bad value names its option."""

    fields: dict[str, Any] = {}
    for option, (field, factor) in _OPTIONS.items():
        v = getattr(args, option)
        if option == "noise_px" and v is None:
            v = noise_px
        if v is None:
            continue
        flag = "--" + option.replace("_", "-")
        if isinstance(v, float) and not (math.isfinite(v) and v >= 0):
            raise InputError(f"{flag} must be a finite number >= 0, got {v}")
        fields[field] = v * factor if factor is not None else v
    try:
        return PlanConfig(**fields)
    except InputError as exc:
        text = str(exc)
        for option, (field, _) in _OPTIONS.items():
            if text.startswith(f"plan config: {field} "):
                text = "--" + option.replace("_", "-") + text[len(f"plan config: {field}"):]
        raise InputError(text) from exc


def run(args: argparse.Namespace) -> int:
    """Calibrate, plan, print the suggestions and write them (``-o``)."""

    if bool(args.dataset) == bool(args.bag):                  # before any work
        raise InputError("give exactly one input: DATASET_DIR or --bag BAG")
    out = _check_output(args)                       # refuse now, not after the work
    _config(args)                                   # bad plan options fail before the work
    inputs, result = solve_handeye_inputs(args)
    samples, setup, views = inputs["samples"], inputs["setup"], inputs["views"]
    sel = result.methods[result.selected]
    estimate = None
    if args.noise_px is None and result.refinement is not None:
        estimate = result.refinement.sigmas.get("px")
    config = _config(args, None if estimate is None else float(estimate))
    kept = [s for s in samples if s.name in set(result.sample_names)]
    plan = suggest_next_poses(kept, result.X, setup, views, Y=sel.Y, config=config)

    base = args.base_frame
    t, q = to_xyz_quat(result.X)
    print(f"hand-eye ({setup}, {result.selected}, {len(kept)} samples): translation "
          f"[{t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}] m, quat_xyzw "
          f"{[round(v, 6) for v in q.tolist()]}")
    if np.isfinite(sel.std_mm):
        print(f"reported 1-sigma ({result.selected}): {sel.std_mm:.3f} mm, "
              f"{sel.std_deg:.4f} deg")
    print(f"predicted 1-sigma now: {plan.std_mm:.3f} mm, {plan.std_deg:.4f} deg (corner noise "
          f"{config.noise_px:.3g} px, robot {1000 * config.robot_sigma_pos_m:.3g} mm / "
          f"{math.degrees(config.robot_sigma_rot_rad):.3g} deg per axis)")
    print(f"next flange poses ({base} -> {args.ee_frame}; {plan.candidates} admissible "
          f"candidates, {plan.criterion} criterion), each assuming the earlier ones are taken:")
    for i, s in enumerate(plan.suggestions, 1):
        xyz, quat = to_xyz_quat(s.base_T_ee)
        print(f"  {i}: xyz [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}] m, quat_xyzw "
              f"[{quat[0]:.5f}, {quat[1]:.5f}, {quat[2]:.5f}, {quat[3]:.5f}], distance "
              f"{s.distance_m:.3f} m, tilt {s.tilt_deg:.1f} deg -> 1-sigma {s.std_mm:.3f} mm, "
              f"{s.std_deg:.4f} deg")
    if len(plan.suggestions) < config.count:
        print(f"warning: only {len(plan.suggestions)} admissible poses found", file=sys.stderr)
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if out is not None:
        doc = {"setup": setup, "base_frame": base, "ee_frame": args.ee_frame,
               "method": result.selected, "samples": len(kept),
               "X": {"xyz": [float(v) for v in t], "quat_xyzw": [float(v) for v in q]},
               "reported_std_mm": float(sel.std_mm) if np.isfinite(sel.std_mm) else None,
               "reported_std_deg": float(sel.std_deg) if np.isfinite(sel.std_deg) else None,
               **plan.to_dict()}
        atomic_write_text(out, "# eye-in-hand calibrate plan: the next flange poses "
                          "(base_T_ee), best first\n"
                          + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
        print(f"wrote {os.fspath(out)}")
    return 0
