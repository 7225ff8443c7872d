"""core.handeye.select: the numbers behind the choice and the written robot noise.

Each test puts the documented formula at a point where a wrong law gives a different answer:
a paired difference between 2 standard errors and 2 standard deviations of the mean, and a
held-out position sigma with a non-zero rotation sigma and a flange far from the base origin.
"""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.core.handeye.select import HeldOut, choose, held_out_position_sigma
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import from_rotvec

N = 12


def _paired(t: float) -> dict[str, HeldOut]:
    """``refined`` and ``park`` whose per-sample squared-error differences ``d`` have a mean
    of exactly ``t`` standard errors (``std(d, ddof=1) / sqrt(N)``)."""
    z = np.sin(np.arange(N) * 1.7)
    z = (z - z.mean()) / np.std(z - z.mean(), ddof=1)      # mean 0, sample std 1
    d = z + t / np.sqrt(N)
    ref = np.full(N, 3.0)
    best = np.sqrt(ref ** 2 + d)
    ones = np.ones(N)
    return {"refined": HeldOut(ref, ones, ones), "park": HeldOut(best, ones, ones)}


@pytest.mark.parametrize("t, chosen", [(-2.6, "park"), (-2.05, "park"), (-1.95, "refined"),
                                       (-1.0, "refined")])
def test_paired_rule_is_two_standard_errors(t, chosen) -> None:
    """Another method replaces ``refined`` when the mean paired difference is below zero by
    more than twice its standard error (sample std with ddof=1, over sqrt(N)): at 2.6 SE it
    wins (2.6 SE is only 0.75 standard deviations, which a rule on the standard deviation
    would call noise), at 1.95 SE it does not."""
    held = _paired(t)
    assert np.sqrt(np.mean(held["park"].px ** 2)) < np.sqrt(np.mean(held["refined"].px ** 2))
    method, reason = choose(held, ["refined", "park"])
    assert method == chosen, reason
    if chosen == "park":
        assert "significantly below refined" in reason
    else:
        assert "within the noise" in reason and "under 2 standard errors" in reason


def test_lowest_score_wins_when_refined_is_no_candidate() -> None:
    held = _paired(-0.5)
    held["tsai"] = HeldOut(held["park"].px * 1.01, np.ones(N), np.ones(N))
    method, reason = choose(held, ["tsai", "park"])
    assert method == "park" and reason.startswith("lowest held-out corner RMS (px): park")


def _expected_sigma(solutions, samples, setup: str, s_r: float) -> tuple[float, float]:
    """The docstring's law, computed independently: s_t^2 = max(0, mean(|e|^2 - 2 s_r^2
    |l|^2)) / 3, ``l`` the board centre in the flange frame."""
    e2, l2 = [], []
    for (X, Y), s in zip(solutions, samples, strict=True):
        c = s.observations[0].object_points.mean(axis=0)
        G = s.base_T_ee
        if setup == "eye_in_hand":
            Yi = G @ X @ s.cam_T_board                       # board in the base, this sample
            p = Y[:3, :3] @ c + Y[:3, 3]                     # the solution's centre, base
            lever = np.linalg.inv(G) @ np.r_[p, 1.0]
        else:
            Yi = np.linalg.inv(G) @ X @ s.cam_T_board        # board on the flange
            lever = np.r_[Y[:3, :3] @ c + Y[:3, 3], 1.0]
        e = (Yi[:3, :3] @ c + Yi[:3, 3]) - (Y[:3, :3] @ c + Y[:3, 3])
        e2.append(e @ e)
        l2.append(lever[:3] @ lever[:3])
    e2, l2 = np.array(e2), np.array(l2)
    return (float(np.sqrt(max(0.0, np.mean(e2 - 2 * s_r ** 2 * l2)) / 3)),
            float(np.sqrt(np.mean(e2))))


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_held_out_sigma_subtracts_the_rotation_term_at_the_flange_lever_arm(setup) -> None:
    """With 0.05 deg of robot rotation noise the lever-arm term is a large part of the held-out
    scatter; the lever arm is the centre seen from the flange (base position minus the flange's
    position, in flange axes), not from the base origin."""
    P = make_problem(10, setup=setup, seed=611, noise_px=0.2, robot_noise_mm=0.3,
                     robot_noise_deg=0.05)
    # the solutions without each sample: the truth with its board off by a few mm / mrad
    rng = np.random.default_rng(5)
    sols = [(P.X, P.Y @ from_rotvec(rng.normal(scale=3e-4, size=3),
                                    rng.normal(scale=1.5e-4, size=3))) for _ in P.samples]
    s_r = np.radians(0.05)
    got = held_out_position_sigma(sols, P.samples, setup, s_r)
    want = _expected_sigma(sols, P.samples, setup, s_r)
    assert got[0] == pytest.approx(want[0], rel=1e-9)
    assert got[1] == pytest.approx(want[1], rel=1e-12)
    # the rotation term matters at this point: without it the sigma is clearly larger
    no_rot = held_out_position_sigma(sols, P.samples, setup, 0.0)[0]
    assert no_rot == pytest.approx(_expected_sigma(sols, P.samples, setup, 0.0)[0], rel=1e-9)
    assert want[0] < 0.97 * no_rot, (want[0], no_rot)
    if setup == "eye_in_hand":
        # the flange stands far from the base origin: a lever arm taken from the base origin
        # (the flange position dropped) would be clearly longer
        c = P.samples[0].observations[0].object_points.mean(axis=0)
        p = P.Y[:3, :3] @ c + P.Y[:3, 3]
        from_flange = np.mean([np.sum((p - s.base_T_ee[:3, 3]) ** 2) for s in P.samples])
        assert p @ p > 1.15 * from_flange, (p @ p, from_flange)


def test_pose_score_without_corners_is_the_rms_of_both_normalised_errors() -> None:
    """Without corners, each sample's held-out error is its board deviation in millimetres and
    in degrees, each divided by the median over the methods of its RMS, combined in quadrature;
    the score is the RMS of that over the samples."""
    from eye_in_hand.core.handeye.select import selection_scores

    rng = np.random.default_rng(8)
    held = {k: HeldOut(None, rng.uniform(0.2, 2.0, N) * s_mm, rng.uniform(0.01, 0.1, N) * s_dg)
            for k, s_mm, s_dg in (("a", 1.0, 1.0), ("b", 1.5, 0.7), ("c", 0.8, 2.0))}
    ref_mm = np.median([np.sqrt(np.mean(h.mm ** 2)) for h in held.values()])
    ref_deg = np.median([np.sqrt(np.mean(h.deg ** 2)) for h in held.values()])
    scores, criterion = selection_scores(held)
    assert "mm and deg" in criterion
    for k, h in held.items():
        want = np.sqrt(np.mean((h.mm / ref_mm) ** 2 + (h.deg / ref_deg) ** 2))
        assert scores[k] == pytest.approx(want, rel=1e-12), k


def test_held_out_board_errors_are_in_mm_and_degrees() -> None:
    """Exact board poses and a solution whose board is turned 0.01 rad about its own z axis
    (origin unmoved): every held-out sample is 0.573 degrees and 0 mm off."""
    from eye_in_hand.core.handeye.select import held_out_prediction

    P = make_problem(6, seed=612, noise_px=0.0)
    Y = P.Y @ from_rotvec([0.0, 0.0, 0.01])
    h = held_out_prediction([(P.X, Y)] * 6, P.samples, None, "eye_in_hand")
    np.testing.assert_allclose(h.deg, np.degrees(0.01), rtol=1e-6)
    np.testing.assert_allclose(h.mm, 0.0, atol=1e-9)
    assert h.px is None


def test_held_out_sigma_subtracts_the_measurement_variance_in_px_squared() -> None:
    """The centre's measurement variance ``v_i`` grows with the square of the corner noise:
    with ``s_0`` the sigma without it, ``s_0^2 - s^2`` at 2 px_sigma is 4 times that at
    px_sigma."""
    P = make_problem(8, seed=613, noise_px=0.3)
    rng = np.random.default_rng(6)
    sols = [(P.X, P.Y @ from_rotvec(rng.normal(scale=1e-3, size=3),
                                    rng.normal(scale=1e-3, size=3))) for _ in P.samples]
    s = [held_out_position_sigma(sols, P.samples, "eye_in_hand", 0.0, P.views, px)[0]
         for px in (0.0, 0.1, 0.2)]
    assert s[2] > 0
    assert (s[0] ** 2 - s[2] ** 2) == pytest.approx(4 * (s[0] ** 2 - s[1] ** 2), rel=1e-6)
