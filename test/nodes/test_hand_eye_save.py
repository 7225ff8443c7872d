"""hand_eye/save: written whole under a temporary name; replaces only its own earlier save."""
from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402


def _node(ros_context, namespace: str, tmp_path: Path, out: Path, **extra) -> HandEyeNode:
    from eye_in_hand.core.handeye import calibrate_hand_eye
    from eye_in_hand.core.handeye.synthetic import make_problem
    from eye_in_hand.sim import World

    World.default().with_image_size(320, 180).rig.save(tmp_path / "calib")
    params = [Parameter("mode", value="calibration"),
              Parameter("calibration_dir", value=str(tmp_path / "calib")),
              Parameter("output_dir", value=str(out))]
    params += [Parameter(k, value=v) for k, v in extra.items()]
    node = HandEyeNode(context=ros_context, namespace=namespace, parameter_overrides=params)
    problem = make_problem(6, seed=1)
    session = node.calibration_mode.session
    session.add_samples(problem.samples)
    session.result = calibrate_hand_eye(session.samples, "eye_in_hand", cameras=problem.views,
                                        leave_one_out=False)
    return node


def _save(node: HandEyeNode):
    from std_srvs.srv import Trigger

    return node.calibration_mode.services._trigger_save(Trigger.Request(),
                                                       Trigger.Response())


def test_save_refuses_a_folder_it_did_not_write(ros_context, namespace, tmp_path) -> None:
    out = tmp_path / "hand_eye_calibration"
    out.mkdir()
    (out / "hand_eye.yaml").write_text("an earlier session's calibration")
    node = _node(ros_context, namespace, tmp_path, out)
    try:
        res = _save(node)
        assert not res.success
        assert "exists already" in res.message and "overwrite_output:=true" in res.message
        assert (out / "hand_eye.yaml").read_text() == "an earlier session's calibration"
    finally:
        node.destroy_node()
    node = _node(ros_context, namespace, tmp_path, out, overwrite_output=True)
    try:
        res = _save(node)
        assert res.success, res.message
        assert sorted(p.name for p in out.iterdir()) == ["hand_eye.yaml", "report.html",
                                                         "report.json"]
    finally:
        node.destroy_node()


def test_save_replaces_its_own_earlier_save_whole(ros_context, namespace, tmp_path) -> None:
    out = tmp_path / "he"
    node = _node(ros_context, namespace, tmp_path, out)
    try:
        res = _save(node)
        assert res.success, res.message
        assert res.message == (f"wrote {out / 'hand_eye.yaml'}, {out / 'report.json'}, "
                               f"{out / 'report.html'}")
        first = (out / "hand_eye.yaml").stat().st_ino
        res = _save(node)  # the operator saves again after more samples: allowed
        assert res.success, res.message
        assert (out / "hand_eye.yaml").stat().st_ino != first
        assert sorted(p.name for p in tmp_path.iterdir()) == ["calib", "he"]  # no leftovers
    finally:
        node.destroy_node()
