"""A loader written against the seed layout only, as an engine would: it rejects unknown keys.

Independent of assetpipe's own code, so the tests check the output against the format's
contract rather than against our reading of it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODEL_KEYS = {"id", "meshes", "idxFilename", "vtxFilename"}
MESH_KEYS = {"id", "materialId", "idxOffset", "idxSize", "vtxOffset", "vtxSize"}
MATERIAL_KEYS = {"id", "texturePath", "color"}


class SeedFormatError(Exception):
    pass


@dataclass
class SeedMesh:
    id: str
    material_id: str
    positions: np.ndarray  # (N, 3) float32
    uvs: np.ndarray  # (N, 2) float32
    indices: np.ndarray  # (M, 3) uint32, local to the mesh


@dataclass
class SeedModel:
    id: str
    meshes: list[SeedMesh]
    materials: list[dict]


def _exact(obj: dict, keys: set, what: str) -> None:
    if set(obj) != keys:
        raise SeedFormatError(f"{what}: keys {sorted(obj)} != {sorted(keys)}")


def load_seed_model(model_json: Path) -> SeedModel:
    model_json = Path(model_json)
    base = model_json.parent
    model = json.loads(model_json.read_text(encoding="utf-8"))
    _exact(model, MODEL_KEYS, "model")
    mats = json.loads((base / f"{model['id']}-mat.json").read_text(encoding="utf-8"))
    if not isinstance(mats, list):
        raise SeedFormatError("material file is not a list")
    for m in mats:
        _exact(m, MATERIAL_KEYS, f"material {m.get('id')}")
        if not isinstance(m["color"], list) or len(m["color"]) != 4:
            raise SeedFormatError(f"material {m['id']}: color is not rgba")
        if m["texturePath"] and not (base / m["texturePath"]).is_file():
            raise SeedFormatError(f"material {m['id']}: {m['texturePath']} missing")
    mat_ids = {m["id"] for m in mats}
    idx_bytes = (base / model["idxFilename"]).read_bytes()
    vtx_bytes = (base / model["vtxFilename"]).read_bytes()
    meshes = []
    for mesh in model["meshes"]:
        _exact(mesh, MESH_KEYS, f"mesh {mesh.get('id')}")
        if mesh["materialId"] not in mat_ids:
            raise SeedFormatError(f"mesh {mesh['id']}: unknown material {mesh['materialId']}")
        vo, vs, io, is_ = (mesh[k] for k in ("vtxOffset", "vtxSize", "idxOffset", "idxSize"))
        if vo + vs > len(vtx_bytes) or io + is_ > len(idx_bytes) or vs % 20 or is_ % 12:
            raise SeedFormatError(f"mesh {mesh['id']}: range outside the binary files or misaligned")
        v = np.frombuffer(vtx_bytes, dtype="<f4", count=vs // 4, offset=vo).reshape(-1, 5)
        i = np.frombuffer(idx_bytes, dtype="<u4", count=is_ // 4, offset=io).reshape(-1, 3)
        meshes.append(SeedMesh(mesh["id"], mesh["materialId"], v[:, :3], v[:, 3:], i))
    return SeedModel(model["id"], meshes, mats)
