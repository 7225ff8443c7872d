"""Pairwise target distances from ``eye-in-hand process`` on a simulated multi-target bag.

Simulates a localization bag of a world with several sphere targets (noisy renders, 1280x720,
camera 0.3-0.6 m from the targets, the simulator's default robot error), runs
``eye-in-hand process`` on it with the true hand-eye transform, and prints the pairwise
distance table (measured mean and standard deviation over the frames, the true distance, the
error in mm) and each target's base-frame RMS error against the ground truth.

A distance between two targets seen in one stereo pair does not depend on the robot pose or
the hand-eye transform (both move the two points rigidly together): its error is the
triangulation's alone. The per-target base-frame RMS includes the robot's pose error.

Target: every pairwise distance within 0.5 mm of the truth.

World and detector settings: ``--world FILE`` and ``--params FILE`` (e.g.
``config/world_multi.yaml`` and ``config/detect_triangulate_multi.yaml``); without them, the
world is ``config/world.yaml`` with four 20 mm spheres of four colours (red, green, blue,
yellow) about 0.1 m apart, and a matching parameter file is written next to the data.

Usage: .venv/bin/python benchmarks/bench_distances.py [--pairs N] [--noise SIGMA]
       [--world FILE --params FILE] [--seed S] [--fresh]
Data is cached in build/bench-data/ (regenerate with --fresh).
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "build" / "bench-data"
TOLERANCE_MM = 0.5

FOUR_COLOURS = """/**/detect_triangulate:
  ros__parameters:
    target_names: [red, green, blue, yellow]
    targets:
      red: {lower: [170, 100, 40], upper: [10, 255, 255], radius_m: 0.02}
      green: {lower: [35, 60, 30], upper: [85, 255, 255], radius_m: 0.02}
      blue: {lower: [100, 100, 30], upper: [130, 255, 255], radius_m: 0.02}
      yellow: {lower: [18, 100, 40], upper: [35, 255, 255], radius_m: 0.02}
"""


def four_colour_world():
    """``config/world.yaml`` with four spheres of four colours instead of its one target."""
    from eye_in_hand.sim import World
    from eye_in_hand.sim.world import Target

    world = World.from_yaml(ROOT / "config" / "world.yaml")
    targets = (Target("red", [0.46, 0.14, 0.02], 0.02, (40, 40, 210)),
               Target("green", [0.56, 0.15, 0.02], 0.02, (40, 170, 40)),
               Target("blue", [0.47, 0.25, 0.02], 0.02, (200, 80, 30)),
               Target("yellow", [0.57, 0.24, 0.02], 0.02, (30, 200, 210)))
    return dataclasses.replace(world, targets=targets)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=90, help="stereo pairs (30 Hz; default 90)")
    parser.add_argument("--noise", type=float, default=1.0,
                        help="image noise, grey levels (1 sigma; default 1)")
    parser.add_argument("--world", metavar="FILE", help="world YAML (default: four colours)")
    parser.add_argument("--params", metavar="FILE",
                        help="detect_triangulate parameter file (required with --world)")
    parser.add_argument("--seed", type=int, default=21, help="trajectory and noise seed")
    parser.add_argument("--fresh", action="store_true", help="regenerate the cached bag")
    args = parser.parse_args()
    if bool(args.world) != bool(args.params):
        parser.error("--world and --params go together")

    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import RenderOptions, write_bag

    world = World.from_yaml(args.world) if args.world else four_colour_world()
    key = hashlib.sha1(json.dumps([args.world and Path(args.world).read_text(), args.pairs,
                                   args.noise, args.seed]).encode()).hexdigest()[:10]
    d = DATA / f"distances-{key}"
    if args.fresh and d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True, exist_ok=True)
    bag = d / "localization"
    if not bag.exists():
        print(f"rendering {args.pairs} pairs of {len(world.targets)} targets "
              f"(noise {args.noise}) ...", flush=True)
        write_bag(world, d / "partial", scenario="localization", frames=args.pairs,
                  seed=args.seed, render=RenderOptions(noise_sigma=args.noise))
        (d / "partial").rename(bag)
    params = Path(args.params) if args.params else d / "params.yaml"
    if not args.params:
        params.write_text(FOUR_COLOURS)
    he = d / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth"))
    out = d / "out"
    cmd = [sys.executable, "-m", "eye_in_hand.cli", "process", str(bag), "--hand-eye", str(he),
           "--params", str(params), "-o", str(out), "--overwrite", "--quiet"]
    print("$ eye-in-hand " + " ".join(cmd[3:]), flush=True)
    proc = subprocess.run(cmd, text=True, capture_output=True)
    print(proc.stdout + proc.stderr, end="")
    if proc.returncode != 0:
        return proc.returncode
    summary = json.loads((out / "summary.json").read_text())
    pairs = summary["distances"]
    print(f"\nworld: {args.world or 'config/world.yaml + four colours'}; {args.pairs} pairs, "
          f"noise {args.noise}, 1280x720, 0.3-0.6 m, default robot error, true hand-eye")
    print(f"{'pair':<22} {'frames':>6} {'mean (m)':>10} {'std (mm)':>9} {'truth (m)':>10} "
          f"{'error (mm)':>10}")
    worst = 0.0
    for p in pairs:
        err = p["error_mm"]
        worst = max(worst, abs(err)) if err is not None else worst
        print(f"{p['a'] + ' - ' + p['b']:<22} {p['frames']:>6} {p['mean_m']:>10.6f} "
              f"{p['std_mm']:>9.3f} {p['truth_m'] or float('nan'):>10.6f} "
              f"{err if err is not None else float('nan'):>+10.3f}")
    print(f"{'target':<22} {'localized':>9} {'base RMS (mm)':>14} {'max (mm)':>9}")
    for tid, t in summary["targets"].items():
        rms = t["rms_mm"] if t["rms_mm"] is not None else float("nan")
        mx = t["max_mm"] if t["max_mm"] is not None else float("nan")
        print(f"{tid:<22} {t['localized']:>9} {rms:>14.3f} {mx:>9.3f}")
    missing = [f"{p['a']}-{p['b']}" for p in pairs if p["error_mm"] is None]
    ok = not missing and worst <= TOLERANCE_MM and len(pairs) > 0
    print(f"largest |distance error|: {worst:.3f} mm (target <= {TOLERANCE_MM} mm): "
          + ("met" if ok else "NOT met" + (f" (no truth for {', '.join(missing)})"
                                           if missing else "")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
