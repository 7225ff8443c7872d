"""Helpers shared by several ``eye-in-hand`` commands (each command is a module of its own and
imports only this one of its siblings), and the commands' one language: the flags several
commands share, defined once here (``-o/--output``, ``--left-topic``/``--right-topic``, the
``--robot-pose`` family with ``--kinematics``), old spellings kept as hidden deprecated aliases,
and the help format that shows every default."""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys

from eye_in_hand.errors import InputError

__all__ = ["apply_overrides", "check_range", "bounded", "MAX_WORKERS", "ROBOT_POSE_SOURCES",
           "KINEMATICS_BUILTIN", "HelpFormatter", "DeprecatedAlias", "deprecated_alias",
           "parse_known_args_with_aliases", "kinematics_spec", "add_output_argument",
           "add_image_topic_arguments", "add_robot_pose_arguments"]

#: Upper bound of ``--workers`` (processes locating stereo pairs): more never helps on any
#: machine the package targets, and each one costs about 100 MB of memory.
MAX_WORKERS = 64


def _fmt(x: float) -> str:
    """A range bound as written in the docs: an integral value in full, else ``%g``."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def check_range(flag: str, value, lo: float, hi: float, unit: str = "", *,
                lo_open: bool = False, integer: bool = False):
    """``value`` if it is a finite number within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``).

    The documented range of a numeric flag, checked before any work: a value outside it (or
    NaN, or infinity) is refused with one line that names the flag, the range and the value.

    Raises:
        InputError: ``--flag: must be within [lo, hi] unit, got value``.
    """
    if value is None:
        return value
    ok = isinstance(value, (int, float)) and math.isfinite(value) and (
        (value > lo) if lo_open else (value >= lo)) and value <= hi
    if ok and integer and int(value) != value:
        ok = False
    if not ok:
        left = "(" if lo_open else "["
        suffix = f" {unit}" if unit else ""
        raise InputError(f"{flag}: must be {'an integer ' if integer else ''}within "
                         f"{left}{_fmt(lo)}, {_fmt(hi)}]{suffix}, got {value}")
    return value


def apply_overrides(config, *, radius: float | None = None, method: str | None = None):
    """The locator config with ``--radius`` (first target, metres) and ``--method`` applied.

    Raises:
        InputError: a radius that is not a positive number.
    """
    if radius is not None:
        if not (math.isfinite(radius) and radius > 0):
            raise InputError(f"--radius: must be a positive number of metres, got {radius}")
        targets = list(config.detector.targets)
        targets[0] = dataclasses.replace(targets[0], radius_m=float(radius))
        config = dataclasses.replace(
            config, detector=dataclasses.replace(config.detector, targets=tuple(targets)))
    if method is not None:
        config = dataclasses.replace(config, method=method)
    return config


def bounded(lo: float, hi: float, unit: str = "", *, integer: bool = False,
            lo_open: bool = False):
    """An argparse ``type=`` that accepts a number within ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``; an integer with ``integer``) and refuses anything else (NaN, infinity, a
    word) at once, so the command line says ``argument --flag: must be within ...`` before
    any work starts."""
    def parse(text: str):
        try:
            value = int(text, 10) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if integer else 'a number'}, got {text!r}") from None
        try:
            check_range("", value, lo, hi, unit, lo_open=lo_open, integer=integer)
        except InputError as exc:
            text_range = str(exc)[2:].rsplit(", got ", 1)[0]
            raise argparse.ArgumentTypeError(f"{text_range}, got {text}") from None
        return value

    parse.__name__ = "bounded"
    parse.range_text = (  # type: ignore[attr-defined]
        f"{'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}]" + (f" {unit}" if unit else "")
        + (", integer" if integer else ""))
    return parse


# ------------------------------------------------------------------------------------------------
# the command language: flags shared by several commands, defined once
# ------------------------------------------------------------------------------------------------
#: The robot pose sources (``--robot-pose``), as the ``hand_eye`` node's ``robot_pose_source``.
ROBOT_POSE_SOURCES = ("ee_pose", "joint_states", "tf")

#: The built-in kinematic chains ``--kinematics`` accepts by name (besides a file).
KINEMATICS_BUILTIN = ("ur5e",)

#: What is printed when a deprecated spelling is used: one line on stderr.
DEPRECATED = "eye-in-hand: warning: {old} is deprecated and will be removed in the next " \
             "release; use {new}"


class HelpFormatter(argparse.HelpFormatter):
    """Every option's default in its ``--help`` line: ``(default: X)`` is appended unless the
    help text already states its default (with ``default``) or there is none to show (None,
    a flag's False)."""

    def _format_usage(self, usage, actions, groups, prefix):
        # while parse_known_args_with_aliases parses, a required flag with a deprecated
        # spelling is not required for argparse; --help still shows it as required
        marked = [a for a in actions if getattr(a, "required_meanwhile", False)]
        for a in marked:
            a.required = True
        try:
            return super()._format_usage(usage, actions, groups, prefix)
        finally:
            for a in marked:
                a.required = False

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS):
            return text
        if not action.option_strings or action.required:
            return text
        return text + (" " if text else "") + "(default: %(default)s)"


class DeprecatedAlias(argparse.Action):
    """An old spelling of a flag, kept for one release: hidden from ``--help``, it stores into
    the new flag's ``dest`` (and ``sets`` further values) and prints one line naming the new
    flag (:data:`DEPRECATED`)."""

    def __init__(self, option_strings, dest, *, new: str, sets: dict | None = None,
                 value=None, **kwargs) -> None:
        kwargs["default"] = argparse.SUPPRESS
        kwargs["help"] = argparse.SUPPRESS
        super().__init__(option_strings, dest, **kwargs)
        self.new = new
        self.sets = dict(sets or {})
        self.value = value

    def __call__(self, parser, namespace, values, option_string=None) -> None:

        print(DEPRECATED.format(old=option_string, new=self.new), file=sys.stderr)
        for key, val in self.sets.items():
            setattr(namespace, key, val)
        setattr(namespace, self.dest, self.value if self.nargs == 0 else values)


def deprecated_alias(parser, old: str, action: argparse.Action, *, new: str | None = None,
                     value=None, sets: dict | None = None) -> argparse.Action:
    """Add ``old`` as a hidden, deprecated spelling of ``action`` (the new flag, as
    ``add_argument`` returned it) to ``parser`` (a parser or an argument group).

    Args:
        new: how the warning names the replacement (default: the new flag's spellings).
        value: for an old flag that takes no value (``--tf``): the value it stands for.
        sets: further ``dest: value`` pairs the old spelling implied.
    """
    kwargs: dict = {"dest": action.dest, "new": new or "/".join(action.option_strings),
                    "sets": sets}
    action.has_alias = True  # type: ignore[attr-defined]  # see parse_known_args_with_aliases
    if value is not None:
        kwargs.update(nargs=0, value=value)
    else:
        kwargs.update(type=action.type, metavar=action.metavar, choices=action.choices,
                      nargs=action.nargs)
    return parser.add_argument(old, action=DeprecatedAlias, **kwargs)


def parse_known_args_with_aliases(parser: argparse.ArgumentParser, parse, args, namespace):
    """``parse(args, namespace)`` (argparse's ``parse_known_args``) where a required flag is
    satisfied by its deprecated spelling too: argparse alone would refuse ``--out X`` for a
    required ``-o/--output``, each spelling being an action of its own. A missing one is
    refused as argparse refuses it."""
    aliased = [a for a in parser._actions if a.required and getattr(a, "has_alias", False)]
    for a in aliased:
        # our flag on argparse's action, read by the help formatter
        a.required, a.required_meanwhile = False, True  # type: ignore[attr-defined]
    try:
        namespace, rest = parse(args, namespace)
    finally:
        for a in aliased:
            a.required, a.required_meanwhile = True, False  # type: ignore[attr-defined]
    missing = [a for a in aliased if getattr(namespace, a.dest, None) is None]
    if missing:
        parser.error("the following arguments are required: "
                     + ", ".join("/".join(a.option_strings) for a in missing))
    return namespace, rest


def kinematics_spec(text: str) -> str:
    """The argparse ``type=`` of ``--kinematics``, the same in every command: a built-in chain
    (``ur5e``, any case) or an existing URDF (``.urdf``, ``.xml``) or DH YAML file."""

    if text.strip().lower() in KINEMATICS_BUILTIN:
        return text.strip().lower()
    if not text or not os.path.isfile(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither {' nor '.join(repr(k) for k in KINEMATICS_BUILTIN)} nor a "
            "file (give 'ur5e', a URDF file or a DH YAML file such as config/world.yaml)")
    return text


kinematics_spec.__name__ = "kinematics"


def add_output_argument(parser, *, metavar: str, help: str, required: bool = True,
                        type=None) -> argparse.Action:
    """``-o/--output``: where every command writes (dest ``output``)."""
    kwargs = {"type": type} if type is not None else {}
    return parser.add_argument("-o", "--output", required=required, metavar=metavar,
                               help=help, **kwargs)


def add_image_topic_arguments(parser, *, left_help: str, right_help: str | None = None,
                              default_left: str | None = None,
                              default_right: str | None = None) -> dict[str, argparse.Action]:
    """``--left-topic`` and (``right_help`` given) ``--right-topic``: the image topics of every
    command that reads images from a bag (dest ``left_topic``, ``right_topic``). A mono camera
    is the left camera: its topic is ``--left-topic``."""
    out = {"left": parser.add_argument("--left-topic", metavar="TOPIC", default=default_left,
                                       help=left_help)}
    if right_help is not None:
        out["right"] = parser.add_argument("--right-topic", metavar="TOPIC",
                                           default=default_right, help=right_help)
    return out


def add_robot_pose_arguments(parser, *, default_source: str | None, source_help: str,
                             base_help: str, ee_help: str, default_base: str | None,
                             default_ee: str | None) -> dict[str, argparse.Action]:
    """The robot pose family, the same in every command that reads robot poses from a bag:
    ``--robot-pose {ee_pose,joint_states,tf}``, ``--ee-pose-topic``, ``--joint-states-topic``
    with ``--kinematics`` (and ``--urdf-base-link``, ``--urdf-tip-link`` for a URDF), and
    ``--base-frame`` -> ``--ee-frame`` over ``--tf-topic`` and ``--tf-static-topic`` for
    ``tf``."""
    add = parser.add_argument
    out = {
        "source": add("--robot-pose", choices=ROBOT_POSE_SOURCES, default=default_source,
                      help=source_help),
        "ee_pose_topic": add("--ee-pose-topic", metavar="TOPIC", default="/ee_pose",
                             help="geometry_msgs/PoseStamped robot pose topic (base -> "
                                  "flange) of --robot-pose ee_pose"),
        "joint_states_topic": add("--joint-states-topic", metavar="TOPIC",
                                  default="/joint_states",
                                  help="sensor_msgs/JointState topic of --robot-pose "
                                       "joint_states (with --kinematics)"),
        "kinematics": add("--kinematics", metavar="SPEC", type=kinematics_spec, default=None,
                          help="kinematic chain of --robot-pose joint_states: "
                               + ", ".join(repr(k) for k in KINEMATICS_BUILTIN)
                               + " (built in), a URDF file (.urdf, .xml) or a DH YAML file "
                                 "(the arm of a world.yaml, e.g. config/world.yaml); "
                                 "default: none"),
        "urdf_base_link": add("--urdf-base-link", metavar="LINK", default=None,
                              help="URDF chain root link (default: --base-frame)"),
        "urdf_tip_link": add("--urdf-tip-link", metavar="LINK", default=None,
                             help="URDF chain tip link (default: --ee-frame)"),
        "base_frame": add("--base-frame", metavar="FRAME", default=default_base,
                          help=base_help),
        "ee_frame": add("--ee-frame", metavar="FRAME", default=default_ee, help=ee_help),
        "tf_topic": add("--tf-topic", metavar="TOPIC", default="/tf",
                        help="TF topic of --robot-pose tf"),
        "tf_static_topic": add("--tf-static-topic", metavar="TOPIC", default="/tf_static",
                               help="static TF topic of --robot-pose tf"),
    }
    return out
