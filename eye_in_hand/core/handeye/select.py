"""Choosing the hand-eye result by leave-one-out prediction of the held-out samples.

Every method (each closed form, the exact-pose refinement and the errors-in-variables
refinement) is solved once without each sample in turn; the solution without sample ``i``
then predicts what sample ``i`` measured from its *reported* robot pose:

* the board's corners in pixels (with corners): ``cam_T_board = inv(X) inv(G_i) Y`` projected
  through every camera of the rig, compared with the detected corners (RMS px over the corners);
* the board in its fixed frame: ``G_i X cam_T_board[i]`` against the ``Y`` of the solution
  without the sample (mm, deg).

This is the error a calibration makes where it is used: predicting where something seen by the
camera is in the robot's frame, from a robot pose as the robot reports it. The method with the
lowest held-out figure is written: the RMS held-out corner error when every sample has corners,
else the held-out board error in the fixed frame, millimetres and degrees each divided by their
median over the methods and summed.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .refine import reprojection_errors
from .samples import CameraView, HandEyeSample
from .solvers import board_in_fixed_frame

__all__ = ["HeldOut", "held_out_prediction", "selection_scores"]


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
    for i, ((X, Y), s) in enumerate(zip(solutions, samples)):
        Yi = board_in_fixed_frame(X, s.base_T_ee[None], s.cam_T_board[None], setup)[0]
        mm[i] = 1000.0 * float(np.linalg.norm(Yi[:3, 3] - Y[:3, 3]))
        deg[i] = float(np.degrees(np.linalg.norm(
            Rotation.from_matrix(Y[:3, :3].T @ Yi[:3, :3]).as_rotvec())))
        if px is not None:
            assert cameras is not None
            e = reprojection_errors(X, Y, [s], cameras, setup)[0]
            px[i] = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
    return HeldOut(px, mm, deg)


def selection_scores(held_out: dict[str, HeldOut]) -> tuple[dict[str, float], str]:
    """The selection score of every method (lower is better) and what it measures.

    Args:
        held_out: the held-out figures by method.

    Returns:
        ``(scores, criterion)``.
    """
    if held_out and all(h.px is not None for h in held_out.values()):
        return ({k: float(np.sqrt(np.mean(h.px ** 2))) for k, h in held_out.items()},  # type: ignore[operator]
                "held-out corner RMS (px)")
    mm = {k: float(np.sqrt(np.mean(h.mm ** 2))) for k, h in held_out.items()}
    deg = {k: float(np.sqrt(np.mean(h.deg ** 2))) for k, h in held_out.items()}
    ref_mm = max(float(np.median(list(mm.values()))), 1e-12)
    ref_deg = max(float(np.median(list(deg.values()))), 1e-12)
    return ({k: mm[k] / ref_mm + deg[k] / ref_deg for k in held_out},
            "held-out board pose in the fixed frame (mm and deg, each over its median)")
