"""Where the farm's time goes: a per-task timeline of one local ``-j 2`` build and one build
on a 2-worker LocalCluster, side by side (issue #15, the seam's overhead).

    .venv/bin/python benchmarks/farm_timeline.py [MODEL ...] [--json FILE]
        [--order local,farm,farm-dask-malloc]

MODEL: folder names under ``$ASSETPIPE_CORPUS/models`` (default: the six of ``farm.py --quick``).
Every task records, in the process that runs it: wall start and stop (``time.time()``, one
clock for every process of the machine), the CPU and system seconds and minor page faults of
that process while it ran (``time.process_time()``, ``os.times()``, ``getrusage``: all its
threads), its thread count (``/proc/self/task``) and the ``OMP/MKL/OPENBLAS_NUM_THREADS`` it
saw. On a Dask worker the time around the step (version check, scratch store in and out) is
recorded too. The report gives, per build: one line per task on its process's lane, the totals
(busy seconds, CPU and system seconds, faults), the idle core-seconds, the time around the
steps on the workers, the order the LOD tasks started in and their CPU/wall ratio (above 1: a
step used more than one core). The outputs of the builds are compared.

Kinds of build (``--order``, default ``local,farm,farm-dask-malloc``): ``local`` (``jobs=2``),
``farm`` (the executor as it is), ``farm-dask-malloc`` (the same, with the workers' allocator
put back as Dask's nanny leaves it: ``MALLOC_TRIM_THRESHOLD_=65536``, so glibc's fixed 128 KiB
mmap threshold; what the executor did before :func:`assetpipe.executor.step_malloc`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
QUICK_MODELS = ["Duck", "BoxTextured", "Avocado", "CesiumMilkTruck", "beast", "fuze"]
LOG_ENV = "ASSETPIPE_TIMELINE_LOG"
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def _threads() -> int:
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return -1


def _arg_label(fn, args) -> str:
    name = fn.__name__.removeprefix("task_")
    for a in args[1:]:
        if isinstance(a, str) and (a.startswith("/") or a.startswith("xxh3:")):
            return f"{name} {Path(a).name if a.startswith('/') else a[5:13]}"
        if isinstance(a, dict) and a.get("name"):
            return f"{name} {a['name']}"
    return name


_INNER: dict = {}


def _log(rec: dict) -> None:
    with open(os.environ[LOG_ENV], "a") as f:
        f.write(json.dumps(rec) + "\n")


def _timed_call_task(fn, *args):
    import resource

    t0, c0, s0 = time.time(), time.process_time(), os.times().system
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    out = _INNER["call_task"](fn, *args)
    _log({"where": "step", "task": _arg_label(fn, args), "fn": fn.__name__, "pid": os.getpid(), "start": t0,
          "stop": time.time(), "cpu": time.process_time() - c0, "sys": os.times().system - s0,
          "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0, "threads": _threads(),
          "env": {k: os.environ.get(k) for k in THREAD_VARS}})
    return out


def _timed_run_on_worker(fn, args, inputs, fingerprint, *rest, **kw):
    t0 = time.time()
    out = _INNER["run_on_worker"](fn, args, inputs, fingerprint, *rest, **kw)
    _log({"where": "worker", "fn": fn.__name__, "pid": os.getpid(), "start": t0, "stop": time.time()})
    return out


def install(worker: bool = False) -> bool:
    """Wrap ``steps.call_task`` (and, on a Dask worker, ``executor.run_on_worker``) in this
    process so that every task appends one JSON line to ``$ASSETPIPE_TIMELINE_LOG``. The
    wrappers take the names they replace, so a process pool's pickles (by name) find them in
    its forked workers."""
    from assetpipe import executor, steps

    if "call_task" in _INNER:
        return False
    _INNER["call_task"] = steps.call_task
    _timed_call_task.__module__, _timed_call_task.__qualname__ = "assetpipe.steps", "call_task"
    steps.call_task = _timed_call_task
    if worker:
        _INNER["run_on_worker"] = executor.run_on_worker
        executor.run_on_worker = _timed_run_on_worker
    return True


def _install_on_worker(folder: str) -> bool:
    """On a Dask worker: import this file as a module there and install its wrappers."""
    if folder not in sys.path:
        sys.path.insert(0, folder)
    import farm_timeline

    return farm_timeline.install(worker=True)


def _set_malloc(dask_default: bool) -> str:
    """On a Dask worker: the allocator as Dask leaves it (``dask_default``), or as
    :func:`assetpipe.executor.step_malloc` sets it at the next task."""
    import ctypes

    from assetpipe import executor

    if dask_default:  # MALLOC_TRIM_THRESHOLD_=65536 and glibc's initial mmap threshold, fixed
        libc = ctypes.CDLL(None)
        libc.mallopt(executor.M_MMAP_THRESHOLD, 128 * 1024)
        libc.mallopt(executor.M_TRIM_THRESHOLD, int(os.environ.get("MALLOC_TRIM_THRESHOLD_", 128 * 1024)))
        executor._malloc_done = "Dask's: fixed 128 KiB mmap threshold, trim " + os.environ.get("MALLOC_TRIM_THRESHOLD_", "?")
        return executor._malloc_done
    executor._malloc_done = None
    return "step_malloc at the next task"


def _read(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def summarise(kind: str, rows: list[dict], t0: float, t1: float, cores: int) -> dict:
    steps_ = sorted((r for r in rows if r["where"] == "step"), key=lambda r: r["start"])
    around = [r for r in rows if r["where"] == "worker"]
    busy = sum(r["stop"] - r["start"] for r in steps_)
    cpu = sum(r["cpu"] for r in steps_)
    sys_ = sum(r["sys"] for r in steps_)
    faults = sum(r["faults"] for r in steps_)
    wall = t1 - t0
    lods = [r for r in steps_ if r["fn"] == "task_lod"]
    # on a worker: the time around each step (scratch store in and out, version check)
    extra = sum(w["stop"] - w["start"] for w in around) - (busy if around else 0.0)
    print(f"\n== {kind}: {wall:.2f} s wall; steps: {len(steps_)} tasks, {busy:.2f} s busy, {cpu:.2f} CPU-s "
          f"(CPU/busy {cpu / max(busy, 1e-9):.2f}; system {sys_:.2f} s, {faults} minor faults); "
          f"idle core-s {cores * wall - busy:.2f}; around the steps on the workers {extra:.2f} s")
    pids = sorted({r["pid"] for r in steps_})
    for r in steps_:
        lane = pids.index(r["pid"])
        print(f"   lane {lane} {r['start'] - t0:7.2f} -> {r['stop'] - t0:7.2f}  {r['stop'] - r['start']:6.2f} s "
              f"cpu {r['cpu']:6.2f} ({r['cpu'] / max(r['stop'] - r['start'], 1e-9):4.2f}x, sys {r['sys']:5.2f}, "
              f"{r['faults']:8d} faults) thr {r['threads']:3d}  {r['task']}  omp={r['env']['OMP_NUM_THREADS']}")
    return {"wall": wall, "busy": busy, "cpu": cpu, "sys": sys_, "faults": faults, "around": extra,
            "tasks": steps_, "lod_order": [r["task"] for r in lods],
            "lod_cpu_per_wall": [r["cpu"] / max(r["stop"] - r["start"], 1e-9) for r in lods]}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="*")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--order", default="local,farm,farm-dask-malloc")
    args = ap.parse_args()
    names = args.models or QUICK_MODELS
    inputs = [CORPUS / m for m in names if (CORPUS / m).exists()]
    tmp = Path(tempfile.mkdtemp(prefix="assetpipe-farm-timeline-"))
    os.environ["ASSETPIPE_CACHE"] = str(tmp / "default-cache")
    log = tmp / "timeline.jsonl"
    os.environ[LOG_ENV] = str(log)

    from assetpipe import executor as ex_mod
    from assetpipe.build import run_build
    from assetpipe.cache.store import Store
    from assetpipe.options import DEFAULT_BUILD_OPTIONS
    from farm_fixtures import make_cluster, tree

    install()  # before the local pool forks: its workers inherit the wrapper
    t0 = time.perf_counter()
    cluster = make_cluster()
    print(f"LocalCluster up in {time.perf_counter() - t0:.2f} s; {len(inputs)} models; temp {tmp}")
    from distributed import Client

    with Client(cluster.scheduler_address, set_as_default=False) as c:
        print("worker environ:", c.run(lambda: {k: os.environ.get(k) for k in THREAD_VARS}))
        c.run(_install_on_worker, str(Path(__file__).resolve().parent))
    warm = ex_mod.DaskExecutor(cluster.scheduler_address)
    run_build([REPO / "examples"], tmp / "warm-out", DEFAULT_BUILD_OPTIONS, cache_dir=Store(tmp / "warm-cache"),
              scheduler=warm)
    warm.close()
    result, trees = {}, {}
    try:
        for kind in args.order.split(","):
            log.unlink(missing_ok=True)
            out = tmp / f"{kind}-out"
            a = time.time()
            if kind == "local":
                run_build(inputs, out, DEFAULT_BUILD_OPTIONS, jobs=2, cache_dir=Store(tmp / f"{kind}-cache"))
            else:
                with Client(cluster.scheduler_address, set_as_default=False) as c:
                    print(f"{kind}: worker malloc:", set(c.run(_set_malloc, kind == "farm-dask-malloc").values()))
                ex = ex_mod.DaskExecutor(cluster.scheduler_address)
                run_build(inputs, out, DEFAULT_BUILD_OPTIONS, cache_dir=Store(tmp / f"{kind}-cache"), scheduler=ex)
                ex.close()
            b = time.time()
            result[kind] = summarise(kind, _read(log), a, b, 2)
            trees[kind] = tree(out)
    finally:
        cluster.close()
    if len(trees) == 2:
        print(f"\noutputs identical: {len(set(map(json.dumps, trees.values()))) == 1}")
    for kind, r in result.items():
        print(f"{kind}: wall {r['wall']:.2f} s, step CPU {r['cpu']:.2f} s (system {r['sys']:.2f} s, "
              f"{r['faults']} minor faults), LOD CPU {sum(t['cpu'] for t in r['tasks'] if t['fn'] == 'task_lod'):.2f} s, "
              f"LOD order {r['lod_order']}, LOD CPU/wall {[round(x, 2) for x in r['lod_cpu_per_wall']]}, "
              f"max threads {max((t['threads'] for t in r['tasks']), default=0)}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
