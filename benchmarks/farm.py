"""Build farm benchmark: the executor seam's overhead, the shared cache, bytes moved per step.

    .venv/bin/python benchmarks/farm.py [--quick] [--repeats 3] [--json FILE]

Everything is written under a private temporary directory; the corpus
(``$ASSETPIPE_CORPUS/models``, default ``../shared/corpus/models``) is only read. Builds run
in this process through ``run_build`` (the CLI's code path without the interpreter start-up).

1. Seam overhead. The whole corpus, cold (a fresh cache folder and output folder per build),
   built locally with ``jobs=2`` (a process pool of 2) and on a ``distributed.LocalCluster``
   of 2 worker processes (1 thread each) through :class:`assetpipe.executor.DaskExecutor`,
   interleaved (local, farm; farm, local; ...: each kind first in turn), median of ``--repeats``
   each. The cluster is started once, before the timings (its start-up is not counted), and
   warmed by one discarded farm build of ``examples/`` (a farm's workers are long-lived; the
   local pool is made per build, as in real use). Goal: farm / local <= 1.15. The outputs of
   the two are compared byte for byte. Besides wall time, every build's CPU seconds are summed
   over all its processes (this one, which also hosts the LocalCluster's scheduler; the local
   pool; the workers): a figure the other users of a shared machine disturb much less.
2. Shared cache. A moto S3 server (``moto_server``, its own process on 127.0.0.1) holds a
   remote tier seeded by one cold build. Then, interleaved, median of ``--repeats``: a build
   into a fresh output folder with the *local* tier warm (every step a local hit), against
   one with a fresh, empty local tier and the warm *remote* tier (every step fetched, verified
   and copied into the local tier). The S3 server shares the 2 cores with the build: its
   request handling is counted in the remote figure.
3. Bytes moved per step: from the farm builds of part 1 (bytes sent to workers with each
   task, bytes of blobs returned, worker seconds per step kind), from the seeding build of
   part 2 (bytes uploaded) and the warm remote builds (bytes downloaded, requests).

``--quick``: six corpus models (default options, LODs on), 2 repeats. ``--seam-only``: part 1
alone. ``--compare-malloc``: part 1 also times, in the same interleaved rounds, a farm build
whose workers keep the allocator as Dask's nanny leaves it (``MALLOC_TRIM_THRESHOLD_=65536``:
the executor before :func:`assetpipe.executor.step_malloc`). The load average (1 min) is
printed before and after every build: the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))  # farm_fixtures: the S3 server and cluster the tests use too

from assetpipe.build import run_build  # noqa: E402
from assetpipe.cache.remote import TieredStore  # noqa: E402
from assetpipe.cache.store import Store  # noqa: E402
from assetpipe.executor import DaskExecutor  # noqa: E402
from assetpipe.inputs import discover_inputs  # noqa: E402
from assetpipe.options import DEFAULT_BUILD_OPTIONS  # noqa: E402
from farm_fixtures import S3Server, make_cluster, tree  # noqa: E402

import farm_timeline  # noqa: E402  (beside this file: the workers' allocator as Dask leaves it)

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
QUICK_MODELS = ["Duck", "BoxTextured", "Avocado", "CesiumMilkTruck", "beast", "fuze"]


def _kb(n: float) -> str:
    return f"{n / 1024:,.1f} KB"


def _steps(report) -> int:
    return sum(len(r.steps) for r in report.results)


def _cpu_self() -> float:
    """User + system CPU seconds of this process (all its threads)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _cpu_children() -> float:
    """... of its reaped children (a finished build's process pool)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _report_seam(result: dict, farm_t: list[float], local_t: list[float], per_step: dict) -> None:
    seam = result["seam"]
    print()
    print(f"1. seam: farm (2-worker LocalCluster) / local -j 2, cold build: {seam['ratio']:.3f}x "
          f"(medians {statistics.median(farm_t):.2f} s / {statistics.median(local_t):.2f} s)  goal <= 1.15: "
          f"{'PASS' if seam['ratio'] <= 1.15 else 'FAIL'}")
    print(f"   per round (farm / local): {', '.join(f'{r:.2f}' for r in seam['pair_ratios'])}; "
          f"load average (1 min) {min(x for _, a, b in seam['loads'] for x in (a, b)):.1f}-"
          f"{max(x for _, a, b in seam['loads'] for x in (a, b)):.1f}")
    cpu = seam["cpu_s"]
    print(f"   CPU seconds of all the build's processes, farm / local: {seam['cpu_ratio']:.3f}x (medians "
          f"{statistics.median(cpu['farm']):.2f} / {statistics.median(cpu['local']):.2f} CPU-s)")
    if "dask_malloc_ratio" in seam:
        print(f"   farm with Dask's worker allocator (before the fix) / local -j 2: {seam['dask_malloc_ratio']:.3f}x "
              f"wall (median {statistics.median(seam['farm_dask_malloc_s']):.2f} s), "
              f"{seam['dask_malloc_cpu_ratio']:.3f}x CPU (median {statistics.median(cpu['farm-dask-malloc']):.2f} CPU-s)")
    print(f"   outputs byte-identical across all builds: {result['outputs_identical']}")
    print("3. bytes moved per step (farm build of part 1; per task):")
    print(f"   {'step':14s} {'tasks':>6s} {'to worker':>12s} {'from worker':>12s} {'worker s':>9s}")
    for name, st in sorted(per_step.items()):
        n = max(st["tasks"], 1)
        print(f"   {name:14s} {st['tasks']:6d} {_kb(st['to_workers'] / n):>12s} {_kb(st['from_workers'] / n):>12s} "
              f"{st['seconds'] / n:9.3f}")
    fm = result["farm_moved"]
    print(f"   all steps: {fm.get('tasks', 0)} tasks, {_kb(fm.get('to_workers', 0))} to workers, "
          f"{_kb(fm.get('from_workers', 0))} back; the client spent {fm.get('client_s', 0.0):.2f} s reading "
          "inputs, submitting, fetching, checking and storing results")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--seam-only", action="store_true", help="part 1 only")
    ap.add_argument("--compare-malloc", action="store_true",
                    help="also time farm builds with Dask's worker allocator settings (the executor before the fix)")
    args = ap.parse_args()
    repeats = args.repeats or (2 if args.quick else 3)
    if args.quick:
        inputs = [CORPUS / m for m in QUICK_MODELS if (CORPUS / m).exists()]
    else:
        inputs = [CORPUS]
    files = discover_inputs(inputs)
    if not files:
        print(f"no model files under {CORPUS} (set ASSETPIPE_CORPUS)", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="assetpipe-farm-bench-"))
    os.environ["ASSETPIPE_CACHE"] = str(tmp / "default-cache")  # nothing touches the user's cache
    opts = DEFAULT_BUILD_OPTIONS
    print(f"farm benchmark: {len(files)} model files from {CORPUS}, {repeats} repeats, temp {tmp}", flush=True)
    result: dict = {"models": len(files), "repeats": repeats}

    # -- 1. the seam ------------------------------------------------------------------------
    t0 = time.perf_counter()
    cluster = make_cluster()
    print(f"LocalCluster (2 worker processes) up in {time.perf_counter() - t0:.1f} s", flush=True)
    try:
        warm = DaskExecutor(cluster.scheduler_address)
        run_build([REPO / "examples"], tmp / "warm-out", opts, cache_dir=Store(tmp / "warm-cache"), scheduler=warm)
        warm.close()
        per_step, moved = {}, []
        kinds = ["local", "farm"] + (["farm-dask-malloc"] if args.compare_malloc else [])
        times: dict[str, list[float]] = {k: [] for k in kinds}
        cpus: dict[str, list[float]] = {k: [] for k in kinds}
        loads = []
        ref = None
        import cloudpickle
        from distributed import Client

        cloudpickle.register_pickle_by_value(farm_timeline)  # workers cannot import benchmarks/
        admin = Client(cluster.scheduler_address, set_as_default=False)
        for i in range(repeats):
            order = kinds[i % len(kinds):] + kinds[:i % len(kinds)]  # each kind first in turn
            for kind in order:
                out, cache = tmp / f"{kind}{i}-out", Store(tmp / f"{kind}{i}-cache")
                if args.compare_malloc and kind != "local":
                    admin.run(farm_timeline._set_malloc, kind == "farm-dask-malloc")
                load0 = os.getloadavg()[0]
                # CPU seconds of every process of the build: this one (the client, and the
                # LocalCluster's scheduler), the local pool (reaped: RUSAGE_CHILDREN), the workers
                w0 = sum(admin.run(_cpu_self).values())
                c0 = _cpu_self() + _cpu_children()
                t0 = time.perf_counter()
                if kind == "local":
                    report = run_build(inputs, out, opts, jobs=2, cache_dir=cache)
                else:
                    ex = DaskExecutor(cluster.scheduler_address)
                    report = run_build(inputs, out, opts, cache_dir=cache, scheduler=ex)
                    ex.close()
                    if kind == "farm":
                        per_step, moved = ex.per_step, moved + [ex.moved]
                dt = time.perf_counter() - t0
                cpu = _cpu_self() + _cpu_children() - c0 + sum(admin.run(_cpu_self).values()) - w0
                times[kind].append(dt)
                cpus[kind].append(cpu)
                failed = [r.id for r in report.results if r.status == "failed"]
                loads.append((kind, load0, os.getloadavg()[0]))
                print(f"  repeat {i + 1} {kind:16s} {dt:7.2f} s, CPU {cpu:6.2f} s  "
                      f"({len(report.results)} assets, {_steps(report)} steps, failed: {failed or 'none'}; "
                      f"load {load0:.1f} -> {os.getloadavg()[0]:.1f})", flush=True)
                t = tree(out)
                if ref is None:
                    ref = t
                elif t != ref:
                    print("  OUTPUTS DIFFER between builds", flush=True)
                    result["outputs_identical"] = False
        result.setdefault("outputs_identical", True)
        admin.close()
    finally:
        cluster.close()
    local_t, farm_t, dask_malloc_t = times["local"], times["farm"], times.get("farm-dask-malloc", [])
    ratio = statistics.median(farm_t) / statistics.median(local_t)
    result["seam"] = {"local_j2_s": local_t, "farm_2_workers_s": farm_t, "ratio": ratio, "loads": loads,
                      "pair_ratios": [f / l for f, l in zip(farm_t, local_t)], "cpu_s": cpus,
                      "cpu_ratio": statistics.median(cpus["farm"]) / statistics.median(cpus["local"])}
    if dask_malloc_t:
        result["seam"]["farm_dask_malloc_s"] = dask_malloc_t
        result["seam"]["dask_malloc_ratio"] = statistics.median(dask_malloc_t) / statistics.median(local_t)
        result["seam"]["dask_malloc_cpu_ratio"] = (statistics.median(cpus["farm-dask-malloc"])
                                                   / statistics.median(cpus["local"]))
    result["per_step"] = per_step
    result["farm_moved"] = moved[-1] if moved else {}

    if args.seam_only:
        _report_seam(result, farm_t, local_t, per_step)
        if args.json:
            args.json.write_text(json.dumps(result, indent=1, default=str))
        return 0

    # -- 2. the shared cache ----------------------------------------------------------------
    s3 = S3Server()
    try:
        url = s3.url("bench")
        seed = TieredStore(Store(tmp / "seed-local"), url)
        t0 = time.perf_counter()
        report = run_build(inputs, tmp / "seed-out", opts, jobs=2, cache_dir=seed)
        seed_s = time.perf_counter() - t0
        n_steps = _steps(report)
        print(f"  seeding build (cold, -j 2, uploading): {seed_s:.2f} s, {n_steps} steps, "
              f"up {_kb(seed.moved['up'])} in {seed.moved['puts']} PUTs", flush=True)
        warm_local, warm_remote, down = [], [], []
        for i in range(repeats):
            order = ("local", "remote") if i % 2 == 0 else ("remote", "local")
            for kind in order:
                out = tmp / f"warm-{kind}{i}-out"
                store = Store(tmp / "seed-local") if kind == "local" else TieredStore(Store(tmp / f"r{i}-local"), url)
                t0 = time.perf_counter()
                r = run_build(inputs, out, opts, jobs=2, cache_dir=store)
                dt = time.perf_counter() - t0
                ran = sum(s["ran"] for x in r.results for s in x.steps)
                (warm_local if kind == "local" else warm_remote).append(dt)
                if kind == "remote":
                    down.append(dict(store.moved))
                print(f"  repeat {i + 1} warm {kind:6s} {dt:7.2f} s  (steps run: {ran})", flush=True)
                if tree(out) != ref:
                    print("  OUTPUTS DIFFER from the seam builds", flush=True)
                    result["outputs_identical"] = False
        cache_ratio = statistics.median(warm_remote) / statistics.median(warm_local)
        result["cache"] = {"seed_s": seed_s, "seed_moved": seed.moved, "warm_local_s": warm_local,
                           "warm_remote_s": warm_remote, "ratio": cache_ratio, "remote_moved": down[-1],
                           "steps": n_steps}
    finally:
        s3.stop()

    # -- report -----------------------------------------------------------------------------
    _report_seam(result, farm_t, local_t, per_step)
    print(f"2. shared cache: warm remote tier (empty local) / warm local tier: {cache_ratio:.2f}x "
          f"(medians {statistics.median(warm_remote):.2f} s / {statistics.median(warm_local):.2f} s)")
    sm, rm = result["cache"]["seed_moved"], result["cache"]["remote_moved"]
    print(f"   remote tier, cold seeding build: up {_kb(sm['up'])} in {sm['puts']} PUTs "
          f"({_kb(sm['up'] / n_steps)} and {sm['puts'] / n_steps:.1f} PUTs per step)")
    print(f"   remote tier, warm build on a fresh machine: down {_kb(rm['down'])} in {rm['gets']} GETs "
          f"({_kb(rm['down'] / n_steps)} per step; {rm['records_fetched']} records)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
