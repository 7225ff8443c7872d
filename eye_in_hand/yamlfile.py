"""Reading YAML files (``yaml.safe_load`` only) with errors that name the file and the problem."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from eye_in_hand.errors import ConfigError

__all__ = ["read_yaml_file"]


def read_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """The parsed content of a YAML file.

    Args:
        path: the file.
        what: what the file is, for messages (e.g. ``"calibration file"``).

    Raises:
        ConfigError: ``<path>: <what> not found``, ``<path>: cannot read <what> (...)`` or
            ``<path>: not valid YAML (...)``.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise ConfigError(f"{p}: {what} not found") from exc
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read {what} ({exc.strerror or exc})") from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML ({exc})") from exc
