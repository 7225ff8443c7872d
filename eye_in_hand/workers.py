"""Worker processes for CPU-bound work that holds the GIL: a small, explicit process pool.

``multiprocessing`` start methods that are safe in a process with threads (``spawn``,
``forkserver``) re-import the caller's ``__main__`` in every child, which breaks scripts
without an ``if __name__ == "__main__"`` guard, and ``fork`` is unsafe once threads (OpenCV's,
DDS's) exist. These workers are plain ``python`` subprocesses instead: they import this package
from the same place as the parent (never from their working directory), talk to the parent over
a private copy of their stdout and their stdin with length-prefixed pickles (anything printed to
stdout, also by C code such as OpenCV's logger, goes to stderr), run in their own session so
Ctrl-C is the parent's to handle, and exit when their stdin closes. A worker whose parent died
(killed with SIGKILL) exits quietly, never with a traceback; any other unexpected error in a
worker is one line on its stderr (see :func:`_serve`).

With ``fork=True`` a caller that runs a single thread (:func:`fork_is_safe`, checked by the
kernel's count, C libraries' threads included) forks its workers instead: the same loop and
channel on pipes, the same session, stdout and exit rules, but no interpreter start-up and no
imports (about 0.1 CPU-s and 0.1 s less per worker with numpy and OpenCV). A caller with any
other thread gets fresh interpreters as above.

Usage::

    pool = ProcessPool(2, "eye_in_hand.offline:_worker_init", (rig, config))
    fut = pool.submit("eye_in_hand.offline:_worker_locate", stamp, left, right)
    ...
    pool.close()

or, to start the processes before the initialiser's arguments are known (they import its
module meanwhile)::

    pool = ProcessPool(2, "eye_in_hand.offline:_worker_init", defer_init=True)
    ...                                   # work out rig and config
    pool.initialize(rig, config)

``submit`` returns a :class:`concurrent.futures.Future`; a task that raises fails its future
with :class:`WorkerError` carrying the traceback, and a worker that dies fails its pending
futures with :class:`WorkerError` (naming its exit code) and takes no more work.

Deadline: with ``task_timeout_s``, a worker that owes a result and has given none for that long
(stopped with SIGSTOP, deadlocked, swapping) is killed; its pending futures fail with a
:class:`WorkerError` that says it timed out, so a caller waiting on a result never hangs. The
clock of a task starts when the worker is free to start it (at submission to an idle worker,
or at the previous result).
"""
from __future__ import annotations

import gc
import importlib
import itertools
import os
import pickle
import signal
import struct
import subprocess
import sys
import threading
import time
from concurrent.futures import Future
from pathlib import Path
from typing import IO, Any

from eye_in_hand.errors import EXIT_UNEXPECTED, EyeInHandError

__all__ = ["WorkerError", "ProcessPool"]

_LEN = struct.Struct("<Q")
_MAX_FRAME = 1 << 31          # a larger length prefix is a corrupt channel, not a message


class WorkerError(EyeInHandError, RuntimeError):
    """A worker process died, or a task raised (the message carries its traceback)."""


def _frame(obj: Any) -> bytes:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return _LEN.pack(len(data)) + data


def _recv_bytes(stream: IO[bytes]) -> bytes:
    head = stream.read(_LEN.size)
    if len(head) < _LEN.size:
        raise EOFError
    (n,) = _LEN.unpack(head)
    if n > _MAX_FRAME:
        raise EOFError(f"corrupt channel: frame length {n}")
    data = stream.read(n)
    if len(data) < n:
        raise EOFError
    return data


def _resolve(name: str) -> Any:
    module, _, attr = name.partition(":")
    return getattr(importlib.import_module(module), attr)


#: The child's bootstrap: drop the working directory from sys.path, and use this package's
#: copy when the child's own sys.path would find another one (or none).
_BOOT = """\
import importlib.util, os, sys
root = {root!r}
sys.path.pop(0)
spec = importlib.util.find_spec("eye_in_hand")
if spec is None or os.path.dirname(os.path.dirname(os.path.abspath(spec.origin))) != root:
    sys.path.insert(0, root)
from eye_in_hand.workers import _serve
sys.exit(_serve())
"""


def _spawn(env: dict[str, str], root: str, preload: str) -> subprocess.Popen[bytes]:
    """A worker as a fresh interpreter (``preload``: the module it imports before it waits for
    its init call)."""
    return subprocess.Popen([sys.executable, "-c", _BOOT.format(root=root), preload],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                            start_new_session=True)


def fork_is_safe() -> bool:
    """Whether this process may start workers with ``fork``: on Linux, while it runs one
    thread (``/proc/self/task``: also the threads of C libraries, OpenCV's pool, OpenBLAS's,
    DDS's, which Python does not see), with its descriptors 0-2 open. A fork copies only the
    calling thread: a lock another thread held stays locked forever in the child."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        for fd in (0, 1, 2):      # else a worker's pipe could land on them
            os.fstat(fd)
        return len(os.listdir("/proc/self/task")) == 1
    except OSError:
        return False


class _ForkedProcess:
    """The parent's handle of a forked worker: the part of ``subprocess.Popen`` that
    :class:`_Worker` uses (``pid``, ``stdin``, ``stdout``, ``poll``, ``wait``, ``kill``)."""

    def __init__(self, pid: int, stdin: IO[bytes], stdout: IO[bytes]) -> None:
        self.pid, self.stdin, self.stdout = pid, stdin, stdout
        self.returncode: int | None = None
        self._lock = threading.Lock()

    def poll(self) -> int | None:
        with self._lock:
            if self.returncode is None:
                try:
                    pid, status = os.waitpid(self.pid, os.WNOHANG)
                except ChildProcessError:     # reaped elsewhere (SIGCHLD ignored)
                    pid, status = self.pid, 0
                if pid == self.pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
            return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        delay = 0.0005
        while (code := self.poll()) is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(f"worker {self.pid}", timeout or 0.0)
            time.sleep(delay if deadline is None else
                       max(0.0, min(delay, deadline - time.monotonic())))
            delay = min(2 * delay, 0.02)
        return code

    def kill(self) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _fork(env: dict[str, str], preload: str) -> _ForkedProcess:
    """A worker forked from this process (see :func:`fork_is_safe`): it starts with this
    process's imported modules instead of importing them again (about 0.1 CPU-s of a fresh
    interpreter with numpy and OpenCV). The child keeps fds 0 (its tasks), 1 (its results) and
    2 (this process's stderr) and closes every other descriptor it inherited, so that it holds
    no end of another worker's pipe (which would keep that worker from seeing its end of
    input) and no file of this process."""
    task_r, task_w = os.pipe()
    result_r, result_w = os.pipe()
    for stream in (sys.stdout, sys.stderr):   # not printed twice: once by each process
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):
            pass
    # objects that exist now are left to the child as they are: a collection in the child
    # would write to (and so copy) every page of this process's heap it visits. This process
    # unfreezes them after the fork, unless its caller had frozen objects itself (a frozen
    # heap is the caller's choice, and unfreeze cannot tell whose objects are whose).
    caller_froze = gc.get_freeze_count() > 0
    gc.freeze()
    try:
        pid = os.fork()
    except BaseException:
        if not caller_froze:
            gc.unfreeze()
        for fd in (task_r, task_w, result_r, result_w):
            os.close(fd)
        raise
    if pid == 0:                                                   # pragma: no cover - child
        _forked_child(task_r, result_w, env, os.getppid(), preload)
    if not caller_froze:
        gc.unfreeze()
    os.close(task_r)
    os.close(result_w)
    return _ForkedProcess(pid, os.fdopen(task_w, "wb"), os.fdopen(result_r, "rb"))


def _forked_child(task_r: int, result_w: int, env: dict[str, str], parent: int,
                  preload: str) -> None:                            # pragma: no cover - child
    """The forked worker: what ``_BOOT`` does in a fresh interpreter, then ``os._exit`` (it
    never returns into the caller's stack, runs no exit handler and flushes no buffer of
    the parent's)."""
    global _PARENT
    code = EXIT_UNEXPECTED   # failed before or outside _serve's guard
    try:
        os.setsid()                       # Ctrl-C in the terminal is the parent's to handle
        os.dup2(task_r, 0)
        os.dup2(result_w, 1)
        _close_inherited()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.environ.update(env)
        _PARENT = parent
        code = _serve(os.fdopen(0, "rb", closefd=False), preload)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    except BaseException:  # noqa: BLE001 - EYE_IN_HAND_DEBUG's traceback, or a broken fd
        try:
            import traceback
            traceback.print_exc()
        except BaseException:  # noqa: BLE001
            pass
    finally:
        try:
            sys.stderr.flush()
        except BaseException:  # noqa: BLE001
            pass
        os._exit(code)


def _close_inherited() -> None:
    """Close every descriptor above 2, those listed in ``/proc/self/fd`` (not a loop up to
    the descriptor limit, which can be a million where ``close_range`` is missing)."""
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        if fd > 2:
            try:
                os.close(fd)
            except OSError:               # the listing's own descriptor, closed already
                pass


class _Worker:
    def __init__(self, proc: subprocess.Popen[bytes] | _ForkedProcess) -> None:
        self.proc = proc
        self.pending: dict[int, Future[Any]] = {}
        self.ready = threading.Event()
        self.progress_at = time.monotonic()  # last result, or submission to an idle worker
        self.timed_out: float | None = None  # the deadline that was missed, once killed
        self.dead = False
        self.closed = False
        self._state = threading.Lock()       # pending, dead
        self._write = threading.Lock()       # the stdin pipe (never held with _state)
        self.reader = threading.Thread(target=self._read, name=f"worker-{self.proc.pid}",
                                       daemon=True)
        self.reader.start()

    def initialize(self, boot: bytes) -> None:
        """Send the init call (a frame of ``("init", init, init_args)``)."""
        try:
            with self._write:
                assert self.proc.stdin is not None
                self.proc.stdin.write(boot)
                self.proc.stdin.flush()
        except (OSError, ValueError):
            pass                              # the reader sees the exit and cleans up

    def _read(self) -> None:
        assert self.proc.stdout is not None
        try:
            while True:
                kind, task, payload = pickle.loads(_recv_bytes(self.proc.stdout))
                if kind == "ready":
                    self.ready.set()
                    continue
                with self._state:
                    fut = self.pending.pop(task, None)
                    self.progress_at = time.monotonic()
                if fut is None or not fut.set_running_or_notify_cancel():
                    continue                  # unknown task, or cancelled by the caller
                if kind == "result":
                    fut.set_result(payload)
                else:
                    fut.set_exception(WorkerError(payload))
        except BaseException:  # noqa: BLE001 - EOF, a corrupt channel: the worker is gone
            pass
        finally:
            self._finish()

    def _finish(self) -> None:
        """Mark the worker dead and fail what it still owed (from the reader thread)."""
        if self.proc.stdout is not None:
            try:
                self.proc.stdout.close()
            except OSError:
                pass
        try:
            code = self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:       # alive but its channel is broken
            self.proc.kill()
            code = self.proc.wait()
        with self._state:
            self.dead = True
            pending, self.pending = self.pending, {}
        for fut in pending.values():
            if fut.set_running_or_notify_cancel():
                fut.set_exception(WorkerError(
                    f"worker process {self.proc.pid} gave no result within the "
                    f"{self.timed_out:g} s task deadline (stopped or hung): killed"
                    if self.timed_out is not None else
                    f"worker process {self.proc.pid} exited with code {code} before finishing "
                    "its task"))
        self.ready.set()  # wake anyone waiting for a worker that will never be ready

    def submit(self, task: int, fn: str, args: tuple[Any, ...]) -> Future[Any]:
        # the call is pickled on its own, so that a worker that cannot unpickle it can still
        # say which task failed
        data = _frame(("call", task, pickle.dumps((fn, args), protocol=pickle.HIGHEST_PROTOCOL)))
        fut: Future[Any] = Future()
        with self._state:
            if self.dead or self.closed:
                raise WorkerError(f"worker process {self.proc.pid} has exited")
            if not self.pending:
                self.progress_at = time.monotonic()
            self.pending[task] = fut
        try:
            with self._write:
                assert self.proc.stdin is not None
                self.proc.stdin.write(data)
                self.proc.stdin.flush()
        except (OSError, ValueError) as exc:
            with self._state:
                self.pending.pop(task, None)
            raise WorkerError(f"worker process {self.proc.pid}: {exc}") from exc
        return fut

    def overdue(self, timeout_s: float) -> bool:
        """Whether the worker owes a result and has given none for ``timeout_s``."""
        with self._state:
            return (bool(self.pending) and not self.dead
                    and time.monotonic() - self.progress_at > timeout_s)

    def kill(self, timeout_s: float) -> None:
        """Kill a worker that missed its deadline (its reader then fails what it owed)."""
        with self._state:
            if self.dead:
                return
            self.timed_out = timeout_s
        try:
            self.proc.kill()                  # SIGKILL also ends a SIGSTOPped process
        except OSError:
            pass

    def close_input(self) -> None:
        """Close the worker's stdin: it exits once it has sent what it owes."""
        with self._state:
            self.closed = True
        try:
            with self._write:
                if self.proc.stdin is not None:
                    self.proc.stdin.close()
        except OSError:
            pass

    def close(self) -> None:
        """:meth:`close_input`, then wait for the exit (a hung worker: killed after 10 s)."""
        self.close_input()
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

    ``defer_init``: the processes start now and import ``init``'s module, but are initialised
    only at :meth:`initialize` (``init_args`` unused): a caller starts them before it knows
    the arguments, and their start-up runs while it works them out.

    ``task_timeout_s`` (None: no deadline): a worker that owes a result and gave none for that
    long is killed and its tasks fail with :class:`WorkerError` (see the module docstring).

    ``fork``: start the workers by forking this process when that is safe
    (:func:`fork_is_safe`: Linux, one thread), else as fresh interpreters; :attr:`forked`
    says which. A forked worker has this process's modules already: it is ready in
    milliseconds instead of a few tenths of a second of imports, and costs that much less CPU.
    ``env`` then only changes its ``os.environ`` (libraries loaded already have read theirs).

    Raises:
        OSError: a process cannot be started (those already started are closed).
    """

    def __init__(self, n: int, init: str, init_args: tuple[Any, ...] = (),
                 env: dict[str, str] | None = None,
                 task_timeout_s: float | None = None, *, defer_init: bool = False,
                 fork: bool = False) -> None:
        if task_timeout_s is not None and not task_timeout_s > 0:
            raise ValueError(f"task_timeout_s: must be > 0, got {task_timeout_s}")
        # pickling errors surface here, before any process starts
        boot = None if defer_init else _frame(("init", init, init_args))
        root = str(Path(__file__).resolve().parent.parent)   # this package, wherever it is
        self._init = init
        self._initialized = False
        self._workers: list[_Worker] = []
        self._ids = itertools.count(1)
        self.task_timeout_s = task_timeout_s
        self.timeouts = 0
        self._closing = threading.Event()
        self._watchdog: threading.Thread | None = None
        preload = init.partition(":")[0]
        # every fork before the first reader thread starts (fork_is_safe counts threads)
        self.forked = fork and fork_is_safe()
        procs: list[subprocess.Popen[bytes] | _ForkedProcess] = []
        try:
            for _ in range(max(1, n)):
                procs.append(_fork(env or {}, preload) if self.forked else
                             _spawn({**os.environ, **(env or {})}, root, preload))
            for proc in procs:
                self._workers.append(_Worker(proc))
        except BaseException:
            for proc in procs[len(self._workers):]:
                proc.kill()
                proc.wait()
            self.close()
            raise
        if boot is not None:
            self._send_init(boot)
        if task_timeout_s is not None:
            self._watchdog = threading.Thread(target=self._watch, name="worker-watchdog",
                                              daemon=True)
            self._watchdog.start()

    def initialize(self, *init_args: Any) -> None:
        """Initialise the workers of a pool made with ``defer_init``: ``init(*init_args)`` in
        each (once; the pool is usable when a worker has run it, see :meth:`ready`).

        Raises:
            RuntimeError: the pool was initialised already.
            pickle.PicklingError, TypeError, AttributeError: ``init_args`` do not pickle.
        """
        self._send_init(_frame(("init", self._init, init_args)))

    def _send_init(self, boot: bytes) -> None:
        if self._initialized:
            raise RuntimeError("the worker processes are initialised already")
        self._initialized = True
        for w in self._workers:
            w.initialize(boot)

    def _watch(self) -> None:
        """Kill workers that missed the task deadline."""
        assert self.task_timeout_s is not None
        period = min(0.1, self.task_timeout_s / 4)
        while not self._closing.wait(period):
            for w in self._workers:
                if w.overdue(self.task_timeout_s):
                    self.timeouts += 1
                    w.kill(self.task_timeout_s)

    def ready(self) -> bool:
        """Whether at least one worker is initialised and alive."""
        return any(w.ready.is_set() and not w.dead for w in self._workers)

    def alive(self) -> bool:
        return any(not w.dead for w in self._workers)

    def submit(self, fn: str, *args: Any) -> Future[Any]:
        """Run ``fn(*args)`` (``"module:function"``) on the least busy ready worker.

        Raises:
            WorkerError: no worker is ready and alive, or the task cannot be sent.
        """
        live = [w for w in self._workers if w.ready.is_set() and not w.dead]
        if not live:
            raise WorkerError("no worker process is ready")
        worker = min(live, key=lambda w: len(w.pending))
        return worker.submit(next(self._ids), fn, args)

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` until every worker is initialised (or dead); whether at
        least one is ready."""
        deadline = time.monotonic() + timeout_s
        for w in self._workers:
            w.ready.wait(max(0.0, deadline - time.monotonic()))
        return self.ready()

    def __len__(self) -> int:
        return len(self._workers)

    def submit_to(self, index: int, fn: str, *args: Any) -> tuple[Future[Any], int]:
        """Run ``fn(*args)`` on worker ``index`` (modulo the pool's size) when it is ready
        and alive, else on the least busy ready one; returns the future and the worker used.

        Raises:
            WorkerError: no worker is ready and alive, or the task cannot be sent.
        """
        i = index % len(self._workers)
        w = self._workers[i]
        if not (w.ready.is_set() and not w.dead):
            live = [k for k, x in enumerate(self._workers) if x.ready.is_set() and not x.dead]
            if not live:
                raise WorkerError("no worker process is ready")
            i = min(live, key=lambda k: len(self._workers[k].pending))
            w = self._workers[i]
        return w.submit(next(self._ids), fn, args), i

    def try_submit_to(self, index: int, fn: str, *args: Any,
                      wait_s: float = 0.0) -> tuple[Future[Any], int] | None:
        """:meth:`submit_to`, first waiting up to ``wait_s`` for the workers to start; None
        when no worker can take the task (none ready and alive, or the pipe fails)."""
        if wait_s > 0 and not self.ready():
            self.wait_ready(wait_s)
        try:
            return self.submit_to(index, fn, *args)
        except WorkerError:
            return None

    def ended(self) -> list[tuple[int, str]]:
        """The workers that ended on their own: their pid and a line (``worker process 123 was
        killed by SIGKILL``): not closed by this pool, nor killed for a missed task deadline (those
        are counted in :attr:`timeouts`). Complete once :meth:`close` has returned."""
        lines = []
        for w in self._workers:
            code = w.proc.poll()
            if not self._initialized or w.timed_out is not None or code in (None, 0):
                continue
            if code < 0:
                try:
                    how = f"was killed by {signal.Signals(-code).name}"
                except ValueError:
                    how = f"was killed by signal {-code}"
            else:
                how = f"exited with code {code}"
            lines.append((w.proc.pid, f"worker process {w.proc.pid} {how}"))
        return lines

    def stop(self) -> None:
        """Tell every worker to exit once it has sent the results it owes (its stdin closed):
        the caller can do other work while they tear down; :meth:`close` waits for them. No
        task can be submitted after it."""
        for w in self._workers:
            w.close_input()

    def close(self) -> None:
        """Close the workers' stdin (they exit) and wait for them; workers never initialised
        (``defer_init`` and no :meth:`initialize`) are killed, not waited for while they
        import."""
        self._closing.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=5)
        if not self._initialized:
            for w in self._workers:
                try:
                    w.proc.kill()
                except OSError:
                    pass
        self.stop()                           # all told first: they exit side by side
        for w in self._workers:               # (8-10 ms each for a forked worker of 100 MB)
            w.close()                         # a hung worker: killed after 10 s

    def __enter__(self) -> ProcessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(stdin: IO[bytes] | None = None, preload: str | None = None) -> int:
    """The worker's process: :func:`_serve_loop` under a top-level guard.

    The parent gone (its end of a pipe closed: a ``BrokenPipeError`` or ``EOFError``, or a
    SIGPIPE) ends the worker quietly with code 0: nobody is left to read a message. Any other
    exception is one line on stderr, ``eye-in-hand worker <pid>: internal error: ...``, exit 70
    (``EYE_IN_HAND_DEBUG=1``: the traceback)."""
    from eye_in_hand.errors import EXIT_UNEXPECTED, debug_enabled, unexpected_error_line

    try:
        return _serve_loop(stdin, preload)
    except (BrokenPipeError, ConnectionResetError, EOFError, KeyboardInterrupt):
        _silence()
        return 0
    except BaseException as exc:  # noqa: BLE001 - the top-level guard of a worker process
        if isinstance(exc, SystemExit):
            raise
        if debug_enabled():
            raise
        if os.getppid() == 1 or _parent_gone():
            _silence()
            return 0
        print(unexpected_error_line(f"eye-in-hand worker {os.getpid()}", exc),
              file=sys.stderr, flush=True)
        return EXIT_UNEXPECTED


_PARENT = os.getppid()


def _parent_gone() -> bool:
    return os.getppid() != _PARENT


def _silence() -> None:
    """Send fds 1 and 2 to /dev/null, so that the interpreter's last flush of a closed pipe
    prints nothing."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            os.dup2(devnull, fd)
    except OSError:
        pass


def _serve_loop(stdin: IO[bytes] | None = None, preload: str | None = None) -> int:
    """The worker's loop: init, then calls until stdin closes. ``stdin``: where the calls
    come from (default ``sys.stdin``'s buffer); ``preload``: the module to import before the
    init call (default the first command-line argument)."""
    import traceback

    if stdin is None:
        stdin = sys.stdin.buffer
    if preload is None:
        preload = sys.argv[1] if len(sys.argv) > 1 else ""
    # Results travel on a private copy of fd 1; fd 1 itself (Python prints, C code such as
    # OpenCV's logger) now goes to stderr, so nothing can corrupt the channel.
    channel = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr

    def send(frame: bytes) -> None:
        try:
            channel.write(frame)
            channel.flush()
        except BrokenPipeError:
            # the parent is gone: drop what is buffered so that closing cannot fail again
            try:
                os.close(channel.fileno())
            except OSError:
                pass
            channel.close = lambda: None  # type: ignore[method-assign]
            raise

    if preload:
        importlib.import_module(preload)   # init's module, while the parent gets ready
    try:
        _kind, init, init_args = pickle.loads(_recv_bytes(stdin))
    except EOFError:
        return 0
    _resolve(init)(*init_args)
    send(_frame(("ready", 0, os.getpid())))
    while True:
        try:
            raw = _recv_bytes(stdin)
        except EOFError:
            return 0
        _kind, task, call = pickle.loads(raw)
        try:
            fn, args = pickle.loads(call)
            result = _resolve(fn)(*args)
            frame = _frame(("result", task, result))
        except Exception:  # noqa: BLE001 - handed to the parent with its traceback
            frame = _frame(("error", task, traceback.format_exc()))
        send(frame)


if __name__ == "__main__":
    sys.exit(_serve())
