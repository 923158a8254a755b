"""The build's value types: one model to build (:class:`AssetSpec`), one model's outcome
(:class:`AssetResult`) and the whole build's (:class:`BuildReport`), and the digest of a build's
options. Shared by the model build (``build.py``) and the scene build (``scene_build.py``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from assetpipe import __version__, versions
from assetpipe.core.hashing import digest_json


@dataclass
class AssetResult:
    """One input's outcome, as the ``--json`` report writes it."""

    source: str
    id: str
    status: str  # "built" | "cached" | "failed" | "skipped" (a scene build: not referenced)
    outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    seconds: float = 0.0
    reason: str | None = None
    steps: list[dict] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    traceback: str | None = None
    skipped: list[str] = field(default_factory=list)  # what was not built for it, and why

    def to_json(self) -> dict:
        d = {"source": self.source, "id": self.id, "status": self.status, "outputs": self.outputs,
             "warnings": self.warnings, "error": self.error, "seconds": round(self.seconds, 4),
             "reason": self.reason}
        if self.steps:
            d["steps"] = self.steps
        if self.stats:
            d["stats"] = self.stats
        if self.skipped:
            d["skipped"] = self.skipped
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
        from assetpipe.core.writer import write_atomic

        write_atomic(Path(path), (json.dumps(self.to_json(), indent=2) + "\n").encode())


# One model's outputs (its files and textures) larger than this fail the model: a sanity limit
# against small inputs that decode to far more than they weigh (#13: a 419 KB PNG wrote 733 MB).
# 2 GiB holds one 16384 x 16384 RGBA8 texture (the usual device limit): its uncompressed KTX2 mip
# chain is 4/3 GiB, plus its PNG level 0. --max-output-mb; docs/BUILD.md.
DEFAULT_MAX_OUTPUT_BYTES = 2 << 30


@dataclass(frozen=True)
class BuildLimits:
    """Limits that apply to the build as a whole, per model (not step options: changing one
    rebuilds nothing)."""

    max_output_bytes: int = DEFAULT_MAX_OUTPUT_BYTES


DEFAULT_BUILD_LIMITS = BuildLimits()


def options_digest(options_json: dict) -> str:
    return digest_json({"assetpipe": __version__, "steps": versions.STEP_VERSIONS,
                        "libs": versions.library_versions(), "options": options_json})


@dataclass
class AssetSpec:
    """One model to build: its source (LOD0 file), id, options, and for scene builds the
    scene's plan for it. ``key`` names its entry in the output state."""

    source: Path
    id: str
    options: object
    options_digest: str
    key: str
    plan: object = None
    extra_sources: tuple = ()
    scenes: tuple = ()  # the scene files that asked for it
