"""eye-in-hand launch: supervised node processes, prefixed output, Ctrl-C, a dying node."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.launcher import NODES, node_command

import numpy as np


def _params(tmp_path, hand_eye_file):
    text = (f"/**/hand_eye:\n  ros__parameters:\n    hand_eye_file: {hand_eye_file}\n"
            "/**/detect_triangulate:\n  ros__parameters:\n    method: dlt\n")
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def _launch(params, env, *extra):
    return subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--params",
                             str(params), "--skip", "stereo_capture", *extra], env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def test_node_commands_put_topics_where_the_bags_have_them():
    cmds = {n.name: " ".join(node_command(n, "p.yaml")) for n in NODES}
    assert "__ns:=/stereo" in cmds["detect_triangulate"]
    assert "target/point:=/target/point" in cmds["detect_triangulate"]
    assert "ee_pose:=/ee_pose" in cmds["stereo_capture"]
    assert "__ns:=/ " in cmds["hand_eye"] + " "
    ns = " ".join(node_command(NODES[1], "p.yaml", root_namespace="/robot1"))
    assert "__ns:=/robot1/stereo" in ns and "target/point:=/robot1/target/point" in ns


def test_a_node_that_dies_stops_the_launch_with_its_name(tmp_path, ros_env):
    proc = _launch(_params(tmp_path, tmp_path / "missing.yaml"), ros_env)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1, out
    assert "[hand_eye]" in out and "missing.yaml" in out
    assert "hand_eye exited with code" in out


def test_ctrl_c_stops_every_node_cleanly(tmp_path, ros_env):
    he = tmp_path / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration("eye_in_hand", "tool0", "camera_left_optical_frame",
                                         np.eye(4)))
    proc = _launch(_params(tmp_path, he), ros_env)
    lines = []
    deadline = time.monotonic() + 60
    assert proc.stdout is not None
    while time.monotonic() < deadline:                 # wait until both nodes report started
        line = proc.stdout.readline()
        lines.append(line)
        text = "".join(lines)
        if "[hand_eye]" in text and "started" in text and "[detect_triangulate]" in text \
                and "detecting" in text:
            break
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, "".join(lines) + rest
