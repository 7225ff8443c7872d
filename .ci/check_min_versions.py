"""Check that this interpreter has exactly the versions pinned in a constraints file.

Usage: python .ci/check_min_versions.py .ci/min-constraints.txt
Prints one line per pin; exits 1 if any installed version differs (or is missing), so that
`make test-min-deps` cannot silently test newer versions than the declared minimums.
"""
from __future__ import annotations

import importlib.metadata
import sys
from pathlib import Path


def main(path: str) -> int:
    bad = 0
    for line in Path(path).read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, _, pinned = (part.strip() for part in line.partition("=="))
        try:
            installed = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            installed = "missing"
        ok = installed == pinned
        bad += not ok
        print(f"{'ok ' if ok else 'BAD'} {name}: pinned {pinned}, installed {installed}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
