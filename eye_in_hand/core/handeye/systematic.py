"""Hand-eye with a systematic robot error model (``refined_systematic``).

Real arms report poses whose error is mostly *systematic*: a pose-dependent kinematic error
(joint offsets, link lengths, compliance) that changes smoothly with the arm's configuration,
not the independent per-pose noise of :mod:`.eiv`. Without joint angles the configuration is
summarised by the flange orientation; the model is the first-order (linear) term of a smooth
error in it, plus independent per-pose noise::

    r_i      = log(R_ref^T R_i)                     flange orientation relative to the mean (rad)
    true_i   = reported_i @ [exp(A_r r_i) | A_t r_i] error on the right, in the flange frame
    residual = log(inv(true_i) @ implied_i)         implied_i: the flange pose the camera sees,
                                                    Y inv(cam_T_board[i]) inv(X) eye-in-hand,
                                                    X cam_T_board[i] inv(Y) eye-to-hand

``A_r`` (3x3, rad/rad) and ``A_t`` (3x3, m/rad) are 18 parameters. ``r_i`` is centred on the
mean orientation, so the correction averages out over the samples and cannot stand in for a
constant error of X or Y; a Gaussian prior of 1-sigma ``level`` on every entry (rad/rad,
m/rad) keeps it small where the data do not ask for it. Each residual is whitened by the
per-pose noise (``robot_r`` rad, ``robot_t`` m, 1 sigma per axis), estimated from the
residuals of an unweighted first fit; the second fit uses them (two fixed passes: nothing to
converge). The prior level is chosen among :data:`LEVELS` (and "no systematic term") by
leave-one-out prediction of the held-out samples' poses, not by the fit.

The cost lives in pose space (the flange pose implied by the board, from PnP): with real arms
the robot's error is one to two orders above the corners' (pixels), so each sample's board
pose is a good measurement of where the flange really was. The covariance of X is the
Gauss-Newton one of the whitened problem, scaled by its residual variance.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from eye_in_hand.core.pose_correction import (
    RobotPoseCorrection,
    exp_rotations,
    log_rotations,
    orientation_features,
)
from eye_in_hand.core.transforms import invert_many
from eye_in_hand.errors import HandEyeError

__all__ = ["LEVELS", "SystematicResult", "fit_systematic", "refine_systematic",
           "leave_one_out_systematic"]

#: Candidate prior levels (1 sigma of every entry of ``A_r`` in rad/rad and ``A_t`` in m/rad);
#: 0 is the model without a systematic term.
LEVELS = (0.0, 0.003, 0.01, 0.03, 0.1)

# Fewer samples than this and the 18 parameters are not worth trying (the level is then 0).
_MIN_SAMPLES_SYSTEMATIC = 6
_SIGMA_FLOOR_R = np.radians(0.001)
_SIGMA_FLOOR_T = 1e-5


def _se3(v: np.ndarray) -> np.ndarray:
    """``[exp(v[3:]) | v[:3]]`` for (N, 6) -> (N, 4, 4)."""
    v = np.asarray(v, dtype=np.float64).reshape(-1, 6)
    T = np.zeros((v.shape[0], 4, 4))
    T[:, :3, :3] = exp_rotations(v[:, 3:])
    T[:, :3, 3] = v[:, :3]
    T[:, 3, 3] = 1.0
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (N, 4, 4) or (4, 4)."""
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _perturb(T0: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[exp([dr]x) R0 | t]`` from ``p = [t (3), dr (3)]`` (as :func:`.refine.perturb`)."""
    T = np.eye(4)
    T[:3, :3] = exp_rotations(p[None, 3:6])[0] @ T0[:3, :3]
    T[:3, 3] = p[:3]
    return T


def _log(T: np.ndarray) -> np.ndarray:
    """``[t, rotvec]`` of (N, 4, 4) -> (N, 6)."""
    return np.concatenate([T[:, :3, 3], log_rotations(T[:, :3, :3])], axis=1)


@dataclass
class SystematicResult:
    """The systematic-error refinement.

    Attributes:
        X, Y: hand-eye transform and board pose in its fixed frame, shape (4, 4) each.
        A_r: rotation error per radian of orientation, shape (3, 3).
        A_t: translation error (m) per radian of orientation, shape (3, 3).
        R_ref: the reference (mean) flange orientation, shape (3, 3).
        level: the prior level used (0: no systematic term).
        sigmas: per-pose noise ``robot_t`` (m) and ``robot_r`` (rad), 1 sigma per axis.
        covariance: covariance of X, shape (6, 6), order ``x y z rx ry rz``.
        level_scores: leave-one-out score of every level tried (lower is better).
        nfev: function evaluations of the final fit.
        converged: the final least-squares fit stopped on a tolerance.
    """

    X: np.ndarray
    Y: np.ndarray
    A_r: np.ndarray
    A_t: np.ndarray
    R_ref: np.ndarray
    level: float
    sigmas: dict[str, float]
    covariance: np.ndarray
    level_scores: dict[float, float] = field(default_factory=dict)
    nfev: int = 0
    converged: bool = True
    # the solution's parameters, whitened residuals, Jacobian and parameter unpacker
    _state: tuple | None = field(default=None, repr=False, compare=False)

    def pose_correction(self) -> RobotPoseCorrection:
        """The model's correction of reported poses, as ``hand_eye.yaml`` stores it and the
        localizer applies it."""
        return RobotPoseCorrection(self.A_r, self.A_t, self.R_ref)

    def correction(self, base_T_ee: np.ndarray) -> np.ndarray:
        """The modelled error ``[A_t r | A_r r]`` of each reported pose, shape (N, 6)."""
        return self.pose_correction().delta(base_T_ee)

    def correct(self, base_T_ee: np.ndarray) -> np.ndarray:
        """The reported poses (N, 4, 4) or (4, 4) corrected by the model."""
        return self.pose_correction().apply(base_T_ee)

    def held_out_nees(self, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                      setup: str) -> np.ndarray:
        """Normalised error of samples this fit did not use (6 dof each; its mean is 6 when
        the model's uncertainty is right).

        The sample's pose error (flange frame, whitened by the noise levels) is compared with
        its predicted covariance ``s^2 (I + J_new (J^T J)^-1 J_new^T)``: the per-pose noise
        plus the uncertainty of X, Y and the systematic term propagated to the new pose
        (``s^2`` the fit's residual variance, ``J`` its Jacobian, ``J_new`` the new sample's).

        Args:
            base_T_ee, cam_T_board: the new samples' poses, shape (M, 4, 4) each.
            setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

        Returns:
            shape (M,).
        """
        if self._state is None:
            raise HandEyeError("held_out_nees: this fit has no Jacobian (a leave-one-out step)")
        p, _, J, _, X0, Y0, s2 = self._state
        bte = np.asarray(base_T_ee, dtype=np.float64).reshape(-1, 4, 4)
        ctb = np.asarray(cam_T_board, dtype=np.float64).reshape(-1, 4, 4)
        Ainv = np.linalg.pinv(J.T @ J)
        out = np.zeros(bte.shape[0])
        for k in range(bte.shape[0]):
            f, _ = _residual_fn(X0, Y0, bte[k:k + 1], ctb[k:k + 1], setup, self.level,
                                self.R_ref, self.sigmas["robot_t"], self.sigmas["robot_r"])
            e = f(p)[:6]
            Jn = _jacobian(lambda q, f=f: f(q)[:6], p)
            S = s2 * (np.eye(6) + Jn @ Ainv @ Jn.T)
            out[k] = float(e @ np.linalg.solve(S, e))
        return out

    def summary(self) -> dict[str, object]:
        """Plain data for report.json."""
        return {"level": self.level, "A_r": self.A_r.tolist(), "A_t_m_per_rad": self.A_t.tolist(),
                "noise": dict(self.sigmas),
                "level_scores": {str(k): v for k, v in self.level_scores.items()},
                "converged": self.converged, "nfev": self.nfev}


def _implied(X: np.ndarray, Y: np.ndarray, cam_T_board: np.ndarray, setup: str) -> np.ndarray:
    """The flange pose (base frame) each board pose implies, (N, 4, 4)."""
    if setup == "eye_in_hand":
        return Y @ invert_many(cam_T_board) @ np.linalg.inv(X)
    return X @ cam_T_board @ np.linalg.inv(Y)


def _mean_rotation(base_T_ee: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(base_T_ee[:, :3, :3]).mean().as_matrix()


def _fit_once(X0: np.ndarray, Y0: np.ndarray, bte: np.ndarray, ctb: np.ndarray, setup: str,
              level: float, R_ref: np.ndarray, s_t: float, s_r: float):
    residual, unpack = _residual_fn(X0, Y0, bte, ctb, setup, level, R_ref, s_t, s_r)
    n_sys = 18 if level > 0 else 0
    p0 = np.concatenate([X0[:3, 3], np.zeros(3), Y0[:3, 3], np.zeros(3), np.zeros(n_sys)])
    with np.errstate(all="ignore"):
        res = least_squares(residual, p0, x_scale="jac", method="lm")
    if not np.all(np.isfinite(res.x)):
        raise HandEyeError("refined_systematic: the fit diverged")
    return res, unpack, residual


def _residual_fn(X0: np.ndarray, Y0: np.ndarray, bte: np.ndarray, ctb: np.ndarray, setup: str,
                 level: float, R_ref: np.ndarray, s_t: float, s_r: float):
    """The whitened residual (6 per sample, then the prior rows) and the parameter unpacker."""
    n_sys = 18 if level > 0 else 0
    r = orientation_features(R_ref, bte)
    Cinv = _inv(ctb)
    w = np.array([1 / s_t] * 3 + [1 / s_r] * 3)

    def unpack(p: np.ndarray):
        X = _perturb(X0, p[:6])
        Y = _perturb(Y0, p[6:12])
        A_r = p[12:21].reshape(3, 3) if n_sys else np.zeros((3, 3))
        A_t = p[21:30].reshape(3, 3) if n_sys else np.zeros((3, 3))
        return X, Y, A_r, A_t

    def residual(p: np.ndarray) -> np.ndarray:
        X, Y, A_r, A_t = unpack(p)
        corr = np.concatenate([r @ A_t.T, r @ A_r.T], axis=1)
        true = bte @ _se3(corr)
        if setup == "eye_in_hand":
            implied = Y @ Cinv @ _inv(X)
        else:
            implied = X @ ctb @ _inv(Y)
        e = _log(_inv(true) @ implied) * w
        out = [e.ravel()]
        if n_sys:
            out.append(p[12:] / level)
        return np.concatenate(out)

    return residual, unpack


def _jacobian(residual, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of ``residual`` at ``p``."""
    cols = []
    for j in range(p.size):
        d = np.zeros_like(p)
        d[j] = h
        cols.append((residual(p + d) - residual(p - d)) / (2.0 * h))
    return np.stack(cols, axis=1)


def _loo_steps(state: tuple, n: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Leave-one-out parameters by one Gauss-Newton step from the full solution, and each
    left-out sample's predicted whitened error (n, 6) (exact for a linear model).

    Without sample ``i`` the normal equations lose ``J_i^T J_i`` and, as ``J^T r = 0`` at the
    solution, the gradient becomes ``-J_i^T r_i``: ``dp_i = (J^T J - J_i^T J_i)^-1 J_i^T r_i``,
    and the held-out error is ``r_i + J_i dp_i``."""
    p, r, J = state[0], state[1], state[2]
    A = J.T @ J
    params, errs = [], np.zeros((n, 6))
    for i in range(n):
        Ji, ri = J[6 * i:6 * i + 6], r[6 * i:6 * i + 6]
        try:
            dp = np.linalg.solve(A - Ji.T @ Ji, Ji.T @ ri)
        except np.linalg.LinAlgError:
            dp = np.linalg.lstsq(A - Ji.T @ Ji, Ji.T @ ri, rcond=None)[0]
        params.append(p + dp)
        errs[i] = ri + Ji @ dp
    return params, errs


def fit_systematic(X0: np.ndarray, Y0: np.ndarray, base_T_ee: np.ndarray,
                   cam_T_board: np.ndarray, setup: str, level: float, *,
                   R_ref: np.ndarray | None = None,
                   sigmas: dict[str, float] | None = None) -> SystematicResult:
    """Fit X, Y and the systematic error at one prior level (see the module docstring).

    Args:
        X0, Y0: start (a closed form and its mean board pose), shape (4, 4) each.
        base_T_ee: reported robot poses, shape (N, 4, 4).
        cam_T_board: board poses in the camera, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        level: prior 1-sigma of the systematic entries; 0 fits X and Y only.
        R_ref: reference orientation (default: the mean of ``base_T_ee``).
        sigmas: per-pose noise; estimated from an unweighted first fit when None.

    Returns:
        The fit.

    Raises:
        HandEyeError: the fit diverged.
    """
    bte = np.asarray(base_T_ee, dtype=np.float64)
    ctb = np.asarray(cam_T_board, dtype=np.float64)
    R_ref = _mean_rotation(bte) if R_ref is None else R_ref
    n = bte.shape[0]
    if sigmas is None:
        # first pass: translation in metres against rotation in radians at 1 m lever
        res, _, _ = _fit_once(X0, Y0, bte, ctb, setup, level, R_ref, 1.0, 1.0)
        m = res.fun[:6 * n].reshape(n, 6)
        p = 12 + (18 if level > 0 else 0)
        dof = max(6 * n - p, 1) / (6 * n)
        s_t = max(float(np.sqrt(np.mean(m[:, :3] ** 2) / dof)), _SIGMA_FLOOR_T)
        s_r = max(float(np.sqrt(np.mean(m[:, 3:] ** 2) / dof)), _SIGMA_FLOOR_R)
        sigmas = {"robot_t": s_t, "robot_r": s_r}
    res, unpack, residual = _fit_once(X0, Y0, bte, ctb, setup, level, R_ref,
                                      sigmas["robot_t"], sigmas["robot_r"])
    X, Y, A_r, A_t = unpack(res.x)
    J = _jacobian(residual, res.x)
    m_res = res.fun.size
    dof = max(m_res - res.x.size, 1)
    s2 = float(2.0 * res.cost / dof)
    try:
        cov_full = np.linalg.pinv(J.T @ J) * max(s2, 1e-12)
    except np.linalg.LinAlgError as exc:
        raise HandEyeError(f"refined_systematic: singular normal matrix ({exc})") from exc
    cov = cov_full[:6, :6]
    return SystematicResult(X, Y, A_r, A_t, R_ref, float(level), dict(sigmas),
                            0.5 * (cov + cov.T), nfev=int(res.nfev),
                            converged=bool(res.status > 0),
                            _state=(res.x.copy(), residual(res.x), J, unpack, X0, Y0, s2))


def _held_out_pose_error(fit: SystematicResult, bte: np.ndarray, ctb: np.ndarray,
                         setup: str) -> np.ndarray:
    """Whitened pose error (6,) of samples ``bte``, ``ctb`` predicted by ``fit``."""
    true = fit.correct(bte)
    implied = _implied(fit.X, fit.Y, ctb, setup)
    e = _log(invert_many(true) @ implied)
    w = np.array([1 / fit.sigmas["robot_t"]] * 3 + [1 / fit.sigmas["robot_r"]] * 3)
    return e * w


def leave_one_out_systematic(fit: SystematicResult, base_T_ee: np.ndarray,
                             cam_T_board: np.ndarray, setup: str,
                             exact: bool = False) -> list[SystematicResult]:
    """The fit without each sample in turn (same level, noise levels and reference
    orientation): one Gauss-Newton step from ``fit`` (:func:`_loo_steps`), or with ``exact``
    a full fit started from it."""
    bte = np.asarray(base_T_ee, dtype=np.float64)
    ctb = np.asarray(cam_T_board, dtype=np.float64)
    n = bte.shape[0]
    if exact or fit._state is None:
        out = []
        for i in range(n):
            keep = np.arange(n) != i
            out.append(fit_systematic(fit.X, fit.Y, bte[keep], ctb[keep], setup, fit.level,
                                      R_ref=fit.R_ref, sigmas=fit.sigmas))
        return out
    params, _ = _loo_steps(fit._state, n)
    unpack = fit._state[3]
    out = []
    for p in params:
        X, Y, A_r, A_t = unpack(p)
        out.append(SystematicResult(X, Y, A_r, A_t, fit.R_ref, fit.level, dict(fit.sigmas),
                                    fit.covariance))
    return out


def refine_systematic(X0: np.ndarray, Y0: np.ndarray, base_T_ee: np.ndarray,
                      cam_T_board: np.ndarray, setup: str,
                      levels: Sequence[float] = LEVELS) -> SystematicResult:
    """Fit the model at the prior level that best predicts the held-out samples.

    Each level is fitted once; its leave-one-out solutions are one Gauss-Newton step from it
    (:func:`_loo_steps`), and the held-out sample's whitened pose error
    (under the noise levels of the level-0 fit, so that every level is scored on one scale) is
    the score (RMS). The lowest-scoring level is fitted on all samples.

    Args:
        X0, Y0: start, shape (4, 4) each.
        base_T_ee, cam_T_board: the samples' poses, shape (N, 4, 4) each.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        levels: candidate levels (0: no systematic term).

    Returns:
        The fit at the chosen level, with every level's score in ``level_scores``.

    Raises:
        HandEyeError: the fit diverged.
    """
    bte = np.asarray(base_T_ee, dtype=np.float64)
    ctb = np.asarray(cam_T_board, dtype=np.float64)
    n = bte.shape[0]
    base = fit_systematic(X0, Y0, bte, ctb, setup, 0.0)
    if n < _MIN_SAMPLES_SYSTEMATIC:
        base.level_scores = {0.0: float("nan")}
        return base
    sig = base.sigmas
    scores: dict[float, float] = {}
    fits: dict[float, SystematicResult] = {}
    for lv in levels:
        f = base if float(lv) == 0.0 else fit_systematic(base.X, base.Y, bte, ctb, setup,
                                                          float(lv), R_ref=base.R_ref,
                                                          sigmas=sig)
        assert f._state is not None
        _, errs = _loo_steps(f._state, n)
        fits[float(lv)] = f
        scores[float(lv)] = float(np.sqrt(np.mean(errs ** 2)))
    best = min(scores, key=lambda k: scores[k])
    # the chosen level's noise levels re-estimated from its own residuals
    out = base if best == 0.0 else fit_systematic(base.X, base.Y, bte, ctb, setup, best,
                                                  R_ref=base.R_ref)
    out.level_scores = scores
    return out
