"""Eye-to-hand localization: a camera fixed in the robot's base frame, no robot pose needed.

``p_base = base_T_cam @ p_cam``; the 3x3 covariance is the camera covariance rotated into the
base frame plus the hand-eye (here: camera mount) covariance, to first order:
``R cov_cam R^T + J cov_hand_eye J^T`` with ``J = [I, -[R p_cam]x]`` (translation, then a
rotation vector applied on the left in the parent frame, the convention of ``hand_eye.yaml``).
It is :func:`eye_in_hand.core.localization.target_in_base` with an identity robot pose and no
robot pose noise, behind the interface of :class:`~eye_in_hand.core.localization.Localizer`.

Pure numpy: no rclpy, no messages.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from eye_in_hand.core.localization import TargetInBase, target_in_base
from eye_in_hand.core.transforms import as_transform

__all__ = ["EyeToHandLocalizer"]

_IDENTITY = np.eye(4)


class EyeToHandLocalizer:
    """Localization with a fixed camera (``calibrate handeye --setup eye_to_hand``).

    Args:
        base_T_cam: shape (4, 4), the camera (left optical frame) in the base frame.
        cov_hand_eye: optional (6, 6) covariance of ``base_T_cam`` (``hand_eye.yaml`` order).

    Raises:
        InputError: a transform or covariance of the wrong shape, not finite, or (covariance)
            not symmetric positive semi-definite.
    """

    def __init__(self, base_T_cam: ArrayLike, cov_hand_eye: ArrayLike | None = None) -> None:
        self.base_T_cam = as_transform(base_T_cam, "base_T_cam").copy()
        self.cov_hand_eye = None if cov_hand_eye is None else np.asarray(cov_hand_eye,
                                                                         dtype=np.float64)
        # a malformed covariance fails here (InputError), not at the first located target
        target_in_base(_IDENTITY, self.base_T_cam, np.zeros(3), cov_hand_eye=self.cov_hand_eye)

    def locate(self, stamp_ns: int, point_cam: ArrayLike, cov_cam: ArrayLike | None = None, *,
               now_ns: int | None = None) -> TargetInBase:
        """The target in the base frame (``now_ns`` is ignored: there is no robot pose to be
        stale); ``base_T_ee`` of the result is the identity.

        Raises:
            InputError: a malformed point or covariance.
        """
        p, cov = target_in_base(_IDENTITY, self.base_T_cam, point_cam, cov_cam=cov_cam,
                                cov_hand_eye=self.cov_hand_eye)
        return TargetInBase(stamp_ns=int(stamp_ns), point_base=p, covariance=cov,
                            base_T_ee=_IDENTITY.copy())
