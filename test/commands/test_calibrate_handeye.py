"""``eye-in-hand calibrate handeye`` end to end: rendered stereo dataset, pose pairs, errors."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.cli import main
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.handeye import METHODS
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import transform_distance
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.io.datasets import write_dataset


def _render(cam: CameraModel, T: np.ndarray, cols: int = 9, rows: int = 6, sq: float = 0.025,
            scale: int = 4) -> np.ndarray:
    """Fast anti-aliased chessboard image: distorted square outlines filled at 4x, then area
    downsampling (corner error about 0.2 px, enough for an end-to-end test)."""
    img = np.full((cam.height * scale, cam.width * scale), 110, np.uint8)
    t = np.linspace(0.0, 1.0, 9)

    def poly(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        pts = np.concatenate([np.stack([x0 + (x1 - x0) * t, np.full(9, y0)], 1),
                              np.stack([np.full(9, x1), y0 + (y1 - y0) * t], 1),
                              np.stack([x1 - (x1 - x0) * t, np.full(9, y1)], 1),
                              np.stack([np.full(9, x0), y1 - (y1 - y0) * t], 1)])
        P = np.hstack([pts, np.zeros((len(pts), 1))]) @ T[:3, :3].T + T[:3, 3]
        px = cam.project(P) * scale + (scale - 1) / 2.0
        return np.round(px * 16).astype(np.int32)

    cv2.fillPoly(img, [poly(-2 * sq, -2 * sq, (cols + 1) * sq, (rows + 1) * sq)], 230,
                 cv2.LINE_8, 4)
    for i in range(-1, cols):
        for j in range(-1, rows):
            if (i + j) % 2 == 0:
                cv2.fillPoly(img, [poly(i * sq, j * sq, (i + 1) * sq, (j + 1) * sq)], 25,
                             cv2.LINE_8, 4)
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module")
def stereo_dataset(tmp_path_factory) -> tuple[Path, np.ndarray]:
    cam = CameraModel(K=np.array([[560.0, 0, 320], [0, 560.0, 200], [0, 0, 1]]),
                      dist=np.array([-0.1, 0.05, 0, 0, 0]), width=640, height=400, name="left")
    P = make_problem(10, seed=3, stereo=True, noise_px=0.0, camera=cam)
    right = P.views[1]
    rig = StereoRig(left=cam, right=right.model, R=right.view_T_cam[:3, :3],
                    T=right.view_T_cam[:3, 3])
    images = [{v.name: _render(v.model, v.view_T_cam @ C) for v in P.views}
              for C in P.true_cam_T_board]
    poses = list(P.true_base_T_ee)
    # One sample where the board is out of view: skipped and listed, never used.
    images.append({"left": np.full((400, 640), 110, np.uint8),
                   "right": np.full((400, 640), 110, np.uint8)})
    poses.append(poses[0])
    root = tmp_path_factory.mktemp("handeye_ds")
    write_dataset(root, setup="eye_in_hand", board="chessboard:9x6:0.025", images=images,
                  base_T_ee=poses, rig=rig, ground_truth={"ee_T_cam": P.X, "base_T_board": P.Y})
    return root, P.X


def test_dataset_end_to_end(stereo_dataset, tmp_path: Path, capsys) -> None:
    root, X_true = stereo_dataset
    out = tmp_path / "out"
    assert main(["calibrate", "handeye", str(root), "-o", str(out)]) == 0
    printed = capsys.readouterr()
    assert "sample '0010' skipped: board not found in the left image" in printed.err
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.setup == "eye_in_hand" and calib.parent_frame == "tool0"
    report = json.loads((out / "report.json").read_text())
    # Exact robot poses: the two refinements coincide and predict the held-out samples best.
    assert calib.child_frame == "camera_left_optical_frame"
    assert calib.method == report["selected"] in ("refined", "refined_exact")
    scores = report["selection"]["scores"]
    assert f"selected {report['selected']}: " in printed.out
    # the default (systematic) robot model scores corners and board position together
    assert "held-out corners (px) and board position (mm)" in report["selection"]["reason"]
    assert report["robot_model"] == "systematic" and calib.robot_pose_correction is None
    assert calib.sample_count == 10 and calib.covariance is not None
    noise = calib.robot_pose_noise
    assert noise is not None and noise == report["robot_pose_noise"]
    assert noise["translation_sigma_m"] < 5e-5 and noise["rotation_sigma_rad"] < 1e-4
    dt, dr = transform_distance(X_true, calib.transform)
    assert dt < 0.0005 and np.degrees(dr) < 0.05, (dt, np.degrees(dr))
    assert set(report["methods"]) == set(scores) == set(METHODS)
    for m in report["methods"].values():
        assert len(m["translation"]) == 3 and len(m["quat_xyzw"]) == 4
        assert m["residuals"]["reproj_px_rms"] < 1.0
    assert report["skipped"] == [{"name": "0010", "reason": report["skipped"][0]["reason"]}]
    assert report["input"]["stereo"] is True
    assert len([s for s in report["samples"] if s["used"]]) == 10
    assert report["ground_truth_error"]["refined"]["mm"] < 0.5
    html = (out / "report.html").read_text()
    assert html.count("<img") >= 3 and "Method comparison" in html and "0010" in html
    # the error budget: in report.json, the HTML report and the summary; its parts add up
    b = report["error_budget"]
    assert "Error budget" in html and "error budget (held-out board position" in printed.out
    parts = sum(b[k] ** 2 for k in ("camera_mm", "robot_mm", "estimate_mm"))
    assert b["estimate_mm"] == 0.0 or parts == pytest.approx(b["held_out_mm"] ** 2, rel=1e-3)


def test_pairs_eye_to_hand_with_method(data_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "o"
    pairs = data_dir / "moveit_eye_to_hand" / "pose_samples.json"
    rc = main(["calibrate", "handeye", "--pairs", str(pairs), "--setup", "eye_to_hand",
               "--method", "park", "--no-html", "--no-outlier-rejection", "-o", str(out)])
    assert rc == 0
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.method == "park" and calib.parent_frame == "base_link"
    ref = np.eye(4)
    ref[:3, :3] = Rotation.from_euler("XYZ", [0.230, -2.540, 1.950]).as_matrix()
    ref[:3, 3] = [0.659, -0.249, 0.830]
    dt, dr = transform_distance(ref, calib.transform)
    assert dt < 0.002 and np.degrees(dr) < 0.35
    report = json.loads((out / "report.json").read_text())
    assert report["refinement"]["space"] == "pose" and "refined" in report["methods"]
    assert not (out / "report.html").exists()


def test_method_average_writes_x_and_the_residual_tables(tmp_path: Path, capsys) -> None:
    """Pose pairs (eye-to-hand), ``--method average --average-solver kronecker``: hand_eye.yaml
    has the average, report.json and report.html the pairs, the spread and the per-motion
    residual table of every method."""
    P = make_problem(7, setup="eye_to_hand", seed=5, noise_px=0.3)
    pairs = tmp_path / "pairs.json"
    pairs.write_text(json.dumps([[s.base_T_ee.tolist(), s.cam_T_board.tolist()]
                                 for s in P.samples]))
    out = tmp_path / "o"
    assert main(["calibrate", "handeye", "--pairs", str(pairs), "--setup", "eye_to_hand",
                 "--method", "average", "--average-solver", "kronecker", "--no-refine",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "average (kronecker per pair): " in printed
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.method == "average" and calib.parent_frame == "base_link"
    dt, dr = transform_distance(P.X, calib.transform)
    assert dt < 0.01 and np.degrees(dr) < 0.3, (dt, np.degrees(dr))
    report = json.loads((out / "report.json").read_text())
    avg = report["methods"]["average"]["average"]
    assert avg["solver"] == "kronecker" and avg["n_motions"] == 21
    assert avg["n_pairs_used"] + sum(avg["skipped"].values()) == 21 * 20 // 2
    assert avg["spread"]["rot_std_deg"] > 0 and avg["spread"]["trans_std_mm"] > 0
    table = report["motion_residuals"]
    assert table["methods"] == list(report["methods"]) and "average" in table["methods"]
    assert table["motions"][0] == ["pair000", "pair001"] and len(table["motions"]) == 21
    for q in ("rot_deg", "trans_mm", "frobenius"):
        assert all(len(table[q][m]) == 21 for m in table["methods"])
        assert set(table["summary"]["average"][q]) == {"mean", "median", "max"}
    assert "selection" in report and "samples" in report     # the keys that were there stay
    html = (out / "report.html").read_text()
    assert "Per-motion AX = XB residuals" in html and "pair000 - pair001" in html
    assert "X from each pair of motions, averaged" in html and "average deg / mm / Frob" in html


def test_duplicate_sample_is_reported(data_dir: Path, tmp_path: Path, capsys) -> None:
    pairs = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    dup = tmp_path / "dup.json"
    dup.write_text(json.dumps(pairs[:12] + [pairs[3]]))
    out = tmp_path / "o"
    assert main(["calibrate", "handeye", "--pairs", str(dup), "--setup", "eye_to_hand",
                 "--no-html", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: sample 'pair012' (#12) duplicates sample 'pair003': dropped" in err
    report = json.loads((out / "report.json").read_text())
    assert any("duplicates sample 'pair003'" in w for w in report["warnings"])
    assert load_hand_eye(out / "hand_eye.yaml").sample_count == 12


def test_errors_are_one_line(tmp_path: Path, data_dir: Path, capsys) -> None:
    pairs = data_dir / "moveit_eye_to_hand" / "pose_samples.json"
    assert main(["calibrate", "handeye", str(tmp_path), "--pairs", str(pairs),
                 "-o", str(tmp_path / "o")]) == 1
    assert "give exactly one input" in capsys.readouterr().err
    two = tmp_path / "two.json"
    two.write_text(json.dumps(json.loads(pairs.read_text())[:2]))
    assert main(["calibrate", "handeye", "--pairs", str(two), "-o", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("eye-in-hand: error:") and "at least 3" in err
    assert err.count("\n") == 1
    assert main(["calibrate", "handeye", str(tmp_path / "none"), "-o", str(tmp_path / "o")]) == 1
    assert "dataset file not found" in capsys.readouterr().err


def test_mono_eye_to_hand_dataset(tmp_path: Path) -> None:
    cam = CameraModel(K=np.array([[560.0, 0, 320], [0, 560.0, 200], [0, 0, 1]]),
                      dist=np.array([-0.1, 0.05, 0, 0, 0]), width=640, height=400,
                      name="camera")
    P = make_problem(9, setup="eye_to_hand", seed=6, noise_px=0.0, camera=cam)
    images = [{"image": _render(cam, C)} for C in P.true_cam_T_board]
    write_dataset(tmp_path / "ds", setup="eye_to_hand", board="chessboard:9x6:0.025",
                  images=images, base_T_ee=list(P.true_base_T_ee), camera=cam,
                  ground_truth={"base_T_cam": P.X})
    out = tmp_path / "out"
    assert main(["calibrate", "handeye", str(tmp_path / "ds"), "--no-html", "-o", str(out)]) == 0
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.setup == "eye_to_hand" and calib.parent_frame == "base_link"
    dt, dr = transform_distance(P.X, calib.transform)  # base_T_cam
    assert dt < 0.001 and np.degrees(dr) < 0.1, (dt, np.degrees(dr))
    report = json.loads((out / "report.json").read_text())
    assert report["refinement"]["space"] == "reprojection"
    assert report["ground_truth_error"]["refined"]["mm"] < 1.0


def test_a_board_given_in_squares_stops_after_the_first_samples(stereo_dataset, tmp_path,
                                                                 capsys) -> None:
    """The trap: `10x7` (squares) for a 9x6 board skipped every sample and failed at the end
    with no hint."""
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(stereo_dataset[0], root)
    text = (root / "dataset.yaml").read_text()
    assert "chessboard:9x6:0.025" in text
    (root / "dataset.yaml").write_text(text.replace("chessboard:9x6:0.025",
                                                    "chessboard:10x7:0.025"))
    assert main(["calibrate", "handeye", str(root), "-o", str(tmp_path / "out")]) != 0
    err = capsys.readouterr().err
    assert ("no board chessboard:10x7:0.025 found in the first 8 samples' left images; a 9x6 "
            "chessboard (inner corners) is found in 8 of them") in err
    assert "dataset.yaml board: chessboard:9x6:0.025" in err
    assert "skipped" not in err and not (tmp_path / "out").exists()


def test_robot_model_systematic_writes_the_pose_correction(tmp_path: Path, capsys) -> None:
    """``--robot-model systematic`` on poses with a pose-dependent robot error: the method is
    refined_systematic and hand_eye.yaml carries the correction its X holds with; the default
    model writes none. The CLI's choices are core.handeye's."""
    from eye_in_hand.cli import build_parser
    from eye_in_hand.core.handeye import calibrate_hand_eye
    from eye_in_hand.core.handeye.calibrate import DEFAULT_ROBOT_MODEL, ROBOT_MODELS

    from ..core.test_handeye_systematic import A_R, A_T, _problem

    handeye = build_parser(["calibrate", "handeye"])._subparsers._group_actions[0] \
        .choices["calibrate"]._subparsers._group_actions[0].choices["handeye"]
    options = {a.dest: a for a in handeye._actions}
    assert tuple(options["method"].choices) == ("all", *METHODS)
    assert tuple(options["robot_model"].choices) == ROBOT_MODELS
    assert options["robot_model"].default == DEFAULT_ROBOT_MODEL
    samples = _problem(12, 5, A_R, A_T)
    pairs = tmp_path / "pairs.json"
    pairs.write_text(json.dumps([[s.base_T_ee.tolist(), s.cam_T_board.tolist()]
                                 for s in samples]))
    out = tmp_path / "sys"
    assert main(["calibrate", "handeye", "--pairs", str(pairs), "--robot-model", "systematic",
                 "--no-html", "-o", str(out)]) == 0
    calib = load_hand_eye(out / "hand_eye.yaml")
    want = calibrate_hand_eye(samples, robot_model="systematic")
    assert calib.method == "refined_systematic" == want.selected
    assert calib.robot_pose_correction is not None
    assert np.allclose(calib.robot_pose_correction.A_r, want.systematic.A_r, atol=1e-12)
    bte = np.stack([s.base_T_ee for s in samples])
    assert np.allclose(calib.robot_pose_correction.apply(bte), want.correct_robot_pose(bte),
                       atol=1e-12)
    report = json.loads((out / "report.json").read_text())
    assert report["robot_model"] == "systematic"
    printed = capsys.readouterr().out
    d = want.pose_correction.delta(bte)
    assert (f"robot pose correction (systematic model) in hand_eye.yaml: up to "
            f"{1000 * np.max(np.linalg.norm(d[:, :3], axis=1)):.2f} mm") in printed
    plain = tmp_path / "plain"
    assert main(["calibrate", "handeye", "--pairs", str(pairs), "--robot-model", "per_pose",
                 "--no-html", "-o", str(plain)]) == 0
    assert load_hand_eye(plain / "hand_eye.yaml").robot_pose_correction is None
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["calibrate", "handeye", "--pairs", str(pairs), "--robot-model", "kinematic",
              "-o", str(tmp_path / "x")])
    assert "invalid choice: 'kinematic'" in capsys.readouterr().err
