"""core.handeye: documented rules that held-out planted bugs showed no test pinned.

Each test puts a rule of the per-pair average, the error budget, the held-out figures, the
systematic robot model and the next-pose planner at a point where the wrong rule gives another
number (see ``tools/mutation_heldout.py`` and the table of ``tools/mutation.py``).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

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


# -- second held-out batch: the rules its survivors showed unpinned -----------------------------

def test_average_with_exactly_the_minimum_of_usable_pairs() -> None:
    """Three motions about three axes give MIN_PAIRS (3) usable pairs: enough."""
    from eye_in_hand.core.handeye.average import MIN_PAIRS, average_hand_eye
    from eye_in_hand.core.transforms import invert

    X = from_rotvec(np.array([0.1, -0.2, 0.3]), np.array([0.03, -0.02, 0.05]))
    A = np.stack([from_rotvec(np.array(v, float), np.array(t, float))
                  for v, t in (([0.5, 0, 0], [0.1, 0, 0]), ([0, 0.6, 0], [0, 0.1, 0.02]),
                               ([0, 0, 0.7], [0.02, 0, 0.1]))])
    m = MotionPairs(A, invert(X) @ A @ X, np.zeros((3, 2), dtype=int))
    res = average_hand_eye(m)
    assert MIN_PAIRS == 3 and res.n_used == 3
    assert np.allclose(res.X, X, atol=1e-9)


def test_budget_camera_part_from_the_rms_pnp_residual(problem) -> None:
    """``camera_mm``: the centre variance at the corners' RMS PnP residual, m^2 -> mm^2."""
    from eye_in_hand.core.handeye.observe import board_pose_pnp
    from eye_in_hand.core.handeye.select import _centre_variance

    views = {v.name: v for v in problem.views}
    rms = [board_pose_pnp(views[s.observations[0].camera].model,
                          s.observations[0].object_points, s.observations[0].image_points)[1]
           for s in problem.samples]
    assert np.std(rms) > 0.05 * np.mean(rms)            # mean and RMS differ
    px = float(np.sqrt(np.mean(np.square(rms))))
    c2 = 1e6 * float(np.mean([_centre_variance(s, problem.views, px, np.zeros(3))
                              for s in problem.samples]))
    n = len(problem.samples)
    b = error_budget(problem.samples, problem.views, "eye_in_hand", problem.Y,
                     np.full(n, 10.0), np.full(n, 20.0))
    assert b["camera_mm"] == pytest.approx(np.sqrt(c2), abs=2e-4)


def test_combined_score_scales_both_parts_by_their_median_rms() -> None:
    from eye_in_hand.core.handeye.select import HeldOut, selection_scores

    ones = np.ones(4)
    held = {"a": HeldOut(np.array([1.0, 2.0, 1.0, 2.0]), np.array([3.0, 1.0, 2.0, 2.0]), ones),
            "b": HeldOut(np.array([2.0, 2.0, 2.0, 2.0]), np.array([6.0, 6.0, 6.0, 6.0]), ones),
            "c": HeldOut(np.array([4.0, 1.0, 1.0, 1.0]), np.array([1.0, 1.0, 1.0, 1.0]), ones)}
    rms = {k: (np.sqrt(np.mean(h.px ** 2)), np.sqrt(np.mean(h.mm ** 2)))
           for k, h in held.items()}
    ref_px = np.median([v[0] for v in rms.values()])
    ref_mm = np.median([v[1] for v in rms.values()])
    scores, _ = selection_scores(held, combine=True)
    for k, h in held.items():
        want = np.sqrt(np.mean((h.px / ref_px) ** 2 + (h.mm / ref_mm) ** 2))
        assert scores[k] == pytest.approx(want)


def test_centre_variance_grows_with_the_lever_arm(problem) -> None:
    """The variance of ``R c + t`` is quadratic in ``c`` with the rotation's uncertainty as
    its curvature: ``v(c) + v(-c) - 2 v(0) = 2 tr([Rc]x C_rr [Rc]x^T) > 0``."""
    from eye_in_hand.core.handeye.select import _centre_variance

    s = problem.samples[0]
    c = np.array([0.3, -0.2, 0.0])
    v0, vp, vm = (_centre_variance(s, problem.views, 0.5, x) for x in (np.zeros(3), c, -c))
    assert vp + vm - 2 * v0 > 0.5 * v0


def test_pose_pair_errors_in_variables_recovers_x() -> None:
    """Pose pairs only: from a start 1 deg and 5 mm off, the refinement returns X within its
    noise, and the camera-pose rotation level it estimates is that of the data (a rotation
    residual measured wrongly would show as a huge level, its rows then ignored)."""
    from eye_in_hand.core.handeye.eiv import refine_errors_in_variables

    P = make_problem(12, seed=2, noise_px=0.2, robot_noise_mm=0.1, robot_noise_deg=0.01)
    pairs = [HandEyeSample(s.name, s.base_T_ee, s.cam_T_board) for s in P.samples]
    X0 = P.X @ from_rotvec(np.radians([1.0, 0, 0]), np.array([0.005, 0, 0]))
    res = refine_errors_in_variables(X0, P.Y, pairs, None, "eye_in_hand")
    assert np.linalg.norm(res.X[:3, 3] - P.X[:3, 3]) < 0.002
    assert np.degrees(np.linalg.norm(
        Rotation.from_matrix(res.X[:3, :3].T @ P.X[:3, :3]).as_rotvec())) < 0.2
    assert res.sigmas["cam_r"] < np.radians(0.2)


def test_systematic_whitening_and_first_pass_levels(problem) -> None:
    """Translation residuals are divided by ``robot_t``, rotations by ``robot_r``; the first
    pass estimates both over ``6 n - p`` degrees of freedom, ``p = 12 + 18`` with the
    systematic term."""
    from eye_in_hand.core.handeye.systematic import _fit_once

    bte, ctb = _arrays(problem.samples)
    R = np.eye(3)
    X0 = problem.X @ from_rotvec(np.array([0.01, 0, 0]), np.array([0.002, 0, 0]))
    f1, _ = _residual_fn(X0, problem.Y, bte, ctb, "eye_in_hand", 0.0, R, 1e-3, 1e-2)
    f2, _ = _residual_fn(X0, problem.Y, bte, ctb, "eye_in_hand", 0.0, R, 2e-3, 1e-2)
    p = np.concatenate([X0[:3, 3], np.zeros(3), problem.Y[:3, 3], np.zeros(3)])
    r1, r2 = f1(p).reshape(-1, 6), f2(p).reshape(-1, 6)
    assert np.allclose(r1[:, :3], 2 * r2[:, :3]) and np.allclose(r1[:, 3:], r2[:, 3:])
    assert np.abs(r1[:, :3]).max() > 0 and np.abs(r1[:, 3:]).max() > 0
    fit = fit_systematic(problem.X, problem.Y, bte, ctb, "eye_in_hand", 0.01)
    n = len(bte)
    res, _, _ = _fit_once(problem.X, problem.Y, bte, ctb, "eye_in_hand", 0.01, fit.R_ref,
                          1.0, 1.0)
    m = res.fun[:6 * n].reshape(n, 6)
    dof = (6 * n - 30) / (6 * n)
    assert fit.sigmas["robot_t"] == pytest.approx(np.sqrt(np.mean(m[:, :3] ** 2) / dof))
    assert fit.sigmas["robot_r"] == pytest.approx(np.sqrt(np.mean(m[:, 3:] ** 2) / dof))


def test_systematic_eye_to_hand_held_out_error_is_zero_on_exact_data() -> None:
    from eye_in_hand.core.handeye.systematic import _held_out_pose_error

    P = make_problem(8, setup="eye_to_hand", seed=3, noise_px=0.0)
    bte, ctb = P.true_base_T_ee, P.true_cam_T_board
    fit = fit_systematic(P.X, P.Y, bte, ctb, "eye_to_hand", 0.0,
                         sigmas={"robot_t": 1e-4, "robot_r": 1e-4})
    assert np.abs(_held_out_pose_error(fit, bte, ctb, "eye_to_hand")).max() < 1e-3


def test_planner_noise_levels_in_eiv_names() -> None:
    sig = PlanConfig(noise_px=0.4, robot_sigma_pos_m=2e-4, robot_sigma_rot_rad=5e-4).sigmas()
    assert sig == {"px": 0.4, "robot_t": 2e-4, "robot_r": 5e-4}


def test_planner_outline_is_one_spacing_beyond_the_outer_corners(problem) -> None:
    """The board's outline (the outer squares a detector needs) lies one corner spacing
    outside the outer corners."""
    from eye_in_hand.core.handeye.plan import _board_points

    pts, outline = _board_points(problem.samples)
    spacing = 0.025                                      # make_problem's default board
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    assert np.allclose(np.sort(np.unique(np.round(outline[:, 0], 9))),
                       [lo[0] - spacing, hi[0] + spacing])
    assert np.allclose(np.sort(np.unique(np.round(outline[:, 1], 9))),
                       [lo[1] - spacing, hi[1] + spacing])
