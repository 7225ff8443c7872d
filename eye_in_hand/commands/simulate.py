"""``eye-in-hand simulate``: record a synthetic scenario as a rosbag2 bag or a calibration
dataset."""
from __future__ import annotations

import argparse
import math
import re
import shutil
import sys
from pathlib import Path

from tqdm import tqdm

from eye_in_hand.commands.common import add_output_argument, bounded, deprecated_alias
from eye_in_hand.errors import InputError
from eye_in_hand.io.atomic import atomic_output_dir, check_output_dir
from eye_in_hand.io.bags import STORAGES
from eye_in_hand.sim.output import RenderOptions, recording_counts, write_bag, write_dataset
from eye_in_hand.sim.robot_error import RobotErrorSpec
from eye_in_hand.sim.world import World

HELP = "simulate the eye-in-hand world: write a bag or a calibration dataset with ground truth"

_DEFAULT_FRAMES = {"calibration": 16, "localization": 90}


#: the largest image side ``--size`` accepts (pixels)
MAX_SIDE = 16384


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or not (16 <= int(m.group(1)) <= MAX_SIDE and 16 <= int(m.group(2)) <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"expected WxH with W, H within [16, {MAX_SIDE}], "
                                         f"got {text!r}")
    return int(m.group(1)), int(m.group(2))


# The cost model of the estimate printed before the work (measured on the reference machine
# under load: 30 pairs at 1280x720, supersample 3: 72 s, 90 MB, 366 MB peak; at 320x180: 15 s;
# re-measured with the runs of docs/simulator.md "Time and size": 6 pairs at 1280x720 in 16 s,
# 73 at 320x180 in 18 s, 52 at 1280x720 in 157 s)
_S_START = 3.0              # start-up: imports, the world, the bag (s)
_S_PER_STOP = 0.5           # calibration: finding one reachable pose that sees the board (s)
_S_PER_PAIR = 0.15          # fixed cost of one stereo pair (s)
_S_PER_MPX = 2.3            # per megapixel of one image (s)
_MEMORY_BASE = 200 << 20    # the interpreter, SciPy, OpenCV (bytes)
_MEMORY_PER_PX = 200        # per pixel of one image, rendering buffers (bytes)
# The size model: zstd-compressed bgr8 images, measured once (default world, seed 0; 6 pairs at
# 1280x720: noise 1 18.0 MB, noise 0 2.0 MB; 10 pairs at 320x180: 2.2 and 0.5 MB): with sensor
# noise an image compresses to ~0.56 of its raw size (Gaussian noise is incompressible: one more
# bit per pixel and channel, 1/8 of the raw size, per doubling of sigma, extrapolated beyond the
# measured sigma 1); without, to ~0.16 MB at 1280x720, growing with the pixels to the power 0.65
# (the edges of the scene, not its area, cost the bytes).
_RATIO_NOISE_1 = 0.56
_BYTES_NOISE_FREE = 0.164e6     # one noise-free 1280x720 image
_NOISE_FREE_EXPONENT = 0.65
_BYTES_PER_ROBOT_SAMPLE = 150   # joint_states, ee_pose and tf at one stamp, compressed


def _image_bytes(size: tuple[int, int], noise: float) -> float:
    """Estimated bytes of one compressed image (see the size model above)."""
    px = size[0] * size[1]
    raw = 3.0 * px
    floor = min(raw, _BYTES_NOISE_FREE * (px / (1280 * 720)) ** _NOISE_FREE_EXPONENT)
    if noise <= 0:
        return floor
    return min(raw, max(floor, (_RATIO_NOISE_1 + math.log2(noise) / 8.0) * raw))


def _counts(args: argparse.Namespace, frames: int, *,
            still_images_only: bool | None = None) -> tuple[int, int]:
    """``(stereo pairs, robot samples)`` the run writes (a calibration bag films the moves
    between its poses unless ``--still-images-only``)."""

    if args.format == "dataset":
        return frames, 0
    return recording_counts(args.scenario, frames, hold_frames=args.hold_frames,
                            move_s=args.move_s, settle_s=args.settle_s,
                            still_images_only=(args.still_images_only
                                               if still_images_only is None
                                               else still_images_only))


def _cost(args: argparse.Namespace, frames: int, size: tuple[int, int], pairs: int,
          robot: int) -> tuple[float, float]:
    """Estimated ``(seconds, bytes on disk)`` of a run of ``pairs`` stereo pairs."""
    stops = frames if args.scenario == "calibration" else 0
    seconds = (_S_START + stops * _S_PER_STOP
               + pairs * (_S_PER_PAIR + _S_PER_MPX * size[0] * size[1] / 1e6))
    disk = 2 * pairs * _image_bytes(size, args.noise) + robot * _BYTES_PER_ROBOT_SAMPLE
    return seconds, disk


def _available_memory() -> int | None:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def estimate(args: argparse.Namespace, frames: int, size: tuple[int, int]) -> str:
    """The run's estimated time, disk and memory, as one line; refuses (``InputError``) a run
    whose upper bound (uncompressed images) cannot fit on the disk, or that cannot fit in
    memory, unless ``--force``."""

    pairs, robot = _counts(args, frames)
    px = size[0] * size[1]
    seconds, disk = _cost(args, frames, size, pairs, robot)
    bound = pairs * 2 * px * 3 + robot * 1000     # uncompressed: the upper bound
    memory = _MEMORY_BASE + _MEMORY_PER_PX * px
    parent = Path(args.output).absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    avail = _available_memory()
    line = (f"simulate: {pairs} stereo pairs at {size[0]}x{size[1]}: about "
            f"{_duration(seconds)} and {_megabytes(disk)} on disk (up to "
            f"{_megabytes(bound)} uncompressed; {free / 1e6:,.0f} MB free), about "
            f"{memory / 1e6:,.0f} MB of memory")
    if args.scenario == "calibration" and args.format == "bag" and not args.still_images_only:
        small, small_robot = _counts(args, frames, still_images_only=True)
        t_small, d_small = _cost(args, frames, size, small, small_robot)
        line += (f"; with --still-images-only: {small} pairs, about {_duration(t_small)} and "
                 f"{_megabytes(d_small)}")
    if not args.force:
        if bound > free:
            raise InputError(f"{line}: does not fit on the disk of {parent} (give --force to "
                             "try anyway, or fewer --frames or a smaller --size)")
        if avail is not None and memory > avail:
            raise InputError(f"{line}: does not fit in the {avail / 1e6:,.0f} MB of free memory "
                             "(give --force to try anyway, or a smaller --size)")
    return line


def _megabytes(n: float) -> str:
    return f"{n / 1e6:,.1f} MB" if n < 10e6 else f"{n / 1e6:,.0f} MB"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:,.1f} h"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand simulate``."""
    parser.add_argument("--scenario", choices=("calibration", "localization"), required=True,
                        help="calibration: still poses looking at the chessboard; "
                             "localization: continuous motion around the target(s)")
    out = add_output_argument(
        parser, metavar="OUT", type=Path,
        help="bag directory (--format bag) or dataset folder (--format dataset), written "
             "whole or not at all; must not exist (or be empty), or give --overwrite")
    deprecated_alias(parser, "--out", out)
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing OUT (whole, once the new one is complete)")
    parser.add_argument("--frames", type=bounded(1, 100000, integer=True), default=None,
                        help="1 to 100000; calibration: number of still poses (default 16); "
                             "localization: number of stereo pairs at 30 Hz (default 90)")
    parser.add_argument("--seed", type=bounded(0, 2**32 - 1, integer=True), default=0,
                        help="seed of poses, trajectory and sensor noise, 0 to 2^32-1 "
                             "(default 0)")
    parser.add_argument("--size", type=_size, default=None, metavar="WxH",
                        help="image size; intrinsics scale with it (default: the world's, "
                             "1280x720)")
    parser.add_argument("--world", type=Path, default=None,
                        help="world YAML (default: the built-in world, = config/world.yaml)")
    parser.add_argument("--storage", choices=STORAGES, default=STORAGES[0],
                        help="bag storage (default mcap, zstd-compressed chunks)")
    parser.add_argument("--format", choices=("bag", "dataset"), default="bag",
                        help="bag (default) or dataset (PNG images + dataset.yaml; "
                             "calibration scenario only)")
    parser.add_argument("--robot-error", default=None, metavar="SPEC",
                        help="robot error of the arm (true arm vs the reported nominal one): 0 "
                             "(ideal arm), default, a scale of the default (e.g. 2), or "
                             "key=value,... overrides (link_sigma_m, twist_sigma_rad, "
                             "joint_offset_sigma_rad, encoder_sigma_rad, time_offset_s, seed), "
                             "e.g. 1,time_offset_s=0.004 (default: the world's robot_error, "
                             "the realistic default)")
    parser.add_argument("--noise", type=bounded(0, 255), default=1.0,
                        help="sensor noise sigma in grey levels, 0 to 255 (default 1.0; 0 = "
                             "none)")
    parser.add_argument("--blur", type=bounded(0, 50, "px"), default=0.0,
                        help="Gaussian blur sigma in pixels, 0 to 50 (default 0)")
    parser.add_argument("--exposure", type=bounded(0, 100, lo_open=True), default=1.0,
                        help="exposure gain, (0, 100] (default 1.0)")
    parser.add_argument("--supersample", type=bounded(1, 8, integer=True), default=3,
                        help="sub-pixel rays per axis on edge pixels, 1 to 8 (default 3)")
    parser.add_argument("--hold-frames", type=bounded(1, 1000, integer=True), default=3,
                        help="calibration bag: image periods of the settled part of each stop, "
                             "1 to 1000 (default 3)")
    parser.add_argument("--settle-s", type=bounded(0, 60, "s"), default=0.25,
                        help="calibration bag: the arm also rests this long before and after "
                             "those frames, 0 to 60 s (default 0.25 s)")
    parser.add_argument("--move-s", type=bounded(0, 60, "s", lo_open=True), default=1.2,
                        help="calibration bag: seconds per move between poses, (0, 60] "
                             "(default 1.2)")
    parser.add_argument("--still-images-only", action="store_true",
                        help="calibration bag: record only the --hold-frames settled images of "
                             "each stop (robot topics stay continuous); much smaller bags")
    parser.add_argument("--no-ee-pose", action="store_true",
                        help="bag: record the robot as a real cell does, /tf, /tf_static and "
                             "/joint_states without /ee_pose")
    parser.add_argument("--force", action="store_true",
                        help="start even when the estimate says the run does not fit on the "
                             "disk or in memory")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar and no estimate")


def run(args: argparse.Namespace) -> int:
    """Simulate and write; prints a one-paragraph summary."""

    frames = args.frames if args.frames is not None else _DEFAULT_FRAMES[args.scenario]
    check_output_dir(args.output, overwrite=args.overwrite, option="-o", inputs=[args.world])
    if args.format == "dataset" and args.scenario != "calibration":
        raise InputError("--format dataset needs --scenario calibration")
    world = World.from_yaml(args.world) if args.world is not None else World.default()
    if args.size is not None:
        world = world.with_image_size(*args.size)
    if args.robot_error is not None:
        world = world.with_robot_error(RobotErrorSpec.parse(args.robot_error,
                                                            world.robot_error))
    line = estimate(args, frames, world.image_size)   # refuses what cannot fit
    if not args.quiet:
        print(line, file=sys.stderr, flush=True)
    render = RenderOptions(noise_sigma=args.noise, supersample=args.supersample,
                           blur_sigma=args.blur, exposure=args.exposure)
    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None:
            bar = tqdm(total=total, unit="pair", desc="rendering", file=sys.stderr)
        bar.update(done - bar.n)

    try:  # written under a temporary name in the same folder, renamed into place when complete
        with atomic_output_dir(args.output, overwrite=args.overwrite, option="-o",
                               create=args.format == "dataset") as tmp:
            if args.format == "dataset":
                path = write_dataset(world, tmp, frames=frames, seed=args.seed, render=render,
                                     progress=progress)
            else:
                summary = write_bag(world, tmp, scenario=args.scenario, frames=frames,
                                    seed=args.seed, storage=args.storage, render=render,
                                    hold_frames=args.hold_frames, move_s=args.move_s,
                                    settle_s=args.settle_s,
                                    still_images_only=args.still_images_only,
                                    ee_pose=not args.no_ee_pose, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if args.format == "dataset":
        print(f"wrote calibration dataset {args.output / path.name} ({frames} stereo pairs, "
              f"{world.image_size[0]}x{world.image_size[1]}, board {world.board}; "
              f"{world.robot_error.describe()})")
        return 0
    size = sum(p.stat().st_size for p in Path(args.output).rglob("*") if p.is_file())
    print(f"wrote bag {args.output} ({args.storage}, {size / 1e6:.1f} MB): "
          f"{summary.n_images} stereo pairs at {world.image_size[0]}x{world.image_size[1]}, "
          f"{summary.n_robot} robot samples, {summary.duration_s:.2f} s; "
          f"{world.robot_error.describe()}")
    return 0
