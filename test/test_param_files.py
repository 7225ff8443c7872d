"""The ROS parameter files of config/: `/**/<node>` keys, so that a namespace keeps them.

A bare ``stereo_capture:`` key only matches the node ``/stereo_capture``; started under
``/stereo`` (as ``eye-in-hand launch`` and the launch file do) the node silently ran on its
defaults. The tests load each file the way rclpy does (``--params-file``) into a node of that
name in a namespace and check every parameter of the file arrives.
"""
from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config"


def node_names() -> set[str]:
    """The package's node executables (setup.py ``NODE_SCRIPTS``)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "NODE_SCRIPTS" for t in stmt.targets):
            return {e.split("=", 1)[0].strip() for e in ast.literal_eval(stmt.value)}
    raise AssertionError("setup.py has no NODE_SCRIPTS list")


def parameter_files() -> dict[Path, dict[str, Any]]:
    """config/*.yaml files whose top-level entries hold ``ros__parameters``."""
    out = {}
    for path in sorted(CONFIG.glob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        if isinstance(data, dict) and any(
                isinstance(v, dict) and "ros__parameters" in v for v in data.values()):
            out[path] = data
    return out


def flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested ``ros__parameters`` -> dotted names, as rcl reads them."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if isinstance(value, dict):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_config_holds_the_parameter_files():
    files = {p.name for p in parameter_files()}
    assert {"eye_in_hand.yaml", "stereo_capture.yaml", "detect_triangulate.yaml"} <= files


@pytest.mark.parametrize("path", sorted(parameter_files()), ids=lambda p: p.name)
def test_parameter_file_keys_are_namespace_wildcards(path):
    """Every entry is ``/**/<node>`` for one of the package's nodes."""
    nodes = node_names()
    for key, body in parameter_files()[path].items():
        assert isinstance(body, dict) and "ros__parameters" in body, f"{path.name}: {key}"
        assert str(key).startswith("/**/") and str(key)[4:] in nodes, (
            f"{path.name}: key {key!r} must be '/**/<node>' with <node> in {sorted(nodes)} "
            f"(a bare node name is ignored when the node runs in a namespace)")


def _overrides_in(ros_context, path: Path, node: str, namespace: str) -> dict[str, Any]:
    """The parameter values rclpy gives node ``namespace/node`` from ``--params-file path``."""
    from rclpy.node import Node

    n = Node(node, namespace=namespace, context=ros_context,
             cli_args=["--ros-args", "--params-file", str(path)],
             automatically_declare_parameters_from_overrides=True,
             start_parameter_services=False, enable_rosout=False)
    try:
        return {name: p.value for name, p in n.get_parameters_by_prefix("").items()
                if name != "use_sim_time"}
    finally:
        n.destroy_node()


def _same(a: Any, b: Any) -> bool:
    if isinstance(b, (list, tuple)):
        return list(a) == list(b)
    return a == b


@pytest.mark.parametrize("namespace", ["/stereo", "/robot1/stereo"])
@pytest.mark.parametrize("path", sorted(parameter_files()), ids=lambda p: p.name)
def test_a_namespaced_node_gets_every_parameter_of_the_file(ros_context, path, namespace):
    for key, body in parameter_files()[path].items():
        node = str(key).rsplit("/", 1)[-1]
        expected = flatten(body["ros__parameters"])
        got = _overrides_in(ros_context, path, node, namespace)
        missing = sorted(set(expected) - set(got))
        assert not missing, f"{path.name}: {namespace}/{node} did not get {missing}"
        wrong = {k: (got[k], v) for k, v in expected.items() if not _same(got[k], v)}
        assert not wrong, f"{path.name}: {namespace}/{node}: (got, file) {wrong}"


def test_stereo_capture_under_stereo_runs_at_the_files_rate(ros_context, tmp_path):
    """The reported case: stereo_capture started in /stereo with its parameter file."""
    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode

    text = (CONFIG / "stereo_capture.yaml").read_text()
    assert "\n    rate_hz: 30.0\n" in text
    params = tmp_path / "stereo_capture.yaml"
    params.write_text(text.replace("\n    rate_hz: 30.0\n", "\n    rate_hz: 12.5\n"))
    node = StereoCaptureNode(context=ros_context, namespace="/stereo",
                             cli_args=["--ros-args", "--params-file", str(params)])
    try:
        assert node.get_fully_qualified_name() == "/stereo/stereo_capture"
        assert node.cfg["rate_hz"] == 12.5
        assert node.timer.timer_period_ns == pytest.approx(1e9 / 12.5)
    finally:
        node.destroy_node()
