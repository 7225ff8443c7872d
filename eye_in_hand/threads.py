"""Threads of the package's processes: one BLAS thread per process unless the user chose a
count, and named OS threads (docs/architecture.md "Threads").

numpy's OpenBLAS starts a pool thread per core when numpy loads, whose idle threads spin, and
splits long products over them: nothing in this package gains from that (its matrices are 3x3
to a few dozen rows; the simulator's long products ran no faster on two threads), and it costs
about 0.1 s of CPU at every process start, twice the CPU of the simulator's renders, and in a
busy live node most of a core. OpenBLAS reads its thread count from the environment when numpy
loads it, so :func:`one_blas_thread` must run before the first numpy import of a process; what
a process sets, the processes it starts inherit.

A count the user chose is kept: any of :data:`BLAS_THREAD_VARS` set (OpenBLAS takes
``OPENBLAS_NUM_THREADS`` first, then ``GOTO_NUM_THREADS``, then ``OMP_NUM_THREADS``) leaves the
environment as it is. This module imports nothing that loads numpy.

:func:`name_os_thread` gives the calling thread a name the operating system shows (``top -H``,
``ps -L``, ``/proc/<pid>/task/<tid>/comm``): a node's worker and the second executor of the
composed chain are told apart from the interpreter's main thread, where every Python thread
is otherwise called ``python``, so their CPU can be attributed to the node that runs on them.
"""
from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping

__all__ = ["BLAS_THREAD_VARS", "ONE_BLAS_THREAD", "OS_THREAD_NAME_MAX", "blas_env_defaults",
           "name_os_thread", "one_blas_thread"]

#: The variables through which a user sets OpenBLAS's thread count.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
#: What a process gets when the user set none of them.
ONE_BLAS_THREAD = {"OPENBLAS_NUM_THREADS": "1"}


def blas_env_defaults(environ: Mapping[str, str]) -> dict[str, str]:
    """The variables to add to ``environ``: :data:`ONE_BLAS_THREAD`, or nothing when the
    user chose a count (a non-empty one of :data:`BLAS_THREAD_VARS`)."""
    if any(environ.get(name) for name in BLAS_THREAD_VARS):
        return {}
    return dict(ONE_BLAS_THREAD)


def one_blas_thread(environ: MutableMapping[str, str] | None = None) -> bool:
    """Add :func:`blas_env_defaults` to ``environ`` (default ``os.environ``); True when it
    set the count, False when the user's choice was kept."""
    env = os.environ if environ is None else environ
    add = blas_env_defaults(env)
    env.update(add)
    return bool(add)


#: the longest OS thread name Linux keeps (15 bytes and the terminating zero)
OS_THREAD_NAME_MAX = 15


def name_os_thread(name: str | None = None) -> bool:
    """Name the calling thread for the operating system (Linux ``prctl(PR_SET_NAME)``),
    truncated to :data:`OS_THREAD_NAME_MAX` bytes; by default its Python name (the ``name``
    its ``threading.Thread`` was given). Only where it does not rename the process:
    the main thread's name is the process's (``ps``, ``pgrep``, ``killall`` match it), so it is
    left alone. Returns whether the name was set (False elsewhere than Linux, or when libc
    refuses: a name is a label, never needed to run)."""
    import sys
    import threading

    if not sys.platform.startswith("linux") or \
            threading.current_thread() is threading.main_thread():
        return False
    if name is None:
        name = threading.current_thread().name
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_name = 15
        raw = name.encode("utf-8", "replace")[:OS_THREAD_NAME_MAX]
        return int(libc.prctl(pr_set_name, ctypes.c_char_p(raw), 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False
