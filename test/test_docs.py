"""The manual documents every command option and every node parameter.

Options come from the real argument parser (``eye_in_hand.cli.build_parser``); node parameters
from the nodes themselves: each node class is constructed in-process with default parameters
while ``declare_parameter(s)`` is recorded (a node that then stops for want of a required file
has still declared its parameters). A name counts as documented when a page of ``docs/`` shows
it in code form (`` `--rate` ``, `` `rate` ``, a ``rate:`` line of a YAML example, or a table
cell); the README is the door and does not count.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from eye_in_hand.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
# (module, class, parameter overrides): stereo_capture declares everything up front, then its
# default source would build a simulator (seconds); an images source without files stops at once
NODES = [
    ("eye_in_hand.nodes.bag_player", "BagPlayer", {}),
    ("eye_in_hand.nodes.bag_recorder", "BagRecorder", {}),
    ("eye_in_hand.nodes.detect_triangulate", "DetectTriangulateNode", {}),
    ("eye_in_hand.nodes.hand_eye", "HandEyeNode", {}),
    ("eye_in_hand.nodes.stereo_capture", "StereoCaptureNode", {"source": "images"}),
]


def _docs_code() -> str:
    """Every piece of code in docs/: fenced blocks and inline code spans, one per line."""
    pages = sorted(DOCS.glob("*.md"))
    assert pages, "docs/ has no pages"
    code: list[str] = []
    for page in pages:
        text = page.read_text()
        fences = re.findall(r"^```[^\n]*\n(.*?)^```", text, re.M | re.S)
        code += fences
        prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.M | re.S)
        code += re.findall(r"`([^`]+)`", prose)
    return "\n".join(c.replace("\n", " ") for c in code)


#: Parameters every rclpy node declares itself.
ROS_BUILTIN = {"use_sim_time", "start_type_description_service"}


def _documented(name: str, code: str) -> bool:
    """``name`` as a whole word of the docs' code (e.g. in `-r, --rate R` or a YAML key)."""
    return bool(re.search(rf"(?<![\w.-]){re.escape(name)}(?![\w-])", code))


def _doc_name(name: str) -> str:
    """Per-target parameters are documented once, as ``targets.<name>.key``."""
    parts = name.split(".")
    return f"targets.<name>.{parts[2]}" if len(parts) == 3 and parts[0] == "targets" else name


def _commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, words + (name,))
    if words:
        yield " ".join(words), parser


def test_every_command_option_is_documented() -> None:
    text = _docs_code()
    missing = []
    for command, parser in _commands(build_parser()):
        for action in parser._actions:
            longs = [o for o in action.option_strings if o.startswith("--")]
            if not longs or longs[0] == "--help":
                continue
            if not any(_documented(o, text) for o in action.option_strings):
                missing.append(f"eye-in-hand {command} {longs[0]}")
    assert not missing, "options missing from docs/: " + ", ".join(missing)


def test_every_node_parameter_is_documented(ros_context, namespace) -> None:
    pytest.importorskip("rclpy")
    import importlib

    from rclpy.node import Node
    from rclpy.parameter import Parameter

    declared: dict[str, set[str]] = {}
    original_one, original_many = Node.declare_parameter, Node.declare_parameters

    def one(self, name, *args, **kwargs):
        declared.setdefault(self.get_name(), set()).add(name)
        return original_one(self, name, *args, **kwargs)

    def many(self, namespace_, parameters, *args, **kwargs):
        for p in parameters:
            full = f"{namespace_}.{p[0]}" if namespace_ else p[0]
            declared.setdefault(self.get_name(), set()).add(full)
        return original_many(self, namespace_, parameters, *args, **kwargs)

    Node.declare_parameter, Node.declare_parameters = one, many  # type: ignore[method-assign]
    try:
        for module, cls, overrides in NODES:
            node_cls = getattr(importlib.import_module(module), cls)
            try:
                node = node_cls(context=ros_context, namespace=namespace, parameter_overrides=[
                    Parameter(k, value=v) for k, v in overrides.items()])
            except Exception:  # noqa: BLE001 - a missing required file; declarations are in
                continue
            node.destroy_node()
    finally:
        Node.declare_parameter, Node.declare_parameters = original_one, original_many
    assert len(declared) == len(NODES), sorted(declared)
    text = _docs_code()
    missing = sorted(f"{node}: {name}" for node, names in declared.items() for name in names
                     if name not in ROS_BUILTIN and not _documented(_doc_name(name), text))
    assert not missing, "node parameters missing from docs/: " + ", ".join(missing)


def test_every_page_has_its_contents_list_up_to_date() -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "docs_contents.py"), "--check"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr + (
        " (run: .venv/bin/python tools/docs_contents.py)")
