"""The shape of a built model's sidecar (``ID.asset.json``, docs/FORMAT.md), as far as the
readers of built models use it (the renderer's loader and checks, ``assetpipe inspect``): a file
edited or cut by hand is one named problem, not an exception where a value is used."""

from __future__ import annotations

from typing import Any

from assetpipe.core.json_shape import fields_problem, is_int, is_number, numbers, objects


def _bounds_problem(b: Any, where: str) -> str | None:
    if not isinstance(b, dict):
        return f"{where} is not an object"
    return fields_problem(where, b, nums=("radius",), vectors=(("min", 3), ("max", 3), ("center", 3)))


def sidecar_problem(side: Any) -> str | None:
    """What in a sidecar (``ID.asset.json``) has another shape than docs/FORMAT.md gives it, as
    far as the loader and the checks read it; None when nothing does."""
    if not isinstance(side, dict):
        return "not a JSON object"
    vl = side.get("vertexLayout")
    if vl is not None:
        if not isinstance(vl, dict) or not is_int(vl.get("stride")) or not objects(vl.get("attributes")):
            return "vertexLayout is not an object with a stride and a list of attributes"
        for i, a in enumerate(vl["attributes"]):
            problem = fields_problem(f"vertexLayout.attributes[{i}]", a, ints=("offset",), strs=("name", "format"))
            if problem:
                return problem
    if side.get("bounds") is not None:
        problem = _bounds_problem(side["bounds"], "bounds")
        if problem:
            return problem
    # (positionOffset: the loader's own check names it; frame_origin reads any value)
    for key in ("meshes", "materials", "sources"):
        if key in side and not objects(side[key]):
            return f"{key} is not a list of objects"
    for i, m in enumerate(side.get("meshes") or []):
        where = f"meshes[{i}]"
        problem = fields_problem(where, m, ints=("vertexCount", "triangleCount"), strs=("id", "name", "materialId"))
        if problem is None and m.get("bounds") is not None:
            problem = _bounds_problem(m["bounds"], f"{where}.bounds")
        if problem is None and m.get("lods") is not None and not objects(m["lods"]):
            problem = f"{where}.lods is not a list of objects"
        for k, lod in enumerate(m.get("lods") or [] if problem is None else []):
            w = f"{where}.lods[{k}]"
            problem = problem or fields_problem(
                w, lod, ints=("level", "idxOffset", "idxSize", "triangles", "vertexCount", "vertexStart"),
                nums=("switchDistance",))
            err = lod.get("error")
            if problem is None and err is not None and (not isinstance(err, dict) or not all(
                    v is None or is_number(v) or isinstance(v, bool) for v in err.values())):
                problem = f"{w}.error is not an object of numbers"
        if problem:
            return problem
    for i, mat in enumerate(side.get("materials") or []):
        where = f"materials[{i}]"
        problem = fields_problem(where, mat, nums=("alphaCutoff",), strs=("id", "name", "alphaMode"))
        if problem is None and mat.get("baseColorFactor") is not None and not numbers(mat["baseColorFactor"]):
            problem = f"{where}.baseColorFactor is not a list of numbers"
        textures = mat.get("textures")
        if problem is None and textures is not None and (
                not isinstance(textures, dict) or not all(isinstance(t, dict) for t in textures.values())):
            problem = f"{where}.textures is not an object of textures"
        for role, t in (textures or {}).items() if problem is None else ():
            w = f"{where}.textures.{role}"
            problem = problem or fields_problem(w, t, ints=("width", "height", "levels", "vkFormat", "texCoord"),
                                                strs=("path", "ktx2", "colorSpace", "source"))
            for key in ("width", "height", "levels", "vkFormat"):  # what the texture is read by
                if problem is None and key in t and t[key] is None:
                    problem = f"{w}.{key} is null"
            sampler = t.get("sampler")
            if problem is None and sampler is not None and (
                    not isinstance(sampler, dict) or not all(v is None or is_int(v) for v in sampler.values())):
                problem = f"{w}.sampler is not an object of integers"
            for key in ("meanDrift", "coverage"):
                if problem is None and t.get(key) is not None and not numbers(t[key], nulls=True):
                    problem = f"{w}.{key} is not a list of numbers"
        if problem:
            return problem
    for i, src in enumerate(side.get("sources") or []):
        problem = fields_problem(f"sources[{i}]", src, strs=("path", "digest"))
        if problem:
            return problem
    return None
