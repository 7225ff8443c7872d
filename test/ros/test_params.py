"""Tests of eye_in_hand.ros.params on real rclpy nodes."""
from __future__ import annotations

from dataclasses import dataclass

import pytest

from eye_in_hand.errors import ConfigError
from eye_in_hand.ros.params import Param, declare_params, load_config, param, params_markdown


def _positive_odd(v: int) -> str | None:
    return None if v % 2 == 1 else "must be odd"


@dataclass(frozen=True)
class DemoConfig:
    rate_hz: float = param(30.0, "processing rate limit", range=(0.1, 1000.0))
    queue: int = param(4, "queue depth", range=(1, 64))
    method: str = param("hsv", "threshold colour space", choices=("hsv", "hsi"))
    frame_id: str = param("camera_left_optical_frame", "frame of the published point")
    hsv_low: tuple[int, ...] = param((0, 120, 70), "lower HSV bound", range=(0, 255),
                                     name="hsv.low")
    gains: tuple[float, ...] = param((1.0, 2.5), "per-axis gains")
    topics: tuple[str, ...] = param((), "extra topics", type="str[]")
    debug: bool = param(False, "publish debug images", read_only=False)
    kernel: int = param(5, "morphology kernel size", range=(1, 31), validate=_positive_odd)

    def __post_init__(self) -> None:
        if self.method == "hsi" and self.rate_hz > 100.0:
            raise ValueError("method 'hsi' supports rate_hz <= 100")


def make_node(ros_context, namespace, overrides=None):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    params = [Parameter(k, value=v) for k, v in (overrides or {}).items()]
    return Node("params_test", context=ros_context, namespace=namespace,
                parameter_overrides=params)


def test_defaults_and_descriptors(ros_context, namespace):
    node = make_node(ros_context, namespace)
    try:
        cfg = load_config(node, DemoConfig)
        assert cfg == DemoConfig()
        assert cfg.hsv_low == (0, 120, 70) and cfg.topics == ()
        with pytest.raises(AttributeError):
            cfg.rate_hz = 1.0  # frozen
        desc = node.describe_parameter("rate_hz")
        assert desc.description == "processing rate limit" and desc.read_only
        fr = desc.floating_point_range[0]
        assert (fr.from_value, fr.to_value) == (0.1, 1000.0)
        ir = node.describe_parameter("queue").integer_range[0]
        assert (ir.from_value, ir.to_value, ir.step) == (1, 64, 1)
        assert "one of hsv, hsi" in node.describe_parameter("method").additional_constraints
        assert "each element in [0, 255]" in node.describe_parameter(
            "hsv.low").additional_constraints
        assert not node.describe_parameter("debug").read_only
        # Read-only parameters cannot be changed at run time; rclpy refuses.
        from rclpy.parameter import Parameter

        result = node.set_parameters([Parameter("queue", value=8)])[0]
        assert not result.successful
        assert node.set_parameters([Parameter("debug", value=True)])[0].successful
    finally:
        node.destroy_node()


def test_overrides_are_read(ros_context, namespace):
    node = make_node(ros_context, namespace, {
        "rate_hz": 12.5, "method": "hsi", "hsv.low": [1, 2, 3], "gains": [0.5, 0.25, 4.0],
        "topics": ["a", "b"], "kernel": 7})
    try:
        cfg = load_config(node, DemoConfig)
        assert (cfg.rate_hz, cfg.method, cfg.hsv_low) == (12.5, "hsi", (1, 2, 3))
        assert cfg.gains == (0.5, 0.25, 4.0) and cfg.topics == ("a", "b") and cfg.kernel == 7
    finally:
        node.destroy_node()


@pytest.mark.parametrize("overrides,match", [
    ({"rate_hz": 0.0}, r"^parameter 'rate_hz': 0\.0 is outside the range \[0\.1, 1000\.0\]"),
    ({"queue": 65}, r"^parameter 'queue': 65 is outside the range \[1, 64\]"),
    ({"rate_hz": 2}, r"^parameter 'rate_hz': expected type float, got integer 2 \(write floats"),
    ({"queue": "four"}, r"^parameter 'queue': expected type int, got string four"),
    ({"method": "rgb"}, r"^parameter 'method': 'rgb' is not one of 'hsv', 'hsi'"),
    ({"hsv.low": [0, 256, 0]}, r"^parameter 'hsv\.low': 256 is outside the range \[0, 255\]"),
    ({"kernel": 4}, r"^parameter 'kernel': must be odd: morphology kernel size"),
    ({"method": "hsi", "rate_hz": 200.0}, r"^DemoConfig: method 'hsi' supports rate_hz <= 100"),
])
def test_bad_values_raise_config_error_naming_the_parameter(ros_context, namespace, overrides,
                                                            match):
    node = make_node(ros_context, namespace, overrides)
    try:
        with pytest.raises(ConfigError, match=match):
            load_config(node, DemoConfig)
    finally:
        node.destroy_node()


def test_required_parameter_and_prefix(ros_context, namespace):
    params = [Param("calibration_file", "", "stereo calibration YAML", required=True),
              Param("gain", 1.0, "gain", range=(0.0, 2.0))]
    node = make_node(ros_context, namespace)
    try:
        with pytest.raises(ConfigError, match="^parameter 'left.calibration_file' is required"):
            declare_params(node, params, prefix="left.")
    finally:
        node.destroy_node()
    node = make_node(ros_context, namespace, {"right.calibration_file": "/x/right.yaml"})
    try:
        values = declare_params(node, params, prefix="right.")
        assert values == {"calibration_file": "/x/right.yaml", "gain": 1.0}
        assert node.has_parameter("right.gain")
    finally:
        node.destroy_node()
    node = make_node(ros_context, namespace, {"calibration_file": ""})
    try:
        with pytest.raises(ConfigError, match="required but is empty"):
            declare_params(node, params[:1])
    finally:
        node.destroy_node()


def test_declaring_twice_is_a_config_error(ros_context, namespace):
    node = make_node(ros_context, namespace)
    try:
        declare_params(node, [Param("x", 1, "x")])
        with pytest.raises(ConfigError, match="declared twice"):
            declare_params(node, [Param("x", 1, "x")])
    finally:
        node.destroy_node()


@pytest.mark.parametrize("kwargs,match", [
    ({"name": "bad name", "default": 1, "description": "d"}, "invalid parameter name"),
    ({"name": "x", "default": 1, "description": " "}, "description is required"),
    ({"name": "x", "default": (), "description": "d"}, "cannot infer a type"),
    ({"name": "x", "default": 1.0, "description": "d", "range": (2.0, 3.0)}, "outside"),
    ({"name": "x", "default": "a", "description": "d", "range": (0, 1)}, "range needs"),
    ({"name": "x", "default": 1, "description": "d", "range": (0.5, 2)}, "int bounds"),
    ({"name": "x", "default": "a", "description": "d", "choices": ("b",)}, "not one of"),
    ({"name": "x", "default": 1, "description": "d", "type": "float[]"}, "must be a tuple"),
    ({"name": "x", "default": (1, "a"), "description": "d"}, "mixes types"),
    ({"name": "x", "default": None, "description": "d"}, "cannot infer"),
])
def test_param_definition_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Param(**kwargs)


def test_param_type_inference_and_markdown():
    assert Param("a", True, "d").type == "bool"
    assert Param("a", 1, "d").type == "int"
    assert Param("a", 1.0, "d").type == "float"
    assert Param("a", (1, 2.5), "d").type == "float[]"
    assert Param("a", (1, 2.5), "d").default == (1.0, 2.5)
    assert Param("a", ["x"], "d").default == ("x",)
    table = params_markdown(DemoConfig)
    assert "| `hsv.low` | int[] | `(0, 120, 70)` | [0, 255] | lower HSV bound |" in table
    assert "| `debug` | bool | `False` | dynamic | publish debug images |" in table
    assert len(table.splitlines()) == 2 + 9


def test_dynamic_parameters_are_checked_at_run_time(ros_context, namespace):
    from rclpy.parameter import Parameter

    params = [Param("mode", "fast", "mode", choices=("fast", "exact"), read_only=False),
              Param("gains", (1.0, 2.0), "gains", range=(0.0, 10.0), read_only=False),
              Param("fixed", 3, "fixed", choices=(3, 5))]
    node = make_node(ros_context, namespace)
    try:
        declare_params(node, params)
        ok = node.set_parameters([Parameter("mode", value="exact")])[0]
        assert ok.successful and node.get_parameter("mode").value == "exact"
        bad = node.set_parameters([Parameter("mode", value="slow")])[0]
        assert not bad.successful and "'slow' is not one of 'fast', 'exact'" in bad.reason
        assert node.get_parameter("mode").value == "exact"
        bad = node.set_parameters([Parameter("gains", value=[1.0, 11.0])])[0]
        assert not bad.successful and "11.0 is outside the range [0.0, 10.0]" in bad.reason
        assert not node.set_parameters([Parameter("mode", value=4)])[0].successful  # type
        assert not node.set_parameters([Parameter("fixed", value=5)])[0].successful  # read-only
    finally:
        node.destroy_node()
