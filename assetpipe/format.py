"""Encoding a built model into the output files (pure: returns bytes, writes nothing).

The seed files (``ID.json``, ``ID-mat.json``, ``ID.idx``, ``ID.vtx``) carry exactly the keys a
seed loader expects; everything else goes into the sidecar ``ID.asset.json``. Every byte and
key is documented in ``docs/FORMAT.md``. Output is deterministic: same input, same bytes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from assetpipe.core.rows import column_bounds

FORMAT_VERSION = 1
SEED_MODEL_KEYS = ("id", "meshes", "idxFilename", "vtxFilename")
SEED_MESH_KEYS = ("id", "materialId", "idxOffset", "idxSize", "vtxOffset", "vtxSize")
SEED_MATERIAL_KEYS = ("id", "texturePath", "color")
_ATTRIBUTE_FORMATS = {3: "float32x3", 2: "float32x2", 4: "float32x4"}


@dataclass(frozen=True, eq=False)
class OutputLod:
    """One level: ``indices`` (K, 3) uint32 into the mesh's vertex range (LOD0's)."""

    indices: np.ndarray
    vertex_count: int  # the prefix of the vertex range this level references
    error: dict = field(default_factory=dict)
    switch_distance: float = 0.0
    chain_level: int | None = None  # its level in the full chain, when levels were skipped
    vertex_start: int = 0  # the first of the level's own vertex rows (a moved level), else 0


@dataclass(frozen=True, eq=False)
class OutputMesh:
    """``vertices`` (N, C) float (layout attributes side by side); ``lods[0]`` is the full mesh."""

    id: str
    name: str
    material_id: str
    vertices: np.ndarray
    lods: tuple[OutputLod, ...]


@dataclass(frozen=True)
class OutputMaterial:
    id: str
    name: str
    color: tuple[float, float, float, float]
    texture_path: str  # "" when none
    alpha_mode: str
    alpha_cutoff: float
    double_sided: bool
    transparent: bool
    textures: dict = field(default_factory=dict, hash=False)  # role -> sidecar dict


def _num(x: float | None) -> float | None:
    """A float rounded to 9 significant digits (float32 precision): stable, readable JSON.
    Not-a-number (an error a simplifier does not estimate) becomes null."""
    if x is None or not math.isfinite(float(x)):
        return None
    return float(f"{float(x):.9g}")


def bounds_of(positions: np.ndarray) -> dict:
    """AABB and bounding sphere (centred on the AABB) of (N, 3) positions (float32 or float64,
    any strides): in one compiled pass (:mod:`pipelines.point_bounds`), numpy's way where a
    coordinate is not finite."""
    if positions.shape[0] == 0:
        z = [0.0, 0.0, 0.0]
        return {"min": z, "max": z, "center": z, "radius": 0.0}
    from assetpipe.pipelines.point_bounds import box_and_radius2

    lo, hi, r2, bad = box_and_radius2(positions)
    if bad:
        p = positions.astype(np.float64)
        lo, hi = column_bounds(p)
        r2 = np.max(np.einsum("ij,ij->i", p - (lo + hi) * 0.5, p - (lo + hi) * 0.5))
    c = (lo + hi) * 0.5
    r = float(np.sqrt(r2))
    return {"min": [_num(v) for v in lo], "max": [_num(v) for v in hi],
            "center": [_num(v) for v in c], "radius": _num(r)}


def _json(value) -> bytes:
    return (json.dumps(value, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode("utf-8")


def _bytes_view(a: np.ndarray) -> memoryview:
    """A C-contiguous array's own bytes (``len`` is its size in bytes), joined once below
    instead of copied by ``tobytes`` first."""
    return memoryview(a.reshape(-1)).cast("B")


def encode_model(model_id: str, meshes: list[OutputMesh], materials: list[OutputMaterial],
                 layout: tuple[str, ...], layout_components: dict[str, int], *, stats: dict,
                 warnings: list[str], sources: list[dict], generator: str,
                 extra: dict | None = None) -> dict[str, bytes]:
    """File name -> content for one model.

    ID.idx: every mesh's LOD0 indices first (mesh order: the seed ranges), then the coarser
    levels' ranges. Indices are local to their mesh. ID.vtx: every mesh's vertices, interleaved
    float32 in ``layout`` order.
    """
    idx_parts: list[memoryview] = []
    vtx_parts: list[memoryview] = []
    idx_off = vtx_off = 0
    seed_meshes, side_meshes, lod_ranges = [], [], []
    for m in meshes:
        v32 = np.ascontiguousarray(m.vertices, dtype="<f4")
        vbytes = _bytes_view(v32)
        lod0 = _bytes_view(np.ascontiguousarray(m.lods[0].indices, dtype="<u4"))
        seed_meshes.append({"id": m.id, "materialId": m.material_id, "idxOffset": idx_off,
                            "idxSize": len(lod0), "vtxOffset": vtx_off, "vtxSize": len(vbytes)})
        lod_ranges.append([(idx_off, len(lod0))])
        idx_parts.append(lod0)
        vtx_parts.append(vbytes)
        idx_off += len(lod0)
        vtx_off += len(vbytes)
    for mi, m in enumerate(meshes):  # coarser levels after all seed ranges
        for lod in m.lods[1:]:
            b = _bytes_view(np.ascontiguousarray(lod.indices, dtype="<u4"))
            lod_ranges[mi].append((idx_off, len(b)))
            idx_parts.append(b)
            idx_off += len(b)

    for mi, m in enumerate(meshes):
        pos32 = np.asarray(m.vertices[:, :3], dtype=np.float32)
        lods = []
        for li, lod in enumerate(m.lods):
            off, size = lod_ranges[mi][li]
            err = {k: (v if isinstance(v, bool) else _num(v)) for k, v in lod.error.items()} if lod.error else {
                "simplifier": 0.0, "hausdorff": 0.0, "rms": 0.0, "hausdorffRel": 0.0, "rmsRel": 0.0,
                "hausdorffLowerRel": 0.0, "boundConverged": True}
            entry = {"level": li, "idxOffset": off, "idxSize": size,
                     "triangles": int(lod.indices.shape[0]), "vertexCount": int(lod.vertex_count),
                     "error": err, "switchDistance": _num(lod.switch_distance)}
            if lod.chain_level is not None and lod.chain_level != li:
                entry["chainLevel"] = lod.chain_level
            if lod.vertex_start:
                entry["vertexStart"] = int(lod.vertex_start)
            lods.append(entry)
        side_meshes.append({"id": m.id, "name": m.name, "materialId": m.material_id,
                            "vertexCount": int(m.vertices.shape[0]),
                            "triangleCount": int(m.lods[0].indices.shape[0]),
                            "bounds": bounds_of(pos32), "lods": lods})

    all_pos = (np.vstack([np.asarray(m.vertices[:, :3], dtype=np.float32) for m in meshes])
               if meshes else np.zeros((0, 3), np.float32))
    offset = 0
    attributes = []
    for name in layout:
        k = layout_components[name]
        attributes.append({"name": name, "format": _ATTRIBUTE_FORMATS[k], "offset": offset})
        offset += 4 * k

    seed_model = {"id": model_id, "meshes": seed_meshes,
                  "idxFilename": f"{model_id}.idx", "vtxFilename": f"{model_id}.vtx"}
    seed_mats = [{"id": m.id, "texturePath": m.texture_path, "color": [_num(c) for c in m.color]}
                 for m in materials]
    side_mats = [{"id": m.id, "name": m.name, "baseColorFactor": [_num(c) for c in m.color],
                  "alphaMode": m.alpha_mode, "alphaCutoff": _num(m.alpha_cutoff),
                  "doubleSided": m.double_sided, "transparent": m.transparent,
                  "textures": {role: m.textures[role] for role in sorted(m.textures)}} for m in materials]
    sidecar = {
        "formatVersion": FORMAT_VERSION,
        "id": model_id,
        "generator": generator,
        "vertexLayout": {"stride": offset, "attributes": attributes},
        "bounds": bounds_of(all_pos),
        "meshes": side_meshes,
        "materials": side_mats,
        "stats": stats,
        "warnings": list(warnings),
        "sources": sources,
    }
    if extra:
        sidecar.update(extra)
    return {
        f"{model_id}.idx": b"".join(idx_parts),
        f"{model_id}.vtx": b"".join(vtx_parts),
        f"{model_id}.json": _json(seed_model),
        f"{model_id}-mat.json": _json(seed_mats),
        f"{model_id}.asset.json": _json(sidecar),
    }
