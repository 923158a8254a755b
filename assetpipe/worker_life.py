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

import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
WATCH_INTERVAL_S = 1.0


def init_worker(parent_pid: int) -> None:
    """Pool initializer: tie this worker's life to ``parent_pid`` (the build process)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watch thread below still applies
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="assetpipe-parent-watch", daemon=True).start()


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(WATCH_INTERVAL_S)
        if os.getppid() != parent_pid:
            os._exit(1)
