"""Simulator figures: render speed, ray accuracy, blob and chessboard-corner agreement with truth,
and the per-pose flange error of the default robot error (``--robot-error-only`` for just that).

Run: ``.venv/bin/python benchmarks/bench_sim.py`` (about a minute on a loaded 2-core machine).
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from eye_in_hand.sim import World
from eye_in_hand.sim.render import Renderer
from eye_in_hand.sim.scenarios import calibration_poses, localization_trajectory


def _moments(w: np.ndarray) -> np.ndarray:
    ys, xs = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    return np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()


def robot_error_figures(world: World) -> None:
    """Per-pose flange error (reported nominal FK vs true arm) of the default robot error, over
    the default scenarios' poses: the default arm (seed 1) and 20 other draws."""
    import math

    from eye_in_hand.sim.robot_error import RobotErrorSpec, draw_true_arm, flange_errors

    spec = world.robot_error
    qs = np.array(calibration_poses(world, 15, seed=0)
                  + [q for _, q in localization_trajectory(world, 3.0, 10.0, seed=0)])
    print(f"{spec.describe()}; {len(qs)} poses (15 calibration poses, 3 s of localization "
          "orbit)")

    def line(label: str, dt: np.ndarray, dr: np.ndarray) -> str:
        dt, dr = dt * 1e3, np.degrees(dr)
        return (f"{label}: translation mean {dt.mean():.3f} mm (p5 {np.percentile(dt, 5):.3f}, "
                f"p95 {np.percentile(dt, 95):.3f}), rotation mean {dr.mean():.4f} deg "
                f"(p5 {np.percentile(dr, 5):.4f}, p95 {np.percentile(dr, 95):.4f})")

    print("  " + line(f"default arm (seed {spec.seed})", *flange_errors(world.arm,
                                                                       world.true_arm, qs)))
    all_t, all_r = [], []
    for seed in range(2, 22):
        arm = draw_true_arm(world.arm, RobotErrorSpec(**{**spec.to_dict(), "seed": seed}))
        dt, dr = flange_errors(world.arm, arm, qs)
        all_t.append(dt)
        all_r.append(dr)
    print("  " + line("20 other arms (seeds 2-21)", np.concatenate(all_t),
                      np.concatenate(all_r)))
    rng = np.random.default_rng(0)
    enc = spec.encoder_sigma_rad * rng.standard_normal(qs.shape)
    dt, dr = flange_errors(world.arm, world.arm, qs, qs + enc)
    print(f"  encoder noise alone ({math.degrees(spec.encoder_sigma_rad):.2g} deg per joint): "
          f"translation RMS {np.sqrt(np.mean(dt ** 2)) * 1e3:.4f} mm, rotation RMS "
          f"{math.degrees(np.sqrt(np.mean(dr ** 2))):.5f} deg")


def main() -> None:
    import sys

    world = World.default()
    robot_error_figures(world)
    if "--robot-error-only" in sys.argv[1:]:
        return
    t = time.perf_counter()
    r = Renderer(world)
    r.rays("left")
    r.rays("right")
    print(f"ray grids (2 x 1280x720, built once): {time.perf_counter() - t:.2f} s, "
          f"round trip max {max(r.rays(s).round_trip_error() for s in ('left', 'right')):.1e} px")
    traj = localization_trajectory(world, 2.0, 5.0, seed=0)
    q = traj[0][1]
    r.render(q)
    for ss in (1, 3):
        times = []
        for k in range(5):
            t = time.perf_counter()
            r.render(traj[k][1], seed=k, noise_sigma=2.0, supersample=ss)
            times.append(time.perf_counter() - t)
        print(f"render 1280x720 stereo pair, supersample {ss}, noise 2: "
              f"median {np.median(times):.3f} s (min {min(times):.3f})")

    # blobs: coverage moments and a red-chromaticity threshold vs the silhouette centroid
    errs_cov, errs_thr, offs = [], [], []
    small = world.with_image_size(640, 360)
    for _, q in localization_trajectory(small, 2.0, 5.0, seed=1):
        f = small.render(q, noise_sigma=0.0, with_coverage=True)
        for side in ("left", "right"):
            cov = getattr(f, f"coverage_{side}")[0]
            sil = getattr(f.truth, f"silhouette_centroid_px_{side}")[0]
            ctr = getattr(f.truth, f"center_px_{side}")[0]
            img = getattr(f, side).astype(float)
            chroma = img[:, :, 2] / np.maximum(img.sum(axis=2), 1.0)
            level = 0.5 * (np.median(chroma[cov >= 1]) + np.median(chroma[cov <= 0]))
            errs_cov.append(np.linalg.norm(_moments(cov) - sil))
            errs_thr.append(np.linalg.norm(_moments((chroma >= level).astype(float)) - sil))
            offs.append(np.linalg.norm(sil - ctr))
    print(f"sphere blobs 640x360 ({len(errs_cov)} views): |coverage centroid - silhouette "
          f"centroid| max {max(errs_cov):.4f} px; chroma-threshold centroid max "
          f"{max(errs_thr):.3f} px, mean {np.mean(errs_thr):.3f} px; silhouette centroid vs "
          f"centre projection: mean {np.mean(offs):.2f} px, max {max(offs):.2f} px")

    # chessboard corners over calibration poses
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    poses = calibration_poses(world, 8, seed=0)
    for ss in (3, 5):
        errs = []
        for i, q in enumerate(poses):
            f = world.render(q, noise_sigma=0.0, supersample=ss)
            for side in ("left", "right"):
                gray = cv2.cvtColor(getattr(f, side), cv2.COLOR_BGR2GRAY)
                ok, c = cv2.findChessboardCorners(gray, (9, 6))
                if not ok:
                    print(f"  pose {i} {side}: board not found")
                    continue
                c = cv2.cornerSubPix(gray, c, (11, 11), (-1, -1), crit).reshape(-1, 2)
                errs.append(np.linalg.norm(c - getattr(f.truth, f"board_corners_px_{side}"),
                                           axis=1))
        e = np.concatenate(errs)
        print(f"chessboard corners 1280x720, supersample {ss}, {len(errs)} views, noise-free, "
              f"cornerSubPix 11x11: RMS {np.sqrt(np.mean(e ** 2)):.3f} px, "
              f"max {e.max():.3f} px")

    t = time.perf_counter()
    n = 0
    for _, q in traj:
        world.arm.ik(world.arm.fk(q), q + 0.05)
        n += 1
    print(f"IK (seeded near the solution): {(time.perf_counter() - t) / n * 1e3:.1f} ms/pose")


if __name__ == "__main__":
    main()
