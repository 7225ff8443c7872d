"""ROS topic names checked with rclpy's own rules, with one-line errors that name the name."""
from __future__ import annotations

from rclpy.exceptions import InvalidNamespaceException, InvalidTopicNameException
from rclpy.validate_namespace import validate_namespace
from rclpy.validate_topic_name import validate_topic_name

from eye_in_hand.errors import InputError

__all__ = ["topic_name_problem", "check_topic_name", "check_parameter_text",
           "namespace_problem", "check_namespace", "MAX_TOPIC_LENGTH", "NAMESPACE_ROOM"]

#: The longest full topic name ROS allows (rmw's ``RMW_TOPIC_MAX_NAME_LENGTH``, 255 - 8: DDS
#: adds a prefix of up to 8 characters).
MAX_TOPIC_LENGTH = 247
#: Characters kept free below a root namespace for the package's own topic names under it
#: (``stereo/right/camera_info``, ``target/<id>/pose_cov``, ``hand_eye/calibration_status``).
NAMESPACE_ROOM = 64


def _reason(exc: Exception, prefixes: tuple[str, ...]) -> str:
    reason = str(exc).splitlines()[0].strip()
    for prefix in prefixes:
        if reason.startswith(prefix):
            reason = reason[len(prefix):].strip()
    return reason.rstrip(":")


def topic_name_problem(name: str) -> str | None:
    """Why ``name`` is not a valid ROS 2 topic name (relative or absolute), or None if it is.

    The rules are rcl's (``rclpy.validate_topic_name``: allowed characters, no token starting
    with a digit, no trailing ``/``, ``~`` only at the start) plus no empty token (``//``).
    """
    if not isinstance(name, str):
        return f"not a string ({type(name).__name__})"
    if not name.isascii():
        return "must not contain characters other than alphanumerics, '_', '~', '{', or '}'"
    try:
        validate_topic_name(name)
    except InvalidTopicNameException as exc:
        return _reason(exc, ("Invalid topic name:", "topic name"))
    if "//" in name:
        return "must not contain an empty token ('//')"
    full = len(name) + (0 if name.startswith("/") else 1)
    if full > MAX_TOPIC_LENGTH:
        return (f"{full} characters as a full name; ROS allows at most {MAX_TOPIC_LENGTH}")
    return None


def namespace_problem(ns: str) -> str | None:
    """Why ``ns`` is not a valid root namespace (absolute, ``/`` included), or None if it is.

    rcl's rules (``rclpy.validate_namespace``: absolute, allowed characters, no ``//``, no
    trailing ``/``) and room for the package's topics below it: at most
    ``MAX_TOPIC_LENGTH - NAMESPACE_ROOM`` characters.
    """
    if not isinstance(ns, str):
        return f"not a string ({type(ns).__name__})"
    if not ns.isascii():
        return "must not contain characters other than alphanumerics, '_', or '/'"
    try:
        validate_namespace(ns)
    except InvalidNamespaceException as exc:
        return _reason(exc, ("Invalid namespace:", "namespace"))
    if len(ns) > MAX_TOPIC_LENGTH - NAMESPACE_ROOM:
        return (f"{len(ns)} characters; at most {MAX_TOPIC_LENGTH - NAMESPACE_ROOM}, so that "
                f"the topics under it stay within ROS's {MAX_TOPIC_LENGTH}")
    return None


def check_namespace(ns: str, what: str = "--namespace") -> str:
    """``ns`` as an absolute namespace (a leading ``/`` is added to a relative one) if valid.

    Raises:
        InputError: ``<what> '<ns>': not a valid namespace (<reason>)``.
    """
    full = ns if isinstance(ns, str) and ns.startswith("/") else f"/{ns}"
    problem = namespace_problem(full)
    if problem is not None:
        shown = ns.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace") \
            if isinstance(ns, str) else ns
        if len(shown) > 80:
            shown = shown[:60] + "..."
        raise InputError(f"{what} {shown!r}: not a valid namespace ({problem})")
    return full


def check_topic_name(name: str, what: str = "topic") -> str:
    """``name`` if it is a valid topic name.

    Args:
        name: the topic name.
        what: what named it, for the message (e.g. ``"echo TOPIC"``, ``"bag topic"``).

    Raises:
        InputError: ``<what> '<name>': not a valid topic name (<reason>)``.
    """
    problem = topic_name_problem(name)
    if problem is not None:
        shown = name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace") \
            if isinstance(name, str) else name
        if isinstance(shown, str) and len(shown) > 80:
            shown = shown[:60] + "..."
        raise InputError(f"{what} {shown!r}: not a valid topic name ({problem})")
    return name


def check_parameter_text(text: str, what: str) -> str:
    """``text`` if it can be a ROS string parameter (UTF-8; a file name with bytes that are not
    UTF-8 cannot: rclpy would fail on it with a traceback).

    Raises:
        InputError: ``<what> '<text with \\xNN>': not UTF-8 text; ...``.
    """
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise InputError(f"{what} '{shown}': not UTF-8 text, so it cannot be passed to a ROS "
                         "node (rename it)") from exc
    return text
