"""Build worker processes: the allocator setting they inherit (assetpipe/worker_life.py)."""

import platform
import subprocess
import sys

import pytest

# A child process allocates a 64 MB array and prints how many bytes glibc holds in separate
# mmapped blocks meanwhile (mallinfo2's hblkhd): by default such a block is mapped afresh (and
# unmapped when freed, its pages faulted in again next time); with the setting it comes from the
# heap, whose freed memory is reused.
_MAPPED = r"""
import ctypes, sys
import numpy as np
from assetpipe.worker_life import keep_freed_memory
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
                 "fordblks", "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = Info
if sys.argv[1] == "on":
    assert keep_freed_memory()
a = np.ones(8 << 20)
print(libc.mallinfo2().hblkhd)
"""


def _mapped_bytes(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _MAPPED, mode], check=True, capture_output=True, text=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt and mallinfo2")
def test_large_blocks_come_from_the_reused_heap():
    block = 64 << 20
    # the default maps the block by itself (so the check below can fail)
    assert _mapped_bytes("off") >= block
    # kept: nothing of that size is mapped apart (the interpreter's own small maps stay below)
    assert _mapped_bytes("on") < block
