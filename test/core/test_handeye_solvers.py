"""Closed-form AX = XB solvers, validation and motion diagnostics."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.handeye import (
    CLOSED_FORM_METHODS,
    HandEyeSample,
    board_in_fixed_frame,
    calibrate_hand_eye,
    motion_diagnostics,
    solve_closed_form,
    validate_samples,
)
from eye_in_hand.core.transforms import from_rotvec, invert, transform_distance
from eye_in_hand.errors import HandEyeError


def _random_T(rng: np.random.Generator) -> np.ndarray:
    return from_rotvec(Rotation.random(random_state=int(rng.integers(1 << 30))).as_rotvec(),
                       rng.normal(scale=0.5, size=3))


def _exact_problem(setup: str, n: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    X, Y = _random_T(rng), _random_T(rng)
    bte = np.stack([_random_T(rng) for _ in range(n)])
    # cam_T_board = inv(X) inv(G) Y with G = base_T_ee (in hand) or its inverse (to hand).
    G = bte if setup == "eye_in_hand" else np.stack([invert(b) for b in bte])
    ctb = np.stack([invert(X) @ invert(g) @ Y for g in G])
    return X, Y, bte, ctb


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("method", list(CLOSED_FORM_METHODS))
def test_noise_free_recovers_x(setup: str, method: str) -> None:
    X, _, bte, ctb = _exact_problem(setup, seed=hash((setup, method)) % 1000)
    Xh = solve_closed_form(method, bte, ctb, setup)
    assert np.max(np.abs(Xh - X)) < 1e-8
    Xc = solve_closed_form(method, bte, ctb, setup, pairs="consecutive")
    assert np.max(np.abs(Xc - X)) < 1e-8


def test_eye_in_hand_meaning_of_x() -> None:
    """X is ee_T_cam: a camera pose is base_T_ee @ X, and the board is fixed in base."""
    X, Y, bte, ctb = _exact_problem("eye_in_hand", seed=3)
    Xh = solve_closed_form("park", bte, ctb, "eye_in_hand")
    for b, c in zip(bte, ctb, strict=True):
        np.testing.assert_allclose(b @ Xh @ c, Y, atol=1e-9)  # base_T_board for every sample
    np.testing.assert_allclose(board_in_fixed_frame(Xh, bte, ctb, "eye_in_hand"),
                               np.repeat(Y[None], len(bte), axis=0), atol=1e-9)


def test_eye_to_hand_meaning_of_x() -> None:
    """X is base_T_cam: the board on the flange is ee_T_board = inv(base_T_ee) X cam_T_board."""
    X, Y, bte, ctb = _exact_problem("eye_to_hand", seed=4)
    Xh = solve_closed_form("tsai", bte, ctb, "eye_to_hand")
    for b, c in zip(bte, ctb, strict=True):
        np.testing.assert_allclose(invert(b) @ Xh @ c, Y, atol=1e-9)


def test_large_rotations_near_180_degrees() -> None:
    """Quaternion sign handling: motions near 180 deg must not break any method."""
    rng = np.random.default_rng(7)
    X, Y = _random_T(rng), _random_T(rng)
    bte = [np.eye(4)]
    for axis in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]):
        a = np.asarray(axis, float) / np.linalg.norm(axis)
        bte.append(from_rotvec(a * np.radians(179.0), rng.normal(scale=0.3, size=3)))
    bte = np.stack(bte)
    ctb = np.stack([invert(X) @ invert(b) @ Y for b in bte])
    for method in CLOSED_FORM_METHODS:
        assert np.max(np.abs(solve_closed_form(method, bte, ctb) - X)) < 1e-8, method


def test_moveit_real_data_matches_published_reference(data_dir) -> None:
    """Every closed form within 2 mm and 0.35 deg of MoveIt Calibration's reference."""
    pairs = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    bte = np.array([p[0] for p in pairs], dtype=float)
    ctb = np.array([p[1] for p in pairs], dtype=float)
    ref = np.eye(4)
    # Eigen eulerAngles(0, 1, 2): R = Rx(a) Ry(b) Rz(c), i.e. intrinsic XYZ.
    ref[:3, :3] = Rotation.from_euler("XYZ", [0.230, -2.540, 1.950]).as_matrix()
    ref[:3, 3] = [0.659, -0.249, 0.830]
    for method in CLOSED_FORM_METHODS:
        X = solve_closed_form(method, bte, ctb, "eye_to_hand")  # base_T_cam
        dt, dr = transform_distance(ref, X)
        assert dt < 0.002, (method, dt)
        assert np.degrees(dr) < 0.35, (method, np.degrees(dr))
    # Reading the pairs as eye-in-hand gives nonsense: the direction matters.
    Xw = solve_closed_form("park", bte, ctb, "eye_in_hand")
    assert transform_distance(ref, Xw)[0] > 0.1


def test_moveit_pipeline_no_rejections_and_refined_close(data_dir) -> None:
    pairs = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    samples = [HandEyeSample(f"p{i}", np.array(a), np.array(b)) for i, (a, b) in enumerate(pairs)]
    res = calibrate_hand_eye(samples[:25], "eye_to_hand", leave_one_out=False)
    assert res.selected == "refined" and res.refinement is not None
    assert res.refinement.space == "pose"
    closed = res.methods["park"].X
    dt, dr = transform_distance(closed, res.X)
    assert dt < 0.003 and np.degrees(dr) < 0.2
    assert res.covariance is not None and res.covariance.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(res.covariance) > 0)


def test_too_few_samples_is_an_error() -> None:
    _, _, bte, ctb = _exact_problem("eye_in_hand", n=2)
    with pytest.raises(HandEyeError, match="at least 3"):
        motion_diagnostics(bte, "eye_in_hand")
    samples = [HandEyeSample(str(i), b, c) for i, (b, c) in enumerate(zip(bte, ctb, strict=True))]
    with pytest.raises(HandEyeError, match="at least 3"):
        calibrate_hand_eye(samples)


def test_parallel_axes_is_an_error_that_says_what_to_add() -> None:
    rng = np.random.default_rng(1)
    X, Y = _random_T(rng), _random_T(rng)
    bte = np.stack([from_rotvec([0, 0, a], rng.normal(size=3)) for a in (0.0, 0.4, 0.9, -0.5)])
    ctb = np.stack([invert(X) @ invert(b) @ Y for b in bte])
    with pytest.raises(HandEyeError, match="same axis.*add samples that rotate"):
        motion_diagnostics(bte, "eye_in_hand")
    samples = [HandEyeSample(str(i), b, c) for i, (b, c) in enumerate(zip(bte, ctb, strict=True))]
    with pytest.raises(HandEyeError, match="same axis"):
        calibrate_hand_eye(samples)


def test_pure_translation_is_an_error() -> None:
    bte = np.stack([from_rotvec([0.3, 0.1, 0.0], [0.1 * i, 0.05 * i, 0.0]) for i in range(5)])
    with pytest.raises(HandEyeError, match="barely rotates"):
        motion_diagnostics(bte, "eye_in_hand")


def test_weak_axis_spread_is_a_warning() -> None:
    rng = np.random.default_rng(2)
    # Rotations about z, each tilted by 1.1 deg about a varying horizontal axis.
    eps = 0.02
    bte = np.stack([from_rotvec([0, 0, 0.35 * (k + 1)], rng.normal(size=3))
                    @ from_rotvec([eps * np.sin(k), eps * np.cos(k), 0]) for k in range(6)])
    d = motion_diagnostics(bte, "eye_in_hand")
    assert 1.0 < d.axis_spread_deg < 15.0
    assert any("axis spread" in w for w in d.warnings)
    _, _, good, _ = _exact_problem("eye_in_hand", n=10, seed=5)
    d2 = motion_diagnostics(good, "eye_in_hand")
    assert d2.warnings == () and d2.axis_spread_deg > 45 and d2.n_samples == 10
    assert d2.rotation_condition < 10 and d2.translation_condition < 10


def test_bad_poses_are_errors_naming_the_sample() -> None:
    _, _, bte, ctb = _exact_problem("eye_in_hand", n=5)
    nan = bte.copy()
    nan[2, 0, 3] = np.nan
    samples = [HandEyeSample(f"img{i}", b, c)
               for i, (b, c) in enumerate(zip(nan, ctb, strict=True))]
    with pytest.raises(HandEyeError, match=r"sample 'img2'.*base_T_ee.*NaN"):
        calibrate_hand_eye(samples)
    skew = ctb.copy()
    skew[3, :3, :3] *= 1.01
    samples = [HandEyeSample(f"img{i}", b, c)
               for i, (b, c) in enumerate(zip(bte, skew, strict=True))]
    with pytest.raises(HandEyeError, match=r"sample 'img3'.*cam_T_board.*not orthonormal"):
        calibrate_hand_eye(samples)


def test_duplicates_are_dropped_with_a_warning() -> None:
    _, _, bte, ctb = _exact_problem("eye_in_hand", n=5)
    samples = [HandEyeSample(f"s{i}", b, c) for i, (b, c) in enumerate(zip(bte, ctb, strict=True))]
    samples.append(HandEyeSample("again", bte[1], ctb[1]))
    kept, warnings = validate_samples(samples)
    assert [s.name for s in kept] == ["s0", "s1", "s2", "s3", "s4"]
    assert any("'again'" in w and "duplicates sample 's1'" in w for w in warnings)
    with pytest.raises(HandEyeError, match="duplicate sample name"):
        validate_samples(samples + [HandEyeSample("s0", bte[0], ctb[0])])


def test_unknown_method_and_setup() -> None:
    _, _, bte, ctb = _exact_problem("eye_in_hand", n=4)
    with pytest.raises(HandEyeError, match="method"):
        solve_closed_form("magic", bte, ctb)
    with pytest.raises(HandEyeError, match="setup"):
        solve_closed_form("tsai", bte, ctb, "eye_on_head")
    with pytest.raises(HandEyeError, match="equal shape"):
        solve_closed_form("tsai", bte, ctb[:3])


def test_wrong_setup_or_pose_direction_is_an_error(data_dir) -> None:
    pairs = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    samples = [HandEyeSample(f"p{i}", np.array(a), np.array(b))
               for i, (a, b) in enumerate(pairs[:20])]
    with pytest.raises(HandEyeError, match="fit with --setup eye_to_hand"):
        calibrate_hand_eye(samples, "eye_in_hand", leave_one_out=False)
    inverted = [HandEyeSample(s.name, s.base_T_ee, invert(s.cam_T_board)) for s in samples]
    with pytest.raises(HandEyeError, match="cam_T_board inverted"):
        calibrate_hand_eye(inverted, "eye_to_hand", leave_one_out=False)
    res = calibrate_hand_eye(samples, "eye_in_hand", leave_one_out=False,
                             check_conventions=False, refine=False)
    assert res.methods["park"].axxb_rot_deg.mean() > 10
