"""``StereoLocator``: one stereo pair in, target points in the left optical frame out.

The public API shared by the ``detect_triangulate`` node, ``eye-in-hand locate`` and users::

    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator import StereoLocator
    from eye_in_hand.core.locator_params import load_locator_config

    rig = StereoRig.load("calib/")                      # ROS left.yaml + right.yaml work as-is
    locator = StereoLocator(rig, load_locator_config("config/detect_triangulate.yaml"))
    result = locator.locate(left_bgr, right_bgr)
    if result.first is not None:
        print(result.first.point_m, result.first.covariance)

Per target: colour detection in both images (:mod:`eye_in_hand.core.detection`), left/right
association (every pair gated by the epipolar constraint: rectified rows agree within
``epipolar_tol_px``; a positive disparity inside the plausible depths; the triangulation; for a
sphere of known radius, its size against its range), solved as one assignment (Hungarian: most
pairs, then least summed row difference), pairs that an equally good other assignment would
change rejected as ``ambiguous`` and counted; triangulation
(:mod:`eye_in_hand.core.triangulation`), and for a sphere of known radius one refinement of the
sphere-centre correction with the angular radius ``asin(radius / range)`` from the triangulated
range, then a second triangulation.

A target with ``count`` other than 1 is a blob set: up to ``count`` blobs (0: all), each with an
id ``<name>_<k>``: ``k`` is given at first sight; later pairs keep it for the blob nearest (3-D,
left optical frame, within ``tracking.gate_m``) the id's last position; an id unseen for
``tracking.max_missed`` pairs is retired and never reused (docs/detection.md).

Parameters: :data:`LOCATOR_PARAMETERS` and :data:`TARGET_PARAMETERS` describe every setting
(name, default, description, range) once; the node declares them as ROS parameters and the CLI
reads the same names from the node's parameter file (:func:`load_parameter_file`). They, the
:class:`~eye_in_hand.core.locator_params.LocatorConfig` and its loaders live in
:mod:`eye_in_hand.core.locator_params`.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from eye_in_hand.core.assignment import min_cost_assignment
from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.detection import (
    ColorDetector,
    Detection,
    TargetSpec,
    sphere_center_direction,
)
from eye_in_hand.core.locator_params import (
    FALLBACK_PIXEL_SIGMA,
    MIN_PIXEL_SIGMA,
    LocatorConfig,
)
from eye_in_hand.core.triangulation import (
    Rejected,
    StereoPoint,
    triangulate_dlt,
    triangulate_optimal,
    triangulate_parallax,
    triangulate_rectified,
)
from eye_in_hand.errors import InputError

__all__ = [
    "TargetLocation",
    "LocateResult",
    "StereoLocator",
]


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
        """JSON-ready dict with exactly ``name``, ``id``, ``point_m``, ``covariance``,
        ``residual_px``, ``left_px`` and ``right_px`` (one element of ``eye-in-hand locate
        --json``)."""
        return {
            "name": self.name,
            "id": self.id,
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
        targets: located targets, in configuration order (only those found); the blobs of a
            blob set in the order of their ids' ``k``.
        rejected: key -> reason. Keys: the name of every one-blob target not located; for a
            blob set, its name when it saw a blob it could not locate (or none at all), and
            the id of every known blob (seen in an earlier frame, not retired) not located in
            this one. Reasons: ``not_detected_left``, ``not_detected_right``,
            ``not_detected``, ``epipolar`` (no candidate pair on the same rectified row),
            ``non_positive_disparity``, ``depth_range`` (disparity outside the plausible
            depths), ``size`` (a sphere's size disagrees with its range), ``ambiguous`` (two
            assignments are equally good), ``over_count`` (more blobs than ``count``; this one
            ranked lower), or a triangulation reason (``behind_camera``, ``residual_gate``,
            ``not_converged``).
        messages: the same keys -> a readable explanation of the rejection.
        first_name: the name of the first configured target (the one on ``target/point``).
        ambiguous: target name -> number of its blobs (left image) rejected as ambiguous in
            this pair (only targets with at least one).
    """

    targets: tuple[TargetLocation, ...]
    rejected: dict[str, str]
    messages: dict[str, str] = field(default_factory=dict)
    first_name: str = ""
    ambiguous: dict[str, int] = field(default_factory=dict)

    @property
    def first(self) -> TargetLocation | None:
        """The first configured target (``first_name``; for a blob set its located blob of
        lowest ``k``) when it was located, else None."""
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


def _norm(v: np.ndarray) -> float:
    """``np.linalg.norm`` of a float64 vector to the last bit (its own ``sqrt(v.dot(v))``),
    without its generic wrapper."""
    return math.sqrt(float(v.dot(v)))


def _finite2(v: np.ndarray) -> bool:
    """Whether both values of a (2,) array are finite."""
    return math.isfinite(v[0]) and math.isfinite(v[1])


#: Cost of an infeasible pair in the assignments (far above any sum of feasible costs).
_INFEASIBLE = 1e9


def _assign(cost: np.ndarray) -> list[tuple[int, int]]:
    """Feasible pairs ``(row, col)`` of the assignment with the most feasible pairs and, among
    those, the least summed cost (``cost >= _INFEASIBLE`` marks an infeasible pair)."""
    if cost.size == 0 or not np.any(cost < _INFEASIBLE):
        return []
    if 1 in cost.shape:          # one blob on a side (every one-blob target): the cheapest pair
        r, c = np.unravel_index(int(np.argmin(cost)), cost.shape)
        return [(int(r), int(c))]
    rows, cols = min_cost_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True)
            if cost[r, c] < _INFEASIBLE]


def _furthest(fails: Mapping[tuple[int, int], tuple[int, str, str]],
              pairs: Sequence[tuple[int, int]]) -> tuple[str, str]:
    """``(reason, message)`` of the pair that passed most gates (first in ``pairs`` on a tie)."""
    best: tuple[int, str, str] | None = None
    for ij in pairs:
        f = fails.get(ij)
        if f is not None and (best is None or f[0] > best[0]):
            best = f
    if best is None:
        return "ambiguous", "its possible partners are ambiguous"
    return best[1], best[2]


@dataclass
class _Association:
    """The outcome of one target's left/right association (internal)."""

    cl: Sequence[Detection]
    cr: Sequence[Detection]
    located: list[tuple[int, int, TargetLocation]] = field(default_factory=list)
    reason: str = ""
    message: str = ""
    n_ambiguous: int = 0
    left_reasons: dict[int, tuple[str, str]] = field(default_factory=dict)
    right_reasons: dict[int, tuple[str, str]] = field(default_factory=dict)
    xl: list[np.ndarray] = field(default_factory=list)
    xr: list[np.ndarray] = field(default_factory=list)


def _unpaired_reasons(out: _Association,
                      fails: Mapping[tuple[int, int], tuple[int, str, str]], free_l: list[int],
                      free_r: list[int], amb_l: set[int], amb_r: set[int]) -> None:
    """Why each unpaired blob (on either side) without a reason yet stayed unpaired:
    ambiguous, no unpaired blob on the other side, or its pair that got furthest through the
    gates (:func:`_furthest`)."""
    for i in free_l:
        if i in out.left_reasons:
            continue
        if i in amb_l:
            out.left_reasons[i] = ("ambiguous", "two left/right assignments are equally "
                                   "good")
        elif not free_r:
            out.left_reasons[i] = ("not_detected_right",
                                   "no unpaired blob in the right image")
        else:
            out.left_reasons[i] = _furthest(fails, [(i, j) for j in free_r])
    for j in free_r:
        if j in out.right_reasons:
            continue
        if j in amb_r:
            out.right_reasons[j] = ("ambiguous", "two left/right assignments are equally "
                                    "good")
        elif not free_l:
            out.right_reasons[j] = ("not_detected_left", "no unpaired blob in the left image")
        else:
            out.right_reasons[j] = _furthest(fails, [(i, j) for i in free_l])


@dataclass
class _Track:
    """A known blob of a blob set: id number, last point (left optical frame, metres), last
    rectified centres (pixels), frames missed since."""

    k: int
    point_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    left_rect: np.ndarray = field(default_factory=lambda: np.zeros(2))
    right_rect: np.ndarray = field(default_factory=lambda: np.zeros(2))
    missed: int = 0


@dataclass
class _BlobSet:
    tracks: list[_Track] = field(default_factory=list)
    next_k: int = 0


class StereoLocator:
    """Detect and triangulate the configured targets in stereo pairs.

    Args:
        rig: the stereo rig; rectified here (alpha 0) if it is not yet.
        config: locator settings (:func:`load_locator_config` gives the node's defaults).

    The locator is stateful for ``selection="nearest"`` (it remembers each target's last
    centres) and for blob sets (it remembers their known blobs, whose ids it keeps):
    :meth:`reset` forgets both. Use one locator per stream, frames in order
    (``LocatorConfig.stateful``).
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
        self._sets: dict[str, _BlobSet] = {}
        k = 1 if self._vertical else 0
        # disparity d (rectified pixels, positive in front) -> depth f B / d
        self._disp_sign = -math.copysign(1.0, P2[k, 3])
        self._fB = abs(float(P2[k, 3]))
        self._f = float(self.rig.P1[k, k])

    def reset(self) -> None:
        """Forget the previous detections (``selection="nearest"``) and the blob sets' known
        blobs (their ids start again at ``<name>_0``)."""
        self._previous.clear()
        self._sets.clear()

    def warm_up(self) -> None:
        """Run once on a synthetic pair (a disc of each target's colour), then :meth:`reset`.

        The first call of the detection path pays one-off costs (OpenCV and NumPy
        initialisation, lazy imports) of up to ~150 ms; paying them at start-up keeps a live
        node's first camera frames from overrunning its hand-over queue and being dropped.
        """
        w, h = self.rig.left.size
        img = np.zeros((h, w, 3), np.uint8)
        for k, spec in enumerate(self.config.detector.targets):
            lo, hi = spec.color.lower, spec.color.upper
            hue = ((lo[0] + hi[0] + (180 if spec.color.wraps else 0)) // 2) % 180
            hsv = np.array([[[hue, (lo[1] + hi[1]) // 2, (lo[2] + hi[2]) // 2]]], np.uint8)
            bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
            cv2.circle(img, (w // 2 + 60 * k, h // 2), max(8, min(w, h) // 30),
                       tuple(int(c) for c in bgr), -1)
        self.locate(img, img.copy())
        self.reset()

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
        ambiguous: dict[str, int] = {}
        for spec in cfg.detector.targets:
            cl, cr = cands_l[spec.name], cands_r[spec.name]
            a = self._associate(spec, cl, cr)
            if a.n_ambiguous:
                ambiguous[spec.name] = a.n_ambiguous
            if not spec.is_set:
                if not a.located:
                    rejected[spec.name] = a.reason
                    messages[spec.name] = f"target '{spec.name}': {a.message}"
                    continue
                loc = a.located[0][2]
                found.append(loc)
                self._previous[spec.name] = (loc.left_px, loc.right_px)
                continue
            if a.reason:
                rejected[spec.name] = a.reason
                messages[spec.name] = f"target '{spec.name}': {a.message}"
            located = self._track(spec, a, rejected, messages)
            found.extend(located)
            if located:
                self._previous[spec.name] = (np.array([t.left_px for t in located]),
                                             np.array([t.right_px for t in located]))
        return LocateResult(tuple(found), rejected, messages, cfg.detector.targets[0].name,
                            ambiguous)

    # -- internals -------------------------------------------------------------------------
    def _rect(self, H: np.ndarray, norm: np.ndarray) -> np.ndarray:
        h = H @ np.array([norm[0], norm[1], 1.0])
        return h[:2] / h[2]

    def _associate(self, spec: TargetSpec, cl: Sequence[Detection], cr: Sequence[Detection]
                   ) -> _Association:
        """Pair the target's left and right blobs (see :meth:`_gate` and the module docs).

        Every pair is gated (epipolar row, disparity sign and depth range, triangulation, the
        size of a sphere of known radius); the assignment with the most pairs and the least
        summed row difference is solved (Hungarian,
        :func:`~eye_in_hand.core.assignment.min_cost_assignment`);
        a pair is ambiguous when forbidding it still leaves an assignment with as many pairs
        whose cost is within ``ambiguity_margin_px`` of the best: the blobs that change
        between the two are rejected (``ambiguous``), never guessed.
        """
        out = _Association(cl, cr)
        xl = [self._rect(self._H1, d.center_norm) for d in cl]
        xr = [self._rect(self._H2, d.center_norm) for d in cr]
        out.xl, out.xr = xl, xr
        if not cl or not cr:
            out.reason = ("not_detected" if not cl and not cr else
                          "not_detected_left" if not cl else "not_detected_right")
            out.message = out.reason.replace("_", " ")
            out.left_reasons = {i: ("not_detected_right", "no blob in the right image")
                                for i in range(len(cl))}
            out.right_reasons = {j: ("not_detected_left", "no blob in the left image")
                                 for j in range(len(cr))}
            return out
        n, m = len(cl), len(cr)
        cost, fails, locs = self._gate_all(spec, cl, cr, xl, xr)
        best = _assign(cost)
        amb_l, amb_r = self._ambiguous(cost, best)
        accepted = sorted((ij for ij in best if ij[0] not in amb_l and ij[1] not in amb_r),
                          key=lambda ij: (ij[0], ij[1]))
        keep = accepted if spec.count == 0 else accepted[:spec.count]
        out.located = [(i, j, locs[i, j]) for i, j in keep]
        out.n_ambiguous = len(amb_l)
        used_l = {i for i, _ in keep}
        used_r = {j for _, j in keep}
        over = [ij for ij in accepted if ij not in keep]
        for i, j in over:
            msg = f"more than count = {spec.count} blobs located; this one ranked lower"
            out.left_reasons[i] = ("over_count", msg)
            out.right_reasons[j] = ("over_count", msg)
        free_r = [j for j in range(m) if j not in used_r]
        free_l = [i for i in range(n) if i not in used_l]
        _unpaired_reasons(out, fails, free_l, free_r, amb_l, amb_r)
        self._own_reason(out, spec, fails, free_l, free_r, amb_l)
        return out

    def _gate_all(self, spec: TargetSpec, cl: Sequence[Detection], cr: Sequence[Detection],
                  xl: list[np.ndarray], xr: list[np.ndarray]
                  ) -> tuple[np.ndarray, dict[tuple[int, int], tuple[int, str, str]],
                             dict[tuple[int, int], TargetLocation]]:
        """Every left/right pair through :meth:`_gate`: the cost matrix (rectified row
        difference, ``_INFEASIBLE`` where the gate fails), each failed pair's reason and each
        passed pair's location."""
        cost = np.full((len(cl), len(cr)), _INFEASIBLE)
        fails: dict[tuple[int, int], tuple[int, str, str]] = {}
        locs: dict[tuple[int, int], TargetLocation] = {}
        for i in range(len(cl)):
            for j in range(len(cr)):
                ok = self._gate(spec, cl[i], cr[j], xl[i], xr[j])
                if isinstance(ok, TargetLocation):
                    locs[i, j] = ok
                    cost[i, j] = abs(xl[i][self._row] - xr[j][self._row])
                else:
                    fails[i, j] = ok
        return cost, fails, locs

    def _ambiguous(self, cost: np.ndarray, best: list[tuple[int, int]]
                   ) -> tuple[set[int], set[int]]:
        """The left and right blobs of pairs that another assignment with as many pairs,
        within ``ambiguity_margin_px`` of the best's cost, pairs differently."""
        amb_l: set[int] = set()
        amb_r: set[int] = set()
        if best and self._has_alternatives(cost):
            total = sum(cost[i, j] for i, j in best)
            for i, j in best:
                c2 = cost.copy()
                c2[i, j] = _INFEASIBLE
                alt = _assign(c2)
                if len(alt) == len(best) and \
                        sum(c2[a, b] for a, b in alt) - total <= self.config.ambiguity_margin_px:
                    for a, b in set(best) ^ set(alt):
                        amb_l.add(a)
                        amb_r.add(b)
        return amb_l, amb_r

    def _own_reason(self, out: _Association, spec: TargetSpec,
                    fails: Mapping[tuple[int, int], tuple[int, str, str]], free_l: list[int],
                    free_r: list[int], amb_l: set[int]) -> None:
        """The target's (or blob set's) own reason: why nothing was located, or for a set
        why some blob was left out (ambiguity first, then the first unpaired blob's)."""
        if not out.located:
            if amb_l:
                out.reason, out.message = "ambiguous", (
                    f"{len(amb_l)} blob(s) could pair with more than one partner equally well "
                    f"(rectified rows within {self.config.ambiguity_margin_px:.2f} px)")
            else:
                order = sorted(fails, key=lambda ij: (ij[0] + ij[1], ij[0]))
                out.reason, out.message = _furthest(fails, order)
        elif spec.is_set:
            pending = [(i, out.left_reasons[i]) for i in free_l] + \
                [(j, out.right_reasons[j]) for j in free_r]
            pending = [p for p in pending if p[1][0] != "over_count"]
            if amb_l:
                out.reason, out.message = "ambiguous", (
                    f"{len(amb_l)} blob(s) could pair with more than one partner equally well")
            elif pending:
                out.reason, out.message = pending[0][1]

    @staticmethod
    def _has_alternatives(cost: np.ndarray) -> bool:
        """False when no blob has two feasible partners (then the assignment is unique)."""
        feasible = cost < _INFEASIBLE
        return bool(np.any(feasible.sum(axis=0) > 1) or np.any(feasible.sum(axis=1) > 1))

    @property
    def _row(self) -> int:
        return 0 if self._vertical else 1

    def _gate(self, spec: TargetSpec, dl: Detection, dr: Detection, xl: np.ndarray,
              xr: np.ndarray) -> TargetLocation | tuple[int, str, str]:
        """The located pair, or ``(stage, reason, message)`` of the first gate it fails:
        0 epipolar, 1 non_positive_disparity, 2 depth_range, 3 triangulation, 4 size."""
        cfg = self.config
        tol = cfg.epipolar_tol_px
        gap = abs(xl[self._row] - xr[self._row])
        if gap > tol:
            return (0, "epipolar", f"best left/right candidates are {gap:.2f} px apart across "
                    f"the epipolar line (tolerance {tol:.2f} px)")
        axis = 1 if self._vertical else 0
        d = ((xl[axis] - self.rig.P1[axis, 2]) - (xr[axis] - self.rig.P2[axis, 2])) \
            * self._disp_sign
        if not d > 0:
            return (1, "non_positive_disparity", f"disparity {d:.3f} px is not positive")
        depth = self._fB / d
        if not cfg.min_depth_m <= depth <= cfg.max_depth_m:
            return (2, "depth_range", f"disparity {d:.2f} px puts the pair at depth "
                    f"{depth:.3f} m, outside {cfg.min_depth_m:g}-{cfg.max_depth_m:g} m")
        try:
            loc = self._triangulate(spec, dl, dr, xl, xr)
        except Rejected as exc:
            return (3, exc.reason, str(exc))
        if cfg.size_tol > 0 and spec.radius_m is not None:
            alphas = [a for a in (dl.angular_radius, dr.angular_radius)
                      if math.isfinite(a) and a > 0]
            if alphas:
                # the mean as np.mean adds it (positive floats: 0 + a is a)
                rng_size = spec.radius_m / math.sin(sum(alphas) / len(alphas))
                rng = _norm(loc.point_m)
                factor = max(rng / rng_size, rng_size / rng)
                if factor > 1.0 + cfg.size_tol:
                    return (4, "size", f"the blobs' size puts a sphere of radius "
                            f"{spec.radius_m:g} m at {rng_size:.3f} m, the disparity at "
                            f"{rng:.3f} m (factor {factor:.2f} > {1 + cfg.size_tol:.2f})")
        return loc

    def _track(self, spec: TargetSpec, a: _Association, rejected: dict[str, str],
               messages: dict[str, str]) -> list[TargetLocation]:
        """Give the located blobs of a blob set their ids ``<name>_<k>`` (module docs)."""
        cfg = self.config
        state = self._sets.setdefault(spec.name, _BlobSet())
        tracks = state.tracks
        pts = [loc.point_m for _, _, loc in a.located]
        cost = np.full((len(pts), len(tracks)), _INFEASIBLE)
        for p, pt in enumerate(pts):
            for t, tr in enumerate(tracks):
                dist = _norm(pt - tr.point_m)
                if dist <= cfg.track_gate_m:
                    cost[p, t] = dist
        match = dict(_assign(cost))
        out: list[TargetLocation] = []
        seen: set[int] = set()
        for p, (i, j, loc) in enumerate(a.located):
            if p in match:
                tr = tracks[match[p]]
            else:
                tr = _Track(state.next_k)
                state.next_k += 1
                tracks.append(tr)
            tr.point_m, tr.left_rect, tr.right_rect, tr.missed = \
                loc.point_m, a.xl[i], a.xr[j], 0
            seen.add(tr.k)
            out.append(dataclasses.replace(loc, id=f"{spec.name}_{tr.k}"))
        keep: list[_Track] = []
        used_l = {i for i, _, _ in a.located}
        used_r = {j for _, j, _ in a.located}
        for tr in tracks:
            if tr.k in seen:
                keep.append(tr)
                continue
            tr.missed += 1
            if tr.missed > cfg.track_max_missed:
                continue   # retired: its id is never given to another blob
            keep.append(tr)
            key = f"{spec.name}_{tr.k}"
            reason, msg = self._why_missing(tr, a, used_l, used_r)
            rejected[key] = reason
            messages[key] = f"target '{key}': {msg}"
        state.tracks = sorted(keep, key=lambda t: t.k)
        return sorted(out, key=lambda t: int(t.id.rsplit("_", 1)[1]))

    def _why_missing(self, tr: _Track, a: _Association, used_l: set[int],
                     used_r: set[int]) -> tuple[str, str]:
        """The reason a known blob was not located: that of the nearest unpaired blob within
        ``missed`` gates (``tracking.gate_m`` seen at its last depth, pixels) of its last
        rectified position (left image first), else ``not_detected``."""
        z = float(tr.point_m[2]) if tr.point_m[2] > 0 else 1.0
        gate_px = max(10.0, self._f * self.config.track_gate_m / z) * max(1, tr.missed)
        for xs, used, reasons in ((a.xl, used_l, a.left_reasons),
                                  (a.xr, used_r, a.right_reasons)):
            last = tr.left_rect if xs is a.xl else tr.right_rect
            near = [(float(np.hypot(*(x - last))), k) for k, x in enumerate(xs)
                    if k not in used and k in reasons]
            near = [nk for nk in near if nk[0] <= gate_px]
            if near:
                return reasons[min(near)[1]]
        return "not_detected", f"not seen near its last position ({self.config.track_max_missed}" \
            f" frames reserve its id; missed {tr.missed})"

    def _pixel_cov(self, dl: Detection, dr: Detection) -> tuple[float, np.ndarray | None]:
        """``(sigma_px, pixel_cov)`` of a pair: the configured pixel sigma (``pixel_cov`` None),
        else the detections' own, (4, 4) over (xl, yl, xr, yr): each image's edge term plus
        the shading shifts ``shade_px``, fully correlated between the two images (one light),
        plus the threshold cut ``cut_sigma_px`` per axis, also alike in both images (the same
        background behind the target; :mod:`eye_in_hand.core.detection`)."""
        if self.config.pixel_sigma > 0:
            return self.config.pixel_sigma, None
        if not (math.isfinite(dl.edge_sigma_px) and math.isfinite(dr.edge_sigma_px)):
            return FALLBACK_PIXEL_SIGMA, None
        e = [max(MIN_PIXEL_SIGMA, d.edge_sigma_px) ** 2 for d in (dl, dr)]
        v = np.concatenate([dl.shade_px, dr.shade_px])
        S = np.diag([e[0], e[0], e[1], e[1]]) + np.outer(v, v)
        for axis in (0, 1):   # the threshold cut: per image axis, alike in both images
            u = np.zeros(4)
            u[axis], u[2 + axis] = dl.cut_sigma_px, dr.cut_sigma_px
            S += np.outer(u, u)
        return 0.0, S

    def _point(self, left_px: np.ndarray, right_px: np.ndarray, xl: np.ndarray,
               xr: np.ndarray, pix: tuple[float, np.ndarray | None] = (FALLBACK_PIXEL_SIGMA, None),
               covariance: bool = True) -> StereoPoint:
        """The pair's point by the configured method; ``covariance`` False: the point and the
        rejections only (dlt and disparity skip the covariance, NaN; optimal computes it)."""
        cfg = self.config
        gate = cfg.max_residual_px
        if cfg.method != "optimal" and (pix[1] is not None or not covariance):
            # the detections' own covariance, built here as a sum of squares, or none: used
            # as it is (the rig, the pixels and it are this locator's own)
            return triangulate_rectified(self.rig, xl, xr, method=cfg.method,
                                         pixel_cov=pix[1] if covariance else None,
                                         max_residual_px=gate)
        kw: dict[str, Any] = ({"sigma_px": pix[0]} if pix[1] is None else {"pixel_cov": pix[1]})
        if cfg.method == "dlt":
            return triangulate_dlt(self.rig, xl, xr, rectified=True, max_residual_px=gate,
                                   covariance=covariance, **kw)
        if cfg.method == "disparity":
            return triangulate_parallax(self.rig, xl, xr, rectified=True, max_residual_px=gate,
                                        covariance=covariance, **kw)
        # the start's covariance is not used: only its point
        start = triangulate_rectified(self.rig, xl, xr, method="dlt", pixel_cov=None,
                                      max_residual_px=None)
        return triangulate_optimal(self.rig, left_px, right_px, initial=start,
                                   max_residual_px=gate, **kw)

    def _triangulate(self, spec: TargetSpec, dl: Detection, dr: Detection, xl: np.ndarray,
                     xr: np.ndarray) -> TargetLocation:
        pix = self._pixel_cov(dl, dr)
        left_px, right_px = dl.center_px, dr.center_px
        radius = spec.radius_m
        if radius is not None and not (_finite2(dl.ellipse_norm) and _finite2(dr.ellipse_norm)):
            radius = None
        # a pass that is refined below needs only its point (and its rejections); the
        # optimal method computes its covariance whatever it is asked
        bare = radius is not None and self.config.method != "optimal"
        pt = self._point(left_px, right_px, xl, xr, pix, covariance=not bare)
        if radius is not None:
            # refine the sphere-centre correction with alpha from the known radius and range
            rng_l = _norm(pt.point)
            rng_r = _norm(self.rig.R @ pt.point + self.rig.T)
            if rng_l > radius and rng_r > radius:
                nl = sphere_center_direction(dl.ellipse_norm, math.asin(radius / rng_l))
                nr = sphere_center_direction(dr.ellipse_norm, math.asin(radius / rng_r))
                left_px = self.rig.left.project_direction(nl[0], nl[1])
                right_px = self.rig.right.project_direction(nr[0], nr[1])
                pt = self._point(left_px, right_px, self._rect(self._H1, nl),
                                 self._rect(self._H2, nr), pix)
            elif bare:   # within the sphere's radius of a camera: no refinement, the full pass
                pt = self._point(left_px, right_px, xl, xr, pix)
        return TargetLocation(
            name=spec.name, point_m=pt.point, covariance=pt.covariance,
            residual_px=pt.residual_px, left_px=np.asarray(left_px, dtype=np.float64),
            right_px=np.asarray(right_px, dtype=np.float64),
            left_centroid_px=dl.centroid_px, right_centroid_px=dr.centroid_px,
            method=pt.method, disparity_px=pt.disparity_px, left=dl, right=dr)
