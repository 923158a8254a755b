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


_WARM = r"""
import sys, threading
from assetpipe.worker_life import warm_lod_kernels
warm_lod_kernels()
import numba.np.arraymath as am
print(am._HAVE_BLAS, "scipy.linalg" in sys.modules)
# another thread, and this one after the warm-up, import scipy.linalg as usual
got = []
t = threading.Thread(target=lambda: got.append(__import__("scipy.linalg").linalg.norm([3.0, 4.0])))
t.start(); t.join()
print(got == [5.0])
"""


def test_warm_up_loads_the_kernels_without_scipy():
    """The build process's warm-up skips numba's BLAS check (0.25-0.33 s: it imports
    scipy.linalg), and only for itself: scipy still imports afterwards."""
    out = subprocess.run([sys.executable, "-c", _WARM], check=True, capture_output=True, text=True)
    assert out.stdout.split() == ["False", "False", "True"], out.stdout + out.stderr


def test_no_compiled_kernel_calls_blas():
    """Workers forked after the warm-up have numba without BLAS (above): a kernel calling
    np.dot, np.linalg, np.matmul, np.vdot, np.inner, np.outer or ``@`` would fail to compile in
    them. Every numba-compiled function of the project, read from its source."""
    import ast
    from pathlib import Path

    import assetpipe
    import assetpipe.cache
    import assetpipe.pipelines
    import assetpipe.renderer

    roots = [Path(assetpipe.__file__).parent] + [Path(p) for m in (assetpipe.pipelines, assetpipe.cache,
                                                                   assetpipe.renderer) for p in m.__path__]
    kernels = 0
    for root in roots:
        for path in root.rglob("*.py"):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if not isinstance(node, ast.FunctionDef):
                    continue
                decos = [ast.unparse(d) for d in node.decorator_list]
                if not any(d.startswith(("njit", "numba.njit", "jit", "numba.jit")) for d in decos):
                    continue
                kernels += 1
                for sub in ast.walk(node):
                    bad = (isinstance(sub, ast.BinOp) and isinstance(sub.op, ast.MatMult)) or (
                        isinstance(sub, ast.Attribute) and sub.attr in ("dot", "linalg", "matmul", "vdot", "inner", "outer"))
                    assert not bad, f"{path}:{sub.lineno}: {node.name} uses BLAS ({ast.unparse(sub)})"
    assert kernels >= 40, kernels  # the kernels were found (closest_point, distance_kernels, ...)


_THREADS = r"""
import os
import assetpipe.cli  # sets the default before numpy is imported
import numpy as np
np.ones((1000, 3)) @ np.eye(3)
print(os.environ["OPENBLAS_NUM_THREADS"], len(os.listdir("/proc/self/task")))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts the threads in /proc/self/task")
def test_the_cli_runs_blas_on_one_thread_unless_told_otherwise():
    """numpy's OpenBLAS would start a thread per core (spinning after each call, beside the
    workers): the CLI asks for one, and a value the caller set is kept."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", _THREADS], check=True, capture_output=True, text=True, env=env)
    value, threads = out.stdout.split()
    assert value == "1" and int(threads) == 1, out.stdout
    out = subprocess.run([sys.executable, "-c", _THREADS], check=True, capture_output=True, text=True,
                         env={**env, "OPENBLAS_NUM_THREADS": "2"})
    value, threads = out.stdout.split()
    assert value == "2" and int(threads) >= 2, out.stdout  # the caller's choice: BLAS threads start


def _frozen() -> int:
    import gc

    return gc.get_freeze_count()


def test_workers_freeze_what_they_inherit():
    """A pool worker's collector skips the objects it inherited (gc.freeze in init_worker)."""
    from assetpipe.graph import Executor

    ex = Executor(2)
    try:
        got = ex.map([(_frozen,), (_frozen,)])
    finally:
        ex.close()
    # a bare interpreter that imported the graph holds about 35,000 tracked objects, all inherited
    # (0 without the freeze)
    assert [r[0] for r in got] == ["ok", "ok"] and all(r[1] > 10_000 for r in got), got
