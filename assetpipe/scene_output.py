"""Scene output: encode ``OUT/<name>.scene.json`` (:func:`encode_scene_output`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from assetpipe.scene_load import max_stretch
from assetpipe.scene_types import ModelKey, Scene, SCENE_FORMAT_VERSION


# -- output ----------------------------------------------------------------------------------

def _num(x: float) -> float:
    """9 significant digits (float32 precision), -0 as 0: stable JSON."""
    v = float(f"{float(x):.9g}")
    return v + 0.0


def encode_scene_output(scene: Scene, models: Mapping[ModelKey, Mapping],
                        textures: Mapping[Path, Mapping] | None = None) -> bytes:
    """The bytes of ``OUT/<scene.name>.scene.json`` (docs/SCENES.md).

    ``models[key]``: ``{"id": str, "switchDistances": [per kept level, model units],
    "bounds": {...} (optional, the sidecar's)}`` for every object's ``key``.
    ``textures[path]`` (optional): for each object texture, what the engine loads, e.g.
    ``{"path": "textures/<digest>.png", "ktx2": "textures/<digest>-baseColor.ktx2"}``.
    """
    from assetpipe import __version__

    textures = textures or {}
    used: dict[str, dict] = {}
    objects = []
    for ob in scene.objects:
        key = ob.key
        if key not in models:
            raise KeyError(f"{scene.path}: object {ob.index}: no built model for {key.label()}")
        info = models[key]
        mid = str(info["id"])
        entry = {"id": mid, "file": f"{mid}.json"}
        if info.get("bounds") is not None:
            entry["bounds"] = info["bounds"]
        if info.get("positionOffset") is not None:  # recentred: world = matrix . (vertex + offset)
            entry["positionOffset"] = [float(v) for v in info["positionOffset"]]
        if mid in used and used[mid] != entry:
            raise ValueError(f"model id {mid!r} given twice with different data")
        used[mid] = entry
        switches = [_num(s) for s in info.get("switchDistances") or [0.0]]
        if any(not math.isfinite(s) for s in switches):
            raise ValueError(f"model {mid!r}: switch distances must be finite")
        switches[0] = 0.0
        tex = None
        if ob.texture is not None:
            if ob.texture not in textures:
                raise KeyError(f"{scene.path}: object {ob.index}: no built texture for {ob.texture}")
            tex = dict(textures[ob.texture])
        near, far = ob.view_distance if ob.view_distance is not None else (None, None)
        objects.append({
            "index": ob.index,
            "model": mid,
            "texture": tex,
            "light": ob.light,
            "viewDistance": None if ob.view_distance is None else [_num(near), None if far == math.inf else _num(far)],
            "maxScreenPx": None if ob.max_screen_px is None else _num(ob.max_screen_px),
            "lod": {"finalClamp": None if ob.final_clamp is None else _num(ob.final_clamp),
                    "switchDistances": switches},
            "instances": [{"matrix": [[_num(v) for v in row] for row in np.asarray(m, dtype=np.float64)],
                           "lodScale": _num(max_stretch(m))} for m in ob.instances],
        })
    out = {
        "formatVersion": SCENE_FORMAT_VERSION,
        "scene": scene.name,
        "generator": f"assetpipe {__version__}",
        "ambientLight": None if scene.ambient_light is None else [_num(v) for v in scene.ambient_light],
        "textureBudget": scene.texture_budget,
        "models": [used[k] for k in sorted(used)],
        "objects": objects,
    }
    return (_pretty(out) + "\n").encode("utf-8")


def _pretty(value: Any, indent: str = "") -> str:
    """JSON with 2-space indents, except that a list of numbers (a colour, a matrix row, the
    switch distances) stays on one line."""
    def dump(x):
        return json.dumps(x, ensure_ascii=False, allow_nan=False)

    inner = indent + "  "
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{dump(str(k))}: {_pretty(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, list):
        if all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in value):
            return "[" + ", ".join(dump(v) for v in value) + "]"
        return "[\n" + ",\n".join(inner + _pretty(v, inner) for v in value) + "\n" + indent + "]"
    return dump(value)
