"""Hand-eye calibration (AX = XB): closed-form solvers, joint refinement, quality figures.

Pure numerics (numpy, scipy, OpenCV for projection): no rclpy, no messages.

* :mod:`.solvers`: Tsai-Lenz, Park-Martin, Horaud-Dornaika, Daniilidis, Andreff and the
  homogeneous Kronecker linear method, for eye-in-hand (``X = ee_T_cam``) and eye-to-hand
  (``X = base_T_cam``); the formulation is documented there.
* :mod:`.average`: the per-motion-pair average (``average``): X from every pair of motions
  with non-parallel axes (Tsai-Lenz or Kronecker per pair), rotation and translation means.
* :mod:`.residuals`: the per-motion AX = XB residuals of every method (report tables).
* :mod:`.samples`: the sample types, validation and motion diagnostics.
* :mod:`.refine`: joint nonlinear refinement of X and the board pose (reprojection or pose
  space) with the covariance of X, the robot poses taken as exact (``refined_exact``).
* :mod:`.eiv`: the errors-in-variables refinement (``refined``): robot-pose corrections with
  noise levels estimated from the data, and its covariance.
* :mod:`.select`: leave-one-out prediction of held-out samples and the choice of the result.
* :mod:`.plan`: the next flange poses to take, scored by the predicted covariance of X.
* :mod:`.calibrate`: the pipeline (:func:`calibrate_hand_eye`) with outlier rejection,
  leave-one-out figures and method-disagreement warnings.
"""
from __future__ import annotations

from .calibrate import (
                        FRAMES,
                        METHODS,
                        HandEyeResult,
                        MethodResult,
                        RejectedSample,
                        axxb_residuals,
                        board_spread,
                        bootstrap_covariance,
                        calibrate_hand_eye,
)
from .eiv import EivResult, leave_one_out_steps, refine_errors_in_variables
from .plan import Plan, PlanConfig, Suggestion, predicted_covariance, suggest_next_poses
from .refine import RefinementResult, refine_pose_space, refine_reprojection, reprojection_errors
from .samples import (
                        MIN_SAMPLES,
                        CameraView,
                        CornerObservation,
                        HandEyeSample,
                        MotionDiagnostics,
                        motion_diagnostics,
                        validate_samples,
)
from .select import HeldOut, choose, held_out_prediction, selection_scores
from .solvers import (
                        CLOSED_FORM_METHODS,
                        SETUPS,
                        MotionPairs,
                        board_in_fixed_frame,
                        gripper_poses,
                        motion_pairs,
                        solve_andreff,
                        solve_closed_form,
                        solve_daniilidis,
                        solve_horaud,
                        solve_kronecker,
                        solve_park,
                        solve_tsai,
)

__all__ = [
    "CLOSED_FORM_METHODS", "METHODS", "SETUPS", "FRAMES", "MIN_SAMPLES",
    "HandEyeSample", "CornerObservation", "CameraView", "MotionDiagnostics", "MotionPairs",
    "HandEyeResult", "MethodResult", "RejectedSample", "RefinementResult",
    "calibrate_hand_eye", "solve_closed_form", "motion_diagnostics", "validate_samples",
    "solve_tsai", "solve_park", "solve_horaud", "solve_daniilidis", "solve_andreff",
    "solve_kronecker", "gripper_poses", "motion_pairs", "board_in_fixed_frame",
    "refine_reprojection", "refine_pose_space", "reprojection_errors",
    "axxb_residuals", "board_spread", "bootstrap_covariance",
    "EivResult", "refine_errors_in_variables", "leave_one_out_steps",
    "HeldOut", "held_out_prediction", "selection_scores", "choose",
    "Plan", "PlanConfig", "Suggestion", "suggest_next_poses", "predicted_covariance",
]
