"""``assetpipe inspect``: a readable summary of a built model and a consistency check.

The check reads only the built files and verifies what an engine relies on: the seed key
sets, byte ranges inside ID.idx / ID.vtx and aligned to their element size, every index below
its mesh's vertex count, every float finite, material ids that exist, LOD ranges, and texture
files that exist.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from assetpipe.core.sidecar_shape import sidecar_problem
from assetpipe.format import SEED_MATERIAL_KEYS, SEED_MESH_KEYS, SEED_MODEL_KEYS


def _load(model_json: Path):
    """(ID.json, ID-mat.json, the sidecar or None), each of the shape its format gives it;
    ValueError (a JSONDecodeError too) or OSError otherwise."""
    model = json.loads(model_json.read_text(encoding="utf-8"))
    if not isinstance(model, dict) or not isinstance(model.get("meshes"), list) \
            or not all(isinstance(m, dict) for m in model["meshes"]):
        raise ValueError(f"{model_json.name} is not a built model's ID.json (an object with a 'meshes' list)")
    base = model_json.parent
    mid = str(model.get("id", model_json.stem))
    mats = json.loads((base / f"{mid}-mat.json").read_text(encoding="utf-8"))
    if not isinstance(mats, list) or not all(isinstance(m, dict) for m in mats):
        raise ValueError(f"{mid}-mat.json is not a list of materials")
    side_path = base / f"{mid}.asset.json"
    side = json.loads(side_path.read_text(encoding="utf-8")) if side_path.exists() else None
    problem = None if side is None else sidecar_problem(side)
    if problem:
        raise ValueError(f"{mid}.asset.json: {problem}")
    return model, mats, side


def check_model(model_json: Path) -> list[str]:
    """Problems found (empty when consistent)."""
    model_json = Path(model_json)
    try:
        model, mats, side = _load(model_json)
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        return [f"{model_json}: cannot read the model files ({exc})"]
    problems: list[str] = []
    try:
        return _check(model_json, model, mats, side, problems)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        # a value of another shape than the format's (a file edited or cut): that is the problem
        return problems + [f"{model_json}: the model files do not have the format's shape "
                           f"({type(exc).__name__}: {exc})"]


def _check(model_json: Path, model: dict, mats: list, side: dict | None, problems: list[str]) -> list[str]:
    """:func:`check_model` on loaded files; appends to ``problems`` as it goes."""
    base = model_json.parent
    if tuple(sorted(model)) != tuple(sorted(SEED_MODEL_KEYS)):
        problems.append(f"ID.json keys {sorted(model)} differ from the seed's {sorted(SEED_MODEL_KEYS)}")
    for m in mats:
        if tuple(sorted(m)) != tuple(sorted(SEED_MATERIAL_KEYS)):
            problems.append(f"material {m.get('id')}: keys {sorted(m)} differ from the seed's")
        tp = m.get("texturePath")
        if tp and not (base / tp).is_file():
            problems.append(f"material {m.get('id')}: texturePath {tp} does not exist")
        color = m.get("color", [])
        if len(color) != 4 or not all(isinstance(c, (int, float)) and math.isfinite(c) for c in color):
            problems.append(f"material {m.get('id')}: color is not 4 finite numbers")
    mat_ids = {m.get("id") for m in mats}
    try:
        idx = np.fromfile(base / model["idxFilename"], dtype="<u4")
        vtx_bytes = (base / model["vtxFilename"]).read_bytes()
    except (OSError, KeyError) as exc:
        return problems + [f"cannot read the binary files ({exc})"]
    stride = side["vertexLayout"]["stride"] if side else 20
    floats_per_vertex = stride // 4
    vtx = np.frombuffer(vtx_bytes[: len(vtx_bytes) // 4 * 4], dtype="<f4")
    if not np.isfinite(vtx).all():
        problems.append(f"{model['vtxFilename']}: {int((~np.isfinite(vtx)).sum())} non-finite floats")
    if len(vtx_bytes) % stride:
        problems.append(f"{model['vtxFilename']}: {len(vtx_bytes)} bytes is not a multiple of the {stride}-byte stride")
    side_meshes = {m["id"]: m for m in side["meshes"]} if side else {}
    seen_ids = set()
    for mesh in model.get("meshes", []):
        mid = mesh.get("id")
        if tuple(sorted(mesh)) != tuple(sorted(SEED_MESH_KEYS)):
            problems.append(f"mesh {mid}: keys {sorted(mesh)} differ from the seed's")
            continue
        if mid in seen_ids:
            problems.append(f"mesh id {mid} is not unique")
        seen_ids.add(mid)
        if mesh["materialId"] not in mat_ids:
            problems.append(f"mesh {mid}: materialId {mesh['materialId']!r} is not in the material list")
        vo, vs, io, is_ = mesh["vtxOffset"], mesh["vtxSize"], mesh["idxOffset"], mesh["idxSize"]
        if vo % stride or vs % stride or vo + vs > len(vtx_bytes) or vs <= 0:
            problems.append(f"mesh {mid}: vertex range {vo}+{vs} is invalid for {len(vtx_bytes)} bytes, stride {stride}")
            continue
        nverts = vs // stride
        ranges = [(io, is_, nverts)]
        if mid in side_meshes:
            lods = side_meshes[mid]["lods"]
            if not lods or (lods[0]["idxOffset"], lods[0]["idxSize"]) != (io, is_):
                problems.append(f"mesh {mid}: sidecar lods[0] does not equal the seed index range")
            # a coarser level indexes the prefix of the vertex range its vertexCount names
            ranges += [(l["idxOffset"], l["idxSize"], min(int(l.get("vertexCount", nverts)), nverts))
                       for l in lods[1:]]
            if side_meshes[mid]["vertexCount"] != nverts:
                problems.append(f"mesh {mid}: sidecar vertexCount {side_meshes[mid]['vertexCount']} != {nverts}")
        for level, (o, s, limit) in enumerate(ranges):
            if o % 4 or s % 12 or o + s > idx.size * 4 or s <= 0:
                problems.append(f"mesh {mid} LOD{level}: index range {o}+{s} is invalid for {idx.size * 4} bytes")
                continue
            part = idx[o // 4:(o + s) // 4]
            if part.size and int(part.max()) >= limit:
                what = "vertex count" if level == 0 else "its vertexCount prefix"
                problems.append(f"mesh {mid} LOD{level}: index {int(part.max())} >= {what} {limit}")
    if side:
        for m in side.get("materials", []):
            for role, t in m.get("textures", {}).items():
                for key in ("path", "ktx2"):
                    if t.get(key) and not (base / t[key]).is_file():
                        problems.append(f"material {m['id']}: {role} {key} {t[key]} does not exist")
    return problems


def summarize(model_json: Path) -> str:
    model, mats, side = _load(Path(model_json))
    lines = [f"model {model['id']}: {len(model['meshes'])} mesh(es), {len(mats)} material(s)"]
    if side:
        b = side["bounds"]
        layout = ", ".join(f"{a['name']}@{a['offset']}" for a in side["vertexLayout"]["attributes"])
        lines.append(f"  layout: {layout} (stride {side['vertexLayout']['stride']})")
        lines.append(f"  bounds: min {b['min']} max {b['max']} radius {b['radius']}")
        for m in side["meshes"]:
            lods = " / ".join(f"{l['triangles']}" for l in m["lods"])
            lines.append(f"  {m['id']}: {m['vertexCount']} vertices, {m['triangleCount']} triangles, "
                         f"material {m['materialId']}, LOD triangles {lods}")
        for m in side["materials"]:
            tex = ", ".join(f"{r} {t['width']}x{t['height']} ({t['levels']} levels)" for r, t in m["textures"].items())
            lines.append(f"  {m['id']} {m['name']!r}: {m['alphaMode']}"
                         f"{' transparent' if m['transparent'] else ''}{' double-sided' if m['doubleSided'] else ''}"
                         f"{'; ' + tex if tex else ''}")
        for w in side.get("warnings", []):
            lines.append(f"  warning: {w}")
    else:
        for m in model["meshes"]:
            lines.append(f"  {m['id']}: {m['idxSize'] // 12} triangles, material {m['materialId']}")
    return "\n".join(lines)
