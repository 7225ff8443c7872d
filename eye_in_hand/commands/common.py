"""Helpers shared by several ``eye-in-hand`` commands (each command is a module of its own and
imports only this one of its siblings)."""
from __future__ import annotations

import dataclasses
import math

from eye_in_hand.errors import InputError

__all__ = ["apply_overrides"]


def apply_overrides(config, *, radius: float | None = None, method: str | None = None):
    """The locator config with ``--radius`` (first target, metres) and ``--method`` applied.

    Raises:
        InputError: a radius that is not a positive number.
    """
    if radius is not None:
        if not (math.isfinite(radius) and radius > 0):
            raise InputError(f"--radius: must be a positive number of metres, got {radius}")
        targets = list(config.detector.targets)
        targets[0] = dataclasses.replace(targets[0], radius_m=float(radius))
        config = dataclasses.replace(
            config, detector=dataclasses.replace(config.detector, targets=tuple(targets)))
    if method is not None:
        config = dataclasses.replace(config, method=method)
    return config
