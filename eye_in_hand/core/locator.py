"""``StereoLocator``: one stereo pair in, target points in the left optical frame out.

The public API shared by the ``detect_triangulate`` node, ``eye-in-hand locate`` and users::

    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator import StereoLocator, load_locator_config

    rig = StereoRig.load("calib/")                      # ROS left.yaml + right.yaml work as-is
    locator = StereoLocator(rig, load_locator_config("config/detect_triangulate.yaml"))
    result = locator.locate(left_bgr, right_bgr)
    if result.first is not None:
        print(result.first.point_m, result.first.covariance)

Per target: colour detection in both images (:mod:`eye_in_hand.core.detection`), left/right
association by the epipolar constraint (rectified rows agree within ``epipolar_tol_px``, the
disparity is positive), triangulation (:mod:`eye_in_hand.core.triangulation`), and for a sphere
of known radius one refinement of the sphere-centre correction with the angular radius
``asin(radius / range)`` from the triangulated range, then a second triangulation.

Parameters: :data:`LOCATOR_PARAMETERS` and :data:`TARGET_PARAMETERS` describe every setting
(name, default, description, range) once; the node declares them as ROS parameters and the CLI
reads the same names from the node's parameter file (:func:`load_parameter_file`).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.detection import (
    COLOR_SPACES,
    SELECTIONS,
    ColorDetector,
    ColorRange,
    Detection,
    DetectorConfig,
    TargetSpec,
    sphere_center_direction,
)
from eye_in_hand.core.triangulation import (
    METHODS,
    Rejected,
    StereoPoint,
    triangulate_dlt,
    triangulate_optimal,
    triangulate_parallax,
)
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.yamlfile import read_yaml_file

__all__ = [
    "ParamSpec",
    "LOCATOR_PARAMETERS",
    "TARGET_PARAMETERS",
    "LocatorConfig",
    "TargetLocation",
    "LocateResult",
    "StereoLocator",
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
                                  f"[{self.min}, {self.max}]")
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
              "estimated per detection from the blob's edge roughness and shading",
              0.0, 20.0),
    ParamSpec("max_residual_px", 2.0, "reject a point whose RMS reprojection residual exceeds "
              "this (pixels)", 0.01, 100.0),
    ParamSpec("epipolar_tol_px", 3.0, "left/right association: largest difference of the "
              "rectified rows (pixels)", 0.1, 100.0),
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
              "estimated from the silhouette)", 0.0, 10.0),
    ParamSpec("is_sphere", True, "the target is a sphere (apply the sphere-centre correction)"),
    ParamSpec("min_area_px", 30.0, "smallest blob area (pixels)", 1.0, 1e8),
    ParamSpec("max_area_px", 0.0, "largest blob area (pixels, 0 = no limit)", 0.0, 1e8),
    ParamSpec("min_circularity", 0.6, "smallest 4 pi area / perimeter^2 (a pixelated disc "
              "measures about 0.9)", 0.0, 1.0),
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
    """

    detector: DetectorConfig
    method: str = "dlt"
    pixel_sigma: float = 0.0
    max_residual_px: float | None = 2.0
    epipolar_tol_px: float = 3.0

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
                min_circularity=tget("min_circularity"), is_sphere=tget("is_sphere")))
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
                             epipolar_tol_px=get("epipolar_tol_px"))
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


@dataclass(frozen=True, eq=False)
class TargetLocation:
    """One located target.

    Attributes:
        name: target name.
        point_m: shape (3,), metres, left optical frame.
        covariance: shape (3, 3), m^2, left optical frame.
        residual_px: RMS reprojection residual (pixels).
        left_px, right_px: the (sphere-corrected) centre in each distorted image, shape (2,).
        left_centroid_px, right_centroid_px: the raw blob centroids, shape (2,).
        method: triangulation method used.
        disparity_px: rectified disparity.
        left, right: the two detections.
        id: the target's id, stable across frames: the name for a target of one blob; the
            blob sets of one colour give ``<name>_<k>``. Empty on construction = ``name``.
    """

    name: str
    point_m: np.ndarray
    covariance: np.ndarray
    residual_px: float
    left_px: np.ndarray
    right_px: np.ndarray
    left_centroid_px: np.ndarray
    right_centroid_px: np.ndarray
    method: str
    disparity_px: float
    left: Detection = field(repr=False)
    right: Detection = field(repr=False)
    id: str = ""

    def __post_init__(self) -> None:
        if not self.id:
            object.__setattr__(self, "id", self.name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with exactly ``point_m``, ``covariance``, ``residual_px``,
        ``left_px`` and ``right_px`` (the output of ``eye-in-hand locate --json``)."""
        return {
            "point_m": [float(v) for v in self.point_m],
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "residual_px": float(self.residual_px),
            "left_px": [float(v) for v in self.left_px],
            "right_px": [float(v) for v in self.right_px],
        }


@dataclass(frozen=True, eq=False)
class LocateResult:
    """The outcome for one stereo pair.

    Attributes:
        targets: located targets, in configuration order (only those found).
        rejected: target name -> reason for every target not located: ``not_detected_left``,
            ``not_detected_right``, ``not_detected``, ``epipolar`` (no candidate pair on the
            same rectified row), or a triangulation reason (``behind_camera``,
            ``non_positive_disparity``, ``residual_gate``, ``not_converged``).
        messages: target name -> a readable explanation of the rejection.
        first_name: the name of the first configured target (the one on ``target/point``).
    """

    targets: tuple[TargetLocation, ...]
    rejected: dict[str, str]
    messages: dict[str, str] = field(default_factory=dict)
    first_name: str = ""

    @property
    def first(self) -> TargetLocation | None:
        """The first configured target (``first_name``) when it was located, else None."""
        return self.get(self.first_name)

    def get(self, name: str) -> TargetLocation | None:
        """The located target whose id is ``name``, else the first one called ``name``, or
        None."""
        for t in self.targets:
            if t.id == name:
                return t
        for t in self.targets:
            if t.name == name:
                return t
        return None


class StereoLocator:
    """Detect and triangulate the configured targets in stereo pairs.

    Args:
        rig: the stereo rig; rectified here (alpha 0) if it is not yet.
        config: locator settings (:func:`load_locator_config` gives the node's defaults).

    The locator is stateful only for ``selection="nearest"`` (it remembers each target's last
    centres); :meth:`reset` forgets them. Use one locator per stream.
    """

    def __init__(self, rig: StereoRig, config: LocatorConfig) -> None:
        if not isinstance(rig, StereoRig):
            raise InputError("rig: expected a StereoRig")
        if not isinstance(config, LocatorConfig):
            raise InputError("config: expected a LocatorConfig")
        if rig.left.size != rig.right.size:
            raise InputError(f"rig: left and right image sizes differ ({rig.left.size} vs "
                             f"{rig.right.size})")
        self.rig = rig if rig.is_rectified else rig.rectified()
        self.config = config
        self.detector = ColorDetector(config.detector)
        P2 = self.rig.P2
        self._vertical = abs(P2[1, 3]) > abs(P2[0, 3])
        if self._vertical and config.method == "disparity":
            raise InputError("method 'disparity' needs a horizontally rectified rig; this one "
                             "is vertical: use 'dlt' or 'optimal'")
        # normalised -> rectified pixels: H = P[:, :3] @ R
        self._H1 = self.rig.P1[:, :3] @ self.rig.R1
        self._H2 = self.rig.P2[:, :3] @ self.rig.R2
        self._previous: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def reset(self) -> None:
        """Forget the previous detections (``selection="nearest"``)."""
        self._previous.clear()

    def locate(self, left: np.ndarray, right: np.ndarray) -> LocateResult:
        """Locate every configured target in one stereo pair.

        Args:
            left, right: BGR uint8 images, shape (H, W, 3), matching the rig's image size.

        Returns:
            The located targets and the reasons for those not located (never a guess).

        Raises:
            InputError: an image has the wrong type, channels or size.
        """
        cfg = self.config
        prev_l = {k: v[0] for k, v in self._previous.items()}
        prev_r = {k: v[1] for k, v in self._previous.items()}
        cands_l = self.detector.candidates(left, self.rig.left, prev_l)
        cands_r = self.detector.candidates(right, self.rig.right, prev_r)
        found: list[TargetLocation] = []
        rejected: dict[str, str] = {}
        messages: dict[str, str] = {}
        for spec in cfg.detector.targets:
            cl, cr = cands_l[spec.name], cands_r[spec.name]
            if not cl or not cr:
                reason = ("not_detected" if not cl and not cr else
                          "not_detected_left" if not cl else "not_detected_right")
                rejected[spec.name] = reason
                messages[spec.name] = f"target '{spec.name}': {reason.replace('_', ' ')}"
                continue
            loc, reason, message = self._associate(spec, cl, cr)
            if loc is None:
                rejected[spec.name] = reason
                messages[spec.name] = f"target '{spec.name}': {message}"
                continue
            found.append(loc)
            self._previous[spec.name] = (loc.left_px, loc.right_px)
        return LocateResult(tuple(found), rejected, messages, cfg.detector.targets[0].name)

    # -- internals -------------------------------------------------------------------------
    def _rect(self, H: np.ndarray, norm: np.ndarray) -> np.ndarray:
        h = H @ np.array([norm[0], norm[1], 1.0])
        return h[:2] / h[2]

    def _associate(self, spec: TargetSpec, cl: Sequence[Detection], cr: Sequence[Detection]
                   ) -> tuple[TargetLocation | None, str, str]:
        tol = self.config.epipolar_tol_px
        axis = 0 if self._vertical else 1
        pairs = sorted(((i, j) for i in range(len(cl)) for j in range(len(cr))),
                       key=lambda ij: (ij[0] + ij[1], ij[0]))
        first_reason, first_msg = "", ""
        for i, j in pairs:
            dl, dr = cl[i], cr[j]
            xl, xr = self._rect(self._H1, dl.center_norm), self._rect(self._H2, dr.center_norm)
            gap = abs(xl[axis] - xr[axis])
            if gap > tol:
                if not first_reason:
                    first_reason = "epipolar"
                    first_msg = (f"best left/right candidates are {gap:.2f} px apart across the "
                                 f"epipolar line (tolerance {tol:.2f} px)")
                continue
            try:
                return self._triangulate(spec, dl, dr, xl, xr), "", ""
            except Rejected as exc:
                if not first_reason or first_reason == "epipolar":
                    first_reason, first_msg = exc.reason, str(exc)
        return None, first_reason, first_msg

    def _pixel_cov(self, dl: Detection, dr: Detection) -> tuple[float, np.ndarray | None]:
        """``(sigma_px, pixel_cov)`` of a pair: the configured pixel sigma (``pixel_cov`` None),
        else the detections' own, (4, 4) over (xl, yl, xr, yr): each image's edge term plus
        the shading shifts ``shade_px``, fully correlated between the two images (one light)."""
        if self.config.pixel_sigma > 0:
            return self.config.pixel_sigma, None
        if not (math.isfinite(dl.edge_sigma_px) and math.isfinite(dr.edge_sigma_px)):
            return FALLBACK_PIXEL_SIGMA, None
        e = [max(MIN_PIXEL_SIGMA, d.edge_sigma_px) ** 2 for d in (dl, dr)]
        v = np.concatenate([dl.shade_px, dr.shade_px])
        return 0.0, np.diag([e[0], e[0], e[1], e[1]]) + np.outer(v, v)

    def _point(self, left_px: np.ndarray, right_px: np.ndarray, xl: np.ndarray,
               xr: np.ndarray, pix: tuple[float, np.ndarray | None] = (FALLBACK_PIXEL_SIGMA, None)
               ) -> StereoPoint:
        cfg = self.config
        gate = cfg.max_residual_px
        kw: dict = ({"sigma_px": pix[0]} if pix[1] is None else {"pixel_cov": pix[1]})
        if cfg.method == "dlt":
            return triangulate_dlt(self.rig, xl, xr, rectified=True, max_residual_px=gate, **kw)
        if cfg.method == "disparity":
            return triangulate_parallax(self.rig, xl, xr, rectified=True, max_residual_px=gate,
                                        **kw)
        start = triangulate_dlt(self.rig, xl, xr, rectified=True, **kw)
        return triangulate_optimal(self.rig, left_px, right_px, initial=start,
                                   max_residual_px=gate, **kw)

    def _triangulate(self, spec: TargetSpec, dl: Detection, dr: Detection, xl: np.ndarray,
                     xr: np.ndarray) -> TargetLocation:
        pix = self._pixel_cov(dl, dr)
        pt = self._point(dl.center_px, dr.center_px, xl, xr, pix)
        left_px, right_px = dl.center_px, dr.center_px
        if spec.radius_m is not None and np.all(np.isfinite(dl.ellipse_norm)) \
                and np.all(np.isfinite(dr.ellipse_norm)):
            # refine the sphere-centre correction with alpha from the known radius and range
            rng_l = float(np.linalg.norm(pt.point))
            rng_r = float(np.linalg.norm(self.rig.R @ pt.point + self.rig.T))
            if rng_l > spec.radius_m and rng_r > spec.radius_m:
                nl = sphere_center_direction(dl.ellipse_norm, math.asin(spec.radius_m / rng_l))
                nr = sphere_center_direction(dr.ellipse_norm, math.asin(spec.radius_m / rng_r))
                left_px = self.rig.left.project(np.array([[nl[0], nl[1], 1.0]]))[0]
                right_px = self.rig.right.project(np.array([[nr[0], nr[1], 1.0]]))[0]
                pt = self._point(left_px, right_px, self._rect(self._H1, nl),
                                 self._rect(self._H2, nr), pix)
        return TargetLocation(
            name=spec.name, point_m=pt.point, covariance=pt.covariance,
            residual_px=pt.residual_px, left_px=np.asarray(left_px, dtype=np.float64),
            right_px=np.asarray(right_px, dtype=np.float64),
            left_centroid_px=dl.centroid_px, right_centroid_px=dr.centroid_px,
            method=pt.method, disparity_px=pt.disparity_px, left=dl, right=dr)
