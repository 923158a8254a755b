"""Spare cores: how a step's own threads share the machine with the build's other tasks.

A local build runs ``-j N`` worker processes, and an LOD step may also spread one model's
meshes (or one mesh's levels) over threads. While the build has a task for every worker, such
threads only take cores from other workers' tasks, and two threads of one process share its
interpreter lock where two processes do not: a cold build of the corpus with ``-j 2`` took
12.9-13.1 s of CPU (6.8-7.0 s) with two threads an LOD step against 12.6-12.7 s (6.6 s) with
one (docs/BUILD.md). But without them a model built alone, or the last step of a build, uses
one core while the others idle.

So the build process counts the cores no task needs: a shared counter (:class:`SpareCores`,
made with the pool, :func:`install` in each worker) starts at ``N``; handing a task to the pool
takes one (it goes negative while tasks wait in the pool's queue), its end gives it back. A
helper thread of :func:`map_spare` works only while it holds a spare core it took from the
counter (> 0), and gives it back as soon as a task has been handed out meanwhile (the counter
below 0) or its items run out. Without a counter (a library call, a farm worker, ``-j 1``),
:func:`map_spare` uses the threads it is allowed, as before.

Results never depend on the threads: each item is computed alone, and results come back in
the items' order.
"""

from __future__ import annotations

import threading
import time
from typing import Callable, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: seconds between a waiting helper's looks at the counter
POLL_S = 0.02

_spare = None  # the pool's shared counter (multiprocessing.Value "i"), in a pool worker


class SpareCores:
    """The build process's side: ``jobs`` cores, one taken by each task handed to the pool
    until it ends. ``value``: the shared ``multiprocessing.Value`` to :func:`install` in the
    workers."""

    def __init__(self, ctx, jobs: int) -> None:
        self.value = ctx.Value("i", int(jobs))

    def task_started(self) -> None:
        with self.value.get_lock():
            self.value.value -= 1

    def task_ended(self, _future=None) -> None:
        with self.value.get_lock():
            self.value.value += 1


def install(spare) -> None:
    """Use the shared counter ``spare`` (:attr:`SpareCores.value`, or None) in this process: a
    pool worker's initializer calls it."""
    global _spare
    _spare = spare


def _take(spare) -> bool:
    with spare.get_lock():
        if spare.value > 0:
            spare.value -= 1
            return True
    return False


def _give(spare) -> None:
    with spare.get_lock():
        spare.value += 1


def map_spare(fn: Callable[[T], R], items: Sequence[T], max_threads: int) -> list[R]:
    """``[fn(x) for x in items]``, on this thread and on up to ``max_threads - 1`` helper
    threads. With a counter (:func:`install`), a helper takes items only while it holds a spare
    core (see the module docstring); without one, ``min(max_threads, len(items))`` threads at
    once. Items are taken in order (put the largest first). An exception of ``fn`` is raised
    here once the items already started have ended (no new item is started after it)."""
    n = len(items)
    if max_threads <= 1 or n <= 1:
        return [fn(x) for x in items]
    spare = _spare
    if spare is None:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=min(max_threads, n)) as pool:
            return list(pool.map(fn, items))
    results: list = [None] * n
    lock = threading.Lock()
    ended = threading.Condition(lock)
    state = {"next": 0, "ended": 0, "error": None}

    def take() -> int | None:
        with lock:
            i = state["next"]
            if i >= n or state["error"] is not None:
                return None
            state["next"] = i + 1
            return i

    def left() -> bool:
        with lock:
            return state["next"] < n and state["error"] is None

    def run(i: int) -> None:
        try:
            results[i] = fn(items[i])
        except BaseException as exc:  # kept for the caller; no thread takes a new item after it
            with lock:
                if state["error"] is None:
                    state["error"] = exc
        finally:
            with lock:
                state["ended"] += 1
                ended.notify_all()

    def helper() -> None:
        while left():
            if not _take(spare):
                time.sleep(POLL_S)
                continue
            try:
                while spare.value >= 0 and (i := take()) is not None:
                    run(i)
            finally:
                _give(spare)

    # helpers are not joined: one still waiting for a spare core when the items run out ends by
    # itself within POLL_S (it has taken no item, so the results are complete without it)
    for _ in range(min(max_threads, n) - 1):
        threading.Thread(target=helper, name="assetpipe-spare-core", daemon=True).start()
    while (i := take()) is not None:
        run(i)
    with lock:
        ended.wait_for(lambda: state["ended"] == state["next"])
    if state["error"] is not None:
        raise state["error"]
    return results


__all__ = ["SpareCores", "install", "map_spare", "POLL_S"]
