"""hand_eye.yaml: round trip and clear errors naming the file and the problem."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from eye_in_hand.core.transforms import from_rotvec
from eye_in_hand.errors import ConfigError
from eye_in_hand.io.config import (
    COVARIANCE_ORDER,
    HandEyeCalibration,
    load_hand_eye,
    save_hand_eye,
)


def _calib(cov: bool = True) -> HandEyeCalibration:
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6)) * 1e-4
    return HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=from_rotvec([0.1, -0.2, 0.3], [0.04, -0.06, 0.09]), method="refined",
        covariance=A @ A.T if cov else None, sample_count=15,
        residuals={"reproj_px_rms": 0.41, "loo_max_mm": None})


def test_round_trip(tmp_path: Path) -> None:
    c = _calib()
    path = save_hand_eye(tmp_path / "sub" / "hand_eye.yaml", c)
    back = load_hand_eye(path)
    np.testing.assert_allclose(back.transform, c.transform, atol=1e-12)
    np.testing.assert_allclose(back.covariance, c.covariance, rtol=1e-12)
    assert (back.setup, back.parent_frame, back.child_frame, back.method, back.sample_count) == \
        ("eye_in_hand", "tool0", "camera_left_optical_frame", "refined", 15)
    assert back.residuals == {"reproj_px_rms": 0.41, "loo_max_mm": None}
    data = yaml.safe_load(path.read_text())
    # translation and quat_xyzw at the top level, quaternion in ROS order with w >= 0.
    np.testing.assert_allclose(data["translation"], [0.04, -0.06, 0.09])
    assert len(data["quat_xyzw"]) == 4 and data["quat_xyzw"][3] >= 0
    assert data["covariance_order"] == list(COVARIANCE_ORDER)
    np.testing.assert_allclose(back.quat_xyzw, data["quat_xyzw"])
    nocov = load_hand_eye(save_hand_eye(tmp_path / "n.yaml", _calib(cov=False)))
    assert nocov.covariance is None


def _write(tmp_path: Path, **changes) -> Path:
    data = _calib().to_dict()
    for k, v in changes.items():
        if v is KeyError:
            data.pop(k)
        else:
            data[k] = v
    p = tmp_path / "hand_eye.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.mark.parametrize("changes, message", [
    ({"translation": KeyError}, "missing key 'translation'"),
    ({"quat_xyzw": KeyError}, "missing key 'quat_xyzw'"),
    ({"translation": [0.1, 0.2]}, "'translation' must be a list of 3 numbers"),
    ({"quat_xyzw": [0.0, 0.0, 0.0, 2.0]}, "not a unit quaternion"),
    ({"translation": [0.1, float("nan"), 0.0]}, "NaN"),
    ({"setup": "eye_on_head"}, "'setup' must be one of"),
    ({"parent_frame": ""}, "'parent_frame'"),
    ({"covariance": [[1.0, 2.0], [2.0, 1.0]]}, "'covariance' must be 6x6"),
    ({"covariance": (-np.eye(6)).tolist()}, "not positive semi-definite"),
    ({"covariance": (np.eye(6) + np.triu(np.ones((6, 6)), 1)).tolist()}, "not symmetric"),
    ({"covariance_order": ["rx", "ry", "rz", "x", "y", "z"]}, "covariance_order"),
    ({"sample_count": -3}, "sample_count"),
    ({"robot_pose_noise": {"translation_sigma_m": 1e-4}}, "'robot_pose_noise' must be a mapping"),
    ({"robot_pose_noise": {"translation_sigma_m": -1.0, "rotation_sigma_rad": 1e-4}},
     "robot_pose_noise.translation_sigma_m"),
])
def test_invalid_files_name_file_and_problem(tmp_path: Path, changes, message) -> None:
    p = _write(tmp_path, **changes)
    with pytest.raises(ConfigError) as info:
        load_hand_eye(p)
    assert str(p) in str(info.value) and message in str(info.value)


def test_robot_pose_noise_round_trip_and_old_files(tmp_path: Path) -> None:
    import dataclasses

    noise = {"translation_sigma_m": 2e-4, "rotation_sigma_rad": 3.5e-4}
    c = dataclasses.replace(_calib(), robot_pose_noise=noise)
    path = save_hand_eye(tmp_path / "hand_eye.yaml", c)
    assert yaml.safe_load(path.read_text())["robot_pose_noise"] == noise
    assert load_hand_eye(path).robot_pose_noise == noise
    # Files written before the key existed load without it.
    old = save_hand_eye(tmp_path / "old.yaml", _calib())
    assert "robot_pose_noise" not in yaml.safe_load(old.read_text())
    assert load_hand_eye(old).robot_pose_noise is None


def test_missing_file_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_hand_eye(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("translation: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_hand_eye(bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_hand_eye(top)


def test_save_refuses_invalid_covariance(tmp_path: Path) -> None:
    c = _calib()
    bad = HandEyeCalibration(c.setup, c.parent_frame, c.child_frame, c.transform, c.method,
                             covariance=np.full((6, 6), np.nan), sample_count=3)
    with pytest.raises(ConfigError, match="NaN"):
        save_hand_eye(tmp_path / "x.yaml", bad)
    assert not (tmp_path / "x.yaml").exists()


def test_robot_pose_noise_of_zero_is_valid(tmp_path: Path) -> None:
    """``robot_pose_noise`` values are finite numbers >= 0: an exact robot (0) loads."""
    import dataclasses

    noise = {"translation_sigma_m": 0.0, "rotation_sigma_rad": 0.0}
    path = save_hand_eye(tmp_path / "hand_eye.yaml",
                         dataclasses.replace(_calib(), robot_pose_noise=noise))
    assert load_hand_eye(path).robot_pose_noise == noise


def test_flat_covariance_and_zero_samples_load(tmp_path: Path) -> None:
    """A covariance may be written as 36 numbers (row-major, as in ROS messages); a
    sample_count of 0 (unknown) is a non-negative integer."""
    c = _calib()
    assert c.covariance is not None
    p = _write(tmp_path, covariance=c.covariance.reshape(36).tolist(), sample_count=0)
    back = load_hand_eye(p)
    assert back.covariance is not None and np.allclose(back.covariance, c.covariance)
    assert back.sample_count == 0
