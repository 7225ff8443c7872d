"""Reading YAML files (``yaml.safe_load`` only) with errors that name the file and the problem."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from eye_in_hand.errors import ConfigError

__all__ = ["read_yaml_file", "read_text_file", "printable"]


def printable(path: str | os.PathLike[str]) -> str:
    """``path`` as text any terminal shows (a non-UTF-8 byte of a file name as ``\\xNN``)."""
    return os.fspath(path).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def read_text_file(path: str | os.PathLike[str], what: str) -> str:
    """The content of a UTF-8 text file.

    Raises:
        ConfigError: ``<path>: <what> not found``, ``<path>: cannot read <what> (...)`` or
            ``<path>: <what> is not UTF-8 text (byte 0xNN at offset N)``.
    """
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise ConfigError(f"{printable(p)}: {what} not found") from exc
    except IsADirectoryError as exc:
        raise ConfigError(f"{printable(p)}: {what} is a folder, not a file") from exc
    except OSError as exc:
        raise ConfigError(f"{printable(p)}: cannot read {what} ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{printable(p)}: {what} is not UTF-8 text (byte "
                          f"0x{exc.object[exc.start]:02x} at offset {exc.start})") from exc


def read_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """The parsed content of a YAML file.

    Args:
        path: the file.
        what: what the file is, for messages (e.g. ``"calibration file"``).

    Raises:
        ConfigError: ``<path>: <what> not found``, ``<path>: cannot read <what> (...)``,
            ``<path>: <what> is not UTF-8 text (...)`` or ``<path>: not valid YAML (...)``.
    """
    p = Path(path)
    text = read_text_file(p, what)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        detail = " ".join(str(exc).split())
        raise ConfigError(f"{printable(p)}: not valid YAML ({detail})") from exc
