"""Hand-eye accuracy with robot pose errors; the reported uncertainty against the actual error.

Datasets: the simulator's geometry (``World.default()`` resampled to 640x480: arm, distorted
camera on ``tool0``, 9x6 chessboard), eye-in-hand, 15 samples per dataset from
``calibration_poses``; board corners projected through the true (distorted) camera with Gaussian
pixel noise; ``cam_T_board`` from ``cv2.solvePnP`` on the noisy corners. Robot pose error: each
reported ``base_T_ee`` is multiplied on the right (flange frame) by a random SE(3) perturbation
whose translation and rotation-vector components are Gaussian with the given 1-sigma per axis.

Default mode: for robot error 0, 0.2 mm / 0.02 deg and 1 mm / 0.1 deg, the median error of the
selected result (what ``calibrate handeye`` writes), every closed form, the exact-pose refinement
(``refined_exact``), the per-motion-pair average (``average``, with the package's default
per-pair solver; ``avg_<other>`` is the same average with the other per-pair solver, on
the same kept samples) and the errors-in-variables refinement (``refined``), in one run; OpenCV
4.12's ``calibrateHandEye`` on the same poses (installed by this script into its own venv under
``build/bench-venv``, since the package's OpenCV 5 has no ``calibrateHandEye``; skipped with
``--no-opencv`` or when it cannot be installed); then the real eye-to-hand pose pairs of
``test/data/moveit_eye_to_hand``.

``--nees N``: N datasets over robot error {0, 0.2 mm/0.02 deg, 1 mm/0.1 deg} x pixel noise
{0.3, 1.0} px; for the selected result, the mean normalised estimation error squared (NEES,
3 dof each for translation and rotation: 3 when the covariance is right) and how often the 95 %
ellipsoid (translation, rotation, and the joint 6-dof one) contains the true X; with
``--case`` and ``--pairs`` on those inputs.

``--case stereo`` and ``--case eye_to_hand``: the same comparison on
``core.handeye.synthetic.make_problem`` datasets (a 640x480 camera with mild distortion, 15
views of a 9x6 board at 0.35-0.6 m; ``stereo``: a second camera 6 cm to the right with its own
corners; ``eye_to_hand``: the camera fixed, the board on the flange, X = ``base_T_cam``), so
that the errors-in-variables refinement is measured on every input it takes (with ``--pairs``:
pose pairs of the same datasets).

Usage::

    .venv/bin/python benchmarks/bench_handeye.py [--trials 8] [--samples 15] [--noise 0.5]
    .venv/bin/python benchmarks/bench_handeye.py --pairs --no-opencv   # pose pairs only
    .venv/bin/python benchmarks/bench_handeye.py --case stereo --no-opencv
    .venv/bin/python benchmarks/bench_handeye.py --case eye_to_hand
    .venv/bin/python benchmarks/bench_handeye.py --nees 102
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


def make_trial(world, seed: int, n: int, noise_px: float, robot_mm: float = 0.0,
               robot_deg: float = 0.0):
    """One dataset: samples (reported robot pose, PnP board pose, corners)."""
    from eye_in_hand.core.handeye import CornerObservation, HandEyeSample
    from eye_in_hand.core.handeye.observe import board_pose_pnp
    from eye_in_hand.core.transforms import from_rotvec, invert
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
        reported = base_T_ee @ from_rotvec(rng.normal(scale=np.radians(robot_deg), size=3),
                                           rng.normal(scale=robot_mm / 1000.0, size=3))
        samples.append(HandEyeSample(f"{k:02d}", reported, C,
                                     (CornerObservation("left", obj, px),)))
    return samples


CASES = ("world", "stereo", "eye_to_hand")


def bench_camera():
    """The synthetic cases' camera: ``default_camera`` scaled to 640x480."""
    from eye_in_hand.core.camera import CameraModel
    from eye_in_hand.core.handeye.synthetic import default_camera

    cam = default_camera()
    K = np.array([[450.0, 0.0, 320.0], [0.0, 450.0, 240.0], [0.0, 0.0, 1.0]])
    return CameraModel(K=K, dist=cam.dist, width=640, height=480, name="left")


def make_case(case: str, world, seed: int, n: int, noise_px: float, robot_mm: float,
              robot_deg: float):
    """One dataset of ``case``: ``(samples, views, setup, X_true)``."""
    from eye_in_hand.core.handeye import CameraView
    from eye_in_hand.core.handeye.synthetic import make_problem

    if case == "world":
        samples = make_trial(world, seed, n, noise_px, robot_mm, robot_deg)
        return samples, [CameraView("left", world.rig.left)], "eye_in_hand", world.ee_T_cam
    P = make_problem(n, setup="eye_to_hand" if case == "eye_to_hand" else "eye_in_hand",
                     seed=seed, noise_px=noise_px, stereo=case == "stereo",
                     robot_noise_mm=robot_mm, robot_noise_deg=robot_deg, camera=bench_camera())
    return P.samples, P.views, P.setup, P.X


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
    res = calibrate_hand_eye(samples, "eye_to_hand")
    ref = np.eye(4)
    ref[:3, :3] = Rotation.from_euler("XYZ", [0.230, -2.540, 1.950]).as_matrix()
    ref[:3, 3] = [0.659, -0.249, 0.830]
    noise = res.robot_pose_noise
    print(f"real data: moveit_eye_to_hand ({len(samples)} pose pairs, eye-to-hand, "
          f"{len(res.rejected)} rejected), X = base_T_cam vs the published reference; "
          f"selected {res.selected} ({res.selection_reason})")
    if noise is not None:
        print("  estimated robot+camera translation noise "
              f"{1000 * noise['translation_sigma_m']:.3f} mm, robot rotation noise "
              f"{np.degrees(noise['rotation_sigma_rad']):.4f} deg")
    for name, mr in res.methods.items():
        deg, mm = errors(ref, mr.X)
        h = mr.held_out.summary() if mr.held_out is not None else {}
        nan = float("nan")
        print(f"  {name:14s} {mm:6.2f} mm {deg:6.3f} deg   held-out "
              f"{h.get('mm_rms', nan):6.2f} mm {h.get('deg_rms', nan):6.3f} deg, score "
              f"{res.selection_scores.get(name, float('nan')):.3f}"
              + ("  <- selected" if name == res.selected else ""))


def run_opencv(payload: list[dict]) -> dict | None:
    """OpenCV 4.12's five methods on every dataset, or None when it cannot be installed."""
    try:
        cv_py = ensure_opencv_venv()
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"OpenCV 4.12 comparison skipped: cannot install it ({exc})")
        return None
    with tempfile.TemporaryDirectory() as tmp:
        inp, outp, script = Path(tmp) / "in.json", Path(tmp) / "out.json", Path(tmp) / "cv.py"
        inp.write_text(json.dumps(payload))
        script.write_text(_OPENCV_SCRIPT)
        subprocess.run([str(cv_py), str(script), str(inp), str(outp)], check=True)
        return json.loads(outp.read_text())


LEVELS = ((0.0, 0.0), (0.2, 0.02), (1.0, 0.1))


def other_average(res, samples) -> dict[str, np.ndarray]:
    """The per-motion-pair average with the non-default per-pair solver(s), on the samples
    ``res`` kept (``avg_<solver>``); empty when it cannot solve them."""
    from eye_in_hand.core.handeye import gripper_poses, motion_pairs
    from eye_in_hand.core.handeye.average import (
        AVERAGE_SOLVERS,
        DEFAULT_AVERAGE_SOLVER,
        average_hand_eye,
    )
    from eye_in_hand.errors import HandEyeError

    kept = [s for s in samples if s.name in set(res.sample_names)]
    m = motion_pairs(gripper_poses(np.stack([s.base_T_ee for s in kept]), res.setup),
                     np.stack([s.cam_T_board for s in kept]))
    out = {}
    for solver in AVERAGE_SOLVERS:
        if solver != DEFAULT_AVERAGE_SOLVER:
            try:
                out[f"avg_{solver}"] = average_hand_eye(m, solver).X
            except HandEyeError:
                pass
    return out


def accuracy(args: argparse.Namespace) -> None:
    """Median errors per robot error level: selected, closed forms, refinements, OpenCV."""
    from eye_in_hand.core.handeye import CLOSED_FORM_METHODS, HandEyeSample, calibrate_hand_eye
    from eye_in_hand.core.handeye.average import AVERAGE_SOLVERS
    from eye_in_hand.sim import World

    world = World.default().with_image_size(640, 480)
    what = {"world": "eye-in-hand, World.default() geometry",
            "stereo": "eye-in-hand stereo (6 cm baseline), synthetic geometry",
            "eye_to_hand": "eye-to-hand, synthetic geometry"}[args.case]
    print(f"hand-eye benchmark: {what}, {args.samples} samples, 640x480, {args.noise} px "
          f"corner noise, {args.trials} datasets per robot error level"
          + (", pose pairs only (corners dropped)" if args.pairs else "")
          + "; medians of |error| (mm, deg)")
    t_ours = 0.0
    for mm_sig, deg_sig in LEVELS:
        errs: dict[str, list[tuple[float, float]]] = {}
        truths: list[np.ndarray] = []
        payload = []
        picked: dict[str, int] = {}
        for trial in range(args.trials):
            samples, views, setup, X_true = make_case(args.case, world, args.seed + trial,
                                                      args.samples, args.noise, mm_sig, deg_sig)
            # OpenCV takes the gripper's motion: gripper-to-base eye-in-hand, its inverse
            # eye-to-hand (then it returns base_T_cam)
            payload.append({"base_T_ee": [(s.base_T_ee if setup == "eye_in_hand"
                                           else np.linalg.inv(s.base_T_ee)).tolist()
                                          for s in samples],
                            "cam_T_board": [s.cam_T_board.tolist() for s in samples]})
            t1 = time.perf_counter()
            if args.pairs:
                samples = [HandEyeSample(s.name, s.base_T_ee, s.cam_T_board) for s in samples]
            res = calibrate_hand_eye(samples, setup, cameras=None if args.pairs else views)
            t_ours += time.perf_counter() - t1
            picked[res.selected] = picked.get(res.selected, 0) + 1
            errs.setdefault("selected", []).append(errors(X_true, res.X))
            for name, mr in res.methods.items():
                errs.setdefault(name, []).append(errors(X_true, mr.X))
            for name, X in other_average(res, samples).items():
                errs.setdefault(name, []).append(errors(X_true, X))
            truths.append(X_true)
        cv_out = None if args.no_opencv else run_opencv(payload)

        def med(v: list[tuple[float, float]]) -> tuple[float, float]:
            a = np.asarray(v)
            return float(np.median(a[:, 0])), float(np.median(a[:, 1]))

        print(f"robot error {mm_sig} mm / {deg_sig} deg (1 sigma per axis, per pose); selected: "
              + ", ".join(f"{k} {v}x" for k, v in sorted(picked.items())))
        rows = ["selected", "refined", "refined_exact", *CLOSED_FORM_METHODS, "average",
                *[f"avg_{k}" for k in AVERAGE_SOLVERS]]
        for name in rows:
            if name in errs:
                d, m = med(errs[name])
                extra = "" if len(errs[name]) == args.trials else \
                    f"  (ran on {len(errs[name])} of {args.trials})"
                print(f"  {name:14s} {m:8.3f} mm {d:8.4f} deg{extra}")
        closed = [k for k in CLOSED_FORM_METHODS if k in errs]
        best_mm = min(closed, key=lambda k: med(errs[k])[1])
        best_deg = min(closed, key=lambda k: med(errs[k])[0])
        s_deg, s_mm = med(errs["selected"])
        print(f"  selected / best closed form: translation {s_mm / med(errs[best_mm])[1]:.2f}x "
              f"({best_mm}), rotation {s_deg / med(errs[best_deg])[0]:.2f}x ({best_deg})")
        # the median of the best of six closed forms is picked after the fact: also the RMS over
        # the datasets, and how often the selected result beats that closed form per dataset
        sel_a = np.asarray(errs["selected"])
        rms_mm = {k: float(np.sqrt(np.mean(np.asarray(errs[k])[:, 1] ** 2))) for k in closed}
        k_mm = min(rms_mm, key=lambda k: rms_mm[k])
        wins = int(np.sum(sel_a[:, 1] <= np.asarray(errs[best_mm])[:, 1]))
        print(f"  RMS over the datasets: selected {np.sqrt(np.mean(sel_a[:, 1] ** 2)):.3f} mm, "
              f"best closed form {rms_mm[k_mm]:.3f} mm ({k_mm}); selected no worse than "
              f"{best_mm} in {wins} of {len(sel_a)} datasets")
        if cv_out is not None:
            theirs: dict[str, list[tuple[float, float]]] = {}
            for trial, X_true in zip(cv_out["trials"], truths, strict=False):
                for name, X in trial.items():
                    theirs.setdefault(name, []).append(errors(X_true, np.array(X)))
            cv_mm = min(theirs, key=lambda k: med(theirs[k])[1])
            cv_deg = min(theirs, key=lambda k: med(theirs[k])[0])
            print(f"  OpenCV {cv_out['version']} best: {med(theirs[cv_mm])[1]:.3f} mm ({cv_mm}), "
                  f"{med(theirs[cv_deg])[0]:.4f} deg ({cv_deg}); OpenCV park "
                  f"{med(theirs['park'])[1]:.3f} mm / {med(theirs['park'])[0]:.4f} deg")
    print(f"time: {1000 * t_ours / (3 * args.trials):.0f} ms per calibration (all methods, "
          "refinements, leave-one-out selection)")
    if args.case == "world":
        moveit_figures()


def nees(args: argparse.Namespace) -> None:
    """NEES and 95 % coverage of the selected result's covariance over a sweep of datasets."""
    from scipy.spatial.transform import Rotation
    from scipy.stats import chi2

    from eye_in_hand.core.handeye import HandEyeSample, calibrate_hand_eye
    from eye_in_hand.sim import World

    world = World.default().with_image_size(640, 480)
    cells = [(lv, px) for lv in LEVELS for px in (0.3, 1.0)]
    k3, k6 = chi2.ppf(0.95, 3), chi2.ppf(0.95, 6)
    rows = []
    for i in range(args.nees):
        (mm_sig, deg_sig), px = cells[i % len(cells)]
        samples, views, setup, X_true = make_case(args.case, world, args.seed + 5000 + i,
                                                  args.samples, px, mm_sig, deg_sig)
        if args.pairs:
            samples = [HandEyeSample(s.name, s.base_T_ee, s.cam_T_board) for s in samples]
        res = calibrate_hand_eye(samples, setup, cameras=None if args.pairs else views)
        C = res.covariance
        e = np.concatenate([res.X[:3, 3] - X_true[:3, 3], Rotation.from_matrix(
            res.X[:3, :3] @ X_true[:3, :3].T).as_rotvec()])
        nt = float(e[:3] @ np.linalg.solve(C[:3, :3], e[:3]))
        nr = float(e[3:] @ np.linalg.solve(C[3:, 3:], e[3:]))
        n6 = float(e @ np.linalg.solve(C, e))
        rows.append((i % len(cells), nt, nr, n6, res.selected))
    a = np.array([r[1:4] for r in rows])
    print(f"uncertainty check ({args.case}{', pose pairs' if args.pairs else ''}): "
          f"{len(rows)} datasets ({args.samples} samples, 640x480), robot "
          "error {0, 0.2 mm/0.02 deg, 1 mm/0.1 deg} x pixel noise {0.3, 1.0} px; covariance of "
          "the selected result")
    print(f"  mean NEES translation {a[:, 0].mean():.2f}, rotation {a[:, 1].mean():.2f} "
          f"(3 when right; target 1.5-6); 6-dof {a[:, 2].mean():.2f} (6 when right)")
    print(f"  95 % ellipsoid coverage: translation {100 * np.mean(a[:, 0] < k3):.1f} %, rotation "
          f"{100 * np.mean(a[:, 1] < k3):.1f} %, 6-dof {100 * np.mean(a[:, 2] < k6):.1f} % "
          "(target 85-99 %)")
    for c, ((mm_sig, deg_sig), px) in enumerate(cells):
        sub = np.array([r[1:4] for r in rows if r[0] == c])
        sel = [r[4] for r in rows if r[0] == c]
        if sub.size:
            print(f"  robot {mm_sig} mm/{deg_sig} deg, {px} px: n={len(sub)} NEES t "
                  f"{sub[:, 0].mean():.2f} r {sub[:, 1].mean():.2f}, coverage 6-dof "
                  f"{100 * np.mean(sub[:, 2] < k6):.0f} %; selected "
                  + ", ".join(f"{k} {sel.count(k)}" for k in sorted(set(sel))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=32,
                        help="datasets per robot error level (at least 8; the medians of 8 "
                             "datasets move by tens of per cent between seeds at 1 mm)")
    parser.add_argument("--case", choices=CASES, default="world",
                        help="world: World.default() eye-in-hand (default); stereo, "
                             "eye_to_hand: synthetic datasets of that kind")
    parser.add_argument("--samples", type=int, default=15)
    parser.add_argument("--noise", type=float, default=0.5, help="corner noise, px")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--no-opencv", action="store_true",
                        help="skip the OpenCV 4.12 comparison")
    parser.add_argument("--pairs", action="store_true",
                        help="calibrate from the pose pairs only (no corners)")
    parser.add_argument("--nees", type=int, default=0, metavar="N",
                        help="instead: the uncertainty check over N datasets")
    args = parser.parse_args()
    if args.nees:
        nees(args)
    else:
        accuracy(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
