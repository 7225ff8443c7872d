"""``make demo`` end to end on the bundled bags: every step runs and the figures it prints hold.

The demo is the first thing a user runs; this checks what it promises: both calibrations from
the calibration bag, the live path over DDS and the offline path on the localization bag, the
base-frame error against the bag's ground truth, and live and offline agreeing frame by frame.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    """One ``make demo`` run (``python -m eye_in_hand.demo``), shared by the tests below."""
    import os

    out = tmp_path_factory.mktemp("demo") / "demo_out"
    env = dict(os.environ, PYTHONUNBUFFERED="1")   # conftest set the isolated DDS domain
    proc = subprocess.run([sys.executable, "-m", "eye_in_hand.demo", "-o", str(out)],
                          cwd=ROOT, env=env, text=True, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, timeout=300)
    return proc, out


def test_demo_runs_every_step_and_meets_its_figures(demo) -> None:
    from eye_in_hand.demo import OUTPUT_TOPICS

    proc, out = demo
    text = proc.stdout
    assert proc.returncode == 0, text[-3000:]
    for step in range(1, 6):
        assert f"== {step}/5" in text, text[-3000:]
    assert (out / "calibration").is_dir() and (out / "hand_eye" / "hand_eye.yaml").is_file()
    assert (out / "processed" / "results.csv").is_file()

    # hand-eye against the true mount (the bag's ground truth)
    m = re.search(r"hand-eye \((\w+)\): ([\d.]+) mm, ([\d.]+) deg from the true mount", text)
    assert m, text[-3000:]
    assert float(m.group(2)) < 2.0 and float(m.group(3)) < 0.2

    # live and offline: frames and base-frame error (target: RMS <= 2 mm)
    rows = {}
    for name in ("live", "offline"):
        m = re.search(rf"^{name}: +(\d+)/(\d+) frames, RMS ([\d.]+) mm", text, re.M)
        assert m, text[-3000:]
        rows[name] = (int(m.group(1)), int(m.group(2)), float(m.group(3)))
    got, total, rms = rows["offline"]
    assert got == total and rms <= 2.0
    got, total, rms = rows["live"]
    assert got == total and rms <= 2.0       # nothing lost, also on a busy machine

    m = re.search(r"live vs offline: (\d+) frames in both, largest difference ([\d.e+-]+) m", text)
    assert m and int(m.group(1)) == rows["live"][0] and float(m.group(2)) <= 1e-6

    # offline = live: the output bag of process holds the topics and messages the live nodes
    # published (recorded during the live step), frame by frame
    m = re.search(r"live vs offline bags: (\d+) topics, (\d+) messages of those frames: (\w+)",
                  text)
    assert m and m.group(3) == "identical", text[-3000:]
    assert int(m.group(1)) == len(OUTPUT_TOPICS) and int(m.group(2)) >= 12 * rows["live"][0]

# -- the figures the docs quote ----------------------------------------------------------------

#: The pages that quote the demo's output, and how to find the quote: README.md's block under
#: "What `make demo` prints", bags/README.md's "Sanity check" block.
QUOTING_PAGES = {"README.md": "### What `make demo` prints", "bags/README.md": "Sanity check"}


def _quotes():
    """test/quotes.py (the quote comparison shared with test_docs_examples), by path."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("quotes", Path(__file__).with_name("quotes.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


quote_problem = _quotes().quote_problem
def quoted_block(page: str, after: str) -> list[str]:
    """The lines of the first fenced block after the line containing ``after``."""
    text = (ROOT / page).read_text()
    start = text.index(after)
    m = re.search(r"^```[^\n]*\n(.*?)^```", text[start:], re.M | re.S)
    assert m, f"{page}: no code block after {after!r}"
    return [line for line in m.group(1).splitlines() if line.strip()]


def test_quote_problem_compares_words_and_numbers() -> None:
    out = ["hand-eye (kronecker): 0.176 mm, 0.0149 deg from the true mount",
           "  stereo: joint RMS 0.0259 px over 34 pairs (0 image(s) skipped)"]
    assert quote_problem("hand-eye (kronecker): 0.18 mm, 0.015 deg from the true mount",
                         out) is None
    assert quote_problem("hand-eye (kronecker): 0.207 mm, 0.0149 deg from the true mount", out)
    assert quote_problem("hand-eye (refined): 0.176 mm, 0.0149 deg from the true mount", out)
    assert quote_problem("  stereo: joint RMS 0.0259 px over 34 pairs ...", out) is None
    assert quote_problem("  stereo: joint RMS 0.0678 px over 34 pairs ...", out)
    assert quote_problem("stereo: joint RMS ... 34 pairs (0 image(s) skipped)", out) is None
    assert quote_problem("stereo: joint RMS ... 35 pairs (0 image(s) skipped)", out)
    assert quote_problem("stereo: joint RMS 0.0259 px over 34 pairs", out)   # not abridged


@pytest.mark.parametrize("page", sorted(QUOTING_PAGES))
def test_docs_quote_the_demo_as_it_prints(demo, page: str) -> None:
    """README.md and bags/README.md quote the demo's output; every quoted line is printed by
    the demo today, its figures within 5 % (paths as from the repository root)."""
    proc, out = demo
    assert proc.returncode == 0, proc.stdout[-3000:]
    output = proc.stdout.replace(str(out), "demo_out").replace(str(ROOT) + "/", "")
    output_lines = output.splitlines()
    problems = [p for q in quoted_block(page, QUOTING_PAGES[page])
                if (p := quote_problem(q, output_lines))]
    assert not problems, "\n".join(problems)
