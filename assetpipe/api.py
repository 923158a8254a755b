"""The Python API: build, validate and load from a script, an editor plugin or a CI job.

    import assetpipe
    from assetpipe.options import BuildOptions, LodOptions

    report = assetpipe.build(["models/"], "out", lod=LodOptions(ratios=(1, 0.5, 0.25)))
    for r in report.failed:
        print(r.error)
    model = assetpipe.load("out/crate.json")
    model.positions          # (N, 3) float32
    results = assetpipe.validate("out")

The options are the dataclasses the CLI builds from its flags (:mod:`assetpipe.options`), the
report is the one ``build --json`` writes (:class:`assetpipe.build_types.BuildReport`). A bad
asset does not raise: it is a failed entry of the report (``report.failed``), as on the command
line; a problem with the build as a whole (an unusable cache folder) raises an
:class:`assetpipe.core.errors.AssetpipeError`.

Typed code should import the functions from here (``from assetpipe.api import build``):
``assetpipe.build`` is also the orchestration module, made callable by the package.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Union

from assetpipe.build import run_build
from assetpipe.build_types import AssetResult, BuildReport
from assetpipe.core.errors import AssetError, AssetpipeError
from assetpipe.options import DEFAULT_BUILD_OPTIONS, BuildOptions
from assetpipe.pipelines.lod_options import LodOptions
from assetpipe.pipelines.mesh_options import MeshOptions
from assetpipe.pipelines.texture_options import TextureOptions
from assetpipe.worker_life import usable_cpus

if TYPE_CHECKING:  # numpy and the renderer are imported when validate() or load() runs
    import numpy as np

    from assetpipe.renderer.validate import ValidateOptions, ValidationResult

PathLike = Union[str, "os.PathLike[str]"]

__all__ = ["build", "validate", "load", "LoadedModel", "LoadedMesh", "BuildOptions", "BuildReport",
           "AssetResult", "MeshOptions", "LodOptions", "TextureOptions", "ValidateOptions", "ValidationResult",
           "AssetError", "AssetpipeError", "usable_cpus"]


def __getattr__(name: str):
    """``ValidateOptions`` and ``ValidationResult`` load the validator's module (and numpy) on first use."""
    if name in ("ValidateOptions", "ValidationResult"):
        from assetpipe.renderer import validate as _validate

        return getattr(_validate, name)
    raise AttributeError(f"module 'assetpipe.api' has no attribute {name!r}")

_KEEP = object()  # "not given": keep the value of ``options``


def _paths(inputs: PathLike | Iterable[PathLike]) -> list[Path]:
    if isinstance(inputs, (str, os.PathLike)):
        return [Path(inputs)]
    return [Path(p) for p in inputs]


def build(inputs: PathLike | Iterable[PathLike], out: PathLike, *, options: BuildOptions | None = None,
          mesh: MeshOptions | None = None, lod: Any = _KEEP, texture: TextureOptions | None = None,
          jobs: int | None = None, cache_dir: PathLike | None = None,
          texture_compression: str | None = None) -> BuildReport:
    """Build ``inputs`` (model files, folders searched recursively, scene ``*.json`` files) into ``out``.

    ``options`` (default :data:`assetpipe.options.DEFAULT_BUILD_OPTIONS`, the CLI's defaults);
    ``mesh``, ``lod`` (a :class:`LodOptions`, or ``None`` for LOD0 only) and ``texture`` replace
    that part of it. ``jobs``: worker processes (default: the usable CPU count). ``cache_dir``:
    as ``--cache`` (default ``$ASSETPIPE_CACHE``, else the user's cache folder). Returns the
    report; ``report.failed`` lists the assets that did not build, each with its one-line error.
    ``texture_compression``: ``"none"``, ``"bc"`` or ``"etc2"`` (``--texture-compression``) for
    the texture options given (or the defaults); a scene's own ``texture_compression`` still wins
    for the textures it uses.
    """
    opts = options if options is not None else DEFAULT_BUILD_OPTIONS
    if not isinstance(opts, BuildOptions):
        raise TypeError(f"options must be a BuildOptions, not {type(opts).__name__}")
    changes: dict[str, Any] = {}
    if mesh is not None:
        changes["mesh"] = mesh
    if lod is not _KEEP:
        if lod is not None and not isinstance(lod, LodOptions):
            raise TypeError(f"lod must be a LodOptions or None, not {type(lod).__name__}")
        changes["lod"] = lod
    if texture is not None:
        changes["texture"] = texture
    if texture_compression is not None:
        changes["texture"] = dataclasses.replace(changes.get("texture", opts.texture), compression=texture_compression)
    if changes:
        opts = dataclasses.replace(opts, **changes)
    n = usable_cpus() if jobs is None else int(jobs)
    if n < 1:
        raise ValueError(f"jobs must be at least 1, not {jobs}")
    return run_build(_paths(inputs), Path(out), opts, jobs=n, cache_dir=Path(cache_dir) if cache_dir else None)


def validate(paths: PathLike | Iterable[PathLike], options: ValidateOptions | None = None, *,
             isolate: bool = True) -> list[ValidationResult]:
    """Render every built model (``OUT/ID.json`` files, or output folders searched for them) on
    lavapipe and check it, as ``assetpipe validate`` does; one :class:`ValidationResult` per model
    (``.passed``, ``.checks``, ``.error``). ``isolate``: render in a crash-isolated subprocess."""
    from assetpipe.renderer.batch import validate_batch
    from assetpipe.renderer.cli_commands import find_built_models

    models = find_built_models([str(p) for p in _paths(paths)])
    return validate_batch(models, options, isolate=isolate)


@dataclass(frozen=True)
class LoadedMesh:
    """One mesh of a built model: its vertex range and its LOD index ranges."""

    id: str
    material: int  # index into LoadedModel.materials
    vertex_base: int  # first vertex in LoadedModel.positions
    vertex_count: int
    lod_ranges: np.ndarray  # (L, 2) int64: first index, index count in LoadedModel.indices, level 0 first
    switch_distances: np.ndarray  # (L,) float64: view distance from which each level is drawn


@dataclass(frozen=True)
class LoadedModel:
    """A built model as numpy arrays, checked while loading (:mod:`assetpipe.renderer.loader`).

    Indices are local to their mesh: mesh ``m``'s level ``k`` draws
    ``positions[m.vertex_base + indices[first:first + count]]``."""

    id: str
    positions: np.ndarray  # (N, 3) float32, model space
    uvs: np.ndarray  # (N, 2) float32 (zeros when the layout has no uv0)
    indices: np.ndarray  # (M,) uint32, 3 per triangle, every mesh's every level
    meshes: tuple[LoadedMesh, ...]
    materials: tuple[dict, ...]  # the sidecar's material entries (name, baseColorFactor, alphaMode, textures...)
    sidecar: dict  # the whole ID.asset.json

    @property
    def lod_ranges(self) -> np.ndarray:
        """(K, 4) int64 rows: mesh index, level, first index, index count."""
        import numpy as np

        rows = [(i, k, int(f), int(c)) for i, m in enumerate(self.meshes) for k, (f, c) in enumerate(m.lod_ranges)]
        return np.array(rows, dtype=np.int64).reshape(-1, 4)

    def triangles(self, mesh: int, level: int = 0) -> np.ndarray:
        """(T, 3) uint32 vertex indices into ``positions`` of one mesh's level."""
        m = self.meshes[mesh]
        first, count = (int(x) for x in m.lod_ranges[level])
        return (self.indices[first:first + count].reshape(-1, 3) + m.vertex_base).astype(self.indices.dtype)


def load(model_json: PathLike) -> LoadedModel:
    """Read a built model (``OUT/ID.json`` and its ``.idx``, ``.vtx``, ``-mat.json``, ``.asset.json``).

    Every size, offset and index range is checked; a broken build raises an
    :class:`assetpipe.core.errors.AssetError` naming the file and the problem. Textures are not
    decoded (their paths are in ``materials``)."""
    import numpy as np

    from assetpipe.renderer.loader import load_built_model

    m = load_built_model(Path(model_json), load_textures=False)
    side_mats = {mat.get("id"): mat for mat in m.sidecar.get("materials", []) if isinstance(mat, dict)}
    meshes = tuple(LoadedMesh(
        id=mesh.id, material=mesh.material, vertex_base=mesh.vertex_base, vertex_count=mesh.vertex_count,
        lod_ranges=np.array([(lod.first_index, lod.index_count) for lod in mesh.lods], dtype=np.int64).reshape(-1, 2),
        switch_distances=np.array([lod.switch_distance for lod in mesh.lods], dtype=np.float64))
        for mesh in m.meshes)
    materials = tuple(side_mats.get(mat.id, {"id": mat.id, "baseColorFactor": list(mat.base_color)})
                      for mat in m.materials)
    # the renderer draws relative to an origin (renderer.loader.frame_origin); the model's own frame
    # is what this API gives: the stored positions, plus a recentred model's positionOffset
    positions = m.positions if not m.position_offset.any() else \
        (m.positions.astype(np.float64) + m.position_offset).astype(np.float32)
    return LoadedModel(id=m.id, positions=positions, uvs=m.uvs, indices=m.indices, meshes=meshes,
                       materials=materials, sidecar=m.sidecar)
