"""Hand-eye on real data: k-fold held-out prediction on the Franka + RealSense ChArUco capture.

Data: ``test/data/franka_eye_in_hand`` (12 views; origin and licence in its README). The board
is detected with the package's detector in each image, its pose in the camera comes from
``cv2.solvePnP`` with the capture's factory intrinsics. There is no ground truth: every method
is judged by 6-fold held-out prediction (:mod:`eye_in_hand.core.handeye.kfold`): fitted on
10 views, it predicts the board of the 2 held-out views in the robot base frame (RMS mm over
the corners) and in their images (RMS px over the corners).

Methods compared on the same detections and the same folds:

* ``selected``: what ``calibrate handeye`` writes (``calibrate_hand_eye`` with every default,
  the method it selects on the fold);
* every method ``calibrate_hand_eye`` computes (closed forms, ``average``, the refinements)
  on the samples it kept;
* the classic closed forms of the package fitted on all the fold's training views
  (``tsai`` ... ``andreff``: X from the motions, the board pose the mean over the views);
* OpenCV 4.12's ``calibrateHandEye`` with its five methods (``cv_tsai`` ... ``cv_daniilidis``,
  installed by ``bench_handeye.py`` into ``build/bench-venv``; skipped with ``--no-opencv``).

Printed: per method the held-out RMS in mm and px over all folds; the selected result over the
best classic method (the best OpenCV method when OpenCV ran) in each; which method was selected
in each fold; the calibration warnings about convergence; with corner-uncertainty figures, the
normalised error (NEES) of the held-out board centre under the selected result's predicted
covariance.

Usage::

    .venv/bin/python benchmarks/bench_handeye_real.py [--k 6] [--refine saddle|none]
        [--robot-model systematic|per_pose] [--no-opencv]
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "test" / "data" / "franka_eye_in_hand"
sys.path.insert(0, str(ROOT))

CLASSIC = ("tsai", "park", "horaud", "daniilidis", "andreff")


def load_capture(data: Path = DATA):
    """``(board, camera, images, offsets, poses)`` of the capture."""
    from eye_in_hand.core.calibration import BoardSpec
    from eye_in_hand.core.camera import CameraModel

    b = yaml.safe_load((data / "board.yaml").read_text())
    board = BoardSpec("charuco", int(b["squares_x"]) - 1, int(b["squares_y"]) - 1,
                      float(b["square_size_m"]), float(b["marker_size_m"]), b["dictionary"])
    intr = yaml.safe_load((data / "intrinsics.yaml").read_text())
    w, h = intr["image_size"]
    cam = CameraModel(K=np.array(intr["K"]), dist=np.array(intr["dist"]), width=int(w),
                      height=int(h), name="image")
    crops = yaml.safe_load((data / "crops.yaml").read_text())
    offsets = [np.array(o, dtype=np.float64) for o in crops["offsets_xy"]]
    poses = [np.array(p, dtype=np.float64) for p in
             yaml.safe_load((data / "poses.yaml").read_text())["poses"]]
    images = [cv2.imread(str(data / "images" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE)
              for i in range(len(poses))]
    return board, cam, images, offsets, poses


def make_samples(detector: str = "auto", data: Path = DATA, refine: str = "saddle"):
    """The capture's hand-eye samples (board detected in every image, PnP pose), the views and
    the detections."""
    from eye_in_hand.core.calibration import detect_board
    from eye_in_hand.core.handeye import CameraView, CornerObservation, HandEyeSample
    from eye_in_hand.core.handeye.observe import board_pose_pnp

    board, cam, images, offsets, poses = load_capture(data)
    samples, dets = [], []
    for i, (img, off, pose) in enumerate(zip(images, offsets, poses, strict=False)):
        det = detect_board(img, board, detector, refine=refine)
        if not det.found:
            raise SystemExit(f"image {i:03d}: board not found ({det.reason})")
        px = det.corners + off
        C, _ = board_pose_pnp(cam, det.object_points, px)
        samples.append(HandEyeSample(f"{i:03d}", pose, C,
                                     (CornerObservation("image", det.object_points, px),)))
        dets.append(det)
    return samples, [CameraView("image", cam)], dets


def opencv_solutions(train_sets) -> list[dict[str, np.ndarray]] | None:
    """OpenCV 4.12's five methods on every training set, or None (through the sibling
    benchmark bench_handeye.py, which installs and runs it)."""
    from benchmarks.bench_handeye import run_opencv

    payload = [{"base_T_ee": np.stack([s.base_T_ee for s in t]).tolist(),
                "cam_T_board": np.stack([s.cam_T_board for s in t]).tolist()}
               for t in train_sets]
    out = run_opencv(payload)
    if out is None:
        return None
    print(f"OpenCV {out['version']} calibrateHandEye on the same detections and folds")
    return [{f"cv_{k}": np.array(v) for k, v in tr.items()} for tr in out["trials"]]


def main() -> None:
    from eye_in_hand.core.handeye import CLOSED_FORM_METHODS, calibrate_hand_eye
    from eye_in_hand.core.handeye.kfold import classic_fit, fold_indices, kfold_held_out, rms
    from eye_in_hand.core.handeye.solvers import board_in_fixed_frame
    from eye_in_hand.core.transforms import average_transforms

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--k", type=int, default=6, help="number of folds (default 6)")
    ap.add_argument("--detector", default="auto", help="board detector (default auto)")
    ap.add_argument("--refine", default="saddle", choices=("saddle", "none"),
                    help="corner refinement (default saddle; none: the detector's corners)")
    ap.add_argument("--no-opencv", action="store_true", help="skip OpenCV 4.12")
    ap.add_argument("--robot-model", default="systematic", choices=("per_pose", "systematic"),
                    help="calibrate_hand_eye's robot_model (default systematic)")
    args = ap.parse_args()

    samples, views, dets = make_samples(args.detector, refine=args.refine)
    n_corners = [d.n_corners for d in dets]
    from eye_in_hand.core.handeye.observe import board_pose_pnp
    pnp = [board_pose_pnp(views[0].model, s.observations[0].object_points,
                          s.observations[0].image_points)[1] for s in samples]
    sig = [d.meta.get("sigma_px", float("nan")) for d in dets]
    print(f"Franka + RealSense ChArUco capture: {len(samples)} views, {sum(n_corners)} corners "
          f"({min(n_corners)}-{max(n_corners)} per view), detector {args.detector!r}, "
          f"{args.k}-fold held-out prediction")
    print(f"corners: refinement {args.refine!r}, PnP residual "
          f"{np.sqrt(np.mean(np.square(pnp))):.3f} "
          f"px RMS over the views"
          + (f", corner sigma (median per view) {np.nanmin(sig):.3f}-{np.nanmax(sig):.3f} px"
             if np.any(np.isfinite(sig)) else ""))
    folds_idx = fold_indices(len(samples), args.k)
    trains = [[s for i, s in enumerate(samples) if i not in set(idx.tolist())]
              for idx in folds_idx]
    cv_sols = None if args.no_opencv else opencv_solutions(trains)
    fold_no = iter(range(args.k))

    def fit(train):
        f = next(fold_no)
        sols = {}
        for name in CLASSIC:
            sols[name] = classic_fit(CLOSED_FORM_METHODS[name], train, "eye_in_hand")
        if cv_sols is not None:
            bte = np.stack([s.base_T_ee for s in train])
            ctb = np.stack([s.cam_T_board for s in train])
            for name, X in cv_sols[f].items():
                sols[name] = (X, average_transforms(board_in_fixed_frame(X, bte, ctb,
                                                                         "eye_in_hand")))
        res = calibrate_hand_eye(train, "eye_in_hand", cameras=views,
                                 robot_model=args.robot_model)
        for name, mr in res.methods.items():
            sols[f"pkg_{name}"] = ((mr.X, mr.Y, res.systematic.correct)
                                   if name == "refined_systematic" else (mr.X, mr.Y))
        sols["selected"] = (res.X, res.methods[res.selected].Y, res.correct_robot_pose)
        return sols, {"selected": res.selected, "warnings": res.warnings,
                      "extra": {"systematic": res.systematic}}

    folds = kfold_held_out(samples, fit, k=args.k, cameras=views)
    methods = list(folds[0].errors)
    table = {}
    for m in methods:
        mm = rms([v.mm for f in folds for v in f.errors[m]])
        px = rms([v.px for f in folds for v in f.errors[m]])
        table[m] = (mm, px)
    ref_names = [m for m in methods if m.startswith("cv_")] or list(CLASSIC)
    best_mm = min(ref_names, key=lambda m: table[m][0])
    best_px = min(ref_names, key=lambda m: table[m][1])
    print(f"\nheld-out RMS over {args.k} folds (board corners of the held-out views):")
    print(f"  {'method':22s} {'base mm':>8s} {'image px':>9s}")
    for m in methods:
        tag = ""
        if m == best_mm:
            tag += "  <- best reference (mm)"
        if m == best_px:
            tag += "  <- best reference (px)"
        print(f"  {m:22s} {table[m][0]:8.3f} {table[m][1]:9.3f}{tag}")
    sel_mm, sel_px = table["selected"]
    print(f"\nselected / best reference: base frame {sel_mm:.3f} / {table[best_mm][0]:.3f} mm "
          f"= {sel_mm / table[best_mm][0]:.3f}x ({best_mm}); image {sel_px:.3f} / "
          f"{table[best_px][1]:.3f} px = {sel_px / table[best_px][1]:.3f}x ({best_px})")
    print("selected per fold: " + ", ".join(f.selected for f in folds)
          + "  (" + ", ".join(f"{k} {v}/{args.k}" for k, v in
                             Counter(f.selected for f in folds).most_common()) + ")")
    by_name = {s.name: s for s in samples}
    nees = []
    for f in folds:
        fit_s = f.extra.get("systematic")
        if fit_s is not None:
            held = [by_name[n] for n in f.held_out]
            nees.extend(fit_s.held_out_nees(np.stack([s.base_T_ee for s in held]),
                                            np.stack([s.cam_T_board for s in held]),
                                            "eye_in_hand").tolist())
    if nees:
        print(f"refined_systematic uncertainty on the held-out views: mean NEES "
              f"{np.mean(nees):.2f} over {len(nees)} views (6 dof: 6 when right; "
              f"{np.mean(nees) / 6:.2f}x dof), median {np.median(nees):.2f}")
    conv = [w for f in folds for w in f.warnings
            if "settle" in w or "converge" in w or "diverged" in w]
    print(f"convergence warnings: {len(conv)} in {args.k} folds"
          + "".join(f"\n  {w}" for w in conv))


if __name__ == "__main__":
    main()
