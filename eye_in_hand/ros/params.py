"""Parameter helpers: declare every parameter with a descriptor, validate once, freeze.

A node describes its parameters as a frozen dataclass whose fields are made with :func:`param`,
and loads it once in ``__init__``::

    @dataclass(frozen=True)
    class DetectorConfig:
        rate_hz: float = param(30.0, "processing rate limit", range=(0.1, 1000.0))
        method: str = param("hsv", "threshold colour space", choices=("hsv", "hsi"))
        frame_id: str = param("camera_left_optical_frame", "frame of the published point")
        hsv_low: tuple[int, ...] = param((0, 120, 70), "lower HSV bound", range=(0, 255))

    class Detector(Node):
        def __init__(self, **kwargs):
            super().__init__("detect_triangulate", **kwargs)
            self.config = load_config(self, DetectorConfig)   # raises ConfigError on bad input

Each field becomes a ROS parameter (the field name, or ``name=`` for dotted names) declared with
a ``ParameterDescriptor`` carrying its description, an ``IntegerRange``/``FloatingPointRange``,
the allowed choices (in ``additional_constraints``) and ``read_only`` (default ``True``: the
config is frozen at start-up, so a later change would silently not apply). rclpy itself rejects
out-of-range and wrongly typed values at declaration; those rejections, a value outside
``choices``, a missing required parameter and a failing ``validate`` hook all become one
:class:`eye_in_hand.errors.ConfigError` naming the parameter. The dataclass's own
``__post_init__`` can check combinations of parameters; a ``ValueError`` raised there becomes a
``ConfigError`` as well.

:func:`declare_params` does the same for a plain list of :class:`Param` and returns a dict.
Parameters declared ``read_only=False`` stay changeable at run time; a set-parameters callback
then applies the same choices, element ranges and hook to every later change (rclpy checks
type and scalar range itself), so ``ros2 param set`` with a bad value is refused with a reason.
Such a node re-reads the value with ``node.get_parameter(name)`` where it uses it.
"""
from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import math
import os
import re
import sys
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)

# rclpy is imported where a node declares its parameters, not here: checking a parameter
# file's keys (unknown_parameter_keys, for `process` and `locate`) loads no rclpy, whose C
# library starts tracing threads in the process (that would keep `process` from forking its
# workers: eye_in_hand.workers.fork_is_safe) and costs ~30 ms of start-up
from eye_in_hand.core.units import unit_hint
from eye_in_hand.errors import ConfigError
from eye_in_hand.yamlfile import printable, read_yaml_file

if TYPE_CHECKING:
    from eye_in_hand.core.locator_params import ParamSpec

__all__ = [
    "PARAM_TYPES",
    "Param",
    "param",
    "params_of",
    "param_from_spec",
    "declare_params",
    "load_config",
    "params_markdown",
    "check_parameter_file",
    "closest_name",
    "unknown_parameter_keys",
    "refuse_undeclared_overrides",
]

#: Parameter type names accepted by :class:`Param` (``type=``).
PARAM_TYPES: tuple[str, ...] = (
    "bool", "int", "float", "str", "bool[]", "int[]", "float[]", "str[]")

_SCALARS: dict[type, str] = {bool: "bool", int: "int", float: "float", str: "str"}
_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*$")
_META_KEY = "eye_in_hand.param"


def _unit_hint(name: str, value: Any, high: float) -> str:
    """:func:`eye_in_hand.core.units.unit_hint` for a value that may be text from rclpy."""

    try:
        return unit_hint(name, float(value), high)
    except (TypeError, ValueError):
        return ""


def _infer_type(default: Any) -> str | None:
    if isinstance(default, (list, tuple)):
        if not default:
            return None
        kinds = {_infer_type(v) for v in default}
        if len(kinds) == 1 and next(iter(kinds)) in _SCALARS.values():
            return f"{next(iter(kinds))}[]"
        if kinds == {"int", "float"}:
            return "float[]"
        raise ValueError(f"list default {default!r} mixes types {sorted(map(str, kinds))}")
    for py, name in _SCALARS.items():
        if type(default) is py:
            return name
    return None


def _coerce(value: Any, type_name: str) -> Any:
    """Normalise a value read from rclpy (lists/array.array -> tuple of Python scalars)."""
    if type_name.endswith("[]"):
        elem = type_name[:-2]
        return tuple(_coerce(v, elem) for v in value)
    if type_name == "float":
        return float(value)
    if type_name == "int":
        return int(value)
    if type_name == "bool":
        return bool(value)
    return str(value)


def _conforms(value: Any, type_name: str) -> bool:
    if type_name.endswith("[]"):
        return isinstance(value, (list, tuple)) and all(
            _conforms(v, type_name[:-2]) for v in value)
    if type_name == "float":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if type_name == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if type_name == "bool":
        return isinstance(value, bool)
    return isinstance(value, str)


@dataclass(frozen=True)
class Param:
    """One ROS parameter: name, default, description and constraints.

    Attributes:
        name: parameter name (``a.b_c`` style; dots make ROS parameter groups).
        default: default value: bool, int, float, str, or a tuple/list of one of them.
            Write floats as floats (``1.0``): the type is inferred from the default.
        description: one line shown by ``ros2 param describe`` and in the README tables.
        range: inclusive ``(low, high)`` for int/float parameters and for each element of
            int[]/float[] parameters.
        choices: the allowed values (str, int or float parameters).
        read_only: declare read-only (default): the value is read once at start-up.
        type: one of :data:`PARAM_TYPES`; needed only when the default is an empty tuple.
        required: no usable default: the parameter must be set (an empty default then means
            "not given").
        validate: optional hook ``value -> error text or None`` for further checks.
    """

    name: str
    default: Any
    description: str
    range: tuple[float, float] | None = None
    choices: tuple[Any, ...] | None = None
    read_only: bool = True
    type: str | None = None
    required: bool = False
    validate: Callable[[Any], str | None] | None = None

    def __post_init__(self) -> None:
        if not _NAME_RE.match(self.name):
            raise ValueError(f"Param: invalid parameter name {self.name!r}")
        if not self.description.strip():
            raise ValueError(f"Param {self.name!r}: a description is required")
        type_name = self.type or _infer_type(self.default)
        if type_name is None:
            raise ValueError(
                f"Param {self.name!r}: cannot infer a type from default {self.default!r}; "
                f"pass type= (one of {', '.join(PARAM_TYPES)})")
        if type_name not in PARAM_TYPES:
            raise ValueError(f"Param {self.name!r}: type {type_name!r} not in {PARAM_TYPES}")
        object.__setattr__(self, "type", type_name)
        default = self.default
        if type_name.endswith("[]"):
            if not isinstance(default, (list, tuple)):
                raise ValueError(f"Param {self.name!r}: default must be a tuple for {type_name}")
            default = tuple(default)
        if not _conforms(default, type_name):
            raise ValueError(f"Param {self.name!r}: default {default!r} is not a {type_name}")
        object.__setattr__(self, "default", _coerce(default, type_name))
        if self.range is not None:
            if type_name.rstrip("[]") not in ("int", "float"):
                raise ValueError(f"Param {self.name!r}: range needs an int or float type")
            lo, hi = self.range
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"Param {self.name!r}: bad range {self.range!r}")
            if type_name.startswith("int") and (int(lo) != lo or int(hi) != hi):
                raise ValueError(f"Param {self.name!r}: an int range needs int bounds")
            object.__setattr__(self, "range", (lo, hi))
        if self.choices is not None:
            if type_name.endswith("[]") or type_name == "bool" or not self.choices:
                raise ValueError(f"Param {self.name!r}: choices need a str, int or float type")
            object.__setattr__(self, "choices", tuple(self.choices))
        if not self.required:
            problem = self.check(self.default)
            if problem:
                raise ValueError(f"Param {self.name!r}: default {self.default!r}: {problem}")

    @property
    def is_array(self) -> bool:
        """True for the ``[]`` types."""
        return str(self.type).endswith("[]")

    def check(self, value: Any) -> str | None:
        """The reason ``value`` is not acceptable (range, choices, hook), or None."""
        if self.range is not None:
            lo, hi = self.range
            values = value if self.is_array else (value,)
            bad = [v for v in values if not (lo <= v <= hi)]
            if bad:
                return (f"{bad[0]!r} is outside the range [{lo}, {hi}]"
                        + _unit_hint(self.name, bad[0], hi))
        if self.choices is not None and value not in self.choices:
            return f"{value!r} is not one of {', '.join(map(repr, self.choices))}"
        if self.validate is not None:
            return self.validate(value)
        return None

    def descriptor(self) -> Any:
        """The ``rcl_interfaces.msg.ParameterDescriptor`` declared for this parameter."""
        desc = ParameterDescriptor(description=self.description, read_only=self.read_only)
        constraints = []
        if self.range is not None:
            lo, hi = self.range
            if self.type == "int":
                desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
            elif self.type == "float":
                desc.floating_point_range = [
                    FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
            else:
                constraints.append(f"each element in [{lo}, {hi}]")
        if self.choices is not None:
            constraints.append("one of " + ", ".join(map(str, self.choices)))
        if self.required:
            constraints.append("required")
        desc.additional_constraints = "; ".join(constraints)
        return desc

    def ros_type(self) -> Any:
        """The ``rclpy.parameter.Parameter.Type`` of this parameter."""
        from rclpy.parameter import Parameter

        return {
            "bool": Parameter.Type.BOOL, "int": Parameter.Type.INTEGER,
            "float": Parameter.Type.DOUBLE, "str": Parameter.Type.STRING,
            "bool[]": Parameter.Type.BOOL_ARRAY, "int[]": Parameter.Type.INTEGER_ARRAY,
            "float[]": Parameter.Type.DOUBLE_ARRAY, "str[]": Parameter.Type.STRING_ARRAY,
        }[str(self.type)]


def param(default: Any, description: str, *, range: tuple[float, float] | None = None,
          choices: Iterable[Any] | None = None, read_only: bool = True,
          type: str | None = None, required: bool = False,
          validate: Callable[[Any], str | None] | None = None,
          name: str | None = None) -> Any:
    """A dataclass field that is also a ROS parameter (see :class:`Param` for the options).

    Args:
        name: the ROS parameter name when it differs from the field name (e.g. ``"hsv.low"``).

    Returns:
        A ``dataclasses.field`` with the default and the parameter metadata.
    """
    spec = {"default": default, "description": description, "range": range,
            "choices": None if choices is None else tuple(choices), "read_only": read_only,
            "type": type, "required": required, "validate": validate, "name": name}
    stored = tuple(default) if isinstance(default, list) else default
    return dataclasses.field(default=stored, metadata={_META_KEY: spec})


def params_of(config_cls: type) -> list[Param]:
    """The :class:`Param` list of a config dataclass made with :func:`param` fields.

    Raises:
        TypeError: not a dataclass, or an init field not made with :func:`param`.
        ValueError: an invalid parameter definition.
    """
    if not dataclasses.is_dataclass(config_cls):
        raise TypeError(f"{config_cls!r} is not a dataclass")
    out = []
    for f in dataclasses.fields(config_cls):
        if not f.init:
            continue
        spec = f.metadata.get(_META_KEY)
        if spec is None:
            raise TypeError(f"{config_cls.__name__}.{f.name}: not declared with param()")
        spec = dict(spec)
        name = spec.pop("name") or f.name
        out.append(Param(name=name, **spec))
    return out


def param_from_spec(spec: ParamSpec) -> Param:
    """The :class:`Param` of a ROS-free parameter description (the locator's, in
    :mod:`eye_in_hand.core.locator_params`); an open end of its range becomes +-1e300."""
    default = tuple(spec.default) if isinstance(spec.default, list) else spec.default
    rng = None
    if spec.min is not None or spec.max is not None:
        lo = spec.min if spec.min is not None else -1e300
        hi = spec.max if spec.max is not None else 1e300
        rng = (int(lo), int(hi)) if isinstance(spec.default, int) and not isinstance(
            spec.default, bool) else (float(lo), float(hi))
    return Param(spec.name, default, spec.description, range=rng,
                 choices=spec.choices or None)


def _declare_one(node: Any, p: Param, full: str) -> Any:
    from rclpy.exceptions import (
        InvalidParameterTypeException,
        InvalidParameterValueException,
        ParameterAlreadyDeclaredException,
        ParameterUninitializedException,
    )

    typed_only = p.required or (p.is_array and not p.default)
    initial = p.ros_type() if typed_only else (list(p.default) if p.is_array else p.default)
    try:
        node.declare_parameter(full, initial, p.descriptor())
    except InvalidParameterValueException as exc:
        text = str(exc.args[0]) if exc.args else str(exc)
        match = re.search(r"Invalid parameter value \((.*?)\) for parameter", text)
        if match and p.range is not None:
            problem = (f"{match.group(1)} is outside the range [{p.range[0]}, {p.range[1]}]"
                       + _unit_hint(full, match.group(1), p.range[1]))
        else:
            problem = f"rejected by rclpy: {text}"
        raise ConfigError(f"parameter '{full}': {problem}: {p.description}") from exc
    except InvalidParameterTypeException as exc:
        text = str(exc.args[0]) if exc.args else str(exc)
        match = re.search(r"to '(.*)' of type '(\w+)'", text, re.S)
        got = f"{match.group(2).lower()} {match.group(1)}" if match else text
        hint = " (write floats with a decimal point, e.g. 2.0)" if "float" in str(p.type) else ""
        raise ConfigError(
            f"parameter '{full}': expected type {p.type}, got {got}{hint}: {p.description}"
        ) from exc
    except ParameterAlreadyDeclaredException as exc:
        raise ConfigError(f"parameter '{full}' is declared twice") from exc
    try:
        value = node.get_parameter(full).value
    except ParameterUninitializedException as exc:
        if p.required:
            raise ConfigError(
                f"parameter '{full}' is required but was not set: {p.description}") from exc
        return p.default  # an empty-array parameter left unset: its default, ()
    value = _coerce(value, str(p.type))
    if p.required and value in ("", ()):
        raise ConfigError(f"parameter '{full}' is required but is empty: {p.description}")
    return value


def declare_params(node: Any, params: Iterable[Param], *, prefix: str = "") -> dict[str, Any]:
    """Declare parameters on ``node`` and return their validated values.

    Args:
        node: an ``rclpy.node.Node``.
        params: the parameters to declare.
        prefix: prepended to every name (e.g. ``"left."``).

    Returns:
        ``{param.name: value}`` (without prefix); arrays as tuples.

    Raises:
        ConfigError: a value out of range, of the wrong type, not among the choices, rejected by
            the hook, or a required parameter not set; the message names the parameter.
    """
    values: dict[str, Any] = {}
    dynamic: dict[str, Param] = {}
    for p in params:
        full = f"{prefix}{p.name}"
        value = _declare_one(node, p, full)
        problem = p.check(value)
        if problem:
            raise ConfigError(f"parameter '{full}': {problem}: {p.description}")
        values[p.name] = value
        if not p.read_only:
            dynamic[full] = p
    if dynamic:
        node.add_on_set_parameters_callback(_run_time_check(dynamic))
    return values


def _run_time_check(dynamic: dict[str, Param]) -> Callable[[list[Any]], Any]:
    """A set-parameters callback applying choices, element ranges and hooks at run time.

    rclpy itself enforces type and scalar range of a later ``ros2 param set``; this adds the
    checks it does not know about, so a dynamic parameter never takes a value that start-up
    validation would have refused.
    """
    def callback(parameters: list[Any]) -> Any:
        for parameter in parameters:
            p = dynamic.get(parameter.name)
            if p is None or parameter.value is None:
                continue
            try:
                value = _coerce(parameter.value, str(p.type))
            except (TypeError, ValueError):
                continue  # a type mismatch: rclpy rejects it with its own reason
            problem = p.check(value)
            if problem:
                return SetParametersResult(
                    successful=False, reason=f"parameter '{parameter.name}': {problem}")
        return SetParametersResult(successful=True)

    return callback


def load_config(node: Any, config_cls: type, *, prefix: str = "") -> Any:
    """Declare the parameters of a config dataclass and build a frozen instance from them.

    Args:
        node: an ``rclpy.node.Node``.
        config_cls: a dataclass whose init fields are made with :func:`param`.
        prefix: prepended to every parameter name.

    Returns:
        An instance of ``config_cls``.

    Raises:
        ConfigError: any parameter is invalid (see :func:`declare_params`), or the dataclass's
            ``__post_init__`` rejected the combination (its ``ValueError`` is wrapped).
    """
    params = params_of(config_cls)
    values = declare_params(node, params, prefix=prefix)
    fields = [f.name for f in dataclasses.fields(config_cls) if f.init]
    kwargs = {field_name: values[p.name] for field_name, p in zip(fields, params, strict=True)}
    try:
        return config_cls(**kwargs)
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(f"{config_cls.__name__}: {exc}") from exc


def params_markdown(params: Iterable[Param] | type) -> str:
    """A Markdown table (name, type, default, constraints, description) for the manual."""
    plist = params_of(params) if isinstance(params, type) else list(params)
    lines = ["| parameter | type | default | constraints | description |",
             "|---|---|---|---|---|"]
    for p in plist:
        constraints = []
        if p.range is not None:
            constraints.append(f"[{p.range[0]}, {p.range[1]}]")
        if p.choices is not None:
            constraints.append(" / ".join(map(str, p.choices)))
        if p.required:
            constraints.append("required")
        if not p.read_only:
            constraints.append("dynamic")
        default = "–" if p.required else f"`{p.default!r}`"  # never an empty code span
        lines.append(f"| `{p.name}` | {p.type} | {default} | {', '.join(constraints)} | "
                     f"{p.description} |")
    return "\n".join(lines)


def check_parameter_file(path: Any) -> None:
    """Check a ROS parameter file with rcl's own parser (``rcl_yaml_param_parser``), the one
    every node runs on ``--params-file`` at start-up, without starting a node.

    rcl is stricter than YAML: no anchors or aliases, no value beside ``ros__parameters``,
    homogeneous arrays, no nested sequences. A file it refuses would stop every node in
    ``rclpy.init`` (and make a supervisor restart them again and again), so it is refused here.

    Raises:
        ConfigError: ``<file>: rcl cannot parse this parameter file: <rcl's reason>``.
    """
    from rclpy.utilities import remove_ros_args

    try:
        remove_ros_args(["check", "--ros-args", "--params-file", str(path)])
    except Exception as exc:  # noqa: BLE001 - rclpy's RCLInvalidROSArgsError, one line here
        text = " ".join(str(exc).split())
        marker = "Error: "
        reason = text[text.index(marker) + len(marker):] if marker in text else text
        reason = re.sub(r",? at /\S+:\d+", "", reason).strip().rstrip(",")
        shown = str(path).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise ConfigError(f"{shown}: rcl cannot parse this parameter file: {reason}") from exc


#: Parameters every rclpy node declares itself.
ALWAYS_DECLARED: frozenset[str] = frozenset({"use_sim_time"})


def closest_name(name: str, candidates: Iterable[str]) -> str | None:
    """The candidate closest to ``name`` (``difflib``), or None when none is close.

    Dotted names are compared first with their siblings (same group: ``targets.red.radius_mm``
    against ``targets.red.*`` by the last part), then as whole names.
    """
    pool = sorted(set(candidates))
    group, _, leaf = name.rpartition(".")
    siblings = {c.rpartition(".")[2]: c for c in pool if c.rpartition(".")[0] == group}
    match = difflib.get_close_matches(leaf, list(siblings), n=1, cutoff=0.6)
    if match:
        return siblings[match[0]]
    match = difflib.get_close_matches(name, pool, n=1, cutoff=0.6)
    if match:
        return match[0]
    leaves = {c.rpartition(".")[2]: c for c in pool}  # the right name in another group
    match = difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.75)
    return leaves[match[0]] if match else None


def _did_you_mean(name: str, candidates: Iterable[str]) -> str:
    best = closest_name(name, candidates)
    return f" (did you mean `{best}`?)" if best else ""


def _flat_parameters(params: Mapping[Any, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in params.items():
        if isinstance(value, Mapping):
            out.update(_flat_parameters(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _sections(data: Mapping[Any, Any], prefix: str = "") -> Iterable[tuple[str, Any]]:
    """``(node key, ros__parameters)`` of a parameter file; nested namespace mappings
    (``/stereo: {detect_triangulate: {ros__parameters: ...}}``) are joined with ``/``."""
    for key, body in data.items():
        path = f"{prefix}/{str(key).strip('/')}" if prefix else str(key)
        if isinstance(body, Mapping) and "ros__parameters" in body:
            yield path, body["ros__parameters"]
        elif isinstance(body, Mapping):
            yield from _sections(body, path)
        else:
            yield path, None


def unknown_parameter_keys(path: str | os.PathLike[str],
                           declared: Callable[[str, Mapping[str, Any]], Collection[str]],
                           nodes: Sequence[str],
                           hint: Callable[[str, str, Mapping[str, Any]], str | None] | None = None,
                           used: Collection[str] | None = None) -> list[str]:
    """Every key of a ROS parameter file that no node it applies to declares, one line each.

    A section's node name is the last part of its key (``/**/hand_eye``, ``/stereo/hand_eye``,
    ``hand_eye``); ``*`` and ``**`` match any node (``/**`` applies to every node). A name
    that matches none of ``nodes`` is an unknown node; a parameter is unknown unless every node
    the section applies to declares it (that node would refuse it at start-up:
    :func:`refuse_undeclared_overrides`).

    Args:
        path: the parameter file.
        declared: ``(node, its flat parameters in the file) -> the names it declares``.
        nodes: the node names a file may configure.
        hint: ``(node, unknown name, its flat parameters) -> advice or None``, said instead of
            the closest name where the node knows better.
        used: the nodes the file is given to (default: all of ``nodes``): a wildcard section
            (``/**``) must hold only what each of these declares.

    Returns:
        ``<file>: unknown ... `<key>` ... (did you mean `<name>`?)`` lines; empty when all is
        known.
    """

    shown = printable(path)
    data = read_yaml_file(path, "parameter file")
    if not isinstance(data, Mapping):
        return [f"{shown}: expected a mapping of node names to ros__parameters"]
    sections = list(_sections(data))
    if not any(isinstance(params, Mapping) for _, params in sections):
        return [f"{shown}: not a ROS parameter file (no `/**/<node>: {{ros__parameters: ...}}` "
                "entry)"]
    problems = []
    for key, params in sections:
        node_pattern = key.rstrip("/").rsplit("/", 1)[-1] or "**"
        matched = [n for n in nodes if fnmatch.fnmatchcase(n, node_pattern.replace("**", "*"))]
        matched = [n for n in matched if used is None or n in used] or matched
        if not matched:
            problems.append(f"{shown}: unknown node name `{key}`"
                            f"{_did_you_mean(node_pattern, nodes)}; the nodes are "
                            f"{', '.join(nodes)}")
            continue
        if not isinstance(params, Mapping):
            problems.append(f"{shown}: `{key}` must contain a 'ros__parameters' mapping")
            continue
        flat = _flat_parameters(params)
        for name in flat:
            for node in matched:
                valid = set(declared(node, flat)) | ALWAYS_DECLARED
                if name not in valid:
                    where = "" if len(matched) == 1 else f" (not a parameter of {node})"
                    advice = hint(node, name, flat) if hint is not None else None
                    problems.append(f"{shown}: unknown parameter "
                                    f"`{key}.ros__parameters.{name}`{where}"
                                    + (f" ({advice})" if advice else
                                       _did_you_mean(name, valid)))
                    break
    return problems


def refuse_undeclared_overrides(node: Any, args: Sequence[str] | None = None) -> None:
    """Refuse the parameter overrides (``--params-file``, ``-p name:=value``) that ``node``
    did not declare: rclpy ignores them silently, so a mistyped name ran on the default.

    Call once the node has declared all its parameters (the end of its construction).

    Raises:
        ConfigError: naming each unknown parameter, the parameter files given, and the closest
            declared name.
    """
    # rclpy keeps the overrides it was given (file and -p) here; it has no public accessor
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    declared = set(node.list_parameters([], 0).names) | ALWAYS_DECLARED
    unknown = sorted(set(overrides) - declared)
    if not unknown:
        return

    argv = list(sys.argv if args is None else args)
    files = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--params-file"]
    source = (f"--params-file {', '.join(files)} or -p" if files
              else "-p or a parameter file")
    lines = [f"`{name}`{_did_you_mean(name, declared)}" for name in unknown]
    raise ConfigError(f"{node.get_fully_qualified_name()}: unknown parameter"
                      f"{'s' if len(unknown) > 1 else ''} ({source}): " + ", ".join(lines)
                      + "; the node does not declare " + ("them" if len(unknown) > 1 else "it")
                      + ", so it would have no effect")
