"""The README's five-minute tour runs as written, in order, from a fresh folder.

The tour's fenced block is taken from README.md as it is and run by bash, command by command
(``set -e``: the first failing command fails the test), in an empty folder that sees the
repository's ``bags/`` and ``config/`` (the tour's inputs), with ``eye-in-hand`` on ``PATH``
and DDS kept on this machine on a domain of its own. Background jobs (``launch``, ``echo``) are
stopped at the end. Then what the tour promises is checked: the calibrations, every live
target pose, the offline results.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parent.parent


def tour_block() -> str:
    """The first fenced block under the README's tour heading."""
    text = (ROOT / "README.md").read_text()
    m = re.search(r"^## A five-minute tour\n(.*?)^## ", text, re.M | re.S)
    assert m, "README.md has no '## A five-minute tour' section"
    block = re.search(r"^```[^\n]*\n(.*?)^```", m.group(1), re.M | re.S)
    assert block, "the tour has no fenced block"
    return block.group(1)


def test_the_tour_block_uses_only_the_bundled_inputs_and_its_own_outputs():
    """No placeholder a reader would have to replace (``my_params.yaml``, ``calib_bag``)."""
    block = tour_block()
    for word in ("calib_bag", "loc_bag", "my_params", "<", "..."):
        assert word not in block.replace("<<", ""), f"the tour still has {word!r}"


def test_the_readme_tour_runs_as_written(tmp_path: Path, ros_env: dict[str, str]) -> None:
    for name in ("bags", "config"):
        (tmp_path / name).symlink_to(ROOT / name)
    env = dict(ros_env)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    script = ("set -e\n" + tour_block() +
              "\nsleep 1\nkill -INT $(jobs -p) 2>/dev/null || true\nwait || true\n")
    proc = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=600)
    assert proc.returncode == 0, proc.stdout[-4000:]
    assert (tmp_path / "calib" / "left.yaml").is_file(), proc.stdout[-3000:]
    assert (tmp_path / "handeye" / "hand_eye.yaml").is_file(), proc.stdout[-3000:]
    poses = [d for d in yaml.safe_load_all((tmp_path / "poses.yaml").read_text()) if d]
    assert len(poses) == 45, proc.stdout[-3000:]           # every frame of the bag, live
    assert {p["header"]["frame_id"] for p in poses} == {"base_link"}
    rows = (tmp_path / "results" / "results.csv").read_text().splitlines()
    assert sum(",ok," in r for r in rows) == 45, proc.stdout[-3000:]
