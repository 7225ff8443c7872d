"""A pose-dependent correction of the robot's reported flange poses.

Real arms report poses whose error is mostly systematic: it changes smoothly with the arm's
configuration (joint offsets, link lengths, compliance). The hand-eye calibration's
``refined_systematic`` model (:mod:`eye_in_hand.core.handeye.systematic`) estimates the
first-order term of that error in the flange orientation, and its X holds only with the robot
poses corrected by it. This module is that correction, used the same way by the calibration,
the live ``hand_eye`` node and ``process`` (:class:`eye_in_hand.core.localization.Localizer`)::

    r        = log(R_ref^T R)                 the reported flange orientation relative to R_ref
    true     = reported @ [exp(A_r r) | A_t r]   (error on the right, in the flange frame)

``A_r`` (3x3, rad per rad) and ``A_t`` (3x3, metres per rad) are the model's parameters and
``R_ref`` the mean flange orientation of the calibration samples. In ``hand_eye.yaml`` it is the
``robot_pose_correction`` block (:mod:`eye_in_hand.io.config`).

The correction is a first-order model fitted on the calibration's poses: far from their
orientations it is an extrapolation (docs/handeye.md, "Systematic robot error").

Pure numpy: no rclpy, no SciPy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from eye_in_hand.errors import InputError

__all__ = ["MODEL", "RobotPoseCorrection", "exp_rotations", "log_rotations",
           "orientation_features"]

#: The model name written in ``hand_eye.yaml``.
MODEL = "flange_orientation_linear"


def exp_rotations(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, rotation vectors (N, 3) -> matrices (N, 3, 3)."""
    th2 = np.sum(w * w, axis=1)
    th = np.sqrt(th2)
    small = th < 1e-6
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    out: np.ndarray = np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)
    return out


def log_rotations(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) -> rotation vectors (N, 3), also near a half turn."""
    c = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]],
                 axis=1)
    # atan2(sin, cos): accurate at every angle, where arccos loses half the digits near 0, pi
    th = np.arctan2(0.5 * np.linalg.norm(v, axis=1), c)
    small = th < 1e-6
    f = np.where(small, 0.5 + th * th / 12.0, th / (2.0 * np.sin(np.where(small, 1.0, th))))
    out: np.ndarray = f[:, None] * v
    big = th > 3.0
    if np.any(big):
        # near pi the antisymmetric part vanishes: the axis from the symmetric part
        for i in np.flatnonzero(big):
            S = 0.5 * (R[i] + R[i].T) - np.eye(3) * c[i]
            k = int(np.argmax(np.diag(S)))
            axis = S[k] / np.linalg.norm(S[k])
            if axis @ v[i] < 0:
                axis = -axis
            out[i] = th[i] * axis
    return out


def orientation_features(R_ref: np.ndarray, base_T_ee: np.ndarray) -> np.ndarray:
    """``r = log(R_ref^T R)`` of each pose (N, 4, 4) -> (N, 3) radians: the model's input."""
    return log_rotations(np.einsum("ji,njk->nik", R_ref, base_T_ee[:, :3, :3]))


@dataclass(frozen=True)
class RobotPoseCorrection:
    """The systematic robot error model's correction of reported flange poses.

    Attributes:
        A_r: rotation error per radian of flange orientation, shape (3, 3).
        A_t: translation error (m) per radian of flange orientation, shape (3, 3).
        R_ref: the reference flange orientation (the calibration samples' mean), (3, 3).
    """

    A_r: np.ndarray
    A_t: np.ndarray
    R_ref: np.ndarray

    def __post_init__(self) -> None:
        for name in ("A_r", "A_t", "R_ref"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (3, 3):
                raise InputError(f"robot pose correction: {name} must be 3x3, got shape "
                                 f"{arr.shape}")
            if not np.isfinite(arr).all():
                raise InputError(f"robot pose correction: {name} has NaN or infinite values")
            object.__setattr__(self, name, arr.copy())
        R = self.R_ref
        if (np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1.0) > 1e-6):
            raise InputError("robot pose correction: R_ref is not a rotation matrix")

    def features(self, base_T_ee: np.ndarray) -> np.ndarray:
        """:func:`orientation_features` of each pose (N, 4, 4) -> (N, 3) radians."""
        return orientation_features(self.R_ref, base_T_ee)

    def delta(self, base_T_ee: np.ndarray) -> np.ndarray:
        """The modelled error ``[A_t r | A_r r]`` of each pose (N, 4, 4) -> (N, 6)."""
        r = self.features(np.asarray(base_T_ee, dtype=np.float64).reshape(-1, 4, 4))
        return np.concatenate([r @ self.A_t.T, r @ self.A_r.T], axis=1)

    def apply(self, base_T_ee: np.ndarray) -> np.ndarray:
        """The corrected poses: (4, 4) -> (4, 4), (N, 4, 4) -> (N, 4, 4)."""
        T = np.asarray(base_T_ee, dtype=np.float64)
        one = T.ndim == 2
        if one:
            return self._apply_one(T)
        b = T.reshape(-1, 4, 4)
        d = self.delta(b)
        E = np.zeros((b.shape[0], 4, 4))
        E[:, :3, :3] = exp_rotations(d[:, 3:])
        E[:, :3, 3] = d[:, :3]
        E[:, 3, 3] = 1.0
        out: np.ndarray = b @ E
        return out[0] if one else out

    def _apply_one(self, T: np.ndarray) -> np.ndarray:
        """:meth:`apply` of one pose in scalar arithmetic (the per-frame path of the
        localizer: about 10x faster than the batch's array calls for N = 1)."""
        Ma = self.R_ref.T @ T[:3, :3]
        (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = Ma.tolist()
        c = (m00 + m11 + m22 - 1.0) / 2.0
        vx, vy, vz = m21 - m12, m02 - m20, m10 - m01
        th = math.atan2(0.5 * math.sqrt(vx * vx + vy * vy + vz * vz), min(1.0, max(-1.0, c)))
        if th > 3.0:                       # near a half turn: the batch's careful branch
            r = log_rotations(Ma[None])[0]
        else:
            f = 0.5 + th * th / 12.0 if th < 1e-6 else th / (2.0 * math.sin(th))
            r = np.array([f * vx, f * vy, f * vz])
        t = (self.A_t @ r).tolist()
        wx, wy, wz = (self.A_r @ r).tolist()
        th2 = wx * wx + wy * wy + wz * wz
        a_ = math.sqrt(th2)
        if a_ < 1e-6:
            a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
        else:
            a, b = math.sin(a_) / a_, (1.0 - math.cos(a_)) / th2
        E = np.array([
            [1.0 - b * (wy * wy + wz * wz), -a * wz + b * wx * wy, a * wy + b * wx * wz, t[0]],
            [a * wz + b * wx * wy, 1.0 - b * (wx * wx + wz * wz), -a * wx + b * wy * wz, t[1]],
            [-a * wy + b * wx * wz, a * wx + b * wy * wz, 1.0 - b * (wx * wx + wy * wy), t[2]],
            [0.0, 0.0, 0.0, 1.0]])
        out: np.ndarray = T @ E
        return out

    @property
    def is_zero(self) -> bool:
        """True when the correction changes nothing."""
        return not (np.any(self.A_r) or np.any(self.A_t))
