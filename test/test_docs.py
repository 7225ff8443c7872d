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


#: Pages whose command examples are checked for paths (docs/ and the two READMEs).
EXAMPLE_PAGES = sorted(DOCS.glob("*.md")) + [ROOT / "README.md", ROOT / "bags" / "README.md"]
#: Where the repository's shipped files live (a bare name of one of them is a path mistake).
SHIPPED_DIRS = ("config", "launch", "bags", "benchmarks", "tools", "test/data")
#: Folders that commands write (git-ignored).
GENERATED = {"demo_out", "build", "out", "install", "log", "dist"}


def _example_paths(text: str) -> list[str]:
    """The values of options (``--kinematics world.yaml``) and the scripts given to
    ``python`` in the code of a page (fenced blocks and code spans; continued lines joined)."""
    fences = re.findall(r"^```[^\n]*\n(.*?)^```", text, re.M | re.S)
    prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.M | re.S)
    values: list[str] = []
    for code in fences + re.findall(r"`([^`]+)`", prose):
        code = code.replace("\\\n", " ")
        values += re.findall(r"(?<![\w-])--[a-z][\w-]*[ =]([^\s`'\"|&;)]+)", code)
        values += re.findall(r"python3?\s+([^\s-]\S*\.py)\b", code)
    return [v.rstrip(".,") for v in values]


def _path_problem(value: str, shipped: dict[str, list[str]]) -> str | None:
    """Why ``value`` is a path that fails when the example is run from the repository root:
    under a folder of the repository but missing, or the bare name of a shipped file."""
    if value.startswith(("/", "-", "$", "~")) or "<" in value or "*" in value:
        return None       # absolute, a flag, a variable, a placeholder or a pattern
    top = value.split("/")[0]
    if top in GENERATED:
        return None       # written by a command (git-ignored), absent from a fresh clone
    if "/" in value and (ROOT / top).is_dir() and not top.startswith("."):
        return None if (ROOT / value).exists() else f"{value}: no such file"
    if "/" not in value and value in shipped and not (ROOT / value).exists():
        return f"{value}: not in the repository root; the shipped file is {shipped[value][0]}"
    return None


def _shipped() -> dict[str, list[str]]:
    shipped: dict[str, list[str]] = {}
    for folder in SHIPPED_DIRS:
        for f in sorted((ROOT / folder).rglob("*")):
            if f.is_file():
                shipped.setdefault(f.name, []).append(str(f.relative_to(ROOT)))
    return shipped


def test_path_problem_flags_missing_and_bare_shipped_files() -> None:
    shipped = _shipped()
    assert _example_paths("x\n```\neye-in-hand a --kinematics world.yaml \\\n    --bag b\n```\n"
                          "and `python tools/x.py`") == ["world.yaml", "b", "tools/x.py"]
    assert _path_problem("world.yaml", shipped) is not None
    assert _path_problem("config/world.yaml", shipped) is None
    assert _path_problem("config/wrold.yaml", shipped) is not None
    assert _path_problem("calib_bag", shipped) is None and _path_problem("out/x", shipped) is None


def test_paths_in_command_examples_exist() -> None:
    """An example run from the repository root finds every repository file it names."""
    shipped = _shipped()
    problems = [f"{page.relative_to(ROOT)}: {problem}" for page in EXAMPLE_PAGES
                for value in _example_paths(page.read_text())
                if (problem := _path_problem(value, shipped))]
    assert not problems, "\n".join(problems)
