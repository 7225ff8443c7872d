"""The ``main()`` of a node: init, spin, clean shutdown on Ctrl-C, one-line start-up errors."""
from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from eye_in_hand.errors import EyeInHandError
from eye_in_hand.ros.dds import use_large_data_profile

__all__ = ["run_node", "run_with_executor", "sigterm_as_interrupt"]


def run_node(name: str, factory: Callable[[], Any], args: Sequence[str] | None = None) -> None:
    """Run one node until Ctrl-C or shutdown (the STYLE.md ``main`` pattern).

    Sets the large-data DDS profile (:mod:`eye_in_hand.ros.dds`), initialises rclpy, builds the
    node with ``factory()`` and spins it. Ctrl-C and external shutdown end it cleanly; an
    :class:`~eye_in_hand.errors.EyeInHandError` while building it (a bad parameter or
    calibration file) is printed as ``<name>: error: ...`` and exits with code 1.
    """
    use_large_data_profile()
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except EyeInHandError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr, flush=True)
        raise SystemExit(1) from exc
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def run_with_executor(factory: Callable[[], Any], spin: Callable[[Any, Any], int],
                      args: Sequence[str] | None = None) -> int:
    """Initialise rclpy, build a ``SingleThreadedExecutor`` and then the node, and return
    ``spin(node, executor)``; Ctrl-C and external shutdown return 0. The node, the executor
    and the context are always shut down. Errors propagate (callers print them their way).

    The executor is built first: an rclpy executor interrupted in its constructor spews on exit.
    """
    rclpy.init(args=args)
    node = None
    executor = None
    try:
        executor = SingleThreadedExecutor()
        node = factory()
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
