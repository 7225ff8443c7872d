"""The ``eye-in-hand`` command's process loads numpy's BLAS with one thread unless the user chose
a count (eye_in_hand/cli.py): an OpenBLAS pool thread per core spins at start and doubled the
CPU of the simulator's renders for no gain in time (docs/architecture.md "Threads")."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

CODE = ("import os, eye_in_hand.cli, numpy; "
        "print(os.environ.get('OPENBLAS_NUM_THREADS', 'unset'), "
        "len(os.listdir('/proc/self/task')))")


def _run(**extra: str) -> tuple[str, int]:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    env.update(extra)
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_the_command_loads_blas_with_one_thread_unless_the_user_chose():
    value, threads = _run()
    assert value == "1"
    assert threads == _run(OPENBLAS_NUM_THREADS="1")[1]     # no BLAS pool threads
    assert _run(OPENBLAS_NUM_THREADS="2")[0] == "2"           # the user's choice is kept
    # the command's own subprocesses (workers, launched nodes) inherit it
    code = "import os, eye_in_hand.cli, subprocess, sys; subprocess.run([sys.executable, " \
           "'-c', 'import os; print(os.environ[\"OPENBLAS_NUM_THREADS\"])'])"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "1"
