"""Hand-eye calibration by per-motion-pair solutions, averaged (method ``average``).

Two relative motions ``(A_p, B_p)``, ``(A_q, B_q)`` whose robot rotation axes are not parallel
determine X uniquely. This method solves X from every such pair of motions on its own, with a
per-pair solver, and averages the solutions:

* **motions**: the same ones as every closed form, ``A_ij = inv(G[j]) G[i]``,
  ``B_ij = C[j] inv(C[i])`` over all sample pairs ``i < j`` (:func:`.solvers.motion_pairs`);
* **usable pairs of motions**: both robot rotations at least :data:`MIN_ROTATION_DEG` and their
  axes (as lines, the angle in [0, 90] deg) at least :data:`MIN_AXIS_ANGLE_DEG` apart; pairs
  failing either test are skipped and counted (``skipped_small_rotation``,
  ``skipped_parallel_axes``), as are pairs whose per-pair system is singular
  (``skipped_degenerate``). With more usable pairs than :data:`MAX_PAIRS`, a fixed-seed random
  subset of that size is solved (``subsampled_out`` counts the rest): with all-pairs motions
  their number grows as N^4. Beyond :data:`MAX_CANDIDATES` pairs of motions (above about 42
  samples) only a fixed-seed random draw of that many is examined, the others count as
  ``subsampled_out`` too;
* **per-pair solvers**: ``"tsai"`` (Tsai-Lenz on the two motions: modified Rodrigues vectors,
  then translation by least squares) or ``"kronecker"`` (the homogeneous Kronecker / Andreff
  linear form on the two motions, 24 equations in 13 unknowns, smallest singular vector);
  both are vectorised over the pairs and equal :func:`.solvers.solve_tsai` and
  :func:`.solvers.solve_kronecker` given the same two motions;
* **averaging**: the rotation by the chordal L2 mean (the SVD projection onto SO(3) of the
  summed rotation matrices), optionally refined to the geodesic (Karcher) mean; the
  translation by the arithmetic mean of the per-pair translations of X (all in X's parent
  frame);
* **spread**: the RMS and largest deviation of the per-pair solutions from the mean (rotation
  angle in degrees, translation in millimetres), with the number of pairs used.

Fewer than :data:`MIN_PAIRS` usable pairs is a :class:`HandEyeError` that says how many pairs
were skipped for which reason; the method then drops out of the comparison like any failing
closed form.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.errors import HandEyeError

from .solvers import MotionPairs, _kronecker_system, _quat_wxyz, _skew

__all__ = [
    "AVERAGE_SOLVERS",
    "DEFAULT_AVERAGE_SOLVER",
    "MIN_ROTATION_DEG",
    "MIN_AXIS_ANGLE_DEG",
    "MAX_PAIRS",
    "MAX_CANDIDATES",
    "MIN_PAIRS",
    "AverageResult",
    "usable_motion_pairs",
    "pair_solutions",
    "rotation_mean",
    "average_hand_eye",
    "solve_average",
]

#: The per-pair solvers.
AVERAGE_SOLVERS = ("tsai", "kronecker")
#: The per-pair solver used unless another is asked for (the more accurate one in
#: ``benchmarks/bench_handeye.py``; see docs/handeye.md).
DEFAULT_AVERAGE_SOLVER = "tsai"
#: Smallest robot rotation of each motion of a pair, degrees.
MIN_ROTATION_DEG = 5.0
#: Smallest angle between the two robot rotation axes of a pair (as lines), degrees.
MIN_AXIS_ANGLE_DEG = 15.0
#: Most pairs of motions solved (a fixed-seed random subset beyond it).
MAX_PAIRS = 2000
#: Most pairs of motions examined against the thresholds (a fixed-seed random draw beyond).
MAX_CANDIDATES = 400_000
#: Fewest usable pairs the average is taken over.
MIN_PAIRS = 3

_ROTATION_MEANS = ("chordal", "geodesic")


@dataclass(frozen=True)
class AverageResult:
    """The averaged X and how it was obtained.

    Attributes:
        X: the averaged hand-eye transform, shape (4, 4).
        solutions: the per-pair solutions used, shape (P, 4, 4).
        pairs: the motion indices ``(p, q)`` of each solution (rows of the motions), (P, 2).
        solver: the per-pair solver.
        rotation_mean: ``"chordal"`` or ``"geodesic"``.
        n_motions: number of motions.
        n_candidates: number of pairs of motions, ``K (K - 1) / 2``.
        skipped_small_rotation, skipped_parallel_axes, skipped_degenerate, subsampled_out:
            pairs not used, by reason (counted in this order: a pair is counted once).
        rot_dev_deg, trans_dev_mm: each used solution's deviation from the mean, shape (P,).
        min_rotation_deg, min_axis_angle_deg, max_pairs: the thresholds applied.
    """

    X: np.ndarray
    solutions: np.ndarray
    pairs: np.ndarray
    solver: str
    rotation_mean: str
    n_motions: int
    n_candidates: int
    skipped_small_rotation: int
    skipped_parallel_axes: int
    skipped_degenerate: int
    subsampled_out: int
    rot_dev_deg: np.ndarray
    trans_dev_mm: np.ndarray
    min_rotation_deg: float
    min_axis_angle_deg: float
    max_pairs: int

    @property
    def n_used(self) -> int:
        """Number of per-pair solutions averaged."""
        return int(self.solutions.shape[0])

    @property
    def rot_std_deg(self) -> float:
        """RMS rotation deviation of the per-pair solutions from the mean, degrees."""
        return float(np.sqrt(np.mean(self.rot_dev_deg ** 2)))

    @property
    def trans_std_mm(self) -> float:
        """RMS translation deviation (3-D norm) of the per-pair solutions from the mean, mm."""
        return float(np.sqrt(np.mean(self.trans_dev_mm ** 2)))

    def summary(self) -> dict[str, Any]:
        """Plain data for report.json (``methods.average.average``)."""
        return {
            "solver": self.solver,
            "rotation_mean": self.rotation_mean,
            "n_motions": self.n_motions,
            "n_pairs_candidates": self.n_candidates,
            "n_pairs_used": self.n_used,
            "skipped": {"small_rotation": self.skipped_small_rotation,
                        "parallel_axes": self.skipped_parallel_axes,
                        "degenerate": self.skipped_degenerate,
                        "subsampled_out": self.subsampled_out},
            "thresholds": {"min_rotation_deg": self.min_rotation_deg,
                           "min_axis_angle_deg": self.min_axis_angle_deg,
                           "max_pairs": self.max_pairs},
            "spread": {"rot_std_deg": self.rot_std_deg, "trans_std_mm": self.trans_std_mm,
                       "rot_max_deg": float(np.max(self.rot_dev_deg)),
                       "trans_max_mm": float(np.max(self.trans_dev_mm))},
        }


def usable_motion_pairs(m: MotionPairs, *, min_rotation_deg: float = MIN_ROTATION_DEG,
                        min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
                        candidates: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
    """The pairs of motions whose robot rotations are large enough and axes far enough apart.

    Args:
        m: the motions (K of them).
        min_rotation_deg: smallest rotation angle of each motion.
        min_axis_angle_deg: smallest angle between the two rotation axes (as lines, 0-90 deg).
        candidates: the pairs ``(p, q)``, p < q, to examine, shape (C, 2); every pair when
            None.

    Returns:
        ``(pairs (P, 2) of motion indices p < q, skipped_small_rotation,
        skipped_parallel_axes)``.
    """
    K = len(m)
    rv = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    axis = rv / np.maximum(ang, 1e-300)[:, None]
    if candidates is None:
        pp, qq = np.triu_indices(K, k=1)
    else:
        pp, qq = candidates[:, 0], candidates[:, 1]
    big = (ang >= np.radians(min_rotation_deg))
    small = ~(big[pp] & big[qq])
    cos = np.abs(np.einsum("ki,ki->k", axis[pp], axis[qq]))
    sep = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    parallel = ~small & (sep < min_axis_angle_deg)
    keep = ~small & ~parallel
    return (np.stack([pp[keep], qq[keep]], axis=1), int(np.count_nonzero(small)),
            int(np.count_nonzero(parallel)))


def _project_so3_batch(M: np.ndarray) -> np.ndarray:
    """Nearest rotations of (P, 3, 3) matrices (SVD, reflection removed)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    return U @ Vt


def _quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()


def _solve3(N: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched 3x3 solves; returns (x (P, 3), ok (P,)) with singular systems flagged."""
    det = np.linalg.det(N)
    scale = np.einsum("kii->k", N) / 3.0
    ok = np.isfinite(det) & (np.abs(det) > 1e-12 * np.maximum(scale, 1e-300) ** 3)
    x = np.zeros(r.shape)
    if np.any(ok):
        x[ok] = np.linalg.solve(N[ok], r[ok][..., None])[..., 0]
    return x, ok


def _pairs_tsai(m: MotionPairs, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tsai-Lenz on each pair of motions (vectorised); ``(X (P, 4, 4), ok (P,))``."""
    qa = _quat_wxyz(m.A[:, :3, :3])
    qb = _quat_wxyz(m.B[:, :3, :3])
    S = _skew(2.0 * (qa[:, 1:] + qb[:, 1:]))           # (K, 3, 3)
    d = 2.0 * (qb[:, 1:] - qa[:, 1:])                  # (K, 3)
    StS = np.einsum("kji,kjl->kil", S, S)
    Std = np.einsum("kji,kj->ki", S, d)
    p, q = pairs[:, 0], pairs[:, 1]
    Pp, ok_r = _solve3(StS[p] + StS[q], Std[p] + Std[q])
    Px = 2.0 * Pp / np.sqrt(1.0 + np.einsum("ki,ki->k", Pp, Pp))[:, None]
    half = Px / 2.0
    w = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ki,ki->k", half, half)))
    R = _quat_wxyz_to_matrix(np.concatenate([w[:, None], half], axis=1))
    # Translation: (R_A - I) t = R t_B - t_A over the two motions.
    L = m.A[:, :3, :3] - np.eye(3)                     # (K, 3, 3)
    LtL = np.einsum("kji,kjl->kil", L, L)
    rhs_p = np.einsum("kij,kj->ki", R, m.B[p, :3, 3]) - m.A[p, :3, 3]
    rhs_q = np.einsum("kij,kj->ki", R, m.B[q, :3, 3]) - m.A[q, :3, 3]
    r = np.einsum("kji,kj->ki", L[p], rhs_p) + np.einsum("kji,kj->ki", L[q], rhs_q)
    t, ok_t = _solve3(LtL[p] + LtL[q], r)
    X = np.zeros((len(pairs), 4, 4))
    X[:, :3, :3] = R
    X[:, :3, 3] = t
    X[:, 3, 3] = 1.0
    return X, ok_r & ok_t


def _pairs_kronecker(m: MotionPairs, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The homogeneous Kronecker form on each pair of motions; ``(X (P, 4, 4), ok (P,))``."""
    M = _kronecker_system(m)
    G = np.einsum("kji,kjl->kil", M, M)                # (K, 13, 13)
    p, q = pairs[:, 0], pairs[:, 1]
    vals, vecs = np.linalg.eigh(G[p] + G[q])
    v = vecs[:, :, 0]                                  # smallest eigenvalue
    # A unique solution needs a one-dimensional null space: the second eigenvalue clear of 0.
    ok = vals[:, 1] > 1e-10 * np.maximum(vals[:, -1], 1e-300)
    B = v[:, :9].reshape(-1, 3, 3)
    det = np.linalg.det(B)
    ok &= np.isfinite(det) & (np.abs(det) > 1e-12)
    safe = np.where(ok, det, 1.0)
    scale = np.sign(safe) / np.cbrt(np.abs(safe))
    X = np.zeros((len(pairs), 4, 4))
    X[:, :3, :3] = _project_so3_batch(scale[:, None, None] * B)
    X[:, :3, 3] = scale[:, None] * v[:, 9:12]
    X[:, 3, 3] = 1.0
    return X, ok


_PAIR_SOLVERS = {"tsai": _pairs_tsai, "kronecker": _pairs_kronecker}


def pair_solutions(m: MotionPairs, pairs: np.ndarray, solver: str = DEFAULT_AVERAGE_SOLVER
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Solve X from each pair of motions on its own.

    Args:
        m: the motions.
        pairs: motion indices ``(p, q)``, shape (P, 2).
        solver: ``"tsai"`` or ``"kronecker"``.

    Returns:
        ``(X (P, 4, 4), ok (P,))``: ``ok`` is False where the pair's system is singular (its
        X is then meaningless).

    Raises:
        HandEyeError: unknown solver.
    """
    if solver not in _PAIR_SOLVERS:
        raise HandEyeError(f"average solver: expected one of {', '.join(AVERAGE_SOLVERS)}, got "
                           f"{solver!r}")
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return np.zeros((0, 4, 4)), np.zeros(0, dtype=bool)
    with np.errstate(all="ignore"):
        X, ok = _PAIR_SOLVERS[solver](m, pairs)
    ok &= np.all(np.isfinite(X.reshape(len(pairs), -1)), axis=1)
    return X, ok


def rotation_mean(R: np.ndarray, method: str = "chordal", *, iterations: int = 50) -> np.ndarray:
    """Mean of rotations.

    ``"chordal"``: the rotation nearest (Frobenius) to the sum of the matrices, i.e. the
    minimiser of the summed squared chordal distances, by SVD projection onto SO(3).
    ``"geodesic"``: the Karcher mean (minimiser of the summed squared rotation angles), by
    Gauss-Newton steps from the chordal mean.

    Args:
        R: rotations, shape (P, 3, 3), P >= 1.
        method: ``"chordal"`` or ``"geodesic"``.
        iterations: most geodesic steps.

    Returns:
        A proper rotation, shape (3, 3).

    Raises:
        HandEyeError: no rotations, unknown method, or a sum with no unique nearest rotation.
    """
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    if R.shape[0] == 0:
        raise HandEyeError("rotation mean of no rotations")
    if method not in _ROTATION_MEANS:
        raise HandEyeError(f"rotation mean: expected one of {', '.join(_ROTATION_MEANS)}, got "
                           f"{method!r}")
    S = R.sum(axis=0)
    U, s, Vt = np.linalg.svd(S)
    if s[1] < 1e-9 * max(s[0], 1e-300):
        raise HandEyeError("rotation mean: the rotations cancel out (no unique mean)")
    D = np.diag([1.0, 1.0, 1.0 if np.linalg.det(U @ Vt) > 0 else -1.0])
    M = U @ D @ Vt
    if method == "geodesic":
        for _ in range(iterations):
            step = Rotation.from_matrix(np.einsum("ji,kjl->kil", M, R)).as_rotvec().mean(axis=0)
            M = M @ Rotation.from_rotvec(step).as_matrix()
            if np.linalg.norm(step) < 1e-14:
                break
    return M


def average_hand_eye(m: MotionPairs, solver: str = DEFAULT_AVERAGE_SOLVER, *,
                     min_rotation_deg: float = MIN_ROTATION_DEG,
                     min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
                     max_pairs: int = MAX_PAIRS, rotation: str = "chordal",
                     seed: int = 0) -> AverageResult:
    """X from every usable pair of motions, averaged (see the module docstring).

    Args:
        m: the motions.
        solver: the per-pair solver, ``"tsai"`` or ``"kronecker"``.
        min_rotation_deg: smallest robot rotation of each motion of a pair.
        min_axis_angle_deg: smallest angle between the pair's robot rotation axes.
        max_pairs: most pairs solved (fixed-seed random subset beyond).
        rotation: the rotation mean, ``"chordal"`` or ``"geodesic"``.
        seed: seed of the subset.

    Returns:
        The average and its spread.

    Raises:
        HandEyeError: unknown solver or mean, or fewer than :data:`MIN_PAIRS` usable pairs.
    """
    if solver not in _PAIR_SOLVERS:
        raise HandEyeError(f"average solver: expected one of {', '.join(AVERAGE_SOLVERS)}, got "
                           f"{solver!r}")
    if rotation not in _ROTATION_MEANS:
        raise HandEyeError(f"rotation mean: expected one of {', '.join(_ROTATION_MEANS)}, got "
                           f"{rotation!r}")
    K = len(m)
    n_cand = K * (K - 1) // 2
    rng = np.random.default_rng(seed)
    cand = None
    if n_cand > MAX_CANDIDATES:
        draw = rng.integers(0, K, size=(MAX_CANDIDATES, 2))
        draw = np.sort(draw[draw[:, 0] != draw[:, 1]], axis=1)
        # distinct (i, j) rows in lexicographic order, as np.unique(axis=0) gives them, through
        # one integer key per row marked in a K*K table (a row-wise unique took 0.5 s a call
        # with 1225 motions, and the held-out figures call this once per sample and method)
        key = draw[:, 0].astype(np.int64) * K + draw[:, 1]
        if K * K <= 50_000_000:
            seen = np.zeros(K * K, dtype=bool)
            seen[key] = True
            key = np.flatnonzero(seen)
        else:
            key = np.unique(key)
        cand = np.stack([key // K, key % K], axis=1)
    pairs, n_small, n_par = usable_motion_pairs(m, min_rotation_deg=min_rotation_deg,
                                                min_axis_angle_deg=min_axis_angle_deg,
                                                candidates=cand)
    n_sub = 0 if cand is None else n_cand - len(cand)
    if len(pairs) > max_pairs:
        pick = np.sort(rng.choice(len(pairs), max_pairs, replace=False))
        n_sub += len(pairs) - max_pairs
        pairs = pairs[pick]
    Xs, ok = pair_solutions(m, pairs, solver)
    n_deg = int(np.count_nonzero(~ok))
    Xs, pairs = Xs[ok], pairs[ok]
    if len(Xs) < MIN_PAIRS:
        raise HandEyeError(
            f"average: {len(Xs)} usable pairs of motions of {n_cand} ({n_small} with a robot "
            f"rotation under {min_rotation_deg:g} deg, {n_par} with rotation axes within "
            f"{min_axis_angle_deg:g} deg of each other, {n_deg} degenerate); need at least "
            f"{MIN_PAIRS}: add samples rotating about different axes")
    R = rotation_mean(Xs[:, :3, :3], rotation)
    t = Xs[:, :3, 3].mean(axis=0)
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = t
    rot_dev = np.degrees(np.linalg.norm(
        Rotation.from_matrix(np.einsum("ji,kjl->kil", R, Xs[:, :3, :3])).as_rotvec(), axis=1))
    trans_dev = 1000.0 * np.linalg.norm(Xs[:, :3, 3] - t, axis=1)
    return AverageResult(X=X, solutions=Xs, pairs=pairs, solver=solver, rotation_mean=rotation,
                         n_motions=K, n_candidates=n_cand, skipped_small_rotation=n_small,
                         skipped_parallel_axes=n_par, skipped_degenerate=n_deg,
                         subsampled_out=n_sub, rot_dev_deg=rot_dev, trans_dev_mm=trans_dev,
                         min_rotation_deg=float(min_rotation_deg),
                         min_axis_angle_deg=float(min_axis_angle_deg), max_pairs=int(max_pairs))


def solve_average(m: MotionPairs, solver: str = DEFAULT_AVERAGE_SOLVER) -> np.ndarray:
    """The averaged X alone (the closed-form solver signature, ``MotionPairs -> X``).

    Args:
        m: the motions.
        solver: the per-pair solver.

    Returns:
        X, shape (4, 4).

    Raises:
        HandEyeError: see :func:`average_hand_eye`.
    """
    return average_hand_eye(m, solver).X
