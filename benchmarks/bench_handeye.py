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

``--case kinematic``: the simulator's real-like arm (:mod:`eye_in_hand.sim.robot_error`)
instead of per-pose random noise. Per dataset a true arm is drawn from ``World.default()``'s
nominal UR5e with ``RobotErrorSpec.default()`` scaled by 1x and 3x (perturbed DH parameters,
the arm's seed the dataset's seed: the same arm shape at both scales); the corners come from
the true arm's flange pose at the true joints, the robot reports the nominal FK at the encoder
reading (the spec's encoder noise). Per level, medians over the datasets of: the error of X
against the true ``ee_T_cam`` (part of a kinematic error is a constant flange offset that no
method can tell from X: only the held-out figures judge the robot model fairly) and the k-fold
held-out prediction of the board (:mod:`eye_in_hand.core.handeye.kfold`: base-frame RMS mm and
image RMS px over the held-out corners, ``refined_systematic`` applying its correction to the
held-out poses, as ``bench_handeye_real.py``), for the selected result, every method it
computed and OpenCV 4.12's five methods; the selected result over the best OpenCV method; with
``--robot-model systematic`` the held-out NEES of the systematic model.

``--robot-model {per_pose,systematic}``: ``calibrate_hand_eye``'s robot error model in every
calibration of the run (default ``systematic``, the package's default).

Usage::

    .venv/bin/python benchmarks/bench_handeye.py [--trials 8] [--samples 15] [--noise 0.5]
    .venv/bin/python benchmarks/bench_handeye.py --pairs --no-opencv   # pose pairs only
    .venv/bin/python benchmarks/bench_handeye.py --case stereo --no-opencv
    .venv/bin/python benchmarks/bench_handeye.py --case eye_to_hand
    .venv/bin/python benchmarks/bench_handeye.py --nees 102
    .venv/bin/python benchmarks/bench_handeye.py --robot-model per_pose
    .venv/bin/python benchmarks/bench_handeye.py --case kinematic [--robot-model per_pose]
        [--k 5]
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


def make_kinematic_trial(world, seed: int, n: int, noise_px: float, spec):
    """One dataset of the real-like arm: the true arm drawn from ``world.arm`` with ``spec``
    (its seed), corners from the true flange poses, the nominal FK of the encoder reading
    reported. Returns ``(samples, flange translation errors m, rotation errors rad)``, the
    flange errors reported vs true per sample."""
    from eye_in_hand.core.handeye import CornerObservation, HandEyeSample
    from eye_in_hand.core.handeye.observe import board_pose_pnp
    from eye_in_hand.core.transforms import invert
    from eye_in_hand.sim.robot_error import (
        draw_true_arm,
        flange_poses,
        pose_error,
        reported_joints,
    )
    from eye_in_hand.sim.scenarios import calibration_poses

    rng = np.random.default_rng(seed)
    true_arm = draw_true_arm(world.arm, spec)
    cam = world.rig.left
    obj = world.board_points()
    samples, err = [], []
    for k, q in enumerate(calibration_poses(world, n, seed=seed)):
        true_T_ee, reported = flange_poses(world.arm, true_arm, q,
                                           reported_joints(q, spec, rng))
        cam_T_board = invert(true_T_ee @ world.ee_T_cam) @ world.base_T_board
        px = cam.project(obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3])
        px = px + rng.normal(scale=noise_px, size=px.shape)
        C, _ = board_pose_pnp(cam, obj, px)
        samples.append(HandEyeSample(f"{k:02d}", reported, C,
                                     (CornerObservation("left", obj, px),)))
        err.append(pose_error(true_T_ee, reported))
    e = np.asarray(err)
    return samples, e[:, 0], e[:, 1]


CASES = ("world", "stereo", "eye_to_hand", "kinematic")


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


def moveit_figures(robot_model: str = "systematic") -> None:
    """Real eye-to-hand data (MoveIt Calibration's pose pairs) against the published reference."""
    from scipy.spatial.transform import Rotation

    from eye_in_hand.core.handeye import HandEyeSample, calibrate_hand_eye
    from eye_in_hand.io.pose_pairs import load_pose_pairs

    pairs = load_pose_pairs(ROOT / "test" / "data" / "moveit_eye_to_hand" / "pose_samples.json")
    samples = [HandEyeSample(f"{i:02d}", a, b) for i, (a, b) in enumerate(pairs)]
    res = calibrate_hand_eye(samples, "eye_to_hand", robot_model=robot_model)
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
        print(f"  {name:18s} {mm:6.2f} mm {deg:6.3f} deg   held-out "
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
          + f", robot model {args.robot_model}; medians of |error| (mm, deg)")
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
            res = calibrate_hand_eye(samples, setup, cameras=None if args.pairs else views,
                                     robot_model=args.robot_model)
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
        rows = ["selected", "refined_systematic", "refined", "refined_exact",
                *CLOSED_FORM_METHODS, "average",
                *[f"avg_{k}" for k in AVERAGE_SOLVERS]]
        for name in rows:
            if name in errs:
                d, m = med(errs[name])
                extra = "" if len(errs[name]) == args.trials else \
                    f"  (ran on {len(errs[name])} of {args.trials})"
                print(f"  {name:18s} {m:8.3f} mm {d:8.4f} deg{extra}")
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
            print(f"  selected / OpenCV best: translation {s_mm / med(theirs[cv_mm])[1]:.2f}x, "
                  f"rotation {s_deg / med(theirs[cv_deg])[0]:.2f}x")
    print(f"time: {1000 * t_ours / (3 * args.trials):.0f} ms per calibration (all methods, "
          "refinements, leave-one-out selection)")
    if args.case == "world":
        moveit_figures(args.robot_model)


#: ``--case kinematic``: scales of ``RobotErrorSpec.default()``.
KINEMATIC_SCALES = (1.0, 3.0)


def kinematic(args: argparse.Namespace) -> None:
    """``--case kinematic``: X against the truth and k-fold held-out prediction, per scale of
    the simulator's robot error, for the selected result, its methods and OpenCV's."""
    from dataclasses import replace

    from eye_in_hand.core.handeye import CameraView, calibrate_hand_eye
    from eye_in_hand.core.handeye.calibrate import METHODS
    from eye_in_hand.core.handeye.kfold import fold_indices, kfold_held_out, rms
    from eye_in_hand.core.handeye.solvers import board_in_fixed_frame
    from eye_in_hand.core.transforms import average_transforms
    from eye_in_hand.sim import World
    from eye_in_hand.sim.robot_error import RobotErrorSpec

    world = World.default().with_image_size(640, 480)
    views = [CameraView("left", world.rig.left)]
    base_spec = RobotErrorSpec.default()
    print(f"hand-eye benchmark: the simulator's real-like arm (World.default() eye-in-hand, "
          f"UR5e), {args.samples} samples, 640x480, {args.noise} px corner noise, "
          f"{args.trials} datasets per robot error level (a true arm drawn per dataset, seed = "
          f"the dataset's), robot model {args.robot_model}, {args.k}-fold held-out prediction")
    print(f"default robot error: {base_spec.describe().split(': ', 1)[1].rsplit(' (seed', 1)[0]}"
          "; levels " + ", ".join(f"{s:g}x" for s in KINEMATIC_SCALES) + " of it")
    print("per level, medians over the datasets: |X - true ee_T_cam| (mm, deg); held-out board "
          "RMS over the k folds' held-out corners, base frame (mm) and image (px)")
    t_ours, n_cal = 0.0, 0
    for scale in KINEMATIC_SCALES:
        data = []
        payload = []
        for trial in range(args.trials):
            spec = replace(base_spec.scaled(scale), seed=args.seed + trial)
            samples, dt, dr = make_kinematic_trial(world, args.seed + trial, args.samples,
                                                   args.noise, spec)
            trains = [[s for i, s in enumerate(samples) if i not in set(idx.tolist())]
                      for idx in fold_indices(len(samples), args.k)]
            for t in [samples, *trains]:
                payload.append({"base_T_ee": [s.base_T_ee.tolist() for s in t],
                                "cam_T_board": [s.cam_T_board.tolist() for s in t]})
            data.append((samples, dt, dr))
        cv_out = None if args.no_opencv else run_opencv(payload)
        cv_sols = None if cv_out is None else [
            {f"cv_{k}": np.array(v) for k, v in tr.items()} for tr in cv_out["trials"]]

        x_err: dict[str, list[tuple[float, float]]] = {}
        held: dict[str, list[tuple[float, float]]] = {}
        picked: dict[str, int] = {}
        fold_picked: dict[str, int] = {}
        nees_all: list[float] = []
        nees_sel: list[float] = []
        flange = []
        for trial, (samples, dt, dr) in enumerate(data):
            flange.append((1000.0 * float(np.sqrt(np.mean(dt ** 2))),
                           float(np.degrees(np.sqrt(np.mean(dr ** 2))))))
            t1 = time.perf_counter()
            res = calibrate_hand_eye(samples, "eye_in_hand", cameras=views,
                                     robot_model=args.robot_model)
            t_ours += time.perf_counter() - t1
            n_cal += 1
            picked[res.selected] = picked.get(res.selected, 0) + 1
            x_err.setdefault("selected", []).append(errors(world.ee_T_cam, res.X))
            for name, mr in res.methods.items():
                x_err.setdefault(name, []).append(errors(world.ee_T_cam, mr.X))
            cv_trial = None if cv_sols is None else cv_sols[trial * (args.k + 1):
                                                            (trial + 1) * (args.k + 1)]
            if cv_trial is not None:
                for name, X in cv_trial[0].items():
                    x_err.setdefault(name, []).append(errors(world.ee_T_cam, X))
            fold_no = iter(range(args.k))

            def fit(train, cv_trial=cv_trial, fold_no=fold_no):
                nonlocal t_ours, n_cal
                f = next(fold_no)
                t1 = time.perf_counter()
                r = calibrate_hand_eye(train, "eye_in_hand", cameras=views,
                                       robot_model=args.robot_model)
                t_ours += time.perf_counter() - t1
                n_cal += 1
                sols = {"selected": (r.X, r.methods[r.selected].Y, r.correct_robot_pose)}
                for name, mr in r.methods.items():
                    sols[name] = ((mr.X, mr.Y, r.systematic.correct)
                                  if name == "refined_systematic" and r.systematic is not None
                                  else (mr.X, mr.Y))
                if cv_trial is not None:
                    bte = np.stack([s.base_T_ee for s in train])
                    ctb = np.stack([s.cam_T_board for s in train])
                    for name, X in cv_trial[1 + f].items():
                        sols[name] = (X, average_transforms(
                            board_in_fixed_frame(X, bte, ctb, "eye_in_hand")))
                return sols, {"selected": r.selected, "warnings": r.warnings,
                              "extra": {"systematic": r.systematic}}

            folds = kfold_held_out(samples, fit, k=args.k, cameras=views)
            for m in folds[0].errors:
                held.setdefault(m, []).append(
                    (rms([v.mm for f in folds for v in f.errors.get(m, [])]),
                     rms([v.px for f in folds for v in f.errors.get(m, [])])))
            by_name = {s.name: s for s in samples}
            for f in folds:
                fold_picked[f.selected] = fold_picked.get(f.selected, 0) + 1
                fit_s = f.extra.get("systematic")
                if fit_s is None:
                    continue
                hs = [by_name[n] for n in f.held_out]
                v = fit_s.held_out_nees(np.stack([s.base_T_ee for s in hs]),
                                        np.stack([s.cam_T_board for s in hs]),
                                        "eye_in_hand").tolist()
                nees_all.extend(v)
                if f.selected == "refined_systematic":
                    nees_sel.extend(v)

        def med(v: list[tuple[float, float]], i: int) -> float:
            return float(np.median(np.asarray(v)[:, i]))

        fl = np.asarray(flange)
        print(f"\nrobot error {scale:g}x default: reported vs true flange RMS per dataset, median "
              f"{np.median(fl[:, 0]):.3f} mm / {np.median(fl[:, 1]):.4f} deg; selected: "
              + ", ".join(f"{k} {v}x" for k, v in sorted(picked.items()))
              + "; selected per fold: "
              + ", ".join(f"{k} {v}x" for k, v in sorted(fold_picked.items())))
        print(f"  {'method':20s} {'X mm':>8s} {'X deg':>8s} {'held mm':>9s} {'held px':>9s}")
        cv_names = sorted(k for k in x_err if k.startswith("cv_"))
        rows = ["selected", *[m for m in METHODS if m in x_err], *cv_names]
        for name in rows:
            n_ok = len(x_err[name])
            extra = "" if n_ok == args.trials else f"  (ran on {n_ok} of {args.trials})"
            h = held.get(name)
            hm = f"{med(h, 0):9.3f} {med(h, 1):9.3f}" if h else f"{'-':>9s} {'-':>9s}"
            print(f"  {name:20s} {med(x_err[name], 1):8.3f} {med(x_err[name], 0):8.4f} "
                  f"{hm}{extra}")
        if cv_names:
            best = {i: min(cv_names, key=lambda k, i=i: med(x_err[k], i)) for i in (0, 1)}
            hbest = {i: min(cv_names, key=lambda k, i=i: med(held[k], i)) for i in (0, 1)}
            print("  selected / best OpenCV (by median): X translation "
                  f"{med(x_err['selected'], 1) / med(x_err[best[1]], 1):.2f}x ({best[1]}), "
                  f"rotation {med(x_err['selected'], 0) / med(x_err[best[0]], 0):.2f}x "
                  f"({best[0]}); held-out base frame "
                  f"{med(held['selected'], 0) / med(held[hbest[0]], 0):.2f}x ({hbest[0]}), "
                  f"image {med(held['selected'], 1) / med(held[hbest[1]], 1):.2f}x "
                  f"({hbest[1]})")
        if nees_all:
            line = (f"  refined_systematic uncertainty on the held-out views: mean NEES "
                    f"{np.mean(nees_all):.2f} over {len(nees_all)} views (6 dof: 6 when right; "
                    f"{np.mean(nees_all) / 6:.2f}x dof), median {np.median(nees_all):.2f}")
            if nees_sel:
                line += (f"; on the folds that selected it {np.mean(nees_sel):.2f} "
                         f"({np.mean(nees_sel) / 6:.2f}x dof, {len(nees_sel)} views)")
            print(line)
    print(f"time: {1000 * t_ours / max(n_cal, 1):.0f} ms per calibration (all methods, "
          f"refinements, leave-one-out selection; {n_cal} calibrations incl. the folds)")


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
        res = calibrate_hand_eye(samples, setup, cameras=None if args.pairs else views,
                                 robot_model=args.robot_model)
        C = res.covariance
        e = np.concatenate([res.X[:3, 3] - X_true[:3, 3], Rotation.from_matrix(
            res.X[:3, :3] @ X_true[:3, :3].T).as_rotvec()])
        nt = float(e[:3] @ np.linalg.solve(C[:3, :3], e[:3]))
        nr = float(e[3:] @ np.linalg.solve(C[3:, 3:], e[3:]))
        n6 = float(e @ np.linalg.solve(C, e))
        rows.append((i % len(cells), nt, nr, n6, res.selected))
    a = np.array([r[1:4] for r in rows])
    print(f"uncertainty check ({args.case}{', pose pairs' if args.pairs else ''}, robot model "
          f"{args.robot_model}): "
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
                             "eye_to_hand: synthetic datasets of that kind; kinematic: the "
                             "simulator's real-like arm (perturbed DH parameters)")
    parser.add_argument("--samples", type=int, default=15)
    parser.add_argument("--noise", type=float, default=0.5, help="corner noise, px")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--no-opencv", action="store_true",
                        help="skip the OpenCV 4.12 comparison")
    parser.add_argument("--pairs", action="store_true",
                        help="calibrate from the pose pairs only (no corners)")
    parser.add_argument("--nees", type=int, default=0, metavar="N",
                        help="instead: the uncertainty check over N datasets")
    parser.add_argument("--robot-model", choices=("per_pose", "systematic"),
                        default="systematic",
                        help="calibrate_hand_eye's robot error model (default: systematic, "
                             "the package's default)")
    parser.add_argument("--k", type=int, default=5,
                        help="--case kinematic: number of folds of the held-out prediction")
    args = parser.parse_args()
    if args.case == "kinematic" and (args.nees or args.pairs):
        parser.error("--case kinematic takes neither --nees nor --pairs")
    if args.case == "kinematic":
        kinematic(args)
    elif args.nees:
        nees(args)
    else:
        accuracy(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
