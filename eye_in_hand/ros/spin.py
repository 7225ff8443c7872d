"""Deadline-bounded spinning: wait for a condition instead of sleeping."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from eye_in_hand.ros.executor import LeanExecutor

__all__ = ["spin_until", "spin_node"]


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


def spin_node(node: Any, keep_going: Callable[[], bool], end: Callable[[], None], *,
              executor: Any | None = None, start: Callable[[], None] | None = None,
              duration_s: float = 0.0) -> None:
    """Spin one node while ``keep_going()`` and its context is ok (and, with ``duration_s`` >
    0, until that much time passed), in 0.1 s steps; ``start()`` runs after the node joined
    the executor, ``end()`` after it left, whatever ended the spin (Ctrl-C, an error).

    Without ``executor`` the node spins on a :class:`~eye_in_hand.ros.executor.LeanExecutor`
    of its context, shut down before the context goes (a garbage-collected executor can crash
    rclpy).
    """
    own = executor is None
    if executor is None:
        executor = LeanExecutor(context=node.context)
    deadline = time.monotonic() + duration_s if duration_s > 0 else None
    executor.add_node(node)
    try:
        if start is not None:
            start()
        while keep_going() and node.context.ok():
            step = 0.1
            if deadline is not None:
                step = min(step, deadline - time.monotonic())
                if step <= 0:
                    break
            executor.spin_once(timeout_sec=step)
    finally:
        executor.remove_node(node)
        end()
        if own:
            executor.shutdown()
