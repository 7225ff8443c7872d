"""``eye-in-hand locate``: locate the targets in one stereo pair read from image files.

Example::

    eye-in-hand locate --left left.png --right right.png --calibration calib/ --json

``calib/`` holds ``left.yaml`` and ``right.yaml`` as ROS's camera_calibration writes them (the
stereo geometry comes from their rectification R and projection P, the right P carrying
``-fx * B``); our ``stereo.yaml`` may be there too. Detector settings come from the node's
parameter file (default: the built-in red sphere, as in ``config/detect_triangulate.yaml``).

Every configured target is located (blob sets give one entry per blob, ``id`` =
``<name>_<k>``); ``--json`` prints a JSON list with one object per located target.

Exit codes: 0 with at least one target printed (those not located are listed on stderr); 1 on
an error (unreadable file, bad calibration or parameters); 2 when no target is located (the
reasons are printed on stderr).
"""
from __future__ import annotations

import argparse
import json
import math
import sys

import cv2
import numpy as np

from eye_in_hand.commands.common import apply_overrides, bounded
from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.core.triangulation import METHODS as TRIANGULATION_METHODS
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.io.images import read_image_file
from eye_in_hand.nodes.parameters import check_parameter_file_keys

HELP = "locate the targets in one stereo pair from image files"

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
    parser.add_argument("--radius", type=bounded(0, 10, "m", lo_open=True), metavar="R",
                        help="sphere radius of the first target in metres (default: the "
                             "parameter file's, else 0.02)")
    parser.add_argument("--method", choices=TRIANGULATION_METHODS,
                        help="triangulation method (default: the parameter file's, else "
                             "dlt)")
    parser.add_argument("--json", action="store_true",
                        help="print a JSON list, one object per located target: name, id, "
                             "point_m, covariance, residual_px, left_px, right_px")


def _read(path: str, side: str):

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
    """Locate the targets; print them (text or JSON). Returns the exit code."""
    if args.params:  # a mistyped key would run on its default, as the live node refuses it
        check_parameter_file_keys(args.params, used=["detect_triangulate"])
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
    misses = [f"{key}: {result.messages.get(key, reason)}"
              for key, reason in result.rejected.items()]
    if not result.targets:
        print(f"eye-in-hand locate: no target: {'; '.join(misses)}", file=sys.stderr)
        return EXIT_NO_TARGET
    if args.json:
        for line in misses:   # stdout holds only the JSON
            print(f"eye-in-hand locate: not located: {line}", file=sys.stderr)
        print(json.dumps([t.to_dict() for t in result.targets]))
        return 0
    for t in result.targets:
        x, y, z = t.point_m
        sx, sy, sz = (math.sqrt(t.covariance[i, i]) for i in range(3))
        label = f"'{t.id}'" if t.id == t.name else f"'{t.id}' (target '{t.name}')"
        print(f"target {label} ({config.method}), left optical frame:")
        print(f"  point_m     [{x:+.5f}, {y:+.5f}, {z:+.5f}]")
        print(f"  sigma_mm    [{sx * 1e3:.3f}, {sy * 1e3:.3f}, {sz * 1e3:.3f}]")
        print(f"  residual_px {t.residual_px:.3f}")
        print(f"  left_px     [{t.left_px[0]:.3f}, {t.left_px[1]:.3f}]")
        print(f"  right_px    [{t.right_px[0]:.3f}, {t.right_px[1]:.3f}]")
    for key, reason in result.rejected.items():
        print(f"not located: '{key}': {reason}")
    ambiguous = ", ".join(f"{k}: {v}" for k, v in result.ambiguous.items())
    if ambiguous:
        print(f"ambiguous blobs rejected: {ambiguous}")
    return 0
