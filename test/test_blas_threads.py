"""One BLAS thread per process unless the user chose a count (eye_in_hand/threads.py): an
OpenBLAS pool thread per core spins at start and doubled the CPU of the simulator's renders for
no gain in time (docs/architecture.md "Threads"). The ``eye-in-hand`` command sets it in
``main`` before its command's module loads numpy, so importing the CLI must not load numpy.
Named OS threads: a thread's name shows in /proc, the main thread's (the process's) is kept."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from eye_in_hand.threads import (
    BLAS_THREAD_VARS,
    blas_env_defaults,
    name_os_thread,
    one_blas_thread,
)

CODE = """\
import os, sys
from eye_in_hand import cli
assert "numpy" not in sys.modules, "importing the CLI loaded numpy: too late for main to set"
try:
    cli.main(["--version"])
except SystemExit:
    pass
import numpy
print(os.environ.get("OPENBLAS_NUM_THREADS", "unset"), len(os.listdir("/proc/self/task")))
"""


def _run(**extra: str) -> tuple[str, int]:
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARS}
    env.update(extra)
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    return out[-2], int(out[-1])


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_the_command_loads_blas_with_one_thread_unless_the_user_chose():
    value, threads = _run()
    assert value == "1"
    assert threads == _run(OPENBLAS_NUM_THREADS="1")[1]     # no BLAS pool threads
    assert _run(OPENBLAS_NUM_THREADS="2")[0] == "2"           # the user's choice is kept
    assert _run(OMP_NUM_THREADS="2")[0] == "unset"            # ... in any of the variables


def test_the_rule():
    assert blas_env_defaults({}) == {"OPENBLAS_NUM_THREADS": "1"}
    for name in BLAS_THREAD_VARS:
        assert blas_env_defaults({name: "3"}) == {}
    assert blas_env_defaults({"OMP_NUM_THREADS": ""}) == {"OPENBLAS_NUM_THREADS": "1"}
    env = {"PATH": "/bin"}
    assert one_blas_thread(env) and env == {"PATH": "/bin", "OPENBLAS_NUM_THREADS": "1"}
    env = {"GOTO_NUM_THREADS": "2"}
    assert not one_blas_thread(env) and env == {"GOTO_NUM_THREADS": "2"}


def test_importing_the_rule_loads_no_numpy():
    code = "import sys, eye_in_hand.threads; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_a_named_thread_shows_its_name_and_the_main_thread_keeps_the_process_name():
    seen: dict[str, tuple[bool, str]] = {}

    def run(name: str) -> None:
        ok = name_os_thread(name)
        comm = Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip()
        seen[name] = (ok, comm)

    for name in ("detect_worker", "a_name_longer_than_fifteen_bytes"):
        thread = threading.Thread(target=run, args=(name,))
        thread.start()
        thread.join()
    assert seen["detect_worker"] == (True, "detect_worker")
    assert seen["a_name_longer_than_fifteen_bytes"] == (True, "a_name_longer_t")
    process_name = Path("/proc/self/comm").read_text()
    assert name_os_thread("renamed") is False          # the main thread: ps and pgrep use it
    assert Path("/proc/self/comm").read_text() == process_name
