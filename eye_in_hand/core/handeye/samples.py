"""Hand-eye samples, their validation and the motion diagnostics run before solving."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import as_transform
from eye_in_hand.errors import HandEyeError, InputError

from .solvers import SETUPS, gripper_poses, motion_pairs

__all__ = [
    "corner_blocks",
    "CornerObservation",
    "CameraView",
    "HandEyeSample",
    "MotionDiagnostics",
    "validate_samples",
    "motion_diagnostics",
    "MIN_SAMPLES",
]

#: Fewest samples the solvers accept.
MIN_SAMPLES = 3

# Motion thresholds (degrees). Below the error levels the rotation is not determined.
_MIN_ROTATION_DEG = 0.5          # a motion rotating less than this carries no rotation axis
_ERROR_AXIS_SPREAD_DEG = 1.0     # all axes within this of each other: rotation undetermined
_WARN_AXIS_SPREAD_DEG = 15.0
_WARN_MAX_ROTATION_DEG = 10.0
_DUPLICATE_ATOL = 1e-9


@dataclass(frozen=True)
class CornerObservation:
    """Board corners seen by one camera in one sample.

    Attributes:
        camera: name of the :class:`CameraView` that saw them (``"left"``, ``"right"``, ...).
        object_points: corners in the board frame, shape (N, 3), metres.
        image_points: their distorted pixels in that camera, shape (N, 2).
    """

    camera: str
    object_points: np.ndarray
    image_points: np.ndarray

    def __post_init__(self) -> None:
        obj = np.asarray(self.object_points, dtype=np.float64)
        img = np.asarray(self.image_points, dtype=np.float64)
        if obj.ndim != 2 or obj.shape[1] != 3 or img.shape != (obj.shape[0], 2):
            raise InputError(f"corner observation ({self.camera}): expected object_points (N, 3) "
                             f"and image_points (N, 2), got {obj.shape} and {img.shape}")
        if obj.shape[0] < 4 or not (np.all(np.isfinite(obj)) and np.all(np.isfinite(img))):
            raise InputError(f"corner observation ({self.camera}): need >= 4 finite corners")
        object.__setattr__(self, "object_points", obj)
        object.__setattr__(self, "image_points", img)


@dataclass(frozen=True)
class CameraView:
    """A camera of the (mono or stereo) rig, for the reprojection refinement.

    Attributes:
        name: matches :attr:`CornerObservation.camera`.
        model: the intrinsics: any object with ``K`` (3, 3) and ``dist`` (n,) in OpenCV's
            order, e.g. :class:`eye_in_hand.core.camera.CameraModel`.
        view_T_cam: maps points in the hand-eye camera frame (the left optical frame) into this
            camera's frame, shape (4, 4): identity for the left camera, ``right_T_left`` for
            the right one.
    """

    name: str
    model: Any
    view_T_cam: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        object.__setattr__(self, "view_T_cam", as_transform(self.view_T_cam,
                                                            f"camera {self.name}: view_T_cam"))


@dataclass(frozen=True)
class HandEyeSample:
    """One robot pose and the board pose seen from the camera at that pose.

    Attributes:
        name: identifies the sample in every message and report (file name, index).
        base_T_ee: robot flange pose in the base frame, shape (4, 4).
        cam_T_board: board pose in the (left) camera frame, shape (4, 4), e.g. from PnP.
        observations: the corners behind ``cam_T_board`` (empty for pose-pairs input).
    """

    name: str
    base_T_ee: np.ndarray
    cam_T_board: np.ndarray
    observations: tuple[CornerObservation, ...] = ()


@dataclass(frozen=True)
class MotionDiagnostics:
    """How well the robot motions constrain X, computed before solving.

    Attributes:
        n_samples: number of samples.
        n_motions: number of sample pairs with a usable rotation (> 0.5 deg).
        rotation_deg: (min, median, max) rotation angle between samples, degrees.
        axis_spread_deg: largest angle between the rotation axes of two motions (0..90).
        axis_eigenvalues: normalised eigenvalues (descending, sum 1) of the scatter matrix of the
            motion axes weighted by ``sin(angle / 2)``: (1, 0, 0) means one axis only.
        rotation_condition: condition number of the rotation system (Tsai-Lenz form).
        translation_condition: condition number of ``sum (I - R_A)^T (I - R_A)``.
        warnings: weak-motion warnings, each a sentence that says what to add.
    """

    n_samples: int
    n_motions: int
    rotation_deg: tuple[float, float, float]
    axis_spread_deg: float
    axis_eigenvalues: tuple[float, float, float]
    rotation_condition: float
    translation_condition: float
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for report.json."""
        return {
            "n_samples": self.n_samples,
            "n_motions": self.n_motions,
            "rotation_deg": {"min": self.rotation_deg[0], "median": self.rotation_deg[1],
                             "max": self.rotation_deg[2]},
            "axis_spread_deg": self.axis_spread_deg,
            "axis_eigenvalues": list(self.axis_eigenvalues),
            "rotation_condition": self.rotation_condition,
            "translation_condition": self.translation_condition,
            "warnings": list(self.warnings),
        }


def validate_samples(samples: Sequence[HandEyeSample]) -> tuple[list[HandEyeSample], list[str]]:
    """Check every sample and drop exact duplicates.

    Args:
        samples: the samples, in order.

    Returns:
        ``(kept, warnings)``: the samples to use, and one warning per dropped duplicate or
        repeated robot pose, naming the samples.

    Raises:
        HandEyeError: a pose with NaN, wrong shape, bad last row or a non-orthonormal rotation,
            or two samples with the same name; the message names the sample and the field.
    """
    kept: list[HandEyeSample] = []
    warnings: list[str] = []
    names: set[str] = set()
    for index, sample in enumerate(samples):
        if not isinstance(sample, HandEyeSample):
            raise HandEyeError(f"sample {index}: expected a HandEyeSample, got "
                               f"{type(sample).__name__}")
        label = f"sample {sample.name!r} (#{index})"
        if sample.name in names:
            raise HandEyeError(f"{label}: duplicate sample name")
        names.add(sample.name)
        try:
            bte = as_transform(sample.base_T_ee, "base_T_ee")
            ctb = as_transform(sample.cam_T_board, "cam_T_board")
        except InputError as exc:
            raise HandEyeError(f"{label}: {exc}") from exc
        duplicate = False
        for other in kept:
            same_robot = np.max(np.abs(other.base_T_ee - bte)) <= _DUPLICATE_ATOL
            if same_robot and np.max(np.abs(other.cam_T_board - ctb)) <= _DUPLICATE_ATOL:
                warnings.append(f"{label} duplicates sample {other.name!r}: dropped")
                duplicate = True
                break
            if same_robot:
                warnings.append(f"{label} has the same robot pose as sample {other.name!r}: "
                                "it adds no motion (kept for averaging)")
                break
        if not duplicate:
            kept.append(HandEyeSample(sample.name, bte, ctb, tuple(sample.observations)))
    return kept, warnings


def motion_diagnostics(base_T_ee: np.ndarray, setup: str) -> MotionDiagnostics:
    """Analyse the robot motions before solving.

    Args:
        base_T_ee: robot poses, shape (N, 4, 4) (validated).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        The diagnostics, with warnings for weak motion.

    Raises:
        HandEyeError: fewer than 3 samples, no rotation between samples, or rotations about
            (nearly) parallel axes only; the message says what motion to add.
    """
    if setup not in SETUPS:
        raise HandEyeError(f"setup: expected one of {', '.join(SETUPS)}, got {setup!r}")
    poses = np.asarray(base_T_ee, dtype=np.float64)
    n = poses.shape[0]
    if n < MIN_SAMPLES:
        raise HandEyeError(f"hand-eye calibration needs at least {MIN_SAMPLES} samples with "
                           f"rotations about different axes, got {n}: add samples")
    G = gripper_poses(poses, setup)
    m = motion_pairs(G, np.repeat(np.eye(4)[None], n, axis=0))
    rv = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    angles = np.linalg.norm(rv, axis=1)
    deg = np.degrees(angles)
    usable = deg > _MIN_ROTATION_DEG
    stats = (float(deg.min()), float(np.median(deg)), float(deg.max()))
    if not np.any(usable):
        raise HandEyeError(
            f"the robot barely rotates between samples (largest rotation {stats[2]:.2f} deg): "
            "hand-eye rotation is undetermined; add samples that tilt the tool by 20-60 deg "
            "about at least two different axes")
    axes = rv[usable] / angles[usable, None]
    weights = np.sin(angles[usable] / 2.0)
    scatter = (axes * weights[:, None] ** 2).T @ axes
    ev = np.sort(np.linalg.eigvalsh(scatter))[::-1]
    ev = np.clip(ev / ev.sum(), 0.0, 1.0)
    cosines = np.clip(np.abs(axes @ axes.T), 0.0, 1.0)
    spread = float(np.degrees(np.arccos(cosines.min())))
    principal = np.linalg.eigh(scatter)[1][:, -1]
    if spread < _ERROR_AXIS_SPREAD_DEG:
        raise HandEyeError(
            f"all robot rotations between samples are about (nearly) the same axis "
            f"({np.round(principal, 3).tolist()} in the "
            f"{'flange' if setup == 'eye_in_hand' else 'base'} frame, spread {spread:.2f} deg): "
            "the hand-eye rotation about that axis is undetermined; add samples that rotate the "
            "tool about a different axis (tilt it by 20-60 deg)")
    # Conditioning of the linear systems the closed forms solve.
    qa = Rotation.from_matrix(m.A[usable, :3, :3]).as_quat()
    qa[qa[:, 3] < 0] *= -1.0
    Pa = 2.0 * qa[:, :3]
    S = np.zeros((Pa.shape[0], 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -Pa[:, 2], Pa[:, 1], -Pa[:, 0]
    S = S - np.swapaxes(S, 1, 2)
    sv = np.linalg.svd(S.reshape(-1, 3), compute_uv=False)
    rot_cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    IR = np.eye(3) - m.A[:, :3, :3]
    tsv = np.linalg.svd(IR.reshape(-1, 3), compute_uv=False)
    trans_cond = float(tsv[0] / tsv[-1]) if tsv[-1] > 0 else float("inf")
    warnings: list[str] = []
    if spread < _WARN_AXIS_SPREAD_DEG:
        warnings.append(
            f"weak rotation-axis spread ({spread:.1f} deg < {_WARN_AXIS_SPREAD_DEG:.0f} deg): "
            "rotate the tool about more varied axes")
    if stats[2] < _WARN_MAX_ROTATION_DEG:
        warnings.append(
            f"small rotations between samples (largest {stats[2]:.1f} deg): larger tilts "
            "(20-60 deg) make the result much less sensitive to noise")
    if n < 6:
        warnings.append(f"only {n} samples: 10-20 well-spread samples are recommended")
    return MotionDiagnostics(
        n_samples=n, n_motions=int(usable.sum()), rotation_deg=stats, axis_spread_deg=spread,
        axis_eigenvalues=(float(ev[0]), float(ev[1]), float(ev[2])),
        rotation_condition=rot_cond, translation_condition=trans_cond,
        warnings=tuple(warnings))


def corner_blocks(samples: Sequence[HandEyeSample], cameras: Sequence[CameraView]
                  ) -> list[tuple[CameraView, np.ndarray, np.ndarray, np.ndarray]]:
    """Every corner of every sample, per camera, for vectorised reprojection models.

    Returns:
        One ``(camera, sample_index (N,), object_points (N, 3), image_points (N, 2))`` per
        camera that has corners.

    Raises:
        HandEyeError: a sample has corners from a camera that ``cameras`` lacks.
    """
    views = {c.name: c for c in cameras}
    for s in samples:
        for ob in s.observations:
            if ob.camera not in views:
                raise HandEyeError(f"sample {s.name!r}: corners from camera {ob.camera!r}, "
                                   f"but the rig has {sorted(views)}")
    blocks = []
    for cam in cameras:
        obs = [(k, ob) for k, s in enumerate(samples) for ob in s.observations
               if ob.camera == cam.name]
        if not obs:
            continue
        idx = np.concatenate([np.full(ob.object_points.shape[0], k) for k, ob in obs])
        obj = np.concatenate([ob.object_points for _, ob in obs])
        img = np.concatenate([ob.image_points for _, ob in obs])
        blocks.append((cam, idx, obj, img))
    return blocks
