"""Exception classes shared across the package.

Every error the package raises on bad input derives from :class:`EyeInHandError`, so the
command line can print one clear line (``eye-in-hand: error: ...``) instead of a traceback.
Messages say what was wrong and where (file, topic, sample index, parameter name).
"""
from __future__ import annotations

__all__ = [
    "EyeInHandError",
    "InputError",
    "ConfigError",
    "ConversionError",
    "BagError",
    "CalibrationError",
    "DetectionError",
    "TriangulationError",
    "HandEyeError",
    "KinematicsError",
    "LocalizationError",
    "DEBUG_ENV",
    "EXIT_UNEXPECTED",
    "debug_enabled",
    "unexpected_error_line",
]

#: Environment variable that shows the traceback of an unexpected error (``--debug`` sets it, so
#: worker processes and launched nodes inherit it).
DEBUG_ENV = "EYE_IN_HAND_DEBUG"
#: Exit code of a process stopped by an unexpected error (a bug, not bad input): EX_SOFTWARE.
EXIT_UNEXPECTED = 70


def debug_enabled(argv: list[str] | tuple[str, ...] | None = None) -> bool:
    """Whether tracebacks are wanted: ``--debug`` among ``argv`` or ``EYE_IN_HAND_DEBUG`` set
    to anything but ``""``/``0``."""
    import os

    if argv is not None and "--debug" in argv:
        return True
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def unexpected_error_line(prog: str, exc: BaseException) -> str:
    """The one line an entry point prints for an unexpected exception (a bug, not bad input):
    ``<prog>: internal error: <Type>: <message> (run with --debug for the traceback)``."""
    text = " ".join(str(exc).split())
    if len(text) > 300:
        text = text[:300] + "..."
    kind = type(exc).__name__
    detail = f"{kind}: {text}" if text else kind
    return (f"{prog}: internal error: {detail} (run with --debug, or {DEBUG_ENV}=1, for the "
            "traceback)")


class EyeInHandError(Exception):
    """Base class for every error the package reports to its users."""


class InputError(EyeInHandError, ValueError):
    """An argument or file content is malformed (shape, range, finiteness, format)."""


class ConfigError(EyeInHandError):
    """A configuration or calibration file is missing or malformed."""


class ConversionError(EyeInHandError, ValueError):
    """A ROS message cannot be converted (bad encoding, data length, field values)."""


class BagError(EyeInHandError):
    """A bag cannot be opened, read or written, or lacks a required topic."""


class CalibrationError(EyeInHandError):
    """Camera or stereo calibration cannot proceed (too few views, mismatched inputs)."""


class DetectionError(EyeInHandError):
    """Target detection was configured or called wrongly (not: 'no target found')."""


class TriangulationError(EyeInHandError):
    """A stereo point was rejected (behind a camera, bad disparity, residual gate)."""


class HandEyeError(EyeInHandError):
    """Hand-eye calibration cannot proceed (too few samples, degenerate motion, bad poses)."""


class KinematicsError(EyeInHandError):
    """Forward/inverse kinematics failed (bad model, unreachable pose, joint limits)."""


class LocalizationError(EyeInHandError):
    """A target pose cannot be formed (no robot pose at the image stamp, stale input).

    Attributes:
        reason: a short stable key saying why (``no_pose``, ``before_buffer``,
            ``no_newer_pose``, ``pose_gap``, ``stale_pose``), used to count refusals by
            reason on ``diagnostics`` and in ``process``'s summary.
    """

    def __init__(self, message: str = "", reason: str = "no_robot_pose") -> None:
        super().__init__(message)
        self.reason = reason
