"""Slow work off a node's executor: jobs on worker threads, their results taken on the executor.

A service that detects a board, solves a calibration or draws an image must not block the
executor (images, robot poses and diagnostics keep flowing, and other services are answered).
:class:`WorkerHandoff` runs each job on a named single-thread pool (jobs of one pool queue
behind each other, those of two pools do not wait for each other) and hands its result back
to the executor's thread through a guard condition, where the node may touch its state,
publishers and futures.
"""
from __future__ import annotations

import queue
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

__all__ = ["WorkerHandoff"]


class WorkerHandoff:
    """Named single-thread pools whose jobs finish on the node's executor thread.

    Args:
        node: the rclpy node (its guard condition wakes the executor).
        pools: pool name -> its thread's name prefix.
    """

    def __init__(self, node: Any, pools: Mapping[str, str]) -> None:
        #: the pools by name (one worker thread each)
        self.pools = {name: ThreadPoolExecutor(1, thread_name_prefix=prefix)
                      for name, prefix in pools.items()}
        self._done: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._wake = node.create_guard_condition(self._run_done)

    def _run_done(self) -> None:
        """Guard-condition callback (executor thread): finish what the workers did."""
        while True:
            try:
                fn = self._done.get_nowait()
            except queue.Empty:
                return
            fn()

    def submit(self, pool: str, job: Callable[[], Any],
               then: Callable[[Any, BaseException | None], None] | None = None) -> None:
        """Run ``job`` on the worker thread of ``pool``, then ``then(result, error)`` on the
        executor thread (``then`` None: ``job`` handles its own errors and result)."""
        if then is None:
            self.pools[pool].submit(job)
            return
        done = then

        def run() -> None:
            try:
                res, err = job(), None
            except BaseException as exc:  # noqa: BLE001 - handed to the executor thread
                res, err = None, exc
            self._done.put(lambda: done(res, err))
            self._wake.trigger()

        self.pools[pool].submit(run)

    def shutdown(self) -> None:
        """Stop every pool: queued jobs are dropped, a running one finishes on its own."""
        for pool in self.pools.values():
            pool.shutdown(wait=False, cancel_futures=True)
