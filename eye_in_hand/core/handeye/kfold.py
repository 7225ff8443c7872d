"""K-fold held-out prediction of a hand-eye calibration: how well X predicts views it was not
fitted on.

The samples are split into ``k`` folds (sample ``i`` is in fold ``i % k``). For every fold
each method is fitted on the other folds and predicts the held-out samples from their *reported*
robot poses:

* **base frame** (mm): the board's corners in the fixed frame (the robot base, eye-in-hand) as
  the held-out sample sees them, ``G_i X cam_T_board[i]``, against the fitted board pose ``Y``;
  the RMS over the corners of the 3-d distance;
* **image** (px): the corners projected from ``Y`` through ``inv(G_i)`` and ``inv(X)`` into the
  held-out image, against the detected corners; the RMS over the corners of the pixel error.

These are the two errors a calibration makes where it is used: a point seen by the camera put
into the base frame, and a base-frame point projected into the image. There is no ground truth
on a real robot; these figures are what can be measured.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from eye_in_hand.core.transforms import average_transforms
from eye_in_hand.errors import HandEyeError

from .refine import reprojection_errors
from .samples import CameraView, HandEyeSample
from .solvers import board_in_fixed_frame, gripper_poses, motion_pairs

__all__ = ["ViewError", "FoldResult", "fold_indices", "predict_view", "classic_fit",
           "kfold_held_out", "rms"]


@dataclass(frozen=True)
class ViewError:
    """One held-out sample's prediction error by one method.

    Attributes:
        name: the sample.
        mm: corner errors in the fixed frame, metres converted to mm, shape (M,).
        px: corner pixel errors (norm), shape (M,); empty without corners.
    """

    name: str
    mm: np.ndarray
    px: np.ndarray


@dataclass
class FoldResult:
    """One fold: what each method predicted of the held-out samples.

    Attributes:
        held_out: names of the held-out samples.
        errors: by method, one :class:`ViewError` per held-out sample.
        selected: the method the package's selection picked on this fold's fit ('' if not run).
        warnings: the calibration's warnings on this fold's fit.
        extra: anything else the caller records (e.g. the covariance check).
    """

    held_out: list[str]
    errors: dict[str, list[ViewError]] = field(default_factory=dict)
    selected: str = ""
    warnings: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)


def rms(values: Sequence[np.ndarray]) -> float:
    """RMS over all entries of a list of arrays (NaN when empty)."""
    a = np.concatenate([np.ravel(v) for v in values]) if values else np.zeros(0)
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def fold_indices(n: int, k: int) -> list[np.ndarray]:
    """The held-out indices of each of ``k`` folds over ``n`` samples (``i % k``).

    Raises:
        HandEyeError: ``k`` below 2 or above ``n``.
    """
    if not 2 <= k <= n:
        raise HandEyeError(f"k-fold: need 2 <= k <= number of samples ({n}), got k={k}")
    return [np.arange(f, n, k) for f in range(k)]


def predict_view(X: np.ndarray, Y: np.ndarray, sample: HandEyeSample,
                 cameras: Sequence[CameraView] | None, setup: str) -> ViewError:
    """Prediction error of one held-out sample by ``(X, Y)`` (see the module docstring).

    Without corner observations the board's origin stands for its corners.
    """
    Yi = board_in_fixed_frame(X, sample.base_T_ee[None], sample.cam_T_board[None], setup)[0]
    obj = (sample.observations[0].object_points if sample.observations else np.zeros((1, 3)))
    seen = obj @ Yi[:3, :3].T + Yi[:3, 3]
    pred = obj @ Y[:3, :3].T + Y[:3, 3]
    mm = 1000.0 * np.linalg.norm(seen - pred, axis=1)
    px = np.zeros(0)
    if cameras and sample.observations:
        e = reprojection_errors(X, Y, [sample], cameras, setup)[0]
        px = np.linalg.norm(e, axis=1)
    return ViewError(sample.name, mm, px)


def classic_fit(solver: Callable[[Any], np.ndarray], samples: Sequence[HandEyeSample],
                setup: str) -> tuple[np.ndarray, np.ndarray]:
    """``(X, Y)`` of a closed-form solver: X from the motions, Y the mean board pose."""
    bte = np.stack([s.base_T_ee for s in samples])
    ctb = np.stack([s.cam_T_board for s in samples])
    with np.errstate(all="ignore"):
        X = solver(motion_pairs(gripper_poses(bte, setup), ctb))
    if not np.all(np.isfinite(X)):
        raise HandEyeError("closed form: solution is not finite")
    return X, average_transforms(board_in_fixed_frame(X, bte, ctb, setup))


#: training samples -> ``({method: (X, Y) or (X, Y, correct)}, info)``; ``correct`` maps a
#: reported robot pose (4, 4) to the one X is used with (a robot error model); ``info`` may
#: give ``selected``, ``warnings`` and ``extra`` for the fold's :class:`FoldResult`.
FitFn = Callable[[list[HandEyeSample]], tuple[dict[str, tuple[Any, ...]], dict[str, Any]]]


def kfold_held_out(samples: Sequence[HandEyeSample], fit: FitFn, *, k: int = 6,
                   cameras: Sequence[CameraView] | None = None,
                   setup: str = "eye_in_hand") -> list[FoldResult]:
    """Run ``fit`` on every fold's training samples and score the held-out ones.

    Args:
        samples: all samples.
        fit: see :data:`FitFn`.
        k: number of folds.
        cameras: the rig's cameras (pixel figures).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        One :class:`FoldResult` per fold.
    """
    samples = list(samples)
    out = []
    for idx in fold_indices(len(samples), k):
        held = set(idx.tolist())
        train = [s for i, s in enumerate(samples) if i not in held]
        test = [samples[i] for i in idx]
        fr = FoldResult([s.name for s in test])
        sols, info = fit(train)
        fr.selected = str(info.get("selected", ""))
        fr.warnings = list(info.get("warnings", []))
        fr.extra = dict(info.get("extra", {}))
        for name, sol in sols.items():
            X, Y = sol[0], sol[1]
            correct = sol[2] if len(sol) > 2 else None
            fr.errors[name] = [predict_view(
                X, Y, s if correct is None else replace(s, base_T_ee=correct(s.base_T_ee)),
                cameras, setup) for s in test]
        out.append(fr)
    return out
