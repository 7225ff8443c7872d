"""Tests of `eye-in-hand locate` on rendered stereo pairs and ROS calibration files."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.sim.sphere import render_sphere

K = np.array([[600.0, 0.0, 400.0], [0.0, 600.0, 300.0], [0.0, 0.0, 1.0]])
X_TRUE = np.array([0.03, 0.02, 0.45])


def make_rig():
    left = CameraModel(K, [-0.1, 0.02, 0.0, 0.0, 0.0], 800, 600, name="left")
    right = CameraModel(K, [-0.1, 0.02, 0.0, 0.0, 0.0], 800, 600, name="right")
    R = cv2.Rodrigues(np.array([0.0, -0.01, 0.0]))[0]
    return StereoRig(left, right, R, [-0.07, 0.0, 0.0]).rectified()


@pytest.fixture
def scene(tmp_path):
    rig = make_rig()
    rig.save(tmp_path / "calib")
    (tmp_path / "calib" / "stereo.yaml").unlink()  # as ROS's camera_calibration writes it
    paths = []
    for side, cam, T in (("left", rig.left, np.eye(4)), ("right", rig.right, rig.right_T_left)):
        img = np.full((600, 800, 3), (90, 110, 100), np.uint8)
        render_sphere(img, cam, T[:3, :3] @ X_TRUE + T[:3, 3], 0.025, (30, 30, 200))
        path = tmp_path / f"{side}.png"
        cv2.imwrite(str(path), img)
        paths.append(str(path))
    return tmp_path, paths


def test_locate_json_has_exactly_the_documented_keys(scene, capsys):
    root, (left, right) = scene
    code = main(["locate", "--left", left, "--right", right, "--calibration",
                 str(root / "calib"), "--radius", "0.025", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    objs = json.loads(out)
    assert isinstance(objs, list) and len(objs) == 1
    obj = objs[0]
    assert list(obj) == ["name", "id", "point_m", "covariance", "residual_px", "left_px",
                         "right_px"]
    assert obj["name"] == obj["id"] == "red"
    assert np.linalg.norm(np.array(obj["point_m"]) - X_TRUE) < 5e-4
    assert np.array(obj["covariance"]).shape == (3, 3) and obj["residual_px"] < 0.3
    rig = make_rig()
    assert np.allclose(obj["left_px"], rig.left.project(X_TRUE[None])[0], atol=0.1)


def test_locate_text_output_with_params_file_and_method(scene, capsys, tmp_path):
    root, (left, right) = scene
    params = tmp_path / "p.yaml"
    params.write_text("detect_triangulate:\n  ros__parameters:\n    method: disparity\n")
    code = main(["locate", "--left", left, "--right", right, "--calibration",
                 str(root / "calib"), "--params", str(params), "--method", "optimal"])
    out = capsys.readouterr().out
    assert code == 0 and "(optimal)" in out and "point_m" in out


def test_no_target_exits_2_with_a_reason(scene, capsys, tmp_path):
    root, (left, right) = scene
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((600, 800, 3), 100, np.uint8))
    code = main(["locate", "--left", left, "--right", str(blank), "--calibration",
                 str(root / "calib"), "--json"])
    cap = capsys.readouterr()
    assert code == 2 and cap.out == "" and "not detected right" in cap.err


def test_errors_are_one_line(scene, capsys, tmp_path):
    root, (left, right) = scene
    assert main(["locate", "--left", str(tmp_path / "none.png"), "--right", right,
                 "--calibration", str(root / "calib")]) == 1
    assert "none.png: cannot read" in capsys.readouterr().err
    assert main(["locate", "--left", left, "--right", right, "--calibration",
                 str(tmp_path / "nowhere")]) == 1
    assert "calibration directory not found" in capsys.readouterr().err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 100, 3), np.uint8))
    assert main(["locate", "--left", str(small), "--right", right, "--calibration",
                 str(root / "calib")]) == 1
    assert "calibration is 800x600" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:   # refused by the option's range, at once
        main(["locate", "--left", left, "--right", right, "--calibration",
              str(root / "calib"), "--radius", "-1"])
    assert exit_info.value.code == 2
    assert "argument --radius: must be within (0, 10] m, got -1" in capsys.readouterr().err


def test_locate_json_lists_every_target_with_its_id(tmp_path, capsys):
    """A green sphere and a set of two red ones (count: 2): one list element per blob."""
    rig = make_rig()
    rig.save(tmp_path / "calib")
    spheres = [(np.array([-0.06, 0.0, 0.45]), (30, 30, 200)),
               (np.array([0.07, 0.02, 0.5]), (30, 30, 200)),
               (np.array([0.0, -0.05, 0.4]), (40, 200, 40))]
    paths = []
    for side, cam, T in (("left", rig.left, np.eye(4)), ("right", rig.right, rig.right_T_left)):
        img = np.full((600, 800, 3), (90, 110, 100), np.uint8)
        for X, col in spheres:
            render_sphere(img, cam, T[:3, :3] @ X + T[:3, 3], 0.02, col)
        paths.append(str(tmp_path / f"{side}.png"))
        cv2.imwrite(paths[-1], img)
    params = tmp_path / "p.yaml"
    params.write_text(
        "/**/detect_triangulate:\n  ros__parameters:\n    target_names: [green, red]\n"
        "    targets:\n      green: {lower: [45, 120, 70], upper: [75, 255, 255]}\n"
        "      red: {count: 2}\n")
    argv = ["locate", "--left", paths[0], "--right", paths[1], "--calibration",
            str(tmp_path / "calib"), "--params", str(params)]
    assert main(argv + ["--json"]) == 0
    objs = json.loads(capsys.readouterr().out)
    assert [(o["name"], o["id"]) for o in objs] == [("green", "green"), ("red", "red_0"),
                                                    ("red", "red_1")]
    for o in objs:
        assert min(np.linalg.norm(np.array(o["point_m"]) - X) for X, _ in spheres) < 5e-4
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "target 'green'" in out and "target 'red_0' (target 'red')" in out \
        and "'red_1'" in out and out.count("point_m") == 3
