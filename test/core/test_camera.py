"""CameraModel / StereoRig: projection round trips, rectification, ROS YAML round trips."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.errors import ConfigError, InputError

K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])


def make_rig(model: str = "plumb_bob") -> StereoRig:
    if model == "plumb_bob":
        dl, dr = [-0.3, 0.15, 0.001, -0.0005, -0.05], [-0.28, 0.1, 0.0, 0.0, 0.0]
    else:
        dl = [-0.3, 0.15, 0.001, -0.0005, -0.05, 0.01, 0.0, 0.002]
        dr = [-0.28, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    left = CameraModel(K, dl, 1280, 720, distortion_model=model, name="left")
    right = CameraModel(K + np.diag([3.0, 2.0, 0.0]), dr, 1280, 720, distortion_model=model,
                        name="right")
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    return StereoRig(left, right, R, [-0.06, 0.001, 0.0005])


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_undistort_inverts_project_over_whole_image(model):
    cam = make_rig(model).left
    grid = np.stack(np.meshgrid(np.linspace(0, 1279, 40), np.linspace(0, 719, 25)), -1)
    px = grid.reshape(-1, 2)
    norm = cam.undistort_points(px)
    back = cam.project(np.c_[norm, np.ones(len(norm))])
    assert np.max(np.abs(back - px)) < 1e-6


def test_project_marks_points_behind_camera_nan():
    cam = make_rig().left
    out = cam.project([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    assert np.allclose(out[0], [640.0, 360.0])
    assert np.all(np.isnan(out[1]))


def test_rectified_rows_agree_and_ros_files_rebuild_extrinsic(tmp_path):
    rig = make_rig().rectified(alpha=0.0)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.2, -0.1, 0.4], [0.2, 0.1, 0.8], (40, 3))
    a = rig.left.rectify_points(rig.left.project(pts))
    b = rig.right.rectify_points(rig.right.project(pts @ rig.R.T + rig.T))
    assert np.max(np.abs(a[:, 1] - b[:, 1])) < 1e-6
    # The right P carries -fx * B, as stereo_image_proc reads it.
    assert rig.P2[0, 3] == pytest.approx(-rig.P2[0, 0] * rig.baseline, rel=1e-3)

    rig.save(tmp_path)
    (tmp_path / "stereo.yaml").unlink()  # ROS's camera_calibration writes only the two files
    back = StereoRig.load(tmp_path)
    assert np.allclose(back.R, rig.R, atol=1e-12)
    assert np.allclose(back.T, rig.T, atol=1e-12)
    assert np.allclose(back.Q, rig.Q, atol=1e-9)


def test_stereo_yaml_round_trip(tmp_path):
    rig = make_rig("rational_polynomial")
    rig.save(tmp_path)
    back = StereoRig.load(tmp_path)
    assert back.left.distortion_model == "rational_polynomial"
    assert np.allclose(back.left.dist, rig.left.dist)
    assert np.allclose(back.T, rig.T) and back.is_rectified


def test_loads_ros_camera_calibration_yaml(tmp_path):
    text = """
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [532.8, 0, 342.5, 0, 532.9, 233.9, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28, 0.029, 0.0012, -0.00014, 0.15]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [532.8, 0, 342.5, 0, 0, 532.9, 233.9, 0, 0, 0, 1, 0]
"""
    path = tmp_path / "cam.yaml"
    path.write_text(text)
    cam = CameraModel.load_yaml(path)
    assert cam.name == "narrow_stereo" and cam.size == (640, 480)
    assert cam.fx == pytest.approx(532.8)
    cam.save_yaml(tmp_path / "out.yaml")
    assert yaml.safe_load((tmp_path / "out.yaml").read_text()) == yaml.safe_load(
        yaml.safe_dump(cam.to_dict()))


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("camera_matrix"), "missing key"),
    (lambda d: d["camera_matrix"].update(data=[1, 2, 3]), "declares 3x3 but has 3"),
    (lambda d: d["distortion_coefficients"].update(cols=3, data=[0, 0, 0]), "has 3 values"),
    (lambda d: d.update(distortion_model="fisheye9"), "not supported"),
    (lambda d: d["camera_matrix"].update(data=[float("nan")] * 9), "NaN"),
])
def test_malformed_yaml_names_file_and_problem(tmp_path, mutate, message):
    data = make_rig().left.to_dict()
    mutate(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message) as info:
        CameraModel.load_yaml(path)
    assert str(path) in str(info.value)


def test_missing_file_and_mono_pair_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        CameraModel.load_yaml(tmp_path / "nope.yaml")
    cam = make_rig().left
    cam.save_yaml(tmp_path / "left.yaml")
    cam.save_yaml(tmp_path / "right.yaml")
    with pytest.raises(ConfigError, match="no baseline"):
        StereoRig.load(tmp_path)


def test_invalid_model_values_raise_input_error():
    with pytest.raises(InputError, match="focal"):
        CameraModel(np.diag([-1.0, 1.0, 1.0]), np.zeros(5), 10, 10)
    with pytest.raises(InputError, match="size"):
        CameraModel(K, np.zeros(5), 0, 10)
