"""Build worker processes die with the build that started them.

A build killed with SIGKILL cannot shut its process pool down: its workers would stay alive
under PID 1 for ever, blocked reading a queue nobody writes (#13: 116 MB and 209 MB each).
:func:`init_worker` runs first in every pool worker:

* on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the worker the moment the
  thread that forked it (the build's main thread) exits, however it exits;
* everywhere, a daemon thread that polls the parent pid once a second and exits when the
  worker has been re-parented (the parent is gone): the fallback where prctl is missing.

A worker holds nothing that needs cleaning up: the cache and the output folder are written
by temporary file and rename, so a worker killed mid-write leaves at most a temporary that
the next build sweeps.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
WATCH_INTERVAL_S = 1.0


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask, as ninja counts them), at least 1: the
    default worker count (here, not in :mod:`assetpipe.api`, so that the CLI's no-op build does
    not import the API's modules)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def init_worker(parent_pid: int, spare=None) -> None:
    """Pool initializer: tie this worker's life to ``parent_pid`` (the build process); ``spare``:
    the pool's shared count of the cores no task needs (:mod:`assetpipe.core.cores`), or None."""
    from assetpipe.core import cores

    cores.install(spare)
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watch thread below still applies
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="assetpipe-parent-watch", daemon=True).start()
    # what the worker inherited (modules, the loaded kernels) lives as long as it does: the cyclic
    # collector leaves it alone from now on instead of walking it at every full collection (and
    # writing to its pages, which copies them from the parent); reference counting still frees
    gc.freeze()


#: glibc malloc: blocks up to this size come from the heap, not a fresh mmap each (M_MMAP_THRESHOLD)
MMAP_THRESHOLD = 256 << 20
#: glibc malloc: freed heap memory is given back to the system only beyond this (M_TRIM_THRESHOLD)
TRIM_THRESHOLD = 512 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # <malloc.h>


def keep_freed_memory() -> bool:
    """Let this process (and the workers it forks afterwards) reuse the memory it frees.

    By default glibc maps every block over 128 kB-32 MB afresh and unmaps it when freed, so
    each large numpy temporary (a decoded texture, a mip level, a bound's cell arrays) costs
    the kernel a page fault per 4 kB page zeroed again. A cold build of the corpus (``-j 2``,
    build process and workers) took 458-498k page faults and 2.44-2.54 s of system time that
    way; kept on the heap (blocks up to :data:`MMAP_THRESHOLD`, trimmed beyond
    :data:`TRIM_THRESHOLD`), 263-265k and 1.91-1.96 s, with the same peak (441-444 MB); the
    texture tasks' faults 177k -> 41k. Results do not depend on it. Returns whether it applied
    (glibc only)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(WATCH_INTERVAL_S)
        if os.getppid() != parent_pid:
            os._exit(1)


class _NoBlasCheck:
    """A meta-path finder that refuses ``scipy.linalg`` to one thread (the one that made it).

    numba's first compile or cache load imports ``numba.np.arraymath``, which imports
    ``scipy.linalg.cython_blas`` only to learn whether ``np.dot`` and ``np.linalg`` may call BLAS
    in compiled code. That import costs the build process 0.25-0.33 s of CPU at start-up (scipy's
    array-API layer walks numpy's attributes and so imports ``numpy.f2py`` and ``numpy.testing``),
    and no kernel of ours uses BLAS (``tests/test_worker_life.py`` checks the kernel modules). With
    the import refused numba records "no BLAS" and loads every kernel as before. Other threads
    import scipy as usual, and a process that has imported it already is not affected."""

    def __init__(self) -> None:
        self.thread = threading.get_ident()

    def find_spec(self, name, path=None, target=None):
        if name == "scipy.linalg" and threading.get_ident() == self.thread:
            raise ModuleNotFoundError("scipy.linalg is not loaded for numba's BLAS check", name=name)
        return None


def warm_lod_kernels() -> None:
    """Load the LOD step's compiled kernels in this process (numba's import, its first-use
    set-up without scipy (:class:`_NoBlasCheck`) and the cached kernels: about 0.55 s in a fresh
    process here, this chain included, against 0.85 s with numba's BLAS check),
    so that worker processes forked afterwards inherit them instead of each loading its own
    (:meth:`assetpipe.graph.Executor.warm`). A small sphere's chain, measured, on the native
    simplifier alone (not the WASM runtime, which starts threads a fork must not copy), and the
    texture step's modules and kernels (:func:`_warm_textures`): a worker's first texture took
    0.26-0.40 s of CPU more than its second when forked without them, 0.01 s with them, for
    0.07 s here. OpenCV's import starts a thread too, but this build's parallel framework
    (pthreads) starts its pool again in a forked child: workers forked after it filter large
    images as before (``tests/test_graph.py``)."""
    finder = _NoBlasCheck()
    sys.meta_path.insert(0, finder)
    try:
        _warm_chain()
        _warm_textures()
    finally:
        sys.meta_path.remove(finder)


def _warm_chain() -> None:
    import numpy as np

    from assetpipe.pipelines.lod import LodOptions, build_lod_chain

    u, v = np.meshgrid(np.linspace(0.0, np.pi, 13), np.linspace(0.0, 2.0 * np.pi, 25), indexing="ij")
    pos = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(12), np.arange(24), indexing="ij")
    a = (i * 25 + j).reshape(-1)
    tri = np.concatenate([np.stack([a, a + 25, a + 1], 1), np.stack([a + 1, a + 25, a + 26], 1)])
    build_lod_chain(pos, tri.astype(np.uint32), options=LodOptions(move_vertices=False))


def _warm_textures() -> None:
    """The texture step's modules (Pillow, OpenCV) and compiled kernels, loaded by mip chains of
    tiny images for every kind of chain (colour with each alpha mode, normal map, linear)."""
    import numpy as np

    from assetpipe.pipelines.texture_mips import build_mip_chain

    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[..., :3] = 128
    rgba[..., 3] = np.arange(64, dtype=np.uint8).reshape(8, 8) * 4
    for role, mode in (("baseColor", "OPAQUE"), ("baseColor", "MASK"), ("baseColor", "BLEND"),
                       ("normal", "OPAQUE"), ("metallicRoughness", "OPAQUE")):
        build_mip_chain(rgba, role, mode)
