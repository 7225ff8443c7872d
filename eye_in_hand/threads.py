"""One BLAS thread per process unless the user chose a count (docs/architecture.md "Threads").

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
"""
from __future__ import annotations

import os
from collections.abc import Mapping, MutableMapping

__all__ = ["BLAS_THREAD_VARS", "ONE_BLAS_THREAD", "blas_env_defaults", "one_blas_thread"]

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
