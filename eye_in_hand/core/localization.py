"""Camera point + robot pose + hand-eye -> target in the robot base frame, with covariance.

``p_base = base_T_ee(t_image) @ ee_T_cam @ p_cam``, with ``base_T_ee`` interpolated at the image
stamp from a :class:`~eye_in_hand.core.sync.PoseBuffer` (never extrapolated, never across a gap
over a limit), and a 3x3 covariance propagated to first order from three independent sources:

* the triangulated point, ``cov_cam`` (3x3, left optical frame);
* the hand-eye calibration, ``cov_hand_eye`` (6x6, order ``[tx, ty, tz, rx, ry, rz]``: translation
  in metres and a rotation vector in radians, the rotation perturbation applied on the left,
  ``R' = exp([dr]x) R``, i.e. expressed in the parent frame ``ee``: the convention of
  :mod:`eye_in_hand.io.config`'s ``hand_eye.yaml``);
* the robot's reported pose, an isotropic position sigma (m) and rotation sigma (rad), the rotation
  perturbation taken about the flange (``R_b' = R_b exp([dr]x)``), which is how joint-encoder
  errors show up at the tool. :func:`robot_pose_sigmas` chooses them: per component the larger
  of the arm's stated accuracy and the hand-eye calibration's estimate.

Why the calibration's estimate alone is too small: an arm's kinematic error (link lengths, joint
zeros) is mostly systematic. Over a working region it is close to one common rigid error of the
reported poses (on the simulator's default arm: 0.4-0.6 mrad of rotation in the base frame, the
same at every calibration stop within 0.1 mrad), and a hand-eye calibration takes any common
error into the board's pose in the base frame: it is invisible in the calibration's residuals,
in its held-out prediction of the board, and in the errors-in-variables estimate
(``hand_eye.yaml``'s ``robot_pose_noise``: the scatter of the poses about that common error).
It is still in every base-frame position the arm reports. Only the arm's own accuracy figure
(datasheet, or a laser-tracker check) bounds it.

Pure numpy: no rclpy, no messages.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from eye_in_hand.core.pose_correction import RobotPoseCorrection
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.transforms import as_points, as_transform, value_key
from eye_in_hand.errors import InputError

__all__ = ["LocalizerConfig", "TargetInBase", "target_in_base", "robot_pose_sigmas",
           "Localizer"]

#: the 3x3 identity (read-only: shared)
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _as_cov(value, name: str, n: int) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n, n):
        raise InputError(f"{name}: expected shape ({n}, {n}), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name}: contains NaN or infinite values")
    scale = max(1.0, float(np.abs(arr).max()))
    if float(np.abs(arr - arr.T).max()) > 1e-9 * scale:
        raise InputError(f"{name}: covariance is not symmetric")
    if n == 3 and _positive_definite_3x3(arr):
        return arr     # the usual case, per point: no eigen-decomposition needed
    if np.min(np.linalg.eigvalsh(arr)) < -1e-12 * scale:
        raise InputError(f"{name}: covariance is not positive semi-definite")
    return arr


def _positive_definite_3x3(a: np.ndarray) -> bool:
    """Sylvester's criterion: every leading minor > 0 (then every eigenvalue is > 0). False
    means "not shown here", and the caller decides with the eigenvalues. The lower triangle,
    as ``eigvalsh`` reads it."""
    (a00, _, _), (a01, a11, _), (a02, a12, a22) = a.tolist()
    m2 = a00 * a11 - a01 * a01
    det = (a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02)
           + a02 * (a01 * a12 - a11 * a02))
    return a00 > 0.0 and m2 > 0.0 and det > 0.0


@dataclass(frozen=True)
class TargetInBase:
    """A target located in the robot base frame.

    Attributes (the arrays read-only as :meth:`Localizer.locate` returns them):
        stamp_ns: the image stamp (int ns).
        point_base: shape (3,), metres, base frame.
        covariance: shape (3, 3), m^2, base frame.
        base_T_ee: the robot pose used (interpolated at ``stamp_ns``, then corrected by the
            calibration's ``pose_correction`` when it has one), shape (4, 4).
    """

    stamp_ns: int
    point_base: np.ndarray
    covariance: np.ndarray
    base_T_ee: np.ndarray


def target_in_base(base_T_ee, ee_T_cam, point_cam, *, cov_cam=None, cov_hand_eye=None,
                   robot_sigma_pos_m: float = 0.0,
                   robot_sigma_rot_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Map a camera-frame point into the base frame and propagate its covariance.

    Args:
        base_T_ee: shape (4, 4), the robot pose at the image stamp.
        ee_T_cam: shape (4, 4), the hand-eye calibration.
        point_cam: shape (3,), the target in the camera (left optical) frame, metres.
        cov_cam: optional (3, 3) covariance of ``point_cam``.
        cov_hand_eye: optional (6, 6) covariance of ``ee_T_cam`` (see module docstring).
        robot_sigma_pos_m: isotropic position noise of the robot pose (1 sigma).
        robot_sigma_rot_rad: isotropic rotation noise of the robot pose about the flange.

    Returns:
        ``(point_base (3,), covariance (3, 3))``.
    """
    b_T_e = as_transform(base_T_ee, "base_T_ee")
    e_T_c = as_transform(ee_T_cam, "ee_T_cam")
    p_c = as_points(point_cam, "point_cam")
    if p_c.shape[0] != 1:
        raise InputError(f"point_cam: expected one point, got {p_c.shape[0]}")
    p_c = p_c[0]
    _check_sigmas(robot_sigma_pos_m, robot_sigma_rot_rad)
    return _propagate(b_T_e, e_T_c, p_c,
                      None if cov_cam is None else _as_cov(cov_cam, "cov_cam", 3),
                      None if cov_hand_eye is None else _as_cov(cov_hand_eye, "cov_hand_eye", 6),
                      robot_sigma_pos_m, robot_sigma_rot_rad)


def _check_sigmas(robot_sigma_pos_m: float, robot_sigma_rot_rad: float) -> None:
    if not (np.isfinite(robot_sigma_pos_m) and robot_sigma_pos_m >= 0
            and np.isfinite(robot_sigma_rot_rad) and robot_sigma_rot_rad >= 0):
        raise InputError("robot pose sigmas must be finite and non-negative")


def _propagate(b_T_e: np.ndarray, e_T_c: np.ndarray, p_c: np.ndarray,
               cov_cam: np.ndarray | None, cov_hand_eye: np.ndarray | None,
               robot_sigma_pos_m: float, robot_sigma_rot_rad: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`target_in_base` on checked inputs (float64 arrays of the right shapes, valid
    transforms and covariances): the one formula of the live and offline paths."""
    Rb, tb = b_T_e[:3, :3], b_T_e[:3, 3]
    Rx, tx = e_T_c[:3, :3], e_T_c[:3, 3]
    q = Rx @ p_c                      # camera point rotated into ee axes
    p_ee = q + tx
    p_base = Rb @ p_ee + tb

    cov = np.zeros((3, 3))
    if cov_cam is not None:
        J = Rb @ Rx
        cov += J @ cov_cam @ J.T
    if cov_hand_eye is not None:
        # d p_ee = dt - [q]x dr  (left rotation perturbation in the ee frame)
        J = Rb @ np.hstack([_EYE3, -_skew(q)])
        cov += J @ cov_hand_eye @ J.T
    if robot_sigma_pos_m > 0:
        cov += robot_sigma_pos_m ** 2 * _EYE3
    if robot_sigma_rot_rad > 0:
        J = -Rb @ _skew(p_ee)         # d p_base = -R_b [p_ee]x dr (flange-frame perturbation)
        cov += robot_sigma_rot_rad ** 2 * (J @ J.T)
    return p_base, 0.5 * (cov + cov.T)


def robot_pose_sigmas(stated_pos_m: float, stated_rot_rad: float,
                      estimated: Mapping[str, float] | None = None) -> tuple[float, float]:
    """The robot pose sigmas for the localization covariance.

    Per component the larger of the arm's stated accuracy (the ``robot_sigma_*`` parameters of
    the ``hand_eye`` node and ``process``) and the hand-eye calibration's estimate
    (``hand_eye.yaml``'s ``robot_pose_noise``). The estimate measures the scatter of the
    reported poses about the calibration's fit and cannot see the arm's common (systematic)
    error, which the fit absorbs (see the module docstring): it raises the stated figure when
    the poses scatter more than it says, and never lowers it.

    Args:
        stated_pos_m: the arm's position accuracy per axis, 1 sigma (m, >= 0).
        stated_rot_rad: the arm's rotation accuracy about the flange per axis, 1 sigma (rad).
        estimated: ``{"translation_sigma_m": float, "rotation_sigma_rad": float}`` or None.

    Returns:
        ``(sigma_pos_m, sigma_rot_rad)``.

    Raises:
        InputError: a negative or non-finite value (named).
    """
    vals = {"robot_sigma_pos_m": stated_pos_m, "robot_sigma_rot_rad": stated_rot_rad}
    if estimated is not None:
        for key in ("translation_sigma_m", "rotation_sigma_rad"):
            if key not in estimated:
                raise InputError(f"robot_pose_noise: missing {key}")
            vals[f"robot_pose_noise.{key}"] = estimated[key]
    for name, v in vals.items():
        if not (np.isfinite(float(v)) and float(v) >= 0):
            raise InputError(f"{name}: must be finite and >= 0, got {v}")
    pos, rot = float(stated_pos_m), float(stated_rot_rad)
    if estimated is not None:
        pos = max(pos, float(estimated["translation_sigma_m"]))
        rot = max(rot, float(estimated["rotation_sigma_rad"]))
    return pos, rot


@dataclass(frozen=True)
class LocalizerConfig:
    """Settings of :class:`Localizer`.

    Attributes:
        max_gap_ns: largest accepted time between the two robot poses that bracket an image stamp.
        buffer_size: robot poses kept (at 500 Hz, 1000 poses are 2 s).
        robot_sigma_pos_m: robot pose position noise (1 sigma, metres).
        robot_sigma_rot_rad: robot pose rotation noise (1 sigma, radians).
        max_age_ns: largest receive age of the robot poses used for a frame (see
            :class:`~eye_in_hand.core.sync.PoseBuffer`), checked when :meth:`Localizer.locate`
            is given ``now_ns``; None: no age rule.
        jump_back_ns: a robot pose stamp (or receive time) this far behind the newest clears
            the pose buffer (bag replayed again, simulated time reset); None: never.
    """

    max_gap_ns: int = 50_000_000
    buffer_size: int = 2000
    robot_sigma_pos_m: float = 0.0
    robot_sigma_rot_rad: float = 0.0
    max_age_ns: int | None = None
    jump_back_ns: int | None = None

    def __post_init__(self) -> None:
        if int(self.max_gap_ns) <= 0:
            raise InputError(f"max_gap_ns: must be positive, got {self.max_gap_ns}")
        if int(self.buffer_size) < 2:
            raise InputError(f"buffer_size: must be >= 2, got {self.buffer_size}")
        for name in ("max_age_ns", "jump_back_ns"):
            v = getattr(self, name)
            if v is not None and int(v) < 0:
                raise InputError(f"{name}: must be >= 0 or None, got {v}")
        for name in ("robot_sigma_pos_m", "robot_sigma_rot_rad"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise InputError(f"{name}: must be finite and >= 0, got {v}")


class Localizer:
    """Stateful localization: a robot pose buffer plus the hand-eye calibration.

    The live ``hand_eye`` node and the offline ``process`` command both use this class, so the
    two paths give the same numbers on the same inputs.

    Args:
        ee_T_cam: shape (4, 4), the hand-eye calibration (tool frame <- left optical frame).
        cov_hand_eye: optional (6, 6) covariance of ``ee_T_cam``.
        config: :class:`LocalizerConfig`.
        pose_correction: the calibration's correction of the reported robot poses
            (``hand_eye.yaml``'s ``robot_pose_correction``), applied to the pose interpolated
            at each image stamp before ``ee_T_cam``; None: the reported poses as they are.
    """

    def __init__(self, ee_T_cam, cov_hand_eye=None,
                 config: LocalizerConfig | None = None,
                 pose_correction: RobotPoseCorrection | None = None) -> None:
        self.pose_correction = pose_correction
        self.config = config or LocalizerConfig()
        self.ee_T_cam = as_transform(ee_T_cam, "ee_T_cam").copy()
        self.cov_hand_eye = (None if cov_hand_eye is None
                             else _as_cov(cov_hand_eye, "cov_hand_eye", 6).copy())
        self.poses = PoseBuffer(self.config.buffer_size, name="base_T_ee",
                                jump_back_ns=self.config.jump_back_ns)
        _check_sigmas(self.config.robot_sigma_pos_m, self.config.robot_sigma_rot_rad)
        #: the key of the last point located, and its result (:meth:`locate`)
        self._last: tuple[tuple[Any, ...], TargetInBase] | None = None

    def add_robot_pose(self, stamp_ns: int, base_T_ee, *, received_ns: int | None = None,
                       checked: bool = False) -> bool:
        """Buffer a robot pose (int ns stamp, (4, 4)) received at ``received_ns`` (optional,
        the clock of :meth:`locate`'s ``now_ns``); raises InputError on a bad pose
        (``checked``: see :meth:`PoseBuffer.add <eye_in_hand.core.sync.PoseBuffer.add>`).

        Returns:
            True when the buffer was cleared first (time jumped back, see ``jump_back_ns``).
        """
        return self.poses.add(stamp_ns, base_T_ee, received_ns=received_ns, checked=checked)

    def locate(self, stamp_ns: int, point_cam, cov_cam=None, *,
               now_ns: int | None = None) -> TargetInBase:
        """The target in the base frame at an image stamp.

        The result's arrays are read-only. The same point and covariance (by value) at the same
        stamp, from the same robot pose, as the call before give that call's result object:
        the ``hand_eye`` node locates its first target for ``target/pose`` and again in its
        frame for ``target/<id>/pose``. The pose lookup and its rules (gap, age at this
        ``now_ns``) run at every call.

        Args:
            now_ns: the clock now (as ``received_ns``); with ``config.max_age_ns`` the robot
                poses used must have been received within that age.

        Raises:
            eye_in_hand.errors.LocalizationError: no robot pose brackets ``stamp_ns`` within
                ``max_gap_ns``, or the poses are older than ``max_age_ns`` (``reason`` says
                which): never a pose from a stale transform.
            InputError: a malformed point or covariance.
        """
        base_T_ee = self.poses.lookup(stamp_ns, int(self.config.max_gap_ns), now_ns=now_ns,
                                      max_age_ns=self.config.max_age_ns)
        if self.pose_correction is not None:
            base_T_ee = self.pose_correction.apply(base_T_ee)
        # the rules above (gap, age at this now_ns) hold for every call; the rest is a
        # function of the key, and the point located last is not located again
        try:
            key = (int(stamp_ns), base_T_ee.tobytes(), value_key(point_cam),
                   None if cov_cam is None else value_key(cov_cam))
        except (TypeError, ValueError):
            key = None      # not arrays of numbers: the checks below say what is wrong
        last = self._last
        if key is not None and last is not None and last[0] == key:
            return last[1]
        p_c = as_points(point_cam, "point_cam")
        if p_c.shape[0] != 1:
            raise InputError(f"point_cam: expected one point, got {p_c.shape[0]}")
        # the calibration and the sigmas were checked once (__init__), the robot pose when it
        # was buffered (an interpolation of checked poses): per point, only its own inputs
        p, cov = _propagate(base_T_ee, self.ee_T_cam, p_c[0],
                            None if cov_cam is None else _as_cov(cov_cam, "cov_cam", 3),
                            self.cov_hand_eye, self.config.robot_sigma_pos_m,
                            self.config.robot_sigma_rot_rad)
        for arr in (p, cov, base_T_ee):
            arr.flags.writeable = False
        res = TargetInBase(stamp_ns=int(stamp_ns), point_base=p, covariance=cov,
                           base_T_ee=base_T_ee)
        if key is not None:
            self._last = (key, res)
        return res

