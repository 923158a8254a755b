"""Build farm benchmark: the executor seam's overhead, the shared cache, bytes moved per step.

    .venv/bin/python benchmarks/farm.py [--quick] [--repeats 3] [--json FILE]

Everything is written under a private temporary directory; the corpus
(``$ASSETPIPE_CORPUS/models``, default ``../shared/corpus/models``) is only read. Builds run
in this process through ``run_build`` (the CLI's code path without the interpreter start-up).

1. Seam overhead. The whole corpus, cold (a fresh cache folder and output folder per build),
   built locally with ``jobs=2`` (a process pool of 2) and on a ``distributed.LocalCluster``
   of 2 worker processes (1 thread each) through :class:`assetpipe.executor.DaskExecutor`,
   interleaved (local, farm, farm, local, ...), median of ``--repeats`` each. The cluster is
   started once, before the timings, and warmed by one discarded farm build of ``examples/``
   (a farm's workers are long-lived; the local pool is made per build, as in real use).
   Goal: farm / local <= 1.15. The outputs of the two are compared byte for byte.
2. Shared cache. A moto S3 server (``moto_server``, its own process on 127.0.0.1) holds a
   remote tier seeded by one cold build. Then, interleaved, median of ``--repeats``: a build
   into a fresh output folder with the *local* tier warm (every step a local hit), against
   one with a fresh, empty local tier and the warm *remote* tier (every step fetched, verified
   and copied into the local tier). The S3 server shares the 2 cores with the build: its
   request handling is counted in the remote figure.
3. Bytes moved per step: from the farm builds of part 1 (bytes sent to workers with each
   task, bytes of blobs returned, worker seconds per step kind), from the seeding build of
   part 2 (bytes uploaded) and the warm remote builds (bytes downloaded, requests).

``--quick``: six corpus models (default options, LODs on), 2 repeats.
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

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
QUICK_MODELS = ["Duck", "BoxTextured", "Avocado", "CesiumMilkTruck", "beast", "fuze"]


def _kb(n: float) -> str:
    return f"{n / 1024:,.1f} KB"


def _steps(report) -> int:
    return sum(len(r.steps) for r in report.results)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
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
        local_t, farm_t, per_step, moved = [], [], {}, []
        ref = None
        for i in range(repeats):
            order = ("local", "farm") if i % 2 == 0 else ("farm", "local")
            for kind in order:
                out, cache = tmp / f"{kind}{i}-out", Store(tmp / f"{kind}{i}-cache")
                t0 = time.perf_counter()
                if kind == "local":
                    report = run_build(inputs, out, opts, jobs=2, cache_dir=cache)
                    local_t.append(time.perf_counter() - t0)
                else:
                    ex = DaskExecutor(cluster.scheduler_address)
                    report = run_build(inputs, out, opts, cache_dir=cache, scheduler=ex)
                    farm_t.append(time.perf_counter() - t0)
                    ex.close()
                    per_step, moved = ex.per_step, moved + [ex.moved]
                failed = [r.id for r in report.results if r.status == "failed"]
                print(f"  repeat {i + 1} {kind:5s} {time.perf_counter() - t0:7.2f} s  "
                      f"({len(report.results)} assets, {_steps(report)} steps, failed: {failed or 'none'})", flush=True)
                t = tree(out)
                if ref is None:
                    ref = t
                elif t != ref:
                    print("  OUTPUTS DIFFER between builds", flush=True)
                    result["outputs_identical"] = False
        result.setdefault("outputs_identical", True)
    finally:
        cluster.close()
    ratio = statistics.median(farm_t) / statistics.median(local_t)
    result["seam"] = {"local_j2_s": local_t, "farm_2_workers_s": farm_t, "ratio": ratio}
    result["per_step"] = per_step
    result["farm_moved"] = moved[-1] if moved else {}

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
    print()
    print(f"1. seam: farm (2-worker LocalCluster) / local -j 2, cold corpus build: {ratio:.3f}x "
          f"(medians {statistics.median(farm_t):.2f} s / {statistics.median(local_t):.2f} s)  goal <= 1.15: "
          f"{'PASS' if ratio <= 1.15 else 'FAIL'}")
    print(f"   outputs byte-identical across all builds: {result['outputs_identical']}")
    print(f"2. shared cache: warm remote tier (empty local) / warm local tier: {cache_ratio:.2f}x "
          f"(medians {statistics.median(warm_remote):.2f} s / {statistics.median(warm_local):.2f} s)")
    print("3. bytes moved per step (farm build of part 1; per task):")
    print(f"   {'step':14s} {'tasks':>6s} {'to worker':>12s} {'from worker':>12s} {'worker s':>9s}")
    for name, st in sorted(per_step.items()):
        n = max(st["tasks"], 1)
        print(f"   {name:14s} {st['tasks']:6d} {_kb(st['to_workers'] / n):>12s} {_kb(st['from_workers'] / n):>12s} "
              f"{st['seconds'] / n:9.3f}")
    fm = result["farm_moved"]
    print(f"   all steps: {fm.get('tasks', 0)} tasks, {_kb(fm.get('to_workers', 0))} to workers, "
          f"{_kb(fm.get('from_workers', 0))} back")
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
