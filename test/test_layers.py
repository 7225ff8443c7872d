"""The package's imports point down the floors of docs/architecture.md and never run in a circle.

Floors, top to bottom (a module may import from its own room or from a lower floor)::

    4  cli, demo, commands.*
    3  nodes.*, offline, launcher
    2  ros.*, io.*, sim.*, report.*, workers
    1  core.*
    0  yamlfile, memory, threads, the package itself
   -1  errors

Every import counts: one inside a function, a relative one (``from .x import y``, resolved
against the importing module's package) and one under ``if TYPE_CHECKING:`` (an annotation
that names a higher floor is an arrow up, and closes a circle as any other import would).
Two rooms of one floor may not import each other's modules,
except where listed (a piece two rooms share moves down a floor); each command and each node is
a room of its own: commands share only ``commands.common`` and ``commands.calibration_inputs``
(and the floors below), nodes share nothing but the floors below (``nodes.localize``, which
composes detect_triangulate and hand_eye in one process, builds both). A node split into
parts keeps them in its room (``NODE_PARTS``): ``nodes.hand_eye_targets`` belongs to
``nodes.hand_eye``.
"""
from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parent.parent / "eye_in_hand"

FLOORS = {
    "cli": 4, "demo": 4, "commands": 4,
    "nodes": 3, "offline": 3, "launcher": 3,
    "ros": 2, "io": 2, "sim": 2, "report": 2, "workers": 2,
    "core": 1,
    "yamlfile": 0, "memory": 0, "threads": 0, "": 0, "errors": -1,
}
#: rooms of one floor that may import from another room of that floor: (importer, imported)
SAME_FLOOR_ALLOWED = {("sim", "io"), ("io", "ros"), ("sim", "ros"), ("report", "io"),
                      # the composed chain builds the two nodes it joins, as the launcher does
                      ("nodes.localize", "nodes.detect_triangulate"),
                      ("nodes.localize", "nodes.hand_eye"), ("nodes.localize", "launcher")}
#: modules of ``commands`` that every command may import
SHARED_COMMANDS = {"commands.common", "commands.calibration_inputs"}
#: modules of ``nodes`` that are parts of one node: part -> the node's module (its room)
NODE_PARTS = {
    "nodes.hand_eye_targets": "nodes.hand_eye",
    "nodes.hand_eye_tf": "nodes.hand_eye",
    "nodes.hand_eye_calibration": "nodes.hand_eye",
    "nodes.detect_triangulate_params": "nodes.detect_triangulate",
    "nodes.detect_triangulate_inputs": "nodes.detect_triangulate",
    "nodes.detect_triangulate_outputs": "nodes.detect_triangulate",
    "nodes.stereo_capture_params": "nodes.stereo_capture",
    "nodes.stereo_capture_sim": "nodes.stereo_capture",
    "nodes.bag_player_config": "nodes.bag_player",
    "nodes.bag_player_pacing": "nodes.bag_player",
    "nodes.bag_player_topics": "nodes.bag_player",
    "nodes.bag_recorder_writer": "nodes.bag_recorder",
    "nodes.hand_eye_calibration_files": "nodes.hand_eye",
    "nodes.hand_eye_calibration_outputs": "nodes.hand_eye",
    "nodes.hand_eye_calibration_services": "nodes.hand_eye",
    "nodes.hand_eye_first_target": "nodes.hand_eye",
    "nodes.hand_eye_params": "nodes.hand_eye",
    "nodes.hand_eye_poses": "nodes.hand_eye",
}


def _module(path: Path, pkg: Path = PKG) -> str:
    parts = list(path.relative_to(pkg.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _absolute(node: ast.ImportFrom, mod: str, is_package: bool) -> str:
    """The absolute module name of ``from <node.module> import ...`` written in ``mod``."""
    if node.level == 0:
        return node.module or ""
    package = mod.split(".") if is_package else mod.split(".")[:-1]
    base = package[:len(package) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(pkg: Path = PKG) -> dict[str, set[str]]:
    """module -> the package's modules it imports (every import, see the module docstring)."""
    modules = {_module(p, pkg): p for p in pkg.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for mod, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom):
                base = _absolute(node, mod, path.name == "__init__.py")
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                # the longest known module the name refers to (from a import b: b may be one)
                while name and name not in modules:
                    name = name.rpartition(".")[0]
                if name.startswith(pkg.name) and name != mod:
                    graph[mod].add(name)
    return graph


def _room(module: str) -> tuple[str, str]:
    """(floor key, room) of ``eye_in_hand.x.y``: commands and nodes are a room per module."""
    parts = module.split(".")[1:]
    top = parts[0] if parts else ""
    if top in ("commands", "nodes") and len(parts) > 1:
        room = ".".join(parts[:2])
        return top, NODE_PARTS.get(room, room)
    return top, top


def test_every_import_points_down_or_stays_in_its_room() -> None:
    bad = []
    for mod, targets in _imports().items():
        top, room = _room(mod)
        for target in targets:
            ttop, troom = _room(target)
            if troom == room or (troom in SHARED_COMMANDS and top == "commands") or (
                    troom == "commands.common" and top in ("cli", "demo")):
                continue
            f, tf = FLOORS[top], FLOORS[ttop]
            if tf < f or (tf == f and ((top, ttop) in SAME_FLOOR_ALLOWED
                                       or (room, troom) in SAME_FLOOR_ALLOWED)):
                continue
            bad.append(f"{mod} -> {target}")
    assert not bad, "imports against the floors: " + "; ".join(sorted(bad))


def test_no_import_circles() -> None:
    graph = _imports()
    cycles: list[list[str]] = []
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    # a package importing its own submodules (re-exports) is not a circle of ideas
    real = [c for c in cycles if not all(c[0].startswith(x) or x.startswith(c[0]) for x in c)]
    assert not real, "import circles: " + "; ".join(" -> ".join(c) for c in real)


def test_relative_and_type_checking_imports_count(tmp_path: Path) -> None:
    """A relative import and one under ``if TYPE_CHECKING:`` are arrows like any other."""
    pkg = tmp_path / "eye_in_hand"
    (pkg / "core").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "__init__.py").write_text("from . import a\n")
    (pkg / "core" / "a.py").write_text(
        "from typing import TYPE_CHECKING\nfrom .b import f\nif TYPE_CHECKING:\n"
        "    from ..offline import Options\n")
    (pkg / "core" / "b.py").write_text("from .. import errors\n")
    (pkg / "errors.py").write_text("")
    (pkg / "offline.py").write_text("from .core.a import g\n")
    graph = _imports(pkg)
    assert graph["eye_in_hand.core"] == {"eye_in_hand.core.a"}
    assert graph["eye_in_hand.core.a"] == {"eye_in_hand.core.b", "eye_in_hand.offline"}
    assert graph["eye_in_hand.core.b"] == {"eye_in_hand", "eye_in_hand.errors"}
    assert graph["eye_in_hand.offline"] == {"eye_in_hand.core.a"}
