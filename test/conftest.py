"""Test harness shared by the whole suite.

DDS isolation: every pytest run picks its own ``ROS_DOMAIN_ID`` (unless one is set in
``EYE_IN_HAND_TEST_DOMAIN_ID``) and limits discovery to this machine, before rclpy is imported
anywhere; child processes started by tests inherit both through :func:`ros_env`.

In-process ROS tests use the ``ros_context``, ``executor`` and ``namespace`` fixtures and wait
with ``spin_until(executor, cond, timeout_s)``, never with sleeps.

Background jobs: a test module that runs a whole command line end to end in a subprocess
(``make demo``, the README's tour) may define ``BACKGROUND_JOB = (name, start)``; when its tests
are collected, ``start(folder, env)`` is called from one background thread, jobs one after
another, while the rest of the suite runs (the second core), and the test takes the result
with the ``background`` fixture (``background(name)`` waits for it). The jobs run on a DDS
domain of their own, so their nodes and the suite's never meet.
"""
from __future__ import annotations

import os
import queue
import random
import shutil
import tempfile
import threading
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

_DOMAIN = os.environ.get("EYE_IN_HAND_TEST_DOMAIN_ID") or str(
    random.SystemRandom().randint(1, 100))
os.environ["ROS_DOMAIN_ID"] = _DOMAIN
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)

#: the background jobs' own domain (with LOCALHOST discovery any id up to 232 is valid)
_JOB_DOMAIN = str(int(_DOMAIN) % 100 + 101)

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
    """A ``SingleThreadedExecutor`` on the test's own context; nodes added are destroyed after."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros_context)
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


class _Background:
    """Runs the collected modules' ``BACKGROUND_JOB``s, one after another, on a thread."""

    def __init__(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="eye_in_hand_jobs_"))
        self.results: dict[str, Any] = {}
        self.done: dict[str, threading.Event] = {}
        self._queue: queue.Queue[tuple[str, Callable[..., Any]] | None] = queue.Queue()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def submit(self, name: str, start: Callable[..., Any]) -> None:
        if name not in self.done:
            self.done[name] = threading.Event()
            self._queue.put((name, start))

    def _run(self) -> None:
        while (job := self._queue.get()) is not None:
            name, start = job
            env = dict(os.environ, ROS_DOMAIN_ID=_JOB_DOMAIN, PYTHONUNBUFFERED="1",
                       ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
            folder = self.folder / name
            folder.mkdir()
            try:
                self.results[name] = start(folder, env)
            except BaseException as exc:  # noqa: BLE001 - handed to the test that asks
                self.results[name] = exc
            self.done[name].set()

    def result(self, name: str, timeout_s: float = 900.0) -> Any:
        assert name in self.done, f"background job {name!r} was not started"
        assert self.done[name].wait(timeout_s), f"background job {name!r} did not finish"
        result = self.results[name]
        if isinstance(result, BaseException):
            raise result
        return result

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=5)
        shutil.rmtree(self.folder, ignore_errors=True)


_JOBS: _Background | None = None


@pytest.hookimpl(trylast=True)          # after -k / -m deselection
def pytest_collection_modifyitems(session, config, items) -> None:
    """Start the background jobs of the modules whose tests were collected."""
    global _JOBS
    seen = set()
    for item in items:
        module = getattr(item, "module", None)
        job = getattr(module, "BACKGROUND_JOB", None)
        if job is None or module in seen or not _have_rclpy():
            continue
        seen.add(module)
        if _JOBS is None:
            _JOBS = _Background()
        _JOBS.submit(*job)


def pytest_sessionfinish(session, exitstatus) -> None:
    if _JOBS is not None:
        _JOBS.close()


@pytest.fixture(scope="session")
def background() -> Callable[[str], Any]:
    """``background(name)``: the result of a module's ``BACKGROUND_JOB`` (waits for it)."""
    def result(name: str) -> Any:
        if _JOBS is None:
            pytest.fail(f"background job {name!r} was not started (is rclpy installed?)")
        return _JOBS.result(name)

    return result

