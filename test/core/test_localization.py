"""core.localization: composition, stamp handling, and covariance against Monte Carlo."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core.localization import Localizer, LocalizerConfig, target_in_base
from eye_in_hand.core.transforms import apply, compose, from_rotvec
from eye_in_hand.errors import InputError, LocalizationError


def _random_pose(rng, scale=0.5):
    return from_rotvec(rng.normal(size=3), rng.normal(scale=scale, size=3))


def test_composition_matches_chain():
    rng = np.random.default_rng(0)
    b_T_e, e_T_c = _random_pose(rng), _random_pose(rng, 0.1)
    p_c = np.array([0.05, -0.02, 0.45])
    p, cov = target_in_base(b_T_e, e_T_c, p_c)
    assert np.allclose(p, apply(compose(b_T_e, e_T_c), p_c), atol=1e-12)
    assert np.allclose(cov, 0.0)


def test_covariance_matches_monte_carlo():
    rng = np.random.default_rng(1)
    b_T_e, e_T_c = _random_pose(rng), _random_pose(rng, 0.1)
    p_c = np.array([0.03, 0.01, 0.5])
    A = rng.normal(size=(3, 3)) * 1e-3
    cov_cam = A @ A.T
    B = rng.normal(size=(6, 6)) * np.r_[[1e-3] * 3, [2e-3] * 3][:, None]
    cov_x = B @ B.T
    s_pos, s_rot = 2e-4, 5e-4
    p0, cov = target_in_base(b_T_e, e_T_c, p_c, cov_cam=cov_cam, cov_hand_eye=cov_x,
                             robot_sigma_pos_m=s_pos, robot_sigma_rot_rad=s_rot)
    n = 20000
    dc = rng.multivariate_normal(np.zeros(3), cov_cam, n)
    dx = rng.multivariate_normal(np.zeros(6), cov_x, n)
    dtb = rng.normal(scale=s_pos, size=(n, 3))
    drb = rng.normal(scale=s_rot, size=(n, 3))
    Rx = Rotation.from_rotvec(dx[:, 3:]).as_matrix() @ e_T_c[:3, :3]      # left, ee frame
    Rb = b_T_e[:3, :3] @ Rotation.from_rotvec(drb).as_matrix()            # flange frame
    p_ee = np.einsum("nij,nj->ni", Rx, p_c + dc) + e_T_c[:3, 3] + dx[:, :3]
    samples = np.einsum("nij,nj->ni", Rb, p_ee) + b_T_e[:3, 3] + dtb
    emp = np.cov(samples.T)
    assert np.allclose(samples.mean(0), p0, atol=3e-4)
    # First-order propagation vs sampling: within 5 % in every direction that matters.
    w = np.linalg.eigvalsh(np.linalg.solve(np.linalg.cholesky(cov), np.linalg.solve(
        np.linalg.cholesky(cov), emp).T))
    assert np.all(np.abs(w - 1.0) < 0.05), w


def test_localizer_interpolates_and_refuses_stale_stamps():
    rng = np.random.default_rng(2)
    e_T_c = _random_pose(rng, 0.1)
    loc = Localizer(e_T_c, config=LocalizerConfig(max_gap_ns=20_000_000))
    T0 = from_rotvec([0, 0, 0.0], [0.4, 0.0, 0.3])
    T1 = from_rotvec([0, 0, 0.1], [0.5, 0.0, 0.3])
    loc.add_robot_pose(1_000_000_000, T0)
    loc.add_robot_pose(1_010_000_000, T1)
    res = loc.locate(1_005_000_000, [0.0, 0.0, 0.5])
    mid = from_rotvec([0, 0, 0.05], [0.45, 0.0, 0.3])
    assert np.allclose(res.point_base, apply(compose(mid, e_T_c), [0.0, 0.0, 0.5]), atol=1e-12)
    with pytest.raises(LocalizationError, match="newer than the newest"):
        loc.locate(1_020_000_000, [0.0, 0.0, 0.5])
    loc.add_robot_pose(1_100_000_000, T1)  # 90 ms gap
    with pytest.raises(LocalizationError, match="over the limit"):
        loc.locate(1_050_000_000, [0.0, 0.0, 0.5])


def test_bad_inputs_are_named():
    with pytest.raises(InputError, match="point_cam"):
        target_in_base(np.eye(4), np.eye(4), [np.nan, 0, 1])
    with pytest.raises(InputError, match="cov_hand_eye"):
        target_in_base(np.eye(4), np.eye(4), [0, 0, 1], cov_hand_eye=np.eye(3))
    with pytest.raises(InputError, match="ee_T_cam"):
        Localizer(np.zeros((4, 4)))
    with pytest.raises(InputError, match="max_gap_ns"):
        LocalizerConfig(max_gap_ns=0)


def test_point_covariance_check_refuses_what_is_not_a_covariance():
    """The localizer's per-point check (Sylvester's criterion first, the eigenvalues when it
    cannot decide): positive definite and semi-definite covariances pass; an indefinite one,
    also one whose leading 2x2 block is positive definite, is refused, as is an asymmetric one;
    the values used are the ones given."""
    from eye_in_hand.core.localization import Localizer, LocalizerConfig

    loc = Localizer(np.eye(4), None, LocalizerConfig(max_gap_ns=10**9))
    loc.add_robot_pose(0, np.eye(4))
    loc.add_robot_pose(10**8, np.eye(4))
    p = np.array([0.1, 0.0, 0.5])
    pd = np.array([[4e-6, 1e-6, 0.5e-6], [1e-6, 3e-6, -0.2e-6], [0.5e-6, -0.2e-6, 9e-6]])
    psd = np.diag([1e-6, 1e-6, 0.0])                       # singular: Sylvester cannot tell
    for cov in (pd, psd):
        res = loc.locate(5 * 10**7, p, cov)
        np.testing.assert_allclose(res.covariance, cov, rtol=0, atol=1e-21)
    indefinite_3 = np.array([[2e-6, 0.0, 1.9e-6], [0.0, 1e-6, 0.0], [1.9e-6, 0.0, 1e-6]])
    assert np.linalg.det(indefinite_3[:2, :2]) > 0 and np.linalg.eigvalsh(indefinite_3)[0] < 0
    for cov in (np.diag([1e-6, -1e-6, 1e-6]), indefinite_3, -pd):
        with pytest.raises(InputError, match="not positive semi-definite"):
            loc.locate(5 * 10**7, p, cov)
    asym = pd.copy()
    asym[0, 2] += 1e-3
    with pytest.raises(InputError, match="not symmetric"):
        loc.locate(5 * 10**7, p, asym)


def test_the_point_located_again_is_not_located_twice_and_keeps_the_rules():
    """The same point and covariance (by value) at the same stamp from the same robot pose
    give the last call's result object, read-only (hand_eye's first target, located for
    target/pose and again in its frame); the pose lookup and its age rule run at every call,
    and a new pose, point, covariance or stamp is located afresh, to the same bits as a
    localizer that never saw the call before."""
    rng = np.random.default_rng(3)
    e_T_c = _random_pose(rng, 0.1)
    cfg = LocalizerConfig(max_gap_ns=20_000_000, max_age_ns=100_000_000,
                          robot_sigma_pos_m=1e-4, robot_sigma_rot_rad=2e-4)
    T0 = from_rotvec([0, 0, 0.0], [0.4, 0.0, 0.3])
    T1 = from_rotvec([0, 0, 0.1], [0.5, 0.0, 0.3])
    T2 = from_rotvec([0, 0.1, 0.1], [0.5, 0.1, 0.3])
    cov = np.diag([1e-6, 2e-6, 4e-6])

    def fresh(poses):
        other = Localizer(e_T_c, np.eye(6) * 1e-8, cfg)
        for stamp, T in poses:
            other.add_robot_pose(stamp, T, received_ns=0)
        return other

    poses = [(1_000_000_000, T0), (1_010_000_000, T1)]
    loc = fresh(poses)
    first = loc.locate(1_005_000_000, np.array([0.01, 0.02, 0.5]), cov, now_ns=1)
    again = loc.locate(1_005_000_000, [0.01, 0.02, 0.5], cov.tolist(), now_ns=2)
    assert again is first
    for arr in (first.point_base, first.covariance, first.base_T_ee):
        assert not arr.flags.writeable
    # the age rule at this call's clock, memo or not
    with pytest.raises(LocalizationError, match="received"):
        loc.locate(1_005_000_000, [0.01, 0.02, 0.5], cov, now_ns=200_000_000)

    def same_bits(res, ref):
        assert res.point_base.tobytes() == ref.point_base.tobytes()
        assert res.covariance.tobytes() == ref.covariance.tobytes()
        assert res.base_T_ee.tobytes() == ref.base_T_ee.tobytes()

    for stamp, p, c in ((1_005_000_000, [0.01, 0.02, 0.51], cov),      # another point
                        (1_005_000_000, [0.01, 0.02, 0.5], cov * 2),   # another covariance
                        (1_005_000_000, [0.01, 0.02, 0.5], None),      # none
                        (1_006_000_000, [0.01, 0.02, 0.5], cov)):      # another stamp
        res = loc.locate(stamp, p, c, now_ns=3)
        assert res is not first
        same_bits(res, fresh(poses).locate(stamp, p, c, now_ns=3))
    loc.locate(1_005_000_000, [0.01, 0.02, 0.5], cov, now_ns=3)
    # a pose that brackets the stamp more closely: another robot pose, located afresh
    loc.add_robot_pose(1_007_000_000, T2, received_ns=0)
    res = loc.locate(1_005_000_000, [0.01, 0.02, 0.5], cov, now_ns=4)
    assert res is not first
    assert not np.array_equal(res.base_T_ee, first.base_T_ee)
    same_bits(res, fresh(poses + [(1_007_000_000, T2)]).locate(
        1_005_000_000, [0.01, 0.02, 0.5], cov, now_ns=4))
    # a bad point or covariance is still named when it follows a good one
    with pytest.raises(InputError, match="cov_cam"):
        loc.locate(1_005_000_000, [0.01, 0.02, 0.5], np.eye(2), now_ns=4)
    with pytest.raises(InputError, match="point_cam"):
        loc.locate(1_005_000_000, ["a", 0.02, 0.5], cov, now_ns=4)
