"""Errors-in-variables hand-eye refinement, held-out selection and hand-eye edge cases."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from eye_in_hand.core.handeye import (
    CLOSED_FORM_METHODS,
    HandEyeSample,
    calibrate_hand_eye,
    solve_closed_form,
)
from eye_in_hand.core.handeye import calibrate as calibrate_module
from eye_in_hand.core.handeye.eiv import leave_one_out_steps, refine_errors_in_variables
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import from_rotvec, invert, transform_distance
from eye_in_hand.errors import HandEyeError


def _err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    dt, dr = transform_distance(A, B)
    return 1000.0 * dt, float(np.degrees(dr))


def _pairs_only(samples):
    return [HandEyeSample(s.name, s.base_T_ee, s.cam_T_board) for s in samples]


def _start(P, samples, cameras):
    bte = np.stack([s.base_T_ee for s in samples])
    ctb = np.stack([s.cam_T_board for s in samples])
    X0 = solve_closed_form("park", bte, ctb, P.setup)
    G = bte if P.setup == "eye_in_hand" else np.stack([invert(b) for b in bte])
    Y0 = G[0] @ X0 @ ctb[0]
    return X0, Y0


def test_exact_poses_match_the_exact_pose_refinement() -> None:
    P = make_problem(10, seed=31, noise_px=0.5)
    res = calibrate_hand_eye(P.samples, cameras=P.views, leave_one_out=False)
    eiv, exact = res.methods["refined"], res.methods["refined_exact"]
    mm, deg = _err(eiv.X, exact.X)
    # Far below their own uncertainty: the same estimate.
    assert mm < 0.1 * eiv.std_mm and deg < 0.1 * eiv.std_deg, (mm, deg)
    noise = res.robot_pose_noise
    assert noise is not None
    assert noise["translation_sigma_m"] < 2e-5 and noise["rotation_sigma_rad"] < 2e-5
    assert 0.4 < res.refinement.sigmas["px"] < 0.6


def test_noisy_poses_errors_in_variables_beats_exact_pose_refinement() -> None:
    """1 mm / 0.1 deg per pose: the exact-pose refinement bends X, the model does not; the noise
    levels are recovered."""
    eiv, exact, best = [], [], []
    for seed in range(3):
        P = make_problem(12, seed=40 + seed, noise_px=0.5, robot_noise_mm=1.0,
                         robot_noise_deg=0.1)
        res = calibrate_hand_eye(P.samples, cameras=P.views, leave_one_out=False,
                                 reject_outliers=False)
        eiv.append(_err(P.X, res.methods["refined"].X))
        exact.append(_err(P.X, res.methods["refined_exact"].X))
        cf = [_err(P.X, res.methods[m].X) for m in CLOSED_FORM_METHODS]
        best.append((min(c[0] for c in cf), min(c[1] for c in cf)))
        sig = res.refinement.sigmas
        assert 0.5e-3 < sig["robot_t"] < 2e-3, sig
        assert 0.5 * np.radians(0.1) < sig["robot_r"] < 2 * np.radians(0.1), sig
    eiv_m, exact_m, best_m = (np.median(a, axis=0) for a in (eiv, exact, best))
    assert eiv_m[0] < 0.6 * exact_m[0] and eiv_m[1] < 0.6 * exact_m[1], (eiv, exact)
    assert eiv_m[0] < 1.25 * best_m[0] and eiv_m[1] < 1.25 * best_m[1], (eiv, best)


@pytest.mark.parametrize("case", ["stereo", "eye_to_hand", "pairs"])
def test_errors_in_variables_other_inputs(case: str) -> None:
    P = make_problem(12, seed=50, noise_px=0.5, robot_noise_mm=1.0, robot_noise_deg=0.1,
                     stereo=case == "stereo",
                     setup="eye_to_hand" if case == "eye_to_hand" else "eye_in_hand")
    samples = _pairs_only(P.samples) if case == "pairs" else P.samples
    cams = None if case == "pairs" else P.views
    r = refine_errors_in_variables(*_start(P, samples, cams), samples, cams, P.setup)
    assert r.converged and r.space == ("pose" if case == "pairs" else "reprojection")
    mm, deg = _err(P.X, r.X)
    assert mm < 3.0 and deg < 0.25, (mm, deg)
    # The reported uncertainty is of the size of the actual error.
    C = r.covariance
    assert mm / 1000.0 < 4.0 * np.sqrt(np.trace(C[:3, :3]))
    assert np.radians(deg) < 4.0 * np.sqrt(np.trace(C[3:, 3:]))
    assert 0.3 * np.radians(0.1) < r.robot_rotation_sigma_rad < 3 * np.radians(0.1)


def test_leave_one_out_step_matches_a_full_resolve() -> None:
    P = make_problem(10, seed=60, noise_px=0.5, robot_noise_mm=0.5, robot_noise_deg=0.05)
    r = refine_errors_in_variables(*_start(P, P.samples, P.views), P.samples, P.views,
                                   P.setup)
    steps = leave_one_out_steps(r.X, r.Y, P.samples, P.views, P.setup, r.sigmas,
                                r.corrections)
    for i in (0, 7):
        sub = [s for k, s in enumerate(P.samples) if k != i]
        full = refine_errors_in_variables(r.X, r.Y, sub, P.views, P.setup, sigmas=r.sigmas,
                                          estimate=False)
        moved = _err(r.X, full.X)
        mm, deg = _err(steps[i][0], full.X)
        assert mm < 0.05 * moved[0] + 1e-4 and deg < 0.05 * moved[1] + 1e-5, (mm, deg, moved)


def test_uncertainty_is_honest_on_a_small_sweep() -> None:
    """NEES and 95 % coverage of the errors-in-variables covariance over 18 small datasets
    (robot error 0 / 0.2 mm 0.02 deg / 1 mm 0.1 deg, 0.3 and 1 px; the benchmark's sweep is
    ``bench_handeye.py --nees``)."""
    levels = [(0.0, 0.0), (0.2, 0.02), (1.0, 0.1)]
    nt, nr = [], []
    for i in range(18):
        mm, deg = levels[i % 3]
        px = (0.3, 1.0)[(i // 3) % 2]
        P = make_problem(8, seed=700 + i, noise_px=px, robot_noise_mm=mm, robot_noise_deg=deg)
        r = refine_errors_in_variables(*_start(P, P.samples, P.views), P.samples, P.views,
                                       P.setup)
        e = np.concatenate([r.X[:3, 3] - P.X[:3, 3],
                            Rotation.from_matrix(r.X[:3, :3] @ P.X[:3, :3].T).as_rotvec()])
        C = r.covariance
        nt.append(float(e[:3] @ np.linalg.solve(C[:3, :3], e[:3])))
        nr.append(float(e[3:] @ np.linalg.solve(C[3:, 3:], e[3:])))
    nt_a, nr_a = np.array(nt), np.array(nr)
    print(f"NEES translation {nt_a.mean():.2f}, rotation {nr_a.mean():.2f}")
    assert 1.5 < nt_a.mean() < 6.0 and 1.5 < nr_a.mean() < 6.0, (nt, nr)
    k = chi2.ppf(0.95, 3)
    assert 0.8 <= np.mean(nt_a < k) <= 1.0 and 0.8 <= np.mean(nr_a < k) <= 1.0, (nt, nr)


def test_selection_by_held_out_prediction() -> None:
    """Noisy poses: the exact-pose refinement predicts held-out samples worse and is not written;
    every method has its held-out figures; --method forces a method."""
    P = make_problem(12, seed=41, noise_px=0.5, robot_noise_mm=1.0, robot_noise_deg=0.1)
    # the per-pose model's rule: the score is the held-out corner RMS (px)
    res = calibrate_hand_eye(P.samples, cameras=P.views, robot_model="per_pose")
    assert set(res.selection_scores) == set(res.methods)
    for name, mr in res.methods.items():
        assert mr.held_out is not None and mr.held_out.px is not None, name
        assert mr.held_out.px.shape == (12,) and np.all(mr.held_out.px > 0)
        assert np.isclose(res.selection_scores[name], np.sqrt(np.mean(mr.held_out.px ** 2)))
    assert res.selection_scores["refined_exact"] > res.selection_scores["refined"]
    assert res.selected != "refined_exact" and res.selected in res.selection_reason
    assert res.covariance is not None
    forced = calibrate_hand_eye(P.samples, cameras=P.views, method="refined_exact")
    assert forced.selected == "refined_exact" and "forced" in forced.selection_reason
    # A method whose held-out prediction is significantly better replaces refined.
    from eye_in_hand.core.handeye.select import HeldOut, choose

    ones = np.ones(12)
    held = {"refined": HeldOut(1.2 * ones + 0.01 * np.arange(12), ones, ones),
            "park": HeldOut(ones, ones, ones),
            "tsai": HeldOut(1.19 * ones + 0.01 * np.arange(12) ** 1.1, ones, ones)}
    assert choose(held, list(held))[0] == "park"
    held["park"] = HeldOut(1.2 * ones + 0.3 * np.sin(np.arange(12)) - 0.01, ones, ones)
    assert choose(held, list(held))[0] == "refined"  # better on average, within the noise


def test_a_failing_solver_removes_only_itself(monkeypatch) -> None:
    P = make_problem(10, seed=70, noise_px=0.3)

    def broken(m):
        raise HandEyeError("tsai: planted failure")

    monkeypatch.setitem(calibrate_module.CLOSED_FORM_METHODS, "tsai", broken)
    res = calibrate_hand_eye(P.samples, cameras=P.views)
    assert "tsai" not in res.methods and "park" in res.methods and "refined" in res.methods
    assert any(w.startswith("tsai failed on these samples") and "planted" in w
               for w in res.warnings)
    assert _err(P.X, res.X)[0] < 1.0


def test_pure_rotation_of_a_still_flange_solves() -> None:
    """The flange stays at one point and only rotates: the linear Kronecker forms are singular
    there, every other method solves."""
    rng = np.random.default_rng(3)
    X = from_rotvec([0.1, -0.2, 0.15], [0.04, -0.06, 0.09])
    Y = from_rotvec([np.pi, 0.0, 0.3], [0.55, 0.1, 0.02])
    samples = []
    for k in range(10):
        b = from_rotvec((Rotation.from_rotvec(rng.normal(scale=0.3, size=3))
                         * Rotation.from_rotvec([np.pi, 0, 0])).as_rotvec(), [0.5, 0.1, 0.45])
        c = invert(X) @ invert(b) @ Y
        c = c @ from_rotvec(rng.normal(scale=1e-4, size=3), rng.normal(scale=5e-5, size=3))
        samples.append(HandEyeSample(f"s{k}", b, c))
    res = calibrate_hand_eye(samples)
    failed = {m for m in CLOSED_FORM_METHODS if m not in res.methods}
    assert failed == {"andreff", "kronecker"}
    assert all(any(w.startswith(f"{m} failed") for w in res.warnings) for m in failed)
    mm, deg = _err(X, res.X)
    assert mm < 1.0 and deg < 0.05, (res.selected, mm, deg)


def test_every_solver_failing_is_one_clear_error(monkeypatch) -> None:
    P = make_problem(6, seed=71, noise_px=0.3)

    def broken(m):
        raise HandEyeError("planted failure")

    for name in list(calibrate_module.CLOSED_FORM_METHODS):
        monkeypatch.setitem(calibrate_module.CLOSED_FORM_METHODS, name, broken)
    monkeypatch.setattr(calibrate_module, "solve_average", lambda m, solver: broken(m))
    with pytest.raises(HandEyeError, match="every closed-form solver failed"):
        calibrate_hand_eye(P.samples, cameras=P.views, check_conventions=False)
