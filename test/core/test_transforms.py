"""Property tests of eye_in_hand.core.transforms (seeded, deterministic)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eye_in_hand.core import transforms as tf
from eye_in_hand.errors import InputError

N = 50


def random_rotvecs(rng: np.random.Generator, n: int, max_angle: float = np.pi) -> np.ndarray:
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * rng.uniform(0.0, max_angle, size=(n, 1))


def random_transforms(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return [tf.from_rotvec(rv, rng.uniform(-3, 3, 3)) for rv in random_rotvecs(rng, n)]


def assert_rigid(T: np.ndarray, atol: float = 1e-12) -> None:
    assert T.shape == (4, 4) and T.dtype == np.float64
    np.testing.assert_allclose(T[3], [0, 0, 0, 1], atol=0)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=atol)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0, abs=atol)


# -- validation -------------------------------------------------------------------------------
def test_as_rotation_accepts_rotations_and_rejects_others():
    rng = np.random.default_rng(0)
    for rv in random_rotvecs(rng, N):
        R = Rotation.from_rotvec(rv).as_matrix()
        np.testing.assert_array_equal(tf.as_rotation(R), R)
    R = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()
    with pytest.raises(InputError, match=r"^R: expected shape \(3, 3\), got \(3, 4\)"):
        tf.as_rotation(np.hstack([R, np.zeros((3, 1))]))
    with pytest.raises(InputError, match="^Rc: contains NaN"):
        tf.as_rotation(np.where(np.eye(3) > 0, np.nan, R), "Rc")
    with pytest.raises(InputError, match="not orthonormal"):
        tf.as_rotation(R * 1.001)
    with pytest.raises(InputError, match="not orthonormal"):
        tf.as_rotation(R @ np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(InputError, match="numeric"):
        tf.as_rotation([["a", "b", "c"]] * 3)
    # Within the tolerance passes, just outside fails.
    assert tf.as_rotation(R + 1e-8) is not None
    with pytest.raises(InputError):
        tf.as_rotation(R + 1e-5)


def test_as_transform_and_as_points():
    T = tf.from_rotvec([0.1, 0.2, 0.3], [1, 2, 3])
    np.testing.assert_array_equal(tf.as_transform(T), T)
    bad = T.copy()
    bad[3, 0] = 0.5
    with pytest.raises(InputError, match=r"^T: last row must be \[0, 0, 0, 1\]"):
        tf.as_transform(bad)
    bad = T.copy()
    bad[0, 3] = np.inf
    with pytest.raises(InputError, match="^base_T_ee: contains NaN or infinite"):
        tf.as_transform(bad, "base_T_ee")
    bad = T.copy()
    bad[:3, :3] *= 2.0
    with pytest.raises(InputError, match="^T rotation block: rotation is not orthonormal"):
        tf.as_transform(bad)
    with pytest.raises(InputError, match=r"expected shape \(4, 4\), got \(3, 3\)"):
        tf.as_transform(np.eye(3))
    assert tf.as_points([1, 2, 3]).shape == (1, 3)
    assert tf.as_points(np.zeros((5, 3))).shape == (5, 3)
    with pytest.raises(InputError, match=r"expected shape \(3,\) or \(N, 3\), got \(4, 2\)"):
        tf.as_points(np.zeros((4, 2)))
    with pytest.raises(InputError, match="NaN"):
        tf.as_points([[0.0, np.nan, 1.0]])


# -- composition and inversion ----------------------------------------------------------------
def test_compose_invert_identities():
    rng = np.random.default_rng(1)
    Ts = random_transforms(rng, N + 2)
    for A, B, C in zip(Ts, Ts[1:], Ts[2:], strict=False):
        inv = tf.invert(A)
        assert_rigid(inv)
        np.testing.assert_allclose(tf.compose(A, inv), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(tf.compose(inv, A), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(tf.invert(inv), A, atol=1e-12)
        np.testing.assert_allclose(tf.invert(A), np.linalg.inv(A), atol=1e-12)
        # associativity and (AB)^-1 = B^-1 A^-1
        np.testing.assert_allclose(tf.compose(tf.compose(A, B), C),
                                   tf.compose(A, tf.compose(B, C)), atol=1e-12)
        np.testing.assert_allclose(tf.compose(A, B, C), A @ B @ C, atol=1e-12)
        np.testing.assert_allclose(tf.invert(tf.compose(A, B)),
                                   tf.compose(tf.invert(B), tf.invert(A)), atol=1e-12)
    np.testing.assert_array_equal(tf.compose(), np.eye(4))
    np.testing.assert_array_equal(tf.compose(Ts[0]), Ts[0])
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match=r"^transforms\[1\]: contains NaN"):
        tf.compose(Ts[0], bad)
    with pytest.raises(InputError, match="^T: "):
        tf.invert(bad)


def test_invert_many_of_stacks_and_single_transforms():
    rng = np.random.default_rng(2)
    Ts = np.stack(random_transforms(rng, 6))
    for stack in (Ts, Ts.reshape(2, 3, 4, 4), Ts[0]):
        inv = tf.invert_many(stack)
        assert inv.shape == stack.shape
        np.testing.assert_allclose(inv, np.linalg.inv(stack), atol=1e-12)
        np.testing.assert_allclose(stack @ inv, np.broadcast_to(np.eye(4), stack.shape),
                                   atol=1e-12)
    np.testing.assert_allclose(tf.invert_many(Ts[0]), tf.invert(Ts[0]), atol=1e-15)


def test_make_transform_and_apply():
    rng = np.random.default_rng(2)
    for rv in random_rotvecs(rng, N):
        R = Rotation.from_rotvec(rv).as_matrix()
        t = rng.normal(size=3)
        T = tf.make_transform(R, t)
        np.testing.assert_array_equal(T[:3, :3], R)
        np.testing.assert_array_equal(T[:3, 3], t)
        assert_rigid(T)
        pts = rng.normal(size=(7, 3))
        out = tf.apply(T, pts)
        np.testing.assert_allclose(out, (R @ pts.T).T + t, atol=1e-12)
        single = tf.apply(T, pts[0])
        assert single.shape == (3,)
        np.testing.assert_allclose(single, out[0], atol=1e-15)
        np.testing.assert_allclose(tf.apply(tf.invert(T), out), pts, atol=1e-12)
        # a_T_b then b_T_c maps like the composition
        T2 = random_transforms(rng, 1)[0]
        np.testing.assert_allclose(tf.apply(T, tf.apply(T2, pts)),
                                   tf.apply(tf.compose(T, T2), pts), atol=1e-12)
    with pytest.raises(InputError, match=r"^t: expected shape \(3,\)"):
        tf.make_transform(np.eye(3), [1.0, 2.0])
    with pytest.raises(InputError, match="^R: rotation is not orthonormal"):
        tf.make_transform(np.ones((3, 3)), [0, 0, 0])
    with pytest.raises(InputError, match="^points"):
        tf.apply(np.eye(4), np.zeros((3, 4)))


# -- quaternions and rotation vectors ---------------------------------------------------------
def test_quaternion_round_trips_and_xyzw_order():
    rng = np.random.default_rng(3)
    for rv in random_rotvecs(rng, N):
        T = tf.from_rotvec(rv, rng.normal(size=3))
        xyz, q = tf.to_xyz_quat(T)
        assert q.shape == (4,) and q[3] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(tf.from_xyz_quat(xyz, q), T, atol=1e-12)
        np.testing.assert_allclose(tf.from_xyz_quat(xyz, -q), T, atol=1e-12)  # double cover
        np.testing.assert_allclose(tf.quat_xyzw_to_matrix(q), T[:3, :3], atol=1e-12)
        np.testing.assert_allclose(tf.matrix_to_quat_xyzw(T[:3, :3]), q, atol=1e-12)
    # ROS order: 90 degrees about z is (0, 0, sin 45, cos 45).
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(tf.matrix_to_quat_xyzw(Rz), [0, 0, np.sqrt(0.5), np.sqrt(0.5)],
                               atol=1e-15)
    np.testing.assert_allclose(tf.quat_xyzw_to_matrix([0, 0, np.sqrt(0.5), np.sqrt(0.5)]), Rz,
                               atol=1e-15)
    # A nearly unit quaternion (float32 source) is normalised; a wrong one is refused.
    q32 = np.array([0, 0, np.sqrt(0.5), np.sqrt(0.5)], dtype=np.float32).astype(np.float64)
    np.testing.assert_allclose(tf.quat_xyzw_to_matrix(q32), Rz, atol=1e-7)
    with pytest.raises(InputError, match="^quat_xyzw: quaternion has zero norm"):
        tf.quat_xyzw_to_matrix([0, 0, 0, 0])
    with pytest.raises(InputError, match="^quat_xyzw: quaternion norm is 2.000000"):
        tf.quat_xyzw_to_matrix([0, 0, 0, 2])
    with pytest.raises(InputError, match=r"^quat_xyzw: expected shape \(4,\)"):
        tf.quat_xyzw_to_matrix([0, 0, 1])
    with pytest.raises(InputError, match="^quat_xyzw: contains NaN"):
        tf.from_xyz_quat([0, 0, 0], [0, 0, np.nan, 1])
    with pytest.raises(InputError, match="^xyz: contains NaN"):
        tf.from_xyz_quat([0, np.nan, 0], [0, 0, 0, 1])


def test_rotvec_round_trips():
    rng = np.random.default_rng(4)
    for rv in random_rotvecs(rng, N, max_angle=np.pi - 1e-6):
        t = rng.normal(size=3)
        T = tf.from_rotvec(rv, t)
        assert_rigid(T)
        np.testing.assert_array_equal(T[:3, 3], t)
        np.testing.assert_allclose(tf.to_rotvec(T), rv, atol=1e-9)
        np.testing.assert_allclose(tf.to_rotvec(T[:3, :3]), rv, atol=1e-9)
        assert tf.rotation_angle(T) == pytest.approx(np.linalg.norm(rv), abs=1e-9)
    np.testing.assert_array_equal(tf.from_rotvec([0, 0, 0]), np.eye(4))
    with pytest.raises(InputError, match="^rotvec: contains NaN"):
        tf.from_rotvec([np.nan, 0, 0])
    with pytest.raises(InputError):
        tf.to_rotvec(np.ones((3, 3)))
    with pytest.raises(InputError):
        tf.to_rotvec(np.ones((2, 2)))


def test_rotation_angle_accuracy_and_validation():
    for angle in (0.0, 1e-9, 1e-4, 0.1, 1.0, 2.0, 3.0, np.pi - 1e-4, np.pi):
        R = Rotation.from_rotvec([0.0, angle, 0.0]).as_matrix()
        assert tf.rotation_angle(R) == pytest.approx(angle, abs=1e-7 if angle > 3 else 1e-12)
    with pytest.raises(InputError, match="NaN"):
        tf.rotation_angle(np.full((3, 3), np.nan))
    with pytest.raises(InputError):
        tf.rotation_angle(np.eye(3) * 2.0)
    with pytest.raises(InputError):
        tf.rotation_angle(np.eye(2))


def test_project_to_so3():
    rng = np.random.default_rng(5)
    for rv in random_rotvecs(rng, N):
        R = Rotation.from_rotvec(rv).as_matrix()
        np.testing.assert_allclose(tf.project_to_so3(R), R, atol=1e-12)
        noisy = R + rng.normal(scale=1e-3, size=(3, 3))
        P = tf.project_to_so3(noisy)
        tf.as_rotation(P, atol=1e-12)
        assert np.linalg.norm(P - R) < 5e-3
        # The projection is the closest rotation: any other nearby rotation is farther.
        other = Rotation.from_rotvec(rng.normal(scale=1e-3, size=3)).as_matrix() @ P
        assert np.linalg.norm(noisy - P) <= np.linalg.norm(noisy - other) + 1e-15
    reflection = np.diag([1.0, 1.0, -1.0])
    P = tf.project_to_so3(reflection)
    assert np.linalg.det(P) == pytest.approx(1.0)
    with pytest.raises(InputError, match="^M: contains NaN"):
        tf.project_to_so3(np.full((3, 3), np.nan))


def test_transform_distance():
    rng = np.random.default_rng(6)
    for T in random_transforms(rng, N):
        dt, dr = tf.transform_distance(T, T)
        assert dt == 0.0 and dr == pytest.approx(0.0, abs=1e-7)
        delta = tf.from_rotvec([0.0, 0.0, 0.25], [0.3, 0.4, 0.0])
        dt, dr = tf.transform_distance(T, tf.compose(T, delta))
        assert dt == pytest.approx(0.5, abs=1e-12) and dr == pytest.approx(0.25, abs=1e-12)
    with pytest.raises(InputError, match="^a_T_c"):
        tf.transform_distance(np.eye(4), np.zeros((4, 4)))


# -- interpolation ----------------------------------------------------------------------------
def test_interpolate_end_points_midpoint_and_constant_velocity():
    rng = np.random.default_rng(7)
    s0 = 1_700_000_000_000_000_000  # realistic ns stamps: integer arithmetic matters
    s1 = s0 + 40_000_000
    for rv in random_rotvecs(rng, N, max_angle=np.pi - 1e-3):
        A = random_transforms(rng, 1)[0]
        delta = tf.from_rotvec(rv, rng.normal(size=3))
        B = tf.compose(A, delta)
        np.testing.assert_allclose(tf.interpolate(s0, s0, A, s1, B), A, atol=1e-12)
        np.testing.assert_allclose(tf.interpolate(s1, s0, A, s1, B), B, atol=1e-12)
        mid = tf.interpolate(s0 + 20_000_000, s0, A, s1, B)
        assert_rigid(mid)
        half = tf.from_rotvec(rv / 2.0)
        np.testing.assert_allclose(mid[:3, :3], A[:3, :3] @ half[:3, :3], atol=1e-9)
        np.testing.assert_allclose(mid[:3, 3], (A[:3, 3] + B[:3, 3]) / 2, atol=1e-12)
        quarter = tf.interpolate(s0 + 10_000_000, s0, A, s1, B)
        _, ang = tf.transform_distance(A, quarter)
        assert ang == pytest.approx(np.linalg.norm(rv) / 4, abs=1e-9)
    # 1 ns resolution at 1.7e18 ns is preserved
    A, B = np.eye(4), tf.from_rotvec([0, 0, 0], [1.0, 0.0, 0.0])
    out = tf.interpolate(s0 + 1, s0, A, s0 + 2, B)
    assert out[0, 3] == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_array_equal(tf.interpolate(s0, s0, A, s0, B), A)


def test_interpolate_validation():
    A = np.eye(4)
    with pytest.raises(InputError, match="outside"):
        tf.interpolate(5, 10, A, 20, A)
    with pytest.raises(InputError, match="outside"):
        tf.interpolate(21, 10, A, 20, A)
    with pytest.raises(InputError, match="out of order"):
        tf.interpolate(15, 20, A, 10, A)
    with pytest.raises(InputError, match="^T1: contains NaN"):
        tf.interpolate(15, 10, A, 20, np.full((4, 4), np.nan))


# -- averaging --------------------------------------------------------------------------------
def test_average_rotations_of_noisy_samples():
    rng = np.random.default_rng(8)
    for rv in random_rotvecs(rng, 10):
        R = Rotation.from_rotvec(rv).as_matrix()
        noise = Rotation.from_rotvec(rng.normal(scale=0.01, size=(400, 3))).as_matrix()
        samples = R @ noise
        mean = tf.average_rotations(samples)
        tf.as_rotation(mean, atol=1e-12)
        # noise 0.01 rad per axis, 400 samples: error of the mean ~ 0.01 * sqrt(3) / 20;
        # measured max 2.1e-3 rad over seeds 0-39 x 10 rotations (this seed 1.1e-3); 1.4x margin
        assert tf.rotation_angle(R.T @ mean) < 3e-3
        # Better than a single sample on average
        single = np.mean([tf.rotation_angle(R.T @ S) for S in samples])
        assert tf.rotation_angle(R.T @ mean) < single / 5
    R = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    np.testing.assert_allclose(tf.average_rotations([R]), R, atol=1e-12)
    # Weights: an outlier with zero weight does not move the mean.
    outlier = Rotation.from_rotvec([1.0, 0.0, 0.0]).as_matrix()
    np.testing.assert_allclose(tf.average_rotations([R, R, outlier], weights=[1, 1, 0]), R,
                               atol=1e-12)
    # Symmetric pair about R averages to R.
    d = Rotation.from_rotvec([0.0, 0.0, 0.2]).as_matrix()
    np.testing.assert_allclose(tf.average_rotations([R @ d, R @ d.T]), R, atol=1e-12)


def test_average_rotations_validation():
    R = np.eye(3)
    with pytest.raises(InputError, match=r"expected shape \(N, 3, 3\) with N >= 1, got \(0,\)"):
        tf.average_rotations([])
    with pytest.raises(InputError, match=r"^rotations\[1\]: rotation is not orthonormal"):
        tf.average_rotations([R, 2 * R])
    for w in ([1.0], [1.0, -1.0], [0.0, 0.0], [np.nan, 1.0]):
        with pytest.raises(InputError, match="^weights"):
            tf.average_rotations([R, R], weights=w)


def test_average_transforms_of_noisy_samples():
    rng = np.random.default_rng(9)
    for T in random_transforms(rng, 10):
        samples = [tf.compose(T, tf.from_rotvec(rng.normal(scale=0.01, size=3),
                                                rng.normal(scale=0.002, size=3)))
                   for _ in range(400)]
        mean = tf.average_transforms(samples)
        assert_rigid(mean)
        dt, dr = tf.transform_distance(T, mean)
        # measured over seeds 0-39 x 10 transforms: dt max 0.40 mm, dr max 2.0e-3 rad (this
        # seed 0.27 mm, 1.3e-3 rad); 1.5x margin
        assert dt < 0.6e-3 and dr < 3e-3
    A = tf.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    B = tf.from_rotvec([0.0, 0.0, 0.0], [3.0, 0.0, 0.0])
    np.testing.assert_allclose(tf.average_transforms([A, B], weights=[2.0, 1.0])[:3, 3],
                               [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(tf.average_transforms(iter([A, B]) and [A, B],
                                                     weights=iter([1.0, 1.0]))[:3, 3],
                               [1.5, 0.0, 0.0], atol=1e-12)
    with pytest.raises(InputError, match=r"expected shape \(N, 4, 4\)"):
        tf.average_transforms(np.zeros((2, 3, 3)))
    bad = np.eye(4)
    bad[3, 3] = 2.0
    with pytest.raises(InputError, match=r"^transforms\[1\]: last row"):
        tf.average_transforms([A, bad])
    with pytest.raises(InputError, match="^weights"):
        tf.average_transforms([A, B], weights=[1.0])
