"""Speed and accuracy of colour-target detection + stereo triangulation (issue 5 figures).

Run once (the machine is shared):  .venv/bin/python benchmarks/bench_detection.py

Speed: per 1280x720 stereo pair, ``StereoLocator.locate`` against the floor measured in the same
run (``cv2.cvtColor`` BGR->HSV + one ``cv2.inRange`` on both full images), the two timed in
turns within each of ``--rounds`` rounds; the ratio is the median over the rounds. Targets
(issue 24): one target at most 1x the floor, four targets at most 1.5x. Latest figures
(docs/detection.md#figures; idle 2-core machine, 2026-11-30 00:42 UTC, ``--repeats 50
--rounds 9 --cv-threads 1``): one target 0.70x the floor (1.66 ms per pair against 2.38 ms),
four targets 1.38x (3.21 ms against 2.33 ms; alternating with the code before an image's
blobs were measured together: 1.42-1.44x against 1.62-1.74x).

``--baseline OTHER_CHECKOUT``: also that checkout's ``locate`` (one target, dlt + sphere
correction) and this checkout's, each in a child process (``baseline_locate.py``) built from
the same parameter file and calibration files and fed the same pairs, timed in the same rounds
against the same floor: the first release (``git worktree add /tmp/first 88607dc``) is the
named baseline of the speed figure.

Accuracy: simulator renders (``eye_in_hand.sim``, default world: 35 mm red sphere, distorted
1280x720 rig, f ~ 900 px, B = 60 mm, sensor noise 2 grey levels) at 0.3-0.6 m range with the
sphere anywhere in the image. RMS 3-D error against ground truth for each method, with and
without the sphere-centre correction, next to the stereo limit ``Z^2 sigma_d / (f B)`` where
``sigma_d = sqrt(2) sigma_c`` and ``sigma_c`` is the measured RMS error of the corrected centres
per image coordinate. Targets: within 1.5x of that limit; DLT and parallax within 0.5 mm.

Several targets (``--multi-frames``, 0 = skip): the multi-target world (config/world_multi.yaml:
four 25 mm spheres, two the same red) along its localization orbit sampled at 10 Hz, located
with config/detect_triangulate_multi.yaml (the red pair one blob set, count 2): speed per pair
against the same floor, and per target id the RMS camera-frame error, the swaps of the red ids
(an id on the other red sphere than at its first sight) and the ambiguous rejections.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from bench_localization import checkout_commit  # this script's folder is on sys.path

from eye_in_hand.core.detection import ColorRange
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.core.transforms import compose, invert
from eye_in_hand.errors import KinematicsError
from eye_in_hand.sim import World
from eye_in_hand.sim.scenarios import HOME_Q, camera_pose_ok, localization_trajectory, look_at

ROOT = Path(__file__).resolve().parent.parent

# The simulator's shaded red sphere (albedo BGR 40, 40, 210, 35 % ambient): the dark side
# reaches V ~ 70 and S ~ 110, so the range is a little wider than the node's default.
SIM_RED = ColorRange((165, 80, 25), (12, 255, 255))


def config(method: str = "dlt", correction: bool = True, radius: float | None = 0.035):
    base = load_locator_config(None)
    spec = dataclasses.replace(base.detector.targets[0], color=SIM_RED, radius_m=radius)
    det = dataclasses.replace(base.detector, targets=(spec,), sphere_correction=correction)
    return dataclasses.replace(base, detector=det, method=method, max_residual_px=5.0)


def sample_poses(world: World, n: int, seed: int) -> list[np.ndarray]:
    """Joint vectors with the target 0.3-0.6 m away, anywhere in both images."""
    rng = np.random.default_rng(seed)
    centre = world.targets[0].center_base
    out: list[np.ndarray] = []
    tries = 0
    while len(out) < n and tries < 200 * n:
        tries += 1
        r = rng.uniform(0.3, 0.6)
        az, el = rng.uniform(0, 2 * math.pi), rng.uniform(math.radians(40), math.radians(70))
        eye = centre + r * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                     math.sin(el)])
        aim = centre + rng.uniform(-0.3, 0.3, 3) * r  # the target lands off axis
        base_T_cam = look_at(aim, eye, roll=rng.uniform(-0.5, 0.5))
        if not camera_pose_ok(world, base_T_cam, targets=True, margin_px=15.0):
            continue
        try:
            q = world.arm.ik(compose(base_T_cam, invert(world.ee_T_cam)), HOME_Q)
        except KinematicsError:
            continue
        out.append(q)
    return out


def floor(left: np.ndarray, right: np.ndarray) -> None:
    """The speed floor: cvtColor + inRange of both images."""
    for img in (left, right):
        cv2.inRange(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), SIM_RED.lower, (179, 255, 255))


def child_inputs(workdir: Path, imgs, params_yaml: str, rig) -> list[str]:
    """The inputs of :class:`ChildLocator` written once to ``workdir`` (the pairs, the
    parameter file, the calibration directory): their paths, as its arguments."""
    pairs = workdir / "pairs.npz"
    np.savez(pairs, left=np.stack([a for a, _ in imgs]), right=np.stack([b for _, b in imgs]))
    (workdir / "params.yaml").write_text(params_yaml)
    rig.save(workdir / "calibration")
    return [str(pairs), str(workdir / "params.yaml"), str(workdir / "calibration")]


class ChildLocator:
    """``StereoLocator.locate`` of a checkout (``code``) in a child process
    (``benchmarks/baseline_locate.py``, the checkout first on ``PYTHONPATH``), on the pairs
    handed over in a file, the locator built from a parameter file and a calibration
    directory, as every release of the package reads them (``inputs``: from
    :func:`child_inputs`). :meth:`timed` runs one round there and returns its wall and CPU
    seconds per pair (the child's own process)."""

    def __init__(self, code: Path, inputs: list[str], cv_threads: int) -> None:
        env = {**os.environ, "PYTHONPATH": str(code)}
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).with_name("baseline_locate.py")), *inputs,
             str(cv_threads)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=code)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline().strip()
        if line != "ready":
            self.close()
            raise SystemExit(f"--baseline {code}: its locator did not start (see above)")

    def timed(self, repeats: int, period_s: float) -> tuple[float, float]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(f"{repeats} {period_s!r}\n")
        self.proc.stdin.flush()
        wall, cpu = self.proc.stdout.readline().split()
        return float(wall), float(cpu)

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def per_pair(named_fns, imgs, repeats: int, rounds: int = 5, warm_up: bool = False,
             period_s: float = 0.0
             ) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
    """Seconds per pair of each ``(name, fn(left, right))`` (the first is the floor), the best
    of ``rounds`` rounds of ``repeats`` pairs, and each one's ratio to the floor in wall time
    and in CPU time (this process, all its threads): the median over the rounds of its time
    over the floor's time in the same round. The functions take turns within each round, so a
    change of the shared machine's load between them moves both sides of a ratio alike.
    ``warm_up`` runs two pairs of each first. With OpenCV's default threads the floor's
    cvtColor and inRange run on both cores: less wall time than CPU time. A
    :class:`ChildLocator` in place of a function is timed in its own process (warmed up
    there), its round of the same pairs in the same turn.

    ``period_s`` > 0: at camera rate, one pair every ``period_s`` (the machine idles between
    them, as a live node does); each call is timed alone."""
    if warm_up:
        for _, fn in named_fns:
            if isinstance(fn, ChildLocator):
                continue
            for left, right in imgs[:2]:
                fn(left, right)
    times: dict[str, list[float]] = {name: [] for name, _ in named_fns}
    cpus: dict[str, list[float]] = {name: [] for name, _ in named_fns}
    for _ in range(rounds):
        for name, fn in named_fns:
            if isinstance(fn, ChildLocator):
                wall, cpu = fn.timed(repeats, period_s)
                times[name].append(wall)
                cpus[name].append(cpu)
                continue
            if period_s > 0:
                wall = cpu = 0.0
                for k in range(repeats):
                    c0, t0 = time.process_time(), time.perf_counter()
                    fn(*imgs[k % len(imgs)])
                    dt = time.perf_counter() - t0
                    wall, cpu = wall + dt, cpu + time.process_time() - c0
                    time.sleep(max(0.0, period_s - dt))
                times[name].append(wall / repeats)
                cpus[name].append(cpu / repeats)
                continue
            c0, t0 = time.process_time(), time.perf_counter()
            for k in range(repeats):
                fn(*imgs[k % len(imgs)])
            times[name].append((time.perf_counter() - t0) / repeats)
            cpus[name].append((time.process_time() - c0) / repeats)
    floor_name = named_fns[0][0]
    best = {name: min(t) for name, t in times.items()}

    def ratios(series: dict[str, list[float]]) -> dict[str, float]:
        return {name: float(np.median([a / f for a, f in zip(t, series[floor_name],
                                                               strict=True)]))
                for name, t in series.items()}

    return best, ratios(times), ratios(cpus)


def print_speed(timings: dict[str, float], wall: dict[str, float], cpu: dict[str, float],
                indent: str = "  ", width: int = 42) -> None:
    for name, t in timings.items():
        print(f"{indent}{name:{width}s} {t * 1e3:7.3f} ms/pair  {1.0 / t:7.1f} pairs/s  "
              f"{wall[name]:5.2f} x floor (wall)  {cpu[name]:5.2f} x floor (CPU)")


def _rate(period_s: float) -> str:
    return f", one pair every {period_s * 1e3:.0f} ms" if period_s > 0 else ", back to back"


#: ``config()``'s one target as a parameter file, in the keys every release reads (the
#: baseline's locator and this checkout's in a child process are built from it)
ONE_TARGET_PARAMS = f"""\
/**/detect_triangulate:
  ros__parameters:
    method: dlt
    max_residual_px: 5.0
    target_names: [red]
    targets:
      red:
        lower: {[int(v) for v in SIM_RED.lower]}
        upper: {[int(v) for v in SIM_RED.upper]}
        radius_m: 0.035
"""


def speed(frames, rig, repeats: int, rounds: int, period_s: float = 0.0,
          baseline: Path | None = None) -> None:
    loc = StereoLocator(rig, config())
    loc_raw = StereoLocator(rig, config(correction=False))
    loc_opt = StereoLocator(rig, config("optimal"))
    imgs = [(f.left, f.right) for f in frames]
    named: list[tuple[str, object]] = [("floor (cvtColor + inRange, both images)", floor),
                                       ("locate dlt + sphere correction", loc.locate),
                                       ("locate dlt, no correction", loc_raw.locate),
                                       ("locate optimal + sphere correction", loc_opt.locate)]
    children: list[ChildLocator] = []
    with tempfile.TemporaryDirectory(prefix="bench_detection_") as tmp:
        try:
            if baseline is not None:
                # the same pairs, parameter file and calibration files for both children
                inputs = child_inputs(Path(tmp), imgs, ONE_TARGET_PARAMS, rig)
                for name, code in (("this checkout", ROOT), (baseline.name, baseline)):
                    children.append(ChildLocator(code, inputs, cv2.getNumThreads()))
                    named.append((f"locate dlt + sphere, {name} (child process)",
                                  children[-1]))
            timings, wall, cpu = per_pair(named, imgs, repeats, rounds, warm_up=True,
                                          period_s=period_s)
        finally:
            for child in children:
                child.close()
    print(f"speed, 1280x720 pairs, best of {rounds} x {repeats} pairs (x floor: median of the "
          f"rounds), cv2 threads {cv2.getNumThreads()}{_rate(period_s)}:")
    print_speed(timings, wall, cpu, width=56 if baseline is not None else 42)
    if baseline is not None:
        this, other = (f"locate dlt + sphere, {n} (child process)"
                       for n in ("this checkout", baseline.name))
        print(f"  {baseline} ({checkout_commit(baseline)}) against this checkout, both in a "
              f"child process: {timings[other] * 1e3:.3f} against {timings[this] * 1e3:.3f} ms "
              f"per pair, {cpu[other]:.2f}x against {cpu[this]:.2f}x the floor's CPU")



def accuracy(world: World, frames) -> None:
    rig = world.rig.rectified()
    f_rect, B = rig.P1[0, 0], rig.baseline
    variants = {
        "dlt": StereoLocator(rig, config("dlt")),
        "disparity": StereoLocator(rig, config("disparity")),
        "optimal": StereoLocator(rig, config("optimal")),
        "dlt, silhouette alpha only": StereoLocator(rig, config("dlt", radius=None)),
        "dlt, no sphere correction": StereoLocator(rig, config("dlt", correction=False)),
    }
    errs: dict[str, list[np.ndarray]] = {k: [] for k in variants}
    px_corr, px_raw, limits, ranges, angles = [], [], [], [], []
    dlt_vs_par: list[float] = []
    disp_err: list[float] = []
    misses = {k: 0 for k in variants}
    for fr in frames:
        X = fr.truth.targets_cam[0]
        res = {}
        for name, loc in variants.items():
            r = loc.locate(fr.left, fr.right).first
            if r is None:
                misses[name] += 1
                continue
            res[name] = r
            errs[name].append(r.point_m - X)
        if "dlt" not in res or "disparity" not in res:
            continue
        t = res["dlt"]
        tl, tr = fr.truth.center_px_left[0], fr.truth.center_px_right[0]
        px_corr += [t.left_px - tl, t.right_px - tr]
        rect = [rig.left.rectify_points(t.left_px)[0] - rig.left.rectify_points(tl)[0],
                rig.right.rectify_points(t.right_px)[0] - rig.right.rectify_points(tr)[0]]
        disp_err.append(float(rect[0][0] - rect[1][0]))
        px_raw += [t.left_centroid_px - fr.truth.center_px_left[0],
                   t.right_centroid_px - fr.truth.center_px_right[0]]
        ranges.append(float(np.linalg.norm(X)))
        angles.append(math.degrees(math.atan2(math.hypot(X[0], X[1]), X[2])))
        limits.append(X[2])
        dlt_vs_par.append(float(np.linalg.norm(res["dlt"].point_m - res["disparity"].point_m)))
    pc, pr = np.array(px_corr), np.array(px_raw)
    sigma_c = float(np.sqrt(np.mean(pc ** 2)))
    Z = np.array(limits)
    limit = Z ** 2 * math.sqrt(2.0) * sigma_c / (f_rect * B)
    rms_limit = float(np.sqrt(np.mean(limit ** 2)))
    print(f"accuracy, {len(frames)} simulator pairs, range {min(ranges):.2f}-{max(ranges):.2f} m, "
          f"field angle {min(angles):.1f}-{max(angles):.1f} deg:")
    print(f"  centre error per coordinate (RMS): corrected {sigma_c:.3f} px, raw centroid "
          f"{float(np.sqrt(np.mean(pr ** 2))):.3f} px (max |raw| "
          f"{float(np.max(np.linalg.norm(pr, axis=1))):.2f} px, max |corrected| "
          f"{float(np.max(np.linalg.norm(pc, axis=1))):.2f} px)")
    print(f"  stereo limit Z^2 sqrt(2) sigma_c / (f B), RMS over frames: {rms_limit * 1e3:.3f} mm "
          f"(f = {f_rect:.1f} px, B = {B * 1e3:.2f} mm)")
    sigma_d = float(np.sqrt(np.mean(np.square(disp_err))))
    limit_d = float(np.sqrt(np.mean((Z ** 2 * sigma_d / (f_rect * B)) ** 2)))
    print(f"  measured disparity error (RMS) {sigma_d:.3f} px (left/right centre errors are "
          f"correlated, so below sqrt(2) sigma_c = {math.sqrt(2) * sigma_c:.3f} px): limit "
          f"Z^2 sigma_d / (f B) = {limit_d * 1e3:.3f} mm")
    for name, e in errs.items():
        if not e:
            print(f"  {name:30s} no detections")
            continue
        a = np.array(e)
        rms3 = float(np.sqrt(np.mean(np.sum(a ** 2, axis=1))))
        rmsz = float(np.sqrt(np.mean(a[:, 2] ** 2)))
        print(f"  {name:30s} RMS 3-D {rms3 * 1e3:6.3f} mm  RMS z {rmsz * 1e3:6.3f} mm  "
              f"max 3-D {float(np.max(np.linalg.norm(a, axis=1))) * 1e3:6.3f} mm  "
              f"{rms3 / rms_limit:5.2f} x limit  misses {misses[name]}")
    print(f"  DLT vs parallax: max |difference| {max(dlt_vs_par) * 1e3:.4f} mm")


def multi(n_frames: int, repeats: int, seed: int, rounds: int = 5,
          period_s: float = 0.0) -> None:
    """Speed and per-target accuracy with four targets, two of one colour (module docs)."""
    world = World.from_yaml(ROOT / "config" / "world_multi.yaml")
    cfg = load_locator_config(ROOT / "config" / "detect_triangulate_multi.yaml")
    t0 = time.perf_counter()
    traj = localization_trajectory(world, (n_frames - 1) / 10.0, 10.0, seed=seed)
    frames = [world.render(q, seed=seed * 1000 + i, noise_sigma=2.0, supersample=3)
              for i, (_, q) in enumerate(traj)]
    print(f"several targets: rendered {len(frames)} pairs of config/world_multi.yaml (orbit at "
          f"10 Hz) in {time.perf_counter() - t0:.1f} s")
    rig = world.rig.rectified()
    loc = StereoLocator(rig, cfg)
    names = [t.name for t in world.targets]
    owner: dict[str, int] = {}
    errs: dict[str, list[float]] = {}
    swaps = ambiguous = 0
    misses: dict[str, int] = {}
    dist_err: list[float] = []
    for fr in frames:
        res = loc.locate(fr.left, fr.right)
        for a in range(len(res.targets)):
            for b in range(a + 1, len(res.targets)):
                ta, tb = res.targets[a], res.targets[b]
                wa = int(np.argmin(np.linalg.norm(fr.truth.targets_cam - ta.point_m, axis=1)))
                wb = int(np.argmin(np.linalg.norm(fr.truth.targets_cam - tb.point_m, axis=1)))
                true = float(np.linalg.norm(fr.truth.targets_cam[wa] - fr.truth.targets_cam[wb]))
                dist_err.append(float(np.linalg.norm(ta.point_m - tb.point_m)) - true)
        ambiguous += sum(res.ambiguous.values())
        for key in res.rejected:
            misses[key] = misses.get(key, 0) + 1
        for t in res.targets:
            d = np.linalg.norm(fr.truth.targets_cam - t.point_m, axis=1)
            w = int(np.argmin(d))
            if owner.setdefault(t.id, w) != w:
                swaps += 1
            errs.setdefault(t.id, []).append(float(d[w]))
    for tid, e in errs.items():
        a = np.array(e)
        print(f"  {tid:8s} = {names[owner[tid]]:6s} located {len(a):3d}/{len(frames)}  "
              f"RMS {float(np.sqrt(np.mean(a ** 2))) * 1e3:.3f} mm  max "
              f"{float(a.max()) * 1e3:.3f} mm")
    de = np.abs(np.array(dist_err))
    print(f"  pairwise distances (camera frame, {len(de)} pairs): RMS error "
          f"{float(np.sqrt(np.mean(de ** 2))) * 1e3:.3f} mm, max {float(de.max()) * 1e3:.3f} mm, "
          f"within 0.5 mm {100.0 * float(np.mean(de <= 5e-4)):.1f} %")
    print(f"  id swaps {swaps}, ambiguous blobs rejected {ambiguous}, rejections "
          f"{misses or 'none'}")

    one = StereoLocator(rig, config())
    imgs = [(f.left, f.right) for f in frames]
    timings, wall, cpu = per_pair((("floor (cvtColor + inRange, both images)", floor),
                                   ("locate, 1 target (red, the single config)", one.locate),
                                   ("locate, 4 targets (red x2 set, green, blue)", loc.locate)),
                                  imgs, repeats, rounds, period_s=period_s)
    print(f"  speed, best of {rounds} x {repeats} pairs (x floor: median of the rounds), cv2 "
          f"threads {cv2.getNumThreads()}{_rate(period_s)}:")
    print_speed(timings, wall, cpu, width=44)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30, help="simulator pairs (default 30)")
    parser.add_argument("--repeats", type=int, default=100, help="timed pairs per round")
    parser.add_argument("--rounds", type=int, default=5,
                        help="timed rounds, the functions taking turns in each (default 5)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--multi-frames", type=int, default=20,
                        help="pairs of the multi-target world (default 20; 0 = skip)")
    parser.add_argument("--multi-only", action="store_true",
                        help="only the several-targets part")
    parser.add_argument("--period-ms", type=float, default=0.0,
                        help="time the speed at camera rate: one pair every PERIOD ms, the "
                             "machine idle between them as a live node's is (default 0: back "
                             "to back)")
    parser.add_argument("--baseline", metavar="OTHER_CHECKOUT", type=Path,
                        help="also time OTHER_CHECKOUT's locate (one target, dlt + sphere "
                             "correction) in a child process, and this checkout's in another, "
                             "in the same rounds (e.g. the first release: git worktree add "
                             "/tmp/first 88607dc)")
    parser.add_argument("--cv-threads", type=int, default=-1,
                        help="cv2.setNumThreads before timing (default: OpenCV's own, "
                             "both cores here; 1: the floor on one core, as a detector "
                             "thread beside other work has it)")
    args = parser.parse_args(argv)
    if args.baseline is not None and not (args.baseline / "eye_in_hand").is_dir():
        parser.error(f"--baseline {args.baseline}: not a checkout of this package (no "
                     "eye_in_hand/ in it); make one with git worktree add DIR COMMIT")
    if args.cv_threads >= 0:
        cv2.setNumThreads(args.cv_threads)
    if args.multi_only:
        multi(args.multi_frames, args.repeats, args.seed, args.rounds, args.period_ms / 1e3)
        return 0
    world = World.default()
    t0 = time.perf_counter()
    qs = sample_poses(world, args.frames, args.seed)
    frames = [world.render(q, seed=args.seed * 1000 + i, noise_sigma=2.0, supersample=3)
              for i, q in enumerate(qs)]
    print(f"rendered {len(frames)} stereo pairs in {time.perf_counter() - t0:.1f} s")
    speed(frames, world.rig.rectified(), args.repeats, args.rounds, args.period_ms / 1e3,
          None if args.baseline is None else args.baseline.resolve())
    accuracy(world, frames)
    if args.multi_frames > 0:
        multi(args.multi_frames, args.repeats, args.seed, args.rounds, args.period_ms / 1e3)
    return 0


if __name__ == "__main__":
    sys.exit(main())
