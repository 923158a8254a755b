"""Build orchestration: inputs -> no-op check -> graph for what changed -> outputs -> report.

Each asset is isolated: an :class:`AssetError` fails that asset with one line naming the file
and the problem; any other exception is reported as an internal error (a bug of ours, with
its traceback in the report), and the other assets are built either way. Outputs are put in
place only from complete blobs, each file atomically, so a failure never leaves a partial
file and never touches the outputs of an earlier successful build.

The no-op path (every asset up to date) imports neither numpy nor any importer.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from assetpipe import __version__, versions
from assetpipe.hashing import digest_json
from assetpipe.inputs import assign_ids, discover_inputs


@dataclass
class AssetResult:
    """One input's outcome, as the ``--json`` report writes it."""

    source: str
    id: str
    status: str  # "built" | "cached" | "failed"
    outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    seconds: float = 0.0
    reason: str | None = None
    steps: list[dict] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    traceback: str | None = None

    def to_json(self) -> dict:
        d = {"source": self.source, "id": self.id, "status": self.status, "outputs": self.outputs,
             "warnings": self.warnings, "error": self.error, "seconds": round(self.seconds, 4),
             "reason": self.reason}
        if self.steps:
            d["steps"] = self.steps
        if self.stats:
            d["stats"] = self.stats
        if self.traceback:
            d["traceback"] = self.traceback
        return d


@dataclass
class BuildReport:
    results: list[AssetResult]
    seconds: float
    removed: list[str] = field(default_factory=list)
    cache_dropped: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[AssetResult]:
        return [r for r in self.results if r.status == "failed"]

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for r in self.results:
            counts[r.status] = counts.get(r.status, 0) + 1
        return counts

    def to_json(self) -> dict:
        return {"assets": [r.to_json() for r in self.results], "counts": self.counts(),
                "removed": self.removed, "cacheDropped": self.cache_dropped, "seconds": round(self.seconds, 4)}

    def write_json(self, path: Path) -> None:
        from assetpipe.writer import write_atomic

        write_atomic(Path(path), (json.dumps(self.to_json(), indent=2) + "\n").encode())


def options_digest(options_json: dict) -> str:
    return digest_json({"assetpipe": __version__, "steps": versions.STEP_VERSIONS,
                        "libs": versions.library_versions(), "options": options_json})


def _outputs_list(out_dir: Path, model_id: str) -> list[str]:
    return [str(out_dir / f"{model_id}.json"), str(out_dir / f"{model_id}-mat.json"),
            str(out_dir / f"{model_id}.asset.json")]


def run_build(inputs: list[str | Path], out_dir: Path, options, *, jobs: int = 1,
              cache_dir: Path | None = None,
              on_result: Callable[[AssetResult, int, int], None] | None = None) -> BuildReport:
    from cache.stat_cache import StatCache
    from cache.store import Store, default_cache_dir
    from assetpipe.state import OutputState
    from assetpipe.writer import sweep_tmp

    t0 = time.perf_counter()
    sources = discover_inputs(inputs)
    ids = assign_ids(sources)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sweep_tmp(out_dir)
    store = Store(Path(cache_dir) if cache_dir else default_cache_dir())
    stat = StatCache(store.root / "stat-cache.json")
    state = OutputState(out_dir)
    opt_digest = options_digest(options.to_json())

    results: dict[Path, AssetResult] = {}
    todo: list[Path] = []
    why: dict[Path, str] = {}
    total = len(sources)
    for src in sources:
        reason = state.check(src, ids[src], opt_digest, stat)
        if reason is None:
            entry = state.assets[str(src.resolve())]
            r = AssetResult(source=str(src), id=ids[src], status="cached", outputs=_outputs_list(out_dir, ids[src]),
                            warnings=list(entry.get("warnings", [])), reason="up to date",
                            stats=entry.get("stats", {}))
            results[src] = r
            if on_result:
                on_result(r, len(results), total)
        else:
            todo.append(src)
            why[src] = reason

    explain_steps = None
    if todo:
        explain_steps = _build_changed(todo, ids, why, out_dir, options, store, stat, state, opt_digest, jobs,
                                       results, on_result, total)
    forgotten = state.forget_missing_sources()
    removed = state.delete_unowned_outputs()
    if todo or forgotten or removed:
        state.save(explain_steps)
    stat.save()
    ordered = [results[s] for s in sources]
    return BuildReport(results=ordered, seconds=time.perf_counter() - t0, removed=removed,
                       cache_dropped=list(store.dropped))


def _build_changed(todo, ids, why, out_dir, options, store, stat, state, opt_digest, jobs, results,
                   on_result, total) -> dict:
    from assetpipe.graph import AssetState, Graph

    explain_prev = state.load_explain()
    graph = Graph(store, stat, options, explain_prev, jobs=jobs)
    assets = [AssetState(source=s, id=ids[s]) for s in todo]
    graph.build(assets)
    explain_steps = dict(explain_prev)
    for a in assets:
        key = str(a.source.resolve())
        r = AssetResult(source=str(a.source), id=a.id, status="failed", seconds=a.seconds)
        r.steps = [{"step": run.step, "ran": run.ran, **({"reason": run.reason} if run.ran else {})}
                   for run in a.runs]
        if not a.failed:
            try:
                table, notes = state.materialise(store, a.outputs, state.assets.get(key))
            except OSError as exc:
                a.error = f"{a.source}: cannot write outputs to {out_dir} ({exc})"
            else:
                ran = [run for run in a.runs if run.ran]
                r.status = "built" if ran else "cached"
                reasons = [f"{run.step}: {run.reason}" for run in ran] + notes
                r.reason = "; ".join(reasons) if reasons else f"results cached ({why[a.source]})"
                r.outputs = _outputs_list(out_dir, a.id)
                r.warnings = a.warnings
                r.stats = (a.records.get("encode") or {}).get("meta", {}).get("stats", {})
                state.assets[key] = {"id": a.id, "options": opt_digest, "inputs": a.inputs, "outputs": table,
                                     "warnings": a.warnings, "stats": r.stats}
                explain_steps[key] = a.key_inputs
        if a.failed:
            r.error = a.error
            r.warnings = a.warnings
            r.traceback = a.internal
            r.reason = why[a.source]
        results[a.source] = r
        if on_result:
            on_result(r, len(results), total)
    return explain_steps
