"""The ``main()`` of a node: init, spin, clean shutdown on Ctrl-C, one-line start-up errors."""
from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["run_node"]


def run_node(name: str, factory: Callable[[], Any], args: Sequence[str] | None = None) -> None:
    """Run one node until Ctrl-C or shutdown (the STYLE.md ``main`` pattern).

    Sets the large-data DDS profile (:mod:`eye_in_hand.ros.dds`), initialises rclpy, builds the
    node with ``factory()`` and spins it. Ctrl-C and external shutdown end it cleanly; an
    :class:`~eye_in_hand.errors.EyeInHandError` while building it (a bad parameter or
    calibration file) is printed as ``<name>: error: ...`` and exits with code 1.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from eye_in_hand.errors import EyeInHandError
    from eye_in_hand.ros.dds import use_large_data_profile

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
