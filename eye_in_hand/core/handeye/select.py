"""Choosing the hand-eye result by leave-one-out prediction of the held-out samples.

Every method (each closed form, the exact-pose refinement and the errors-in-variables
refinement) is solved once without each sample in turn; the solution without sample ``i``
then predicts what sample ``i`` measured from its *reported* robot pose:

* the board's corners in pixels (with corners): ``cam_T_board = inv(X) inv(G_i) Y`` projected
  through every camera of the rig, compared with the detected corners (RMS px over the corners);
* the board in its fixed frame: ``G_i X cam_T_board[i]`` against the ``Y`` of the solution
  without the sample (mm, deg).

This is the error a calibration makes where it is used: predicting where something seen by the
camera is in the robot's frame, from a robot pose as the robot reports it. Each sample's error
is the held-out corner error (px) when every sample has corners, else the held-out board
position (mm) and orientation (deg) in the fixed frame, each divided by its median RMS over the
methods (its own noise scale), combined as the root of their sum of squares. With
``combine=True`` (the systematic robot model) the corner error and the board position are
combined that way. The score is the RMS over the samples.

The method with the lowest score is written, unless the errors-in-variables refinement
(``refined``, the one whose covariance accounts for both noise sources) predicts the held-out
samples as well within the statistical noise of the comparison: the per-sample differences of
the squared held-out errors between the two, paired over the samples, must be below zero by
more than twice their standard error for another method to replace it. When the robot poses are
noisy, each held-out prediction carries that sample's own robot error, which is the same for
every method; the paired test keeps a method from being written on the strength of that noise
alone. With the systematic robot model ``refined`` is still the reference: ``refined_systematic``
is written only when it passes that test against it.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .refine import _project, perturb, reprojection_errors
from .samples import CameraView, HandEyeSample
from .solvers import board_in_fixed_frame

__all__ = ["HeldOut", "held_out_prediction", "selection_scores", "choose",
           "held_out_position_sigma"]


@dataclass(frozen=True)
class HeldOut:
    """Leave-one-out prediction figures of one method, per sample (sample order).

    Attributes:
        px: RMS corner error of each held-out sample, px, shape (N,); None without corners.
        mm, deg: the held-out sample's board pose in the fixed frame against the solution's,
            shape (N,) each.
    """

    px: np.ndarray | None
    mm: np.ndarray
    deg: np.ndarray

    def summary(self) -> dict[str, float | None]:
        """RMS figures for report.json."""
        def rms(a: np.ndarray | None) -> float | None:
            return None if a is None else float(np.sqrt(np.mean(a ** 2)))

        return {"px_rms": rms(self.px), "mm_rms": rms(self.mm), "deg_rms": rms(self.deg)}


def held_out_prediction(solutions: Sequence[tuple[np.ndarray, np.ndarray]],
                        samples: Sequence[HandEyeSample],
                        cameras: Sequence[CameraView] | None, setup: str) -> HeldOut:
    """Predict each sample from the solution computed without it.

    Args:
        solutions: ``(X, Y)`` without sample ``i``, for every sample, in order.
        samples: the samples.
        cameras: the rig's cameras (corner figures when given and every sample has corners).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        The figures.
    """
    n = len(samples)
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in samples)
    px = np.zeros(n) if use_corners else None
    mm = np.zeros(n)
    deg = np.zeros(n)
    for i, ((X, Y), s) in enumerate(zip(solutions, samples, strict=True)):
        Yi = board_in_fixed_frame(X, s.base_T_ee[None], s.cam_T_board[None], setup)[0]
        mm[i] = 1000.0 * float(np.linalg.norm(Yi[:3, 3] - Y[:3, 3]))
        deg[i] = float(np.degrees(np.linalg.norm(
            Rotation.from_matrix(Y[:3, :3].T @ Yi[:3, :3]).as_rotvec())))
        if px is not None:
            assert cameras is not None
            e = reprojection_errors(X, Y, [s], cameras, setup)[0]
            px[i] = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
    return HeldOut(px, mm, deg)


def _per_sample(held_out: dict[str, HeldOut],
                combine: bool = False) -> tuple[dict[str, np.ndarray], str]:
    """Each method's per-sample held-out error (the quantity whose RMS is the score)."""
    ref_mm = max(float(np.median([np.sqrt(np.mean(h.mm ** 2)) for h in held_out.values()])),
                 1e-12)
    corners = bool(held_out) and all(h.px is not None for h in held_out.values())
    if corners and not combine:
        return ({k: np.asarray(h.px) for k, h in held_out.items()},
                "held-out corner RMS (px)")
    if corners:
        ref_px = max(float(np.median([np.sqrt(np.mean(np.asarray(h.px) ** 2))
                                      for h in held_out.values()])), 1e-12)
        return ({k: np.hypot(np.asarray(h.px) / ref_px, h.mm / ref_mm)
                 for k, h in held_out.items()},
                "held-out corners (px) and board position (mm), each over its median RMS")
    ref_deg = max(float(np.median([np.sqrt(np.mean(h.deg ** 2)) for h in held_out.values()])),
                  1e-12)
    return ({k: np.hypot(h.mm / ref_mm, h.deg / ref_deg) for k, h in held_out.items()},
            "held-out board pose in the fixed frame (mm and deg, each over its median RMS)")


def selection_scores(held_out: dict[str, HeldOut],
                     combine: bool = False) -> tuple[dict[str, float], str]:
    """The selection score of every method (lower is better) and what it measures.

    Args:
        held_out: the held-out figures by method.
        combine: score corners (px) and board position (mm) together (module docstring).

    Returns:
        ``(scores, criterion)``: the RMS over the samples of each method's held-out error.
    """
    per, criterion = _per_sample(held_out, combine)
    return {k: float(np.sqrt(np.mean(v ** 2))) for k, v in per.items()}, criterion


def choose(held_out: dict[str, HeldOut], candidates: Sequence[str],
           reference: str = "refined", combine: bool = False) -> tuple[str, str]:
    """Pick the result among ``candidates`` (see the module docstring for the rule).

    Args:
        held_out: the held-out figures by method.
        candidates: the methods that may be written.
        reference: the method kept unless another predicts significantly better.
        combine: score corners (px) and board position (mm) together (module docstring).

    Returns:
        ``(method, reason)``.
    """
    per, criterion = _per_sample(held_out, combine)
    scores = {k: float(np.sqrt(np.mean(per[k] ** 2))) for k in candidates}
    best = min(scores, key=lambda k: scores[k])
    others = ", ".join(f"{k} {v:.4g}" for k, v in sorted(scores.items(),
                                                         key=lambda kv: kv[1]) if k != best)
    if reference not in scores or best == reference:
        return best, f"lowest {criterion}: {best} {scores[best]:.4g} (then {others})"
    d = per[best] ** 2 - per[reference] ** 2
    se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("inf")
    if float(np.mean(d)) < -2.0 * se:
        return best, (f"lowest {criterion}: {best} {scores[best]:.4g}, significantly below "
                      f"{reference} {scores[reference]:.4g} (paired over the samples; then "
                      f"{others})")
    return reference, (f"{criterion}: {reference} {scores[reference]:.4g} is within the noise of "
                       f"the lowest, {best} {scores[best]:.4g} (paired over the samples, under 2 "
                       "standard errors), and its covariance models both noise sources")


def _centre_variance(s: HandEyeSample, cameras: Sequence[CameraView], px_sigma: float,
                     c: np.ndarray) -> float:
    """Trace of the covariance (m^2) of the board point ``c`` (board frame) in the camera, as
    the sample's board pose ``cam_T_board`` was measured: PnP on its first observation's
    corners (:func:`.observe.observe_sample`), ``px_sigma^2 (J^T J)^-1`` of the pose's six
    parameters, propagated to the point."""
    views = {v.name: v for v in cameras}
    C0 = s.cam_T_board
    h = 1e-7
    ob = s.observations[0]

    def corners(C: np.ndarray) -> np.ndarray:
        return _project(views[ob.camera], C, ob.object_points).ravel()

    f0 = corners(C0)
    J = np.zeros((f0.size, 6))
    Jc = np.zeros((3, 6))
    base = np.concatenate([C0[:3, 3], np.zeros(3)])
    for j in range(6):
        d = base.copy()
        d[j] += h
        C = perturb(C0, d)
        J[:, j] = (corners(C) - f0) / h
        Jc[:, j] = ((C[:3, :3] @ c + C[:3, 3]) - (C0[:3, :3] @ c + C0[:3, 3])) / h
    try:
        cov = px_sigma ** 2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return 0.0
    return float(np.trace(Jc @ cov @ Jc.T))


def held_out_position_sigma(solutions: Sequence[tuple[np.ndarray, np.ndarray]],
                            samples: Sequence[HandEyeSample], setup: str,
                            rotation_sigma_rad: float,
                            cameras: Sequence[CameraView] | None = None,
                            px_sigma: float | None = None) -> tuple[float, float]:
    """Per-pose position noise (1 sigma per axis) that the held-out board positions show.

    Each sample's board centre (the mean of its corners in the board frame; the board origin
    without corners) is mapped into the fixed frame through its *reported* robot pose and the
    solution without it, and compared with that solution's board: the error a base-frame
    position seen by the camera makes at a pose the calibration did not use. Its mean square
    ``m`` holds the robot's translation noise (3 ``s_t^2``), its rotation noise about the
    flange at the centre's lever arm ``l_i`` (``2 s_r^2 |l_i|^2``), the held-out view's own
    measurement noise of the centre (``v_i``: the trace of its covariance from the corners at
    ``px_sigma``, as :func:`_centre_variance`; 0 without corners), and whatever else scatters
    from pose to pose (an intrinsic or stereo calibration error seen from another distance and
    angle). All of it but the rotation and measurement terms is given to ``s_t``::

        s_t^2 = max(0, mean_i(|e_i|^2 - 2 s_r^2 |l_i|^2 - v_i)) / 3

    An upper bound of the robot's own translation noise, and the honest per-pose position
    scatter of the camera-to-base chain as the localization uses it. Like every figure
    computed from the calibration's own data it cannot see an error common to all samples
    (see :mod:`eye_in_hand.core.localization`).

    Args:
        solutions: ``(X, Y)`` without sample ``i``, for every sample, in order.
        samples: the samples.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        rotation_sigma_rad: the robot's rotation noise about the flange, per axis (rad).
        cameras: the rig's cameras (the centre's measurement noise is subtracted when given
            and every sample has corners).
        px_sigma: the corners' pixel noise (1 sigma per coordinate), with ``cameras``.

    Returns:
        ``(s_t (m), rms (m))``: the sigma and the RMS held-out centre error (norm).
    """
    sq = []
    lever_sq = []
    meas = []
    use_corners = (bool(cameras) and px_sigma is not None
                   and all(len(s.observations) > 0 for s in samples))
    for (X, Y), s in zip(solutions, samples, strict=True):
        c = (np.mean(s.observations[0].object_points, axis=0) if s.observations
             else np.zeros(3))
        Yi = board_in_fixed_frame(X, s.base_T_ee[None], s.cam_T_board[None], setup)[0]
        e = (Yi[:3, :3] @ c + Yi[:3, 3]) - (Y[:3, :3] @ c + Y[:3, 3])
        sq.append(float(e @ e))
        # the centre in the flange frame: the lever arm of a flange rotation error
        if setup == "eye_in_hand":
            p_fixed = Y[:3, :3] @ c + Y[:3, 3]                   # base frame
            p_ee = s.base_T_ee[:3, :3].T @ (p_fixed - s.base_T_ee[:3, 3])
        else:
            p_ee = Y[:3, :3] @ c + Y[:3, 3]                      # board on the flange
        lever_sq.append(float(p_ee @ p_ee))
        if use_corners:
            assert cameras is not None and px_sigma is not None
            meas.append(_centre_variance(s, cameras, px_sigma, c))
    m = np.asarray(sq)
    excess = float(np.mean(m - 2.0 * rotation_sigma_rad ** 2 * np.asarray(lever_sq)
                           - (np.asarray(meas) if meas else 0.0)))
    return float(np.sqrt(max(0.0, excess) / 3.0)), float(np.sqrt(np.mean(m)))
