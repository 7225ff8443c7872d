"""hand_eye where tf2_msgs is missing (no compiler when the venv was made): it still localizes
from ee_pose with one warning and no TF, and ``robot_pose_source: tf`` refuses to start with a
message that says how to get tf2_msgs."""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.core.transforms import from_rotvec  # noqa: E402
from eye_in_hand.errors import ConfigError  # noqa: E402
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye  # noqa: E402


@pytest.fixture
def no_tf2_msgs(monkeypatch):
    import eye_in_hand.ros.tf as rtf

    def missing():
        raise ConfigError(rtf._MISSING)

    monkeypatch.setattr(rtf, "have_tf2_msgs", lambda: False)
    monkeypatch.setattr(rtf, "tf_message_class", missing)


def _params(tmp_path, **extra):
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration("eye_in_hand", "tool0", "camera_left_optical_frame",
                                           from_rotvec([0.1, 0.0, 0.0], [0.0, 0.0, 0.05])))
    return [Parameter(k, value=v) for k, v in {"hand_eye_file": str(path), **extra}.items()]


def test_without_tf2_msgs_the_node_runs_without_tf(tmp_path, ros_context, namespace,
                                                   no_tf2_msgs):
    from eye_in_hand.nodes.hand_eye import HandEyeNode

    node = HandEyeNode(context=ros_context, namespace=namespace,
                       parameter_overrides=_params(tmp_path))
    try:
        assert node.tf_output.pub_tf is None and node.tf_output.pub_tf_static is None
        assert node.first_target.pub_pose is not None
    finally:
        node.destroy_node()


def test_tf_source_without_tf2_msgs_is_a_clear_start_up_error(tmp_path, ros_context, namespace,
                                                              no_tf2_msgs):
    from eye_in_hand.nodes.hand_eye import HandEyeNode

    with pytest.raises(ConfigError, match=r"robot_pose_source: tf: tf2_msgs is not installed.*"
                                          r"make venv"):
        HandEyeNode(context=ros_context, namespace=namespace,
                    parameter_overrides=_params(tmp_path, robot_pose_source="tf"))
