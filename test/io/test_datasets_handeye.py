"""Calibration datasets and pose-pair files: round trip and errors naming sample and field."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import ConfigError
from eye_in_hand.io.datasets import load_dataset, write_dataset
from eye_in_hand.io.pose_pairs import load_pose_pairs, save_pose_pairs


def _camera(name: str = "camera") -> CameraModel:
    K = np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1]])
    return CameraModel(K=K, dist=np.array([-0.1, 0.01, 0, 0, 0]), width=160, height=120,
                       name=name)


def _poses(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [from_rotvec(rng.normal(scale=0.5, size=3), rng.normal(size=3)) for _ in range(n)]


def test_mono_round_trip(tmp_path: Path) -> None:
    poses = _poses(3)
    imgs = [{"image": np.full((120, 160), 10 * i, np.uint8)} for i in range(3)]
    truth = {"ee_T_cam": poses[0]}
    path = write_dataset(tmp_path / "ds", setup="eye_to_hand", board="chessboard:9x6:0.025",
                         images=imgs, base_T_ee=poses, camera=_camera(), ground_truth=truth)
    ds = load_dataset(path.parent)
    assert ds.setup == "eye_to_hand" and ds.board == "chessboard:9x6:0.025"
    assert not ds.is_stereo and ds.camera is not None and ds.camera_names == ("image",)
    assert [s.name for s in ds.samples] == ["0000", "0001", "0002"]
    for s, T in zip(ds.samples, poses, strict=True):
        np.testing.assert_allclose(s.base_T_ee, T, atol=1e-12)
        assert s.images["image"].is_file()
    np.testing.assert_allclose(ds.ground_truth["ee_T_cam"], poses[0], atol=1e-12)
    np.testing.assert_allclose(ds.camera.K, _camera().K)


def test_stereo_round_trip(tmp_path: Path) -> None:
    rig = StereoRig(left=_camera("left"), right=_camera("right"),
                    R=from_rotvec([0, 0.02, 0])[:3, :3], T=np.array([-0.06, 0.0, 0.001]))
    poses = _poses(2)
    imgs = [{"left": np.zeros((120, 160), np.uint8), "right": np.zeros((120, 160), np.uint8)}
            for _ in poses]
    path = write_dataset(tmp_path, setup="eye_in_hand", board="chessboard:9x6:0.025",
                         images=imgs, base_T_ee=poses, rig=rig, names=["a", "b"])
    ds = load_dataset(path)
    assert ds.is_stereo and ds.rig is not None and ds.camera_names == ("left", "right")
    np.testing.assert_allclose(ds.rig.R, rig.R, atol=1e-9)
    np.testing.assert_allclose(ds.rig.T, rig.T, atol=1e-9)
    assert [s.name for s in ds.samples] == ["a", "b"]
    # Without stereo.yaml the extrinsic is rebuilt from the ROS projection matrices.
    data = yaml.safe_load(path.read_text())
    del data["stereo"]
    path.write_text(yaml.safe_dump(data))
    ds2 = load_dataset(path)
    np.testing.assert_allclose(ds2.rig.right_T_left, rig.right_T_left, atol=1e-6)


def _mono(tmp_path: Path) -> Path:
    poses = _poses(2)
    imgs = [{"image": np.zeros((120, 160), np.uint8)} for _ in poses]
    return write_dataset(tmp_path, setup="eye_in_hand", board="chessboard:9x6:0.025",
                         images=imgs, base_T_ee=poses, camera=_camera())


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["samples"][1].pop("base_T_ee"), r"samples\[1\]: missing 'base_T_ee'"),
    (lambda d: d["samples"][1]["base_T_ee"].update(quat_xyzw=[0, 0, 0, 3]),
     r"samples\[1\].base_T_ee.quat_xyzw: not a unit quaternion"),
    (lambda d: d["samples"][0]["base_T_ee"].update(translation=[1, 2]),
     r"samples\[0\].base_T_ee.translation: expected a list of 3"),
    (lambda d: d["samples"][0]["base_T_ee"].update(translation=[1, float("nan"), 2]),
     r"samples\[0\].base_T_ee: contains NaN"),
    (lambda d: d["samples"][1].update(image="images/missing.png"),
     r"samples\[1\].image: file not found"),
    (lambda d: d["samples"][0].update(left="images/0000.png"),
     r"samples\[0\]: has left but the dataset is mono"),
    (lambda d: d.update(setup="eye_on_head"), "'setup' must be one of"),
    (lambda d: d.pop("board"), "missing 'board'"),
    (lambda d: d.pop("camera"), "missing camera calibration"),
    (lambda d: d.update(samples=[]), "'samples' must be a non-empty list"),
])
def test_errors_name_sample_and_field(tmp_path: Path, edit, message) -> None:
    path = _mono(tmp_path)
    data = yaml.safe_load(path.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message):
        load_dataset(tmp_path)


def test_missing_dataset(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="dataset file not found"):
        load_dataset(tmp_path)


def test_pose_pairs_round_trip_and_errors(tmp_path: Path, data_dir: Path) -> None:
    pairs = list(zip(_poses(4, 1), _poses(4, 2), strict=True))
    p = save_pose_pairs(tmp_path / "pairs.json", pairs)
    back = load_pose_pairs(p)
    assert len(back) == 4
    for (a, b), (c, d) in zip(pairs, back, strict=True):
        np.testing.assert_allclose(a, c)
        np.testing.assert_allclose(b, d)
    real = load_pose_pairs(data_dir / "moveit_eye_to_hand" / "pose_samples.json")
    assert len(real) == 50 and real[0][0].shape == (4, 4)
    raw = [[np.asarray(a).tolist(), np.asarray(b).tolist()] for a, b in pairs]
    bad = raw[:2] + [raw[2] + [raw[2][0]]]
    (tmp_path / "three.json").write_text(json.dumps(bad))
    with pytest.raises(ConfigError, match="pair 2: expected \\[base_T_ee, cam_T_board\\], got 3"):
        load_pose_pairs(tmp_path / "three.json")
    nan = json.loads(json.dumps(raw))
    nan[1][1][0][0] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(nan))
    with pytest.raises(ConfigError, match="pair 1: cam_T_board: contains NaN"):
        load_pose_pairs(tmp_path / "nan.json")
    skew = json.loads(json.dumps(raw))
    skew[3][0][0][0] *= 1.1
    (tmp_path / "skew.json").write_text(json.dumps(skew))
    with pytest.raises(ConfigError, match="pair 3: .*not orthonormal"):
        load_pose_pairs(tmp_path / "skew.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ConfigError, match="cannot read pose pairs"):
        load_pose_pairs(tmp_path / "bad.json")
