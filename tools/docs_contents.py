"""Rewrite the contents list at the top of every docs/ page from its ``##`` headings.

Usage: ``.venv/bin/python tools/docs_contents.py`` (``--check``: exit 1 if a list is out of date,
as ``test/test_docs.py`` does).
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs"


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading."""
    h = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return h.replace(" ", "-")


def headings(text: str) -> list[str]:
    out, fence = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fence = not fence
        elif not fence and line.startswith("## "):
            out.append(line[3:].strip())
    return out


def with_contents(text: str) -> str:
    """The page with its ``Contents:`` block (after the title) rebuilt from its headings."""
    items = "".join(f"- [{h}](#{anchor(h)})\n" for h in headings(text))
    block = f"Contents:\n\n{items}\n"
    if re.search(r"^Contents:\n\n(?:- .*\n)*\n?", text, re.M):
        return re.sub(r"^Contents:\n\n(?:- .*\n)*\n?", lambda _m: block, text, count=1,
                      flags=re.M)
    title, _, rest = text.partition("\n")
    return f"{title}\n\n{block}{rest.lstrip(chr(10))}"


def main(argv: list[str]) -> int:
    stale = []
    for page in sorted(DOCS.glob("*.md")):
        text = page.read_text()
        new = with_contents(text)
        if new != text:
            stale.append(page.name)
            if "--check" not in argv:
                page.write_text(new)
    if stale:
        print(("out of date: " if "--check" in argv else "rewrote: ") + ", ".join(stale))
    return 1 if stale and "--check" in argv else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
