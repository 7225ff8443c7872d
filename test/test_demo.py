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


def test_demo_runs_every_step_and_meets_its_figures(tmp_path: Path, ros_env) -> None:
    out = tmp_path / "demo_out"
    proc = subprocess.run([sys.executable, "-m", "eye_in_hand.demo", "--out", str(out)],
                          cwd=ROOT, env=ros_env, text=True, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, timeout=300)
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
    assert int(m.group(1)) == 14 and int(m.group(2)) >= 12 * rows["live"][0]

