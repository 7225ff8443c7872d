"""Deadline-bounded spinning: wait for a condition instead of sleeping."""
from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["spin_until"]


def spin_until(executor, condition: Callable[[], bool], timeout_s: float,
               *, step_s: float = 0.01) -> bool:
    """Spin ``executor`` until ``condition()`` is true or ``timeout_s`` passes.

    Args:
        executor: an rclpy executor with the nodes under test added.
        condition: checked before every spin step.
        timeout_s: deadline in seconds (wall clock).
        step_s: the timeout of each ``spin_once`` call.

    Returns:
        True when the condition became true, False on timeout.
    """
    deadline = time.monotonic() + timeout_s
    while not condition():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        executor.spin_once(timeout_sec=min(step_s, remaining))
    return True
