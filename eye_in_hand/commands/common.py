"""Helpers shared by several ``eye-in-hand`` commands (each command is a module of its own and
imports only this one of its siblings)."""
from __future__ import annotations

import argparse
import dataclasses
import math

from eye_in_hand.errors import InputError

__all__ = ["apply_overrides", "check_range", "bounded", "MAX_WORKERS"]

#: Upper bound of ``--workers`` (processes locating stereo pairs): more never helps on any
#: machine the package targets, and each one costs about 100 MB of memory.
MAX_WORKERS = 64


def _fmt(x: float) -> str:
    """A range bound as written in the docs: an integral value in full, else ``%g``."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def check_range(flag: str, value, lo: float, hi: float, unit: str = "", *,
                lo_open: bool = False, integer: bool = False):
    """``value`` if it is a finite number within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``).

    The documented range of a numeric flag, checked before any work: a value outside it (or
    NaN, or infinity) is refused with one line that names the flag, the range and the value.

    Raises:
        InputError: ``--flag: must be within [lo, hi] unit, got value``.
    """
    if value is None:
        return value
    ok = isinstance(value, (int, float)) and math.isfinite(value) and (
        (value > lo) if lo_open else (value >= lo)) and value <= hi
    if ok and integer and int(value) != value:
        ok = False
    if not ok:
        left = "(" if lo_open else "["
        suffix = f" {unit}" if unit else ""
        raise InputError(f"{flag}: must be {'an integer ' if integer else ''}within "
                         f"{left}{_fmt(lo)}, {_fmt(hi)}]{suffix}, got {value}")
    return value


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


def bounded(lo: float, hi: float, unit: str = "", *, integer: bool = False,
            lo_open: bool = False):
    """An argparse ``type=`` that accepts a number within ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``; an integer with ``integer``) and refuses anything else (NaN, infinity, a
    word) at once, so the command line says ``argument --flag: must be within ...`` before
    any work starts."""
    def parse(text: str):
        try:
            value = int(text, 10) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected {'an integer' if integer else 'a number'}, got {text!r}") from None
        try:
            check_range("", value, lo, hi, unit, lo_open=lo_open, integer=integer)
        except InputError as exc:
            text_range = str(exc)[2:].rsplit(", got ", 1)[0]
            raise argparse.ArgumentTypeError(f"{text_range}, got {text}") from None
        return value

    parse.__name__ = "bounded"
    parse.range_text = (  # type: ignore[attr-defined]
        f"{'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}]" + (f" {unit}" if unit else "")
        + (", integer" if integer else ""))
    return parse
