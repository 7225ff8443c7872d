"""Distances between located targets over many frames, and their error against the truth.

A *track* is one target's positions over the frames of a recording, shape (N, 3) in metres,
one row per frame (the same N frames for every target), NaN where the target was not located
in that frame. For every pair of targets the distance is computed per frame where both were
located; its mean and standard deviation over those frames are the measurement. The truth is
either per-frame true positions (the simulator's ground truth, tracks of the same shape) or
known distances given by the user.

Pure numpy (and scipy's assignment solver): no ROS, no files.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from eye_in_hand.core.assignment import min_cost_assignment
from eye_in_hand.errors import InputError

__all__ = ["PairDistance", "TargetStats", "pairwise_distances", "apply_known_distances",
           "target_stats", "match_truth", "distance_table"]


@dataclass(frozen=True)
class PairDistance:
    """The distance between targets ``a`` and ``b`` over the frames where both were located.

    Attributes:
        a, b: target ids (``a`` before ``b`` in the order the tracks were given).
        frames: frames where both were located.
        mean_m: mean distance (m), NaN when ``frames`` is 0.
        std_m: sample standard deviation over frames (m, ddof 1), NaN with fewer than 2.
        truth_m: the true distance (m): the mean over the same frames of the distance between
            the two true positions, or a known distance; NaN when there is no truth.
        error_mm: ``mean(measured - true)`` over the frames with both (mm), NaN without truth.
        truth_source: ``"ground_truth"``, ``"known"`` or ``""``.
    """

    a: str
    b: str
    frames: int
    mean_m: float
    std_m: float
    truth_m: float = math.nan
    error_mm: float = math.nan
    truth_source: str = ""

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: NaN becomes None."""
        def num(v: float) -> float | None:
            return None if not math.isfinite(v) else float(v)
        return {"a": self.a, "b": self.b, "frames": int(self.frames), "mean_m": num(self.mean_m),
                "std_mm": num(1000.0 * self.std_m), "truth_m": num(self.truth_m),
                "error_mm": num(self.error_mm), "truth_source": self.truth_source or None}


@dataclass(frozen=True)
class TargetStats:
    """One target's figures over a recording.

    Attributes:
        id: the target id.
        located: frames where it was located (finite position).
        truth_frames: frames with both a position and a true position.
        rms_mm, max_mm: position error against the truth over those frames (mm), NaN without.
    """

    id: str
    located: int
    truth_frames: int = 0
    rms_mm: float = math.nan
    max_mm: float = math.nan

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: NaN becomes None."""
        return {"located": int(self.located), "truth_frames": int(self.truth_frames),
                "rms_mm": None if not math.isfinite(self.rms_mm) else float(self.rms_mm),
                "max_mm": None if not math.isfinite(self.max_mm) else float(self.max_mm)}


def _tracks(tracks: Mapping[str, np.ndarray], name: str) -> tuple[list[str], np.ndarray]:
    """Validate ``{id: (N, 3)}`` and stack it to shape (M, N, 3)."""
    ids = [str(k) for k in tracks]
    if not ids:
        return [], np.zeros((0, 0, 3))
    arrays = [np.asarray(tracks[k], dtype=np.float64) for k in tracks]
    n = arrays[0].shape[0] if arrays[0].ndim == 2 else -1
    for k, arr in zip(ids, arrays, strict=True):
        if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] != n:
            raise InputError(f"{name}[{k!r}]: expected shape ({max(n, 0)}, 3), got {arr.shape}")
        if np.any(np.isinf(arr)):
            raise InputError(f"{name}[{k!r}]: infinite values (use NaN for a missing frame)")
    return ids, np.stack(arrays)


def pairwise_distances(tracks: Mapping[str, np.ndarray],
                       truth: Mapping[str, np.ndarray] | None = None) -> list[PairDistance]:
    """Every pair's distance statistics, in the order of ``tracks`` (a before b).

    Args:
        tracks: target id -> positions, shape (N, 3), NaN rows where not located.
        truth: optional target id -> true positions, shape (N, 3) (same frames), NaN rows
            where the truth is missing; ids absent here have no truth.

    Returns:
        One :class:`PairDistance` per unordered pair, ``M (M - 1) / 2`` of them.

    Raises:
        InputError: tracks of different lengths or not (N, 3).
    """
    ids, P = _tracks(tracks, "tracks")
    T = None
    if truth:
        tids, Tstack = _tracks(truth, "truth")
        if Tstack.size and P.size and Tstack.shape[1] != P.shape[1]:
            raise InputError(f"truth: {Tstack.shape[1]} frames, tracks have {P.shape[1]}")
        T = {k: Tstack[i] for i, k in enumerate(tids)}
    out: list[PairDistance] = []
    for i in range(len(ids)):
        for j in range(i + 1, len(ids)):
            d = np.linalg.norm(P[i] - P[j], axis=1)          # NaN where either is missing
            ok = np.isfinite(d)
            n = int(ok.sum())
            mean = float(d[ok].mean()) if n else math.nan
            std = float(d[ok].std(ddof=1)) if n >= 2 else math.nan
            pair = PairDistance(ids[i], ids[j], n, mean, std)
            if T is not None and ids[i] in T and ids[j] in T:
                dt = np.linalg.norm(T[ids[i]] - T[ids[j]], axis=1)
                both = ok & np.isfinite(dt)
                if both.any():
                    pair = replace(pair, truth_m=float(dt[both].mean()),
                                   error_mm=1000.0 * float(np.mean(d[both] - dt[both])),
                                   truth_source="ground_truth")
            out.append(pair)
    return out


def _pair_key(a: str, b: str) -> tuple[str, str]:
    return (a, b) if a <= b else (b, a)


def apply_known_distances(pairs: Sequence[PairDistance],
                          known: Sequence[tuple[str, str, float]]
                          ) -> tuple[list[PairDistance], list[tuple[str, str, float]]]:
    """Set the truth of the pairs named in ``known`` (overriding any ground truth).

    Args:
        pairs: from :func:`pairwise_distances`.
        known: ``(a, b, metres)`` entries, order of a and b free.

    Returns:
        ``(pairs with truth, the known entries that match no measured pair)``.
    """
    table = {_pair_key(a, b): float(m) for a, b, m in known}
    out = []
    for p in pairs:
        m = table.pop(_pair_key(p.a, p.b), None)
        if m is not None:
            err = 1000.0 * (p.mean_m - m) if p.frames else math.nan
            p = replace(p, truth_m=m, error_mm=err, truth_source="known")
        out.append(p)
    unmatched = [(a, b, m) for a, b, m in known if _pair_key(a, b) in table]
    return out, unmatched


def target_stats(tracks: Mapping[str, np.ndarray],
                 truth: Mapping[str, np.ndarray] | None = None) -> list[TargetStats]:
    """Per target: frames located and the position error against the truth (RMS, max)."""
    ids, P = _tracks(tracks, "tracks")
    out = []
    for i, k in enumerate(ids):
        located = int(np.all(np.isfinite(P[i]), axis=1).sum())
        t = None if truth is None else truth.get(k)
        if t is None:
            out.append(TargetStats(k, located))
            continue
        e = np.linalg.norm(P[i] - np.asarray(t, dtype=np.float64), axis=1)
        e = e[np.isfinite(e)]
        out.append(TargetStats(k, located, int(e.size),
                               1000.0 * float(np.sqrt(np.mean(e ** 2))) if e.size else math.nan,
                               1000.0 * float(e.max()) if e.size else math.nan))
    return out


def match_truth(positions: Mapping[str, np.ndarray], truth_points: np.ndarray, *,
                max_distance_m: float = math.inf) -> dict[str, int]:
    """Which true target each located target is: the assignment (each truth used at most
    once) that minimises the sum of distances between the targets' positions and the true
    points (Hungarian method), pairs farther apart than ``max_distance_m`` left out.

    Args:
        positions: target id -> a representative position (e.g. the median over frames),
            shape (3,); ids with a non-finite position are left out.
        truth_points: the true targets, shape (K, 3).
        max_distance_m: largest accepted distance of a match.

    Returns:
        target id -> index into ``truth_points``.
    """
    T = np.asarray(truth_points, dtype=np.float64).reshape(-1, 3)
    ids = [k for k, v in positions.items() if np.all(np.isfinite(np.asarray(v, float)))]
    if not ids or T.shape[0] == 0:
        return {}
    P = np.array([np.asarray(positions[k], dtype=np.float64).reshape(3) for k in ids])
    cost = np.linalg.norm(P[:, None, :] - T[None, :, :], axis=2)
    rows, cols = min_cost_assignment(cost)
    return {ids[r]: int(c) for r, c in zip(rows, cols, strict=True)
            if cost[r, c] <= max_distance_m}


def distance_table(pairs: Sequence[PairDistance],
                   targets: Sequence[TargetStats] = ()) -> list[str]:
    """The pairs (and per-target figures) as lines of a fixed-width text table."""
    def f(v: float, fmt: str) -> str:
        return format(v, fmt) if math.isfinite(v) else "-"

    width = max([len(p.a) + len(p.b) + 3 for p in pairs] + [4])
    lines = [f"{'pair':<{width}} {'frames':>6} {'mean (m)':>10} {'std (mm)':>9} "
             f"{'truth (m)':>10} {'error (mm)':>10}  truth"]
    for p in pairs:
        lines.append(f"{p.a + ' - ' + p.b:<{width}} {p.frames:>6d} {f(p.mean_m, '.6f'):>10} "
                     f"{f(1000.0 * p.std_m, '.3f'):>9} {f(p.truth_m, '.6f'):>10} "
                     f"{f(p.error_mm, '+.3f'):>10}  {p.truth_source or '-'}")
    if targets:
        tw = max([len(t.id) for t in targets] + [6])
        lines.append(f"{'target':<{tw}} {'located':>7} {'RMS (mm)':>9} {'max (mm)':>9}")
        for t in targets:
            lines.append(f"{t.id:<{tw}} {t.located:>7d} {f(t.rms_mm, '.3f'):>9} "
                         f"{f(t.max_mm, '.3f'):>9}")
    return lines
