"""The hand-eye calibration pipeline: diagnose, reject outliers, solve, refine, assess.

:func:`calibrate_hand_eye` runs, on a list of :class:`HandEyeSample`:

1. validation (NaN, non-orthonormal rotations, duplicates: errors or warnings naming samples);
2. motion diagnostics (too few samples or rotations about one axis only is an error);
3. outlier rejection by leave-one-out prediction: each sample's board pose in the fixed frame,
   predicted from X solved without it, is compared with the other samples' board poses; the
   worst sample beyond ``outlier_threshold`` times the median deviation (and beyond absolute
   floors) is rejected and the test repeated;
4. every closed form (:data:`CLOSED_FORM_METHODS`) and the per-motion-pair average
   (``average``, :mod:`.average`) on the kept samples; a solver that fails on them is left out
   of the comparison with a warning;
5. two joint refinements from the best closed form (reprojection when corners are available,
   pose space otherwise): ``refined_exact`` takes the robot poses as exact (:mod:`.refine`),
   ``refined`` models their errors too and estimates both noise levels (:mod:`.eiv`);
6. quality figures for every method: AX = XB residuals per sample, reprojection RMS per sample,
   the spread of the board pose in the fixed frame, and, leaving each sample out in turn, the
   prediction of the held-out sample (:mod:`.select`), the change of X and, for the closed
   forms, a jackknife covariance;
7. selection: the method that best predicts the held-out samples is the result (``method``
   forces one); a warning names any method that differs from it beyond their uncertainty.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.pose_correction import RobotPoseCorrection
from eye_in_hand.core.transforms import average_transforms, invert_many, to_xyz_quat
from eye_in_hand.errors import HandEyeError

from .average import AVERAGE_SOLVERS, DEFAULT_AVERAGE_SOLVER, average_hand_eye, solve_average
from .budget import error_budget
from .eiv import SIGMA_FLOORS, EivResult, leave_one_out_steps, refine_errors_in_variables
from .refine import (
    RefinementResult,
    pose_residual_scales,
    refine_pose_space,
    refine_reprojection,
    reprojection_errors,
)
from .residuals import motion_residuals
from .samples import (
    MIN_SAMPLES,
    CameraView,
    HandEyeSample,
    MotionDiagnostics,
    motion_diagnostics,
    validate_samples,
)
from .select import HeldOut, choose, held_out_position_sigma, held_out_prediction, selection_scores
from .solvers import CLOSED_FORM_METHODS, SETUPS, board_in_fixed_frame, gripper_poses, motion_pairs
from .systematic import SystematicResult, leave_one_out_systematic, refine_systematic

__all__ = [
    "METHODS",
    "ROBOT_MODELS",
    "FRAMES",
    "MethodResult",
    "RejectedSample",
    "HandEyeResult",
    "calibrate_hand_eye",
    "axxb_residuals",
    "board_spread",
    "bootstrap_covariance",
]

#: Every method name accepted by ``--method`` (besides ``all``).
METHODS = (*CLOSED_FORM_METHODS, "average", "refined_exact", "refined", "refined_systematic")

#: The robot error models ``calibrate_hand_eye`` accepts: ``per_pose`` (independent noise per
#: pose; the result's X is used with the robot's reported poses), ``systematic`` (the
#: ``refined_systematic`` model is a candidate too, written only when it predicts the held-out
#: samples significantly better than ``refined``: its X holds only with the robot poses
#: corrected by :attr:`HandEyeResult.pose_correction`).
ROBOT_MODELS = ("per_pose", "systematic")
#: The robot error model of ``calibrate handeye``, the live calibration and the API.
DEFAULT_ROBOT_MODEL = "systematic"

# A reading of the poses whose AX = XB rotation residual is this many times lower than the
# given one (which is above the floor, degrees) means the given conventions are wrong.
_CONVENTION_RATIO = 10.0
_CONVENTION_MIN_DEG = 2.0

# Below this many samples the leave-one-out predictions are too noisy to reject anything.
_MIN_SAMPLES_FOR_REJECTION = 8

#: Default (parent, child) frame ids of X per setup.
FRAMES = {"eye_in_hand": ("tool0", "camera_left_optical_frame"),
          "eye_to_hand": ("base_link", "camera_left_optical_frame")}


@dataclass(frozen=True)
class RejectedSample:
    """A sample left out of the solution, and why."""

    name: str
    reason: str


@dataclass
class MethodResult:
    """One method's X and its quality figures (per-sample arrays are in sample order).

    Attributes:
        name: method name.
        X: hand-eye transform, shape (4, 4).
        Y: board pose in its fixed frame (mean over samples, or refined), shape (4, 4).
        axxb_rot_deg, axxb_trans_mm: RMS AX = XB residual over the motions each sample is
            part of, shape (N,).
        board_dev_mm, board_dev_deg: each sample's board pose in the fixed frame minus ``Y``,
            shape (N,).
        reproj_rms_px: corner reprojection RMS per sample with this X and Y, shape (N,), or
            None without corners.
        loo_mm, loo_deg: change of X when the sample is left out, shape (N,), or None.
        std_mm, std_deg: one-sigma uncertainty of X (translation norm, rotation angle): from
            the covariance for ``refined``, the jackknife of the leave-one-out solutions for
            the closed forms; NaN when not computed.
        covariance: (6, 6) covariance of X, order ``x y z rx ry rz``: from the Jacobian for
            the refinements, the jackknife of the leave-one-out solutions for the closed forms.
        held_out: leave-one-out prediction figures (see :mod:`.select`), or None.
        average: for ``average``, the per-pair counts, thresholds and spread
            (:meth:`.average.AverageResult.summary`); None for the other methods.
    """

    name: str
    X: np.ndarray
    Y: np.ndarray
    axxb_rot_deg: np.ndarray
    axxb_trans_mm: np.ndarray
    board_dev_mm: np.ndarray
    board_dev_deg: np.ndarray
    reproj_rms_px: np.ndarray | None = None
    loo_mm: np.ndarray | None = None
    loo_deg: np.ndarray | None = None
    std_mm: float = float("nan")
    std_deg: float = float("nan")
    covariance: np.ndarray | None = None
    held_out: HeldOut | None = None
    average: dict[str, Any] | None = None

    def summary(self) -> dict[str, Any]:
        """Plain-data summary for report.json (X as translation + quat_xyzw, RMS figures)."""
        t, q = to_xyz_quat(self.X)

        def rms(a: np.ndarray | None) -> float | None:
            return None if a is None or a.size == 0 else float(np.sqrt(np.mean(a ** 2)))

        out: dict[str, Any] = {
            "translation": t.tolist(),
            "quat_xyzw": q.tolist(),
            "residuals": {
                "axxb_rot_deg_rms": rms(self.axxb_rot_deg),
                "axxb_trans_mm_rms": rms(self.axxb_trans_mm),
                "board_spread_mm_rms": rms(self.board_dev_mm),
                "board_spread_deg_rms": rms(self.board_dev_deg),
                "reproj_px_rms": rms(self.reproj_rms_px),
                "loo_max_mm": None if self.loo_mm is None else float(np.max(self.loo_mm)),
                "loo_max_deg": None if self.loo_deg is None else float(np.max(self.loo_deg)),
            },
            "std_mm": None if not np.isfinite(self.std_mm) else float(self.std_mm),
            "std_deg": None if not np.isfinite(self.std_deg) else float(self.std_deg),
        }
        out["held_out"] = None if self.held_out is None else self.held_out.summary()
        if self.covariance is not None:
            out["covariance"] = self.covariance.tolist()
        if self.average is not None:
            out["average"] = self.average
        return out


@dataclass
class HandEyeResult:
    """Everything a hand-eye calibration produced.

    Attributes:
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        sample_names: names of the samples used, in order (per-sample arrays follow it).
        rejected: samples rejected as outliers, with the reason.
        diagnostics: motion diagnostics of the samples used.
        methods: results by method name (closed forms, and ``refined_exact`` and ``refined``
            when run); a method that failed on the samples is absent (and named in warnings).
        selected: the method whose X is the result.
        warnings: every warning (duplicates, weak motion, disagreement, ...).
        refinement: the errors-in-variables refinement (``refined``), or None.
        refinement_exact: the exact-pose refinement (``refined_exact``), or None.
        selection_reason: why ``selected`` was chosen.
        selection_scores: the held-out score of every method (lower is better).
        held_out_sigma_m: the per-pose position noise the held-out board positions of
            ``refined`` show (:func:`.select.held_out_position_sigma`), or None.
        systematic: the systematic robot error model fit (``refined_systematic``,
            :mod:`.systematic`), or None when it was not run.
        robot_model: the robot error model of the selection (:data:`ROBOT_MODELS`).
        error_budget: where the held-out error comes from (:func:`.budget.error_budget`),
            or None without leave-one-out figures.
    """

    setup: str
    sample_names: list[str]
    rejected: list[RejectedSample]
    diagnostics: MotionDiagnostics
    methods: dict[str, MethodResult]
    selected: str
    warnings: list[str] = field(default_factory=list)
    refinement: EivResult | None = None
    refinement_exact: RefinementResult | None = None
    selection_reason: str = ""
    selection_scores: dict[str, float] = field(default_factory=dict)
    held_out_sigma_m: float | None = None
    systematic: SystematicResult | None = None
    robot_model: str = DEFAULT_ROBOT_MODEL
    error_budget: dict[str, Any] | None = None

    @property
    def X(self) -> np.ndarray:
        """The selected hand-eye transform, shape (4, 4)."""
        return self.methods[self.selected].X

    @property
    def covariance(self) -> np.ndarray | None:
        """Covariance of the selected X, shape (6, 6), when available."""
        return self.methods[self.selected].covariance

    @property
    def robot_pose_noise(self) -> dict[str, float] | None:
        """The robot-pose noise (1 sigma per axis, flange frame) written to hand_eye.yaml:
        ``translation_sigma_m``, ``rotation_sigma_rad``; None without the errors-in-variables
        refinement.

        The rotation is the refinement's estimate; the translation the larger of the
        refinement's and the per-pose position scatter of the held-out board positions
        (``held_out_sigma_m``), which also holds what the model leaves unexplained between
        poses (e.g. a camera calibration error seen from another distance and angle).

        With ``refined_systematic`` selected: that model's per-pose noise, what is left of the
        robot's error once its poses are corrected (:attr:`pose_correction`)."""
        if self.selected == "refined_systematic" and self.systematic is not None:
            return {"translation_sigma_m": float(self.systematic.sigmas["robot_t"]),
                    "rotation_sigma_rad": float(self.systematic.sigmas["robot_r"])}
        if self.refinement is None:
            return None
        t = self.refinement.robot_translation_sigma_m
        if self.held_out_sigma_m is not None:
            t = max(t, self.held_out_sigma_m)
        return {"translation_sigma_m": t,
                "rotation_sigma_rad": self.refinement.robot_rotation_sigma_rad}

    @property
    def pose_correction(self) -> RobotPoseCorrection | None:
        """The correction of the robot's reported poses that the selected X holds with
        (``hand_eye.yaml``'s ``robot_pose_correction``): the systematic model's when
        ``refined_systematic`` is selected with a systematic term, else None."""
        if self.selected != "refined_systematic" or self.systematic is None:
            return None
        c = self.systematic.pose_correction()
        return None if c.is_zero else c

    def correct_robot_pose(self, base_T_ee: np.ndarray) -> np.ndarray:
        """The robot pose(s) (4, 4) or (N, 4, 4) the selected X is to be used with: corrected
        by the systematic error model when ``refined_systematic`` is selected, else as given."""
        c = self.pose_correction
        return np.asarray(base_T_ee, dtype=np.float64) if c is None else c.apply(base_T_ee)

    def sample_table(self) -> list[dict[str, Any]]:
        """Per-sample rows for the selected method (report.json ``samples``)."""
        m = self.methods[self.selected]
        rows = []
        for k, name in enumerate(self.sample_names):
            row: dict[str, Any] = {
                "name": name, "used": True,
                "axxb_rot_deg": float(m.axxb_rot_deg[k]),
                "axxb_trans_mm": float(m.axxb_trans_mm[k]),
                "board_dev_mm": float(m.board_dev_mm[k]),
                "board_dev_deg": float(m.board_dev_deg[k]),
                "reproj_rms_px": None if m.reproj_rms_px is None else float(m.reproj_rms_px[k]),
                "loo_mm": None if m.loo_mm is None else float(m.loo_mm[k]),
                "loo_deg": None if m.loo_deg is None else float(m.loo_deg[k]),
            }
            rows.append(row)
        for r in self.rejected:
            rows.append({"name": r.name, "used": False, "reason": r.reason})
        return rows

    def to_report(self) -> dict[str, Any]:
        """The report.json content (without the input description, added by the caller)."""
        return {
            "setup": self.setup,
            "selected": self.selected,
            "methods": {k: v.summary() for k, v in self.methods.items()},
            "samples": self.sample_table(),
            "rejected": [{"name": r.name, "reason": r.reason} for r in self.rejected],
            "diagnostics": self.diagnostics.to_dict(),
            "warnings": list(self.warnings),
            "selection": {"reason": self.selection_reason,
                          "scores": dict(self.selection_scores)},
            "robot_pose_noise": self.robot_pose_noise,
            "held_out_sigma_m": self.held_out_sigma_m,
            "robot_model": self.robot_model,
            "error_budget": self.error_budget,
            "systematic": None if self.systematic is None else self.systematic.summary(),
            "refinement": None if self.refinement is None else {
                "space": self.refinement.space, "sigma": self.refinement.sigma,
                "noise_levels": dict(self.refinement.sigmas),
                "iterations": self.refinement.iterations,
                "converged": self.refinement.converged, "nfev": self.refinement.nfev},
            "refinement_exact": None if self.refinement_exact is None else {
                "space": self.refinement_exact.space, "sigma": self.refinement_exact.sigma,
                "nfev": self.refinement_exact.nfev},
        }


def axxb_residuals(X: np.ndarray, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                   setup: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample AX = XB residuals: RMS over the motions (all pairs) each sample is part of.

    The residual of a motion is ``E = inv(A X) X B``: its rotation angle (deg) and the norm of
    its translation (mm).

    Args:
        X: shape (4, 4).
        base_T_ee: shape (N, 4, 4).
        cam_T_board: shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        ``(rot_deg (N,), trans_mm (N,))``.
    """
    n = base_T_ee.shape[0]
    per_motion = motion_residuals(X, base_T_ee, cam_T_board, setup)
    index, ang, tr = per_motion["index"], per_motion["rot_deg"], per_motion["trans_mm"]
    rot = np.zeros(n)
    trans = np.zeros(n)
    count = np.zeros(n)
    for col in (0, 1):
        np.add.at(rot, index[:, col], ang ** 2)
        np.add.at(trans, index[:, col], tr ** 2)
        np.add.at(count, index[:, col], 1.0)
    count = np.maximum(count, 1.0)
    return np.sqrt(rot / count), np.sqrt(trans / count)


def board_spread(X: np.ndarray, base_T_ee: np.ndarray, cam_T_board: np.ndarray, setup: str,
                 Y: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The board pose in its fixed frame as each sample sees it, against their mean (or ``Y``).

    Args:
        X: shape (4, 4).
        base_T_ee: shape (N, 4, 4).
        cam_T_board: shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        Y: reference board pose, shape (4, 4); the mean of the samples' when None.

    Returns:
        ``(Y (4, 4), dev_mm (N,), dev_deg (N,))``.
    """
    Yi = board_in_fixed_frame(X, base_T_ee, cam_T_board, setup)
    if Y is None:
        Y = average_transforms(Yi)
    dmm = 1000.0 * np.linalg.norm(Yi[:, :3, 3] - Y[:3, 3], axis=1)
    dR = np.einsum("ji,kjl->kil", Y[:3, :3], Yi[:, :3, :3])
    ddeg = np.degrees(np.linalg.norm(Rotation.from_matrix(dR).as_rotvec(), axis=1))
    return Y, dmm, ddeg


def _solve(method: str, base_T_ee: np.ndarray, cam_T_board: np.ndarray, setup: str,
           average_solver: str = DEFAULT_AVERAGE_SOLVER) -> np.ndarray:
    m = motion_pairs(gripper_poses(base_T_ee, setup), cam_T_board)
    with np.errstate(all="ignore"):
        X = (solve_average(m, average_solver) if method == "average"
             else CLOSED_FORM_METHODS[method](m))
    if not np.all(np.isfinite(X)):
        raise HandEyeError(f"{method}: solution is not finite (degenerate motions)")
    return X


def _solve_first(base_T_ee: np.ndarray, cam_T_board: np.ndarray, setup: str) -> np.ndarray:
    """Park-Martin, or the first closed form that solves these samples (for the checks)."""
    errors = []
    for method in ("park", *[k for k in CLOSED_FORM_METHODS if k != "park"]):
        try:
            return _solve(method, base_T_ee, cam_T_board, setup)
        except (HandEyeError, np.linalg.LinAlgError, ValueError) as exc:
            errors.append(str(exc))
    raise HandEyeError("every closed-form solver failed on these samples: " + "; ".join(errors))


def _x_delta(Xa: np.ndarray, Xb: np.ndarray) -> tuple[float, float]:
    """(mm, deg) between two transforms."""
    dt = 1000.0 * float(np.linalg.norm(Xa[:3, 3] - Xb[:3, 3]))
    dr = float(np.degrees(np.linalg.norm(
        Rotation.from_matrix(Xa[:3, :3].T @ Xb[:3, :3]).as_rotvec())))
    return dt, dr


def _loo_prediction(method: str, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                    setup: str) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """For every sample: its board-pose deviation (mm, deg) from the others, predicted by X
    solved without it; and the leave-one-out X's."""
    n = base_T_ee.shape[0]
    dmm = np.zeros(n)
    ddeg = np.zeros(n)
    xs: list[np.ndarray] = []
    for i in range(n):
        keep = np.arange(n) != i
        Xi = (_solve_first(base_T_ee[keep], cam_T_board[keep], setup) if method == "first"
              else _solve(method, base_T_ee[keep], cam_T_board[keep], setup))
        xs.append(Xi)
        Yo = average_transforms(board_in_fixed_frame(Xi, base_T_ee[keep], cam_T_board[keep],
                                                     setup))
        Ys = board_in_fixed_frame(Xi, base_T_ee[i:i + 1], cam_T_board[i:i + 1], setup)[0]
        dmm[i], ddeg[i] = _x_delta(Yo, Ys)
    return dmm, ddeg, xs


def _reject_outliers(samples: list[HandEyeSample], setup: str, threshold: float,
                     floor_mm: float, floor_deg: float,
                     min_keep: int) -> tuple[list[HandEyeSample], list[RejectedSample]]:
    rejected: list[RejectedSample] = []
    kept = list(samples)
    while len(kept) > min_keep:
        bte = np.stack([s.base_T_ee for s in kept])
        ctb = np.stack([s.cam_T_board for s in kept])
        dmm, ddeg, _ = _loo_prediction("first", bte, ctb, setup)
        med_mm = max(float(np.median(dmm)), 1e-12)
        med_deg = max(float(np.median(ddeg)), 1e-12)
        score = np.maximum(dmm / med_mm, ddeg / med_deg)
        bad = (score > threshold) & ((dmm > floor_mm) | (ddeg > floor_deg))
        if not np.any(bad):
            break
        worst = int(np.argmax(np.where(bad, score, -np.inf)))
        rejected.append(RejectedSample(
            kept[worst].name,
            f"outlier: its board pose in the fixed frame is {dmm[worst]:.2f} mm / "
            f"{ddeg[worst]:.3f} deg off the other samples' (median {med_mm:.2f} mm / "
            f"{med_deg:.3f} deg; limit {threshold:g}x the median)"))
        del kept[worst]
    return kept, rejected


def _check_conventions(bte: np.ndarray, ctb: np.ndarray, setup: str) -> str | None:
    """Compare the AX = XB rotation residual of the given reading of the poses with the other
    readings (other setup; ``cam_T_board`` inverted). Returns an error message when another
    reading fits far better, i.e. the input's conventions are almost certainly wrong."""
    other = "eye_to_hand" if setup == "eye_in_hand" else "eye_in_hand"
    inv_ctb = invert_many(ctb)

    def rot_rms(b: np.ndarray, c: np.ndarray, su: str) -> float:
        X = _solve_first(b, c, su)
        r, _ = axxb_residuals(X, b, c, su)
        return float(np.sqrt(np.mean(r ** 2)))

    given = rot_rms(bte, ctb, setup)
    if given < _CONVENTION_MIN_DEG:
        return None
    variants = {f"--setup {other}": rot_rms(bte, ctb, other),
                "cam_T_board inverted (board_T_cam given)": rot_rms(bte, inv_ctb, setup)}
    best = min(variants.values())
    if best * _CONVENTION_RATIO < given:
        fits = " or ".join(f"with {k} ({v:.3f} deg)" for k, v in variants.items()
                           if v < 2.0 * best + 1e-9)
        return (f"the poses do not fit AX = XB as given ({setup}: rotation residual "
                f"{given:.2f} deg RMS) but fit {fits}: check the setup and that the poses are "
                "base_T_ee (flange in base) and cam_T_board (board in camera)")
    return None


def _jackknife(xs: Sequence[np.ndarray], X: np.ndarray) -> tuple[float, float, np.ndarray,
                                                                   np.ndarray]:
    n = len(xs)
    loo_mm = np.zeros(n)
    loo_deg = np.zeros(n)
    t = np.stack([x[:3, 3] for x in xs])
    rv = np.stack([Rotation.from_matrix(x[:3, :3] @ X[:3, :3].T).as_rotvec() for x in xs])
    for i, x in enumerate(xs):
        loo_mm[i], loo_deg[i] = _x_delta(x, X)
    f = (n - 1) / n
    std_mm = 1000.0 * float(np.sqrt(f * np.sum((t - t.mean(axis=0)) ** 2)))
    std_deg = float(np.degrees(np.sqrt(f * np.sum((rv - rv.mean(axis=0)) ** 2))))
    return std_mm, std_deg, loo_mm, loo_deg


def _reproj_rms(X: np.ndarray, Y: np.ndarray, samples: Sequence[HandEyeSample],
                cameras: Sequence[CameraView], setup: str) -> np.ndarray:
    errs = reprojection_errors(X, Y, samples, cameras, setup)
    return np.array([float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))) if e.size else np.nan
                     for e in errs])


def _refine(X0: np.ndarray, Y0: np.ndarray, samples: Sequence[HandEyeSample],
            cameras: Sequence[CameraView] | None, setup: str,
            use_corners: bool) -> RefinementResult:
    if use_corners:
        assert cameras is not None
        return refine_reprojection(X0, Y0, samples, cameras, setup)
    bte = np.stack([s.base_T_ee for s in samples])
    ctb = np.stack([s.cam_T_board for s in samples])
    return refine_pose_space(X0, Y0, bte, ctb, setup)


def calibrate_hand_eye(samples: Sequence[HandEyeSample], setup: str = "eye_in_hand", *,
                       cameras: Sequence[CameraView] | None = None,
                       method: str = "all",
                       refine: bool = True,
                       reject_outliers: bool = True,
                       outlier_threshold: float = 5.0,
                       outlier_floor_mm: float = 1.0,
                       outlier_floor_deg: float = 0.2,
                       leave_one_out: bool = True,
                       check_conventions: bool = True,
                       average_solver: str = DEFAULT_AVERAGE_SOLVER,
                       robot_model: str = DEFAULT_ROBOT_MODEL) -> HandEyeResult:
    """Solve AX = XB with every method, refine, and assess the result.

    Args:
        samples: the samples (robot pose, board pose, optional corners), at least 3.
        setup: ``"eye_in_hand"`` (X = ``ee_T_cam``) or ``"eye_to_hand"`` (X = ``base_T_cam``).
        cameras: the rig's cameras, needed for the reprojection refinement and reprojection
            figures; without them (or without corners) the refinement is done in pose space.
        method: the method whose X is the result: ``"all"`` (the method that best predicts
            the held-out samples), or a method name (``refined``: errors in variables;
            ``refined_exact``: the refinement that takes the robot poses as exact).
        refine: run the joint refinements.
        reject_outliers: reject samples by leave-one-out prediction (see module docstring);
            needs at least 8 samples (else a warning says it was skipped).
        outlier_threshold: rejection limit in multiples of the median deviation.
        outlier_floor_mm, outlier_floor_deg: deviations below both floors are never rejected.
        leave_one_out: solve every method without each sample in turn: the held-out
            prediction figures the result is selected by (see :mod:`.select`), leave-one-out
            changes, and the jackknife uncertainties of the closed forms. Without it (or with
            3 samples) ``refined`` is selected.
        check_conventions: refuse input that fits AX = XB far better read another way (the
            other setup, or ``cam_T_board`` inverted): a wrong setup or pose direction.
        average_solver: the per-pair solver of ``average`` (``"tsai"`` or ``"kronecker"``).
        robot_model: ``"systematic"`` (default) or ``"per_pose"`` (:data:`ROBOT_MODELS`):
            with ``systematic``, ``refined_systematic`` (a pose-dependent robot error fitted
            with X, :mod:`.systematic`) is computed and is a candidate of the selection, written
            only when it predicts the held-out samples significantly better than ``refined``;
            when selected, X is to be used with :attr:`HandEyeResult.pose_correction`.

    Returns:
        The result; ``result.X`` is the selected method's transform.

    Raises:
        HandEyeError: bad poses (naming the sample), too few samples, degenerate motion,
            poses that only fit with another setup or pose direction, unknown setup or
            method, or a solver failure.
    """
    _check_options(setup, method, average_solver, robot_model, refine)
    kept, rejected, warnings = _screen(samples, setup, check_conventions, reject_outliers,
                                       outlier_threshold, outlier_floor_mm, outlier_floor_deg)
    bte = np.stack([s.base_T_ee for s in kept])
    ctb = np.stack([s.cam_T_board for s in kept])
    diag = motion_diagnostics(bte, setup)
    warnings.extend(diag.warnings)
    use_corners, loo = _modes(kept, cameras, leave_one_out, warnings)
    held: dict[str, HeldOut] = {}
    results = _closed_forms(kept, bte, ctb, cameras, setup, average_solver, use_corners, loo,
                            warnings, held)
    if not results:
        raise HandEyeError("every closed-form solver failed on these samples: "
                           + "; ".join(w for w in warnings if " failed on these samples" in w))
    best = _best_closed_form(results)
    refinement, refinement_exact, systematic, held_out_sigma = _refinements(
        results[best], kept, cameras, setup, use_corners, loo, refine,
        robot_model == "systematic" or method == "refined_systematic", warnings, held,
        results)
    selected, reason, scores = _select(method, robot_model, results, held, best, warnings)
    sel = results[selected]
    warnings.extend(_disagreements(results, selected))
    budget = None if sel.held_out is None else _budget(
        sel, selected == "refined_systematic", kept, bte, systematic,
        cameras if use_corners else None, setup)
    return HandEyeResult(setup=setup, sample_names=[s.name for s in kept], rejected=rejected,
                         diagnostics=diag, methods=results, selected=selected,
                         warnings=warnings, refinement=refinement,
                         refinement_exact=refinement_exact, selection_reason=reason,
                         selection_scores=scores, held_out_sigma_m=held_out_sigma,
                         systematic=systematic, robot_model=robot_model,
                         error_budget=budget)


def _screen(samples: Sequence[HandEyeSample], setup: str, check_conventions: bool,
            reject_outliers: bool, outlier_threshold: float, outlier_floor_mm: float,
            outlier_floor_deg: float
            ) -> tuple[list[HandEyeSample], list[RejectedSample], list[str]]:
    """The samples the calibration uses, the rejected ones and the warnings so far: valid
    samples, enough of them, motions that can determine X (failing early), the conventions
    checked, outliers rejected where there are enough samples to tell."""
    kept, warnings = validate_samples(samples)
    if len(kept) < MIN_SAMPLES:
        raise HandEyeError(f"hand-eye calibration needs at least {MIN_SAMPLES} samples, got "
                           f"{len(kept)} usable: add samples")
    motion_diagnostics(np.stack([s.base_T_ee for s in kept]), setup)  # fail early
    if check_conventions:
        problem = _check_conventions(np.stack([s.base_T_ee for s in kept]),
                                     np.stack([s.cam_T_board for s in kept]), setup)
        if problem:
            raise HandEyeError(problem)
    rejected: list[RejectedSample] = []
    if reject_outliers and len(kept) < _MIN_SAMPLES_FOR_REJECTION:
        warnings.append(f"outlier rejection skipped: {len(kept)} samples, fewer than "
                        f"{_MIN_SAMPLES_FOR_REJECTION} (too little redundancy to tell a bad "
                        "sample from noise)")
    elif reject_outliers:
        min_keep = max(MIN_SAMPLES + 2, (len(kept) + 1) // 2)
        kept, rejected = _reject_outliers(kept, setup, outlier_threshold, outlier_floor_mm,
                                          outlier_floor_deg, min_keep)
        for r in rejected:
            warnings.append(f"sample {r.name!r} rejected: {r.reason}")
    return kept, rejected, warnings


def _modes(kept: Sequence[HandEyeSample], cameras: Sequence[CameraView] | None,
           leave_one_out: bool, warnings: list[str]) -> tuple[bool, bool]:
    """Whether the refinement uses the corners (cameras, and corners in every sample) and
    whether there are enough samples for the leave-one-out figures; a warning where not."""
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in kept)
    if bool(cameras) and not use_corners and any(len(s.observations) for s in kept):
        warnings.append("some samples have no corner observations: refinement in pose space")
    loo = leave_one_out and len(kept) > MIN_SAMPLES
    if leave_one_out and not loo:
        warnings.append(f"leave-one-out figures need more than {MIN_SAMPLES} samples")
    return use_corners, loo


def _best_closed_form(results: dict[str, MethodResult]) -> str:
    """The closed form the refinements start from: a classical one (the average when it
    alone solved) with the lowest reprojection RMS, else the lowest normalised board spread."""
    def score(mr: MethodResult) -> float:
        if mr.reproj_rms_px is not None:
            return float(np.sqrt(np.mean(mr.reproj_rms_px ** 2)))
        ref_mm = np.median([np.sqrt(np.mean(r.board_dev_mm ** 2)) for r in results.values()])
        ref_deg = np.median([np.sqrt(np.mean(r.board_dev_deg ** 2)) for r in results.values()])
        return float(np.sqrt(np.mean(mr.board_dev_mm ** 2)) / max(ref_mm, 1e-12)
                     + np.sqrt(np.mean(mr.board_dev_deg ** 2)) / max(ref_deg, 1e-12))

    return min([k for k in results if k in CLOSED_FORM_METHODS] or list(results),
               key=lambda k: score(results[k]))


def _budget(sel: MethodResult, corrected: bool, kept: list[HandEyeSample], bte: np.ndarray,
            systematic: SystematicResult | None, cameras: Sequence[CameraView] | None,
            setup: str) -> dict[str, Any]:
    """The selected method's error budget, over the robot poses it takes (``corrected``:
    ``refined_systematic``'s, corrected by the systematic model)."""
    assert sel.held_out is not None
    used = kept
    if corrected and systematic is not None:
        used = [replace(s, base_T_ee=b)
                for s, b in zip(kept, systematic.correct(bte), strict=True)]
    return error_budget(used, cameras, setup, sel.Y, sel.board_dev_mm, sel.held_out.mm,
                        None if systematic is None else systematic.correction(bte))


def _check_options(setup: str, method: str, average_solver: str, robot_model: str,
                   refine: bool) -> None:
    """Refuse an unknown setup, method, average solver or robot model, and a refined method
    without refinement (:class:`HandEyeError` naming the choices)."""
    if setup not in SETUPS:
        raise HandEyeError(f"setup: expected one of {', '.join(SETUPS)}, got {setup!r}")
    if method != "all" and method not in METHODS:
        raise HandEyeError(f"method: expected 'all' or one of {', '.join(METHODS)}, "
                           f"got {method!r}")
    if average_solver not in AVERAGE_SOLVERS:
        raise HandEyeError(f"average solver: expected one of {', '.join(AVERAGE_SOLVERS)}, "
                           f"got {average_solver!r}")
    if robot_model not in ROBOT_MODELS:
        raise HandEyeError(f"robot model: expected one of {', '.join(ROBOT_MODELS)}, "
                           f"got {robot_model!r}")
    if method in ("refined", "refined_exact", "refined_systematic") and not refine:
        raise HandEyeError(f"method {method!r} requested with refinement disabled")


def _closed_forms(kept: Sequence[HandEyeSample], bte: np.ndarray, ctb: np.ndarray,
                  cameras: Sequence[CameraView] | None, setup: str, average_solver: str,
                  use_corners: bool, loo: bool, warnings: list[str],
                  held: dict[str, HeldOut]) -> dict[str, MethodResult]:
    """Every closed-form method (and the average) with its residuals, board spread,
    reprojection RMS and, with leave-one-out, its jackknife uncertainty and held-out
    prediction (into ``held``). A method that fails is left out with a warning."""
    results: dict[str, MethodResult] = {}
    keep_masks = [np.arange(len(kept)) != i for i in range(len(kept))]
    for name in (*CLOSED_FORM_METHODS, "average"):
        try:
            X = _solve(name, bte, ctb, setup, average_solver)
        except (HandEyeError, np.linalg.LinAlgError, ValueError) as exc:
            warnings.append(f"{name} failed on these samples and is left out of the "
                            f"comparison: {exc}")
            continue
        rot, trans = axxb_residuals(X, bte, ctb, setup)
        Y, dmm, ddeg = board_spread(X, bte, ctb, setup)
        mr = MethodResult(name, X, Y, rot, trans, dmm, ddeg)
        if name == "average":
            mr.average = average_hand_eye(motion_pairs(gripper_poses(bte, setup), ctb),
                                          average_solver).summary()
        if use_corners:
            assert cameras is not None
            mr.reproj_rms_px = _reproj_rms(X, Y, kept, cameras, setup)
        if loo:
            try:
                xs = [_solve(name, bte[k], ctb[k], setup, average_solver) for k in keep_masks]
            except (HandEyeError, np.linalg.LinAlgError, ValueError) as exc:
                warnings.append(f"leave-one-out figures of {name} unavailable: {exc}")
            else:
                mr.std_mm, mr.std_deg, mr.loo_mm, mr.loo_deg = _jackknife(xs, X)
                mr.covariance = _jackknife_covariance(xs)
                ys = [average_transforms(board_in_fixed_frame(x, bte[k], ctb[k], setup))
                      for x, k in zip(xs, keep_masks, strict=True)]
                held[name] = held_out_prediction(list(zip(xs, ys, strict=True)), kept,
                                                 cameras, setup)
                mr.held_out = held[name]
        results[name] = mr
    return results


def _refinements(start: MethodResult, kept: Sequence[HandEyeSample],
                 cameras: Sequence[CameraView] | None, setup: str, use_corners: bool,
                 loo: bool, refine: bool, with_systematic: bool, warnings: list[str],
                 held: dict[str, HeldOut], results: dict[str, MethodResult]
                 ) -> tuple[EivResult | None, RefinementResult | None,
                            SystematicResult | None, float | None]:
    """The joint refinements from the best closed form ``start``: ``refined_exact``,
    ``refined`` (errors in variables) and, ``with_systematic``, ``refined_systematic``, each
    into ``results`` (and its held-out prediction into ``held``); a failure is a warning.
    Returns the refinements and the held-out position sigma of ``refined``."""
    refinement: EivResult | None = None
    refinement_exact: RefinementResult | None = None
    systematic: SystematicResult | None = None
    held_out_sigma: float | None = None
    if refine:
        # Today's refinement: the robot poses taken as exact.
        try:
            refinement_exact = _refine(start.X, start.Y, kept, cameras, setup, use_corners)
        except HandEyeError as exc:
            warnings.append(f"refined_exact failed and is left out of the comparison: {exc}")
        else:
            mr = _refined_result("refined_exact", refinement_exact.X, refinement_exact.Y,
                                 refinement_exact.covariance, kept, cameras, setup, use_corners)
            if loo:
                sig = _exact_pose_sigmas(refinement_exact, kept, setup, use_corners)
                _refined_loo(mr, kept, cameras, setup, sig, None, warnings, held)
            results["refined_exact"] = mr
        # Errors in variables: robot poses and images both noisy, noise levels estimated.
        try:
            refinement = refine_errors_in_variables(start.X, start.Y, kept, cameras, setup)
        except HandEyeError as exc:
            warnings.append(f"refined failed and is left out of the comparison: {exc}")
        else:
            mr = _refined_result("refined", refinement.X, refinement.Y, refinement.covariance,
                                 kept, cameras, setup, use_corners)
            if loo:
                sols = _refined_loo(mr, kept, cameras, setup, refinement.sigmas,
                                    refinement.corrections, warnings, held)
                if sols is not None:
                    held_out_sigma, _ = held_out_position_sigma(
                        sols, kept, setup, refinement.robot_rotation_sigma_rad,
                        cameras if use_corners else None,
                        refinement.sigmas.get("px"))
            results["refined"] = mr
            if not refinement.converged:
                warnings.append("refined: the noise levels did not settle in "
                                f"{refinement.iterations} iterations")
        if with_systematic:
            systematic = _systematic(start.X, start.Y, kept, cameras, setup, use_corners, loo,
                                     warnings, held, results)
    return refinement, refinement_exact, systematic, held_out_sigma


def _select(method: str, robot_model: str, results: dict[str, MethodResult],
            held: dict[str, HeldOut], best: str, warnings: list[str]
            ) -> tuple[str, str, dict[str, float]]:
    """The selected method, the reason and the selection scores (:mod:`.select`): forced by
    ``method``, else the best held-out prediction, else ``refined`` or the best closed form."""
    combine = robot_model == "systematic"
    scores, _ = selection_scores(held, combine) if held else ({}, "")
    # refined_exact is listed with its figures but not a candidate when the errors-in-variables
    # refinement ran: its covariance ignores the robot-pose noise (with exact poses the two
    # coincide), so the written uncertainty could not be trusted.
    candidates = {k: v for k, v in scores.items()
                  if not (k == "refined_exact" and "refined" in scores)
                  and not (k == "refined_systematic" and robot_model != "systematic")}
    if method != "all":
        selected, reason = method, f"forced by --method {method}"
        if method not in results:
            raise HandEyeError(f"method {method!r} failed on these samples: "
                               + "; ".join(w for w in warnings if w.startswith(method)))
    elif candidates:
        # refined stays the reference with the systematic model too: refined_systematic (a
        # pose-space fit of 30 parameters) is written only where the held-out samples show
        # it clearly better, never on the strength of the comparison's noise
        reference = "refined" if "refined" in candidates else "refined_systematic"
        selected, reason = choose(held, list(candidates), reference=reference,
                                  combine=combine)
    else:
        selected = "refined" if "refined" in results else best
        reason = ("no leave-one-out figures (leave-one-out off or too few samples): "
                  + ("the errors-in-variables refinement" if selected == "refined"
                     else "the closed form with the lowest residuals"))
    return selected, reason, scores


def _disagreements(results: dict[str, MethodResult], selected: str) -> list[str]:
    """Warnings for the methods whose X differs from the selected one's beyond 3 sigma of
    their combined uncertainty."""
    # refined_systematic's X holds with the corrected robot poses, every other X with the
    # reported ones: the two kinds differ by the mean of the systematic error by design, so
    # only Xs of one kind are compared.
    sel = results[selected]
    out: list[str] = []
    for name, mr in results.items():
        if name == selected or not (np.isfinite(mr.std_mm) and np.isfinite(sel.std_mm)):
            continue
        if (name == "refined_systematic") != (selected == "refined_systematic"):
            continue
        diff_mm, diff_deg = _x_delta(mr.X, sel.X)
        lim_mm = 3.0 * float(np.hypot(mr.std_mm, sel.std_mm)) + 1e-6
        lim_deg = 3.0 * float(np.hypot(mr.std_deg, sel.std_deg)) + 1e-7
        if diff_mm > lim_mm or diff_deg > lim_deg:
            out.append(
                f"methods disagree: {name} differs from {selected} by {diff_mm:.2f} mm / "
                f"{diff_deg:.3f} deg, beyond 3 sigma of their uncertainties ({lim_mm:.2f} mm / "
                f"{lim_deg:.3f} deg): check for bad samples or unmodelled errors")
    return out


def _systematic(X0: np.ndarray, Y0: np.ndarray, kept: Sequence[HandEyeSample],
                cameras: Sequence[CameraView] | None, setup: str, use_corners: bool, loo: bool,
                warnings: list[str], held: dict[str, HeldOut],
                results: dict[str, MethodResult]) -> SystematicResult | None:
    """The systematic robot error refinement (``refined_systematic``) and its leave-one-out
    figures, each held-out sample predicted from its pose corrected by the model fitted
    without it; None (with a warning) when it fails."""
    bte = np.stack([s.base_T_ee for s in kept])
    ctb = np.stack([s.cam_T_board for s in kept])
    try:
        fit = refine_systematic(X0, Y0, bte, ctb, setup)
    except HandEyeError as exc:
        warnings.append(f"refined_systematic failed and is left out of the comparison: {exc}")
        return None
    # Figures against the corrected poses: the model's X holds with them.
    corrected = [replace(s, base_T_ee=b) for s, b in zip(kept, fit.correct(bte), strict=True)]
    mr = _refined_result("refined_systematic", fit.X, fit.Y, fit.covariance, corrected,
                         cameras, setup, use_corners)
    if loo:
        try:
            sols = leave_one_out_systematic(fit, bte, ctb, setup)
        except HandEyeError as exc:
            warnings.append(f"leave-one-out figures of refined_systematic unavailable: {exc}")
        else:
            mr.loo_mm = np.zeros(len(sols))
            mr.loo_deg = np.zeros(len(sols))
            for i, f in enumerate(sols):
                mr.loo_mm[i], mr.loo_deg[i] = _x_delta(f.X, fit.X)
            held_samples = [replace(s, base_T_ee=f.correct(s.base_T_ee))
                            for s, f in zip(kept, sols, strict=True)]
            held["refined_systematic"] = held_out_prediction(
                [(f.X, f.Y) for f in sols], held_samples, cameras, setup)
            mr.held_out = held["refined_systematic"]
    results["refined_systematic"] = mr
    return fit


def _jackknife_covariance(xs: Sequence[np.ndarray]) -> np.ndarray:
    """Jackknife covariance (6, 6) of X from its leave-one-out solutions (``x y z rx ry rz``,
    rotation on the left of their mean)."""
    n = len(xs)
    X_mean = average_transforms(np.stack(xs))
    par = np.stack([np.concatenate([x[:3, 3], Rotation.from_matrix(
        x[:3, :3] @ X_mean[:3, :3].T).as_rotvec()]) for x in xs])
    d = par - par.mean(axis=0)
    cov = (n - 1) / n * np.einsum("ki,kj->ij", d, d)
    return 0.5 * (cov + cov.T)


def _refined_result(name: str, X: np.ndarray, Y: np.ndarray, cov: np.ndarray,
                    kept: Sequence[HandEyeSample], cameras: Sequence[CameraView] | None,
                    setup: str, use_corners: bool) -> MethodResult:
    bte = np.stack([s.base_T_ee for s in kept])
    ctb = np.stack([s.cam_T_board for s in kept])
    rot, trans = axxb_residuals(X, bte, ctb, setup)
    _, dmm, ddeg = board_spread(X, bte, ctb, setup, Y)
    mr = MethodResult(name, X, Y, rot, trans, dmm, ddeg, covariance=cov)
    mr.std_mm = 1000.0 * float(np.sqrt(np.trace(cov[:3, :3])))
    mr.std_deg = float(np.degrees(np.sqrt(np.trace(cov[3:, 3:]))))
    if use_corners:
        assert cameras is not None
        mr.reproj_rms_px = _reproj_rms(X, Y, kept, cameras, setup)
    return mr


def _exact_pose_sigmas(ref: RefinementResult, kept: Sequence[HandEyeSample], setup: str,
                       use_corners: bool) -> dict[str, float]:
    """Noise levels under which the errors-in-variables model is the exact-pose refinement."""
    sig = {"robot_t": SIGMA_FLOORS["robot_t"], "robot_r": SIGMA_FLOORS["robot_r"]}
    if use_corners:
        sig["px"] = max(ref.sigma, SIGMA_FLOORS["px"])
    else:
        sig["cam_r"], sig["cam_t"] = pose_residual_scales(
            ref.X, ref.Y, np.stack([s.base_T_ee for s in kept]),
            np.stack([s.cam_T_board for s in kept]), setup)
    return sig


def _refined_loo(mr: MethodResult, kept: Sequence[HandEyeSample],
                 cameras: Sequence[CameraView] | None, setup: str, sigmas: dict[str, float],
                 corrections: np.ndarray | None, warnings: list[str],
                 held: dict[str, HeldOut]) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Leave-one-out figures of a refinement (into ``mr`` and ``held``); returns the
    solutions without each sample, or None when they could not be computed."""
    try:
        sols = leave_one_out_steps(mr.X, mr.Y, kept, cameras if cameras else None, setup,
                                   sigmas, corrections)
    except HandEyeError as exc:
        warnings.append(f"leave-one-out figures of {mr.name} unavailable: {exc}")
        return None
    n = len(sols)
    mr.loo_mm = np.zeros(n)
    mr.loo_deg = np.zeros(n)
    for i, (Xi, _) in enumerate(sols):
        mr.loo_mm[i], mr.loo_deg[i] = _x_delta(Xi, mr.X)
    held[mr.name] = held_out_prediction(sols, kept, cameras, setup)
    mr.held_out = held[mr.name]
    return sols


def bootstrap_covariance(samples: Sequence[HandEyeSample], setup: str, *,
                         cameras: Sequence[CameraView] | None = None, n_boot: int = 50,
                         seed: int = 0, start: str = "park",
                         X0: np.ndarray | None = None,
                         Y0: np.ndarray | None = None) -> np.ndarray:
    """Bootstrap covariance of the exact-pose refinement's X (``refined_exact``; resampling
    samples with replacement).

    Used to check the Jacobian covariance. Each draw solves ``start`` and refines from it.

    Args:
        samples: validated samples.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        cameras: rig cameras (reprojection refinement when given and corners exist).
        n_boot: number of bootstrap draws.
        seed: random seed.
        start: the closed form to start each refinement from, unless ``X0``, ``Y0`` are given.
        X0, Y0: start every refinement from these (e.g. the full-data solution; faster).

    Returns:
        shape (6, 6), order ``x y z rx ry rz`` (rotation as a left perturbation of the mean).
    """
    rng = np.random.default_rng(seed)
    samples = list(samples)
    n = len(samples)
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in samples)
    xs = []
    for _ in range(n_boot):
        idx = rng.integers(0, n, n)
        if len(set(idx.tolist())) < MIN_SAMPLES + 1:
            continue
        sub = [samples[i] for i in idx]
        bte = np.stack([s.base_T_ee for s in sub])
        ctb = np.stack([s.cam_T_board for s in sub])
        if X0 is not None and Y0 is not None:
            Xs, Ys = X0, Y0
        else:
            Xs = _solve(start, bte, ctb, setup)
            Ys, _, _ = board_spread(Xs, bte, ctb, setup)
        xs.append(_refine(Xs, Ys, sub, cameras, setup, use_corners).X)
    X_mean = average_transforms(np.stack(xs))
    par = np.stack([np.concatenate([x[:3, 3], Rotation.from_matrix(
        x[:3, :3] @ X_mean[:3, :3].T).as_rotvec()]) for x in xs])
    return np.cov(par.T)

