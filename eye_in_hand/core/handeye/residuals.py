"""Per-motion residuals of the hand-eye equation AX = XB, per method (report tables).

For every motion ``(A, B)`` (all sample pairs ``i < j``, as the solvers use them,
:func:`.solvers.motion_pairs`) and a method's X:

* ``rot_deg``: the rotation angle of ``E = inv(A X) X B`` (degrees);
* ``trans_mm``: the norm of the translation of ``E`` (millimetres), equal to the norm of the
  translation column of ``A X - X B``;
* ``frobenius``: the Frobenius norm of ``A X - X B`` (4x4, translations in metres), i.e.
  ``sqrt(8 sin^2(rot/2) + trans_m^2)``.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import invert_many

from .solvers import gripper_poses, motion_pairs

__all__ = ["QUANTITIES", "motion_residuals", "motion_residual_table"]

#: The residual quantities, in table order.
QUANTITIES = ("rot_deg", "trans_mm", "frobenius")


def motion_residuals(X: np.ndarray, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                     setup: str) -> dict[str, np.ndarray]:
    """The AX = XB residual of every motion (see the module docstring).

    Args:
        X: the hand-eye transform, shape (4, 4).
        base_T_ee: robot poses, shape (N, 4, 4).
        cam_T_board: board poses, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        ``index`` (K, 2) sample indices ``(i, j)`` and ``rot_deg``, ``trans_mm``,
        ``frobenius`` of shape (K,) each, K = N (N - 1) / 2.
    """
    X = np.asarray(X, dtype=np.float64)
    m = motion_pairs(gripper_poses(np.asarray(base_T_ee, dtype=np.float64), setup),
                     np.asarray(cam_T_board, dtype=np.float64))
    AX = m.A @ X
    XB = X @ m.B
    E = invert_many(AX) @ XB
    return {"index": m.index,
            "rot_deg": np.degrees(np.linalg.norm(
                Rotation.from_matrix(E[:, :3, :3]).as_rotvec(), axis=1)),
            "trans_mm": 1000.0 * np.linalg.norm(E[:, :3, 3], axis=1),
            "frobenius": np.linalg.norm((AX - XB).reshape(len(m), -1), axis=1)}


def _stats(v: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(v)), "median": float(np.median(v)), "max": float(np.max(v))}


def motion_residual_table(transforms: Mapping[str, np.ndarray], base_T_ee: np.ndarray,
                          cam_T_board: np.ndarray, setup: str,
                          sample_names: Sequence[str]) -> dict[str, Any]:
    """The per-motion residual table of several methods (report.json ``motion_residuals``).

    Args:
        transforms: X by method name (the table's column order).
        base_T_ee: robot poses of the samples used, shape (N, 4, 4).
        cam_T_board: board poses, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        sample_names: the N sample names.

    Returns:
        ``{"motions": [[name_i, name_j], ...] (K rows), "methods": [...], "rot_deg": {method:
        [K]}, "trans_mm": {...}, "frobenius": {...}, "summary": {method: {quantity: {"mean",
        "median", "max"}}}, "units": {...}}``.
    """
    names = list(sample_names)
    out: dict[str, Any] = {"motions": [], "methods": list(transforms),
                           **{q: {} for q in QUANTITIES}, "summary": {},
                           "units": {"rot_deg": "deg, rotation angle of inv(AX) XB",
                                     "trans_mm": "mm, translation norm of inv(AX) XB",
                                     "frobenius": "||AX - XB||_F, translations in metres"}}
    for name, X in transforms.items():
        r = motion_residuals(X, base_T_ee, cam_T_board, setup)
        if not out["motions"]:
            out["motions"] = [[names[i], names[j]] for i, j in r["index"].tolist()]
        for q in QUANTITIES:
            out[q][name] = r[q].tolist()
        out["summary"][name] = {q: _stats(r[q]) for q in QUANTITIES}
    return out
