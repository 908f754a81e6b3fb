"""The console command's heap thresholds (lenssim_cli.main.tune_allocator): a buffer the size of a window batch or a
band of a 24 MP frame comes from the heap instead of pages mapped afresh for it (checked in a fresh process, so the
test process keeps its own settings)."""

import ctypes.util
import os
import subprocess
import sys

import pytest

PROBE = r"""
import ctypes, ctypes.util, sys
libc = ctypes.CDLL(ctypes.util.find_library("c"))
class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                               "uordblks", "fordblks", "keepcost")]
libc.mallinfo2.restype = MallInfo2
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)

def mapped_bytes(n):
    # bytes glibc holds in separately mapped blocks while a buffer of n bytes is held
    p = libc.malloc(n)
    held = libc.mallinfo2().hblkhd
    libc.free(p)
    return held

n = 40 * 2**20  # over glibc's own largest adaptive threshold (32 MiB), under the command's (64 MiB)
before = mapped_bytes(n)
if sys.argv[1] == "tuned":
    from lenssim_cli.main import tune_allocator
    assert tune_allocator() is True
print(before, mapped_bytes(n))
"""


def _glibc_with_mallinfo2() -> bool:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        return bool(libc.gnu_get_libc_version) and bool(libc.mallinfo2)
    except (OSError, AttributeError, TypeError):
        return False


@pytest.mark.skipif(not _glibc_with_mallinfo2(), reason="glibc >= 2.33 (mallinfo2) only")
@pytest.mark.parametrize("mode", ["default", "tuned"])
def test_tuned_heap_serves_batch_sized_buffers(mode):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}  # glibc's own defaults
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True,
                         env=env).stdout
    before, after = map(int, out.split())
    n = 40 * 2**20
    assert before >= n  # glibc's default maps a 40 MB buffer by itself (the page faults the tuning avoids)
    if mode == "tuned":
        assert after < n  # from the heap once tuned
    else:
        assert after >= n


def _is_glibc() -> bool:
    try:
        return bool(ctypes.CDLL(ctypes.util.find_library("c")).gnu_get_libc_version)
    except (OSError, AttributeError, TypeError):
        return False


def test_tune_allocator_reports_what_it_did():
    # in a fresh process: True on glibc; elsewhere False, and nothing changes
    code = "from lenssim_cli.main import tune_allocator; print(tune_allocator())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == str(_is_glibc())
