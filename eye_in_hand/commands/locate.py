"""``eye-in-hand locate``: locate the target in one stereo pair read from image files.

Example::

    eye-in-hand locate --left left.png --right right.png --calibration calib/ --json

``calib/`` holds ``left.yaml`` and ``right.yaml`` as ROS's camera_calibration writes them (the
stereo geometry comes from their rectification R and projection P, the right P carrying
``-fx * B``); our ``stereo.yaml`` may be there too. Detector settings come from the node's
parameter file (default: the built-in red sphere, as in ``config/detect_triangulate.yaml``).

Exit codes: 0 with the point printed; 1 on an error (unreadable file, bad calibration or
parameters); 2 when there is no target (the reason is printed on stderr).
"""
from __future__ import annotations

import argparse
import json
import sys

from eye_in_hand.commands.common import apply_overrides

HELP = "locate the target in one stereo pair from image files"

#: Exit code when the pair was processed but holds no (acceptable) target.
EXIT_NO_TARGET = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand locate``."""
    parser.add_argument("--left", required=True, metavar="IMG", help="left image file")
    parser.add_argument("--right", required=True, metavar="IMG", help="right image file")
    parser.add_argument("--calibration", required=True, metavar="DIR",
                        help="directory with left.yaml and right.yaml (ROS camera_calibration "
                             "files; stereo.yaml optional)")
    parser.add_argument("--params", metavar="FILE",
                        help="the detect_triangulate parameter file (default: built-in red "
                             "sphere)")
    parser.add_argument("--radius", type=float, metavar="R",
                        help="sphere radius of the first target in metres (overrides the "
                             "parameter file)")
    parser.add_argument("--method", choices=("dlt", "disparity", "optimal"),
                        help="triangulation method (overrides the parameter file)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object: point_m, covariance, residual_px, "
                             "left_px, right_px")


def _read(path: str, side: str):
    import cv2
    import numpy as np

    from eye_in_hand.errors import InputError

    from eye_in_hand.io.images import read_image_file

    try:
        img = read_image_file(path)
    except InputError as exc:
        raise InputError(f"--{side} {exc}") from exc
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"--{side} {path}: a colour image is needed, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise InputError(f"--{side} {path}: an 8-bit image is needed, got {img.dtype}")
    return img




def run(args: argparse.Namespace) -> int:
    """Locate the target; print it (text or JSON). Returns the exit code."""
    import math

    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator import StereoLocator, load_locator_config
    from eye_in_hand.errors import ConfigError, InputError

    config = apply_overrides(load_locator_config(args.params), radius=args.radius,
                             method=args.method)
    rig = StereoRig.load(args.calibration)
    try:
        locator = StereoLocator(rig, config)
    except InputError as exc:
        raise ConfigError(f"--calibration {args.calibration}: {exc}") from exc
    left, right = _read(args.left, "left"), _read(args.right, "right")
    for side, img, cam in (("left", left, rig.left), ("right", right, rig.right)):
        if (img.shape[1], img.shape[0]) != cam.size:
            raise InputError(f"--{side}: image is {img.shape[1]}x{img.shape[0]} but the "
                             f"calibration is {cam.width}x{cam.height}")
    result = locator.locate(left, right)
    first = result.first
    if first is None:
        reason = result.messages.get(result.first_name, result.rejected.get(result.first_name))
        print(f"eye-in-hand locate: no target: {reason}", file=sys.stderr)
        return EXIT_NO_TARGET
    if args.json:
        print(json.dumps(first.to_dict()))
        return 0
    x, y, z = first.point_m
    sx, sy, sz = (math.sqrt(first.covariance[i, i]) for i in range(3))
    print(f"target '{first.name}' ({config.method}), left optical frame:")
    print(f"  point_m     [{x:+.5f}, {y:+.5f}, {z:+.5f}]")
    print(f"  sigma_mm    [{sx * 1e3:.3f}, {sy * 1e3:.3f}, {sz * 1e3:.3f}]")
    print(f"  residual_px {first.residual_px:.3f}")
    print(f"  left_px     [{first.left_px[0]:.3f}, {first.left_px[1]:.3f}]")
    print(f"  right_px    [{first.right_px[0]:.3f}, {first.right_px[1]:.3f}]")
    return 0
