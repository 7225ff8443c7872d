"""SE(3) helpers on 4x4 homogeneous matrices.

Conventions (DESIGN.md): a transform ``a_T_b`` is a float64 array of shape (4, 4) that maps
points expressed in frame ``b`` into frame ``a``; quaternions are in ROS order
``quat_xyzw``; translations in metres; stamps in int nanoseconds.

Inputs are validated at the boundary (shape, finiteness, orthonormality of the rotation within
a tolerance) and raise :class:`eye_in_hand.errors.InputError` (a ``ValueError``) naming the
argument; internal helpers trust their inputs.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from eye_in_hand.errors import InputError

__all__ = [
    "ORTHONORMAL_ATOL",
    "as_finite_array",
    "as_points",
    "as_rotation",
    "as_transform",
    "make_transform",
    "value_key",
    "compose",
    "invert",
    "invert_many",
    "apply",
    "from_xyz_quat",
    "to_xyz_quat",
    "quat_xyzw_to_matrix",
    "matrix_to_quat_xyzw",
    "from_rotvec",
    "to_rotvec",
    "project_to_so3",
    "rotation_angle",
    "transform_distance",
    "interpolate",
    "interpolate_unchecked",
    "average_rotations",
    "average_transforms",
    "rotation_class",
]

def rotation_class() -> Any:
    """``scipy.spatial.transform.Rotation``, imported on first use: SciPy takes 0.2-0.8 s to
    import (0.75 s measured with a cold page cache, ``python -X importtime``), and processes
    that only detect and triangulate, or print a command's ``--help``, never need it."""
    from scipy.spatial.transform import Rotation

    return Rotation


#: Largest accepted deviation of R^T R from identity (max abs element) and of det(R) from 1.
ORTHONORMAL_ATOL = 1e-6


def as_finite_array(value: ArrayLike, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """Validate a finite float64 array of an exact shape, raising InputError naming ``name``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected a numeric array of shape {shape}") from exc
    if arr.shape != shape:
        raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def as_rotation(R: ArrayLike, name: str = "R", *, atol: float = ORTHONORMAL_ATOL) -> np.ndarray:
    """Validate a rotation matrix.

    Args:
        R: array-like, shape (3, 3).
        name: used in error messages.
        atol: tolerance on ``|R^T R - I|`` (max element) and ``|det R - 1|``.

    Returns:
        The rotation as a float64 array of shape (3, 3).

    Raises:
        InputError: wrong shape, non-finite values, not orthonormal or a reflection.
    """
    arr = as_finite_array(R, name, (3, 3))
    return _checked_rotation(arr, name, atol)


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
_EYE4 = np.eye(4)
_EYE4.setflags(write=False)


def _checked_rotation(arr: np.ndarray, name: str, atol: float) -> np.ndarray:
    """``arr`` (finite float64, (3, 3)) if it is a rotation within ``atol``, else InputError.
    On the per-pose path of the live node: the determinant as a triple product of the rows
    (what LAPACK's gives within ~1e-16, a million times below any tolerance), no copies."""
    err = float(np.abs(arr.T @ arr - _EYE3).max())
    r0, r1, r2 = arr.tolist()
    det = (r0[0] * (r1[1] * r2[2] - r1[2] * r2[1]) - r0[1] * (r1[0] * r2[2] - r1[2] * r2[0])
           + r0[2] * (r1[0] * r2[1] - r1[1] * r2[0]))
    if err > atol or abs(det - 1.0) > max(atol, 3 * err):
        raise InputError(
            f"{name}: rotation is not orthonormal (|R^T R - I| = {err:.2e}, det = {det:.6f}, "
            f"tolerance {atol:.0e})")
    return arr


def as_transform(T: ArrayLike, name: str = "T", *, atol: float = ORTHONORMAL_ATOL) -> np.ndarray:
    """Validate a homogeneous transform.

    Args:
        T: array-like, shape (4, 4); last row must be ``[0, 0, 0, 1]``.
        name: used in error messages.
        atol: orthonormality tolerance of the rotation block.

    Returns:
        float64 array of shape (4, 4).

    Raises:
        InputError: wrong shape, non-finite values, bad last row or rotation block.
    """
    arr = as_finite_array(T, name, (4, 4))
    a, b, c, d = arr[3].tolist()
    if max(abs(a), abs(b), abs(c), abs(d - 1.0)) > 1e-9:
        raise InputError(f"{name}: last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    _checked_rotation(arr[:3, :3], f"{name} rotation block", atol)
    return arr


def value_key(a: ArrayLike) -> tuple[tuple[int, ...], bytes]:
    """What an array-like is, by value, for a cache key: its shape and float64 bytes (equal
    values in any container or dtype give equal keys). Raises TypeError or ValueError when it
    is no array of numbers."""
    arr = np.asarray(a, dtype=np.float64)
    return arr.shape, arr.tobytes()


def as_points(points: ArrayLike, name: str = "points") -> np.ndarray:
    """Validate points: array-like shape (3,) or (N, 3), finite. Returns shape (N, 3)."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected a numeric array of shape (N, 3)") from exc
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (3,) or (N, 3), got {np.shape(points)}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def make_transform(R: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Build ``a_T_b`` from rotation (3, 3) and translation (3,)."""
    Rm = as_rotation(R, "R")
    tv = as_finite_array(np.ravel(t), "t", (3,))
    T = np.eye(4)
    T[:3, :3] = Rm
    T[:3, 3] = tv
    return T


def compose(*transforms: ArrayLike) -> np.ndarray:
    """Chain transforms left to right: ``compose(a_T_b, b_T_c) == a_T_c``."""
    if not transforms:
        return np.eye(4)
    out = as_transform(transforms[0], "transforms[0]")
    for i, T in enumerate(transforms[1:], start=1):
        out = out @ as_transform(T, f"transforms[{i}]")
    return out


def invert(T: ArrayLike) -> np.ndarray:
    """Inverse of a rigid transform: ``invert(a_T_b) == b_T_a`` (exact, via R^T)."""
    arr = as_transform(T, "T")
    R = arr[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ arr[:3, 3]
    return out


def invert_many(T: np.ndarray) -> np.ndarray:
    """Rigid inverses of a stack of transforms, shape (..., 4, 4) -> (..., 4, 4).

    Unlike :func:`invert` the input is not validated (a trusted float array whose rotation
    blocks are orthonormal): for the inner loops of the solvers and refinements.
    """
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros(np.shape(T), dtype=np.result_type(T, np.float64))
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def apply(T: ArrayLike, points: ArrayLike) -> np.ndarray:
    """Map points from frame b to frame a with ``a_T_b``.

    Args:
        T: shape (4, 4).
        points: shape (3,) or (N, 3).

    Returns:
        shape (3,) for a single point, else (N, 3).
    """
    arr = as_transform(T, "T")
    single = np.ndim(points) == 1
    pts = as_points(points)
    out: np.ndarray = pts @ arr[:3, :3].T + arr[:3, 3]
    return out[0] if single else out


def quat_xyzw_to_matrix(quat_xyzw: ArrayLike, name: str = "quat_xyzw") -> np.ndarray:
    """Rotation matrix from a quaternion (x, y, z, w); normalised, must not be near zero."""
    q = as_finite_array(np.ravel(quat_xyzw), name, (4,))
    x, y, z, w = (float(v) for v in q)
    return np.array(quat_xyzw_rows(x, y, z, w, name))


def quat_xyzw_rows(x: float, y: float, z: float, w: float, name: str = "quat_xyzw"
                   ) -> list[list[float]]:
    """The rows of :func:`quat_xyzw_to_matrix` from four finite floats, as Python floats
    (for a caller that builds a larger matrix around them: one array, not two)."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n < 1e-9:
        raise InputError(f"{name}: quaternion has zero norm")
    if abs(n - 1.0) > 1e-3:
        raise InputError(f"{name}: quaternion norm is {n:.6f}, expected 1 "
                         "(check xyzw order/units)")
    x, y, z, w = x / n, y / n, z / n, w / n
    # The unit-quaternion rotation matrix, written out (no BLAS call, no Rotation object: this
    # runs for every robot pose).
    return [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
        [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
        [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)]]


def matrix_to_quat_xyzw(R: ArrayLike) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation matrix, canonical with w >= 0.

    SciPy's ``Rotation.from_matrix(R).as_quat()``, to the bit: for a matrix orthonormal within
    SciPy's own test (``R R^T`` within 1e-12 of the identity off its diagonal), its conversion
    written out (:func:`_orthonormal_quat`), else SciPy's, which first projects the matrix
    onto the rotations. ``process`` converts one matrix (``/hand_eye/transform``) and would
    otherwise import SciPy's rotation module for it: 0.49 s of CPU.
    """
    arr = as_rotation(R, "R")
    q = _orthonormal_quat(arr)
    if q is None:
        q = rotation_class().from_matrix(arr).as_quat()
    return -q if q[3] < 0 else q


def _orthonormal_quat(R: np.ndarray) -> np.ndarray | None:
    """The quaternion (x, y, z, w; not canonical) of SciPy 1.17's ``from_matrix`` for a matrix
    its test takes as orthogonal (``isclose(R R^T, I, atol=1e-12)``), computed as it does
    (Markley's method: the largest of the diagonal and the trace picks the formula; then the
    division by the norm); None for any other matrix. Checked bit for bit against SciPy
    (1.15.2 and 1.17.1) on 3000 random rotations, special angles and matrices at its
    tolerance (test_quat_scipy)."""
    if not bool(np.all(np.abs(R @ R.T - _EYE3) <= 1e-12 + 1e-5 * _EYE3)):
        return None
    r = R.tolist()
    trace = r[0][0] + r[1][1] + r[2][2]
    decision = (r[0][0], r[1][1], r[2][2], trace)
    choice = decision.index(max(decision))
    if choice != 3:
        i = choice
        j = (i + 1) % 3
        k = (j + 1) % 3
        q = [0.0, 0.0, 0.0, 0.0]
        q[i] = 1 - trace + 2 * r[i][i]
        q[j] = r[j][i] + r[i][j]
        q[k] = r[k][i] + r[i][k]
        q[3] = r[k][j] - r[j][k]
    else:
        q = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1], 1 + trace]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return np.array([q[0] / n, q[1] / n, q[2] / n, q[3] / n])


def from_xyz_quat(xyz: ArrayLike, quat_xyzw: ArrayLike) -> np.ndarray:
    """4x4 transform from a translation (3,) and a quaternion (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = quat_xyzw_to_matrix(quat_xyzw)
    T[:3, 3] = as_finite_array(np.ravel(xyz), "xyz", (3,))
    return T


def to_xyz_quat(T: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Split a transform into (xyz (3,), quat_xyzw (4,)), with w >= 0."""
    arr = as_transform(T, "T")
    return arr[:3, 3].copy(), matrix_to_quat_xyzw(arr[:3, :3])


def from_rotvec(rotvec: ArrayLike, t: ArrayLike = (0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 transform from a rotation vector (axis * angle, radians) and a translation."""
    rv = as_finite_array(np.ravel(rotvec), "rotvec", (3,))
    T = np.eye(4)
    T[:3, :3] = rotation_class().from_rotvec(rv).as_matrix()
    T[:3, 3] = as_finite_array(np.ravel(t), "t", (3,))
    return T


def to_rotvec(T_or_R: ArrayLike) -> np.ndarray:
    """Rotation vector (3,) of a 4x4 transform or 3x3 rotation."""
    arr = np.asarray(T_or_R, dtype=np.float64)
    R = as_transform(arr)[:3, :3] if arr.shape == (4, 4) else as_rotation(arr)
    rotvec: np.ndarray = rotation_class().from_matrix(R).as_rotvec()
    return rotvec


def project_to_so3(M: ArrayLike) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to a 3x3 matrix, via SVD with det = +1."""
    arr = as_finite_array(M, "M", (3, 3))
    U, _, Vt = np.linalg.svd(arr)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    nearest: np.ndarray = U @ D @ Vt
    return nearest


def rotation_angle(R: ArrayLike) -> float:
    """Angle (radians, in [0, pi]) of a rotation matrix or of the rotation block of a 4x4.

    Raises:
        InputError: not shape (3, 3) or (4, 4), non-finite, or not a rotation. The tolerance is
            10 * ORTHONORMAL_ATOL so that products like ``A.T @ B`` of validated rotations pass.
    """
    arr = np.asarray(R, dtype=np.float64)
    if arr.shape == (4, 4):
        arr = arr[:3, :3]
    arr = as_rotation(arr, "R", atol=10 * ORTHONORMAL_ATOL)
    c = np.clip((np.trace(arr) - 1.0) / 2.0, -1.0, 1.0)
    # arccos is inaccurate near 0; use the rotation vector norm there.
    if c > 0.99:
        return float(np.linalg.norm(rotation_class().from_matrix(arr).as_rotvec()))
    return float(np.arccos(c))


def transform_distance(a_T_b: ArrayLike, a_T_c: ArrayLike) -> tuple[float, float]:
    """Difference between two transforms: (translation distance in m, rotation angle in rad)."""
    A = as_transform(a_T_b, "a_T_b")
    B = as_transform(a_T_c, "a_T_c")
    dt = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    return dt, rotation_angle(A[:3, :3].T @ B[:3, :3])


def interpolate(stamp_ns: int, stamp0_ns: int, T0: ArrayLike, stamp1_ns: int,
                T1: ArrayLike) -> np.ndarray:
    """Pose at ``stamp_ns`` between two stamped poses: slerp on rotation, lerp on translation.

    Args:
        stamp_ns: the query stamp (int ns), with ``stamp0_ns <= stamp_ns <= stamp1_ns``.
        stamp0_ns, T0: the earlier stamped pose.
        stamp1_ns, T1: the later stamped pose.

    Raises:
        InputError: the stamps are out of order or the query lies outside them.
    """
    A = as_transform(T0, "T0")
    B = as_transform(T1, "T1")
    if stamp1_ns < stamp0_ns:
        raise InputError(f"interpolate: stamps out of order ({stamp0_ns} > {stamp1_ns})")
    if not stamp0_ns <= stamp_ns <= stamp1_ns:
        raise InputError(
            f"interpolate: stamp {stamp_ns} outside [{stamp0_ns}, {stamp1_ns}] (no extrapolation)")
    return interpolate_unchecked(stamp_ns, stamp0_ns, A, stamp1_ns, B)


def interpolate_unchecked(stamp_ns: int, stamp0_ns: int, A: np.ndarray, stamp1_ns: int,
                          B: np.ndarray) -> np.ndarray:
    """:func:`interpolate` for transforms and stamps the caller has validated already (a pose
    buffer's): quaternion slerp along the shorter arc (= ``R_A exp(s log(R_A^T R_B))``), lerp
    on translation. Plain float arithmetic: it runs for every image."""
    if stamp1_ns == stamp0_ns:
        return np.array(A, dtype=np.float64)
    # Integer arithmetic first: ns stamps near 1.7e18 lose precision as float64.
    s = float(stamp_ns - stamp0_ns) / float(stamp1_ns - stamp0_ns)
    q0 = _quat_of(A)
    q1: tuple[float, ...] = _quat_of(B)
    if sum(a * b for a, b in zip(q0, q1, strict=True)) < 0.0:
        q1 = tuple(-v for v in q1)
    # the angle between the quaternions, accurate also when they are nearly equal
    theta = 2.0 * math.atan2(math.dist(q0, q1), math.dist(q0, tuple(-v for v in q1)))
    if theta < 1e-12:
        w0, w1 = 1.0 - s, s
    else:
        sin_t = math.sin(theta)
        w0, w1 = math.sin((1.0 - s) * theta) / sin_t, math.sin(s * theta) / sin_t
    q = [w0 * a + w1 * b for a, b in zip(q0, q1, strict=True)]
    out: np.ndarray = _EYE4.copy()
    out[:3, :3] = quat_xyzw_to_matrix(q)
    out[:3, 3] = (1.0 - s) * A[:3, 3] + s * B[:3, 3]
    return out


def _quat_of(T: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation (block), Shepperd's method (stable)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(T)[:3, :3].tolist()
    tr = m00 + m11 + m22
    if tr >= max(m00, m11, m22):
        r = math.sqrt(1.0 + tr) * 2.0
        q = ((m21 - m12) / r, (m02 - m20) / r, (m10 - m01) / r, 0.25 * r)
    elif m00 >= m11 and m00 >= m22:
        r = math.sqrt(1.0 + m00 - m11 - m22) * 2.0
        q = (0.25 * r, (m01 + m10) / r, (m02 + m20) / r, (m21 - m12) / r)
    elif m11 >= m22:
        r = math.sqrt(1.0 + m11 - m00 - m22) * 2.0
        q = ((m01 + m10) / r, 0.25 * r, (m12 + m21) / r, (m02 - m20) / r)
    else:
        r = math.sqrt(1.0 + m22 - m00 - m11) * 2.0
        q = ((m02 + m20) / r, (m12 + m21) / r, 0.25 * r, (m10 - m01) / r)
    n = math.sqrt(sum(v * v for v in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def average_rotations(rotations: ArrayLike,
                      weights: Iterable[float] | None = None) -> np.ndarray:
    """Mean rotation (chordal L2 mean via the quaternion eigenvector, Markley et al. 2007).

    Args:
        rotations: array-like, shape (N, 3, 3), N >= 1.
        weights: optional non-negative weights, shape (N,).

    Returns:
        shape (3, 3).
    """
    arr = np.asarray(rotations, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (3, 3) or arr.shape[0] == 0:
        raise InputError(f"rotations: expected shape (N, 3, 3) with N >= 1, got {arr.shape}")
    for i, R in enumerate(arr):
        as_rotation(R, f"rotations[{i}]")
    w = None
    if weights is not None:
        w = np.asarray(list(weights), dtype=np.float64)
        if (w.shape != (arr.shape[0],) or not np.all(np.isfinite(w)) or np.any(w < 0)
                or w.sum() <= 0):
            raise InputError("weights: expected N finite non-negative values with a positive sum")
    mean: np.ndarray = rotation_class().from_matrix(arr).mean(weights=w).as_matrix()
    return mean


def average_transforms(transforms: ArrayLike,
                       weights: Iterable[float] | None = None) -> np.ndarray:
    """Mean pose: rotation by :func:`average_rotations`, translation by weighted mean.

    Args:
        transforms: array-like, shape (N, 4, 4).
        weights: optional, shape (N,).
    """
    arr = np.asarray(transforms, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or arr.shape[0] == 0:
        raise InputError(f"transforms: expected shape (N, 4, 4) with N >= 1, got {arr.shape}")
    for i, T in enumerate(arr):
        as_transform(T, f"transforms[{i}]")
    w = None if weights is None else list(weights)
    out = np.eye(4)
    out[:3, :3] = average_rotations(arr[:, :3, :3], w)
    ww = np.ones(arr.shape[0]) if w is None else np.asarray(w, dtype=np.float64)
    out[:3, 3] = (ww[:, None] * arr[:, :3, 3]).sum(axis=0) / ww.sum()
    return out
