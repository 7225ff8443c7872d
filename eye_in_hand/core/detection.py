"""Colour-target detection: HSV/HSI threshold, morphology, blob selection, sub-pixel centre.

Pipeline per image (the hot path: the only pass over every pixel is the downscale of step 1;
everything after it works on a blob's region of interest, its contour or its image moments.
A 1280x720 pair with one target costs about 0.7 of the cvtColor + inRange floor on the two
full images, with four targets 1.4 times it; docs/detection.md#figures):

1. A coarse pass on a ``downscale``-times smaller copy (nearest-neighbour, no float images):
   colour conversion, threshold (:meth:`ColorRange.threshold_planes`), external contours.
   Blobs big enough to be a target become candidates.
2. A full-resolution pass inside a region of interest around each candidate: threshold,
   morphological open/close, the largest connected component, its area and circularity gates,
   and its image moments (sub-pixel centroid). Then the centre-uncertainty terms below, for
   all of the image's blobs together (:func:`_measure_blobs`: one pass of NumPy calls over
   their contours and profiles, the sums blob by blob, so each blob's numbers are its own to
   the last bit).
3. With a camera model, the sphere-centre correction: the silhouette of a sphere is the conic of
   its tangent cone. In undistorted normalised coordinates it is an ellipse whose centre lies
   farther from the principal point than the image of the sphere's centre. With ``m`` the
   radial distance of the ellipse centre, ``theta`` the field angle of the sphere's centre and
   ``alpha`` its angular radius, ``m = sin(2 theta) / (cos(2 theta) + cos(2 alpha))``, solved
   in closed form for ``theta`` (:func:`sphere_center_direction`). ``alpha`` comes from the
   ellipse's minor axis (:func:`angular_radius_from_minor_axis`) or, better, from the known
   radius and the triangulated range (done by :class:`eye_in_hand.core.locator.StereoLocator`).
   The ellipse centre is measured as the area centroid of the undistorted contour, so lens
   distortion does not bias it either.

Colour ranges use OpenCV's 8-bit conventions: hue 0..179 (degrees / 2), saturation and value
0..255. A range whose lower hue exceeds its upper hue wraps around 0 (red: ``170..10``). HSI
(hue, saturation ``1 - min/mean``, intensity ``mean``) uses the same scales.

Per-detection centre uncertainty (``Detection.center_sigma_px``, 1 sigma per image axis),
``sqrt(sigma_edge^2 + sigma_shade^2 + sigma_cut^2)``, the first two estimated from the blob:

* ``sigma_edge``: the roughness of the blob's edge. An ellipse is fitted to the outer contour;
  the radial residuals' RMS ``s`` (pixel quantisation, image noise, blur) and their correlation
  along the contour (integrated autocorrelation ``tau``) give the centre's uncertainty as that of
  a fit to ``N / tau`` independent edge points: ``s * sqrt(2 tau / N)``.
* ``sigma_shade``: the threshold cuts a shaded sphere's dark side further in than its lit side,
  shifting the centroid towards the light. The shift scales with the brightness asymmetry of
  the blob: ``SHADE_GAIN * |g|``, ``g`` the offset (px) of the brightness-weighted centroid from
  the area centroid; it lies along ``g`` (``Detection.shade_px``, a rank-one covariance), and
  the stereo locator treats it as common to both images (the same light). ``SHADE_GAIN`` =
  0.015 was measured on the simulator's renders (least squares of the centre error on ``g``:
  0.015 on both axes; median ``|error| / |g|`` 0.016, 90th percentile 0.020; 48 stereo views
  at 1280x720, 0.3-0.6 m, one orbit).
* ``sigma_cut``: the threshold cut (``CUT_SIGMA_PX`` = 0.02 px per axis, a stated floor; the
  blob does not show it). An anti-aliased edge pixel is kept or dropped by the mix of target
  and background colour in it, so the cut runs a fraction of a pixel inside or outside the true
  outline by an amount that changes with the background (and the light) along the edge. A
  difference between two sides moves the centroid; a shift of the whole outline is one of the
  ellipse's own parameters, so the edge residuals cannot see it. The same background lies
  behind the target in both images: the shift is nearly the same in both, and the stereo
  locator treats it as common to the pair (``Detection.cut_sigma_px``), which moves the point
  sideways, not in depth. Measured on the simulator's renders (1280x720, noise 1, no blur;
  ``benchmarks/bench_point_cov.py``): against the exact anti-aliased coverage centroid (flat
  light, 25 views), the binary centroid's error common to the two images (``E[e_l e_r]``) is
  0.010 px in x and 0.027 px in y, 0.020 px RMS over the axes; on the benchmark orbit (90
  shaded views) the common error beyond the shading term is 0.035 px in y and none in x (the
  shading term exceeds it there), 0.019 px RMS over the axes. The coverage centroid is within
  0.004 px of the true silhouette centroid and the sphere-centre correction adds about
  0.004 px: the cut is the error. Without this term the camera-frame point's sideways sigma
  was about half its sideways error across the shading direction (lateral NEES 5.9 for 2 dof
  on the benchmark orbit, 2.8 with it).

Blur (optics, focus, motion) widens the edge, and both the shading and the threshold-cut shifts
grow with it: the threshold picks a level set of the blurred image, which moves with the local
contrast and curvature of the brightness by about ``blur^2``. The detector measures the blur per
blob (``Detection.blur_px``): :func:`edge_width` reads 64 colour profiles across the contour
(about 0.08 ms per blob), ``w`` their Gaussian-equivalent width, and the blur is
``b = sqrt(max(w^2 - BLUR_W0_PX^2, 0))``. ``BLUR_W0_PX`` = 0.65 px is ``w`` on unblurred
renders (0.646 px mean on the benchmark orbit, 0.583 on test_nees's; the pixel footprint, the
sensor noise of 1 grey level); with a Gaussian blur of 0.5 / 1.0 px ``b`` reads 0.48 / 1.11 px
(benchmark orbit) and 0.36 / 1.04 px (test_nees orbit). The two shared terms then become

* shading: ``SHADE_GAIN * (1 + SHADE_BLUR_GAIN b^2) * g``, ``SHADE_BLUR_GAIN`` = 2.3 per px^2:
  the least squares of the left/right-mean centre error on ``g`` over both orbits at blur 0,
  0.5 and 1 px (60 + 25 views each) with that law (2.28); per blur, the fitted gain over
  ``SHADE_GAIN`` is 1.06 / 1.75 / 3.95 (benchmark orbit, blur 0 / 0.5 / 1) and 0.73 / 1.27 /
  3.06 (test_nees orbit). It also carries the left-minus-right part along x that the depth
  sees (``SHADE_GAIN * (g_l - g_r)``: 0.023 px unblurred, the left-minus-right x error 0.080 px
  at 1 px blur);
* threshold cut: ``CUT_SIGMA_PX * (1 + CUT_BLUR_GAIN b)``, ``CUT_BLUR_GAIN`` = 2.0 per px: the
  left/right-mean error left after that shading term, less the edge terms' share, is 1.95 /
  3.57 times ``CUT_SIGMA_PX`` at blur 0.5 / 1 on the benchmark orbit (2.0 and 2.3 per px of
  ``b``) and 1.0 / 2.6 times on test_nees's (0 and 1.5 per px).

Unblurred, ``b`` reads 0-0.3 px (mean 0.03 px on the benchmark orbit, 0 on test_nees's): the
cut term grows by about 7 % on average, by up to 58 % in single views. The laws
are fitted to the simulator's Gaussian blur of a red sphere on its backgrounds with sensor
noise 1; ``BLUR_W0_PX`` depends on the noise and the pixel (a noisier camera reads a wider
``w`` without blur), so on a real camera it should be re-measured on its sharpest images.

A detector returns detections or nothing, never a guess: blobs that fail a gate or touch the
image border (a truncated silhouette has a biased centre) are not reported.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from eye_in_hand.core.camera import CameraModel
from eye_in_hand.errors import DetectionError, InputError

__all__ = [
    "COLOR_SPACES",
    "SELECTIONS",
    "ColorRange",
    "ColorPlanes",
    "TargetSpec",
    "DetectorConfig",
    "Detection",
    "ColorDetector",
    "bgr_to_hsi",
    "convert_color",
    "sphere_center_direction",
    "sphere_silhouette_center",
    "angular_radius_from_minor_axis",
    "range_from_samples",
]

#: Centroid shift per pixel of brightness asymmetry of the blob (see the module docstring).
SHADE_GAIN = 0.015
#: Threshold-cut term (px, 1 sigma per image axis, common to both images of a stereo pair; see
#: the module docstring).
CUT_SIGMA_PX = 0.02
#: Edge width (px) that :func:`edge_width` measures on an unblurred render; the blur estimate
#: is ``sqrt(max(w^2 - BLUR_W0_PX^2, 0))`` (see the module docstring).
BLUR_W0_PX = 0.65
#: Growth of the shading gain with the blur ``b``: ``SHADE_GAIN * (1 + SHADE_BLUR_GAIN b^2)``.
SHADE_BLUR_GAIN = 2.3
#: Growth of the threshold-cut term with the blur ``b``: ``CUT_SIGMA_PX (1 + CUT_BLUR_GAIN b)``.
CUT_BLUR_GAIN = 2.0
#: Half-length (px) of :func:`edge_width`'s profiles across the edge, and their number.
_EDGE_BAND_PX = 4
_EDGE_PROFILES = 64

#: Supported colour spaces for thresholds.
COLOR_SPACES = ("hsv", "hsi")
#: Blob selection rules: biggest area, most circular, or nearest the previous detection.
SELECTIONS = ("largest", "circular", "nearest")

_MAX = (179, 255, 255)

#: Most blobs one target considers per image (``count: 0`` = every blob, up to this many).
MAX_BLOBS = 200


def bgr_to_hsi(image: np.ndarray) -> np.ndarray:
    """Convert a BGR uint8 image to HSI on OpenCV's 8-bit scales.

    H is the geometric HSI hue ``atan2(sqrt(3) (G - B), 2R - G - B)`` in degrees / 2 (0..179),
    S = ``1 - min(R, G, B) / I`` scaled to 0..255, I = ``(R + G + B) / 3`` (0..255).

    Args:
        image: shape (H, W, 3), uint8, BGR.

    Returns:
        shape (H, W, 3), uint8.
    """
    f = image.astype(np.float32)
    b, g, r = f[..., 0], f[..., 1], f[..., 2]
    total = b + g + r
    intensity = total / 3.0
    mn = np.minimum(np.minimum(b, g), r)
    sat = np.where(total > 0, 1.0 - 3.0 * mn / np.maximum(total, 1e-6), 0.0)
    hue = np.degrees(np.arctan2(math.sqrt(3.0) * (g - b), 2.0 * r - g - b))
    hue = np.mod(hue, 360.0) / 2.0
    out = np.empty(image.shape, dtype=np.uint8)
    out[..., 0] = np.minimum(np.rint(hue), 179.0).astype(np.uint8) % 180
    out[..., 1] = np.clip(np.rint(sat * 255.0), 0, 255).astype(np.uint8)
    out[..., 2] = np.clip(np.rint(intensity), 0, 255).astype(np.uint8)
    return out


def convert_color(image: np.ndarray, space: str) -> np.ndarray:
    """BGR uint8 (H, W, 3) to ``space`` ("hsv" with OpenCV's BGR2HSV, or "hsi"), uint8."""
    if space == "hsv":
        return cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    if space == "hsi":
        return bgr_to_hsi(image)
    raise DetectionError(f"color space '{space}' is not supported ({', '.join(COLOR_SPACES)})")


def _triple(value: Any, name: str) -> tuple[int, int, int]:
    try:
        vals = [float(v) for v in value]
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected three numbers, got {value!r}") from exc
    if len(vals) != 3 or not all(math.isfinite(v) and v == int(v) for v in vals):
        raise InputError(f"{name}: expected three integers, got {value!r}")
    out = tuple(int(v) for v in vals)
    for i, (v, hi) in enumerate(zip(out, _MAX, strict=True)):
        if not 0 <= v <= hi:
            raise InputError(f"{name}[{i}]: {v} is outside 0..{hi}")
    return out  # type: ignore[return-value]


class ColorPlanes:
    """A converted uint8 image's three planes and the masks of bounds on them, each made once
    (:meth:`ColorRange.threshold_planes`).

    Args:
        converted: the image in a colour space, uint8, shape (H, W, 3).
    """

    def __init__(self, converted: np.ndarray) -> None:
        self._planes = cv2.split(converted)
        self._masks: dict[tuple[int, int, int], np.ndarray] = {}

    def at_least(self, channel: int, value: int) -> np.ndarray:
        """0/255 mask of ``plane >= value`` (1 <= value <= 255); shared: do not modify it."""
        return self._bound(channel, value - 1, cv2.THRESH_BINARY)

    def at_most(self, channel: int, value: int) -> np.ndarray:
        """0/255 mask of ``plane <= value`` (0 <= value <= 254); shared: do not modify it."""
        return self._bound(channel, value, cv2.THRESH_BINARY_INV)

    def _bound(self, channel: int, thresh: int, kind: int) -> np.ndarray:
        key = (channel, thresh, kind)
        mask = self._masks.get(key)
        if mask is None:
            # uint8 threshold: > thresh (BINARY) or <= thresh (BINARY_INV), exact integers
            mask = self._masks[key] = cv2.threshold(self._planes[channel], thresh, 255, kind)[1]
        return mask


@dataclass(frozen=True)
class ColorRange:
    """A box in HSV or HSI (OpenCV 8-bit scales), hue wrapping when ``lower[0] > upper[0]``.

    Attributes:
        lower: (h, s, v) lower bounds, inclusive; h in 0..179, s and v in 0..255.
        upper: (h, s, v) upper bounds, inclusive.
        space: "hsv" or "hsi".
    """

    lower: tuple[int, int, int]
    upper: tuple[int, int, int]
    space: str = "hsv"

    def __post_init__(self) -> None:
        if self.space not in COLOR_SPACES:
            raise InputError(f"space: '{self.space}' is not one of {', '.join(COLOR_SPACES)}")
        lo, hi = _triple(self.lower, "lower"), _triple(self.upper, "upper")
        for i in (1, 2):
            if lo[i] > hi[i]:
                raise InputError(f"lower[{i}] = {lo[i]} exceeds upper[{i}] = {hi[i]}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @property
    def wraps(self) -> bool:
        """True when the hue range wraps around 0 (e.g. red, 170..10)."""
        return self.lower[0] > self.upper[0]

    def threshold(self, converted: np.ndarray) -> np.ndarray:
        """Binary mask (uint8 0/255, shape (H, W)) of the pixels inside the range.

        Args:
            converted: an image already in this range's colour space, uint8 (H, W, 3).
        """
        if not self.wraps:
            return cv2.inRange(converted, self.lower, self.upper)
        lo, hi = self.lower, self.upper
        a = cv2.inRange(converted, (lo[0], lo[1], lo[2]), (179, hi[1], hi[2]))
        b = cv2.inRange(converted, (0, lo[1], lo[2]), (hi[0], hi[1], hi[2]))
        return cv2.bitwise_or(a, b, dst=a)

    def threshold_planes(self, planes: ColorPlanes) -> np.ndarray:
        """The mask of :meth:`threshold`, from one-sided bounds on single planes.

        Each bound is one ``cv2.threshold`` pass over one plane, made once per image in
        ``planes`` (targets with the same saturation and value bounds share them), and the
        bounds are ANDed: on a coarse image with three targets about a third of the time of a
        three-channel ``cv2.inRange`` each (two for a wrapping hue). The same mask as
        :meth:`threshold`, pixel for pixel, for any uint8 image (hue values above 179
        included).

        Args:
            planes: the image, already in this range's colour space, split into its planes.
        """
        lo, hi = self.lower, self.upper
        masks: list[np.ndarray] = []
        if self.wraps:
            # [lo, 179] or [0, hi]
            upper = cv2.bitwise_and(planes.at_least(0, lo[0]), planes.at_most(0, _MAX[0]))
            masks.append(cv2.bitwise_or(upper, planes.at_most(0, hi[0]), dst=upper))
        for c in range(3):
            if c > 0 or not self.wraps:
                if lo[c] > 0:
                    masks.append(planes.at_least(c, lo[c]))
                if hi[c] < 255:        # (the uint8 maximum: no bound)
                    masks.append(planes.at_most(c, hi[c]))
        # (never empty: the upper hue bound is at most 179)
        out = cv2.bitwise_and(masks[0], masks[1]) if len(masks) > 1 else masks[0].copy()
        for m in masks[2:]:
            cv2.bitwise_and(out, m, dst=out)
        return out

    def contains(self, hsv: Sequence[float]) -> bool:
        """Whether one (h, s, v) triple lies inside the range."""
        h, s, v = hsv
        in_h = (self.lower[0] <= h or h <= self.upper[0]) if self.wraps else \
            self.lower[0] <= h <= self.upper[0]
        return bool(in_h and self.lower[1] <= s <= self.upper[1]
                    and self.lower[2] <= v <= self.upper[2])


@dataclass(frozen=True)
class TargetSpec:
    """One target to find.

    Attributes:
        name: identifies the target in results and topics (a letter, then ``[A-Za-z0-9_]``).
        color: its colour range.
        radius_m: sphere radius in metres, or None for a flat or unknown target (then the
            sphere-centre correction estimates the angular radius from the silhouette).
        min_area_px: smallest accepted blob area at full resolution (pixels).
        max_area_px: largest accepted blob area (pixels), or None for no limit.
        min_circularity: smallest accepted ``4 pi area / perimeter^2`` (1 for a disc; a
            pixelated disc measures about 0.85-0.9).
        is_sphere: apply the sphere-centre correction (False for a flat disc facing the camera).
        count: how many blobs of this colour to locate: 1 (default) = one target whose id is
            its name; N > 1 = up to the N best blobs (a blob set, ids ``<name>_<k>``); 0 = every
            blob above ``min_area_px`` (a blob set of any size).
    """

    name: str
    color: ColorRange
    radius_m: float | None = None
    min_area_px: float = 30.0
    max_area_px: float | None = None
    min_circularity: float = 0.6
    is_sphere: bool = True
    count: int = 1

    @property
    def is_set(self) -> bool:
        """True for a blob set (``count`` 0 or > 1): ids ``<name>_<k>``, tracked across frames."""
        return self.count != 1

    def __post_init__(self) -> None:
        if not self.name or not self.name[0].isalpha() or not all(
                c.isalnum() or c == "_" for c in self.name):
            raise InputError(f"target name '{self.name}': start with a letter, then use "
                             "letters, digits and underscores (it becomes a topic name)")
        if not isinstance(self.color, ColorRange):
            raise InputError(f"target '{self.name}': color must be a ColorRange")
        if self.radius_m is not None and not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise InputError(f"target '{self.name}': radius_m must be > 0, got {self.radius_m}")
        if not (math.isfinite(self.min_area_px) and self.min_area_px >= 1):
            raise InputError(f"target '{self.name}': min_area_px must be >= 1, "
                             f"got {self.min_area_px}")
        if self.max_area_px is not None and not self.max_area_px > self.min_area_px:
            raise InputError(f"target '{self.name}': max_area_px must exceed min_area_px")
        if not 0.0 <= self.min_circularity <= 1.0:
            raise InputError(f"target '{self.name}': min_circularity must be in [0, 1], "
                             f"got {self.min_circularity}")
        if isinstance(self.count, bool) or not isinstance(self.count, (int, np.integer)) \
                or not 0 <= self.count <= MAX_BLOBS:
            raise InputError(f"target '{self.name}': count must be an integer in "
                             f"[0, {MAX_BLOBS}] (0 = every blob), got {self.count!r}")


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings shared by every target.

    Attributes:
        targets: the targets, in priority order (the first is "the" target), at least one.
        downscale: factor of the coarse pass (1 = threshold the whole image at full size).
        open_px: kernel size (pixels, full resolution) of the morphological opening that
            removes speckle; 0 disables it.
        close_px: kernel size of the closing that fills holes (specular highlights); 0 disables.
        selection: "largest", "circular" or "nearest" (nearest the previous detection; largest
            when there is none).
        max_candidates: blobs per target examined at full resolution (>= 1).
        roi_margin_px: margin around a coarse blob for the full-resolution pass.
        sphere_correction: correct sphere centroids for the perspective offset (needs a camera).
        reject_border: drop blobs that touch the image border (truncated silhouettes).
    """

    targets: tuple[TargetSpec, ...]
    downscale: int = 4
    open_px: int = 3
    close_px: int = 5
    selection: str = "largest"
    max_candidates: int = 3
    roi_margin_px: int = 8
    sphere_correction: bool = True
    reject_border: bool = True

    def __post_init__(self) -> None:
        targets = tuple(self.targets)
        if not targets:
            raise InputError("targets: at least one target is needed")
        names = [t.name for t in targets]
        if len(set(names)) != len(names):
            raise InputError(f"targets: names must be unique, got {names}")
        for t in targets:
            if t.is_set:
                clash = [n for n in names if n.startswith(f"{t.name}_")
                         and n[len(t.name) + 1:].isdigit()]
                if clash:
                    raise InputError(f"targets: '{clash[0]}' would clash with the ids "
                                     f"'{t.name}_<k>' of the blob set '{t.name}'")
        object.__setattr__(self, "targets", targets)
        for key, lo, hi in (("downscale", 1, 16), ("open_px", 0, 51), ("close_px", 0, 51),
                            ("max_candidates", 1, 20), ("roi_margin_px", 0, 200)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise InputError(f"{key}: expected an integer in [{lo}, {hi}], got {v!r}")
        if self.selection not in SELECTIONS:
            raise InputError(f"selection: '{self.selection}' is not one of "
                             f"{', '.join(SELECTIONS)}")

    def limit(self, target: TargetSpec) -> int:
        """Blobs per image examined for ``target``: ``max_candidates`` for one blob, ``count +
        max_candidates - 1`` for ``count`` N > 1, ``MAX_BLOBS`` for ``count: 0``."""
        if target.count == 0:
            return MAX_BLOBS
        return min(MAX_BLOBS, target.count + self.max_candidates - 1)

    def target(self, name: str) -> TargetSpec:
        """The target called ``name``."""
        for t in self.targets:
            if t.name == name:
                return t
        raise InputError(f"no target named '{name}' (have {[t.name for t in self.targets]})")


@dataclass(frozen=True, eq=False)
class Detection:
    """One detected blob.

    Attributes:
        name: the target's name.
        centroid_px: area centroid of the blob in the (distorted) image, shape (2,).
        center_px: the image of the target's centre in the distorted image, shape (2,): the
            sphere-corrected centre when a camera was given and correction is on, else the
            centroid.
        center_norm: ``center_px`` in undistorted normalised coordinates (x/z, y/z), shape (2,);
            NaN without a camera model.
        area_px: blob area in pixels.
        circularity: ``4 pi area / perimeter^2`` of its outer contour.
        bbox: (x, y, w, h) in pixels.
        angular_radius: the sphere's angular radius (radians) estimated from the silhouette,
            NaN without a camera model.
        ellipse_norm: centre of the silhouette ellipse in normalised coordinates, shape (2,)
            (the uncorrected centre; NaN unless the sphere correction ran), from which
            :func:`sphere_center_direction` recomputes the centre for a better ``alpha``.
        center_sigma_px: estimated 1-sigma error of ``center_px`` per image axis (pixels),
            from the blob's edge roughness, shading and the threshold cut (module docstring);
            NaN if the blob is too small to tell.
        edge_sigma_px: the edge-roughness part of ``center_sigma_px`` (pixels, per axis).
        shade_px: the shading part as a vector (pixels, shape (2,)): ``SHADE_GAIN * g`` (grown
            with ``blur_px``), the
            1-sigma extent of the centroid's shift along the brightness asymmetry ``g`` (the
            same light shifts both images of a stereo pair alike).
        cut_sigma_px: the threshold-cut part (pixels, per axis): ``CUT_SIGMA_PX`` (grown with
            ``blur_px``), common to both images of a stereo pair (the same background behind
            the target); 0 when ``center_sigma_px`` is NaN.
        blur_px: the blur the edge shows (pixels, Gaussian sigma, 0 for a sharp edge), from
            :func:`edge_width`; it scales the shading and threshold-cut parts.
    """

    name: str
    centroid_px: np.ndarray
    center_px: np.ndarray
    center_norm: np.ndarray
    area_px: float
    circularity: float
    bbox: tuple[int, int, int, int]
    angular_radius: float = float("nan")
    ellipse_norm: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    center_sigma_px: float = float("nan")
    edge_sigma_px: float = float("nan")
    shade_px: np.ndarray = field(default_factory=lambda: np.zeros(2))
    cut_sigma_px: float = 0.0
    blur_px: float = 0.0


def range_from_samples(samples: np.ndarray, space: str = "hsv", *, percentile: float = 5.0,
                       margin: Sequence[int] = (4, 20, 20)) -> ColorRange:
    """A colour range capturing pixel samples, from robust percentiles.

    Hue is circular: percentiles are taken of the offsets from the circular mean hue, so a red
    region straddling 0 gives a wrapping range (lower hue > upper hue). Saturation and value
    (or intensity) use plain percentiles. The margins widen each side.

    Args:
        samples: pixels already converted to ``space``, uint8, shape (N, 3), N >= 1.
        space: "hsv" or "hsi".
        percentile: lower percentile p (the range spans p .. 100 - p), 0 <= p < 50.
        margin: (h, s, v) widening on each side, in the 8-bit units.

    Returns:
        The range (hue covers 0..179 when the samples' hue spread is 180 or more).

    Raises:
        InputError: empty or malformed samples, bad percentile or margin.
    """
    arr = np.asarray(samples)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise InputError(f"samples: expected shape (N, 3) with N >= 1, got {arr.shape}")
    if not 0.0 <= percentile < 50.0:
        raise InputError(f"percentile: expected 0 <= p < 50, got {percentile}")
    m = [int(v) for v in margin]
    if len(m) != 3 or min(m) < 0:
        raise InputError(f"margin: expected three non-negative integers, got {margin!r}")
    a = arr.astype(np.float64)
    ang = a[:, 0] * (np.pi / 90.0)  # hue units (0..180) -> radians
    mean_h = (math.degrees(math.atan2(np.sin(ang).mean(), np.cos(ang).mean())) / 2.0) % 180.0
    off = (a[:, 0] - mean_h + 90.0) % 180.0 - 90.0  # offsets in [-90, 90)
    lo_off, hi_off = np.percentile(off, [percentile, 100.0 - percentile])
    lo_off, hi_off = lo_off - m[0], hi_off + m[0]
    if hi_off - lo_off >= 179.0:
        h_lo, h_hi = 0, 179
    else:
        h_lo = int(math.floor(mean_h + lo_off)) % 180
        h_hi = int(math.ceil(mean_h + hi_off)) % 180
    lower, upper = [h_lo], [h_hi]
    for ch in (1, 2):
        plo, phi = np.percentile(a[:, ch], [percentile, 100.0 - percentile])
        lower.append(int(max(0, math.floor(plo) - m[ch])))
        upper.append(int(min(255, math.ceil(phi) + m[ch])))
    return ColorRange(tuple(lower), tuple(upper), space)  # type: ignore[arg-type]


# -- sphere geometry -----------------------------------------------------------------------

def sphere_silhouette_center(direction_angle: float, angular_radius: float) -> float:
    """Radial distance (normalised plane) of the silhouette ellipse centre of a sphere.

    Args:
        direction_angle: field angle theta of the sphere centre (radians, from the optical axis).
        angular_radius: alpha = asin(radius / distance) (radians).

    Returns:
        ``sin(2 theta) / (cos(2 theta) + cos(2 alpha))``; compare ``tan(theta)``.
    """
    return math.sin(2 * direction_angle) / (math.cos(2 * direction_angle)
                                            + math.cos(2 * angular_radius))


def sphere_center_direction(ellipse_center_norm: np.ndarray, angular_radius: float) -> np.ndarray:
    """Normalised image of a sphere's centre from its silhouette ellipse centre (closed form).

    Inverts :func:`sphere_silhouette_center`: with ``m = |c|`` and ``phi = atan(m)``,
    ``2 theta = phi + asin(m cos(2 alpha) / sqrt(1 + m^2))``; the centre keeps the direction of
    ``c`` with radial distance ``tan(theta)``.

    Args:
        ellipse_center_norm: ellipse (silhouette) centre in normalised coordinates, shape (2,).
        angular_radius: alpha in radians, 0 <= alpha < pi/2.

    Returns:
        shape (2,), normalised coordinates of the sphere centre's image.
    """
    c = np.asarray(ellipse_center_norm, dtype=np.float64)
    m = float(math.hypot(c[0], c[1]))
    if m < 1e-12 or not angular_radius > 0:
        return c.copy()
    phi = math.atan(m)
    s = m * math.cos(2 * angular_radius) / math.sqrt(1.0 + m * m)
    theta = 0.5 * (phi + math.asin(max(-1.0, min(1.0, s))))
    return c * (math.tan(theta) / m)


def angular_radius_from_minor_axis(minor_semi_axis: float, direction_angle: float) -> float:
    """Angular radius alpha of a sphere from its silhouette's minor semi-axis b (normalised).

    ``b = sin(alpha) / sqrt(cos^2(theta) - sin^2(alpha))``, so
    ``sin^2(alpha) = b^2 cos^2(theta) / (1 + b^2)``.
    """
    b2 = minor_semi_axis * minor_semi_axis
    c2 = math.cos(direction_angle) ** 2
    return math.asin(math.sqrt(min(1.0, b2 * c2 / (1.0 + b2))))


# -- the detector --------------------------------------------------------------------------

@dataclass
class _Blob:
    """A blob found in one image: its geometry from :meth:`ColorDetector._fine_blob`, then its
    centre-uncertainty terms from :func:`_measure_blobs` (made for all of an image's blobs at
    once)."""
    mask: np.ndarray          # uint8 0/1 component mask over the blob's bounding box
    x0: int                   # the region of interest's corner in the image
    y0: int
    area: float
    circularity: float
    centroid: np.ndarray
    contour: np.ndarray       # (K, 2) float64 full-image pixel coordinates
    bbox: tuple[int, int, int, int]
    local: np.ndarray         # (K, 2) float64 the contour in the bounding box's coordinates
    grey: np.ndarray          # uint8 grey image over the bounding box
    moments: Mapping[str, float]   # cv2.moments of ``mask``
    roi_size: tuple[int, int]      # (w, h) of the region of interest
    roi_contour: np.ndarray   # (K, 2) int the contour in the region of interest's coordinates
    roi_center: np.ndarray    # (2,) the centroid in the region of interest's coordinates
    center_sigma_px: float = float("nan")
    edge_sigma_px: float = float("nan")
    shade_px: np.ndarray = field(default_factory=lambda: np.zeros(2))
    cut_sigma_px: float = 0.0
    blur_px: float = 0.0


class ColorDetector:
    """Find coloured targets in BGR images. Stateless: safe to share between threads.

    Args:
        config: the detector settings.

    Raises:
        InputError: ``config`` is not a :class:`DetectorConfig`.
    """

    def __init__(self, config: DetectorConfig) -> None:
        if not isinstance(config, DetectorConfig):
            raise InputError("config: expected a DetectorConfig")
        self.config = config
        self._spaces = sorted({t.color.space for t in config.targets})
        self._open = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (config.open_px,) * 2)
                      if config.open_px > 1 else None)
        self._close = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (config.close_px,) * 2)
                       if config.close_px > 1 else None)

    # -- public ----------------------------------------------------------------------------
    def detect(self, image: np.ndarray, camera: CameraModel | None = None,
               previous: Mapping[str, np.ndarray] | None = None) -> list[Detection]:
        """The best detection of each target (targets not found are absent), in config order.

        Args:
            image: BGR uint8, shape (H, W, 3).
            camera: the image's camera model, for the sphere-centre correction and
                ``center_norm``; None to skip both.
            previous: target name -> previous ``center_px``, shape (2,) or (K, 2) (a blob set:
                the nearest of them counts), for ``selection="nearest"``.

        Returns:
            Detections, at most one per target.

        Raises:
            InputError: the image is not (H, W, 3) uint8, or disagrees with the camera's size.
        """
        cands = self.candidates(image, camera, previous)
        return [c[0] for c in (cands[t.name] for t in self.config.targets) if c]

    def candidates(self, image: np.ndarray, camera: CameraModel | None = None,
                   previous: Mapping[str, np.ndarray] | None = None) -> dict[str, list[Detection]]:
        """Up to ``max_candidates`` detections per target (``DetectorConfig.limit`` for a blob
        set), best first by the selection rule.

        Arguments and errors as :meth:`detect`. Returns a dict over every target name (empty
        lists for targets not found).
        """
        self._check_image(image, camera)
        cfg = self.config
        s = cfg.downscale
        h, w = image.shape[:2]
        if s > 1:
            small = cv2.resize(image, (max(1, w // s), max(1, h // s)),
                               interpolation=cv2.INTER_NEAREST)
        else:
            small = image
        planes = {space: ColorPlanes(convert_color(small, space)) for space in self._spaces}
        sx, sy = w / small.shape[1], h / small.shape[0]
        found: list[tuple[TargetSpec, _Blob]] = []
        for target in cfg.targets:
            mask = target.color.threshold_planes(planes[target.color.space])
            blobs = self._coarse_blobs(mask, target, sx * sy, cfg.limit(target))
            seen: list[tuple[int, int, int, int]] = []
            for (bx, by, bw, bh) in blobs:
                x0 = int(bx * sx) - cfg.roi_margin_px
                y0 = int(by * sy) - cfg.roi_margin_px
                x1 = int(math.ceil((bx + bw) * sx)) + cfg.roi_margin_px
                y1 = int(math.ceil((by + bh) * sy)) + cfg.roi_margin_px
                box = (int(bx * sx), int(by * sy), int(math.ceil((bx + bw) * sx)),
                       int(math.ceil((by + bh) * sy)))
                blob = self._fine_blob(image, target, x0, y0, x1, y1, box, seen)
                if blob is None:
                    continue
                seen.append(blob.bbox)
                found.append((target, blob))
        # the per-blob measurements of all the image's blobs at once (the same bits as one
        # by one, a fraction of the NumPy calls: :func:`_measure_blobs`)
        _measure_blobs(image, [blob for _, blob in found])
        out: dict[str, list[Detection]] = {t.name: [] for t in cfg.targets}
        for (target, _), det in zip(found, self._make_detections(found, camera), strict=True):
            if det is not None:
                out[target.name].append(det)
        for target in cfg.targets:
            out[target.name] = self._rank(out[target.name],
                                          previous.get(target.name) if previous else None,
                                          cfg.limit(target))
        return out

    def mask(self, image: np.ndarray, target: str | None = None) -> np.ndarray:
        """Full-resolution binary mask (0/255) of one target's colour range, after morphology.

        For debugging and tuning (it thresholds the whole image, unlike :meth:`detect`).
        """
        self._check_image(image, None)
        spec = self.config.targets[0] if target is None else self.config.target(target)
        m = spec.color.threshold(convert_color(image, spec.color.space))
        return self._morph(m)

    # -- internals -------------------------------------------------------------------------
    @staticmethod
    def _check_image(image: Any, camera: CameraModel | None) -> None:
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 \
                or image.shape[2] != 3:
            shape = getattr(image, "shape", None)
            dtype = getattr(image, "dtype", type(image).__name__)
            raise InputError(f"image: expected a BGR uint8 array of shape (H, W, 3), got "
                             f"shape {shape} dtype {dtype}")
        if image.shape[0] < 8 or image.shape[1] < 8:
            raise InputError(f"image: {image.shape[1]}x{image.shape[0]} is too small")
        if camera is not None and (image.shape[1], image.shape[0]) != camera.size:
            raise InputError(f"image: size {image.shape[1]}x{image.shape[0]} disagrees with the "
                             f"camera model's {camera.width}x{camera.height}")

    def _morph(self, mask: np.ndarray) -> np.ndarray:
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        return mask

    def _coarse_blobs(self, mask: np.ndarray, target: TargetSpec, pixel_area: float,
                      limit: int) -> list[tuple[int, int, int, int]]:
        # External contours are several times cheaper than labelling the whole coarse mask.
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            return []
        # pixel count of a blob ~ polygon area through the boundary pixel centres + half its
        # perimeter + 1; a coarse blob is kept when it could be a target (nearest sampling
        # keeps the area within a few coarse pixels of area / pixel_area)
        min_area = max(1.0, 0.5 * target.min_area_px / pixel_area)
        scored = []
        for c in contours:
            area = cv2.contourArea(c) + 0.5 * cv2.arcLength(c, True) + 1.0
            if area >= min_area:
                scored.append((area, cv2.boundingRect(c)))
        scored.sort(key=lambda a: -a[0])
        return [tuple(int(v) for v in box) for _, box in  # type: ignore[misc]
                scored[: 2 * limit]]

    def _fine_blob(self, image: np.ndarray, target: TargetSpec, x0: int, y0: int,
                   x1: int, y1: int, box: tuple[int, int, int, int] | None = None,
                   seen: Sequence[tuple[int, int, int, int]] = ()) -> _Blob | None:
        """The blob of the coarse ``box`` (x0, y0, x1, y1, full-image pixels) inside the ROI:
        the component covering most of the box (the largest when only one is there), so that a
        neighbouring blob of the same colour reaching into the ROI is not taken instead.
        None when it fails a gate or its bounding box is in ``seen`` (found already from
        another coarse blob: the caller drops it, so it is not measured again)."""
        h, w = image.shape[:2]
        for _ in range(3):  # grow the ROI when the blob reaches its edge
            x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
            roi = image[y0:y1, x0:x1]
            mask = self._morph(target.color.threshold(convert_color(roi, target.color.space)))
            single = _single_component(mask)
            if single is not None:         # the usual ROI: no labelling needed
                if not single:
                    return None
                labels, k = None, 1
                bx, by, bw, bh, area, outer = single
            else:
                n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8,
                                                                       ltype=cv2.CV_16U)
                k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
                if n > 2 and box is not None:
                    inner = labels[max(0, box[1] - y0):max(0, box[3] - y0),
                                   max(0, box[0] - x0):max(0, box[2] - x0)]
                    votes = np.bincount(inner.ravel(), minlength=n)[1:] if inner.size else None
                    if votes is not None and votes.max() > 0:
                        k = 1 + int(np.argmax(votes))
                bx, by, bw, bh, area = (int(v) for v in stats[k])
            touches_roi = (bx == 0 and x0 > 0) or (by == 0 and y0 > 0) or \
                (bx + bw == x1 - x0 and x1 < w) or (by + bh == y1 - y0 and y1 < h)
            if not touches_roi:
                break
            grow = max(bw, bh) // 2 + self.config.roi_margin_px + 1
            x0, y0, x1, y1 = x0 - grow, y0 - grow, x1 + grow, y1 + grow
        else:
            return None
        bbox = (x0 + bx, y0 + by, bw, bh)
        if bbox in seen:
            return None
        if self.config.reject_border and (bbox[0] == 0 or bbox[1] == 0 or
                                          bbox[0] + bw == w or bbox[1] + bh == h):
            return None
        if area < target.min_area_px or (target.max_area_px is not None
                                         and area > target.max_area_px):
            return None
        # the component's 0/1 mask (the 0/255 mask's pixels above 0: one cv2.threshold pass)
        if labels is None:
            comp = cv2.threshold(mask[by:by + bh, bx:bx + bw], 0, 1, cv2.THRESH_BINARY)[1]
            contour = outer              # its outer border, traced already (the ROI's pixels)
            roi_contour = outer.reshape(-1, 2)
            local = roi_contour.astype(np.float64)
            local -= (bx, by)            # (whole numbers: exact)
        else:
            comp = (labels[by:by + bh, bx:bx + bw] == k).astype(np.uint8)
            contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            contour = max(contours, key=cv2.contourArea)
            local = contour.reshape(-1, 2).astype(np.float64)
            roi_contour = contour.reshape(-1, 2) + (bx, by)
        perimeter = cv2.arcLength(contour, True)   # (the same wherever the contour lies)
        circ = 4.0 * math.pi * area / (perimeter * perimeter) if perimeter > 0 else 0.0
        if circ < target.min_circularity:
            return None
        # comp is 0/1: the plain moments are the binary ones (m00, m10, m01 exact integers)
        # without the binary pass's conversion of the mask
        mom = cv2.moments(comp)
        centroid = np.array([x0 + bx + mom["m10"] / mom["m00"], y0 + by + mom["m01"] / mom["m00"]])
        pts = local + (x0 + bx, y0 + by)
        grey = cv2.cvtColor(roi[by:by + bh, bx:bx + bw], cv2.COLOR_BGR2GRAY)
        return _Blob(comp, x0, y0, float(area), float(min(circ, 1.0)), centroid, pts, bbox,
                     local, grey, mom, (x1 - x0, y1 - y0), roi_contour,
                     np.array([bx + mom["m10"] / mom["m00"], by + mom["m01"] / mom["m00"]]))

    def _make_detections(self, found: Sequence[tuple[TargetSpec, _Blob]],
                         camera: CameraModel | None) -> list[Detection | None]:
        """The detection of each found blob (None: its polygon is degenerate). With a camera
        and the sphere correction, the contours of all the image's spheres are undistorted in
        one call and their polygons measured together (:func:`_polygon_centers_and_minor_axes`:
        the same bits as one by one)."""
        ellipses: dict[int, tuple[np.ndarray | None, float]] = {}
        if camera is not None and self.config.sphere_correction:
            spheres = [k for k, (target, blob) in enumerate(found)
                       if target.is_sphere and len(blob.contour) >= 5]
            if spheres:
                contours = [found[k][1].contour for k in spheres]
                norm = camera.undistort_points(contours[0] if len(contours) == 1
                                               else np.concatenate(contours))
                ellipses = dict(zip(spheres, _polygon_centers_and_minor_axes(
                    norm, [len(c) for c in contours], camera.fx), strict=True))
        # each sphere's centre from its ellipse, then all of them projected in one call
        spheres_c: list[tuple[int, np.ndarray, float, np.ndarray]] = []
        for k, (ellipse_c, minor) in ellipses.items():
            if ellipse_c is not None:
                theta = math.atan(float(np.hypot(*ellipse_c)))
                alpha = angular_radius_from_minor_axis(minor, theta)
                spheres_c.append((k, ellipse_c, alpha, sphere_center_direction(ellipse_c, alpha)))
        centres: dict[int, tuple[np.ndarray, float, np.ndarray, np.ndarray]] = {}
        if camera is not None and spheres_c:
            px = camera.project_directions(np.array([c[3] for c in spheres_c]))
            centres = {k: (ellipse_c, alpha, norm, row.copy())
                       for (k, ellipse_c, alpha, norm), row in zip(spheres_c, px, strict=True)}
        return [self._make_detection(target, blob, camera, k in ellipses, centres.get(k))
                for k, (target, blob) in enumerate(found)]

    @staticmethod
    def _make_detection(target: TargetSpec, blob: _Blob, camera: CameraModel | None,
                        corrected: bool,
                        centre: tuple[np.ndarray, float, np.ndarray, np.ndarray] | None
                        ) -> Detection | None:
        """One blob's detection. ``corrected``: the sphere correction applies to it, and then
        ``centre`` is its ``(ellipse centre, alpha, centre direction, centre pixel)``, None for
        a degenerate polygon."""
        if camera is None:
            nan2 = np.full(2, np.nan)
            return Detection(target.name, blob.centroid, blob.centroid.copy(), nan2, blob.area,
                             blob.circularity, blob.bbox, center_sigma_px=blob.center_sigma_px,
                             edge_sigma_px=blob.edge_sigma_px, shade_px=blob.shade_px,
                             cut_sigma_px=blob.cut_sigma_px, blur_px=blob.blur_px)
        if not corrected:
            norm = camera.undistort_points(blob.centroid)[0]
            return Detection(target.name, blob.centroid, blob.centroid.copy(), norm, blob.area,
                             blob.circularity, blob.bbox, center_sigma_px=blob.center_sigma_px,
                             edge_sigma_px=blob.edge_sigma_px, shade_px=blob.shade_px,
                             cut_sigma_px=blob.cut_sigma_px, blur_px=blob.blur_px)
        if centre is None:
            return None
        ellipse_c, alpha, center_norm, center_px = centre
        return Detection(target.name, blob.centroid, center_px, center_norm, blob.area,
                         blob.circularity, blob.bbox, alpha, ellipse_c, blob.center_sigma_px,
                         blob.edge_sigma_px, blob.shade_px, blob.cut_sigma_px, blob.blur_px)

    def _rank(self, dets: list[Detection], previous: np.ndarray | None,
              limit: int) -> list[Detection]:
        sel = self.config.selection
        if sel == "circular":
            dets.sort(key=lambda d: (-d.circularity, -d.area_px))
        elif sel == "nearest" and previous is not None and np.size(previous):
            p = np.asarray(previous, dtype=np.float64).reshape(-1, 2)
            dets.sort(key=lambda d: float(np.min(np.hypot(*(d.center_px - p).T))))
        else:
            dets.sort(key=lambda d: -d.area_px)
        return dets[:limit]


def _mean(x: np.ndarray, axis: int | None = None) -> Any:
    """``np.mean(x, axis)`` of a float64 array to the last bit: the sum over the count, which
    is what ``np.mean`` computes, without its generic wrapper (a few microseconds a call, on
    the per-blob path)."""
    return np.add.reduce(x, axis=axis) / (x.size if axis is None else x.shape[axis])


def _spans(counts: Sequence[int]) -> tuple[list[int], list[int]]:
    """Where each of several blocks of ``counts`` items lies in their concatenation: the
    start and end (exclusive) indices of each, in order."""
    ends = np.cumsum(counts).tolist()
    return [0] + ends[:-1], ends


def _single_component(mask: np.ndarray
                      ) -> tuple[int, int, int, int, int, np.ndarray] | tuple[()] | None:
    """A 0/255 mask's only 8-connected component as ``(x, y, w, h, pixels, outer)``: the stats
    ``cv2.connectedComponentsWithStats`` gives it and its outer border (int32, shape (K, 1, 2),
    every pixel: ``CHAIN_APPROX_NONE``), ``()`` for an empty mask, None when it has several
    components. The outer borders that ``cv2.findContours`` follows (8-connected foreground,
    the top level of ``RETR_CCOMP``; the others are holes) are the components: about 8 us for
    a target's ROI against 36 us to label it. The border is the one ``cv2.findContours``
    gives on the component's bounding box alone (``RETR_EXTERNAL``), shifted by its corner:
    the same pixels from the same first pixel in the same order."""
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return ()
    outer = contours[0]
    if len(contours) > 1:
        top = hierarchy[0, :, 3] < 0
        if int(np.count_nonzero(top)) > 1:
            return None
        outer = contours[int(np.argmax(top))]
    x, y, w, h = cv2.boundingRect(outer)
    return x, y, w, h, cv2.countNonZero(mask), outer


def center_sigma_parts(mask: np.ndarray, grey: np.ndarray, contour: np.ndarray, *,
                       moments: Mapping[str, float] | None = None
                       ) -> tuple[float, np.ndarray]:
    """Estimated 1-sigma error (px, per axis) of a blob's centre (see the module docstring),
    as its two parts: ``sigma_edge`` (per axis) and the shading vector ``SHADE_GAIN * g``.

    The brightness asymmetry ``g`` comes from two sets of image moments over the blob's own
    pixels (``cv2.moments`` of the mask and of the grey image inside it): their ``m00``,
    ``m10`` and ``m01`` are integer sums, exact in float64, so ``g`` is the same to the last
    bit as from the pixel lists, without building them.

    Args:
        mask: the blob's 0/1 mask, uint8, shape (h, w).
        grey: the grey image over the same pixels, uint8, shape (h, w).
        contour: the blob's outer contour in the same coordinates, shape (K, 2).
        moments: ``cv2.moments(mask)`` when the caller has it already.

    Returns:
        ``(sigma_edge, shade (2,))``; ``(nan, 0)`` for fewer than 12 contour points.
    """
    edge = _edge_sigmas([np.asarray(contour, dtype=np.float64)])[0]
    if edge is None:
        return float("nan"), np.zeros(2)
    return edge, _shade(mask, grey, moments)


def _edge_sigmas(contours: Sequence[np.ndarray]) -> list[float | None]:
    """``sigma_edge`` (module docstring) of each contour (float64, shape (K, 2)); None for
    fewer than 12 points or a degenerate ellipse.

    An ellipse is fitted to each contour (``cv2.fitEllipse``); the radial residuals of all the
    contours are then computed in one pass of NumPy calls over their concatenation, and only
    the sums are taken contour by contour. Element-wise arithmetic gives every element the same
    bits whatever array it is in, and each sum runs over the same contiguous values in the same
    order as for one contour alone: the result is that of one contour at a time, to the last
    bit (test_hot_path_bits), with a fraction of the calls (each costs microseconds on a few
    hundred points)."""
    out: list[float | None] = [None] * len(contours)
    fits: list[tuple[int, float, float, float, float, float, float]] = []
    for i, contour in enumerate(contours):
        if len(contour) < 12:
            continue
        (cx, cy), (d1, d2), ang = cv2.fitEllipse(contour.astype(np.float32))
        a, b = 0.5 * d1, 0.5 * d2
        if not (a > 0 and b > 0):
            continue
        fits.append((i, cx, cy, a, b, math.cos(math.radians(ang)), math.sin(math.radians(ang))))
    if not fits:
        return out
    counts = [len(contours[f[0]]) for f in fits]
    # the semi-axes, the angle's cosine and sine: numbers, or one per point
    ax: Any
    bx: Any
    c: Any
    s_: Any
    if len(fits) == 1:           # one blob: its ellipse as scalars
        _, cx, cy, ax, bx, c, s_ = fits[0]
        d = contours[fits[0][0]] - (cx, cy)
    else:                        # each contour's ellipse, one row per point
        par = np.repeat(np.array([f[1:] for f in fits]), counts, axis=0)
        d = np.concatenate([contours[f[0]] for f in fits]) - par[:, :2]
        ax, bx, c, s_ = par[:, 2], par[:, 3], par[:, 4], par[:, 5]
    u, v = d[:, 0] * c + d[:, 1] * s_, -d[:, 0] * s_ + d[:, 1] * c
    rho = np.sqrt((u / ax) ** 2 + (v / bx) ** 2)
    res = (rho - 1.0) * np.hypot(u, v) / np.maximum(rho, 1e-12)
    if len(fits) == 1:
        res = res - _mean(res)
        var = float(_mean(res * res))
        out[fits[0][0]] = math.sqrt(var * 2.0 * _correlation_time(res, var) / counts[0])
        return out
    starts, ends = _spans(counts)
    res = res - np.repeat(np.array([_mean(res[i:j]) for i, j in zip(starts, ends, strict=True)]),
                          counts)
    sq = res * res
    for f, i, j in zip(fits, starts, ends, strict=True):
        var = float(_mean(sq[i:j]))
        # a fresh copy of the contour's residuals: the lag-1 dot product then reads an array
        # laid out as one contour's own (its sum does not depend on where the block starts)
        out[f[0]] = math.sqrt(var * 2.0 * _correlation_time(res[i:j].copy(), var) / (j - i))
    return out


def _shade(mask: np.ndarray, grey: np.ndarray,
           moments: Mapping[str, float] | None = None) -> np.ndarray:
    """``SHADE_GAIN * g`` of a blob (:func:`center_sigma_parts`)."""
    # g = brightness-weighted centroid - area centroid, from moments: m00 the weight (pixel
    # count), m10 / m01 the weighted sums of x / y. For uint8 images every one is an integer
    # below 2^53, summed exactly, so the result does not depend on the summation order.
    weighted = cv2.moments(cv2.bitwise_and(grey, grey, mask=mask))
    total = weighted["m00"]
    shade = np.zeros(2)
    if total > 0:
        m = cv2.moments(mask, binaryImage=True) if moments is None else moments
        shade = np.array([weighted["m10"] / total - m["m10"] / m["m00"],
                          weighted["m01"] / total - m["m01"] / m["m00"]])
    return SHADE_GAIN * shade


def _measure_blobs(image: np.ndarray, blobs: Sequence[_Blob]) -> None:
    """Fill in the centre-uncertainty terms of the blobs found in ``image`` (module
    docstring): the edge term (:func:`_edge_sigmas`), the shading vector, the blur from the
    edge width (:func:`_edge_widths`), and the threshold cut; all the blobs' NumPy work in one
    pass, the same bits as one blob at a time."""
    if not blobs:
        return
    edges = _edge_sigmas([b.local for b in blobs])
    widths = _edge_widths(image, [b.roi_contour for b in blobs], [b.roi_center for b in blobs],
                          [(b.x0, b.y0) for b in blobs], [b.roi_size for b in blobs])
    for blob, edge_or_none, width in zip(blobs, edges, widths, strict=True):
        if edge_or_none is None:
            edge, shade = float("nan"), np.zeros(2)
        else:
            edge, shade = edge_or_none, _shade(blob.mask, blob.grey, blob.moments)
        blur = math.sqrt(max(width * width - BLUR_W0_PX ** 2, 0.0)) if math.isfinite(width) \
            else 0.0
        shade = shade * (1.0 + SHADE_BLUR_GAIN * blur * blur)
        cut = CUT_SIGMA_PX * (1.0 + CUT_BLUR_GAIN * blur) if math.isfinite(edge) else 0.0
        blob.center_sigma_px = math.hypot(edge, float(np.hypot(*shade)), cut)
        blob.edge_sigma_px, blob.shade_px, blob.cut_sigma_px, blob.blur_px = \
            edge, shade, cut, blur


#: How far (in correlation) the directly summed lag-1 autocorrelation must lie below the cut
#: of :func:`_correlation_time` for the FFT's to be below it too: both are within about
#: ``n * 2.2e-16`` of the exact value (``|ac| <= 1``), far inside this margin.
_AC_MARGIN = 1e-9


def _correlation_time(res: np.ndarray, var: float) -> float:
    """The integrated autocorrelation ``tau = 1 + 2 sum_k ac[k]`` of the edge residuals
    ``res`` (zero mean, ``var`` their mean square), over the lags before the circular
    autocorrelation ``ac`` (from the FFT) first drops below 0.05, up to ``n / 4``.

    Most blobs' residuals are nearly uncorrelated: ``ac[1] < 0.05`` and ``tau`` is exactly 1.
    The lag-1 sum alone (one dot product) decides that case, when it lies below the cut by
    more than ``_AC_MARGIN``; the FFT (about 15 us of a blob's measurement) runs only
    otherwise, so ``tau`` has the FFT's bits either way."""
    n = len(res)
    if not var > 0 or n // 4 <= 1:       # no spread, or no lag to sum
        return 1.0
    lag1 = (float(np.dot(res[:-1], res[1:])) + float(res[-1] * res[0])) / (n * var)
    if lag1 < 0.05 - _AC_MARGIN:
        return 1.0
    tau = 1.0
    spec = np.fft.rfft(res)
    ac = np.fft.irfft(spec * np.conj(spec), n) / (n * var)   # circular autocorrelation
    for k in range(1, n // 4):
        if ac[k] < 0.05:
            break
        tau += 2.0 * float(ac[k])
    return tau


@functools.lru_cache(maxsize=4096)
def _profile_points(n: int) -> np.ndarray:
    """The indices of :func:`edge_width`'s profiles on a contour of ``n`` points: ``m =
    min(n, _EDGE_PROFILES)`` evenly spaced, as ``np.linspace(0, n, m, endpoint=False)`` gives
    them (``arange(m)`` times the step ``n / m``, to the bit). Made once per contour length
    (read-only: shared)."""
    m = min(n, _EDGE_PROFILES)
    idx = (np.arange(m) * (n / m)).astype(int)
    idx.setflags(write=False)
    return idx


def edge_width(image: np.ndarray, contour: np.ndarray, center: np.ndarray) -> float:
    """Width (px) of a blob's edge from colour profiles across its contour.

    At up to ``_EDGE_PROFILES`` contour points, evenly spaced, the image is sampled along the
    row or column nearer the outward normal (taken from ``center`` to the point; the gates keep
    blobs round), ``2 _EDGE_BAND_PX + 2`` pixels across the edge. With ``d_j`` the colour
    distances between neighbouring samples, each profile gives ``(sum d_j)^2 / sum d_j^2
    / (2 sqrt(pi))`` times the cosine between the normal and the sampling axis: for a step
    blurred by a Gaussian of sigma ``s`` this is ``s`` whatever the contrast (the profile's
    slope integrates to the contrast, its square to ``contrast^2 / (2 sqrt(pi) s)``). The
    mean over the profiles is returned; pixel sampling and image noise add about
    ``BLUR_W0_PX`` in quadrature.

    Args:
        image: the pixels around the blob, shape (h, w, 3) (or (h, w)), uint8.
        contour: the blob's outer contour in ``image``'s pixel coordinates, shape (K, 2).
        center: the blob's centre in the same coordinates, shape (2,).

    Returns:
        the width in pixels; NaN for fewer than 12 contour points or no contrast.
    """
    h, w = image.shape[:2]
    return _edge_widths(image, [contour], [np.asarray(center, dtype=np.float64)], [(0, 0)],
                        [(w, h)])[0]


def _edge_widths(image: np.ndarray, contours: Sequence[np.ndarray],
                 centers: Sequence[np.ndarray], origins: Sequence[tuple[int, int]],
                 sizes: Sequence[tuple[int, int]]) -> list[float]:
    """:func:`edge_width` of several blobs of one image at once, to the last bit.

    Blob ``i``'s region is ``image[oy:oy + h, ox:ox + w]`` (``origins[i] = (ox, oy)``,
    ``sizes[i] = (w, h)``): its profiles are clamped to it, as :func:`edge_width` clamps them
    to the image it is given; ``contours[i]`` and ``centers[i]`` are in the region's
    coordinates. The profiles of all the blobs go through one pass of NumPy calls (element by
    element, so each has the bits it has alone) and only each blob's mean is taken blob by blob
    (over the same contiguous values in the same order)."""
    out = [float("nan")] * len(contours)
    use = [i for i, c in enumerate(contours) if len(c) >= 12]
    if not use:
        return out
    # (the hot path: plain ufuncs on the profiles; np.clip, np.diff and np.mean would give
    # the same numbers through slower generic wrappers)
    counts = [min(len(contours[i]), _EDGE_PROFILES) for i in use]
    if len(use) == 1:            # one blob: its region, as edge_width reads it
        i = use[0]
        (ox, oy), (w, h) = origins[i], sizes[i]
        image = image[oy:oy + h, ox:ox + w]
        pts = contours[i][_profile_points(len(contours[i]))]
        cen: np.ndarray = centers[i]
        x_max: Any = w - 1
        y_max: Any = h - 1
    else:
        pts = np.concatenate([contours[i][_profile_points(len(contours[i]))] for i in use])
        cen = np.repeat(np.array([centers[i] for i in use]), counts, axis=0)
        geo = np.repeat(np.array([(origins[i][0], origins[i][1], sizes[i][0] - 1,
                                   sizes[i][1] - 1) for i in use]), counts, axis=0)
        x_max, y_max = geo[:, 2:3], geo[:, 3:]
    nrm = pts - cen
    anrm = np.abs(nrm)
    horiz = anrm[:, 0] >= anrm[:, 1]
    cos = np.maximum(anrm[:, 0], anrm[:, 1]) / np.maximum(np.hypot(nrm[:, 0], nrm[:, 1]), 1e-9)
    sign = np.sign(np.where(horiz, nrm[:, 0], nrm[:, 1]))
    j = np.arange(-_EDGE_BAND_PX, _EDGE_BAND_PX + 2)
    step = (sign[:, None] * j[None, :]).astype(np.intp)
    along = np.where(horiz[:, None], step, 0)
    ipts = pts.astype(int)
    xs = np.minimum(np.maximum(ipts[:, :1] + along, 0), x_max)
    ys = np.minimum(np.maximum(ipts[:, 1:] + (step - along), 0), y_max)
    if len(use) > 1:             # from each blob's region to the image
        xs, ys = xs + geo[:, :1], ys + geo[:, 1:2]
    prof = image[ys, xs].astype(np.float32)                  # (P, samples[, 3])
    d = prof[:, 1:] - prof[:, :-1]
    if d.ndim == 3 and d.shape[2] == 3:
        # the colour distance: the squares of uint8 differences and their sum over the three
        # channels are integers below 2^24, exact in float32 in any order: the same bits as
        # the reduction over that short last axis, in two adds
        dd = d * d
        d = np.sqrt(dd[..., 0] + dd[..., 1] + dd[..., 2])
    else:
        d = np.sqrt((d * d).sum(axis=2)) if d.ndim == 3 else np.abs(d)
    s1, s2 = np.add.reduce(d, axis=1), np.add.reduce(d * d, axis=1)
    ok = s2 > 0
    width = s1[ok] ** 2 / s2[ok] * cos[ok]          # the profiles with contrast, blob by blob
    n_ok = np.cumsum(ok).tolist() if len(use) > 1 else [int(np.count_nonzero(ok))] * counts[0]
    first = done = 0
    for i, m in zip(use, counts, strict=True):
        k = n_ok[first + m - 1] - done
        first += m
        if k:
            out[i] = float(np.add.reduce(width[done:done + k]) / k) / (2.0 * math.sqrt(math.pi))
        done += k
    return out


def _polygon_center_and_minor_axis(contour_norm: np.ndarray,
                                   scale: float) -> tuple[np.ndarray | None, float]:
    """Area centroid and minor semi-axis of a closed polygon (normalised coordinates).

    The contour runs through boundary pixel centres, half a pixel inside the true edge: the
    minor semi-axis is grown by half a pixel (``0.5 / scale`` in normalised units).

    Returns:
        (centre (2,), minor semi-axis), or (None, nan) for a degenerate polygon.
    """
    return _polygon_centers_and_minor_axes(contour_norm, [len(contour_norm)], scale)[0]


def _polygon_centers_and_minor_axes(points: np.ndarray, counts: Sequence[int], scale: float
                                    ) -> list[tuple[np.ndarray | None, float]]:
    """:func:`_polygon_center_and_minor_axis` of several polygons at once, to the last bit:
    ``points`` (float64, shape (N, 2), C order) holds them one after the other, ``counts``
    their vertex counts. The per-vertex terms of all of them are one pass of NumPy calls; the
    sums are taken polygon by polygon, over the same contiguous values as for one alone."""
    starts, ends = _spans(counts)
    c0s = [_mean(points[a:b], axis=0) for a, b in zip(starts, ends, strict=True)]
    if len(counts) == 1:
        p = (points - c0s[0]) * scale  # well-conditioned units (about pixels)
        nxt = np.concatenate((p[1:], p[:1]))      # the next vertex (np.roll by -1, cheaper)
    else:
        p = (points - np.repeat(np.array(c0s), counts, axis=0)) * scale
        following = np.arange(1, len(p) + 1)
        following[[b - 1 for b in ends]] = starts   # each polygon's last vertex: its first
        nxt = p[following]
    x, y = p[:, 0], p[:, 1]
    xn, yn = nxt[:, 0], nxt[:, 1]
    # the summed terms, one row each (written in place: the bits of the plain expressions)
    terms = np.empty((6, len(p)))
    cross = np.subtract(x * yn, xn * y, out=terms[0])
    np.multiply(x + xn, cross, out=terms[1])
    np.multiply(y + yn, cross, out=terms[2])
    np.multiply(x * x + x * xn + xn * xn, cross, out=terms[3])
    np.multiply(y * y + y * yn + yn * yn, cross, out=terms[4])
    np.multiply(x * yn + 2 * x * y + 2 * xn * yn + xn * y, cross, out=terms[5])
    out: list[tuple[np.ndarray | None, float]] = []
    for c0, a, b in zip(c0s, starts, ends, strict=True):
        s_cross, s_x, s_y, s_xx, s_yy, s_xy = np.add.reduce(terms[:, a:b], axis=1)
        area = s_cross / 2.0
        if abs(area) < 1e-9:
            out.append((None, float("nan")))
            continue
        cx = s_x / (6.0 * area)
        cy = s_y / (6.0 * area)
        sxx = s_xx / (12.0 * area) - cx * cx
        syy = s_yy / (12.0 * area) - cy * cy
        sxy = s_xy / (24.0 * area) - cx * cy
        lam_min = 0.5 * (sxx + syy) - math.sqrt(max(0.0, 0.25 * (sxx - syy) ** 2 + sxy * sxy))
        minor = 2.0 * math.sqrt(max(lam_min, 0.0)) + 0.5
        out.append((c0 + np.array([cx, cy]) / scale, minor / scale))
    return out
