"""ROS topic names checked with rclpy's own rules, with one-line errors that name the name."""
from __future__ import annotations

from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_topic_name import validate_topic_name

from eye_in_hand.errors import InputError

__all__ = ["topic_name_problem", "check_topic_name", "check_parameter_text"]


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
        reason = str(exc).splitlines()[0].strip()
        for prefix in ("Invalid topic name:", "topic name"):
            if reason.startswith(prefix):
                reason = reason[len(prefix):].strip()
        return reason.rstrip(":")
    if "//" in name:
        return "must not contain an empty token ('//')"
    return None


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
