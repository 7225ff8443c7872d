"""Short rooms: no function of the package over 80 lines without a reason, and no node module
over 300 lines (docs/architecture.md, "Short rooms").

A function's length counts every line from its ``def`` to its last line, docstring included. A
longer one states why in its docstring, in a paragraph that starts with ``Long because:``.
A node module keeps to the ROS plumbing: its parameters, topics and services, handing each
message to the ROS-free code below it.
"""
from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parent.parent / "eye_in_hand"
MAX_FUNCTION_LINES = 80
MAX_NODE_MODULE_LINES = 300
REASON = "Long because:"


def long_functions(pkg: Path = PKG) -> list[str]:
    """``path:line name (N lines)`` of every function over the limit without a reason."""
    out = []
    for path in sorted(pkg.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            n = (node.end_lineno or node.lineno) - node.lineno + 1
            doc = ast.get_docstring(node) or ""
            if n > MAX_FUNCTION_LINES and REASON not in doc:
                out.append(f"{path.relative_to(pkg.parent)}:{node.lineno} {node.name} "
                           f"({n} lines)")
    return out


def long_node_modules(pkg: Path = PKG) -> list[str]:
    return [f"{p.relative_to(pkg.parent)} ({n} lines)"
            for p in sorted((pkg / "nodes").glob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_NODE_MODULE_LINES]


def test_no_long_function_without_a_reason() -> None:
    assert long_functions() == [], (
        f"functions over {MAX_FUNCTION_LINES} lines: split them, or say why in a "
        f"'{REASON}' paragraph of the docstring")


def test_node_modules_are_short() -> None:
    assert long_node_modules() == [], (
        f"node modules over {MAX_NODE_MODULE_LINES} lines: move what is not ROS plumbing down "
        "a floor (docs/architecture.md)")


def test_the_checks_see_a_long_function(tmp_path: Path) -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "nodes").mkdir()
    (tmp_path / "nodes" / "big.py").write_text("\n" * MAX_NODE_MODULE_LINES + "y = 1\n")
    (tmp_path / "a.py").write_text(f"def f():\n{body}\n\n\ndef g():\n"
                                   f"    '''Short.\n\n    {REASON} a table.'''\n{body}\n")
    assert [s.split(" ", 1)[1] for s in long_functions(tmp_path)] == [
        f"f ({MAX_FUNCTION_LINES + 1} lines)"]
    assert long_node_modules(tmp_path) == [f"{tmp_path.name}/nodes/big.py "
                                           f"({MAX_NODE_MODULE_LINES + 1} lines)"]
