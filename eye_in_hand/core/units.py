"""Plausibility of values with units: the hint for a length given in millimetres."""
from __future__ import annotations

import math

__all__ = ["unit_hint"]


def unit_hint(name: str, value: float, high: float | None) -> str:
    """For a length parameter (its name ends in ``_m``) above its largest plausible value
    ``high`` whose value in millimetres would fit: `` (metres: for 20 mm write 0.02)``, else
    ``""``. A radius of 20 written for 20 mm is 20 m; the range alone does not say why."""
    if high is None or not name.endswith("_m") or not isinstance(value, (int, float)):
        return ""
    if not (math.isfinite(value) and value > high and value / 1000.0 <= high):
        return ""
    return f" (it is in metres: for {value:g} mm write {value / 1000.0:g})"
