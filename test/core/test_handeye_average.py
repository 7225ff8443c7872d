"""The per-motion-pair average (method ``average``) and the per-motion residual table."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.handeye import (
    HandEyeSample,
    MotionPairs,
    calibrate_hand_eye,
    gripper_poses,
    motion_pairs,
    solve_closed_form,
    solve_kronecker,
    solve_tsai,
)
from eye_in_hand.core.handeye import calibrate as calibrate_module
from eye_in_hand.core.handeye.average import (
    AVERAGE_SOLVERS,
    MIN_AXIS_ANGLE_DEG,
    MIN_ROTATION_DEG,
    average_hand_eye,
    pair_solutions,
    rotation_mean,
    usable_motion_pairs,
)
from eye_in_hand.core.handeye.residuals import motion_residual_table, motion_residuals
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import from_rotvec, invert, transform_distance
from eye_in_hand.errors import HandEyeError


def _random_T(rng: np.random.Generator) -> np.ndarray:
    return from_rotvec(Rotation.random(random_state=int(rng.integers(1 << 30))).as_rotvec(),
                       rng.normal(scale=0.5, size=3))


def _exact(setup: str, n: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    X, Y = _random_T(rng), _random_T(rng)
    bte = np.stack([_random_T(rng) for _ in range(n)])
    G = gripper_poses(bte, setup)
    ctb = np.stack([invert(X) @ invert(g) @ Y for g in G])
    return X, bte, ctb


def _err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    dt, dr = transform_distance(A, B)
    return 1000.0 * dt, float(np.degrees(dr))


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("solver", AVERAGE_SOLVERS)
def test_exact_motions_recover_x(setup: str, solver: str) -> None:
    X, bte, ctb = _exact(setup, seed=11 if setup == "eye_in_hand" else 12)
    res = average_hand_eye(motion_pairs(gripper_poses(bte, setup), ctb), solver)
    assert np.max(np.abs(res.X - X)) < 1e-9
    assert res.n_used > 100 and res.n_used + res.skipped_parallel_axes \
        + res.skipped_small_rotation + res.skipped_degenerate + res.subsampled_out \
        == res.n_candidates == 28 * 27 // 2
    assert res.rot_std_deg < 1e-8 and res.trans_std_mm < 1e-6
    # Every per-pair solution is X itself, not only their mean.
    assert np.max(np.abs(res.solutions - X)) < 1e-8


@pytest.mark.parametrize("solver", AVERAGE_SOLVERS)
def test_pair_solutions_equal_the_full_solvers_on_two_motions(solver: str) -> None:
    """Noisy motions: each vectorised per-pair solution equals the registry's solver run on
    just those two motions."""
    X, bte, ctb = _exact("eye_in_hand", seed=5)
    rng = np.random.default_rng(1)
    m = motion_pairs(bte, ctb)
    noisy = MotionPairs(m.A @ np.stack([from_rotvec(rng.normal(scale=0.01, size=3),
                                                    rng.normal(scale=0.002, size=3))
                                        for _ in range(len(m))]), m.B, m.index)
    pairs, _, _ = usable_motion_pairs(noisy)
    pairs = pairs[::37]
    Xs, ok = pair_solutions(noisy, pairs, solver)
    assert ok.all()
    full = solve_tsai if solver == "tsai" else solve_kronecker
    for Xp, (p, q) in zip(Xs, pairs, strict=True):
        ref = full(MotionPairs(noisy.A[[p, q]], noisy.B[[p, q]], noisy.index[[p, q]]))
        assert np.max(np.abs(Xp - ref)) < 1e-9
    assert np.max(np.abs(Xs - X)) > 1e-4  # the noise does change them


def test_rotation_mean_is_a_proper_rotation_and_symmetric_sets_average_to_the_centre() -> None:
    rng = np.random.default_rng(4)
    R0 = Rotation.random(random_state=3).as_matrix()
    # Scattered rotations: the arithmetic mean of the matrices is not a rotation.
    Rs = np.stack([R0 @ Rotation.from_rotvec(rng.normal(scale=0.4, size=3)).as_matrix()
                   for _ in range(20)])
    assert abs(np.linalg.det(Rs.mean(axis=0)) - 1.0) > 1e-3
    for method in ("chordal", "geodesic"):
        M = rotation_mean(Rs, method)
        assert np.max(np.abs(M.T @ M - np.eye(3))) < 1e-12
        assert abs(np.linalg.det(M) - 1.0) < 1e-12
    # Symmetric set R0 exp(+-theta e_k): the mean is R0 (both means), whatever theta.
    sym = np.stack([R0 @ Rotation.from_rotvec(s * 0.7 * e).as_matrix()
                    for e in np.eye(3) for s in (1.0, -1.0)])
    for method in ("chordal", "geodesic"):
        assert np.max(np.abs(rotation_mean(sym, method) - R0)) < 1e-12
    # Geodesic mean: the rotation vectors of the rotations about the mean sum to zero.
    G = rotation_mean(Rs, "geodesic")
    resid = Rotation.from_matrix(np.einsum("ji,kjl->kil", G, Rs)).as_rotvec().sum(axis=0)
    assert np.linalg.norm(resid) < 1e-10
    with pytest.raises(HandEyeError, match="rotation mean"):
        rotation_mean(Rs, "median")


def _motions(rotvecs_deg: list[list[float]]) -> MotionPairs:
    """Motions with the given robot rotations (deg rotation vectors) and a consistent X."""
    rng = np.random.default_rng(9)
    X = _random_T(rng)
    A = np.stack([from_rotvec(np.radians(r), rng.normal(scale=0.2, size=3))
                  for r in rotvecs_deg])
    B = invert(X)[None] @ A @ X[None]
    return MotionPairs(A, B, np.zeros((len(A), 2), dtype=int))


def test_parallel_axis_and_small_rotation_pairs_are_skipped_and_counted() -> None:
    assert (MIN_ROTATION_DEG, MIN_AXIS_ANGLE_DEG) == (5.0, 15.0)
    sep = MIN_AXIS_ANGLE_DEG - 2.0   # just under the threshold: parallel
    ok = MIN_AXIS_ANGLE_DEG + 2.0    # just over: used

    def about(deg_from_z: float, angle: float) -> list[float]:
        a = np.radians(deg_from_z)
        return (angle * np.array([np.sin(a), 0.0, np.cos(a)])).tolist()

    m = _motions([
        [0.0, 0.0, 30.0],            # 0: z
        [0.0, 0.0, -50.0],           # 1: -z (anti-parallel axis: parallel as a line)
        about(sep, 40.0),            # 2: 13 deg from z
        about(ok, 40.0),             # 3: 17 deg from z
        [0.0, 3.0, 0.0],             # 4: rotation under 5 deg
        [40.0, 0.0, 0.0],            # 5: x
    ])
    pairs, small, parallel = usable_motion_pairs(m)
    assert small == 5                                    # every pair with motion 4
    # (0,1) anti-parallel, (0,2), (1,2) 13 deg apart; (2,3) 4 deg apart.
    assert parallel == 4
    assert sorted(map(tuple, pairs.tolist())) == [(0, 3), (0, 5), (1, 3), (1, 5), (2, 5),
                                                  (3, 5)]
    res = average_hand_eye(m)
    assert (res.n_used, res.skipped_small_rotation, res.skipped_parallel_axes,
            res.n_candidates) == (6, 5, 4, 15)
    summary = res.summary()
    assert summary["skipped"] == {"small_rotation": 5, "parallel_axes": 4, "degenerate": 0,
                                  "subsampled_out": 0}
    assert summary["n_pairs_used"] == 6 and summary["thresholds"]["min_axis_angle_deg"] == 15.0


def test_too_few_usable_pairs_is_a_clear_error() -> None:
    # z, x, z again, and a 2 deg motion: (z, x) twice usable, (z, z) parallel, 3 pairs small.
    m = _motions([[0.0, 0.0, 30.0], [40.0, 0.0, 0.0], [0.0, 0.0, 50.0], [0.0, 2.0, 0.0]])
    with pytest.raises(HandEyeError, match=r"average: 2 usable pairs of motions of 6 \(3 with a "
                                           r"robot rotation under 5 deg, 1 with rotation axes "
                                           r"within 15 deg"):
        average_hand_eye(m)


def test_the_subset_is_counted_and_reproducible() -> None:
    X, bte, ctb = _exact("eye_in_hand", n=10, seed=21)
    m = motion_pairs(bte, ctb)
    a = average_hand_eye(m, max_pairs=50)
    b = average_hand_eye(m, max_pairs=50)
    assert a.n_used == 50 and np.array_equal(a.pairs, b.pairs)
    assert a.n_used + a.subsampled_out + a.skipped_parallel_axes + a.skipped_small_rotation \
        == 45 * 44 // 2
    assert np.max(np.abs(a.X - X)) < 1e-9


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_noisy_average_is_near_the_truth(setup: str) -> None:
    """0.5 px corner noise, 12 samples, 8 datasets: every average within 3 mm / 0.3 deg of the
    truth (the largest error measured over these seeds is 2.1 mm / 0.21 deg), and its median
    error within 1.5x Park-Martin's (measured: 1.00x / 1.10x eye-in-hand, 1.08x / 1.23x
    eye-to-hand, translation / rotation)."""
    ours, park = [], []
    for seed in range(200, 208):
        P = make_problem(12, setup=setup, seed=seed, noise_px=0.5)
        b = np.stack([s.base_T_ee for s in P.samples])
        c = np.stack([s.cam_T_board for s in P.samples])
        res = average_hand_eye(motion_pairs(gripper_poses(b, setup), c))
        ours.append(_err(P.X, res.X))
        park.append(_err(P.X, solve_closed_form("park", b, c, setup)))
        assert res.rot_std_deg > 0.0 and res.trans_std_mm > 0.0
    ours_a, park_a = np.array(ours), np.array(park)
    assert np.all(ours_a[:, 0] < 3.0) and np.all(ours_a[:, 1] < 0.3), ours
    assert np.median(ours_a[:, 0]) < 1.5 * np.median(park_a[:, 0])
    assert np.median(ours_a[:, 1]) < 1.5 * np.median(park_a[:, 1])


def test_average_takes_part_in_the_pipeline_and_selection() -> None:
    P = make_problem(8, seed=31, noise_px=0.3)
    res = calibrate_hand_eye(P.samples, cameras=P.views, refine=False)
    assert "average" in res.methods and "average" in res.selection_scores
    s = res.methods["average"].summary()
    assert s["average"]["solver"] == "tsai" and s["average"]["n_pairs_used"] > 100
    assert s["held_out"]["px_rms"] > 0
    forced = calibrate_hand_eye(P.samples, cameras=P.views, refine=False, method="average",
                                average_solver="kronecker")
    assert forced.selected == "average"
    assert forced.methods["average"].average["solver"] == "kronecker"
    assert _err(P.X, forced.X)[0] < 3.0
    with pytest.raises(HandEyeError, match="average solver"):
        calibrate_hand_eye(P.samples, average_solver="park")


def test_average_without_usable_pairs_is_left_out_with_the_reason() -> None:
    """Tool rotations of 2 deg about varied axes (every motion under 4 deg): the closed forms
    solve these exact poses, the average has no usable pair, says why, and cannot be forced."""
    rng = np.random.default_rng(2)
    X = from_rotvec([0.1, -0.2, 0.15], [0.04, -0.06, 0.09])
    Y = from_rotvec([np.pi, 0.0, 0.3], [0.55, 0.1, 0.02])
    samples = []
    for k in range(8):
        u = rng.normal(size=3)
        b = from_rotvec(np.radians(2.0) * u / np.linalg.norm(u), rng.normal(scale=0.2, size=3))
        samples.append(HandEyeSample(f"s{k}", b, invert(X) @ invert(b) @ Y))
    res = calibrate_hand_eye(samples, refine=False, reject_outliers=False)
    assert "average" not in res.methods and "park" in res.methods
    assert _err(X, res.X)[0] < 1e-6
    assert any(w.startswith("average failed on these samples") and "average: 0 usable pairs "
               "of motions of 378 (378 with a robot rotation under 5 deg" in w
               for w in res.warnings), res.warnings
    with pytest.raises(HandEyeError, match="method 'average' failed"):
        calibrate_hand_eye(samples, refine=False, reject_outliers=False, method="average")


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_residual_table_matches_a_direct_computation(setup: str) -> None:
    P = make_problem(6, setup=setup, seed=41, noise_px=0.5)
    b = np.stack([s.base_T_ee for s in P.samples])
    c = np.stack([s.cam_T_board for s in P.samples])
    names = [s.name for s in P.samples]
    Xs = {"truth": P.X, "park": solve_closed_form("park", b, c, setup)}
    table = motion_residual_table(Xs, b, c, setup, names)
    assert table["methods"] == ["truth", "park"] and len(table["motions"]) == 15
    k = 0
    for i in range(6):
        for j in range(i + 1, 6):
            assert table["motions"][k] == [names[i], names[j]]
            # Direct: robot motion A and camera motion B between samples i and j.
            Gi, Gj = (b[i], b[j]) if setup == "eye_in_hand" else (invert(b[i]), invert(b[j]))
            A = invert(Gj) @ Gi
            B = c[j] @ invert(c[i])
            for name, X in Xs.items():
                D = A @ X - X @ B
                assert table["frobenius"][name][k] == pytest.approx(np.linalg.norm(D),
                                                                    rel=1e-9, abs=1e-15)
                assert table["trans_mm"][name][k] == pytest.approx(
                    1000.0 * np.linalg.norm(D[:3, 3]), rel=1e-9, abs=1e-12)
                cos = (np.trace((A @ X)[:3, :3].T @ (X @ B)[:3, :3]) - 1.0) / 2.0
                assert table["rot_deg"][name][k] == pytest.approx(
                    np.degrees(np.arccos(np.clip(cos, -1, 1))), abs=1e-6)
            k += 1
    for name in Xs:
        s = table["summary"][name]
        for q in ("rot_deg", "trans_mm", "frobenius"):
            v = np.array(table[q][name])
            assert s[q]["mean"] == pytest.approx(v.mean()) and s[q]["max"] == v.max()
            assert s[q]["median"] == pytest.approx(np.median(v))
    # The true X's residuals are the noise of the camera motions alone: nonzero, and smaller
    # than a wrong X's.
    r_true = motion_residuals(P.X, b, c, setup)
    r_off = motion_residuals(P.X @ from_rotvec([0.0, 0.02, 0.0], [0.01, 0.0, 0.0]), b, c, setup)
    assert 0 < np.median(r_true["frobenius"]) < np.median(r_off["frobenius"])


def test_every_solver_failing_includes_the_average(monkeypatch) -> None:
    P = make_problem(6, seed=71, noise_px=0.3)

    def broken(m, *args):
        raise HandEyeError("planted failure")

    for name in list(calibrate_module.CLOSED_FORM_METHODS):
        monkeypatch.setitem(calibrate_module.CLOSED_FORM_METHODS, name, broken)
    res = calibrate_hand_eye(P.samples, cameras=P.views, check_conventions=False, refine=False)
    assert set(res.methods) == {"average"} and res.selected == "average"
    monkeypatch.setattr(calibrate_module, "solve_average", broken)
    with pytest.raises(HandEyeError, match="every closed-form solver failed"):
        calibrate_hand_eye(P.samples, cameras=P.views, check_conventions=False)


def test_degenerate_pairs_are_skipped_and_counted_never_averaged() -> None:
    """The flange only rotates about a still point (robot motions without translation): the
    homogeneous Kronecker form of every pair has a two-dimensional null space, so every pair
    is degenerate and the average is an error that says so; Tsai per pair solves."""
    rng = np.random.default_rng(3)
    X = from_rotvec([0.1, -0.2, 0.15], [0.04, -0.06, 0.09])
    Y = from_rotvec([np.pi, 0.0, 0.3], [0.55, 0.1, 0.02])
    bte = np.stack([from_rotvec((Rotation.from_rotvec(rng.normal(scale=0.4, size=3))
                                 * Rotation.from_rotvec([np.pi, 0, 0])).as_rotvec(),
                                [0.5, 0.1, 0.45]) for _ in range(6)])
    ctb = np.stack([invert(X) @ invert(b) @ Y for b in bte])
    m = motion_pairs(bte, ctb)
    res = average_hand_eye(m, "tsai")
    assert np.max(np.abs(res.X - X)) < 1e-9 and res.skipped_degenerate == 0
    n_usable = len(usable_motion_pairs(m)[0])
    with pytest.raises(HandEyeError, match=rf", {n_usable} degenerate\); need at least 3"):
        average_hand_eye(m, "kronecker")


def test_spread_is_each_pair_solution_against_the_mean_in_mm_and_deg() -> None:
    """``trans_dev_mm`` / ``rot_dev_deg``: each per-pair solution's distance from the averaged
    X, millimetres and degrees; the RMS figures are their RMS."""
    P = make_problem(10, seed=71, noise_px=0.5)
    bte = np.stack([s.base_T_ee for s in P.samples])
    ctb = np.stack([s.cam_T_board for s in P.samples])
    res = average_hand_eye(motion_pairs(gripper_poses(bte, "eye_in_hand"), ctb))
    dev_mm = 1000.0 * np.linalg.norm(res.solutions[:, :3, 3] - res.X[:3, 3], axis=1)
    dev_deg = np.degrees(np.linalg.norm(Rotation.from_matrix(
        np.einsum("ji,kjl->kil", res.X[:3, :3], res.solutions[:, :3, :3])).as_rotvec(), axis=1))
    np.testing.assert_allclose(res.trans_dev_mm, dev_mm, rtol=1e-12)
    np.testing.assert_allclose(res.rot_dev_deg, dev_deg, rtol=1e-9, atol=1e-12)
    assert res.trans_std_mm == pytest.approx(np.sqrt(np.mean(dev_mm ** 2)), rel=1e-12)
    assert 0.05 < res.trans_std_mm < 50.0     # millimetres of a 0.5 px problem, not metres
    # X's translation is the arithmetic mean of the per-pair translations (not a median)
    np.testing.assert_allclose(res.X[:3, 3], res.solutions[:, :3, 3].mean(axis=0), rtol=1e-12)
    assert np.max(np.abs(np.median(res.solutions[:, :3, 3], axis=0) - res.X[:3, 3])) > 1e-7


def test_chordal_mean_is_a_rotation_when_the_summed_matrix_has_a_negative_determinant() -> None:
    """Half turns about x, y and z sum to nearly -I (determinant < 0): the SVD projection must
    flip the last singular direction to stay in SO(3), not return a reflection."""
    R = Rotation.from_rotvec(np.array([[np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi]])
                             + np.array([[0, 0.05, 0], [0.02, 0, 0], [0, 0.03, 0]])).as_matrix()
    assert np.linalg.det(R.sum(axis=0)) < 0
    M = rotation_mean(R)
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(M) == pytest.approx(1.0, abs=1e-12)
