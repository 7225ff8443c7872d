"""Hand-eye accuracy: our solvers against OpenCV 4.12's ``calibrateHandEye`` on the same data.

Datasets: the simulator's geometry (``World.default()``: arm, distorted camera on ``tool0``,
9x6 chessboard), eye-in-hand, 15 samples per trial from ``calibration_poses``; board corners
projected through the true (distorted) left camera with 0.5 px Gaussian noise; ``cam_T_board``
from ``cv2.solvePnP`` on the noisy corners. Every method sees the same robot poses and the same
PnP poses; our ``refined`` additionally uses the same noisy corners of the left camera (no
right-camera data, so the comparison stays fair).

OpenCV 4.12 (which still ships ``calibrateHandEye``; the package's OpenCV 5 does not) is
installed by this script into its own venv under ``build/bench-venv`` and run as a subprocess.

Usage::

    .venv/bin/python benchmarks/bench_handeye.py [--trials 40] [--samples 15] [--noise 0.5]

Prints per-method median rotation (deg) and translation (mm) errors, ours vs OpenCV's, their
ratios, and the refined-vs-best-OpenCV ratios; then every method on the real eye-to-hand pose
pairs of ``test/data/moveit_eye_to_hand`` against the published reference.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BENCH_VENV = ROOT / "build" / "bench-venv"
OPENCV_PIN = "opencv-python-headless==4.12.0.88"

_OPENCV_SCRIPT = r"""
import json, sys
import cv2, numpy as np
data = json.load(open(sys.argv[1]))
methods = {"tsai": cv2.CALIB_HAND_EYE_TSAI, "park": cv2.CALIB_HAND_EYE_PARK,
           "horaud": cv2.CALIB_HAND_EYE_HORAUD, "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
           "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS}
out = {"version": cv2.__version__, "trials": []}
for trial in data:
    g = np.array(trial["base_T_ee"]); c = np.array(trial["cam_T_board"])
    res = {}
    for name, flag in methods.items():
        R, t = cv2.calibrateHandEye([m[:3, :3] for m in g], [m[:3, 3] for m in g],
                                    [m[:3, :3] for m in c], [m[:3, 3] for m in c], method=flag)
        X = np.eye(4); X[:3, :3] = R; X[:3, 3] = t.ravel()
        res[name] = X.tolist()
    out["trials"].append(res)
json.dump(out, open(sys.argv[2], "w"))
"""


def ensure_opencv_venv() -> Path:
    """Create ``build/bench-venv`` with OpenCV 4.12 if needed; return its python."""
    py = BENCH_VENV / "bin" / "python"
    check = [str(py), "-c", "import cv2, sys; sys.exit(cv2.__version__ != '4.12.0')"]
    if py.exists() and subprocess.run(check, capture_output=True).returncode == 0:
        return py
    print(f"installing {OPENCV_PIN} into {BENCH_VENV} ...", flush=True)
    subprocess.run([sys.executable, "-m", "venv", str(BENCH_VENV)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "--quiet", OPENCV_PIN, "numpy<2.3"],
                   check=True)
    subprocess.run(check, check=True)
    return py


def make_trial(world, seed: int, n: int, noise_px: float):
    """One dataset: samples (robot pose, PnP board pose, corners) and the true ee_T_cam."""
    from eye_in_hand.core.handeye import CornerObservation, HandEyeSample
    from eye_in_hand.core.handeye.observe import board_pose_pnp
    from eye_in_hand.core.transforms import invert
    from eye_in_hand.sim.scenarios import calibration_poses

    rng = np.random.default_rng(seed)
    cam = world.rig.left
    obj = world.board_points()
    samples = []
    for k, q in enumerate(calibration_poses(world, n, seed=seed)):
        base_T_ee = world.arm.fk(q)
        cam_T_board = invert(base_T_ee @ world.ee_T_cam) @ world.base_T_board
        px = cam.project(obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3])
        px = px + rng.normal(scale=noise_px, size=px.shape)
        C, _ = board_pose_pnp(cam, obj, px)
        samples.append(HandEyeSample(f"{k:02d}", base_T_ee, C,
                                     (CornerObservation("left", obj, px),)))
    return samples


def errors(X_true: np.ndarray, X: np.ndarray) -> tuple[float, float]:
    from eye_in_hand.core.transforms import transform_distance

    dt, dr = transform_distance(X_true, X)
    return float(np.degrees(dr)), 1000.0 * dt


def moveit_figures() -> None:
    """Real eye-to-hand data (MoveIt Calibration's pose pairs) against the published reference."""
    from scipy.spatial.transform import Rotation

    from eye_in_hand.core.handeye import HandEyeSample, calibrate_hand_eye
    from eye_in_hand.io.datasets import load_pose_pairs

    pairs = load_pose_pairs(ROOT / "test" / "data" / "moveit_eye_to_hand" / "pose_samples.json")
    samples = [HandEyeSample(f"{i:02d}", a, b) for i, (a, b) in enumerate(pairs)]
    res = calibrate_hand_eye(samples, "eye_to_hand", leave_one_out=False)
    ref = np.eye(4)
    ref[:3, :3] = Rotation.from_euler("XYZ", [0.230, -2.540, 1.950]).as_matrix()
    ref[:3, 3] = [0.659, -0.249, 0.830]
    print(f"real data: moveit_eye_to_hand ({len(samples)} pose pairs, eye-to-hand, "
          f"{len(res.rejected)} rejected), X = base_T_cam vs the published reference:")
    parts = []
    for name, mr in res.methods.items():
        deg, mm = errors(ref, mr.X)
        parts.append(f"{name} {mm:.2f} mm / {deg:.3f} deg")
    print("  " + ", ".join(parts))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--samples", type=int, default=15)
    parser.add_argument("--noise", type=float, default=0.5, help="corner noise, px")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()

    from eye_in_hand.core.handeye import CLOSED_FORM_METHODS, CameraView, calibrate_hand_eye
    from eye_in_hand.sim import World

    cv_py = ensure_opencv_venv()
    world = World.default()
    views = [CameraView("left", world.rig.left)]
    ours: dict[str, list[tuple[float, float]]] = {}
    payload = []
    t_ours = 0.0
    t0 = time.perf_counter()
    for trial in range(args.trials):
        samples = make_trial(world, args.seed + trial, args.samples, args.noise)
        payload.append({"base_T_ee": [s.base_T_ee.tolist() for s in samples],
                        "cam_T_board": [s.cam_T_board.tolist() for s in samples]})
        t1 = time.perf_counter()
        res = calibrate_hand_eye(samples, "eye_in_hand", cameras=views, reject_outliers=False,
                                 leave_one_out=False)
        t_ours += time.perf_counter() - t1
        for name, mr in res.methods.items():
            ours.setdefault(name, []).append(errors(world.ee_T_cam, mr.X))
    t_gen = time.perf_counter() - t0 - t_ours
    with tempfile.TemporaryDirectory() as tmp:
        inp, outp, script = Path(tmp) / "in.json", Path(tmp) / "out.json", Path(tmp) / "cv.py"
        inp.write_text(json.dumps(payload))
        script.write_text(_OPENCV_SCRIPT)
        t1 = time.perf_counter()
        subprocess.run([str(cv_py), str(script), str(inp), str(outp)], check=True)
        t_cv = time.perf_counter() - t1
        cv_out = json.loads(outp.read_text())
    theirs: dict[str, list[tuple[float, float]]] = {}
    for trial in cv_out["trials"]:
        for name, X in trial.items():
            theirs.setdefault(name, []).append(errors(world.ee_T_cam, np.array(X)))

    def med(v: list[tuple[float, float]]) -> tuple[float, float]:
        a = np.asarray(v)
        return float(np.median(a[:, 0])), float(np.median(a[:, 1]))

    print(f"hand-eye benchmark: eye-in-hand, {args.samples} samples, {args.noise} px corner "
          f"noise, {args.trials} trials (simulator geometry, World.default()); medians")
    print(f"OpenCV {cv_out['version']} calibrateHandEye (own venv {BENCH_VENV.relative_to(ROOT)})")
    print(f"{'method':11s} {'ours deg':>9s} {'cv deg':>9s} {'ratio':>6s}   "
          f"{'ours mm':>8s} {'cv mm':>8s} {'ratio':>6s}")
    for name in CLOSED_FORM_METHODS:
        o = med(ours[name])
        if name in theirs:
            c = med(theirs[name])
            print(f"{name:11s} {o[0]:9.4f} {c[0]:9.4f} {o[0] / c[0]:6.2f}   "
                  f"{o[1]:8.3f} {c[1]:8.3f} {o[1] / c[1]:6.2f}")
        else:
            print(f"{name:11s} {o[0]:9.4f} {'-':>9s} {'-':>6s}   {o[1]:8.3f} {'-':>8s} "
                  f"{'-':>6s}   (no OpenCV counterpart)")
    r = med(ours["refined"])
    best_deg = min(med(v)[0] for v in theirs.values())
    best_mm = min(med(v)[1] for v in theirs.values())
    best_deg_name = min(theirs, key=lambda k: med(theirs[k])[0])
    best_mm_name = min(theirs, key=lambda k: med(theirs[k])[1])
    print(f"{'refined':11s} {r[0]:9.4f} {'':9s} {'':6s}   {r[1]:8.3f}")
    print(f"refined vs best OpenCV: rotation {r[0] / best_deg:.2f}x (best {best_deg_name} "
          f"{best_deg:.4f} deg), translation {r[1] / best_mm:.2f}x (best {best_mm_name} "
          f"{best_mm:.3f} mm)")
    moveit_figures()
    print(f"time: data {t_gen:.1f} s, ours (6 closed forms + refinement + figures) "
          f"{1000 * t_ours / args.trials:.0f} ms/trial, OpenCV 5 methods "
          f"{1000 * t_cv / args.trials:.0f} ms/trial incl. process start")
    return 0


if __name__ == "__main__":
    sys.exit(main())
