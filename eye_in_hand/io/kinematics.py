"""Kinematics files: an arm's chain from ``ur5e``, a URDF file or a DH YAML file.

One loader for every place that reads a kinematics file: the ``hand_eye`` node
(``kinematics_file``), ``eye-in-hand process --kinematics`` and ``eye-in-hand calibrate handeye
--kinematics``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from eye_in_hand.core.kinematics import DHChain, UrdfChain
from eye_in_hand.errors import ConfigError, EyeInHandError
from eye_in_hand.yamlfile import printable, read_yaml_file

__all__ = ["load_kinematics"]


def load_kinematics(spec: str | Path, base_link: str = "base_link",
                    tip_link: str = "tool0") -> Any:
    """A kinematic chain (:class:`DHChain` or :class:`UrdfChain`).

    Args:
        spec: ``ur5e`` (the built-in UR5e, frames as ur_description), a URDF file (``*.urdf``,
            ``*.xml``), or a DH YAML file: the ``arm`` mapping of ``world.yaml`` (or a file
            with an ``arm`` key).
        base_link, tip_link: the URDF chain's ends (unused for DH).

    Raises:
        ConfigError: the file is missing, unreadable, not UTF-8 or malformed (names it).
    """
    if str(spec) == "ur5e":
        return DHChain.ur5e()
    p = Path(spec)
    if not p.is_file():
        raise ConfigError(f"{printable(p)}: kinematics file not found (give 'ur5e', a URDF or "
                          "a DH YAML file)")
    try:
        if p.suffix.lower() in (".urdf", ".xml"):
            return UrdfChain.from_file(p, base_link, tip_link)
        data = read_yaml_file(p, "kinematics file")
        if isinstance(data, dict) and "arm" in data:
            data = data["arm"]
        if not isinstance(data, dict):
            raise ConfigError(f"{printable(p)}: expected a DH mapping (d, a, alpha, ...)")
        return DHChain.from_dict(data)
    except ConfigError:
        raise
    except OSError as exc:
        raise ConfigError(f"{printable(p)}: cannot read kinematics file ({exc})") from exc
    except (EyeInHandError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(f"{printable(p)}: invalid kinematics file ({exc})") from exc
