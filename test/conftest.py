"""Test harness shared by the whole suite.

DDS isolation: every pytest run picks its own ``ROS_DOMAIN_ID`` (unless one is set in
``EYE_IN_HAND_TEST_DOMAIN_ID``) and limits discovery to this machine, before rclpy is imported
anywhere; child processes started by tests inherit both through :func:`ros_env`.

In-process ROS tests use the ``ros_context``, ``executor`` and ``namespace`` fixtures and wait
with ``spin_until(executor, cond, timeout_s)``, never with sleeps.
"""
from __future__ import annotations

import os
import random
import uuid
from pathlib import Path

import pytest

_DOMAIN = os.environ.get("EYE_IN_HAND_TEST_DOMAIN_ID") or str(
    random.SystemRandom().randint(1, 100))
os.environ["ROS_DOMAIN_ID"] = _DOMAIN
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
# The package's Fast DDS profile (camera-size images over shared memory) in this process too, as
# every command and node sets it for itself: without it a test that publishes images from here
# had them go over fragmented UDP, where best-effort frames are lost now and then, unless an
# earlier test had run a command in this process (which sets it): a test that passed in the
# whole suite and failed alone
from eye_in_hand.ros.dds import use_large_data_profile  # noqa: E402 - after the domain

use_large_data_profile()

TEST_DIR = Path(__file__).resolve().parent
DATA_DIR = TEST_DIR / "data"


def _have_rclpy() -> bool:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The folder of bundled test data (``test/data``)."""
    return DATA_DIR


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for child processes: same isolated domain, unbuffered output."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = _DOMAIN
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture
def ros_context():
    """A fresh, initialised ``rclpy.Context`` for one test, shut down afterwards."""
    if not _have_rclpy():
        pytest.skip("rclpy is not installed (pip install -e .[ros])")
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def executor(ros_context):
    """The nodes' executor (``LeanExecutor``) on the test's own context; nodes added are
    destroyed after."""
    from eye_in_hand.ros.executor import LeanExecutor

    ex = LeanExecutor(context=ros_context)
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


@pytest.fixture
def namespace() -> str:
    """A unique ROS namespace for one test (``/t_<hex>``)."""
    return f"/t_{uuid.uuid4().hex[:12]}"


@pytest.fixture
def spin_until():
    """``spin_until(executor, condition, timeout_s) -> bool``: see eye_in_hand.ros.spin."""
    from eye_in_hand.ros.spin import spin_until as _spin_until

    return _spin_until
