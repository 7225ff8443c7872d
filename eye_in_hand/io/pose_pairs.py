"""Hand-eye pose-pair files (no images).

A JSON list of ``[base_T_ee, cam_T_board]`` pairs, each a 4x4 row-major nested list, metres
(the format of MoveIt Calibration's test data).
"""
from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from eye_in_hand.core.transforms import as_transform
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.io.atomic import atomic_write_text

__all__ = ["load_pose_pairs", "save_pose_pairs"]


def load_pose_pairs(path: str | os.PathLike[str]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Read a pose-pairs JSON file: a list of ``[base_T_ee, cam_T_board]`` 4x4 pairs.

    Args:
        path: the JSON file.

    Returns:
        ``[(base_T_ee (4, 4), cam_T_board (4, 4)), ...]``.

    Raises:
        ConfigError: missing file, bad JSON, a pair with other than two matrices, or a matrix
            of the wrong shape, with NaN or a non-orthonormal rotation (naming the pair index).
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{p}: pose-pairs file not found") from exc
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{p}: cannot read pose pairs ({exc})") from exc
    if not isinstance(data, list) or not data:
        raise ConfigError(f"{p}: expected a non-empty JSON list of [base_T_ee, cam_T_board] pairs")
    out = []
    for i, pair in enumerate(data):
        if not isinstance(pair, list) or len(pair) != 2:
            n = len(pair) if isinstance(pair, list) else type(pair).__name__
            raise ConfigError(f"{p}: pair {i}: expected [base_T_ee, cam_T_board], got {n} "
                              "entries")
        mats = []
        for name, M in zip(("base_T_ee", "cam_T_board"), pair, strict=True):
            try:
                mats.append(as_transform(np.asarray(M, dtype=np.float64), name))
            except (InputError, ValueError, TypeError) as exc:
                raise ConfigError(f"{p}: pair {i}: {exc}") from exc
        out.append((mats[0], mats[1]))
    return out


def save_pose_pairs(path: str | os.PathLike[str],
                    pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> Path:
    """Write pose pairs in the format :func:`load_pose_pairs` reads."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(p, json.dumps([[np.asarray(a).tolist(), np.asarray(b).tolist()]
                                     for a, b in pairs]))
    return p
