"""The ``main()`` of a node: init, spin, clean shutdown on Ctrl-C, one-line errors.

Every node's ``main`` runs under :func:`guard`: an :class:`~eye_in_hand.errors.EyeInHandError`
is ``<node>: error: ...`` (exit 1), an ``RCLError`` from rcl (a bad ``--ros-args`` value or
parameter file) ``<node>: error: rcl: ...`` (exit 1), and any other exception ``<node>: internal
error: ...`` (exit 70); ``--debug`` among the node's own arguments or ``EYE_IN_HAND_DEBUG=1``
shows the traceback instead."""
from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException

from eye_in_hand.errors import (
    EXIT_UNEXPECTED,
    EyeInHandError,
    debug_enabled,
    unexpected_error_line,
)
from eye_in_hand.memory import reuse_large_buffers
from eye_in_hand.ros.dds import use_large_data_profile
from eye_in_hand.ros.executor import LeanExecutor
from eye_in_hand.ros.params import refuse_undeclared_overrides

__all__ = ["guard", "prepare_process", "run_node", "run_with_executor", "sigterm_as_interrupt"]


def _own_args(args: Sequence[str] | None) -> list[str]:
    argv = list(sys.argv[1:] if args is None else args)
    return argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv


def guard(name: str, body: Callable[[], Any], args: Sequence[str] | None = None) -> int:
    """Run ``body()`` and return its exit code (``None`` is 0), turning every exception into
    one line on stderr and an exit code: 1 for an ``EyeInHandError`` or an rcl error, 70 for
    anything else. With ``--debug`` in ``args`` (before ``--ros-args``) or ``EYE_IN_HAND_DEBUG``
    set, an unexpected exception propagates with its traceback."""
    try:
        code = body()
        return int(code or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except KeyboardInterrupt:
        return 0
    except EyeInHandError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr, flush=True)
        return 1
    except Exception as exc:  # noqa: BLE001 - the top-level guard of a node process
        if debug_enabled(_own_args(args)):
            raise
        if type(exc).__module__.startswith("rclpy") and "RCL" in type(exc).__name__:
            reason = " ".join(str(exc).split())
            print(f"{name}: error: rcl: {reason}", file=sys.stderr, flush=True)
            return 1
        print(unexpected_error_line(name, exc), file=sys.stderr, flush=True)
        return EXIT_UNEXPECTED


def prepare_process() -> None:
    """What every node process sets before rclpy starts: the large-data Fast DDS profile
    (:mod:`eye_in_hand.ros.dds`) and image-sized memory blocks reused instead of mapped afresh
    for each frame (:mod:`eye_in_hand.memory`)."""
    use_large_data_profile()
    reuse_large_buffers()


def run_node(name: str, factory: Callable[[], Any], args: Sequence[str] | None = None) -> None:
    """Run one node until Ctrl-C or shutdown (the STYLE.md ``main`` pattern).

    Prepares the process (:func:`prepare_process`), initialises rclpy, builds the
    node with ``factory()`` and spins it on a :class:`~eye_in_hand.ros.executor.LeanExecutor`
    (rclpy's single-threaded semantics, a cheaper wake-up). Ctrl-C and external shutdown end
    it cleanly; an :class:`~eye_in_hand.errors.EyeInHandError` while building it (a bad
    parameter or calibration file) is printed as ``<name>: error: ...`` and exits with code 1;
    any other exception is one line as well (:func:`guard`).
    """
    def spin(node: Any, executor: Any) -> int:
        rclpy.spin(node, executor)
        return 0

    def body() -> int:
        prepare_process()
        return run_with_executor(factory, spin, args)

    code = guard(name, body, args)
    if code:
        raise SystemExit(code)


def run_with_executor(factory: Callable[[], Any], spin: Callable[[Any, Any], int],
                      args: Sequence[str] | None = None) -> int:
    """Initialise rclpy, build a :class:`~eye_in_hand.ros.executor.LeanExecutor` and then the
    node, and return
    ``spin(node, executor)``; Ctrl-C and external shutdown return 0. The node, the executor
    and the context are always shut down. Errors propagate (callers print them their way).

    The executor is built first: an rclpy executor interrupted in its constructor spews on exit.
    """
    rclpy.init(args=None if args is None else list(args))
    node = None
    executor = None
    try:
        executor = LeanExecutor()
        node = factory()
        refuse_undeclared_overrides(node, args)
        return spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        if executor is not None:
            executor.shutdown()
        rclpy.try_shutdown()


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def sigterm_as_interrupt() -> None:
    """Make SIGTERM stop the process like Ctrl-C (a ``KeyboardInterrupt``), so that ``finally``
    blocks run and the bag is closed. Call before ``rclpy.init`` (rclpy chains to this handler;
    without it, rclpy passes SIGTERM on to the default action, which kills the process)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupt)
