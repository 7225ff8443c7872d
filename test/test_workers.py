"""eye_in_hand.workers: the subprocess pool (results, task errors, dying workers)."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import pytest

from eye_in_hand.workers import ProcessPool, WorkerError


def _wait_ready(pool: ProcessPool, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pool.ready() and pool.alive() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_results_come_back_from_every_worker():
    with ProcessPool(2, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        assert pool.ready()
        futs = [pool.submit("math:sqrt", float(i)) for i in range(50)]
        assert [f.result(timeout=30) for f in futs] == [math.sqrt(i) for i in range(50)]
        # both workers answer: while each is busy with a sleep, the least-busy rule sends one
        # getpid to each (a worker may still be starting: try again until the deadline)
        pids: set[int] = set()
        deadline = time.monotonic() + 30
        while len(pids) < 2 and time.monotonic() < deadline:
            batch = [pool.submit("time:sleep", 0.2), pool.submit("time:sleep", 0.2),
                     pool.submit("os:getpid"), pool.submit("os:getpid")]
            pids |= {f.result(timeout=30) for f in batch[2:]}
        assert len(pids) == 2 and os.getpid() not in pids


def test_a_task_error_carries_its_traceback_and_the_worker_goes_on():
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        with pytest.raises(WorkerError, match="ValueError: math domain error"):
            pool.submit("math:sqrt", -1.0).result(timeout=30)
        assert pool.submit("math:sqrt", 4.0).result(timeout=30) == 2.0


def test_a_dying_worker_fails_its_task_and_leaves_the_pool():
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        fut = pool.submit("os:_exit", 3)
        with pytest.raises(WorkerError, match="exited with code 3"):
            fut.result(timeout=30)
        deadline = time.monotonic() + 10
        while pool.alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not pool.alive() and not pool.ready()
        with pytest.raises(WorkerError, match="no worker process is ready"):
            pool.submit("math:sqrt", 1.0)


def test_a_failing_initialiser_leaves_no_ready_worker():
    with ProcessPool(2, "math:sqrt", ("not a number",)) as pool:
        _wait_ready(pool)
        assert not pool.ready() and not pool.alive()


def test_output_on_the_workers_stdout_does_not_disturb_the_channel():
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        assert pool.submit("os:write", 1, b"noise from C code or print\n").result(timeout=30) > 0
        assert pool.submit("math:sqrt", 9.0).result(timeout=30) == 3.0


def test_large_arguments_and_results_do_not_deadlock():
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        lens = [pool.submit("builtins:len", b"x" * 40_000) for _ in range(20)]
        blobs = [pool.submit("builtins:bytes", 1_000_000) for _ in range(20)]
        assert [f.result(timeout=60) for f in lens] == [40_000] * 20
        assert all(len(f.result(timeout=60)) == 1_000_000 for f in blobs)


def test_a_cancelled_or_unpicklable_task_leaves_the_pool_working():
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        slow = pool.submit("time:sleep", 0.3)
        assert slow.cancel()
        with pytest.raises(WorkerError, match="pickle|Pickl"):
            pool.submit("threading:Lock").result(timeout=30)     # a result that cannot pickle
        assert pool.submit("math:sqrt", 16.0).result(timeout=30) == 4.0
        assert pool.alive() and pool.ready()


def test_workers_never_import_from_their_working_directory(tmp_path, monkeypatch):
    fake = tmp_path / "eye_in_hand"
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('the wrong eye_in_hand')\n")
    monkeypatch.chdir(tmp_path)
    with ProcessPool(1, "builtins:len", ((),)) as pool:
        _wait_ready(pool)
        assert pool.ready()
        assert pool.submit("math:sqrt", 1.0).result(timeout=30) == 1.0


def test_a_stopped_worker_misses_its_deadline_and_is_killed():
    import os
    import signal

    with ProcessPool(1, "builtins:len", ((),), task_timeout_s=0.5) as pool:
        _wait_ready(pool)
        assert pool.submit("math:sqrt", 4.0).result(timeout=30) == 2.0
        os.kill(pool._workers[0].proc.pid, signal.SIGSTOP)
        t0 = time.monotonic()
        fut = pool.submit("math:sqrt", 9.0)
        with pytest.raises(WorkerError, match="0.5 s task deadline"):
            fut.result(timeout=30)                  # fails, does not hang
        assert time.monotonic() - t0 < 10
        assert pool.timeouts == 1 and not pool.alive()


def test_a_slow_but_answering_worker_is_not_killed():
    with ProcessPool(1, "builtins:len", ((),), task_timeout_s=1.0) as pool:
        _wait_ready(pool)
        futs = [pool.submit("time:sleep", 0.4) for _ in range(5)]   # 2 s in all, 0.4 s each
        assert [f.result(timeout=30) for f in futs] == [None] * 5
        assert pool.timeouts == 0 and pool.alive()


def test_a_deferred_pool_imports_its_init_module_and_waits_for_initialize(tmp_path):
    """``defer_init``: the processes start and import the initialiser's module at once, but
    are not ready (take no task) until :meth:`initialize`, which runs once."""
    (tmp_path / "deferred_init_mod.py").write_text(
        "import os, pathlib\n"
        "pathlib.Path(os.environ['MARK_DIR'], f'imported-{os.getpid()}').touch()\n"
        "def init(text):\n"
        "    pathlib.Path(os.environ['MARK_DIR'], f'init-{os.getpid()}').write_text(text)\n")
    env = {"PYTHONPATH": str(tmp_path), "MARK_DIR": str(tmp_path)}
    with ProcessPool(2, "deferred_init_mod:init", env=env, defer_init=True) as pool:
        deadline = time.monotonic() + 30
        while len(list(tmp_path.glob("imported-*"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(list(tmp_path.glob("imported-*"))) == 2     # imported before initialize
        time.sleep(0.2)
        assert not pool.ready() and pool.alive() and not list(tmp_path.glob("init-*"))
        with pytest.raises(WorkerError, match="no worker process is ready"):
            pool.submit("math:sqrt", 4.0)
        pool.initialize("the rig")
        # every worker, not the first: ready() is true once one of them has initialised
        assert pool.wait_ready(30) and all(w.ready.is_set() for w in pool._workers)
        assert pool.submit("math:sqrt", 4.0).result(timeout=30) == 2.0
        assert sorted(p.read_text() for p in tmp_path.glob("init-*")) == ["the rig"] * 2
        with pytest.raises(RuntimeError, match="initialised already"):
            pool.initialize("again")


def test_a_deferred_pool_closed_before_initialize_is_not_waited_for(tmp_path, capfd):
    """A pool never initialised (the caller failed before it knew the arguments) is killed
    at close, not waited for while its workers import, and says nothing."""
    (tmp_path / "slow_import_mod.py").write_text("import time\ntime.sleep(20)\n"
                                                  "def init():\n    pass\n")
    pool = ProcessPool(2, "slow_import_mod:init", env={"PYTHONPATH": str(tmp_path)},
                       defer_init=True)
    t0 = time.monotonic()
    pool.close()
    assert time.monotonic() - t0 < 10
    assert all(w.proc.returncode is not None for w in pool._workers) and not pool.alive()
    assert "error" not in capfd.readouterr().err


def test_a_process_worker_imports_only_what_locating_needs():
    """A `process` worker imports eye_in_hand.offline for _worker_init and _worker_locate:
    not the bag reader, the results and output messages, the robot-pose code, rosbags or
    SciPy, which only the reading process uses (each costs start-up CPU in every worker). Of
    eye_in_hand.io only io.pages (mmap alone), to release the pages of the images it read."""
    code = ("import sys, eye_in_hand.workers, eye_in_hand.offline\n"
            "print(' '.join(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert [m for m in out if m.startswith("eye_in_hand.io.")] == ["eye_in_hand.io.pages"]
    for name in ("eye_in_hand.io.bags", "eye_in_hand.io.results", "eye_in_hand.ros.outputs",
                 "eye_in_hand.core.localization", "eye_in_hand.core.sync", "rosbags", "scipy",
                 "rclpy"):
        assert name not in out, name
    assert "cv2" in out and "eye_in_hand.core.locator" in out


# -- forked workers: each scenario runs in a fresh interpreter, where the caller is the only
# thread (pytest's process is not: the ROS libraries it loaded run tracing threads) ----------

_FORK_PRELUDE = """\
import json, math, os, sys, threading, time
from eye_in_hand.workers import ProcessPool, WorkerError, fork_is_safe
def wait_ready(pool):
    deadline = time.monotonic() + 30
    while not pool.ready() and pool.alive() and time.monotonic() < deadline:
        time.sleep(0.005)
"""


def _forking(code: str, timeout_s: float = 120.0) -> tuple[dict, str]:
    """Run ``code`` after :data:`_FORK_PRELUDE` in a fresh interpreter; its last stdout line
    as JSON, and its stderr."""
    run = subprocess.run([sys.executable, "-c", _FORK_PRELUDE + code], capture_output=True,
                         text=True, timeout=timeout_s,
                         env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


def test_a_single_threaded_caller_forks_its_workers():
    """``fork=True`` in a process with one thread: forked workers (children of this process,
    each in its own session), ready at once, answering tasks; closing reaps them, quickly:
    a worker holds no end of another worker's pipe (its stdin sees the end of input)."""
    out, err = _forking("""
safe = fork_is_safe()
pool = ProcessPool(2, "builtins:len", ((),), fork=True)
wait_ready(pool)
futs = [pool.submit("math:sqrt", float(i)) for i in range(20)]
values = [f.result(timeout=30) for f in futs]
pids = {pool.submit_to(k, "os:getpid")[0].result(timeout=30) for k in range(2)}
sids = [os.getsid(p) for p in pids]
ppids = [int(open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()[1]) for p in pids]
t0 = time.monotonic()
pool.close()
close_s = time.monotonic() - t0
codes = [w.proc.returncode for w in pool._workers]
try:
    os.waitpid(-1, os.WNOHANG)
    reaped = False
except ChildProcessError:
    reaped = True
print(json.dumps(dict(safe=safe, forked=pool.forked, values=values, pids=sorted(pids),
                      me=os.getpid(), sids=sids, mysid=os.getsid(0), ppids=ppids,
                      close_s=close_s, codes=codes, reaped=reaped)))
""")
    assert out["safe"] and out["forked"]
    assert out["values"] == [math.sqrt(i) for i in range(20)]
    assert len(out["pids"]) == 2 and out["me"] not in out["pids"]
    assert out["ppids"] == [out["me"]] * 2
    assert sorted(out["sids"]) == out["pids"]      # each the leader of its own session
    assert out["close_s"] < 5.0, out              # not the 10 s wait for a hung worker
    assert out["codes"] == [0, 0] and out["reaped"]
    assert "error" not in err


def test_a_caller_with_another_thread_starts_fresh_interpreters():
    """A second thread (here Python's; also a C library's) makes forking unsafe: the pool
    starts fresh interpreters instead, which work the same."""
    out, _ = _forking("""
stop = threading.Event()
threading.Thread(target=stop.wait, daemon=True).start()
safe = fork_is_safe()
with ProcessPool(1, "builtins:len", ((),), fork=True) as pool:
    wait_ready(pool)
    value = pool.submit("math:sqrt", 9.0).result(timeout=30)
    forked = pool.forked
stop.set()
print(json.dumps(dict(safe=safe, forked=forked, value=value)))
""")
    assert out == {"safe": False, "forked": False, "value": 3.0}


def test_forked_workers_keep_the_pools_rules():
    """Forked workers as spawned ones: a task's error carries its traceback, a print goes to
    stderr (never into the result channel), a worker that dies fails its task with its exit
    code, and one that misses the deadline is killed."""
    out, err = _forking("""
pool = ProcessPool(2, "builtins:len", ((),), fork=True, task_timeout_s=1.0)
wait_ready(pool)
try:
    pool.submit_to(0, "math:sqrt", -1.0)[0].result(timeout=30)
    error = None
except WorkerError as exc:
    error = str(exc)
printed = pool.submit_to(0, "builtins:print", "printed by a forked worker")[0].result(timeout=30)
after = pool.submit_to(0, "math:sqrt", 16.0)[0].result(timeout=30)
try:
    pool.submit_to(0, "os:_exit", 3)[0].result(timeout=30)
    died = None
except WorkerError as exc:
    died = str(exc)
try:
    pool.submit_to(1, "time:sleep", 30)[0].result(timeout=30)
    hung = None
except WorkerError as exc:
    hung = str(exc)
timeouts = pool.timeouts
pool.close()
print(json.dumps(dict(forked=pool.forked, error=error, printed=printed, after=after, died=died,
                      hung=hung, timeouts=timeouts)))
""")
    assert out["forked"]
    assert "ValueError: math domain error" in out["error"]
    assert out["printed"] is None and out["after"] == 4.0
    assert "printed by a forked worker" in err
    assert "exited with code 3" in out["died"]
    assert "task deadline" in out["hung"] and out["timeouts"] == 1


def test_a_caller_without_stdin_starts_fresh_interpreters():
    """With descriptor 0 closed a worker's pipe could take its number (and be overwritten
    when the child sets up its own): such a caller does not fork."""
    out, _ = _forking("""
os.close(0)
safe = fork_is_safe()
with ProcessPool(1, "builtins:len", ((),), fork=True) as pool:
    wait_ready(pool)
    value = pool.submit("math:sqrt", 9.0).result(timeout=30)
    forked = pool.forked
print(json.dumps(dict(safe=safe, forked=forked, value=value)))
""")
    assert out == {"safe": False, "forked": False, "value": 3.0}


def test_forking_leaves_the_callers_garbage_collector_as_it_was():
    """The objects frozen for the fork are unfrozen in the caller after it, unless the caller
    had frozen objects itself (then they stay frozen: its choice)."""
    out, _ = _forking("""
import gc
before = gc.get_freeze_count()
with ProcessPool(1, "builtins:len", ((),), fork=True) as pool:
    plain = gc.get_freeze_count()
    forked = pool.forked
junk = [object() for _ in range(1000)]
gc.freeze()
frozen = gc.get_freeze_count()
with ProcessPool(1, "builtins:len", ((),), fork=True) as pool:
    after = gc.get_freeze_count()
print(json.dumps(dict(forked=forked, before=before, plain=plain, frozen=frozen, after=after)))
""")
    assert out["forked"] and out["before"] == out["plain"] == 0
    assert out["frozen"] > 0 and out["after"] > 0      # not unfrozen (freed ones leave it)


def test_stop_lets_owed_results_arrive_and_the_workers_exit_before_close():
    pool = ProcessPool(2, "builtins:len", ((),))
    try:
        _wait_ready(pool)
        slow = [pool.submit("time:sleep", 0.3) for _ in range(2)]
        pool.stop()                       # told while both tasks are in flight
        assert [f.result(timeout=30) for f in slow] == [None, None]
        with pytest.raises(WorkerError):
            pool.submit("math:sqrt", 1.0)
        # they exit on their own, not when close asks
        deadline = time.monotonic() + 30
        while pool.alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not pool.alive()
    finally:
        pool.close()
    assert pool.ended() == []             # a worker told to exit did not end "on its own"
