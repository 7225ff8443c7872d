"""Comparing a doc's quote of a command's output with what the command prints today.

A quoted line matches a printed line when it has the same words and its numbers agree: counts
exactly, other figures within a relative tolerance or one unit of the quote's last digit;
``...`` in a quote stands for text left out. Used by test_demo.py (the README's demo block,
bags/README.md) and test_docs_examples.py (the runnable examples of docs/).
"""
from __future__ import annotations

import re

_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[+-]?\d+)?")


def _skeleton(line: str) -> str:
    return " ".join(_NUMBER.sub("#", line).split())


def _pairs(quote: str, line: str) -> list[tuple[str, str]] | None:
    """The (quoted, printed) number pairs when ``line`` has the words of ``quote``, whose
    ``...`` stand for any text; None when it has not."""
    skel, nums = _skeleton(line), _NUMBER.findall(line)
    pos, pairs = 0, []
    segments = quote.split("...")
    for k, segment in enumerate(segments):
        want = _skeleton(segment)
        if not want:
            continue
        at = skel.find(want, pos)
        if at < 0 or (k == 0 and at != 0):
            return None
        first = skel[:at].count("#")
        found = _NUMBER.findall(segment)
        pairs += list(zip(found, nums[first:first + len(found)], strict=False))
        pos = at + len(want)
    if segments[-1].strip() and pos != len(skel):
        return None       # not abridged at the end: the whole line
    return pairs


def _close(quoted: str, printed: str, rel: float) -> bool:
    """Counts equal; other figures within ``rel``, or one unit of the quote's last digit."""
    if re.fullmatch(r"-?\d+", quoted):
        return quoted == printed
    unit = 10.0 ** -len(quoted.split(".")[1].split("e")[0]) if "." in quoted else 1.0
    return abs(float(printed) - float(quoted)) <= max(rel * abs(float(quoted)), unit)


def quote_problem(quote: str, output: list[str], rel: float = 0.05) -> str | None:
    """Why ``quote`` (a line of a doc; ``...`` stands for text left out) is not a line of
    ``output``: None when an output line has the same words and its numbers are within
    ``rel`` (or one unit of the quote's last digit). The run time (``demo finished in N s``)
    is machine-dependent and not compared; the live figures are compared with the offline
    ones, which the demo checks they equal (a busy machine may lose a live frame)."""
    quote = quote.strip()
    if quote.startswith("live:"):
        quote = "offline:" + quote[len("live:"):]
    timing = quote.startswith("demo finished in")
    best = None
    for line in output:
        pairs = _pairs(quote, line.strip())
        if pairs is None:
            continue
        bad = [(q, g) for q, g in pairs if not timing and not _close(q, g, rel)]
        if not bad:
            return None
        best = f"{quote!r}: the command prints {line.strip()!r} (quoted vs printed: {bad})"
    return best or f"{quote!r}: no such line in the demo's output"
