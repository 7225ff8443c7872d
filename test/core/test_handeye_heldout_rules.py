"""core.handeye: documented rules that held-out planted bugs showed no test pinned.

Each test puts a rule of the per-pair average, the error budget, the held-out figures, the
systematic robot model and the next-pose planner at a point where the wrong rule gives another
number (see ``tools/mutation_heldout.py`` and the table of ``tools/mutation.py``).
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.handeye.average import usable_motion_pairs
from eye_in_hand.core.handeye.budget import error_budget
from eye_in_hand.core.handeye.plan import PlanConfig, _score, _std, suggest_next_poses
from eye_in_hand.core.handeye.refine import reprojection_errors
from eye_in_hand.core.handeye.samples import HandEyeSample
from eye_in_hand.core.handeye.select import held_out_prediction
from eye_in_hand.core.handeye.solvers import MotionPairs
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.handeye.systematic import (
    LEVELS,
    _jacobian,
    _residual_fn,
    fit_systematic,
    refine_systematic,
)
from eye_in_hand.core.transforms import from_rotvec


@pytest.fixture(scope="module")
def problem():
    return make_problem(6, seed=11, noise_px=0.3, robot_noise_mm=0.3, robot_noise_deg=0.03)


# -- average: every pair of motions counted once ------------------------------------------------

def test_skipped_pairs_are_counted_once_each() -> None:
    """Small rotations first, then parallel axes among the rest: kept + both counts is every
    pair (a pair with a small rotation is not counted again as parallel)."""
    rv = [[0.02, 0, 0], [0.0, 0.01, 0], [0.5, 0, 0], [0.6, 0, 0], [0, 0.5, 0], [0, 0, 0.7]]
    A = np.stack([from_rotvec(np.array(v, float), np.zeros(3)) for v in rv])
    m = MotionPairs(A, A.copy(), np.zeros((len(rv), 2), dtype=int))
    pairs, small, parallel = usable_motion_pairs(m)
    K = len(rv)
    assert len(pairs) + small + parallel == K * (K - 1) // 2
    # 2 small motions: pairs touching either = 1 + 2 * 4 = 9; parallel among the big: (2, 3)
    assert (small, parallel, len(pairs)) == (9, 1, 5)


# -- budget: the parts add in squares ----------------------------------------------------------

def _flat_samples(n: int) -> list[HandEyeSample]:
    rng = np.random.default_rng(5)
    return [HandEyeSample(f"s{k}", from_rotvec(rng.normal(scale=0.6, size=3),
                                               rng.normal(scale=0.2, size=3) + [0.4, 0, 0.3]),
                          np.eye(4)) for k in range(n)]


def test_budget_parts_follow_the_documented_laws() -> None:
    """Without corners: ``robot_mm = sqrt(mean(dev^2) n / (n - 2))``, ``estimate_mm =
    sqrt(h^2 - r^2)``, ``largest`` the largest part."""
    n = 7
    samples = _flat_samples(n)
    dev = np.linspace(0.2, 0.8, n)
    held = np.linspace(0.5, 1.5, n)
    b = error_budget(samples, None, "eye_in_hand", np.eye(4), dev, held)
    r2 = np.mean(dev ** 2) * n / (n - 2)
    assert b["camera_mm"] is None
    assert b["robot_mm"] == pytest.approx(np.sqrt(r2), abs=1e-4)
    assert b["estimate_mm"] == pytest.approx(np.sqrt(np.mean(held ** 2) - r2), abs=1e-4)
    assert b["largest"] == "estimate_mm"
    b2 = error_budget(samples, None, "eye_in_hand", np.eye(4), held, dev)
    assert b2["largest"] == "robot_mm" and b2["estimate_mm"] == 0.0


def test_budget_systematic_part_moves_the_board_origin_by_w_cross_lever() -> None:
    """A rotation correction ``w`` (flange frame) moves the board origin by ``w x l``, ``l`` the
    origin in the flange frame; with a translation ``t`` too: ``|t + w x l|``."""
    samples = _flat_samples(5)
    Y = from_rotvec(np.array([np.pi, 0, 0]), np.array([0.5, 0.1, -0.05]))
    d = np.tile([0.0004, -0.0002, 0.0001, 0.002, -0.001, 0.003], (5, 1))
    b = error_budget(samples, None, "eye_in_hand", Y, np.ones(5), np.ones(5) * 2, d)
    moved = [d[k, :3] + np.cross(d[k, 3:], s.base_T_ee[:3, :3].T @ (Y[:3, 3]
                                                                    - s.base_T_ee[:3, 3]))
             for k, s in enumerate(samples)]
    want = 1000.0 * np.sqrt(np.mean(np.sum(np.square(moved), axis=1)))
    assert b["robot_systematic_mm"] == pytest.approx(want, abs=1e-4)


# -- select: the held-out corner error is an RMS over corners of the 2-d error ------------------

def test_held_out_corner_error_is_rms_of_the_corner_distance(problem) -> None:
    X, Y = problem.X @ from_rotvec(np.array([0.002, 0, 0]), np.array([0.001, 0, 0])), problem.Y
    sols = [(X, Y)] * len(problem.samples)
    h = held_out_prediction(sols, problem.samples, problem.views, "eye_in_hand")
    assert h.px is not None
    for s, px in zip(problem.samples, h.px, strict=True):
        e = reprojection_errors(X, Y, [s], problem.views, "eye_in_hand")[0]
        assert px == pytest.approx(np.sqrt(np.mean(np.sum(e ** 2, axis=1))), rel=1e-9)


# -- systematic: residual variance, prior, NEES, the sample floor -------------------------------

def _arrays(samples):
    return (np.stack([s.base_T_ee for s in samples]), np.stack([s.cam_T_board for s in samples]))


def test_systematic_residual_variance_and_prior_rows(problem) -> None:
    """``s^2 = |r|^2 / (m - p)`` scales the covariance; the prior rows are ``A / level``."""
    bte, ctb = _arrays(problem.samples)
    fit = fit_systematic(problem.X, problem.Y, bte, ctb, "eye_in_hand", 0.01)
    assert fit._state is not None
    p, r, J, _, X0, Y0, s2 = fit._state
    assert s2 == pytest.approx(float(r @ r) / (r.size - p.size), rel=1e-9)
    cov = np.linalg.pinv(J.T @ J)[:6, :6] * s2
    assert np.allclose(fit.covariance, 0.5 * (cov + cov.T), rtol=1e-9, atol=0)
    f, _ = _residual_fn(X0, Y0, bte, ctb, "eye_in_hand", 0.01, fit.R_ref,
                        fit.sigmas["robot_t"], fit.sigmas["robot_r"])
    q = np.arange(30, dtype=float) * 1e-3
    assert np.allclose(f(q)[-18:], q[12:] / 0.01)


def test_systematic_held_out_nees_includes_the_model_uncertainty(problem) -> None:
    """NEES = ``e^T S^-1 e`` with ``S = s^2 (I + J_new (J^T J)^-1 J_new^T)``."""
    bte, ctb = _arrays(problem.samples)
    fit = fit_systematic(problem.X, problem.Y, bte[:-1], ctb[:-1], "eye_in_hand", 0.0)
    nees = fit.held_out_nees(bte[-1:], ctb[-1:], "eye_in_hand")
    assert fit._state is not None
    p, _, J, _, X0, Y0, s2 = fit._state
    f, _ = _residual_fn(X0, Y0, bte[-1:], ctb[-1:], "eye_in_hand", 0.0, fit.R_ref,
                        fit.sigmas["robot_t"], fit.sigmas["robot_r"])
    e = f(p)[:6]
    Jn = _jacobian(lambda q: f(q)[:6], p)
    S = s2 * (np.eye(6) + Jn @ np.linalg.pinv(J.T @ J) @ Jn.T)
    assert nees[0] == pytest.approx(float(e @ np.linalg.solve(S, e)), rel=1e-6)
    assert nees[0] < float(e @ e) / s2     # the model term only lowers it


def test_six_samples_are_enough_for_the_systematic_levels(problem) -> None:
    bte, ctb = _arrays(problem.samples)
    assert len(bte) == 6
    fit = refine_systematic(problem.X, problem.Y, bte, ctb, "eye_in_hand")
    assert sorted(fit.level_scores) == sorted(float(v) for v in LEVELS)
    assert all(np.isfinite(v) for v in fit.level_scores.values())


# -- plan: the score's units and distinct suggestions -------------------------------------------

def test_trace_score_divides_each_part_by_its_own_target() -> None:
    cfg = PlanConfig(target_mm=0.5, target_deg=0.02)
    cov = np.diag([1e-8, 2e-8, 3e-8, 1e-8, 4e-8, 2e-8])
    mm, deg = _std(cov)
    assert mm == pytest.approx(1000.0 * np.sqrt(6e-8))
    assert deg == pytest.approx(np.degrees(np.sqrt(7e-8)))
    assert _score(cov, cfg) == pytest.approx((mm / 0.5) ** 2 + (deg / 0.02) ** 2)


def test_no_candidate_is_suggested_twice() -> None:
    P = make_problem(5, seed=4, noise_px=0.5, robot_noise_mm=0.2, robot_noise_deg=0.02)
    cfg = PlanConfig(count=3, candidates=3, seed=2)
    plan = suggest_next_poses(P.samples, P.X, "eye_in_hand", P.views, Y=P.Y, config=cfg)
    poses = [s.base_T_ee for s in plan.suggestions]
    assert len(poses) == 3
    for i in range(3):
        for j in range(i + 1, 3):
            assert not np.allclose(poses[i], poses[j])
