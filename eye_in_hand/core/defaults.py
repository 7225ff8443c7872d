"""Defaults the live nodes and ``process`` share, written once.

The ``hand_eye`` node's robot pose rules and robot sigmas (:class:`PoseRules`) and
``detect_triangulate``'s stereo pairing (``sync.slop_s``, ``sync.queue_size``) are also
``process``'s options (:class:`eye_in_hand.offline.ProcessOptions`) and its ``--params`` file
fallbacks: every one of them takes its default from here. No imports: the worker processes of
``process`` load this module without the localization code.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PoseRules", "POSE_RULES", "DEFAULT_SYNC_SLOP_S", "DEFAULT_SYNC_QUEUE_SIZE"]


@dataclass(frozen=True)
class PoseRules:
    """The robot pose rules of localization and their defaults.

    Attributes:
        max_pose_gap_s: largest gap between the two robot poses that bracket an image stamp.
        max_pose_age_s: largest receive age (live) or log-time age (offline) of those poses.
        pose_jump_back_s: a stamp this far behind the newest restarts the pose buffer.
        robot_sigma_pos_m, robot_sigma_rot_rad: the arm's stated accuracy (1 sigma per axis;
            :func:`eye_in_hand.core.localization.robot_pose_sigmas`).
    """

    max_pose_gap_s: float = 0.05
    max_pose_age_s: float = 1.0
    pose_jump_back_s: float = 1.0
    robot_sigma_pos_m: float = 0.00015
    robot_sigma_rot_rad: float = 0.0004


#: The defaults of :class:`PoseRules`.
POSE_RULES = PoseRules()

#: Stereo pairing: largest left/right stamp difference (s) and frames per side waiting. A second
#: of frames at 30 Hz: over DDS one camera's images can stall for 0.3-0.5 s while the other's
#: keep coming (a reliable reader repairing a large image, seen under load in the demo's live
#: step); a queue of 5 dropped 1-12 of 45 frames there. Worst case held: 30 images per side.
DEFAULT_SYNC_SLOP_S = 0.005
DEFAULT_SYNC_QUEUE_SIZE = 30
