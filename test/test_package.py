"""Package-level tests: ament metadata, declared dependencies, a real ``colcon build``, and the
CLI's command list.

The dependency tests parse every Python file of the package, the launch file, the tests and
the benchmarks, and fail on any third-party import not declared in setup.py and package.xml.

The colcon test copies the package sources into a temporary workspace and builds it with the
colcon of the venv (colcon-common-extensions, no network, no ROS install), as a user would on a
ROS 2 machine, then checks the install tree ``ros2 run`` relies on.
"""
from __future__ import annotations

import ast
import os
import re
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
    "launch", "launch_ros", "ament_index_python", "tf2_msgs", "python3-rosbags-pip",
    "python3-lz4",
}
#: Every third-party Python import that is not a ROS package: import name -> (PyPI
#: distribution declared in setup.py, rosdep key declared in package.xml). An import missing
#: here fails test_every_import_is_declared until it is added and declared.
THIRD_PARTY: dict[str, tuple[str, str]] = {
    "numpy": ("numpy", "python3-numpy"),
    "scipy": ("scipy", "python3-scipy"),
    "cv2": ("opencv-python-headless", "python3-opencv"),
    "yaml": ("pyyaml", "python3-yaml"),
    "matplotlib": ("matplotlib", "python3-matplotlib"),
    "tqdm": ("tqdm", "python3-tqdm"),
    "rosbags": ("rosbags", "python3-rosbags-pip"),
    "lz4": ("lz4", "python3-lz4"),
    "zstandard": ("zstandard", "python3-zstandard"),
    # No rosdep key of its own: rosdep's pip install of the newest rosbags brings it.
    "backports.zstd": ("backports.zstd", "python3-rosbags-pip"),
    "pytest": ("pytest", "python3-pytest"),
    "catkin_pkg": ("catkin_pkg", "python3-catkin-pkg"),
}
#: Namespace packages: their distributions are named by the first two parts of the import.
NAMESPACE_PACKAGES = {"backports"}
#: ROS packages the code imports besides the interface packages (``*_msgs``, ``*_srvs``,
#: ``*_interfaces``): their rosdep key is their name; pip gets rclpy and the interfaces
#: from the ``ros`` extra, launch and launch_ros only come with a ROS install.
ROS_PACKAGES = {"rclpy", "launch", "launch_ros", "ament_index_python"}
#: Standard-library modules newer than the oldest supported Python (compression.zstd: 3.14;
#: the code falls back to backports.zstd before it).
NEWER_STDLIB = {"compression"}
#: Where imports are scanned: runtime code, then code that only tests and benchmarks run.
RUNTIME_DIRS = ("eye_in_hand", "launch")
TEST_DIRS = ("test", "benchmarks")

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


def _literal_call_arg(node: ast.Call) -> str | None:
    """``"name"`` of ``pytest.importorskip("name")`` / ``importlib.import_module("name")``."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
    if name in ("importorskip", "import_module") and node.args and isinstance(
            node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
        return node.args[0].value
    return None


def scan_imports(paths: list[Path], root: Path = ROOT) -> dict[str, str]:
    """Every absolute import in ``paths`` (anywhere: module level, functions, try blocks, and
    ``importorskip``/``import_module`` of a literal name) -> the first file importing it.

    Namespace packages (:data:`NAMESPACE_PACKAGES`) keep two parts (``backports.zstd``),
    everything else its top-level name.
    """
    found: dict[str, str] = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
                if node.module in NAMESPACE_PACKAGES:
                    names = [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Call):
                name = _literal_call_arg(node)
                names = [name] if name else []
            for name in names:
                parts = name.split(".")
                key = ".".join(parts[:2]) if parts[0] in NAMESPACE_PACKAGES else parts[0]
                found.setdefault(key, str(path.relative_to(root)))
    return found


def _python_files(dirs: tuple[str, ...]) -> list[Path]:
    return sorted(p for d in dirs for p in (ROOT / d).rglob("*.py"))


#: Names the sources import from themselves (the package; test helpers via conftest; a
#: benchmark script from another, run from their folder: ``from bench_localization import``).
FIRST_PARTY = {PACKAGE, *TEST_DIRS, "conftest",
               *(p.stem for p in (ROOT / "benchmarks").glob("bench_*.py"))}


def _is_ros_package(name: str) -> bool:
    return name in ROS_PACKAGES or name.endswith(("_msgs", "_srvs", "_interfaces"))


def _normalize(dist: str) -> str:
    return re.sub(r"[-_.]+", "-", dist).lower()


def setup_requirements() -> tuple[dict[str, str], dict[str, dict[str, str]]]:
    """``install_requires`` and ``extras_require`` of setup.py, read without running it, as
    {normalized distribution: requirement text}."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, "id", "") == "setup")
    kw = {k.arg: k.value for k in call.keywords}

    def by_name(reqs: list[str]) -> dict[str, str]:
        return {_normalize(re.match(r"[A-Za-z0-9._-]+", r).group(0)): r for r in reqs}

    extras = ast.literal_eval(kw["extras_require"]) if "extras_require" in kw else {}
    return (by_name(ast.literal_eval(kw["install_requires"])),
            {extra: by_name(reqs) for extra, reqs in extras.items()})


def check_declared(runtime: dict[str, str], tests: dict[str, str],
                   first_party: set[str]) -> list[str]:
    """What is imported but not declared, one line per problem (empty: all declared)."""
    root = package_xml()
    exec_depends = {e.text for e in root.findall("exec_depend")} | {
        e.text for e in root.findall("depend")}
    test_depends = exec_depends | {e.text for e in root.findall("test_depend")}
    install, extras = setup_requirements()
    test_reqs = install | extras.get("test", {}) | extras.get("ros", {})
    stdlib = set(sys.stdlib_module_names) | NEWER_STDLIB
    problems = []
    for imports, is_runtime in ((runtime, True), (tests, False)):
        for name, where in sorted(imports.items()):
            if name.split(".")[0] in stdlib or name.split(".")[0] in first_party:
                continue
            keys = exec_depends if is_runtime else test_depends
            xml_tag = "exec_depend" if is_runtime else "test_depend (or exec_depend)"
            if _is_ros_package(name):
                if name not in keys:
                    problems.append(f"{name} (imported in {where}): package.xml lacks "
                                    f"<{xml_tag}>{name}</...>")
                continue
            if name not in THIRD_PARTY:
                problems.append(f"{name} (imported in {where}): unknown third-party import; "
                                f"add it to THIRD_PARTY and declare it in setup.py and "
                                f"package.xml")
                continue
            dist, key = THIRD_PARTY[name]
            reqs = install if is_runtime else test_reqs
            if _normalize(dist) not in reqs:
                where_in_setup = "install_requires" if is_runtime else (
                    "install_requires or extras_require['test']")
                problems.append(f"{name} (imported in {where}): setup.py {where_in_setup} "
                                f"lacks {dist}")
            if key not in keys:
                problems.append(f"{name} (imported in {where}): package.xml lacks "
                                f"<{xml_tag}>{key}</...>")
    return problems


def test_every_import_is_declared():
    """Each third-party import of the package, its launch file, tests and benchmarks is
    declared: runtime ones in setup.py install_requires and as package.xml exec_depend, test
    ones in the test extra (or install_requires) and as test_depend (or exec_depend).

    A missing one works in the venv but breaks ``pip install``, or ``rosdep install`` +
    ``ros2 run`` on a robot.
    """
    runtime_files, test_files = _python_files(RUNTIME_DIRS), _python_files(TEST_DIRS)
    assert any(p.name.endswith(".launch.py") for p in runtime_files)
    runtime, tests = scan_imports(runtime_files), scan_imports(test_files)
    assert {"rclpy", "rosbags", "lz4", "backports.zstd", "launch_ros"} <= set(runtime)
    problems = check_declared(runtime, tests, FIRST_PARTY)
    assert not problems, "undeclared imports:\n" + "\n".join(problems)


def test_scan_finds_imports_in_functions_and_flags_undeclared_ones(tmp_path):
    """The scan sees imports nested in functions and try blocks, and an import that is not
    declared (or not known at all) is reported."""
    src = tmp_path / "mod.py"
    src.write_text("def f():\n    try:\n        from backports import zstd\n"
                   "    except ImportError:\n        import lz4.frame\n"
                   "    import requests\n    pytest.importorskip('catkin_pkg.package')\n")
    names = set(scan_imports([src], tmp_path))
    assert {"backports.zstd", "lz4", "requests", "catkin_pkg"} <= names
    problems = check_declared({n: "mod.py" for n in names}, {}, set())
    assert any(p.startswith("requests ") and "unknown third-party" in p for p in problems)
    assert any(p.startswith("catkin_pkg ") and "install_requires lacks" in p
               for p in problems), problems  # a test-only dependency imported at run time
    assert not any(p.startswith(("lz4 ", "backports.zstd ")) for p in problems), problems


def test_third_party_table_names_the_installed_distributions():
    """THIRD_PARTY maps each import to the distribution that really provides it."""
    import importlib.metadata

    provided = importlib.metadata.packages_distributions()
    for name, (dist, _key) in THIRD_PARTY.items():
        top = name.split(".")[0]
        if top not in provided:
            continue  # not installed here (e.g. catkin_pkg without colcon)
        assert _normalize(dist) in {_normalize(d) for d in provided[top]}, (
            f"{name} is provided by {provided[top]}, not {dist}")


def test_runtime_minimums_are_the_pinned_min_versions():
    """Each install_requires has a ``>=`` minimum equal to its pin in
    .ci/min-constraints.txt, where ``make test-min-deps`` runs the bag tests."""
    install, _extras = setup_requirements()
    pins = {}
    for line in (ROOT / ".ci" / "min-constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            pins[_normalize(name)] = version.strip()
    for dist, req in install.items():
        match = re.search(r">=\s*([0-9][0-9a-zA-Z.]*)", req)
        assert match, f"setup.py: {req!r} has no minimum version"
        assert pins.get(dist) == match.group(1), (
            f"setup.py {req!r} but .ci/min-constraints.txt pins {pins.get(dist)!r}")
    assert set(pins) == set(install), "min-constraints.txt pins what install_requires lists"


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


def test_ros2_run_finds_the_cli_in_the_sourced_workspace(colcon_install):
    """What ``ros2 run eye_in_hand eye-in-hand --help`` does after ``colcon build`` and
    ``source install/setup.bash``: find the package prefix in the ament index, run
    ``<prefix>/lib/eye_in_hand/eye-in-hand``, importing eye_in_hand from the install tree."""
    bash = shutil.which("bash")
    if bash is None:
        pytest.skip("bash is not installed")
    setup = colcon_install / "setup.bash"
    assert setup.is_file(), sorted(p.name for p in colcon_install.iterdir())
    script = f"""set -e
. "{setup}"
prefix=$("{sys.executable}" -c "from ament_index_python.packages import get_package_prefix
print(get_package_prefix('{PACKAGE}'))")
echo "prefix=$prefix"
"$prefix/lib/{PACKAGE}/eye-in-hand" --help
"{sys.executable}" -c "import {PACKAGE}; print('module=' + {PACKAGE}.__file__)"
"""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH",
                        "CMAKE_PREFIX_PATH")}
    proc = subprocess.run([bash, "-c", script], env=env, cwd=colcon_install,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert f"prefix={colcon_install / PACKAGE}" in lines
    assert "usage: eye-in-hand" in proc.stdout
    module = next(line for line in lines if line.startswith("module="))[len("module="):]
    assert Path(module).is_relative_to(colcon_install), module


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
    """``eye-in-hand --help`` stays fast: no command module, rclpy, OpenCV, SciPy or matplotlib
    loads; one command's line imports that command's module and no other command's."""
    code = ("import sys\n"
            "from eye_in_hand.cli import build_parser\n"
            "build_parser(sys.argv[1:])\n"
            "heavy = ('rclpy', 'cv2', 'scipy', 'matplotlib')\n"
            "print(' '.join(m for m in sorted(sys.modules) if m.startswith(heavy)\n"
            "               or m.startswith('eye_in_hand.commands.')))\n")

    def loaded(*argv: str) -> set[str]:
        proc = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True,
                              text=True, timeout=60, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr
        return {m.split(".")[0] if not m.startswith("eye_in_hand") else m
                for m in proc.stdout.split()}

    shared = {"eye_in_hand.commands.common"}
    assert loaded("--help") <= shared, "imported at --help time"
    assert loaded("calibrate", "--help") <= shared, "imported at calibrate --help time"
    assert loaded("bag", "info", "x.mcap") == shared | {"eye_in_hand.commands.bag_info"}
    got = loaded("--debug", "calibrate", "plan", "--help")
    assert "eye_in_hand.commands.calibrate_plan" in got
    assert not {m for m in got if m.startswith("eye_in_hand.commands.")} - shared - {
        "eye_in_hand.commands.calibrate_plan", "eye_in_hand.commands.calibration_inputs"}


def test_a_command_run_reads_no_other_commands_source(monkeypatch):
    """The other commands' help lines are read only when a help that lists them can print."""
    from eye_in_hand import cli

    read: list[str] = []
    monkeypatch.setattr(cli, "_help_line", lambda m: read.append(m) or m)
    cli.build_parser(["bag", "info", "x.mcap"])
    cli.build_parser(["calibrate", "plan", "--help"])
    assert read == []
    cli.build_parser(["calibrate", "-h", "plan"])
    assert "eye_in_hand.commands.calibrate_camera" in read


def test_every_command_is_listed_without_importing_it():
    """The help line of a command that is not on the command line comes from its module's
    source (a literal ``HELP``), and is the module's ``HELP``."""
    import importlib

    from eye_in_hand.cli import COMMANDS, _help_line

    for _words, module_name in COMMANDS:
        assert _help_line(module_name) == importlib.import_module(module_name).HELP


def test_rviz_config_shows_the_topics_the_nodes_publish():
    """config/eye_in_hand.rviz is YAML and every topic it shows is one a node publishes."""
    import yaml

    root = Path(__file__).resolve().parents[1]
    cfg = yaml.safe_load((root / "config" / "eye_in_hand.rviz").read_text())
    topics = [d["Topic"]["Value"] for d in cfg["Visualization Manager"]["Displays"]
              if "Topic" in d]
    assert topics
    sources = {
        "/target/markers": "eye_in_hand/nodes/hand_eye_targets.py",
        "/target/poses": "eye_in_hand/nodes/hand_eye_targets.py",
        "/hand_eye/next_pose_markers": "eye_in_hand/nodes/hand_eye_calibration_outputs.py",
        "/hand_eye/next_poses": "eye_in_hand/nodes/hand_eye_calibration_outputs.py",
        "/hand_eye/debug_image": "eye_in_hand/nodes/hand_eye_calibration_outputs.py",
        "/target/debug_image": "eye_in_hand/nodes/detect_triangulate_outputs.py",
    }
    for topic in topics:
        assert topic in sources, topic
        name = topic.split("/", 2)[2] if topic.startswith("/hand_eye/") else topic[1:]
        text = (root / sources[topic]).read_text()
        assert f'"{name}"' in text or f'"~/{name}"' in text, (topic, sources[topic])
