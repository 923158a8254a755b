"""Build orchestration: inputs -> no-op check -> graph for what changed -> outputs -> report.

Each asset is isolated: an :class:`AssetError` fails that asset with one line naming the file
and the problem; any other exception is reported as an internal error (a bug of ours, with
its traceback in the report), and the other assets are built either way. Outputs are put in
place only from complete blobs, each file atomically, so a failure never leaves a partial
file and never touches the outputs of an earlier successful build.

The no-op path (every asset up to date) imports neither numpy nor any importer.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

from assetpipe.build_types import (DEFAULT_BUILD_LIMITS, AssetResult, AssetSpec, BuildLimits,  # noqa: F401 (public)
                                   BuildReport, options_digest)
from assetpipe.inputs import assign_ids, discover_inputs


def _format_exc() -> str:
    """The current exception's traceback (importing traceback, with textwrap, took 1.7 ms of a
    no-op build: only when something fails)."""
    import traceback

    return traceback.format_exc()


def _outputs_list(out_dir: Path, model_id: str) -> list[str]:
    base = os.path.join(out_dir, model_id)
    return [f"{base}.json", f"{base}-mat.json", f"{base}.asset.json"]


def run_build(inputs: list[str | Path], out_dir: Path, options, *, jobs: int = 1,
              cache_dir: Path | str | None = None,
              on_result: Callable[[AssetResult, int, int], None] | None = None,
              limits: BuildLimits = DEFAULT_BUILD_LIMITS, scheduler=None) -> BuildReport:
    """Build ``inputs`` (model files, folders, and scene files ``*.json``) into ``out_dir``.

    With scene files, only what the scenes reference is built (the other inputs are candidates,
    reported as skipped), each model with what its scenes need; ``OUT/<scene>.scene.json`` is
    written per scene.

    ``cache_dir``: a folder, an fsspec URL for a shared remote tier behind the local cache
    (:mod:`assetpipe.cache.remote`), or a store object. ``scheduler``: run the steps on a Dask cluster (an address
    ``tcp://HOST:PORT``, a ``distributed.Client`` or cluster, or an
    :class:`assetpipe.executor.DaskExecutor`); None: locally with ``jobs`` processes.

    One build at a time per output folder: a second one waits for ``OUT/.assetpipe/lock`` (and
    says so on stderr), then starts from the first one's state, so neither loses the other's
    sources or deletes its outputs."""
    from assetpipe import versions
    from assetpipe.cache.store import Store, default_cache_dir, is_url
    from assetpipe.core.writer import sweep_tmp

    scene_paths = [Path(p) for p in inputs if Path(p).suffix.lower() == ".json"]
    model_inputs = [p for p in inputs if Path(p).suffix.lower() != ".json"]
    sources = discover_inputs(model_inputs) if model_inputs else []
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    lock = _lock_output(out_dir)
    try:
        t0 = time.perf_counter()
        sweep_tmp(out_dir)
        if hasattr(cache_dir, "get_record"):  # a store made by the caller (a TieredStore, say)
            store = cache_dir
        elif is_url(cache_dir):  # a remote tier (the farm's shared cache) behind the local folder
            from assetpipe.cache.remote import open_store

            store = open_store(cache_dir)
        else:
            store = Store(Path(cache_dir) if cache_dir else default_cache_dir())
        versions.use_cache_dir(store.root)  # nothing is written outside -o and the cache
        session = store.begin_build(out_dir)  # for the cache collector and `assetpipe cache stats`
        return _run_locked(t0, sources, scene_paths, out_dir, options, jobs, store, session, on_result, limits, scheduler)
    finally:
        lock.close()


def _lock_output(out_dir: Path):
    """Take ``OUT/.assetpipe/lock`` (flock: released by the kernel when a killed build dies)."""
    import fcntl
    import sys

    from assetpipe.core.errors import ConfigError
    from assetpipe.core.writer import STATE_DIR

    hidden = out_dir / STATE_DIR
    root = os.path.realpath(out_dir)
    if os.path.islink(hidden) or os.path.commonpath([root, os.path.realpath(hidden)]) != root:
        raise ConfigError(f"{hidden} is a link leading out of the output folder: not writing there")
    hidden.mkdir(exist_ok=True)
    f = open(hidden / "lock", "a+b")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        print(f"assetpipe: waiting for another build into {out_dir} to finish", file=sys.stderr, flush=True)
        fcntl.flock(f, fcntl.LOCK_EX)
    return f


def _run_locked(t0, sources, scene_paths, out_dir, options, jobs, store, session, on_result, limits, scheduler) -> BuildReport:
    from assetpipe.cache.stat_cache import StatCache
    from assetpipe.state import OutputState

    stat = StatCache(store.root / "stat-cache.json")
    state = OutputState(out_dir)
    # a file name that is not UTF-8 cannot go into the build's JSON (its records, state and
    # outputs): that model fails with a line saying so, the others build (it failed every model of
    # the build before, each with a UnicodeEncodeError)
    sources, unnamed = _split_unnamed(sources)
    results: list[AssetResult] = list(unnamed)
    scene_run = None
    if scene_paths:
        from assetpipe.scene_build import SceneRun

        scene_run = SceneRun(scene_paths, sources, options, out_dir)
        specs = scene_run.specs()
        results.extend(scene_run.failed_results + scene_run.skipped_results)
    else:
        ids = assign_ids(sources)
        digest = options_digest(options.to_json())
        specs = [AssetSpec(source=s, id=ids[s], options=options, options_digest=digest, key=os.path.abspath(s))
                 for s in sources]

    by_key: dict[str, AssetResult] = {}
    todo: list[AssetSpec] = []
    why: dict[str, str] = {}
    total = len(specs)
    for r in unnamed if on_result else ():
        on_result(r, 0, total)
    for spec in specs:
        reason = state.check_entry(spec.key, spec.id, spec.options_digest, stat)
        if reason is None:
            entry = state.assets[spec.key]
            r = AssetResult(source=str(spec.source), id=spec.id, status="cached",
                            outputs=_outputs_list(out_dir, spec.id), warnings=list(entry.get("warnings", [])),
                            reason="up to date", stats=entry.get("stats", {}))
            r.skipped = list(entry.get("skipped", []))
            by_key[spec.key] = r
            if on_result:
                on_result(r, len(by_key), total)
        else:
            todo.append(spec)
            why[spec.key] = reason

    explain_steps = None
    if todo:
        explain_steps = _build_changed(todo, why, out_dir, store, stat, state, jobs, by_key, on_result, total,
                                       limits, scheduler)
    results = [by_key[s.key] for s in specs] + results
    if scene_run is not None:
        results.extend(scene_run.write_outputs(state, store, stat, by_key, jobs))
        state.forget_entries(scene_run.stale_entries(state))
    forgotten = state.forget_missing_sources()
    removed = state.delete_unowned_outputs()
    if todo or forgotten or removed or state.touched or scene_run is not None:
        try:
            state.save(explain_steps)
        except OSError as exc:  # a full disk, a read-only folder: one line, not a traceback
            from assetpipe.core.errors import ConfigError

            raise ConfigError(f"cannot write the build state in {out_dir}: {exc}") from None
    stat.save()
    store.end_build(session, out_dir, time.perf_counter() - t0)
    return BuildReport(results=results, seconds=time.perf_counter() - t0, removed=removed,
                       cache_dropped=list(store.dropped))


def _split_unnamed(sources: list[Path]) -> tuple[list[Path], list[AssetResult]]:
    """(the sources whose path is UTF-8 text, a failed result for each other one)."""
    named, failed = [], []
    for src in sources:
        try:
            str(src).encode("utf-8")
        except UnicodeEncodeError:
            shown = os.fsencode(src).decode("utf-8", "backslashreplace")  # the bytes that are not: \xff
            failed.append(AssetResult(source=shown, id="", status="failed",
                                      error=f"{shown}: the file name is not valid UTF-8 (rename the file): "
                                            "it cannot be written into the build's records and outputs"))
        else:
            named.append(src)
    return named, failed


def _build_changed(todo, why, out_dir, store, stat, state, jobs, by_key, on_result, total, limits,
                   scheduler=None) -> dict:
    from assetpipe.core.errors import AssetpipeError
    from assetpipe.graph import AssetState, Graph

    explain_prev = state.load_explain()
    executor = None
    if scheduler is not None:
        from assetpipe.executor import make_executor

        executor = make_executor(scheduler, store)
    graph = Graph(store, stat, todo[0].options, explain_prev, jobs=jobs, executor=executor)
    assets = [AssetState(source=s.source, id=s.id, options=s.options, plan=s.plan, extra_sources=s.extra_sources,
                         key=s.key) for s in todo]
    spec_of = {id(a): spec for spec, a in zip(todo, assets)}
    finished: set[int] = set()
    explain_steps = dict(explain_prev)

    def finish(a: AssetState) -> None:
        """Write a finished asset's outputs and its result (once): called by the graph as soon as
        the asset is done, while the others are still building, and here for the rest."""
        if id(a) in finished:
            return
        finished.add(id(a))
        spec = spec_of[id(a)]
        key = spec.key
        r = AssetResult(source=str(a.source), id=a.id, status="failed", seconds=a.seconds)
        r.steps = [{"step": run.step, "ran": run.ran, **({"reason": run.reason} if run.ran else {})}
                   for run in a.runs]
        r.skipped = list(dict.fromkeys(a.skipped))
        if not a.failed:
            try:
                _check_output_size(a, store, limits)
                table, notes = state.materialise(store, a.outputs, state.assets.get(key))
            except AssetpipeError as exc:
                a.error = f"{a.source}: {exc}"
            except OSError as exc:
                a.error = f"{a.source}: cannot write outputs to {out_dir} ({exc})"
            except MemoryError:
                a.error = f"{a.source}: out of memory writing its outputs"
            except Exception as exc:  # a bug of ours: this asset fails, the others are written
                a.error = f"{a.source}: internal error writing its outputs ({type(exc).__name__}: {exc}); please report it"
                a.internal = _format_exc()
            else:
                ran = [run for run in a.runs if run.ran]
                r.status = "built" if ran else "cached"
                reasons = [f"{run.step}: {run.reason}" for run in ran] + notes
                r.reason = "; ".join(reasons) if reasons else f"results cached ({why[key]})"
                r.outputs = _outputs_list(out_dir, a.id)
                r.warnings = a.warnings
                r.stats = (a.records.get("encode") or {}).get("meta", {}).get("stats", {})
                entry = {"id": a.id, "options": spec.options_digest, "inputs": a.inputs, "outputs": table,
                         "warnings": a.warnings, "stats": r.stats, "skipped": r.skipped}
                if spec.scenes:
                    entry["scenes"] = [str(p) for p in spec.scenes]
                    entry["source"] = str(a.source.resolve())
                state.assets[key] = entry
                explain_steps[key] = a.key_inputs
        if a.failed:
            r.error = a.error
            r.warnings = a.warnings
            r.traceback = a.internal
            r.reason = why[key]
        by_key[key] = r
        if on_result:
            on_result(r, len(by_key), total)

    try:
        graph.build(assets, on_done=finish)
    except AssetpipeError:  # the cache is unusable, ...: the whole build stops with its one line
        # the models already written keep their state (their entries, as after a full build; the
        # others keep their earlier ones and outputs), so the next build does not build them again
        if finished:
            try:
                state.save(explain_steps)
            except OSError:
                pass  # the output folder is unusable too: the build's own error says what stopped it
        raise
    except Exception as exc:  # a bug of ours between steps: every unfinished asset fails, the report is written
        for a in assets:
            if id(a) not in finished and not a.failed and a.records.get("encode") is None:
                a.error = f"{a.source}: internal error in the build graph ({type(exc).__name__}: {exc}); please report it"
                a.internal = _format_exc()
    for a in assets:  # those failed before the last steps (and any the graph did not finish)
        finish(a)
    return explain_steps


def _check_output_size(a, store, limits: BuildLimits) -> None:
    """Fail the asset (one line) when its outputs together exceed ``limits.max_output_bytes``."""
    from assetpipe.core.errors import AssetError

    total = 0
    for digest in set(a.outputs.values()):
        try:
            total += store.blob_path(digest).stat().st_size
        except OSError:
            pass  # a vanished blob: materialise says so
    if total > limits.max_output_bytes:
        raise AssetError(None, f"its outputs would take {total / 2**20:.1f} MiB, over the per-model limit of "
                               f"{limits.max_output_bytes / 2**20:.4g} MiB (--max-output-mb)")
