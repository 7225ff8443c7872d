"""``launch/eye_in_hand.launch.py`` brings up the nodes as ``eye-in-hand launch`` does.

``ros2 launch`` and ``launch_ros`` have no wheels, so the launch file runs here against small
stand-ins of the few launch classes it uses, which record what it asks for.
"""
from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

import pytest

LAUNCH_FILE = Path(__file__).resolve().parents[1] / "launch" / "eye_in_hand.launch.py"


class _Config:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: dict[str, str]) -> str:
        return context[self.name]


class _Recorded:
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


def _stand_ins() -> dict[str, types.ModuleType]:
    mods = {name: types.ModuleType(name) for name in (
        "launch", "launch.actions", "launch.conditions", "launch.substitutions", "launch_ros",
        "launch_ros.actions", "ament_index_python", "ament_index_python.packages")}
    mods["launch"].LaunchDescription = _Recorded
    mods["launch.actions"].DeclareLaunchArgument = _Recorded
    mods["launch.actions"].OpaqueFunction = _Recorded
    mods["launch.conditions"].IfCondition = _Recorded
    mods["launch.substitutions"].LaunchConfiguration = _Config
    mods["launch_ros.actions"].Node = _Recorded
    mods["ament_index_python.packages"].get_package_share_directory = lambda pkg: f"/share/{pkg}"
    return mods


def _bring_up(monkeypatch: pytest.MonkeyPatch, **args: str) -> list[dict[str, Any]]:
    for blas in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(blas, raising=False)     # no BLAS thread count of the user's
    for name, mod in _stand_ins().items():
        monkeypatch.setitem(sys.modules, name, mod)
    spec = importlib.util.spec_from_file_location("eye_in_hand_launch_file", LAUNCH_FILE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    context = {a.args[0]: a.kwargs["default_value"] for a in description.args[0]
               if a.kwargs.get("default_value") is not None and a.args}
    context.update(args)
    opaque = [a for a in description.args[0] if "function" in a.kwargs]
    assert len(opaque) == 1
    return [n.kwargs for n in opaque[0].kwargs["function"](context)]


def test_localization_bring_up(monkeypatch: pytest.MonkeyPatch) -> None:
    nodes = _bring_up(monkeypatch, namespace="cell", params_file="/p.yaml")
    assert [(n["name"], n["executable"], n["namespace"]) for n in nodes] == [
        ("stereo_capture", "stereo_capture", "/cell/stereo"),
        ("detect_triangulate", "detect_triangulate", "/cell/stereo"),
        ("hand_eye", "hand_eye", "/cell")]
    remaps = {n["name"]: dict(n["remappings"]) for n in nodes}
    assert remaps["stereo_capture"] == {"ee_pose": "/cell/ee_pose",
                                        "joint_states": "/cell/joint_states",
                                        "diagnostics": "/cell/diagnostics"}
    assert remaps["detect_triangulate"] == {
        "target/point": "/cell/target/point", "target/point_cov": "/cell/target/point_cov",
        "target/debug_image": "/cell/target/debug_image",
        "targets/markers": "/cell/targets/markers", "diagnostics": "/cell/diagnostics"}
    assert remaps["hand_eye"] == {}     # already in the root namespace
    assert all(n["parameters"] == ["/p.yaml"] for n in nodes)
    assert "condition" in nodes[0] and all("condition" not in n for n in nodes[1:])
    assert all(n["respawn"] is True and n["respawn_delay"] == 2.0 for n in nodes)
    assert all(n["additional_env"]["OPENBLAS_NUM_THREADS"] == "1" for n in nodes)


def test_calibration_and_composed_bring_up(monkeypatch: pytest.MonkeyPatch) -> None:
    nodes = _bring_up(monkeypatch, mode="calibration", respawn="false")
    assert [(n["name"], n["namespace"]) for n in nodes] == [("stereo_capture", "/stereo"),
                                                           ("hand_eye", "/")]
    hand_eye = nodes[1]
    assert hand_eye["parameters"] == [
        "/share/eye_in_hand/config/hand_eye_calibration.yaml", {"mode": "calibration"}]
    assert dict(hand_eye["remappings"]) == {"left/image_raw": "/stereo/left/image_raw",
                                            "right/image_raw": "/stereo/right/image_raw",
                                            "image_raw": "/stereo/left/image_raw"}
    assert all(n["respawn"] is False for n in nodes)

    nodes = _bring_up(monkeypatch, composed="true", namespace="/cell/")
    assert [n.get("name", n["executable"]) for n in nodes] == ["stereo_capture", "localize"]
    assert nodes[1]["arguments"] == ["--namespace", "/cell"]
    assert nodes[1]["parameters"] == ["/share/eye_in_hand/config/eye_in_hand.yaml"]


def test_unknown_mode_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(RuntimeError, match="mode:=calib: must be localization or calibration"):
        _bring_up(monkeypatch, mode="calib")
