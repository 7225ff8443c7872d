"""``eye-in-hand tune-color``: colour ranges that capture an image region.

Example::

    eye-in-hand tune-color left.png --roi 600,320,40,40 --name red

prints a block for the ``targets:`` section of the detect_triangulate parameter file, with the
HSV (and HSI) ranges from robust percentiles of the region's pixels (hue taken circularly, so
red gives a wrapping range), and how much of the region and of the rest of the image each
range captures (the second figure should be near zero).
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np

from eye_in_hand.commands.common import bounded
from eye_in_hand.core.detection import COLOR_SPACES, convert_color, range_from_samples
from eye_in_hand.errors import InputError
from eye_in_hand.io.images import read_image_file

HELP = "print HSV/HSI colour ranges that capture an image region (for the parameter file)"


def _roi(text: str) -> tuple[int, int, int, int]:
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected x,y,w,h integers, got '{text}'") from exc
    if len(vals) != 4 or vals[2] <= 0 or vals[3] <= 0 or vals[0] < 0 or vals[1] < 0:
        raise argparse.ArgumentTypeError(f"expected x,y,w,h with x, y >= 0 and w, h > 0, "
                                         f"got '{text}'")
    return vals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand tune-color``."""
    parser.add_argument("image", metavar="IMG", help="a colour image showing the target")
    parser.add_argument("--roi", required=True, type=_roi, metavar="x,y,w,h",
                        help="region inside the target (pixels)")
    parser.add_argument("--space", choices=(*COLOR_SPACES, "both"), default="both",
                        help="colour space(s) to print (default: both)")
    parser.add_argument("--name", default="red", help="target name in the printed block")
    parser.add_argument("--percentile", type=bounded(0, 49), default=5.0, metavar="P",
                        help="ranges span the P..100-P percentiles of the region, 0 to 49 "
                             "(default 5)")
    parser.add_argument("--margin", default="4,20,20", metavar="H,S,V",
                        help="widening on each side, 8-bit units (default 4,20,20)")


def run(args: argparse.Namespace) -> int:
    """Print the ranges. Returns the exit code."""

    img = read_image_file(args.image, cv2.IMREAD_COLOR)
    x, y, w, h = args.roi
    H, W = img.shape[:2]
    if x + w > W or y + h > H:
        raise InputError(f"--roi {x},{y},{w},{h} extends beyond the {W}x{H} image")
    try:
        margin = tuple(int(v) for v in args.margin.split(","))
    except ValueError as exc:
        raise InputError(f"--margin: expected H,S,V integers, got '{args.margin}'") from exc
    if not args.name or not all(c.isalnum() or c == "_" for c in args.name):
        raise InputError(f"--name: '{args.name}' must be letters, digits and underscores")
    spaces = ("hsv", "hsi") if args.space == "both" else (args.space,)
    inside = np.zeros((H, W), bool)
    inside[y:y + h, x:x + w] = True
    print("# paste under ros__parameters.targets (one block; keep the colour space you prefer)")
    for i, space in enumerate(spaces):
        conv = convert_color(img, space)
        rng = range_from_samples(conv[y:y + h, x:x + w].reshape(-1, 3), space,
                                 percentile=args.percentile, margin=margin)
        mask = rng.threshold(conv) > 0
        captured = mask[inside].mean()
        elsewhere = mask[~inside].mean() if (~inside).any() else 0.0
        prefix = "" if i == 0 else "# "
        print(f"{prefix}{args.name}:")
        print(f"{prefix}  color_space: {space}")
        print(f"{prefix}  lower: [{rng.lower[0]}, {rng.lower[1]}, {rng.lower[2]}]")
        print(f"{prefix}  upper: [{rng.upper[0]}, {rng.upper[1]}, {rng.upper[2]}]"
              f"{'   # hue wraps around 0' if rng.wraps else ''}")
        print(f"#   {space}: captures {captured * 100:.1f} % of the region and "
              f"{elsewhere * 100:.2f} % of the pixels outside it")
    return 0
