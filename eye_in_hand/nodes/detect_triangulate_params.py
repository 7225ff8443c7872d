"""The ``detect_triangulate`` node's parameters: its own, the locator's, one group per target.

A part of :mod:`eye_in_hand.nodes.detect_triangulate`: :data:`NODE_PARAMETERS` (the node's
own), the locator's :data:`~eye_in_hand.core.locator_params.LOCATOR_PARAMETERS` and
``targets.<name>.*`` (:data:`~eye_in_hand.core.locator_params.TARGET_PARAMETERS`) for each
name of ``target_names``. :func:`declare_parameters` declares them on the node;
:func:`parameter_names` and :func:`parameter_hint` give the same names to the parameter-file
check (:mod:`eye_in_hand.nodes.parameters`) before any node starts.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from eye_in_hand.core.defaults import DEFAULT_SYNC_QUEUE_SIZE, DEFAULT_SYNC_SLOP_S
from eye_in_hand.core.locator_params import (
    LOCATOR_PARAMETERS,
    TARGET_PARAMETERS,
    LocatorConfig,
    locator_config_from_params,
)
from eye_in_hand.errors import ConfigError
from eye_in_hand.ros.outputs import MARKER_DIAMETER_M, MARKER_LIFETIME_S
from eye_in_hand.ros.params import Param, declare_params, param_from_spec

__all__ = ["NODE_PARAMETERS", "DEFAULT_FRAME", "declare_parameters", "parameter_names",
           "parameter_hint"]

#: The frame of the published points when neither ``frame_id`` nor the image names one.
DEFAULT_FRAME = "camera_left_optical_frame"

#: Node-only parameters (the locator's are in :mod:`eye_in_hand.core.locator_params`).
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("calibration_dir", "", "directory with left.yaml + right.yaml (ROS camera_calibration "
          "files; stereo.yaml optional); empty = use the camera_info topics"),
    Param("frame_id", "", "frame of the published points; empty = the left image's frame_id "
          f"(or {DEFAULT_FRAME} when that is empty)"),
    Param("sync.slop_s", DEFAULT_SYNC_SLOP_S, "largest left/right stamp difference of a "
          "stereo pair (s); 0 = exact stamps only", range=(0.0, 1.0)),
    Param("sync.queue_size", DEFAULT_SYNC_QUEUE_SIZE, "frames per side waiting for a partner",
          range=(1, 100)),
    Param("queue_depth", 6, "stereo pairs waiting for the worker (6: 0.2 s at 30 Hz, enough "
          "for a burst of late DDS deliveries); when full the oldest is dropped (counted as "
          "dropped_pairs). 1 = only ever the newest pair", range=(1, 30)),
    Param("images.reliable", False, "subscribe to the images reliably: lost samples are sent "
          "again (a bag replay loses nothing in transport) but only reliable publishers "
          "match; false = best effort (sensor data QoS), which matches every camera driver"),
    Param("images.depth", 5, "images kept per side until the executor takes them (a busy "
          "machine may stall it for a few frames)", range=(1, 100)),
    Param("debug_image.max_rate_hz", 5.0, "rate limit of target/debug_image (Hz); 0 = never "
          "publish it", range=(0.0, 100.0)),
    Param("diagnostics_period_s", 1.0, "diagnostics publication period (s)",
          range=(0.05, 60.0)),
    Param("max_targets", 64, "most target ids that get targets/<id>/point(_cov) publishers; "
          "targets with further ids are refused (counted as targets_refused)",
          range=(1, 10_000)),
    Param("markers.lifetime_s", MARKER_LIFETIME_S, "lifetime of the spheres on "
          "targets/markers (s); 0 = until the next frame's DELETEALL", range=(0.0, 3600.0)),
    Param("markers.diameter_m", MARKER_DIAMETER_M, "sphere diameter on targets/markers for a "
          "target of unknown radius (radius_m 0)", range=(1e-4, 10.0)),
)

#: The default of ``target_names``.
_DEFAULT_TARGET_NAMES = [p for p in LOCATOR_PARAMETERS if p.name == "target_names"][0].default


def _target_group(name: str) -> tuple[str, list[Param]]:
    """``(prefix, parameters)`` of one target: ``targets.<name>.*``."""
    return f"targets.{name}.", [param_from_spec(p) for p in TARGET_PARAMETERS]


def _parameter_groups(target_names: Iterable[str]) -> list[tuple[str, list[Param]]]:
    """``(prefix, parameters)`` the node declares: its own, the locator's, and one group
    ``targets.<name>.`` per entry of ``target_names``."""
    groups = [("", list(NODE_PARAMETERS)), ("", [param_from_spec(p) for p in LOCATOR_PARAMETERS])]
    return groups + [_target_group(tname) for tname in target_names]


def declare_parameters(node: Any) -> tuple[dict[str, Any], LocatorConfig]:
    """Declare every parameter on ``node``: the node's own values, and the locator's
    configuration read from the locator's and the targets' parameters.

    Raises:
        ConfigError: a bad value or a bad name in ``target_names`` (the message names the
            parameter).
    """
    (_, own), (_, locator) = _parameter_groups(())
    node_values = declare_params(node, own)
    loc_values = declare_params(node, locator)
    flat: dict[str, Any] = dict(loc_values)
    for tname in loc_values["target_names"]:
        if not tname or not all(c.isalnum() or c == "_" for c in tname) \
                or not tname[0].isalpha():
            raise ConfigError(f"parameter 'target_names': '{tname}' must start with a "
                              "letter and contain only letters, digits and underscores")
        prefix, group = _target_group(tname)
        vals = declare_params(node, group, prefix=prefix)
        flat.update({f"{prefix}{k}": v for k, v in vals.items()})
    return node_values, locator_config_from_params(flat)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares, given its parameter values (flat, dotted) from
    a parameter file: the per-target names follow ``target_names`` (default ``[red]``)."""
    names = values.get("target_names")
    if not isinstance(names, (list, tuple)):
        names = _DEFAULT_TARGET_NAMES
    return [prefix + p.name for prefix, group in _parameter_groups([str(n) for n in names])
            for p in group]


def parameter_hint(name: str, values: Mapping[str, Any]) -> str | None:
    """Advice for an undeclared ``targets.<name>.*``: its target is not in ``target_names``."""
    parts = name.split(".")
    if len(parts) != 3 or parts[0] != "targets":
        return None
    names = values.get("target_names", _DEFAULT_TARGET_NAMES)
    if parts[1] in names:
        return None
    return (f"target '{parts[1]}' is not in target_names [{', '.join(map(str, names))}]: add it "
            "there, or remove its section (a node declares targets.<name>.* only for the "
            "names in target_names)")
