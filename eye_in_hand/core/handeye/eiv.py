"""Errors-in-variables refinement of the hand-eye transform: noisy images *and* noisy robot poses.

The joint refinement of :mod:`.refine` treats every reported robot pose as exact. A real arm's
reported flange pose is off by tenths of a millimetre and hundredths of a degree (kinematic model
errors, encoder quantisation, the pose read at a slightly different time than the image); a fit
that trusts it bends X to absorb those errors, and its covariance (image noise only) is far too
small. This module models both noise sources.

Model. Each sample's reported flange pose ``B_i = base_T_ee[i]`` is corrected on the right (in
the flange frame, so a rotation error does not move the flange origin)::

    true base_T_ee[i] = B_i @ [exp([d_r,i]x) | d_t,i],     d_t,i ~ N(0, s_t^2 I3),
                                                           d_r,i ~ N(0, s_r^2 I3)

and ``cam_T_board[i] = inv(X) inv(G_i) Y`` with ``G_i`` the corrected pose as the solvers take
it (see :mod:`.solvers`). The unknowns are X, Y (12 numbers, parametrised as in :mod:`.refine`)
and every correction ``d_i`` (6 per sample), the latter as ``d_i = diag(s) u_i`` so that the
prior is the unit residual ``u_i`` whatever the scale. The measurements are

* with corners: every corner's pixel error in every camera, divided by the pixel noise ``s_px``;
* pose pairs only: the measured ``cam_T_board`` against the prediction (rotation vector and
  translation), divided by the camera-pose rotation noise ``s_cr`` (rad) and by ``s_t``: a
  translation error of the camera pose and one of the robot pose are both isotropic in the
  base frame and cannot be told apart from pose pairs, so one level serves both (``s_t`` is
  then the robot's and the camera's translation noise together, an upper bound of the robot's).

Variance components. The noise levels (``s_px`` or ``s_cr``; and ``s_t, s_r``) are
estimated from the data by Förstner's iteration: after each weighted least-squares solve, each
group's level is rescaled by ``sum(w_g^2) / r_g``, its whitened square sum over its redundancy
``r_g = n_g - trace(H_gg)`` (``H`` the hat matrix of the whitened problem), until the levels
change by less than 1 %. A group whose data show no noise shrinks to a floor (1 µm, 1 µrad) and
the fit then equals the exact-pose refinement.

Covariance. ``(J^T J)^-1`` of the whitened problem at the solution, X block, order
``x y z rx ry rz`` (rotation vector applied on the left), as in :mod:`.refine`: with the noise
levels estimated, it accounts for both the image and the robot-pose noise.

The problem is solved by Gauss-Newton steps (with step halving should the cost rise), each
followed by the variance-component update from the linearised residuals, until both settle; the
Jacobian by forward differences grouped by its sparsity (a sample's residuals depend on X, Y and
that sample's correction only: 18 evaluations per Jacobian). The normal equations are small
(12 + 6 N unknowns) and solved through their Cholesky factor.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import invert_many
from eye_in_hand.errors import HandEyeError

from .refine import _start, perturb, pose_residual_scales, project_points
from .samples import CameraView, HandEyeSample, corner_blocks
from .solvers import board_in_fixed_frame, gripper_poses

__all__ = ["EivResult", "refine_errors_in_variables", "leave_one_out_steps", "predict_cam_T_board"]

#: Lower bounds of the estimated noise levels (robot m, rad; pixels; camera pose m, rad).
SIGMA_FLOORS = {"robot_t": 1e-6, "robot_r": 1e-6, "px": 1e-4, "cam_t": 1e-7, "cam_r": 1e-7}
# A noise level has settled when it changes by less than 1 % or by less than this (m, rad):
# a robot-pose level of a micrometre or microradian has no effect left on X.
_SETTLED_ABS = {"robot_t": 1e-6, "robot_r": 1e-6, "px": 0.0, "cam_t": 0.0, "cam_r": 0.0}
_FD_STEP = 1e-7


@dataclass(frozen=True)
class EivResult:
    """Outcome of the errors-in-variables refinement.

    Attributes:
        X: refined hand-eye transform, shape (4, 4).
        Y: refined board pose in its fixed frame, shape (4, 4).
        covariance: covariance of X, shape (6, 6), order ``x y z rx ry rz`` (m, rad; rotation on
            the left).
        covariance_full: covariance of X and Y, shape (12, 12).
        sigmas: the estimated noise levels: ``robot_t`` (m, per axis), ``robot_r`` (rad, per
            axis), and ``px`` (pixels, per coordinate) or ``cam_r`` (rad, pose pairs).
        corrections: the estimated robot-pose corrections ``[d_t (m), d_r (rad)]`` per sample,
            shape (N, 6).
        sigma: measurement noise level (px for reprojection; unitless 1 for pose space).
        cost: final cost (half the whitened square sum).
        nfev: function evaluations, all iterations.
        iterations: variance-component iterations.
        converged: the noise levels settled within ``max_iter`` iterations.
        space: ``"reprojection"`` or ``"pose"``.
    """

    X: np.ndarray
    Y: np.ndarray
    covariance: np.ndarray
    covariance_full: np.ndarray
    sigmas: dict[str, float]
    corrections: np.ndarray
    sigma: float
    cost: float
    nfev: int
    iterations: int
    converged: bool
    space: str
    redundancy: dict[str, float] = field(default_factory=dict)

    @property
    def robot_translation_sigma_m(self) -> float:
        """Estimated robot-pose translation noise, 1 sigma per axis, metres."""
        return float(self.sigmas["robot_t"])

    @property
    def robot_rotation_sigma_rad(self) -> float:
        """Estimated robot-pose rotation noise, 1 sigma per axis, radians."""
        return float(self.sigmas["robot_r"])


def _corrected_poses(bte: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``bte[i] @ [exp(d_r) | d_t]``, shape (N, 4, 4)."""
    D = np.zeros_like(bte)
    D[:, :3, :3] = Rotation.from_rotvec(d[:, 3:]).as_matrix()
    D[:, :3, 3] = d[:, :3]
    D[:, 3, 3] = 1.0
    return bte @ D


def predict_cam_T_board(X: np.ndarray, Y: np.ndarray, base_T_ee: np.ndarray,
                        setup: str) -> np.ndarray:
    """The board pose each robot pose predicts in the camera, ``inv(X) inv(G) Y``, (N, 4, 4)."""
    G = gripper_poses(np.asarray(base_T_ee, dtype=np.float64), setup)
    return invert_many(X) @ invert_many(G) @ Y


class _Problem:
    """The whitened residual function and its groups for one data set and one set of levels."""

    def __init__(self, X0: np.ndarray, Y0: np.ndarray, samples: Sequence[HandEyeSample],
                 cameras: Sequence[CameraView] | None, setup: str, use_corners: bool) -> None:
        self.X0, self.Y0, self.setup = X0, Y0, setup
        self.n = len(samples)
        self.bte = np.stack([s.base_T_ee for s in samples])
        self.use_corners = use_corners
        if use_corners:
            assert cameras is not None
            self.blocks = corner_blocks(samples, cameras)
            self.meas_rows = [np.repeat(b[1], 2) for b in self.blocks]
            self.meas_sample = np.concatenate(self.meas_rows)
            self.meas_groups = np.zeros(self.meas_sample.size, dtype=int)
            self.group_names = ["px", "robot_t", "robot_r"]
        else:
            self.C = np.stack([s.cam_T_board for s in samples])
            self.meas_sample = np.repeat(np.arange(self.n), 6)
            # Camera and robot translation noise are both isotropic in the base frame and cannot
            # be told apart from pose pairs: one level (robot_t) for both.
            self.meas_groups = np.tile([0, 0, 0, 1, 1, 1], self.n)
            self.group_names = ["cam_r", "robot_t", "robot_t", "robot_r"]
        m = self.meas_sample.size
        # Prior rows: u_i (t then r), 6 per sample.
        prior_groups = np.tile([0, 0, 0, 1, 1, 1], self.n) + (1 if use_corners else 2)
        self.groups = np.concatenate([self.meas_groups, prior_groups])
        self.n_meas = m
        # Rows sorted by sample, and where each sample's rows start (per-sample sums).
        self.order = np.argsort(self.meas_sample, kind="stable")
        self.starts = np.searchsorted(self.meas_sample[self.order], np.arange(self.n))

    def per_sample_sum(self, a: np.ndarray) -> np.ndarray:
        """Sum of a per-row array over each sample's measurement rows, shape (N, ...)."""
        return np.add.reduceat(a[self.order], self.starts, axis=0)

    def jacobian(self, p: np.ndarray, sig: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian of the measurement rows by forward differences, 18 evaluations: one per
        X/Y parameter and one per correction component (all samples at once, as a sample's
        residuals depend on its own correction only).

        Returns:
            ``(Jg (M, 12), Ju (M, 6))``: the derivatives by X, Y and by the row's own sample's
            correction. The prior rows' Jacobian is the identity on the corrections.
        """
        f0 = self.residuals(p, sig)[:self.n_meas]
        m = self.n_meas
        Jg = np.zeros((m, 12))
        Ju = np.zeros((m, 6))
        for j in range(12):
            q = p.copy()
            q[j] += _FD_STEP
            Jg[:, j] = (self.residuals(q, sig)[:m] - f0) / _FD_STEP
        for j in range(6):
            h = _FD_STEP / (sig["robot_t"] if j < 3 else sig["robot_r"])
            q = p.copy()
            q[12 + j::6] += h
            Ju[:, j] = (self.residuals(q, sig)[:m] - f0) / h
        return Jg, Ju

    def corrections(self, p: np.ndarray, sig: dict[str, float]) -> np.ndarray:
        u = p[12:].reshape(self.n, 6)
        scale = np.array([sig["robot_t"]] * 3 + [sig["robot_r"]] * 3)
        return u * scale

    def residuals(self, p: np.ndarray, sig: dict[str, float]) -> np.ndarray:
        X = perturb(self.X0, p[:6])
        Y = perturb(self.Y0, p[6:12])
        d = self.corrections(p, sig)
        B = _corrected_poses(self.bte, d)
        C = invert_many(X) @ invert_many(gripper_poses(B, self.setup)) @ Y
        out = []
        if self.use_corners:
            for cam, idx, obj, img in self.blocks:
                T = cam.view_T_cam @ C
                pts = np.einsum("kij,kj->ki", T[idx, :3, :3], obj) + T[idx, :3, 3]
                out.append(((project_points(pts, cam.model.K, cam.model.dist) - img)
                            / sig["px"]).ravel())
        else:
            dR = np.einsum("kji,kjl->kil", self.C[:, :3, :3], C[:, :3, :3])
            r = Rotation.from_matrix(dR).as_rotvec() / sig["cam_r"]
            t = (C[:, :3, 3] - self.C[:, :3, 3]) / sig["robot_t"]
            out.append(np.concatenate([r, t], axis=1).ravel())
        out.append(p[12:])
        return np.concatenate(out)


@dataclass
class _Normal:
    """The whitened normal equations in block form: 12 global unknowns (X, Y) and one 6x6 block
    per sample's correction, reduced by the Schur complement (no large dense products)."""

    A: np.ndarray        # (12, 12) global block
    B: np.ndarray        # (N, 12, 6) global-correction blocks
    Dinv: np.ndarray     # (N, 6, 6) inverse correction blocks
    gg: np.ndarray       # (12,) gradient, global part
    gu: np.ndarray       # (N, 6) gradient, corrections
    A_k: np.ndarray      # (N, 12, 12) each sample's share of A
    gg_k: np.ndarray     # (N, 12) each sample's share of gg


def _normal(prob: _Problem, Jg: np.ndarray, Ju: np.ndarray, r: np.ndarray) -> _Normal:
    n, m = prob.n, prob.n_meas
    rm = r[:m]
    A_k = prob.per_sample_sum(np.einsum("ki,kj->kij", Jg, Jg))
    B = prob.per_sample_sum(np.einsum("ki,kj->kij", Jg, Ju))
    D = prob.per_sample_sum(np.einsum("ki,kj->kij", Ju, Ju)) + np.eye(6)
    gg_k = prob.per_sample_sum(Jg * rm[:, None])
    gu = prob.per_sample_sum(Ju * rm[:, None]) + r[m:].reshape(n, 6)
    return _Normal(A_k.sum(axis=0), B, np.linalg.inv(D), gg_k.sum(axis=0), gu, A_k, gg_k)


def _schur_solve(S: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``S^-1`` and ``S^-1 rhs`` for the 12x12 reduced system."""
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError as exc:
        raise HandEyeError("errors-in-variables refinement: the problem is singular (the "
                           "motions do not determine X)") from exc
    Linv = np.linalg.inv(L)
    Sinv = Linv.T @ Linv
    return Sinv, Sinv @ rhs


def _solve_normal(prob: _Problem, nm: _Normal, Jg: np.ndarray, Ju: np.ndarray,
                  hat: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The Gauss-Newton step, the covariance of the 12 global unknowns and (``hat``) the
    hat-matrix diagonal of every row (measurements, then priors)."""
    BD = np.einsum("kij,kjl->kil", nm.B, nm.Dinv)                   # (N, 12, 6)
    S = nm.A - np.einsum("kij,klj->il", BD, nm.B)
    Cg, xg = _schur_solve(S, -nm.gg + np.einsum("kij,kj->i", BD, nm.gu))
    xu = -np.einsum("kij,kj->ki", nm.Dinv, nm.gu + np.einsum("kji,j->ki", nm.B, xg))
    step = np.concatenate([xg, xu.ravel()])
    if not hat:
        return step, Cg, None
    Cgu = -np.einsum("ij,kjl->kil", Cg, BD)                        # (N, 12, 6)
    Cuu = nm.Dinv + np.einsum("kji,jl,klm->kim", BD, Cg, BD)       # (N, 6, 6)
    k = prob.meas_sample
    h_meas = (np.einsum("ki,ij,kj->k", Jg, Cg, Jg)
              + 2.0 * np.einsum("ki,kij,kj->k", Jg, Cgu[k], Ju)
              + np.einsum("ki,kij,kj->k", Ju, Cuu[k], Ju))
    h_prior = np.einsum("kii->ki", Cuu).ravel()
    return step, Cg, np.concatenate([h_meas, h_prior])


def refine_errors_in_variables(X0: np.ndarray, Y0: np.ndarray,
                               samples: Sequence[HandEyeSample],
                               cameras: Sequence[CameraView] | None, setup: str, *,
                               sigmas: dict[str, float] | None = None,
                               estimate: bool = True, max_iter: int = 100) -> EivResult:
    """Refine X and Y with per-sample robot-pose corrections and estimated noise levels.

    Args:
        X0: start hand-eye transform, shape (4, 4).
        Y0: start board pose in its fixed frame, shape (4, 4).
        samples: validated samples; with ``cameras`` and corners in every sample the
            measurements are the corners (reprojection), else the board poses (pose space).
        cameras: the rig's cameras, or None for pose pairs.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        sigmas: start (or, with ``estimate=False``, fixed) noise levels by group name (see
            :class:`EivResult`); estimated from the start solution when None.
        estimate: estimate the noise levels (variance components); False keeps ``sigmas``.
        max_iter: iterations (Gauss-Newton step + variance-component update); on the real
            Franka capture the levels settle in 19-61 iterations (a 40 cap stopped 3 of 6 folds).

    Returns:
        The result.

    Raises:
        HandEyeError: a camera missing from ``cameras``, or a singular problem.
    """
    samples = list(samples)
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in samples)
    prob = _Problem(X0, Y0, samples, cameras, setup, use_corners)
    sig = dict(sigmas) if sigmas is not None else _start_sigmas(X0, Y0, prob, samples, setup,
                                                               use_corners)
    p = np.concatenate([_start(X0), _start(Y0), np.zeros(6 * prob.n)])
    names = list(dict.fromkeys(prob.group_names))
    group_rows = {name: np.isin(prob.groups, [g for g, nm in enumerate(prob.group_names)
                                              if nm == name]) for name in names}
    nfev, converged, iterations = 0, False, 0
    redundancy: dict[str, float] = {}
    r = prob.residuals(p, sig)
    cost = 0.5 * float(r @ r)
    # Gauss-Newton steps, each followed by the variance-component update computed from the
    # linearised residuals at the new point (exact for the linearised problem).
    for iterations in range(1, max_iter + 1):  # noqa: B007 - the count is read after the loop
        Jg, Ju = prob.jacobian(p, sig)
        step, _, h = _solve_normal(prob, _normal(prob, Jg, Ju, r), Jg, Ju, hat=estimate)
        step, r_new, cost_new, evaluations = _safeguarded_step(prob, p, step, sig, cost)
        nfev += 19 + evaluations
        p = p + step
        r_lin = _linearised_residuals(prob, r, Jg, Ju, step)
        r, cost = r_new, cost_new
        small_step = bool(np.max(np.abs(step[:12])) < 1e-9)
        if not estimate:
            if small_step:
                converged = True
                break
            continue
        assert h is not None
        new = _variance_components(sig, group_rows, h, r_lin, redundancy)
        settled = all(abs(new[k] - sig[k]) < max(0.01 * sig[k], _SETTLED_ABS[k]) for k in sig)
        _keep_corrections(p, prob.n, sig, new)
        sig = new
        r = prob.residuals(p, sig)
        cost = 0.5 * float(r @ r)
        nfev += 1
        if settled and small_step:
            converged = True
            break
    p, r, cov = _final_step(prob, p, r, sig)
    nfev += 39
    X = perturb(X0, p[:6])
    Y = perturb(Y0, p[6:12])
    return EivResult(X=X, Y=Y, covariance=cov[:6, :6], covariance_full=cov,
                     sigmas={k: float(v) for k, v in sig.items()},
                     corrections=prob.corrections(p, sig),
                     sigma=float(sig["px"]) if use_corners else 1.0,
                     cost=0.5 * float(r @ r), nfev=nfev, iterations=iterations,
                     converged=converged, space="reprojection" if use_corners else "pose",
                     redundancy=redundancy)


def _start_sigmas(X0: np.ndarray, Y0: np.ndarray, prob: _Problem,
                  samples: list[HandEyeSample], setup: str,
                  use_corners: bool) -> dict[str, float]:
    """Upper-bound starts of the noise levels: the whole board-pose spread as robot noise; half
    a pixel, or the camera-pose rotation scale of the start solution."""
    sig: dict[str, float] = {}
    bte = prob.bte
    ctb = np.stack([s.cam_T_board for s in samples])
    Yi = board_in_fixed_frame(X0, bte, ctb, setup)
    spread_t = np.linalg.norm(Yi[:, :3, 3] - Y0[:3, 3], axis=1)
    dR = np.einsum("ji,kjl->kil", Y0[:3, :3], Yi[:, :3, :3])
    spread_r = np.linalg.norm(Rotation.from_matrix(dR).as_rotvec(), axis=1)
    sig["robot_t"] = max(float(np.median(spread_t)) / np.sqrt(3.0), 1e-5)
    sig["robot_r"] = max(float(np.median(spread_r)) / np.sqrt(3.0), 1e-5)
    if use_corners:
        sig["px"] = 0.5
    else:
        sr, _ = pose_residual_scales(X0, Y0, bte, ctb, setup)
        sig["cam_r"] = sr
    return sig


def _safeguarded_step(prob: _Problem, p: np.ndarray, step: np.ndarray, sig: dict[str, float],
                      cost: float) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The Gauss-Newton ``step`` halved while the cost rises (a safeguard: the problem is
    nearly linear here): ``(step, residuals, cost, evaluations)`` at ``p + step``."""
    evaluations = 0
    for _ in range(20):
        r_new = prob.residuals(p + step, sig)
        evaluations += 1
        cost_new = 0.5 * float(r_new @ r_new)
        if cost_new <= cost * (1 + 1e-12) or np.linalg.norm(step) < 1e-14:
            break
        step *= 0.5
    return step, r_new, cost_new, evaluations


def _linearised_residuals(prob: _Problem, r: np.ndarray, Jg: np.ndarray, Ju: np.ndarray,
                          step: np.ndarray) -> np.ndarray:
    """The residuals ``r`` moved by ``step`` through the Jacobian (measurements, priors)."""
    m = prob.n_meas
    r_lin = r.copy()
    r_lin[:m] += Jg @ step[:12] + np.einsum("kj,kj->k", Ju,
                                             step[12:].reshape(prob.n, 6)[prob.meas_sample])
    r_lin[m:] += step[12:]
    return r_lin


def _variance_components(sig: dict[str, float], group_rows: dict[str, np.ndarray],
                         h: np.ndarray, r_lin: np.ndarray,
                         redundancy: dict[str, float]) -> dict[str, float]:
    """Förstner's update: each group's level rescaled by its whitened square sum over its
    redundancy ``r_g = n_g - trace(H_gg)`` (written into ``redundancy``), floored."""
    new = dict(sig)
    for name, rows in group_rows.items():
        r_g = float(rows.sum() - h[rows].sum())
        redundancy[name] = r_g
        if r_g > 1e-6:
            new[name] = max(sig[name] * np.sqrt(float(r_lin[rows] @ r_lin[rows]) / r_g),
                            SIGMA_FLOORS[name])
    return new


def _keep_corrections(p: np.ndarray, n: int, sig: dict[str, float],
                      new: dict[str, float]) -> None:
    """Keep the corrections ``d = diag(s) u`` fixed while their scale changes to ``new``: the
    unit residuals ``u`` in ``p`` rescaled in place."""
    u = p[12:].reshape(n, 6)
    u[:, :3] *= sig["robot_t"] / new["robot_t"]
    u[:, 3:] *= sig["robot_r"] / new["robot_r"]


def _final_step(prob: _Problem, p: np.ndarray, r: np.ndarray, sig: dict[str, float]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A last step at the final levels, and the covariance there: ``(p, residuals, cov)``
    (39 evaluations)."""
    Jg, Ju = prob.jacobian(p, sig)
    step, _, _ = _solve_normal(prob, _normal(prob, Jg, Ju, r), Jg, Ju, hat=False)
    p = p + step
    r = prob.residuals(p, sig)
    Jg, Ju = prob.jacobian(p, sig)
    _, Cg, _ = _solve_normal(prob, _normal(prob, Jg, Ju, r), Jg, Ju, hat=False)
    return p, r, 0.5 * (Cg + Cg.T)


def leave_one_out_steps(X: np.ndarray, Y: np.ndarray, samples: Sequence[HandEyeSample],
                        cameras: Sequence[CameraView] | None, setup: str,
                        sigmas: dict[str, float],
                        corrections: np.ndarray | None = None) -> list[tuple[np.ndarray,
                                                                             np.ndarray]]:
    """The solution without each sample, by one Gauss-Newton step from the full solution.

    At the full solution ``(X, Y, corrections)`` with fixed noise levels, sample ``i``'s rows
    (its measurements and its correction's prior) and its correction's columns are removed from
    the whitened normal equations, which are solved once. The problem is nearly linear at its
    minimum, so one step is what a full re-solve gives to second order, at the cost of one
    small linear solve per sample.

    Args:
        X, Y: the full solution, shape (4, 4) each.
        samples: the samples it was computed from.
        cameras: the rig's cameras, or None for pose pairs.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        sigmas: the noise levels (see :class:`EivResult`).
        corrections: the robot-pose corrections of the full solution, shape (N, 6); zeros
            when None (e.g. for the exact-pose refinement, with robot levels at the floor).

    Returns:
        ``(X_without_i, Y_without_i)`` for every sample, in order.
    """

    samples = list(samples)
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in samples)
    prob = _Problem(X, Y, samples, cameras, setup, use_corners)
    u = np.zeros((prob.n, 6)) if corrections is None else np.array(corrections, dtype=float)
    u[:, :3] /= sigmas["robot_t"]
    u[:, 3:] /= sigmas["robot_r"]
    p = np.concatenate([_start(X), _start(Y), u.ravel()])
    r = prob.residuals(p, sigmas)
    Jg, Ju = prob.jacobian(p, sigmas)
    nm = _normal(prob, Jg, Ju, r)
    BD = np.einsum("kij,kjl->kil", nm.B, nm.Dinv)
    BDB = np.einsum("kij,klj->kil", BD, nm.B)                      # (N, 12, 12)
    BDg = np.einsum("kij,kj->ki", BD, nm.gu)                        # (N, 12)
    S = nm.A - BDB.sum(axis=0)
    rhs = -nm.gg + BDg.sum(axis=0)
    out = []
    for i in range(prob.n):
        # Without sample i: its rows leave A and gg, its correction block leaves the sums.
        try:
            _, xg = _schur_solve(S - nm.A_k[i] + BDB[i], rhs + nm.gg_k[i] - BDg[i])
        except HandEyeError as exc:
            raise HandEyeError(f"leave-one-out without sample {samples[i].name!r}: the "
                               "remaining samples do not determine X") from exc
        out.append((perturb(X, p[:6] + xg[:6]), perturb(Y, p[6:12] + xg[6:12])))
    return out
