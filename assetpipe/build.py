"""Build orchestration: run every input's model build, write outputs, collect the report.

Each asset is isolated: an :class:`AssetError` fails that asset with one line naming the file
and the problem; any other exception is reported as an internal error (a bug of ours, with a
traceback in the report), and the other assets are built either way. Outputs are written
only once a model is completely encoded in memory, each file atomically, so a failure never
leaves a partial file and never touches the outputs of an earlier successful build.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from assetpipe.errors import AssetError
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
    stats: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        d = {"source": self.source, "id": self.id, "status": self.status, "outputs": self.outputs,
             "warnings": self.warnings, "error": self.error, "seconds": round(self.seconds, 4)}
        if self.reason is not None:
            d["reason"] = self.reason
        if self.stats:
            d["stats"] = self.stats
        return d


@dataclass
class BuildReport:
    results: list[AssetResult]
    seconds: float

    @property
    def failed(self) -> list[AssetResult]:
        return [r for r in self.results if r.status == "failed"]

    def to_json(self) -> dict:
        counts: dict[str, int] = {}
        for r in self.results:
            counts[r.status] = counts.get(r.status, 0) + 1
        return {"assets": [r.to_json() for r in self.results], "counts": counts,
                "seconds": round(self.seconds, 4)}

    def write_json(self, path: Path) -> None:
        from assetpipe.writer import write_atomic

        write_atomic(Path(path), (json.dumps(self.to_json(), indent=2) + "\n").encode())


def build_one(source: Path, model_id: str, out_dir: Path, options) -> AssetResult:
    """Build one model and write its outputs; never raises for a bad asset."""
    from assetpipe.model_build import build_model
    from assetpipe.writer import write_outputs

    t0 = time.perf_counter()
    result = AssetResult(source=str(source), id=model_id, status="failed")
    try:
        out = build_model(source, model_id, options)
        write_outputs(out_dir, out.textures)
        paths = write_outputs(out_dir, out.files)
        by_name = {p.name: str(p) for p in paths}
        result.status = "built"
        result.outputs = [by_name[f"{model_id}.json"], by_name[f"{model_id}-mat.json"],
                          by_name[f"{model_id}.asset.json"]]
        result.warnings = list(out.warnings)
        result.stats = out.stats
    except AssetError as exc:
        result.error = str(exc)
    except MemoryError:
        result.error = f"{source}: out of memory while building"
    except Exception as exc:  # a bug of ours: say so, keep the traceback, go on with the batch
        result.error = f"{source}: internal error ({type(exc).__name__}: {exc}); please report it"
        result.warnings.append(traceback.format_exc())
    result.seconds = time.perf_counter() - t0
    return result


def run_build(inputs: list[str | Path], out_dir: Path, options,
              on_result: Callable[[AssetResult, int, int], None] | None = None) -> BuildReport:
    t0 = time.perf_counter()
    sources = discover_inputs(inputs)
    ids = assign_ids(sources)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for n, src in enumerate(sources):
        r = build_one(src, ids[src], out_dir, options)
        results.append(r)
        if on_result:
            on_result(r, n + 1, len(sources))
    return BuildReport(results=results, seconds=time.perf_counter() - t0)
