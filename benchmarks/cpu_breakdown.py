"""Where a cold build's CPU goes: per step, per model (beside gltfpack's on the same file), and
inside the LOD steps. A diagnosis, not a goal: it says which part a speed-up has to come from.

Run:  .venv/bin/python benchmarks/cpu_breakdown.py [INPUT ...] [--no-models] [--no-gltfpack]

Everything runs in this process with ``-j 1`` (steps inline, one thread a step), after a
warm-up build of a small model so that the compiled kernels are loaded before anything is
timed (a ``-j 2`` build forks its workers from a process that loaded them). CPU is this
process's (``time.process_time``).

1. The inputs (default: the shared corpus) built cold: CPU per step kind, and inside the LOD
   steps the recorded bounds (``measure_levels``), the candidates' estimates, the candidates'
   simplifications (meshoptimizer's WASM ``simplifyWithUpdate`` separately) and the balance
   curves, each timed by wrapping it; then the recorded bounds split by direction (level 0 ->
   level, level -> level 0) and level size: CPU, first-pass cells (the source side's
   triangles) and engine queries; the bound's stages (the cells each is given, the cells it
   settles, its CPU; the height field's cells by why it gave up, ``patch_bound.WHY_*``); and
   the ten most expensive directions one by one (level 0's and the level's triangles, whether
   the level's vertices moved, its bound and the largest distance it evaluated).
2. With ``--models`` (the default), each model file built cold alone: its CPU against
   ``gltfpack -si 0.5`` on the same file (CPU of the process, its start-up included: what the
   cold-build benchmark runs), largest first.
"""

from __future__ import annotations

import argparse
import collections
import inspect
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from cold_build import CORPUS, find_gltfpack  # noqa: E402


def _build(inputs: list[str], folder: str) -> None:
    from assetpipe.cli import main

    try:
        main(["build", *inputs, "-o", f"{folder}/out", "--cache", f"{folder}/cache", "-j", "1", "-q"],
             standalone_mode=False)
    except SystemExit:
        pass


class Timer:
    """CPU seconds of wrapped functions, by label (a function called from another wrapped one
    counts in both), and any counts ``tally`` takes from their results."""

    def __init__(self) -> None:
        self.seconds: collections.Counter = collections.Counter()
        self.calls: collections.Counter = collections.Counter()
        self.counts: dict = collections.defaultdict(collections.Counter)

    def wrap(self, owner, name: str, label=None, tally=None):
        """Time ``owner.name`` from now on; ``label``: a name, or a function of the call's
        arguments giving one (default: ``name``); ``tally``: a function of (result, the call's
        arguments) giving a dict of counts added to ``counts[label]``. Returns the function it
        replaced."""
        real = getattr(owner, name)
        label_of = label if callable(label) else (lambda *a, **k: label or name)

        def timed(*args, **kwargs):
            t = time.process_time()
            result = None
            try:
                result = real(*args, **kwargs)
                return result
            finally:
                key = label_of(*args, **kwargs)
                self.seconds[key] += time.process_time() - t
                self.calls[key] += 1
                if tally is not None and result is not None:
                    self.counts[key].update(tally(result, *args, **kwargs))

        setattr(owner, name, timed)
        return real

    def clear(self) -> None:
        self.seconds.clear(), self.calls.clear(), self.counts.clear()


def _direction_label(src, dst, *args, **kwargs) -> tuple[str, int]:
    """A recorded bound's direction (``surface_error._direction(src, dst, ...)``) and the level's
    size against level 0: k where the level has about 1/2^k of level 0's triangles (the nearest
    power of two: a balanced mesh's levels fall in the bucket nearest their own ratio)."""
    small, big = sorted((src.tri.shape[0], dst.tri.shape[0]))
    k = round(math.log2(big / small)) if small else 0
    return ("level 0 -> level" if src.tri.shape[0] >= dst.tri.shape[0] else "level -> level 0", k)


def _direction_tally(result, src, dst, *args, **kwargs) -> dict:
    return {"cells": src.tri.shape[0], "queries": result[0].queries}


ORDER = ("recorded bounds (measure_levels)", "candidates' estimates", "candidates' simplifications",
         "  of them meshoptimizer's WASM (moved)", "balance curves")


#: the height field's reasons, in the order of ``pipelines.patch_bound.WHY_*``
WHY = ("bounded", "skipped", "too many", "uncovered", "border", "non-manifold", "folded")


def _stage_tallies(timer: Timer, surface_error) -> None:
    """Time the bound's stages where ``_bound_direction`` calls them (``surface_error``'s
    namespace): per stage the cells given, the ones it settles (bound <= the threshold it was
    given) and, for the height field, why it gave up on the others."""
    def settled(ub, thr) -> dict:
        return {"cells": int(ub.shape[0]), "settled": int((ub <= thr).sum())}

    timer.wrap(surface_error, "near_bounds", "near bounds (Lipschitz, convexity, pair)",
               tally=lambda r, v, d, f, hint, thr, *a: settled(r[0], thr))
    timer.wrap(surface_error, "patch_bound_seeded", "height field",
               tally=lambda r, v, rho, *a: {**settled(r[0], rho[0] if rho.size else 0.0),
                                            **dict(zip(WHY, np.bincount(r[1], minlength=len(WHY)).tolist()))})
    timer.wrap(surface_error, "pair_bound", "pair bound (after the centroid query)",
               tally=lambda r, *a: settled(r, a[-1]))
    timer.wrap(surface_error._Engine, "query", "engine queries (first pass and splits)",
               tally=lambda r, engine, points, *a, **k: {"cells": int(points.shape[0])})


def breakdown(inputs: list[str]) -> None:
    from assetpipe import steps
    from assetpipe.pipelines import lod, lod_model, meshopt_wasm, surface_error

    by_step = Timer()
    inner = Timer()
    directions = Timer()
    stages = Timer()
    # the bound's directions, by direction and level size; the signature of the function wrapped
    signature = inspect.signature(directions.wrap(surface_error, "_direction", _direction_label,
                                                  _direction_tally))
    _stage_tallies(stages, surface_error)
    # per direction: (CPU s, source's triangles, target's triangles, moved, bound, largest evaluated)
    each: list[tuple] = []
    timed_direction = surface_error._direction

    def one_direction(*args, **kwargs):
        src, dst = args[0], args[1]
        t = time.process_time()
        res = timed_direction(*args, **kwargs)
        # a moved level: its rows equal to level 0's are given (``same``)
        moved = signature.bind(*args, **kwargs).arguments.get("same") is not None
        each.append((time.process_time() - t, src.tri.shape[0], dst.tri.shape[0], moved,
                     res[0].upper, res[0].lower))
        return res

    surface_error._direction = one_direction
    lod_model.LOD_THREADS = 1  # one thread: the wrapped parts' CPU adds up to the step's
    for (owner, name), label in zip([(lod, "measure_levels"), (lod._Estimator, "__call__"),
                                     (lod, "_candidates"), (meshopt_wasm, "simplify_with_update"),
                                     (lod_model, "balanced_ratios")], ORDER):
        inner.wrap(owner, name, label)
    with tempfile.TemporaryDirectory() as d:
        _build([str(REPO / "examples")], f"{d}/warm")
        # the wrapped parts count from here (the warm-up build's LOD steps ran through them too)
        inner.clear(), directions.clear(), stages.clear(), each.clear()
        real_call = by_step.wrap(steps, "call_task", label=lambda fn, *args: fn.__name__)
        try:
            t = time.process_time()
            _build(inputs, f"{d}/cold")
            total = time.process_time() - t
        finally:
            steps.call_task = real_call
    print(f"cold build of {', '.join(inputs)} at -j 1: {total:.2f} s of CPU")
    for name, s in by_step.seconds.most_common():
        print(f"  {name:24s} {s:7.2f} s  ({by_step.calls[name]} calls)")
    print(f"  {'(outside the steps)':24s} {total - sum(by_step.seconds.values()):7.2f} s")
    print(f"inside the LOD steps (of {by_step.seconds['task_lod']:.2f} s):")
    for name in ORDER:
        print(f"  {name:40s} {inner.seconds[name]:7.2f} s  ({inner.calls[name]} calls)")
    print("  the recorded bounds by direction, and by level size (the level has about 1/N of level 0's triangles):")
    for (name, k) in sorted(directions.seconds):
        c = directions.counts[(name, k)]
        print(f"    {name:18s} 1/{2 ** k:<4d} {directions.seconds[(name, k)]:7.2f} s  "
              f"{c['cells']:9d} first-pass cells  {c['queries']:9d} queries")
    print("  the bound's stages (cells given, cells settled; the height field's others by why it gave up):")
    for name in sorted(stages.seconds, key=lambda n: -stages.seconds[n]):
        c = stages.counts[name]
        why = ", ".join(f"{w} {c[w]}" for w in WHY[1:] if c.get(w))
        print(f"    {name:40s} {stages.seconds[name]:7.2f} s  {c['cells']:9d} cells"
              + (f"  {c['settled']:9d} settled" if "settled" in c else "") + (f"  ({why})" if why else ""))
    print("  the ten most expensive directions (bounds in fractions of level 0's diagonal):")
    for sec, n_src, n_dst, moved, upper, low in sorted(each, reverse=True)[:10]:
        way = "level 0 -> level" if n_src >= n_dst else "level -> level 0"
        print(f"    {sec:6.2f} s  {way}  level 0 {max(n_src, n_dst):7d} triangles, level {min(n_src, n_dst):7d}"
              f"{' (moved)' if moved else '        '}  bound {upper:.3g}, largest evaluated {low:.3g}")


def per_model(inputs: list[str], gltfpack: str | None) -> None:
    from assetpipe.inputs import discover_inputs

    files = discover_inputs(inputs)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        _build([str(REPO / "examples")], f"{d}/warm")
        for i, f in enumerate(files):
            t = time.process_time()
            _build([str(f)], f"{d}/m{i}")
            ours = time.process_time() - t
            theirs = None
            if gltfpack is not None:
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                r = subprocess.run([gltfpack, "-i", str(f), "-o", f"{d}/g{i}.glb", "-si", "0.5"],
                                   capture_output=True)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                if r.returncode == 0:
                    theirs = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
            rows.append((ours, theirs, os.path.relpath(f, inputs[0]) if len(inputs) == 1 else str(f)))
    rows.sort(key=lambda r: -r[0])
    print("per model, built alone (CPU s): ours, gltfpack -si 0.5 (its process start-up included)")
    for ours, theirs, name in rows:
        g = f"{theirs:6.2f}  {ours / theirs:5.1f}x" if theirs else "     -       "
        print(f"  {ours:6.2f}  {g}  {name}")
    known = [r for r in rows if r[1]]
    if known:
        print(f"  total {sum(r[0] for r in known):.2f} s against {sum(r[1] for r in known):.2f} s "
              f"over {len(known)} files both built")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inputs", nargs="*", help="models or folders (default: the shared corpus)")
    ap.add_argument("--no-models", action="store_true", help="skip the per-model part")
    ap.add_argument("--no-gltfpack", action="store_true", help="per model, ours only")
    args = ap.parse_args()
    inputs = args.inputs or [str(CORPUS)]
    if not all(Path(p).exists() for p in inputs):
        sys.exit(f"no such input: {[p for p in inputs if not Path(p).exists()]}")
    breakdown(inputs)
    if not args.no_models:
        per_model(inputs, None if args.no_gltfpack else find_gltfpack())


if __name__ == "__main__":
    main()
