"""Package-level tests: ament metadata, a real ``colcon build``, and the CLI's command list.

The colcon test copies the package sources into a temporary workspace and builds it with the
colcon of the venv (colcon-common-extensions, no network, no ROS install), as a user would on a
ROS 2 machine, then checks the install tree ``ros2 run`` relies on.
"""
from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "eye_in_hand"

#: exec_depends the issue requires in package.xml.
REQUIRED_EXEC_DEPENDS = {
    "rclpy", "sensor_msgs", "geometry_msgs", "std_msgs", "std_srvs", "diagnostic_msgs",
    "python3-numpy", "python3-scipy", "python3-opencv", "python3-yaml",
}
#: Python imports -> rosdep keys they need in package.xml.
PYTHON_ROSDEP = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "cv2": "python3-opencv",
    "yaml": "python3-yaml", "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm",
}
#: Interface packages every rclpy install brings (rclpy depends on them itself).
PROVIDED_BY_RCLPY = {"builtin_interfaces", "rcl_interfaces", "rosgraph_msgs"}

# What the build needs from the source tree; everything else (tests, venv, caches) stays out.
_IGNORE = shutil.ignore_patterns(".git", ".venv", "build", "install", "log", "test", "docs",
                                 "benchmarks", "__pycache__", "*.egg-info", ".pytest_cache",
                                 ".mypy_cache", ".ruff_cache", "out", "demo_out", "*.pyc")


def node_scripts() -> list[tuple[str, str]]:
    """``NODE_SCRIPTS`` of setup.py as (executable, 'module:function'), read without running it."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "NODE_SCRIPTS" for t in stmt.targets):
            entries = ast.literal_eval(stmt.value)
            return [tuple(part.strip() for part in e.split("=", 1)) for e in entries]
    raise AssertionError("setup.py has no NODE_SCRIPTS list")


def package_xml() -> ET.Element:
    return ET.parse(ROOT / "package.xml").getroot()


# -- metadata ---------------------------------------------------------------------------------
def test_package_xml_format_3_ament_python_and_exec_depends():
    root = package_xml()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    assert root.findtext("export/build_type") == "ament_python"
    for tag in ("version", "description", "maintainer", "license"):
        assert (root.findtext(tag) or "").strip(), f"package.xml lacks <{tag}>"
    exec_depends = {e.text for e in root.findall("exec_depend")} | {
        e.text for e in root.findall("depend")}
    missing = REQUIRED_EXEC_DEPENDS - exec_depends
    assert not missing, f"package.xml lacks exec_depend {sorted(missing)}"
    from eye_in_hand import __version__

    assert root.findtext("version") == __version__


def test_package_xml_is_valid_for_catkin_pkg():
    """catkin_pkg (what colcon and rosdep use) parses and validates the manifest."""
    catkin_pkg = pytest.importorskip("catkin_pkg.package")
    pkg = catkin_pkg.parse_package(str(ROOT / "package.xml"))
    pkg.validate()
    assert pkg.package_format == 3 and pkg.name == PACKAGE


def test_every_imported_dependency_is_declared():
    """Each ROS interface package and system Python library the code imports is an exec_depend.

    A missing one works in the venv but breaks ``rosdep install`` + ``ros2 run`` on a robot.
    """
    imported: dict[str, str] = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                imported.setdefault(name.split(".")[0], str(path.relative_to(ROOT)))
    root = package_xml()
    declared = {e.text for e in root.findall("exec_depend")} | {
        e.text for e in root.findall("depend")}
    needed = {}
    for module, where in imported.items():
        if module == "rclpy" or module.endswith(("_msgs", "_srvs", "_interfaces")):
            if module not in PROVIDED_BY_RCLPY:
                needed[module] = where
        elif module in PYTHON_ROSDEP:
            needed[PYTHON_ROSDEP[module]] = where
    missing = {key: where for key, where in needed.items() if key not in declared}
    assert not missing, "package.xml lacks <exec_depend> for: " + ", ".join(
        f"{key} (imported in {where})" for key, where in sorted(missing.items()))


def test_setup_cfg_and_resource_marker():
    cfg = (ROOT / "setup.cfg").read_text()
    assert "script_dir=$base/lib/eye_in_hand" in cfg.replace(" ", "")
    assert "install_scripts=$base/lib/eye_in_hand" in cfg.replace(" ", "")
    assert (ROOT / "resource" / PACKAGE).is_file()


def test_node_scripts_point_to_main_functions():
    import importlib

    scripts = node_scripts()
    names = [name for name, _ in scripts]
    assert {"bag_player", "bag_recorder"} <= set(names)
    assert len(names) == len(set(names))
    for name, target in scripts:
        module_name, _, func = target.partition(":")
        module = importlib.import_module(module_name)
        assert callable(getattr(module, func, None)), f"{name}: {target} is not callable"


# -- colcon build -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory) -> Path:
    colcon = Path(sys.executable).with_name("colcon")
    if not colcon.exists():
        found = shutil.which("colcon")
        if found is None:
            pytest.skip("colcon is not installed (pip install -e .[test])")
        colcon = Path(found)
    ws = tmp_path_factory.mktemp("colcon_ws")
    shutil.copytree(ROOT, ws / "src" / PACKAGE, ignore=_IGNORE)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["COLCON_HOME"] = str(ws / ".colcon")  # no user configuration or mixins
    env.pop("COLCON_DEFAULTS_FILE", None)
    proc = subprocess.run(
        [str(colcon), "--log-base", str(ws / "log"), "build", "--base-paths", str(ws / "src"),
         "--build-base", str(ws / "build"), "--install-base", str(ws / "install"),
         "--event-handlers", "console_direct-", "console_cohesion+"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"colcon build failed:\n{proc.stdout}\n{proc.stderr}"
    return ws / "install"


def test_colcon_build_installs_node_executables(colcon_install):
    lib = colcon_install / PACKAGE / "lib" / PACKAGE
    expected = {name for name, _ in node_scripts()} | {"eye-in-hand"}
    assert expected <= {p.name for p in lib.iterdir()}, sorted(p.name for p in lib.iterdir())
    for name in expected:
        assert os.access(lib / name, os.X_OK), f"{name} is not executable"
    share = colcon_install / PACKAGE / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    installed_xml = share / PACKAGE / "package.xml"
    assert installed_xml.read_text() == (ROOT / "package.xml").read_text()


def test_colcon_installed_cli_runs_from_the_install_tree(colcon_install):
    site = next((colcon_install / PACKAGE / "lib").glob("python3*/site-packages"))
    assert (site / PACKAGE / "cli.py").is_file()
    env = dict(os.environ, PYTHONPATH=str(site))
    # cwd outside the source tree: ``python -c`` puts the cwd first on sys.path.
    code = "import eye_in_hand; print(eye_in_hand.__file__)"
    probe = subprocess.run([sys.executable, "-c", code],
                           env=env, cwd=colcon_install, capture_output=True, text=True,
                           timeout=60)
    assert probe.returncode == 0, probe.stderr
    assert Path(probe.stdout.strip()).is_relative_to(site)
    exe = colcon_install / PACKAGE / "lib" / PACKAGE / "eye-in-hand"
    proc = subprocess.run([str(exe), "--help"], env=env, cwd=colcon_install,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "usage: eye-in-hand" in proc.stdout


# -- the eye-in-hand command ------------------------------------------------------------------
def _help(argv: list[str], capsys) -> str:
    from eye_in_hand.cli import main

    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0, f"eye-in-hand {' '.join(argv)} --help exited {exc.value.code}"
    return capsys.readouterr().out


def test_help_lists_every_registered_command(capsys):
    from eye_in_hand.cli import COMMANDS, build_parser

    build_parser()  # every command module imports and adds its arguments
    top = _help([], capsys)
    groups: dict[str, list[str]] = {}
    for words, _module in COMMANDS:
        parts = words.split()
        assert 1 <= len(parts) <= 2, words
        assert parts[0] in top, f"'{parts[0]}' missing from eye-in-hand --help"
        if len(parts) == 2:
            groups.setdefault(parts[0], []).append(parts[1])
    for group, subs in groups.items():
        text = _help([group], capsys)
        for sub in subs:
            assert sub in text, f"'{group} {sub}' missing from eye-in-hand {group} --help"
    for words, _module in COMMANDS:
        usage = _help(words.split(), capsys)
        assert f"usage: eye-in-hand {words}" in usage


def test_command_modules_follow_the_contract():
    import importlib

    from eye_in_hand.cli import COMMANDS

    assert len({w for w, _ in COMMANDS}) == len(COMMANDS), "a command is registered twice"
    for _words, module_name in COMMANDS:
        module = importlib.import_module(module_name)
        assert isinstance(module.HELP, str) and module.HELP.strip(), f"{module_name}: HELP"
        assert callable(module.add_arguments) and callable(module.run), module_name


def test_help_does_not_import_heavy_modules():
    """``eye-in-hand --help`` stays fast: rclpy, OpenCV and matplotlib load only in run()."""
    code = ("import sys\n"
            "from eye_in_hand.cli import build_parser\n"
            "build_parser()\n"
            "print(' '.join(m for m in ('rclpy', 'cv2', 'matplotlib') if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"imported at --help time: {proc.stdout.strip()}"
