"""Closed-form solvers for the hand-eye equation AX = XB.

Formulation
-----------
Every sample ``i`` gives a robot pose ``base_T_ee[i]`` and a board pose ``cam_T_board[i]``.
The solvers see the problem in one form, ``A_ij X = X B_ij`` over the pairs of samples, with

* ``G[i]`` the "gripper" pose handed to the solvers and ``C[i] = cam_T_board[i]``,
* ``A_ij = inv(G[j]) @ G[i]`` (robot motion) and ``B_ij = C[j] @ inv(C[i])`` (camera motion),

which is the formulation of Tsai-Lenz (1989) and of OpenCV's ``calibrateHandEye``.

* **Eye-in-hand** (camera on the flange, board fixed in the world): ``G[i] = base_T_ee[i]`` and
  the solution is ``X = ee_T_cam``. The board pose in the fixed frame is ``base_T_board``.
* **Eye-to-hand** (camera fixed, board on the flange): ``G[i] = inv(base_T_ee[i]) = ee_T_base``
  and the solution is ``X = base_T_cam``. The board pose in its fixed frame is ``ee_T_board``.

In both cases ``cam_T_board[i] = inv(X) @ inv(G[i]) @ Y`` with ``Y`` the board pose in its fixed
frame (``base_T_board`` or ``ee_T_board``), which is what :func:`board_in_fixed_frame` inverts.

Pairs: every solver uses **all pairs** ``i < j`` of samples (n(n-1)/2 motions), as OpenCV's
``calibrateHandEye`` does: with the same noise model this keeps each method comparable to its
OpenCV counterpart, and all pairs average the independent PnP noise of every sample better than
consecutive motions (which use each sample in only two motions and chain their errors).

Quaternion signs are made consistent (``w >= 0`` on both sides of a motion, whose angles are
equal by the screw congruence theorem) before Tsai-Lenz, Horaud-Dornaika and Daniilidis use
them, so motions above 90 degrees are handled the same as small ones.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import invert_many, project_to_so3
from eye_in_hand.errors import HandEyeError

__all__ = [
    "CLOSED_FORM_METHODS",
    "SETUPS",
    "MotionPairs",
    "gripper_poses",
    "motion_pairs",
    "solve_tsai",
    "solve_park",
    "solve_horaud",
    "solve_daniilidis",
    "solve_andreff",
    "solve_kronecker",
    "solve_closed_form",
    "board_in_fixed_frame",
]

#: The supported setups.
SETUPS = ("eye_in_hand", "eye_to_hand")


def _skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of vectors, shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) with w >= 0 of rotations, shape (..., 3, 3) -> (..., 4)."""
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()  # xyzw
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(R.shape[:-2] + (4,))


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions in (w, x, y, z) order."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz,
                     pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def _quat_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    q = np.asarray(q_wxyz, dtype=np.float64)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares through the (small) normal equations, formed without threaded BLAS.

    The systems here are tall and thin (3-12 unknowns, well conditioned when the motion
    diagnostics pass); a LAPACK SVD of the tall matrix is far slower on a loaded machine.
    """
    N = np.einsum("ki,kj->ij", A, A)
    r = np.einsum("ki,k->i", A, b)
    try:
        return np.linalg.solve(N, r)
    except np.linalg.LinAlgError:
        sol, *_ = np.linalg.lstsq(A, b, rcond=None)
        return sol


def _null_vectors(M: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` right singular vectors of smallest singular value of a tall matrix ``M``,
    as rows (smallest last), from the eigenvectors of ``M^T M``."""
    _, vecs = np.linalg.eigh(np.einsum("ki,kj->ij", M, M))
    return vecs[:, :k][:, ::-1].T


@dataclass(frozen=True)
class MotionPairs:
    """Relative motions over all sample pairs ``i < j``.

    Attributes:
        A: robot motions ``inv(G[j]) G[i]``, shape (K, 4, 4).
        B: camera motions ``C[j] inv(C[i])``, shape (K, 4, 4).
        index: the sample indices ``(i, j)`` of each motion, shape (K, 2).
    """

    A: np.ndarray
    B: np.ndarray
    index: np.ndarray

    def __len__(self) -> int:
        return int(self.A.shape[0])


def gripper_poses(base_T_ee: np.ndarray, setup: str) -> np.ndarray:
    """The poses ``G`` the solvers take: ``base_T_ee`` (eye-in-hand) or its inverse (eye-to-hand).

    Args:
        base_T_ee: robot poses, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        shape (N, 4, 4).

    Raises:
        HandEyeError: unknown setup.
    """
    if setup == "eye_in_hand":
        return np.array(base_T_ee, dtype=np.float64)
    if setup == "eye_to_hand":
        return invert_many(np.asarray(base_T_ee, dtype=np.float64))
    raise HandEyeError(f"setup: expected one of {', '.join(SETUPS)}, got {setup!r}")


def motion_pairs(G: np.ndarray, C: np.ndarray, pairs: str = "all") -> MotionPairs:
    """Build the motions ``A_ij``, ``B_ij``.

    Args:
        G: gripper poses (see :func:`gripper_poses`), shape (N, 4, 4).
        C: board poses ``cam_T_board``, shape (N, 4, 4).
        pairs: ``"all"`` (every ``i < j``) or ``"consecutive"`` (``j = i + 1``).

    Returns:
        The motions.
    """
    n = G.shape[0]
    if pairs == "all":
        ii, jj = np.triu_indices(n, k=1)
    elif pairs == "consecutive":
        ii = np.arange(n - 1)
        jj = ii + 1
    else:
        raise HandEyeError(f"pairs: expected 'all' or 'consecutive', got {pairs!r}")
    A = invert_many(G[jj]) @ G[ii]
    B = C[jj] @ invert_many(C[ii])
    return MotionPairs(A, B, np.stack([ii, jj], axis=1))


def _assemble(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = t
    return X


def _translation_lstsq(m: MotionPairs, R: np.ndarray) -> np.ndarray:
    """Solve ``(R_A - I) t = R t_B - t_A`` over all motions (shared by several methods)."""
    K = len(m)
    lhs = (m.A[:, :3, :3] - np.eye(3)).reshape(3 * K, 3)
    rhs = (m.B[:, :3, 3] @ R.T - m.A[:, :3, 3]).reshape(3 * K)
    return _lstsq(lhs, rhs)


def solve_tsai(m: MotionPairs) -> np.ndarray:
    """Tsai and Lenz (1989): modified Rodrigues vectors, then translation by least squares.

    Rotation: ``skew(P_A + P_B) P' = P_B - P_A`` with ``P = 2 sin(theta/2) axis``, then
    ``P_X = 2 P' / sqrt(1 + |P'|^2)``.

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).
    """
    qa = _quat_wxyz(m.A[:, :3, :3])
    qb = _quat_wxyz(m.B[:, :3, :3])
    Pa = 2.0 * qa[:, 1:]
    Pb = 2.0 * qb[:, 1:]
    lhs = _skew(Pa + Pb).reshape(-1, 3)
    rhs = (Pb - Pa).reshape(-1)
    Pp = _lstsq(lhs, rhs)
    Px = 2.0 * Pp / np.sqrt(1.0 + Pp @ Pp)
    half = Px / 2.0  # sin(theta/2) * axis
    w = np.sqrt(max(0.0, 1.0 - half @ half))
    R = _quat_to_matrix(np.concatenate([[w], half]))
    return _assemble(R, _translation_lstsq(m, R))


def solve_park(m: MotionPairs) -> np.ndarray:
    """Park and Martin (1994): rotation from the log maps, ``R = (M^T M)^(-1/2) M^T``.

    ``M = sum b a^T`` with ``a = log R_A``, ``b = log R_B`` (since ``a = R_X b``); computed as the
    orthogonal Procrustes solution with the reflection case removed. Translation by least squares.

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).
    """
    a = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    b = Rotation.from_matrix(m.B[:, :3, :3]).as_rotvec()
    H = a.T @ b  # sum a b^T = M^T
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    return _assemble(R, _translation_lstsq(m, R))


def solve_horaud(m: MotionPairs) -> np.ndarray:
    """Horaud and Dornaika (1995): rotation quaternion as the eigenvector of smallest eigenvalue.

    Each motion gives ``q_A * q_X = q_X * q_B``, i.e. ``(Q(q_A) - W(q_B)) q_X = 0`` with ``Q``
    and ``W`` the left and right quaternion-product matrices. Translation by least squares.

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).
    """
    qa = _quat_wxyz(m.A[:, :3, :3])
    qb = _quat_wxyz(m.B[:, :3, :3])
    # Left product matrix Q(p) q = p * q and right product matrix W(p) q = q * p.
    aw, ax, ay, az = qa.T
    bw, bx, by, bz = qb.T
    Q = np.stack([np.stack([aw, -ax, -ay, -az], -1), np.stack([ax, aw, -az, ay], -1),
                  np.stack([ay, az, aw, -ax], -1), np.stack([az, -ay, ax, aw], -1)], axis=1)
    W = np.stack([np.stack([bw, -bx, -by, -bz], -1), np.stack([bx, bw, bz, -by], -1),
                  np.stack([by, -bz, bw, bx], -1), np.stack([bz, by, -bx, bw], -1)], axis=1)
    D = Q - W
    S = np.einsum("kji,kjl->il", D, D)  # sum D^T D
    _, vecs = np.linalg.eigh(S)
    R = _quat_to_matrix(vecs[:, 0])
    return _assemble(R, _translation_lstsq(m, R))


def _dual_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dual quaternions (real, dual), each (K, 4) in (w, x, y, z), with real w >= 0."""
    q = _quat_wxyz(T[:, :3, :3])
    t = np.concatenate([np.zeros((T.shape[0], 1)), T[:, :3, 3]], axis=1)
    return q, 0.5 * _qmul(t, q)


def solve_daniilidis(m: MotionPairs) -> np.ndarray:
    """Daniilidis (1999): rotation and translation together from dual quaternions.

    Stacks ``[a - b, skew(a + b), 0, 0; a' - b', skew(a' + b'), a - b, skew(a + b)]`` (6 rows per
    motion, 8 unknowns), takes the two right singular vectors of smallest singular value and
    fixes their combination from the unit-norm and orthogonality constraints of the dual
    quaternion (eqs. 34-35 of the paper).

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).

    Raises:
        HandEyeError: the quadratic of the paper has no real solution (degenerate motions).
    """
    qa, qa_d = _dual_quat(m.A)
    qb, qb_d = _dual_quat(m.B)
    a, ad = qa[:, 1:], qa_d[:, 1:]
    b, bd = qb[:, 1:], qb_d[:, 1:]
    K = len(m)
    T = np.zeros((K, 6, 8))
    T[:, :3, 0] = a - b
    T[:, :3, 1:4] = _skew(a + b)
    T[:, 3:, 0] = ad - bd
    T[:, 3:, 1:4] = _skew(ad + bd)
    T[:, 3:, 4] = a - b
    T[:, 3:, 5:8] = _skew(a + b)
    v7, v8 = _null_vectors(T.reshape(6 * K, 8), 2)
    u1, w1 = v7[:4], v7[4:]
    u2, w2 = v8[:4], v8[4:]
    qa_ = u1 @ w1
    qb_ = u1 @ w2 + u2 @ w1
    qc_ = u2 @ w2
    disc = qb_ * qb_ - 4.0 * qa_ * qc_
    if abs(qa_) < 1e-15:
        # u1 . w1 = 0: the first vector alone satisfies the orthogonality constraint (s -> inf).
        candidates = [(np.inf, u1 @ u1)]
    else:
        if disc < 0:
            if disc < -1e-9 * max(1.0, qb_ * qb_):
                raise HandEyeError("daniilidis: no real solution of the dual-quaternion "
                                   "constraints (degenerate motions)")
            disc = 0.0
        root = np.sqrt(disc)
        candidates = []
        for s in ((-qb_ + root) / (2 * qa_), (-qb_ - root) / (2 * qa_)):
            candidates.append((s, s * s * (u1 @ u1) + 2 * s * (u1 @ u2) + u2 @ u2))
    s, val = max(candidates, key=lambda c: c[1])
    if np.isinf(s):
        dq = v7 / np.linalg.norm(u1)
    else:
        l2 = np.sqrt(1.0 / val)
        dq = s * l2 * v7 + l2 * v8
    q, qd = dq[:4], dq[4:]
    n = np.linalg.norm(q)
    q, qd = q / n, qd / n
    R = _quat_to_matrix(q)
    t = 2.0 * _qmul(qd, q * np.array([1.0, -1.0, -1.0, -1.0]))[1:]
    return _assemble(R, t)


def _normalize_rotation_block(M: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale a 3x3 block to unit determinant, return its projection onto SO(3) and the scale."""
    det = float(np.linalg.det(M))
    if not np.isfinite(det) or abs(det) < 1e-12:
        raise HandEyeError("rotation block of the linear solution is singular "
                           "(degenerate motions)")
    scale = np.copysign(1.0, det) / np.cbrt(abs(det))
    return project_to_so3(scale * M), scale


def _kron_rotation_rows(m: MotionPairs) -> np.ndarray:
    """``I9 - kron(R_A, R_B)`` per motion (row-major vec of R_X), shape (K, 9, 9)."""
    RA = m.A[:, :3, :3]
    RB = m.B[:, :3, :3]
    kron = np.einsum("kij,klm->kiljm", RA, RB).reshape(-1, 9, 9)
    return np.eye(9) - kron


def _kron_translation_rows(m: MotionPairs) -> np.ndarray:
    """``kron(I3, t_B^T)`` per motion, shape (K, 3, 9), so that it maps vec(R_X) to R_X t_B."""
    K = len(m)
    out = np.zeros((K, 3, 9))
    for r in range(3):
        out[:, r, 3 * r:3 * r + 3] = m.B[:, :3, 3]
    return out


def solve_andreff(m: MotionPairs) -> np.ndarray:
    """Andreff, Horaud and Espiau (1999): the Kronecker-product linear form, solved in one go.

    ``[I9 - kron(R_A, R_B), 0; kron(I3, t_B^T), I3 - R_A] [vec R; t] = [0; t_A]`` as a linear
    least-squares problem in 12 unknowns; the rotation block is scaled to unit determinant and
    projected onto SO(3) (eq. 15), the translation is taken from the same solution.

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).
    """
    K = len(m)
    A = np.zeros((K, 12, 12))
    b = np.zeros((K, 12))
    A[:, :9, :9] = _kron_rotation_rows(m)
    A[:, 9:, :9] = _kron_translation_rows(m)
    A[:, 9:, 9:] = np.eye(3) - m.A[:, :3, :3]
    b[:, 9:] = m.A[:, :3, 3]
    sol = _lstsq(A.reshape(12 * K, 12), b.reshape(12 * K))
    R, _ = _normalize_rotation_block(sol[:9].reshape(3, 3))
    return _assemble(R, sol[9:])


def _kronecker_system(m: MotionPairs) -> np.ndarray:
    """The homogeneous Kronecker system of each motion, shape (K, 12, 13): unknowns
    ``vec(R_X)`` (9), ``t_X`` (3) and the scale (1)."""
    M = np.zeros((len(m), 12, 13))
    M[:, :9, :9] = _kron_rotation_rows(m)
    M[:, 9:, :9] = _kron_translation_rows(m)
    M[:, 9:, 9:12] = np.eye(3) - m.A[:, :3, :3]
    M[:, 9:, 12] = -m.A[:, :3, 3]
    return M


def solve_kronecker(m: MotionPairs) -> np.ndarray:
    """Homogeneous Kronecker (direct-product) linear method.

    Stacks, for every motion, the rotation equations ``(I9 - kron(R_A, R_B)) vec R = 0`` and
    the translation equations ``kron(I3, t_B^T) vec R + (I3 - R_A) t - t_A = 0`` as one
    homogeneous system ``M [vec R; t; 1] = 0`` (13 unknowns) and takes the solution vector as the
    eigenvector of ``M^T M`` of smallest eigenvalue (the right singular vector of smallest
    singular value; the null space for exact data). The scale of the vector is fixed from its
    rotation block (``det = 1``, which also fixes the sign); the block is then orthogonalised
    by SVD projection onto SO(3) and the translation is the equally scaled ``t`` part.

    Args:
        m: the motions.

    Returns:
        X, shape (4, 4).
    """
    K = len(m)
    M = _kronecker_system(m)
    v = _null_vectors(M.reshape(12 * K, 13), 1)[0]
    R, scale = _normalize_rotation_block(v[:9].reshape(3, 3))
    return _assemble(R, scale * v[9:12])


#: The closed-form methods by name, in the order the reports list them.
CLOSED_FORM_METHODS: dict[str, Callable[[MotionPairs], np.ndarray]] = {
    "tsai": solve_tsai,
    "park": solve_park,
    "horaud": solve_horaud,
    "daniilidis": solve_daniilidis,
    "andreff": solve_andreff,
    "kronecker": solve_kronecker,
}


def solve_closed_form(method: str, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                      setup: str = "eye_in_hand", *, pairs: str = "all") -> np.ndarray:
    """Solve AX = XB with one closed-form method.

    Args:
        method: one of :data:`CLOSED_FORM_METHODS`.
        base_T_ee: robot poses, shape (N, 4, 4), N >= 3 (trusted: validate with
            :func:`eye_in_hand.core.handeye.validate_samples` first).
        cam_T_board: board poses in the camera frame, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` (returns ``ee_T_cam``) or ``"eye_to_hand"`` (``base_T_cam``).
        pairs: ``"all"`` or ``"consecutive"`` motions.

    Returns:
        X, shape (4, 4).

    Raises:
        HandEyeError: unknown method or setup, fewer than 3 samples, degenerate system.
    """
    if method not in CLOSED_FORM_METHODS:
        raise HandEyeError(f"method: expected one of {', '.join(CLOSED_FORM_METHODS)}, "
                           f"got {method!r}")
    base_T_ee = np.asarray(base_T_ee, dtype=np.float64)
    cam_T_board = np.asarray(cam_T_board, dtype=np.float64)
    if (base_T_ee.shape != cam_T_board.shape or base_T_ee.ndim != 3
            or base_T_ee.shape[1:] != (4, 4)):
        raise HandEyeError(f"expected base_T_ee and cam_T_board of equal shape (N, 4, 4), got "
                           f"{base_T_ee.shape} and {cam_T_board.shape}")
    if base_T_ee.shape[0] < 3:
        raise HandEyeError(f"{method}: need at least 3 samples, got {base_T_ee.shape[0]}")
    m = motion_pairs(gripper_poses(base_T_ee, setup), cam_T_board, pairs)
    X = CLOSED_FORM_METHODS[method](m)
    if not np.all(np.isfinite(X)):
        raise HandEyeError(f"{method}: solution is not finite (degenerate motions)")
    return X


def board_in_fixed_frame(X: np.ndarray, base_T_ee: np.ndarray, cam_T_board: np.ndarray,
                         setup: str) -> np.ndarray:
    """Each sample's estimate of the board pose in its fixed frame, ``Y_i = G_i X C_i``.

    Args:
        X: the hand-eye transform, shape (4, 4).
        base_T_ee: shape (N, 4, 4).
        cam_T_board: shape (N, 4, 4).
        setup: ``"eye_in_hand"`` (returns ``base_T_board``) or ``"eye_to_hand"``
            (``ee_T_board``).

    Returns:
        shape (N, 4, 4).
    """
    G = gripper_poses(np.asarray(base_T_ee, dtype=np.float64), setup)
    return G @ np.asarray(X, dtype=np.float64) @ np.asarray(cam_T_board, dtype=np.float64)

