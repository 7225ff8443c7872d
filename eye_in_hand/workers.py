"""Worker processes for CPU-bound work that holds the GIL: a small, explicit process pool.

``multiprocessing`` start methods that are safe in a process with threads (``spawn``,
``forkserver``) re-import the caller's ``__main__`` in every child, which breaks scripts
without an ``if __name__ == "__main__"`` guard, and ``fork`` is unsafe once threads (OpenCV's,
DDS's) exist. These workers are plain ``python -m eye_in_hand.workers`` subprocesses instead:
they import only the function they run, talk to the parent over their stdin/stdout with
length-prefixed pickles, ignore Ctrl-C (the parent decides) and exit when their stdin closes.

Usage::

    pool = ProcessPool(2, "eye_in_hand.offline:_worker_init", (rig, config))
    fut = pool.submit("eye_in_hand.offline:_worker_locate", stamp, left, right)
    ...
    pool.close()

``submit`` returns a :class:`concurrent.futures.Future`; a worker that dies fails its pending
futures with :class:`WorkerError` (naming its exit code) and takes no more work.
"""
from __future__ import annotations

import importlib
import os
import pickle
import struct
import subprocess
import sys
import threading
from concurrent.futures import Future
from pathlib import Path
from typing import Any, BinaryIO

__all__ = ["WorkerError", "ProcessPool"]

_LEN = struct.Struct("<Q")


class WorkerError(RuntimeError):
    """A worker process died, or a task raised (the message carries its traceback)."""


def _send(stream: BinaryIO, obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LEN.pack(len(data)) + data)
    stream.flush()


def _recv(stream: BinaryIO) -> Any:
    head = stream.read(_LEN.size)
    if len(head) < _LEN.size:
        raise EOFError
    (n,) = _LEN.unpack(head)
    data = stream.read(n)
    if len(data) < n:
        raise EOFError
    return pickle.loads(data)


def _resolve(name: str) -> Any:
    module, _, attr = name.partition(":")
    return getattr(importlib.import_module(module), attr)


class _Worker:
    def __init__(self, init: str, init_args: tuple[Any, ...], env: dict[str, str]) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "eye_in_hand.workers"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self.pending: dict[int, Future[Any]] = {}
        self.ready = threading.Event()
        self.dead = False
        self.lock = threading.Lock()
        assert self.proc.stdin is not None
        _send(self.proc.stdin, ("init", init, init_args))
        self.reader = threading.Thread(target=self._read, name=f"worker-{self.proc.pid}",
                                       daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        try:
            while True:
                kind, task, payload = _recv(self.proc.stdout)
                if kind == "ready":
                    self.ready.set()
                    continue
                with self.lock:
                    fut = self.pending.pop(task, None)
                if fut is None:
                    continue
                if kind == "result":
                    fut.set_result(payload)
                else:
                    fut.set_exception(WorkerError(payload))
        except (EOFError, OSError, pickle.UnpicklingError):
            pass
        code = self.proc.wait()
        with self.lock:
            self.dead = True
            pending, self.pending = self.pending, {}
        for fut in pending.values():
            fut.set_exception(WorkerError(f"worker process {self.proc.pid} exited with code "
                                          f"{code} before finishing its task"))
        self.ready.set()  # wake anyone waiting for a worker that will never be ready

    def submit(self, task: int, fn: str, args: tuple[Any, ...]) -> Future[Any]:
        fut: Future[Any] = Future()
        with self.lock:
            if self.dead:
                raise WorkerError(f"worker process {self.proc.pid} has exited")
            self.pending[task] = fut
            assert self.proc.stdin is not None
            try:
                _send(self.proc.stdin, ("call", task, (fn, args)))
            except (BrokenPipeError, OSError) as exc:
                self.pending.pop(task, None)
                raise WorkerError(f"worker process {self.proc.pid}: {exc}") from exc
        return fut

    def close(self) -> None:
        try:
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.reader.join(timeout=10)


class ProcessPool:
    """``n`` worker processes, each initialised by ``init(*init_args)`` (``"module:function"``),
    with ``env`` added to this process's environment.

    Processes start at once and become usable after importing and initialising (typically a
    few tenths of a second); :meth:`ready` says whether one is. ``init_args`` and every task's
    arguments and result must pickle.
    """

    def __init__(self, n: int, init: str, init_args: tuple[Any, ...] = (),
                 env: dict[str, str] | None = None) -> None:
        env = {**os.environ, **(env or {})}
        root = str(Path(__file__).resolve().parent.parent)   # this package, wherever it is
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        self._workers = [_Worker(init, init_args, env) for _ in range(max(1, n))]
        self._next = 0

    def ready(self) -> bool:
        """Whether at least one worker is initialised and alive."""
        return any(w.ready.is_set() and not w.dead for w in self._workers)

    def alive(self) -> bool:
        return any(not w.dead for w in self._workers)

    def submit(self, fn: str, *args: Any) -> Future[Any]:
        """Run ``fn(*args)`` (``"module:function"``) on the least busy ready worker.

        Raises:
            WorkerError: no worker is ready and alive.
        """
        live = [w for w in self._workers if w.ready.is_set() and not w.dead]
        if not live:
            raise WorkerError("no worker process is ready")
        worker = min(live, key=lambda w: len(w.pending))
        self._next += 1
        return worker.submit(self._next, fn, args)

    def close(self) -> None:
        """Close the workers' stdin (they exit) and wait for them."""
        for w in self._workers:
            w.close()

    def __enter__(self) -> ProcessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve() -> int:
    """The worker's loop: init, then calls until stdin closes."""
    import signal
    import traceback

    signal.signal(signal.SIGINT, signal.SIG_IGN)    # the parent handles Ctrl-C and closes us
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr                         # stray prints must not corrupt the channel
    try:
        kind, init, init_args = _recv(stdin)
    except EOFError:
        return 0
    _resolve(init)(*init_args)
    _send(stdout, ("ready", 0, os.getpid()))
    while True:
        try:
            _kind, task, (fn, args) = _recv(stdin)
        except EOFError:
            return 0
        try:
            result = _resolve(fn)(*args)
        except Exception:  # noqa: BLE001 - handed to the parent with its traceback
            _send(stdout, ("error", task, traceback.format_exc()))
            continue
        _send(stdout, ("result", task, result))


if __name__ == "__main__":
    sys.exit(_serve())
