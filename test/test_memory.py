"""eye_in_hand.memory: image-sized blocks reused instead of mapped (and faulted in) afresh."""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap

import pytest

from eye_in_hand import memory

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

# A node's pattern: a few image-sized blocks in flight, each new one written whole (a bytearray
# is zero-filled), the oldest freed. Prints the minor page faults per block.
_RING = """
    import collections, resource, sys
    if sys.argv[1] == "1":
        from eye_in_hand.memory import reuse_large_buffers
        assert reuse_large_buffers()
    ring = collections.deque()
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for i in range(200):
        ring.append(bytearray(2_764_800 + (i % 3) * 4096))     # 1280x720 BGR, sizes vary
        if len(ring) > int(sys.argv[2]):
            ring.popleft()
    print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 200)
"""


def _faults_per_block(reuse: bool, in_flight: int) -> float:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(_RING), str(int(reuse)),
                           str(in_flight)], capture_output=True, text=True, env=env,
                          timeout=60, check=True)
    return float(proc.stdout.strip())


@pytest.mark.skipif(not GLIBC, reason="glibc's malloc only")
@pytest.mark.parametrize("in_flight", [1, 4])
def test_reused_blocks_are_not_faulted_in_again(in_flight):
    # a 2.7 MB block is 675 pages: without the setting glibc maps many blocks afresh
    before = _faults_per_block(False, in_flight)
    after = _faults_per_block(True, in_flight)
    assert before > 150, before          # the cost this module removes is there
    assert after < 40, after             # a few pages of Python's own per block, no more


def test_the_users_malloc_settings_win(monkeypatch):
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_",
                 "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    assert memory.user_malloc_settings() == []
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.rtld.optional_static_tls=4096")
    assert memory.user_malloc_settings() == []          # not a malloc tunable
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=1000")
    assert memory.user_malloc_settings() == ["GLIBC_TUNABLES"]
    assert memory.reuse_large_buffers() is False
    monkeypatch.delenv("GLIBC_TUNABLES")
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "0")
    assert memory.user_malloc_settings() == ["MALLOC_TRIM_THRESHOLD_"]
    assert memory.reuse_large_buffers() is False


def test_other_platforms_are_left_alone(monkeypatch):
    monkeypatch.setattr(memory.sys, "platform", "darwin")
    assert memory.reuse_large_buffers() is False


def test_a_refused_setting_is_reported(monkeypatch):
    """mallopt returns 0 when glibc refuses a value: then not True."""
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_",
                 "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)

    class _Libc:
        gnu_get_libc_version = object()

        class mallopt:  # noqa: N801 - stands in for the C function
            argtypes = restype = None

            def __new__(cls, param, value):
                return 0

    monkeypatch.setattr(memory.ctypes, "CDLL", lambda _name: _Libc())
    monkeypatch.setattr(memory.sys, "platform", "linux")
    assert memory.reuse_large_buffers() is False
