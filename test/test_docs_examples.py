"""The runnable examples of docs/ run as written and print what the docs quote.

A fenced block whose info string is ``sh runnable`` is run by bash (``set -e``), the blocks of
one page in order and in one folder that sees the repository's ``bags/`` and ``config/``, with
``eye-in-hand`` on ``PATH``. A ``text output`` block right after it quotes lines of its output
(``...`` leaves text out): each must be printed today, figures within 5 % (counts exactly;
:mod:`quotes`). Examples that need a robot, a camera or minutes stay unmarked.
"""
from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
_FENCE = re.compile(r"^```([^\n]*)\n(.*?)^```", re.M | re.S)


def _quote_problem():
    spec = importlib.util.spec_from_file_location("quotes", Path(__file__).with_name("quotes.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.quote_problem


def examples(text: str) -> list[tuple[str, list[str]]]:
    """``(script, quoted output lines)`` of every runnable block of a page, in order."""
    blocks = [(m.group(1).split(), m.group(2)) for m in _FENCE.finditer(text)]
    out = []
    for k, (info, body) in enumerate(blocks):
        if info[:2] != ["sh", "runnable"]:
            continue
        quoted: list[str] = []
        if k + 1 < len(blocks) and blocks[k + 1][0][:2] == ["text", "output"]:
            quoted = [line for line in blocks[k + 1][1].splitlines() if line.strip()]
        out.append((body, quoted))
    return out


PAGES = sorted(p.name for p in DOCS.glob("*.md") if examples(p.read_text()))


def test_some_pages_have_runnable_examples():
    assert len(PAGES) >= 2, PAGES


def test_examples_are_found_with_their_quotes():
    text = "```sh runnable\necho a 1\n```\n\n```text output\na 1\n```\n```\nnot run\n```\n"
    assert examples(text) == [("echo a 1\n", ["a 1"])]


@pytest.mark.parametrize("page", PAGES)
def test_runnable_examples_of_a_page(page: str, tmp_path: Path, ros_env: dict[str, str]):
    for name in ("bags", "config"):
        (tmp_path / name).symlink_to(ROOT / name)
    env = dict(ros_env)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    quote_problem = _quote_problem()
    for k, (script, quoted) in enumerate(examples((DOCS / page).read_text())):
        proc = subprocess.run(["bash", "-c", "set -e\n" + script], cwd=tmp_path, env=env,
                              text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              timeout=300)
        where = f"{page}, runnable example {k + 1}"
        assert proc.returncode == 0, f"{where} failed:\n{script}\n{proc.stdout[-3000:]}"
        lines = proc.stdout.replace(str(tmp_path) + "/", "").splitlines()
        problems = [p for q in quoted if (p := quote_problem(q, lines))]
        assert not problems, f"{where}:\n" + "\n".join(problems)
