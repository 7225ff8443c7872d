"""Accuracy of camera and stereo calibration on real and synthetic data; prints its figures.

Run:  .venv/bin/python benchmarks/bench_calibration.py [--frames 24] [--seeds 5] [--no-render]

1. Real data (test/data/opencv_stereo_chessboard, OpenCV's 13 stereo pairs, 9x6, square 1):
   detectors classic / sb / auto compared on boards found, left RMS against OpenCV's published
   0.196335, K and dist L1 distance to OpenCV's reference, stereo baseline, rectified |dy|,
   square measured back.
2. Synthetic, corner level (simulator ground truth, 1280x720, calibration_poses): exact corner
   projections + 0.2 px Gaussian noise per axis, several seeds; errors of fx, fy (%), cx, cy (px)
   and baseline (mm) for the joint bundle, OpenCV's stereoCalibrate (intrinsics free, from the
   mono results) and fixed intrinsics; and the same with a quarter of the views seen by one
   camera only.
3. Synthetic, image level: the simulator's rendered images, boards detected with classic and
   sb (corner error against the true projections), then calibrated.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from eye_in_hand.core.calibration import (  # noqa: E402
    BoardDetection,
    BoardSpec,
    calibrate_camera,
    calibrate_stereo,
    detect_board,
)

REF_RMS = 0.196334638034
REF_K = np.array([[532.80992189, 0.0, 342.4952186], [0.0, 532.93346422, 233.8879292],
                  [0.0, 0.0, 1.0]])
REF_DIST = np.array([-2.81325576e-01, 2.91130406e-02, 1.21234330e-03, -1.40825372e-04,
                     1.54865844e-01])


def real_data() -> None:
    folder = ROOT / "test" / "data" / "opencv_stereo_chessboard"
    board = BoardSpec.parse("chessboard:9x6:1.0")
    lfiles = sorted(folder.glob("left*.jpg"))
    limgs = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in lfiles]
    rimgs = [cv2.imread(str(f).replace("left", "right"), cv2.IMREAD_GRAYSCALE) for f in lfiles]
    print("== Real data: OpenCV stereo chessboard, 13 pairs 640x480, 9x6, square 1 ==")
    print(f"{'detector':9s} {'found L/R':>9s} {'det ms':>7s} {'left RMS':>9s} {'dRMS':>7s} "
          f"{'K L1':>6s} {'dist L1':>8s} {'baseline':>9s} {'|dy| mean':>9s} {'square':>8s} "
          f"{'epi px':>7s} {'joint RMS':>9s}")
    for det in ("classic", "sb", "auto"):
        t0 = time.perf_counter()
        fb = det == "auto"
        left = [detect_board(i, board, det, fallback=fb) for i in limgs]
        right = [detect_board(i, board, det, fallback=fb) for i in rimgs]
        ms = 1000 * (time.perf_counter() - t0) / (len(limgs) + len(rimgs))
        mono = calibrate_camera(left)
        st = calibrate_stereo(left, right, board=board)
        q = st.quality
        print(f"{det:9s} {sum(d.found for d in left):>4d}/{sum(d.found for d in right):<4d} "
              f"{ms:7.1f} {mono.rms_px:9.4f} {mono.rms_px - REF_RMS:+7.4f} "
              f"{np.abs(mono.camera.K - REF_K).sum():6.2f} "
              f"{np.abs(mono.camera.dist - REF_DIST).sum():8.4f} {st.rig.baseline:9.4f} "
              f"{q.rectified_dy_mean_px:9.4f} {q.square_measured_mean:8.4f} "
              f"{q.epipolar_error_px:7.4f} {st.rms_px:9.4f}")
    print("targets: RMS 0.1963 +- 0.01 (classic), K L1 < 10, dist L1 < 0.05, baseline "
          "3.34 +- 0.03, |dy| <= 0.2, square 1.00 +- 0.02")


def _errors(cal, rig_true) -> dict[str, float]:
    out = {}
    for side, cam, true in (("L", cal.rig.left, rig_true.left), ("R", cal.rig.right,
                                                                   rig_true.right)):
        out[f"fx{side}%"] = 100 * abs(cam.fx / true.fx - 1)
        out[f"fy{side}%"] = 100 * abs(cam.fy / true.fy - 1)
        out[f"cx{side}"] = abs(cam.cx - true.cx)
        out[f"cy{side}"] = abs(cam.cy - true.cy)
    out["cyR std"] = cal.std["right.cy"]
    out["B mm"] = 1000 * abs(cal.rig.baseline - rig_true.baseline)
    out["B std mm"] = 1000 * cal.std["baseline"]
    return out


def _print_table(title: str, rows: dict[str, list[dict[str, float]]]) -> None:
    keys = list(next(iter(rows.values()))[0].keys())
    print(title)
    print(f"{'method':24s} " + " ".join(f"{k:>9s}" for k in keys))
    for name, errs in rows.items():
        mean = {k: np.mean([e[k] for e in errs]) for k in keys}
        worst = {k: np.max([e[k] for e in errs]) for k in keys}
        print(f"{name + ' mean':24s} " + " ".join(f"{mean[k]:9.3f}" for k in keys))
        print(f"{name + ' max':24s} " + " ".join(f"{worst[k]:9.3f}" for k in keys))


def spread_views(world, n: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """True corner pixels (left, right) of n board poses spread over the whole image.

    Same distances (0.30-0.48 m) and tilts (up to 38 degrees) as the simulator's
    calibration_poses, but the board centre is placed anywhere in the inner 80 % of the image
    instead of near the image centre. Uses the simulator's rig and board, not the arm.
    """
    rig = world.rig
    obj = world.board_points()
    centre = obj.mean(axis=0)
    w, h = world.image_size
    r_T_l = rig.right_T_left
    out = []
    while len(out) < n:
        d = rng.uniform(0.30, 0.48)
        tilt = np.radians(38.0) * np.sqrt(rng.uniform())
        az = rng.uniform(0, 2 * np.pi)
        R = cv2.Rodrigues(tilt * np.array([np.cos(az), np.sin(az), 0.0]))[0] @ \
            cv2.Rodrigues(np.array([0.0, 0.0, rng.uniform(-0.6, 0.6)]))[0]
        ray = np.linalg.solve(rig.left.K, [rng.uniform(0.1, 0.9) * w, rng.uniform(0.1, 0.9) * h,
                                           1.0])
        t = d * ray / np.linalg.norm(ray) - R @ centre
        X = obj @ R.T + t
        pl = rig.left.project(X)
        pr = rig.right.project(X @ r_T_l[:3, :3].T + r_T_l[:3, 3])
        if all(np.all(np.isfinite(p)) and p.min() > 10 and p[:, 0].max() < w - 10
               and p[:, 1].max() < h - 10 for p in (pl, pr)):
            out.append((pl, pr))
    return out


def synthetic_corners(world, n_frames: int, seeds: int) -> None:
    from eye_in_hand.sim.scenarios import calibration_poses

    board = BoardSpec.parse(str(world.board))
    obj = world.board_points()
    ids = np.arange(obj.shape[0])
    size = world.image_size
    rows: dict[str, list] = {"bundle": [], "opencv": [], "fixed intrinsics": [],
                             "bundle, 25% one-sided": [], "opencv, 25% one-sided": [],
                             "bundle, spread poses": []}
    for seed in range(seeds):
        qs = calibration_poses(world, n_frames, seed=100 + seed)
        rng = np.random.default_rng(seed)
        left, right = [], []

        def add(px_l: np.ndarray, px_r: np.ndarray, lst_l: list, lst_r: list,
                rng: np.random.Generator = rng) -> None:
            for px, lst in ((px_l, lst_l), (px_r, lst_r)):
                noisy = px + rng.normal(0.0, 0.2, px.shape)
                lst.append(BoardDetection(True, noisy, obj, ids, size, "truth+noise"))

        for q in qs:
            t = world.truth(q)
            add(t.board_corners_px_left, t.board_corners_px_right, left, right)
        sl, sr = [], []
        for pl, pr in spread_views(world, n_frames, rng):
            add(pl, pr, sl, sr)
        rows["bundle, spread poses"].append(
            _errors(calibrate_stereo(sl, sr, board=board), world.rig))
        for method, fix in (("bundle", False), ("opencv", False), ("fixed intrinsics", True)):
            cal = calibrate_stereo(left, right, board=board, method="bundle" if fix else method,
                                   fix_intrinsics=fix)
            rows[method].append(_errors(cal, world.rig))
        # a quarter of the boards seen by only one camera (alternating sides)
        l2, r2 = list(left), list(right)
        for k in range(0, n_frames, 4):
            if (k // 4) % 2:
                l2[k] = BoardDetection.missing(size, "", "hidden")
            else:
                r2[k] = BoardDetection.missing(size, "", "hidden")
        for method in ("bundle", "opencv"):
            cal = calibrate_stereo(l2, r2, board=board, method=method)
            rows[f"{method}, 25% one-sided"].append(_errors(cal, world.rig))
    print(f"\n== Synthetic corners: simulator truth {size[0]}x{size[1]}, {n_frames} views, "
          f"0.2 px noise per axis, {seeds} seeds ==")
    print("(views from sim.scenarios.calibration_poses, except 'spread poses': board centre "
          "anywhere in the image)")
    _print_table("errors (fx, fy in %, cx, cy in px, baseline in mm; targets 0.3 %, 1 px, "
                 "0.2 mm):", rows)


def synthetic_images(world, n_frames: int) -> None:
    from eye_in_hand.sim.scenarios import calibration_poses

    board = BoardSpec.parse(str(world.board))
    qs = calibration_poses(world, n_frames, seed=7)
    frames = []
    t0 = time.perf_counter()
    for k, q in enumerate(qs):
        f = world.render(q, seed=k)
        frames.append((f.left, f.right, f.truth))
    print(f"\n== Synthetic images: {n_frames} rendered pairs {world.image_size[0]}x"
          f"{world.image_size[1]} (render {time.perf_counter() - t0:.0f} s) ==")
    print(f"{'detector':9s} {'found L/R':>9s} {'corner RMS px':>13s} {'corner max px':>13s} "
          f"{'fxL %':>7s} {'cxL px':>7s} {'cyL px':>7s} {'fxR %':>7s} {'B mm':>7s} "
          f"{'joint RMS':>9s} {'|dy|':>6s}")
    for det in ("classic", "sb"):
        left = [detect_board(f[0], board, det, fallback=False) for f in frames]
        right = [detect_board(f[1], board, det, fallback=False) for f in frames]
        errs = []
        for d, f, side in [(d, f, 0) for d, f in zip(left, frames, strict=True)] + \
                          [(d, f, 1) for d, f in zip(right, frames, strict=True)]:
            if d.found:
                truth = f[2].board_corners_px_left if side == 0 else f[2].board_corners_px_right
                errs.append(np.linalg.norm(d.corners - truth, axis=1))
        e = np.concatenate(errs)
        cal = calibrate_stereo(left, right, board=board)
        er = _errors(cal, world.rig)
        print(f"{det:9s} {sum(d.found for d in left):>4d}/{sum(d.found for d in right):<4d} "
              f"{np.sqrt(np.mean(e ** 2)):13.4f} {e.max():13.4f} {er['fxL%']:7.3f} "
              f"{er['cxL']:7.3f} {er['cyL']:7.3f} {er['fxR%']:7.3f} {er['B mm']:7.3f} "
              f"{cal.rms_px:9.4f} {cal.quality.rectified_dy_mean_px:6.3f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=24, help="synthetic views (default 24)")
    parser.add_argument("--seeds", type=int, default=5, help="corner-level seeds (default 5)")
    parser.add_argument("--no-render", action="store_true", help="skip the rendered images")
    args = parser.parse_args()
    real_data()
    try:
        from eye_in_hand.sim import World
    except ImportError as exc:  # pragma: no cover - the simulator is part of the package
        print(f"\n(simulator not available: {exc}; synthetic part skipped)")
        return 0
    world = World.default()
    synthetic_corners(world, args.frames, args.seeds)
    if not args.no_render:
        synthetic_images(world, args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
