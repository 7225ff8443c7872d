"""The ROS parameter files of config/: `/**/<node>` keys, so that a namespace keeps them.

A bare ``stereo_capture:`` key only matches the node ``/stereo_capture``; started under
``/stereo`` (as ``eye-in-hand launch`` and the launch file do) the node silently ran on its
defaults. The tests load each file the way rclpy does (``--params-file``) into a node of that
name in a namespace and check every parameter of the file arrives.
"""
from __future__ import annotations

import ast
import os
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


# -- unknown keys: an error for every command and every node ----------------------------------

def _write(tmp_path: Path, text: str, name: str = "params.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _key_problems(path: Path) -> str:
    from eye_in_hand.errors import ConfigError
    from eye_in_hand.nodes.parameters import check_parameter_file_keys

    with pytest.raises(ConfigError) as info:
        check_parameter_file_keys(path)
    return str(info.value)


def test_every_node_has_a_parameter_list():
    """The nodes whose files are checked are the package's node executables (``localize``
    runs two of them, detect_triangulate and hand_eye, under their own names)."""
    from eye_in_hand.nodes.localize import LocalizationChain  # noqa: F401 - it exists
    from eye_in_hand.nodes.parameters import NODE_NAMES, declared_parameters

    assert set(NODE_NAMES) == node_names() - {"localize"}
    assert {"detect_triangulate", "hand_eye"} <= set(NODE_NAMES)
    for node in NODE_NAMES:
        assert declared_parameters(node, {}), node


@pytest.mark.parametrize("path", sorted(parameter_files()), ids=lambda p: p.name)
def test_the_shipped_parameter_files_have_no_unknown_key(path):
    from eye_in_hand.nodes.parameters import check_parameter_file_keys

    check_parameter_file_keys(path)


def test_a_mistyped_key_names_the_file_the_key_and_the_closest_name(tmp_path):
    """The trap: `radius_mm:` ran on the default radius, offline and live, exit 0."""
    path = _write(tmp_path, "/**/detect_triangulate:\n  ros__parameters:\n    method: optimal\n"
                            "    targets:\n      red:\n        radius_mm: 20.0\n")
    text = _key_problems(path)
    assert str(path) in text
    assert "`/**/detect_triangulate.ros__parameters.targets.red.radius_mm`" in text
    assert "did you mean `targets.red.radius_m`?" in text
    assert "method" not in text


def test_an_unknown_node_name_is_refused(tmp_path):
    """The trap: `/**/detect_triangulat:` configured no node at all."""
    path = _write(tmp_path, "/**/detect_triangulat:\n  ros__parameters:\n    method: optimal\n")
    text = _key_problems(path)
    assert "unknown node name `/**/detect_triangulat`" in text
    assert "did you mean `detect_triangulate`?" in text


@pytest.mark.parametrize("key", ["/stereo/hand_eye", "hand_eye", "/robot1/*/hand_eye"])
def test_namespaced_and_bare_node_names_are_checked(tmp_path, key):
    path = _write(tmp_path, f"{key}:\n  ros__parameters:\n    max_pose_gap: 0.1\n"
                            "    base_frame: base\n")
    text = _key_problems(path)
    assert f"`{key}.ros__parameters.max_pose_gap` (did you mean `max_pose_gap_s`?)" in text
    assert "base_frame" not in text


def test_nested_namespace_sections_are_checked(tmp_path):
    path = _write(tmp_path, "/stereo:\n  stereo_capture:\n    ros__parameters:\n"
                            "      rate_hz: 10.0\n      rate: 10.0\n")
    assert "`/stereo/stereo_capture.ros__parameters.rate`" in _key_problems(path)


def test_target_parameters_follow_target_names(tmp_path):
    """targets.<name>.* is declared only for the names in target_names."""
    from eye_in_hand.nodes.parameters import check_parameter_file_keys

    good = ("/**/detect_triangulate:\n  ros__parameters:\n    target_names: [red, blue]\n"
            "    targets:\n      blue:\n        radius_m: 0.01\n")
    check_parameter_file_keys(_write(tmp_path, good))
    bad = good.replace("[red, blue]", "[red]")
    text = _key_problems(_write(tmp_path, bad, "bad.yaml"))
    assert "`/**/detect_triangulate.ros__parameters.targets.blue.radius_m` (target 'blue' is " \
           "not in target_names [red]: add it there, or remove its section" in text
    typo = good.replace("      blue:\n        radius_m", "      blue:\n        radius")
    assert "targets.blue.radius` (did you mean `targets.blue.radius_m`?)" in _key_problems(
        _write(tmp_path, typo, "typo.yaml"))


def test_a_wildcard_section_holds_only_what_every_node_declares(tmp_path):
    from eye_in_hand.nodes.parameters import check_parameter_file_keys

    check_parameter_file_keys(_write(tmp_path, "/**:\n  ros__parameters:\n"
                                               "    use_sim_time: true\n"))
    text = _key_problems(_write(tmp_path, "/**:\n  ros__parameters:\n    method: dlt\n", "b.yaml"))
    assert "`/**.ros__parameters.method` (not a parameter of" in text


def test_a_file_without_ros_parameters_is_not_a_parameter_file():
    assert "not a ROS parameter file" in _key_problems(CONFIG / "world.yaml")


def test_a_node_refuses_an_override_it_does_not_declare(ros_context, tmp_path):
    """In-process: the check the node's main() runs once the node is built (detect_triangulate:
    built in milliseconds, where stereo_capture's default source builds a simulator)."""
    from eye_in_hand.errors import ConfigError
    from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode
    from eye_in_hand.ros.params import refuse_undeclared_overrides

    path = _write(tmp_path, "/**/detect_triangulate:\n  ros__parameters:\n"
                            "    queue_dept: 12\n")
    args = ["--ros-args", "--params-file", str(path), "-p", "queue_depth:=20"]
    node = DetectTriangulateNode(context=ros_context, namespace="/stereo", cli_args=args)
    try:
        with pytest.raises(ConfigError) as info:
            refuse_undeclared_overrides(node, args)
        text = str(info.value)
        assert text.startswith("/stereo/detect_triangulate: unknown parameter (--params-file "
                               f"{path} or -p): `queue_dept` (did you mean `queue_depth`?)")
    finally:
        node.destroy_node()
    node = DetectTriangulateNode(context=ros_context, namespace="/stereo",
                                 cli_args=["--ros-args", "-p", "queue_depth:=20"])
    try:
        refuse_undeclared_overrides(node, [])  # every override declared: no error
    finally:
        node.destroy_node()


def test_a_node_process_exits_on_an_unknown_key(ros_env, tmp_path):
    """The trap, live: the node ran on its defaults with a mistyped key and never said so."""
    import subprocess
    import sys

    path = _write(tmp_path, "/**/detect_triangulate:\n  ros__parameters:\n    targets:\n"
                            "      red:\n        radius_mm: 20.0\n")
    proc = subprocess.run(
        [sys.executable, "-m", "eye_in_hand.nodes.detect_triangulate", "--ros-args",
         "-r", "__ns:=/stereo", "--params-file", str(path)],
        env=ros_env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    assert ("detect_triangulate: error: /stereo/detect_triangulate: unknown parameter "
            f"(--params-file {path} or -p): `targets.red.radius_mm` (did you mean "
            "`targets.red.radius_m`?)") in proc.stderr


@pytest.mark.parametrize("command", [
    ["process", "BAG", "--hand-eye", "HE", "-o", "OUT", "--quiet"],
    ["locate", "--left", "L.png", "--right", "R.png", "--calibration", "CAL"],
    ["launch", "--duration", "1"],
])
def test_commands_refuse_an_unknown_key_before_any_work(tmp_path, capsys, command):
    """The trap, offline: `process --params` with `radius_mm:` located with the default radius."""
    from eye_in_hand.cli import main

    path = _write(tmp_path, "/**/detect_triangulate:\n  ros__parameters:\n    targets:\n"
                            "      red:\n        radius_mm: 20.0\n")
    argv = [str(tmp_path / a) if a.isupper() or a.endswith(".png") else a for a in command]
    assert main(argv + ["--params", str(path)]) != 0
    err = capsys.readouterr().err
    assert (f"{path}: unknown parameter `/**/detect_triangulate.ros__parameters.targets.red."
            "radius_mm` (did you mean `targets.red.radius_m`?)") in err
    assert not (tmp_path / "OUT").exists()


# -- values with units: plausible, and a hint when a length was given in millimetres ----------

def test_a_radius_in_millimetres_is_refused_with_the_value_in_metres(tmp_path):
    """A 20 mm sphere written `radius_m: 20.0` is a 20 m sphere."""
    from eye_in_hand.core.locator_params import load_locator_config
    from eye_in_hand.errors import ConfigError

    path = _write(tmp_path, "/**/detect_triangulate:\n  ros__parameters:\n    targets:\n"
                            "      red:\n        radius_m: 20.0\n")
    with pytest.raises(ConfigError) as info:
        load_locator_config(path)
    assert str(info.value) == ("parameter 'targets.red.radius_m': 20.0 is outside [0.0, 1.0] "
                               "(it is in metres: for 20 mm write 0.02)")
    # a radius of a few metres is no target either: refused, without a mm hint
    with pytest.raises(ConfigError) as info:
        load_locator_config(_write(tmp_path, path.read_text().replace("20.0", "2000.0")))
    assert "outside [0.0, 1.0]" in str(info.value) and "mm" not in str(info.value)


def test_a_node_parameter_in_millimetres_gets_the_same_hint(ros_context):
    from rclpy.parameter import Parameter

    from eye_in_hand.errors import ConfigError
    from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode

    with pytest.raises(ConfigError) as info:
        DetectTriangulateNode(context=ros_context, namespace="/units",
                              parameter_overrides=[Parameter("markers.diameter_m", value=40.0)])
    assert "parameter 'markers.diameter_m': 40.0 is outside the range [0.0001, 10.0] (it is " \
           "in metres: for 40 mm write 0.04)" in str(info.value)


def test_a_wildcard_section_is_checked_against_the_nodes_a_command_runs(tmp_path, capsys):
    """`locate` runs only detect_triangulate's code: `/**: {method: ...}` is fine there, and
    refused where other nodes would get it (launch)."""
    from eye_in_hand.nodes.parameters import check_parameter_file_keys

    path = _write(tmp_path, "/**:\n  ros__parameters:\n    method: optimal\n")
    check_parameter_file_keys(path, used=["detect_triangulate"])
    text = _key_problems(path)
    assert "`/**.ros__parameters.method` (not a parameter of stereo_capture)" in text
    bad = _write(tmp_path, "/**:\n  ros__parameters:\n    methd: optimal\n", "bad.yaml")
    from eye_in_hand.errors import ConfigError

    with pytest.raises(ConfigError, match="did you mean `method`"):
        check_parameter_file_keys(bad, used=["detect_triangulate"])


def test_process_defaults_are_the_live_nodes_defaults():
    """Without a --params file, process runs on the hand_eye and detect_triangulate nodes'
    defaults: the pose rules, the robot sigmas and the stereo pairing are written once."""
    import dataclasses

    from eye_in_hand.nodes.detect_triangulate_params import NODE_PARAMETERS
    from eye_in_hand.nodes.hand_eye_params import HandEyeNodeConfig
    from eye_in_hand.offline import ProcessOptions

    opts = ProcessOptions()
    hand_eye = {f.name: f.default for f in dataclasses.fields(HandEyeNodeConfig)}
    for key in ("max_pose_gap_s", "max_pose_age_s", "pose_jump_back_s", "robot_sigma_pos_m",
                "robot_sigma_rot_rad"):
        assert hand_eye[key] == getattr(opts, key), key
    detect = {p.name: p.default for p in NODE_PARAMETERS}
    assert detect["sync.slop_s"] == opts.sync_slop_s
    assert detect["sync.queue_size"] == opts.sync_queue_size


def test_checking_a_files_keys_loads_no_rclpy():
    """`process` and `locate` check their parameter file's keys without rclpy: its C library
    starts tracing threads, after which `process` could not fork its worker processes
    (eye_in_hand.workers.fork_is_safe), and its import costs start-up."""
    import subprocess
    import sys

    code = ("import os, sys\n"
            "from eye_in_hand.nodes.parameters import check_parameter_file_keys\n"
            f"check_parameter_file_keys({str(CONFIG / 'detect_triangulate_multi.yaml')!r}, "
            "used=['detect_triangulate', 'hand_eye'])\n"
            f"check_parameter_file_keys({str(CONFIG / 'eye_in_hand.yaml')!r}, "
            "used=['detect_triangulate', 'hand_eye'])\n"
            "print(sorted(m for m in sys.modules if m.startswith('rclpy')),"
            " len(os.listdir('/proc/self/task')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}).stdout
    assert out.split() == ["[]", "1"]
