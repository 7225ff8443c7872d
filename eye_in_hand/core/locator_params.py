"""The locator's parameters: every setting described once, and the config read from them.

:data:`LOCATOR_PARAMETERS` and :data:`TARGET_PARAMETERS` describe every setting of
:class:`~eye_in_hand.core.locator.StereoLocator` (name, default, description, range) once; the
``detect_triangulate`` node declares them as ROS parameters and the CLI reads the same names
from the node's parameter file (:func:`load_parameter_file`). :func:`locator_config_from_params`
turns flat dotted parameters into a checked :class:`LocatorConfig`. All of these are also
importable from :mod:`eye_in_hand.core.locator`.
"""
from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eye_in_hand.core.detection import (
    COLOR_SPACES,
    SELECTIONS,
    ColorRange,
    DetectorConfig,
    TargetSpec,
)
from eye_in_hand.core.triangulation import METHODS
from eye_in_hand.core.units import unit_hint
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.yamlfile import read_yaml_file

__all__ = [
    "ParamSpec",
    "MIN_PIXEL_SIGMA",
    "FALLBACK_PIXEL_SIGMA",
    "LOCATOR_PARAMETERS",
    "TARGET_PARAMETERS",
    "LocatorConfig",
    "locator_config_from_params",
    "load_parameter_file",
    "load_locator_config",
]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: flat dotted name, default, description and allowed range or choices.

    Attributes:
        name: flat name (``detector.open_px``); for per-target parameters the suffix after
            ``targets.<name>.``.
        default: the default value; its type is the parameter's type.
        description: one line for ``ros2 param describe`` and the README.
        min, max: inclusive range for numbers (None: unbounded).
        choices: allowed values for strings (empty: any).
    """

    name: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] = ()

    def check(self, value: Any, full_name: str | None = None) -> Any:
        """Validate and normalise a value; raises ConfigError naming the parameter."""
        name = full_name or self.name
        d = self.default
        try:
            if isinstance(d, bool):
                if not isinstance(value, bool):
                    raise TypeError
                out: Any = value
            elif isinstance(d, int):
                if isinstance(value, bool) or float(value) != int(value):
                    raise TypeError
                out = int(value)
            elif isinstance(d, float):
                if isinstance(value, bool):
                    raise TypeError
                out = float(value)
                if not math.isfinite(out):
                    raise TypeError
            elif isinstance(d, str):
                if not isinstance(value, str):
                    raise TypeError
                out = value
            elif isinstance(d, list):
                if isinstance(value, (str, bytes)):
                    raise TypeError
                out = list(value)
                proto = d[0] if d else None
                if isinstance(proto, int) and not all(
                        not isinstance(v, bool) and float(v) == int(v) for v in out):
                    raise TypeError
                if isinstance(proto, str) and not all(isinstance(v, str) for v in out):
                    raise TypeError
                out = [int(v) for v in out] if isinstance(proto, int) else out
            else:  # pragma: no cover - specs are ours
                out = value
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"parameter '{name}': expected a {type(d).__name__} like {d!r}, "
                              f"got {value!r}") from exc
        if self.choices and out not in self.choices:
            raise ConfigError(f"parameter '{name}': '{out}' is not one of "
                              f"{', '.join(self.choices)}")
        if isinstance(out, (int, float)) and not isinstance(out, bool):
            if (self.min is not None and out < self.min) or (self.max is not None
                                                              and out > self.max):
                raise ConfigError(f"parameter '{name}': {out} is outside "
                                  f"[{self.min}, {self.max}]"
                                  f"{unit_hint(name, out, self.max)}")
        return out


#: Smallest per-detection pixel sigma used (pixels): guards against a degenerate estimate.
MIN_PIXEL_SIGMA = 0.01
#: Pixel sigma of a detection without its own estimate (tiny blobs), pixels.
FALLBACK_PIXEL_SIGMA = 0.3

#: Locator and detector parameters (flat names), shared by the node and the CLI.
LOCATOR_PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("method", "dlt", "triangulation method: dlt (linear, P1/P2), disparity "
              "(parallax on rectified coordinates) or optimal (reprojection error in both "
              "distorted images)", choices=METHODS),
    ParamSpec("pixel_sigma", 0.0, "centre noise (pixels, 1 sigma) for the covariance; 0 = "
              "estimated per detection from the blob's edge roughness, shading and threshold "
              "cut",
              0.0, 20.0),
    ParamSpec("max_residual_px", 2.0, "reject a point whose RMS reprojection residual exceeds "
              "this (pixels)", 0.01, 100.0),
    ParamSpec("epipolar_tol_px", 3.0, "left/right association: largest difference of the "
              "rectified rows (pixels)", 0.1, 100.0),
    ParamSpec("min_depth_m", 0.05, "left/right association: nearest plausible depth (m); a "
              "pair whose disparity puts it nearer is rejected (depth_range)", 0.001, 1000.0),
    ParamSpec("max_depth_m", 100.0, "left/right association: farthest plausible depth (m); a "
              "pair whose disparity puts it farther is rejected (depth_range)", 0.001, 1e6),
    ParamSpec("size_tol", 1.0, "left/right association, spheres of known radius: the range "
              "from the blob's angular size and the triangulated range agree within a factor "
              "1 + size_tol, else the pair is rejected (size); 0 = off", 0.0, 100.0),
    ParamSpec("ambiguity_margin_px", 1.0, "left/right association: another assignment of the "
              "same number of pairs whose summed rectified row difference is within this of "
              "the best makes the pairs it changes ambiguous (rejected, counted)", 0.0, 100.0),
    ParamSpec("tracking.gate_m", 0.03, "blob sets: largest distance (m, left optical frame) "
              "between a blob and a known blob's last position for it to keep that id",
              1e-4, 10.0),
    ParamSpec("tracking.max_missed", 30, "blob sets: frames an unseen blob keeps its id "
              "reserved (and is reported as rejected); then the id is retired, never reused",
              0, 1000000),
    ParamSpec("target_names", ["red"], "targets, in priority order; the first is published "
              "on target/point; each has parameters targets.<name>.*"),
    ParamSpec("detector.downscale", 4, "factor of the coarse detection pass (1 = threshold "
              "whole images at full resolution)", 1, 16),
    ParamSpec("detector.open_px", 3, "morphological opening kernel (pixels, 0 = off)", 0, 51),
    ParamSpec("detector.close_px", 5, "morphological closing kernel (pixels, 0 = off)", 0, 51),
    ParamSpec("detector.selection", "largest", "blob selection: largest, circular, or nearest "
              "the previous detection", choices=SELECTIONS),
    ParamSpec("detector.max_candidates", 3, "blobs per target and image considered for the "
              "left/right association", 1, 20),
    ParamSpec("detector.roi_margin_px", 8, "margin around a coarse blob for the "
              "full-resolution pass (pixels)", 0, 200),
    ParamSpec("detector.sphere_correction", True, "correct sphere centroids for the "
              "perspective offset of the silhouette"),
    ParamSpec("detector.reject_border", True, "ignore blobs touching the image border "
              "(truncated silhouettes have biased centres)"),
)

#: Per-target parameters, each named ``targets.<name>.<suffix>``.
TARGET_PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("color_space", "hsv", "colour space of lower/upper: hsv or hsi",
              choices=COLOR_SPACES),
    ParamSpec("lower", [170, 120, 70], "lower bound [h, s, v] (h 0..179, s, v 0..255); "
              "h > upper h wraps around 0 (red)"),
    ParamSpec("upper", [10, 255, 255], "upper bound [h, s, v]"),
    ParamSpec("radius_m", 0.02, "sphere radius in metres (0 = unknown: the angular radius is "
              "estimated from the silhouette)", 0.0, 1.0),
    ParamSpec("is_sphere", True, "the target is a sphere (apply the sphere-centre correction)"),
    ParamSpec("min_area_px", 30.0, "smallest blob area (pixels)", 1.0, 1e8),
    ParamSpec("max_area_px", 0.0, "largest blob area (pixels, 0 = no limit)", 0.0, 1e8),
    ParamSpec("min_circularity", 0.6, "smallest 4 pi area / perimeter^2 (a pixelated disc "
              "measures about 0.9)", 0.0, 1.0),
    ParamSpec("count", 1, "blobs of this colour: 1 = one target (id = name); N > 1 = up to the "
              "N best blobs, a blob set with ids <name>_<k> stable across frames; 0 = every "
              "blob above min_area_px (a blob set)", 0, 200),
)

_LOC = {p.name: p for p in LOCATOR_PARAMETERS}
_TGT = {p.name: p for p in TARGET_PARAMETERS}


@dataclass(frozen=True)
class LocatorConfig:
    """Settings of :class:`StereoLocator`.

    Attributes:
        detector: the colour-detector settings (targets, morphology, selection).
        method: "dlt", "disparity" or "optimal".
        pixel_sigma: centre noise (pixels) for the covariance; 0 (default): each detection's
            own ``center_sigma_px`` (:mod:`eye_in_hand.core.detection`), at least
            ``MIN_PIXEL_SIGMA``; ``FALLBACK_PIXEL_SIGMA`` where a detection has none.
        max_residual_px: residual gate (pixels), None for none.
        epipolar_tol_px: largest rectified row difference of an associated pair (pixels).
        min_depth_m, max_depth_m: plausible depth range of an associated pair (metres): its
            disparity must lie between ``f B / max_depth_m`` and ``f B / min_depth_m``.
        size_tol: spheres of known radius: the range ``radius / sin(angular radius)`` from the
            blob's size and the triangulated range agree within a factor ``1 + size_tol``
            (0 = no check).
        ambiguity_margin_px: an alternative assignment with as many pairs whose summed row
            difference is within this (pixels) of the best makes the pairs it changes ambiguous.
        track_gate_m: blob sets: largest distance (metres) from a known blob's last position
            for a blob to keep that id.
        track_max_missed: blob sets: frames an unseen blob's id stays reserved.
    """

    detector: DetectorConfig
    method: str = "dlt"
    pixel_sigma: float = 0.0
    max_residual_px: float | None = 2.0
    epipolar_tol_px: float = 3.0
    min_depth_m: float = 0.05
    max_depth_m: float = 100.0
    size_tol: float = 1.0
    ambiguity_margin_px: float = 1.0
    track_gate_m: float = 0.03
    track_max_missed: int = 30

    @property
    def stateful(self) -> bool:
        """True when a locator's result depends on earlier frames (``selection: nearest`` or
        a blob set, whose ids are tracked): locate such a stream in order, with one locator."""
        return self.detector.selection == "nearest" or any(
            t.is_set for t in self.detector.targets)

    def __post_init__(self) -> None:
        if not isinstance(self.detector, DetectorConfig):
            raise InputError("detector: expected a DetectorConfig")
        if self.method not in METHODS:
            raise InputError(f"method: '{self.method}' is not one of {', '.join(METHODS)}")
        if not (math.isfinite(self.pixel_sigma) and self.pixel_sigma >= 0):
            raise InputError(f"pixel_sigma: must be >= 0 (0 = per detection), "
                             f"got {self.pixel_sigma}")
        if self.max_residual_px is not None and not self.max_residual_px > 0:
            raise InputError(f"max_residual_px: must be > 0, got {self.max_residual_px}")
        if not self.epipolar_tol_px > 0:
            raise InputError(f"epipolar_tol_px: must be > 0, got {self.epipolar_tol_px}")
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise InputError(f"min_depth_m, max_depth_m: need 0 < min < max, got "
                             f"{self.min_depth_m}, {self.max_depth_m}")
        for key in ("size_tol", "ambiguity_margin_px"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{key}: must be >= 0, got {v}")
        if not self.track_gate_m > 0:
            raise InputError(f"tracking.gate_m: must be > 0, got {self.track_gate_m}")
        if not self.track_max_missed >= 0:
            raise InputError(f"tracking.max_missed: must be >= 0, got {self.track_max_missed}")


def locator_config_from_params(params: Mapping[str, Any]) -> LocatorConfig:
    """Build a :class:`LocatorConfig` from flat dotted parameters (missing ones default).

    Args:
        params: e.g. ``{"method": "optimal", "target_names": ["red"],
            "targets.red.lower": [170, 120, 70], ...}``. Keys that are not locator or target
            parameters are ignored (the node has its own).

    Raises:
        ConfigError: a value has the wrong type or range, or a target setting is inconsistent;
            the message names the parameter.
    """
    def get(name: str) -> Any:
        spec = _LOC[name]
        return spec.check(params[name]) if name in params else spec.default

    names = get("target_names")
    if not names:
        raise ConfigError("parameter 'target_names': at least one target is needed")
    targets = []
    for tname in names:
        def tget(suffix: str, _t: str = tname) -> Any:
            key = f"targets.{_t}.{suffix}"
            spec = _TGT[suffix]
            return spec.check(params[key], key) if key in params else spec.default
        try:
            color = ColorRange(tuple(tget("lower")), tuple(tget("upper")), tget("color_space"))
        except InputError as exc:
            raise ConfigError(f"parameters 'targets.{tname}.lower/upper': {exc}") from exc
        radius = tget("radius_m")
        max_area = tget("max_area_px")
        try:
            targets.append(TargetSpec(
                name=tname, color=color, radius_m=radius if radius > 0 else None,
                min_area_px=tget("min_area_px"), max_area_px=max_area if max_area > 0 else None,
                min_circularity=tget("min_circularity"), is_sphere=tget("is_sphere"),
                count=tget("count")))
        except InputError as exc:
            raise ConfigError(f"parameters 'targets.{tname}.*': {exc}") from exc
    try:
        detector = DetectorConfig(
            targets=tuple(targets), downscale=get("detector.downscale"),
            open_px=get("detector.open_px"), close_px=get("detector.close_px"),
            selection=get("detector.selection"), max_candidates=get("detector.max_candidates"),
            roi_margin_px=get("detector.roi_margin_px"),
            sphere_correction=get("detector.sphere_correction"),
            reject_border=get("detector.reject_border"))
        return LocatorConfig(detector=detector, method=get("method"),
                             pixel_sigma=get("pixel_sigma"),
                             max_residual_px=get("max_residual_px"),
                             epipolar_tol_px=get("epipolar_tol_px"),
                             min_depth_m=get("min_depth_m"), max_depth_m=get("max_depth_m"),
                             size_tol=get("size_tol"),
                             ambiguity_margin_px=get("ambiguity_margin_px"),
                             track_gate_m=get("tracking.gate_m"),
                             track_max_missed=get("tracking.max_missed"))
    except InputError as exc:
        raise ConfigError(f"parameters: {exc}") from exc


def _flatten(node: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for key, value in node.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            _flatten(value, f"{name}.", out)
        else:
            out[name] = value


def load_parameter_file(path: str | os.PathLike[str],
                        node_name: str = "detect_triangulate") -> dict[str, Any]:
    """Read a ROS 2 parameter file and return the node's parameters, flattened.

    Accepts ``<node_name>: {ros__parameters: ...}`` (optionally with a namespace prefix such
    as ``/ns/detect_triangulate``) or the wildcard ``/**: {ros__parameters: ...}``; entries for
    the node override the wildcard. Nested mappings become dotted names.

    Raises:
        ConfigError: missing or unreadable file, not YAML, or no parameters for the node.
    """
    p = Path(path)
    data = read_yaml_file(p, "parameter file")
    if not isinstance(data, Mapping):
        raise ConfigError(f"{p}: expected a mapping of node names to ros__parameters")
    out: dict[str, Any] = {}
    found = False
    keys = sorted(data, key=lambda k: 0 if str(k) in ("/**", "**") else 1)  # wildcard first
    for key in keys:
        k = str(key)
        if k not in ("/**", "**") and k.rstrip("/").split("/")[-1] != node_name:
            continue
        body = data[key]
        if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"), Mapping):
            raise ConfigError(f"{p}: '{k}' must contain a 'ros__parameters' mapping")
        _flatten(body["ros__parameters"], "", out)
        found = True
    if not found:
        raise ConfigError(f"{p}: no parameters for node '{node_name}' (expected a "
                          f"'{node_name}:' or '/**:' entry with ros__parameters)")
    return out


def load_locator_config(path: str | os.PathLike[str] | None = None,
                        node_name: str = "detect_triangulate") -> LocatorConfig:
    """The locator settings from a node parameter file (None: the built-in defaults)."""
    params = {} if path is None else load_parameter_file(path, node_name)
    return locator_config_from_params(params)
