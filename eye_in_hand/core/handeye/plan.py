"""The next poses to take: flange poses that would most reduce the hand-eye uncertainty.

Model. The uncertainty of X is the one of the errors-in-variables reprojection problem of
:mod:`.eiv`, linearised at the current X and Y (the board pose in its fixed frame): every
corner's pixel error in every camera, with noise ``noise_px`` per coordinate, and every
sample's flange pose off by a correction of ``robot_sigma_pos_m`` (per axis, flange frame) and
``robot_sigma_rot_rad``. With the corrections marginalised out, a sample ``i`` contributes the
information (12 x 12, over X and Y, parametrised as in :mod:`.refine`)::

    I_i = J_i^T (s_px^2 I + K_i S_robot K_i^T)^-1 J_i = A_i - B_i D_i^-1 B_i^T

``J_i`` the corners' Jacobian by X and Y, ``K_i`` by the sample's flange-pose correction: the
pixel noise plus the robot-pose noise propagated through the corners, computed in its
whitened form (``A, B, D`` of :mod:`.eiv`, the Schur complement of the correction block). The
covariance of X is the X block of ``(sum_i I_i)^-1``, the Schur complement of Y: the board pose
is unknown too. Its one-sigma figures are those of :class:`.calibrate.MethodResult`:
``std_mm = 1000 sqrt(trace(C_t))``, ``std_deg = deg(sqrt(trace(C_r)))``. The Jacobians need
only the predicted corners, not measured ones, so a pose not yet taken is scored the same way.

Choice. Candidates are camera viewpoints on a cap around the board normal, on the side the
samples saw the board from: up to ``max_tilt_deg`` between the optical axis and the normal, at
a camera-to-board-centre distance within the reached range widened by ``distance_margin``,
looking at a point near the board centre, rolled about the optical axis within
``max_step_deg`` of a reached camera's roll. Each becomes a flange pose (eye-in-hand:
``base_T_ee = Y inv(C) inv(X)``; eye-to-hand: ``base_T_ee = X C inv(Y)``) and is kept when
every board corner projects at least ``margin_px`` inside the image of every camera (in front
of it), and so does the board's outline one corner spacing beyond the outer corners (the
outer squares a detector needs to see), and the flange pose is within ``max_step_m`` and
``max_step_deg`` of one reached sample's. Greedily, ``count`` times, the candidate with the
lowest score after it is added is taken and its information kept for the next pick. The
score (``criterion``):

* ``"trace"`` (default): ``(std_mm / target_mm)^2 + (std_deg / target_deg)^2``, the trace of
  the X covariance with translation in mm and rotation in degrees, each divided by its target
  (0.3 mm and 0.03 deg by default: 1 mm weighs as 0.1 deg), so both parts count as fractions
  of the uncertainty wanted;
* ``"logdet"``: ``log det`` of the X covariance (D-optimal; unit-free).

The prediction is a linearisation with assumed noise levels; it is as good as X, Y and those
levels. It does not know the robot's reach or obstacles: a suggestion must still be checked
for reachability and collisions before the robot moves there.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from eye_in_hand.core.transforms import (
    as_transform,
    average_transforms,
    invert,
    invert_many,
    to_xyz_quat,
)
from eye_in_hand.errors import HandEyeError, InputError

from .eiv import SIGMA_FLOORS, _normal, _Problem
from .refine import _start, project_points
from .samples import MIN_SAMPLES, CameraView, CornerObservation, HandEyeSample, validate_samples
from .solvers import SETUPS, board_in_fixed_frame

__all__ = ["PlanConfig", "Suggestion", "Plan", "suggest_next_poses", "CRITERIA",
           "predicted_covariance"]

#: Scores of a candidate set (see the module docstring).
CRITERIA = ("trace", "logdet")

# Candidates evaluated per Jacobian batch (memory: ~ batch x corners x 144 floats).
_BATCH = 64
# Candidate draws per admissible candidate wanted, at most (the limits reject most draws).
_MAX_DRAW_FACTOR = 40
# Nearest distance of a corner in front of a camera (m).
_MIN_DEPTH_M = 0.02


@dataclass(frozen=True)
class PlanConfig:
    """How suggestions are made (see the module docstring).

    Attributes:
        count: suggestions returned (greedy, each assuming the earlier ones are taken).
        noise_px: corner noise, 1 sigma per coordinate, pixels.
        robot_sigma_pos_m: robot flange position noise, 1 sigma per axis, metres.
        robot_sigma_rot_rad: robot flange rotation noise, 1 sigma per axis, radians.
        max_tilt_deg: largest angle between the optical axis and the board normal.
        distance_margin: the camera-to-board-centre distance stays within the reached range
            widened by this fraction on both ends.
        max_step_m: a suggestion's flange position is within this of a reached sample's ...
        max_step_deg: ... and its flange rotation within this of that sample's.
        margin_px: every board corner, and the outline one corner spacing beyond the outer
            corners, at least this far inside every image.
        candidates: admissible candidates evaluated.
        seed: random seed of the candidate draw.
        criterion: ``"trace"`` or ``"logdet"``.
        target_mm, target_deg: the weights of the ``"trace"`` criterion (the uncertainty
            wanted).
    """

    count: int = 3
    noise_px: float = 0.5
    robot_sigma_pos_m: float = 0.0002
    robot_sigma_rot_rad: float = 0.0004
    max_tilt_deg: float = 45.0
    distance_margin: float = 0.2
    max_step_m: float = 0.15
    max_step_deg: float = 45.0
    margin_px: float = 20.0
    candidates: int = 500
    seed: int = 0
    criterion: str = "trace"
    target_mm: float = 0.3
    target_deg: float = 0.03

    def __post_init__(self) -> None:
        def bad(name: str, want: str) -> InputError:
            return InputError(f"plan config: {name} must be {want}, got {getattr(self, name)!r}")

        for name in ("count", "candidates"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise bad(name, "an integer >= 1")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise bad("seed", "an integer")
        for name in ("noise_px", "max_step_m", "max_step_deg", "target_mm", "target_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v > 0):
                raise bad(name, "a finite number > 0")
        for name in ("robot_sigma_pos_m", "robot_sigma_rot_rad", "distance_margin",
                     "margin_px"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v >= 0):
                raise bad(name, "a finite number >= 0")
        if not (isinstance(self.max_tilt_deg, (int, float, np.floating))
                and 0 < self.max_tilt_deg < 90):
            raise bad("max_tilt_deg", "in (0, 90)")
        if self.distance_margin >= 1:
            raise bad("distance_margin", "below 1")
        if self.criterion not in CRITERIA:
            raise bad("criterion", f"one of {', '.join(CRITERIA)}")

    def sigmas(self) -> dict[str, float]:
        """The noise levels in :mod:`.eiv`'s names (robot levels at least its floors)."""
        return {"px": float(self.noise_px),
                "robot_t": max(float(self.robot_sigma_pos_m), SIGMA_FLOORS["robot_t"]),
                "robot_r": max(float(self.robot_sigma_rot_rad), SIGMA_FLOORS["robot_r"])}


@dataclass(frozen=True)
class Suggestion:
    """One suggested pose.

    Attributes:
        base_T_ee: the flange pose to move to, shape (4, 4).
        cam_T_board: the board as the (left) camera would see it there, shape (4, 4).
        std_mm, std_deg: predicted 1-sigma of X once this and the earlier suggestions are
            taken (translation norm, rotation angle).
        distance_m: camera to board centre.
        tilt_deg: angle between the optical axis and the board normal.
    """

    base_T_ee: np.ndarray
    cam_T_board: np.ndarray
    std_mm: float
    std_deg: float
    distance_m: float
    tilt_deg: float

    def to_dict(self) -> dict[str, Any]:
        """Plain data: poses as ``xyz`` (m) and ``quat_xyzw``."""
        return {"base_T_ee": _pose_dict(self.base_T_ee),
                "cam_T_board": _pose_dict(self.cam_T_board),
                "std_mm": float(self.std_mm), "std_deg": float(self.std_deg),
                "distance_m": float(self.distance_m), "tilt_deg": float(self.tilt_deg)}


@dataclass(frozen=True)
class Plan:
    """The suggestions and the predicted uncertainty now.

    Attributes:
        suggestions: best first; fewer than ``count`` when fewer candidates were admissible.
        std_mm, std_deg: predicted 1-sigma of X with the current samples.
        candidates: admissible candidates that were scored.
        criterion: the score used.
        sigmas: the noise levels assumed (``px``, ``robot_t`` m, ``robot_r`` rad).
    """

    suggestions: list[Suggestion]
    std_mm: float
    std_deg: float
    candidates: int = 0
    criterion: str = "trace"
    sigmas: dict[str, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain data for JSON/YAML (poses as ``xyz`` + ``quat_xyzw``)."""
        return {"std_mm": _finite(self.std_mm), "std_deg": _finite(self.std_deg),
                "criterion": self.criterion, "candidates": int(self.candidates),
                "noise": None if self.sigmas is None else {
                    "corner_px": self.sigmas["px"],
                    "robot_translation_m": self.sigmas["robot_t"],
                    "robot_rotation_rad": self.sigmas["robot_r"]},
                "suggestions": [s.to_dict() for s in self.suggestions]}


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _pose_dict(T: np.ndarray) -> dict[str, list[float]]:
    t, q = to_xyz_quat(T)
    return {"xyz": [float(v) for v in t], "quat_xyzw": [float(v) for v in q]}


def _std(cov_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(std_mm, std_deg)`` of a (..., 6, 6) covariance of X, as MethodResult reports them."""
    tt = np.trace(cov_x[..., :3, :3], axis1=-2, axis2=-1)
    tr = np.trace(cov_x[..., 3:, 3:], axis1=-2, axis2=-1)
    return 1000.0 * np.sqrt(np.maximum(tt, 0.0)), np.degrees(np.sqrt(np.maximum(tr, 0.0)))


def _information(samples: Sequence[HandEyeSample], X: np.ndarray, Y: np.ndarray,
                 views: Sequence[CameraView], setup: str,
                 sig: dict[str, float]) -> np.ndarray:
    """Each sample's information about X and Y with its robot-pose correction marginalised
    (the Schur complement of its correction block), shape (N, 12, 12)."""
    out = []
    for k in range(0, len(samples), _BATCH):
        chunk = list(samples[k:k + _BATCH])
        prob = _Problem(X, Y, chunk, views, setup, True)
        p = np.concatenate([_start(X), _start(Y), np.zeros(6 * len(chunk))])
        Jg, Ju = prob.jacobian(p, sig)
        nm = _normal(prob, Jg, Ju, prob.residuals(p, sig))
        BD = np.einsum("kij,kjl->kil", nm.B, nm.Dinv)
        out.append(nm.A_k - np.einsum("kij,klj->kil", BD, nm.B))
    info = np.concatenate(out)
    return 0.5 * (info + np.swapaxes(info, 1, 2))


def _x_covariance(info: np.ndarray) -> np.ndarray:
    """X block of the inverse of (..., 12, 12) information matrices; inf where singular."""
    try:
        return np.linalg.inv(info)[..., :6, :6]
    except np.linalg.LinAlgError:
        flat = info.reshape(-1, 12, 12)
        out = np.empty((flat.shape[0], 6, 6))
        for i, M in enumerate(flat):
            try:
                out[i] = np.linalg.inv(M)[:6, :6]
            except np.linalg.LinAlgError:
                out[i] = np.full((6, 6), np.inf)
        return out.reshape(info.shape[:-2] + (6, 6))


def predicted_covariance(samples: Sequence[HandEyeSample], X: np.ndarray, setup: str,
                         views: Sequence[CameraView], *, Y: np.ndarray | None = None,
                         config: PlanConfig = PlanConfig()) -> np.ndarray:
    """The covariance of X (6, 6; ``x y z rx ry rz``, m and rad) the model predicts for these
    samples (see the module docstring); arguments as :func:`suggest_next_poses`."""
    kept, X, Y, views = _check(samples, X, setup, views, Y)
    cov = _x_covariance(_information(kept, X, Y, views, setup, config.sigmas()).sum(axis=0))
    return 0.5 * (cov + cov.T)


def _check(samples: Sequence[HandEyeSample], X: np.ndarray, setup: str,
           views: Sequence[CameraView], Y: np.ndarray | None
           ) -> tuple[list[HandEyeSample], np.ndarray, np.ndarray, list[CameraView]]:
    if setup not in SETUPS:
        raise HandEyeError(f"setup: expected one of {', '.join(SETUPS)}, got {setup!r}")
    views = list(views or [])
    if not views:
        raise HandEyeError("planning needs the rig's cameras (views), got none")
    for v in views:
        if not isinstance(v, CameraView):
            raise HandEyeError(f"views: expected CameraView, got {type(v).__name__}")
        w, h = getattr(v.model, "width", None), getattr(v.model, "height", None)
        if not (isinstance(w, (int, np.integer)) and isinstance(h, (int, np.integer))
                and w > 0 and h > 0):
            raise HandEyeError(f"camera {v.name!r}: the model has no image size (width, "
                               "height): planning needs it to keep the board in view")
    kept, _ = validate_samples(samples)
    if len(kept) < MIN_SAMPLES:
        raise HandEyeError(f"planning needs at least {MIN_SAMPLES} samples, got {len(kept)}")
    names = {v.name for v in views}
    for s in kept:
        if not s.observations:
            raise HandEyeError(f"sample {s.name!r} has no corner observations: planning needs "
                               "the corners of every sample (images, not pose pairs)")
        for ob in s.observations:
            if ob.camera not in names:
                raise HandEyeError(f"sample {s.name!r}: corners from camera {ob.camera!r}, but "
                                   f"the rig has {sorted(names)}")
    try:
        X = as_transform(X, "X")
        if Y is None:
            bte = np.stack([s.base_T_ee for s in kept])
            ctb = np.stack([s.cam_T_board for s in kept])
            Y = average_transforms(board_in_fixed_frame(X, bte, ctb, setup))
        Y = as_transform(Y, "Y")
    except InputError as exc:
        raise HandEyeError(f"planning: {exc}") from exc
    return kept, X, Y, views


def _board_points(samples: Sequence[HandEyeSample]) -> tuple[np.ndarray, np.ndarray]:
    """Every distinct corner the samples saw, and the board's outline, board frame.

    Returns:
        ``(corners (M, 3), outline (4, 3))``: the outline is the corners' bounding rectangle
        in the board plane (its x-y plane when the corners lie in it, as every board of the
        package has them; else their principal plane) widened by one corner spacing on each
        side: the outer squares of a chessboard, which a detector needs to see.
    """
    pts = np.concatenate([ob.object_points for s in samples for ob in s.observations])
    pts = np.unique(np.round(pts, 9), axis=0)
    centre = pts.mean(axis=0)
    if np.ptp(pts[:, 2]) < 1e-9:
        axes = np.eye(3)[:2]
    else:
        axes = np.linalg.svd(pts - centre)[2][:2]
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.fill_diagonal(d, np.inf)
    spacing = float(np.median(d.min(axis=1)))
    uv = (pts - centre) @ axes.T
    lo, hi = uv.min(axis=0) - spacing, uv.max(axis=0) + spacing
    outline = np.array([centre + u * axes[0] + v * axes[1]
                        for u, v in ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]),
                                     (lo[0], hi[1]))])
    return pts, outline


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _flange(C: np.ndarray, X: np.ndarray, Y: np.ndarray, setup: str) -> np.ndarray:
    """The flange poses (N, 4, 4) at which the camera sees the board at ``C`` (N, 4, 4)."""
    if setup == "eye_in_hand":
        return Y @ invert_many(C) @ invert(X)
    return X @ C @ invert(Y)


@dataclass
class _Candidates:
    C: np.ndarray           # (K, 4, 4) cam_T_board
    B: np.ndarray           # (K, 4, 4) base_T_ee
    distance: np.ndarray    # (K,)
    tilt_deg: np.ndarray    # (K,)
    pixels: list[np.ndarray]  # per view, (K, M, 2)


def _draw(kept: Sequence[HandEyeSample], X: np.ndarray, Y: np.ndarray,
          views: Sequence[CameraView], setup: str, obj: np.ndarray, cfg: PlanConfig,
          rng: np.random.Generator, n: int) -> _Candidates:
    """``n`` candidate viewpoints, and which of them pass every limit."""
    centre = obj.mean(axis=0)
    _, _, vt = np.linalg.svd(obj - centre)
    normal = vt[2]
    cams = invert_many(np.stack([s.cam_T_board for s in kept]))     # board_T_cam
    rel = cams[:, :3, 3] - centre
    if np.mean(rel @ normal) < 0:
        normal = -normal                       # towards the side the cameras are on
    e1, e2 = _basis(normal)
    dist = np.linalg.norm(rel, axis=1)
    d_lo = dist.min() * (1.0 - cfg.distance_margin)
    d_hi = dist.max() * (1.0 + cfg.distance_margin)
    extent = np.abs((obj - centre) @ np.stack([e1, e2]).T).max(axis=0)
    tilt = np.radians(cfg.max_tilt_deg) * np.sqrt(rng.uniform(size=n))
    az = rng.uniform(0.0, 2 * np.pi, size=n)
    d = rng.uniform(d_lo, d_hi, size=n)
    off = rng.uniform(-0.3, 0.3, size=(n, 2)) * extent
    aim = centre + off[:, :1] * e1 + off[:, 1:] * e2
    direction = (np.cos(tilt)[:, None] * normal
                 + np.sin(tilt)[:, None] * (np.cos(az)[:, None] * e1 + np.sin(az)[:, None] * e2))
    pos = aim + d[:, None] * direction
    z = aim - pos
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    # roll: a reached camera's x axis, projected normal to z, turned by up to max_step_deg
    anchor = rng.integers(0, len(kept), size=n)
    x0 = cams[anchor, :3, 0]
    x0 = x0 - np.sum(x0 * z, axis=1, keepdims=True) * z
    bad = np.linalg.norm(x0, axis=1) < 1e-6
    x0[bad] = np.cross(z[bad], e1)
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    roll = np.radians(cfg.max_step_deg) * rng.uniform(-1.0, 1.0, size=n)
    y0 = np.cross(z, x0)
    x = np.cos(roll)[:, None] * x0 + np.sin(roll)[:, None] * y0
    y = np.cross(z, x)
    board_T_cam = np.zeros((n, 4, 4))
    board_T_cam[:, :3, :3] = np.stack([x, y, z], axis=2)
    board_T_cam[:, :3, 3] = pos
    board_T_cam[:, 3, 3] = 1.0
    C = invert_many(board_T_cam)
    B = _flange(C, X, Y, setup)
    return _Candidates(C, B, np.linalg.norm(pos - centre, axis=1),
                       np.degrees(np.arccos(np.clip(-(z @ normal), -1.0, 1.0))), [])


def _admissible(cand: _Candidates, kept: Sequence[HandEyeSample], views: Sequence[CameraView],
                obj: np.ndarray, outline: np.ndarray, cfg: PlanConfig,
                d_range: tuple[float, float]) -> np.ndarray:
    """Mask of the candidates within every limit; fills ``cand.pixels`` (the corners')."""
    ok = (cand.tilt_deg <= cfg.max_tilt_deg) & (cand.distance >= d_range[0]) \
        & (cand.distance <= d_range[1])
    every = np.concatenate([obj, outline])
    for v in views:
        T = v.view_T_cam @ cand.C
        pts = np.einsum("kij,mj->kmi", T[:, :3, :3], every) + T[:, None, :3, 3]
        in_front = np.all(pts[..., 2] > _MIN_DEPTH_M, axis=1)
        safe = np.where(pts[..., 2:3] > _MIN_DEPTH_M, pts, np.array([0.0, 0.0, 1.0]))
        px = project_points(safe.reshape(-1, 3), v.model.K, v.model.dist).reshape(
            pts.shape[0], pts.shape[1], 2)
        m = cfg.margin_px
        inside = np.all(np.isfinite(px), axis=(1, 2)) \
            & np.all((px[..., 0] >= m) & (px[..., 0] <= v.model.width - 1 - m)
                     & (px[..., 1] >= m) & (px[..., 1] <= v.model.height - 1 - m), axis=1)
        ok &= in_front & inside
        cand.pixels.append(px[:, :obj.shape[0]])
    reached = np.stack([s.base_T_ee for s in kept])
    dt = np.linalg.norm(cand.B[:, None, :3, 3] - reached[None, :, :3, 3], axis=2)
    Rrel = np.einsum("nji,kjl->knil", reached[:, :3, :3], cand.B[:, :3, :3])
    cos = np.clip((np.trace(Rrel, axis1=2, axis2=3) - 1.0) / 2.0, -1.0, 1.0)
    dr = np.degrees(np.arccos(cos))
    ok &= np.any((dt <= cfg.max_step_m) & (dr <= cfg.max_step_deg), axis=1)
    return ok


def _score(cov_x: np.ndarray, cfg: PlanConfig) -> np.ndarray:
    if cfg.criterion == "logdet":
        sign, logdet = np.linalg.slogdet(cov_x)
        return np.where(sign > 0, logdet, np.inf)
    mm, deg = _std(cov_x)
    return (mm / cfg.target_mm) ** 2 + (deg / cfg.target_deg) ** 2


def candidate_poses(samples: Sequence[HandEyeSample], X: np.ndarray, setup: str,
                    views: Sequence[CameraView], *, Y: np.ndarray | None = None,
                    config: PlanConfig = PlanConfig()
                    ) -> tuple[list[HandEyeSample], np.ndarray, np.ndarray]:
    """The admissible candidates, as noise-free samples (predicted corners), with their
    distances (m) and tilts (deg); arguments as :func:`suggest_next_poses`.

    Raises:
        HandEyeError: as :func:`suggest_next_poses`.
    """
    kept, X, Y, views = _check(samples, X, setup, views, Y)
    return _candidates(kept, X, Y, views, setup, config)


def _candidates(kept: list[HandEyeSample], X: np.ndarray, Y: np.ndarray,
                views: list[CameraView], setup: str, cfg: PlanConfig
                ) -> tuple[list[HandEyeSample], np.ndarray, np.ndarray]:
    obj, outline = _board_points(kept)
    rng = np.random.default_rng(cfg.seed)
    centre = obj.mean(axis=0)
    dist = np.linalg.norm(invert_many(np.stack([s.cam_T_board for s in kept]))[:, :3, 3]
                          - centre, axis=1)
    d_range = (dist.min() * (1.0 - cfg.distance_margin), dist.max() * (1.0 + cfg.distance_margin))
    out: list[HandEyeSample] = []
    dists: list[float] = []
    tilts: list[float] = []
    drawn = 0
    batch = max(4 * cfg.candidates, 256)
    while len(out) < cfg.candidates and drawn < _MAX_DRAW_FACTOR * cfg.candidates:
        cand = _draw(kept, X, Y, views, setup, obj, cfg, rng, batch)
        drawn += batch
        ok = np.flatnonzero(_admissible(cand, kept, views, obj, outline, cfg, d_range))
        for k in ok[:cfg.candidates - len(out)]:
            obs = tuple(CornerObservation(v.name, obj, px[k])
                        for v, px in zip(views, cand.pixels, strict=True))
            out.append(HandEyeSample(f"candidate{len(out):04d}", cand.B[k], cand.C[k], obs))
            dists.append(float(cand.distance[k]))
            tilts.append(float(cand.tilt_deg[k]))
    if not out:
        raise HandEyeError(
            f"no admissible pose among {drawn} candidates: none keeps the whole board "
            f"(its outer squares too) {cfg.margin_px:g} px inside every image within "
            f"{cfg.max_tilt_deg:g} deg of tilt, "
            f"{d_range[0]:.3f}-{d_range[1]:.3f} m and {cfg.max_step_m:g} m / "
            f"{cfg.max_step_deg:g} deg of a reached pose: relax the limits")
    return out, np.array(dists), np.array(tilts)


def suggest_next_poses(samples: Sequence[HandEyeSample], X: np.ndarray, setup: str,
                       views: Sequence[CameraView], *, Y: np.ndarray | None = None,
                       config: PlanConfig = PlanConfig()) -> Plan:
    """The next flange poses that would most reduce the uncertainty of X.

    Args:
        samples: the samples taken, with their corner observations (at least 3).
        X: the current hand-eye estimate, shape (4, 4): ``ee_T_cam`` eye-in-hand,
            ``base_T_cam`` eye-to-hand.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        views: the rig's cameras (each model with ``K``, ``dist``, ``width``, ``height``).
        Y: the board pose in its fixed frame (``base_T_board`` eye-in-hand, ``ee_T_board``
            eye-to-hand); the mean of the samples' by default.
        config: the limits, noise levels and criterion.

    Returns:
        The plan: predicted 1-sigma now and ``config.count`` suggestions (fewer if fewer
        candidates are admissible), best first, each with the 1-sigma once it is taken.

    Raises:
        HandEyeError: unknown setup, fewer than 3 samples, a sample without corners or with
            corners from a camera not in ``views``, a camera without an image size, bad X or
            Y, or no admissible candidate (the message names the limits).
    """
    kept, X, Y, views = _check(samples, X, setup, views, Y)
    sig = config.sigmas()
    S = _information(kept, X, Y, views, setup, sig).sum(axis=0)
    mm0, deg0 = _std(_x_covariance(S))
    cands, dists, tilts = _candidates(kept, X, Y, views, setup, config)
    info = _information(cands, X, Y, views, setup, sig)
    free = np.ones(len(cands), dtype=bool)
    out: list[Suggestion] = []
    for _ in range(min(config.count, len(cands))):
        idx = np.flatnonzero(free)
        cov = _x_covariance(S[None] + info[idx])
        j = int(np.argmin(_score(cov, config)))
        k = idx[j]
        S = S + info[k]
        free[k] = False
        mm, deg = _std(cov[j])
        out.append(Suggestion(base_T_ee=cands[k].base_T_ee, cam_T_board=cands[k].cam_T_board,
                              std_mm=float(mm), std_deg=float(deg),
                              distance_m=float(dists[k]), tilt_deg=float(tilts[k])))
    return Plan(suggestions=out, std_mm=float(mm0), std_deg=float(deg0),
                candidates=len(cands), criterion=config.criterion, sigmas=sig)
