"""Image-sized memory blocks reused inside the process instead of mapped afresh for each frame.

glibc's ``malloc`` serves a block above its mmap threshold (128 KiB at start, raised as such
blocks are freed) with a fresh ``mmap``, and gives free memory at the top of its heap back to
the kernel once there is more than its trim threshold. An image stream allocates and frees a
few megabytes per frame (the middleware's copy of each message, its Python copy), so a node
paid a page fault for every 4 KiB of many of its images: in ``detect_triangulate`` at
1280x720 and 30 Hz, about 600 faults and 1 ms of kernel time per pair, half of its executor
thread's CPU (docs/localization.md).

:func:`reuse_large_buffers` sets both thresholds once, at start: blocks up to
:data:`MMAP_THRESHOLD` come from the heap, and up to :data:`TRIM_THRESHOLD` of free heap stay
in the process for the next frames. The process's resident memory may stay that much above
what it holds. Settings the user gave glibc in the environment (``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_``, ``GLIBC_TUNABLES`` with ``glibc.malloc``) are left alone, and
so is any C library other than glibc.
"""
from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "reuse_large_buffers", "user_malloc_settings"]

#: blocks up to this size come from the heap (glibc's largest allowed value on 64-bit):
#: a 1920x1080 BGR image is 6.2 MB, a 3840x2160 one 24.9 MB
MMAP_THRESHOLD = 32 * 1024 * 1024
#: free heap kept for reuse: a few dozen 1280x720 images in flight
TRIM_THRESHOLD = 64 * 1024 * 1024

_M_TRIM_THRESHOLD = -1   # glibc's mallopt parameter numbers (malloc.h)
_M_MMAP_THRESHOLD = -3
_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_",
        "MALLOC_MMAP_MAX_")


def user_malloc_settings(environ: dict[str, str] | None = None) -> list[str]:
    """The environment variables through which the user tunes glibc's malloc (empty: none)."""
    env = os.environ if environ is None else environ
    names = [n for n in _ENV if n in env]
    if "glibc.malloc." in env.get("GLIBC_TUNABLES", ""):
        names.append("GLIBC_TUNABLES")
    return names


def reuse_large_buffers() -> bool:
    """Set glibc's mmap and trim thresholds (module docs); True when they were set.

    False, with nothing changed, on a C library other than glibc or when the user tunes
    malloc through the environment (:func:`user_malloc_settings`).
    """
    if not sys.platform.startswith("linux") or user_malloc_settings():
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
        libc.gnu_get_libc_version  # noqa: B018 - glibc only (musl has mallopt, a no-op)
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and \
        bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
