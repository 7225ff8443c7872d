"""The parameters of every node, for checking a parameter file before any node starts.

Each node module (or its parameter part, :data:`PARAMETER_MODULES`) has
``parameter_names(values)``: the names it declares, derived from the same
:class:`~eye_in_hand.ros.params.Param` lists and config dataclasses it declares at start-up
(``detect_triangulate``'s per-target names follow the file's ``target_names``). A node refuses
an override it does not declare at start-up
(:func:`eye_in_hand.ros.params.refuse_undeclared_overrides`);
:func:`check_parameter_file_keys` refuses the same keys earlier, for the commands that read a
parameter file (``launch``, ``process``, ``locate``), and unknown node names as well.
"""
from __future__ import annotations

import importlib
import os
from collections.abc import Mapping, Sequence
from typing import Any

from eye_in_hand.errors import ConfigError

__all__ = ["NODE_NAMES", "PARAMETER_MODULES", "declared_parameters", "check_parameter_file_keys"]

#: The package's nodes (the executables of setup.py's NODE_SCRIPTS), each a module of this
#: package of the same name.
NODE_NAMES: tuple[str, ...] = ("stereo_capture", "detect_triangulate", "hand_eye",
                               "bag_player", "bag_recorder")
#: The module of a node's ``parameter_names`` (and ``parameter_hint``) where it is not the
#: node's own module: a part of the node.
#: (Those of the nodes of the shipped parameter files import no rclpy: see ros.params.)
PARAMETER_MODULES: dict[str, str] = {"detect_triangulate": "detect_triangulate_params",
                                      "hand_eye": "hand_eye_params",
                                      "stereo_capture": "stereo_capture_params"}


def _parameter_module(node: str) -> Any:
    return importlib.import_module(f"eye_in_hand.nodes.{PARAMETER_MODULES.get(node, node)}")


def declared_parameters(node: str, values: Mapping[str, Any]) -> list[str]:
    """The parameter names ``node`` declares, given its flat parameter values from a file."""
    if node not in NODE_NAMES:
        raise ConfigError(f"unknown node {node!r} (the nodes are {', '.join(NODE_NAMES)})")
    return list(_parameter_module(node).parameter_names(values))


def _hint(node: str, name: str, values: Mapping[str, Any]) -> str | None:
    advise = getattr(_parameter_module(node), "parameter_hint", None)
    return advise(name, values) if advise is not None else None


def check_parameter_file_keys(path: str | os.PathLike[str],
                              used: Sequence[str] | None = None) -> None:
    """Refuse a parameter file with a key no node declares, or a section for an unknown node.

    Args:
        path: the parameter file.
        used: the nodes it is given to (default: every node); a ``/**`` section must hold only
            what each of them declares (``locate`` runs only ``detect_triangulate``'s code).

    Raises:
        ConfigError: one line per unknown key: the file, the key (``/**/<node>.ros__parameters.
            <name>``) and the closest valid name (``did you mean `radius_m`?``).
    """
    # local: only a command given a parameter file needs it (no rclpy: see ros.params)
    from eye_in_hand.ros.params import unknown_parameter_keys

    problems = unknown_parameter_keys(path, declared_parameters, NODE_NAMES, _hint, used)
    if problems:
        raise ConfigError("\n".join(problems))
