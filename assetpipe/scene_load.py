"""Scene files: parsing and validation (:func:`load_scene`) and instance transforms
(:func:`compose_ops`). Strict: an unknown key, a wrong type, a missing file or a bad transform is a
:class:`SceneError` whose one line names the scene, the object index and the problem. See
:mod:`assetpipe.scene` for the conventions.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from assetpipe.core.errors import SceneError
from assetpipe.scene_types import (
    _LIGHT_KEYS,
    _LOD_KEYS,
    _MODEL_KEYS,
    _OBJECT_KEYS,
    _SCENE_KEYS,
    _TOP_KEYS,
    INSTANCE_OPS,
    MODEL_EXTENSIONS,
    Scene,
    SceneObject,
    TEXTURE_EXTENSIONS,
)


# -- errors and JSON helpers -----------------------------------------------------------------

class _Obj(dict):
    """A JSON object remembering its duplicate keys (json keeps only the last)."""

    duplicates: tuple[str, ...] = ()


def _pairs(pairs: list[tuple[str, Any]]) -> _Obj:
    out = _Obj()
    dups = []
    for k, v in pairs:
        if k in out:
            dups.append(k)
        out[k] = v
    out.duplicates = tuple(dups)
    return out


def _show(value: Any) -> str:
    """A value for an error message: JSON-ish, one line, short."""
    try:
        text = json.dumps(value, allow_nan=True)
    except (TypeError, ValueError):
        text = repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 60 else text[:57] + "..."


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


class _Ctx:
    def __init__(self, path: Path):
        self.path = path
        self.base = path.parent

    def fail(self, where: str, problem: str) -> SceneError:
        msg = f"{where}: {problem}" if where else problem
        return SceneError(self.path, " ".join(msg.split()))

    def obj(self, value: Any, where: str, allowed: Sequence[str], required: Sequence[str] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be an object, not {_type_name(value)}")
        dups = getattr(value, "duplicates", ())
        if dups:
            raise self.fail(where, f"duplicate key {dups[0]!r}")
        unknown = [k for k in value if k not in allowed]
        if unknown:
            raise self.fail(where, f"unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")
        for k in required:
            if k not in value:
                raise self.fail(where, f"missing key {k!r}")
        return value

    def number(self, value: Any, where: str, *, positive: bool = False, min_value: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(where, f"must be a number, not {_type_name(value)} {_show(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(where, f"must be finite, not {_show(value)}")
        if positive and not x > 0:
            raise self.fail(where, f"must be > 0, not {_show(value)}")
        if min_value is not None and x < min_value:
            raise self.fail(where, f"must be >= {min_value:g}, not {_show(value)}")
        return x

    def vector(self, value: Any, where: str, sizes: Sequence[int]) -> tuple[float, ...]:
        want = " or ".join(str(n) for n in sizes)
        if not isinstance(value, list) or len(value) not in sizes:
            raise self.fail(where, f"must be a list of {want} numbers, not {_show(value)}")
        return tuple(self.number(v, f"{where}[{i}]") for i, v in enumerate(value))

    def file(self, value: Any, where: str, kind: str, extensions: Sequence[str]) -> Path:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"must be a file name, not {_type_name(value)} {_show(value)}")
        p = Path(value)
        full = p if p.is_absolute() else self.base / p
        if full.suffix.lower() not in extensions:
            raise self.fail(where, f"{value}: unsupported {kind} file type {full.suffix or '(none)'!r} "
                                   f"(one of {', '.join(extensions)})")
        if not full.is_file():
            what = "is not a file" if full.exists() else "file not found"
            raise self.fail(where, f"{value}: {what} ({kind}, relative to the scene's folder)")
        return full.resolve()


# -- transforms ------------------------------------------------------------------------------

def _cos_sin_deg(deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact for multiples of 90."""
    q, r = divmod(deg, 90.0)
    if r == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(q) % 4]
    a = math.radians(deg)
    return math.cos(a), math.sin(a)


def op_matrix(op: str, value) -> np.ndarray:
    """The 4x4 matrix (column vectors) of one instance op."""
    m = np.eye(4)
    if op == "translation":
        m[:3, 3] = value
    elif op == "scaling":
        m[0, 0], m[1, 1], m[2, 2] = value
    elif op in ("rotationX", "rotationY", "rotationZ"):
        c, s = _cos_sin_deg(float(value))
        i, j = {"rotationX": (1, 2), "rotationY": (2, 0), "rotationZ": (0, 1)}[op]
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    else:
        raise ValueError(f"unknown instance op {op!r}")
    return m


def compose_ops(ops: Sequence[tuple[str, Any]]) -> np.ndarray:
    """``M = O1 @ O2 @ ... @ On`` for ops ``[(name, value), ...]`` (list order)."""
    m = np.eye(4)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported by the caller
        for name, value in ops:
            m = m @ op_matrix(name, value)
    return m


def max_stretch(matrix: np.ndarray) -> float:
    """The largest factor by which the matrix stretches a length (largest singular value of
    its upper 3x3): what an LOD's error is multiplied by in world units."""
    return float(np.linalg.svd(np.asarray(matrix, dtype=np.float64)[:3, :3], compute_uv=False)[0])


def _instance(ctx: _Ctx, value: Any, where: str) -> np.ndarray:
    if not isinstance(value, list):
        raise ctx.fail(where, f"must be a list of transform ops, not {_type_name(value)} {_show(value)}")
    ops = []
    for j, op in enumerate(value):
        w = f"{where}[{j}]"
        if not isinstance(op, dict) or len(op) != 1 or getattr(op, "duplicates", ()):
            raise ctx.fail(w, f"must be an object with exactly one of {', '.join(INSTANCE_OPS)}, not {_show(op)}")
        (name, arg), = op.items()
        if name == "translation":
            ops.append((name, ctx.vector(arg, f"{w}.translation", (3,))))
        elif name == "scaling":
            ops.append((name, ctx.vector(arg, f"{w}.scaling", (3,))))
        elif name in ("rotationX", "rotationY", "rotationZ"):
            ops.append((name, ctx.number(arg, f"{w}.{name}")))
        else:
            raise ctx.fail(w, f"unknown transform op {name!r} (one of {', '.join(INSTANCE_OPS)})")
    m = compose_ops(ops)
    if not np.all(np.isfinite(m)):
        raise ctx.fail(where, "transform is not finite (overflow)")
    sv = np.linalg.svd(m[:3, :3], compute_uv=False)
    if not np.all(np.isfinite(sv)):
        raise ctx.fail(where, "transform is not finite (overflow)")
    if not sv[-1] > 1e-12 * max(1.0, sv[0]):
        raise ctx.fail(where, "transform is singular (a zero scaling?)")
    return m


# -- loading ---------------------------------------------------------------------------------

def scene_name(path: str | Path) -> str:
    name = Path(path).name
    for suffix in (".json", ".scene"):
        if name.lower().endswith(suffix) and len(name) > len(suffix):
            name = name[: -len(suffix)]
    return name


def load_scene(path: str | Path) -> Scene:
    """Parse and validate one scene file (docs/SCENES.md). Raises :class:`SceneError` with one
    line ``<scene path>: object <i>: <where>: <problem>``."""
    path = Path(path)
    ctx = _Ctx(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ctx.fail("", "scene file not found") from None
    except IsADirectoryError:
        raise ctx.fail("", "is a folder, not a scene file") from None
    except UnicodeDecodeError as exc:
        raise ctx.fail("", f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise ctx.fail("", f"cannot read the scene file ({exc.strerror})") from None
    try:
        data = json.loads(text, object_pairs_hook=_pairs)
    except json.JSONDecodeError as exc:
        raise ctx.fail("", f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    top = ctx.obj(data, "", _TOP_KEYS, required=("scene",))
    body = ctx.obj(top["scene"], "scene", _SCENE_KEYS, required=("objects",))

    ambient = None
    if body.get("ambient_light") is not None:
        ambient = ctx.vector(body["ambient_light"], "scene.ambient_light", (3, 4))
    budget = None
    if body.get("texture_budget") is not None:
        b = body["texture_budget"]
        if isinstance(b, bool) or not isinstance(b, int) or b < 1:
            raise ctx.fail("scene.texture_budget", f"must be a whole number of pixels >= 1, not {_show(b)}")
        budget = int(b)
    compression = None
    if body.get("texture_compression") is not None:
        from assetpipe.pipelines.texture_options import TEXTURE_CODECS  # noqa: PLC0415

        c = body["texture_compression"]
        if not isinstance(c, str) or c not in TEXTURE_CODECS:
            raise ctx.fail("scene.texture_compression", f"must be one of {', '.join(TEXTURE_CODECS)}, not {_show(c)}")
        compression = c
    objects_raw = body["objects"]
    if not isinstance(objects_raw, list):
        raise ctx.fail("scene.objects", f"must be a list, not {_type_name(objects_raw)}")
    objects = tuple(_object(ctx, raw, i) for i, raw in enumerate(objects_raw))
    return Scene(path=path, name=scene_name(path), ambient_light=ambient, objects=objects,
                 texture_budget=budget, texture_compression=compression)


def _object(ctx: _Ctx, raw: Any, index: int) -> SceneObject:
    at = f"object {index}"
    o = ctx.obj(raw, at, _OBJECT_KEYS, required=("model",))
    m = ctx.obj(o["model"], f"{at}: model", _MODEL_KEYS)
    lod = ctx.obj(m["lod"], f"{at}: model.lod", _LOD_KEYS) if m.get("lod") is not None else None

    model, lod_files, ratios, clamp = None, (), None, None
    if lod is not None and lod.get("final_clamp") is not None:
        clamp = ctx.number(lod["final_clamp"], f"{at}: model.lod.final_clamp", positive=True)
    if "name" in m:
        model = ctx.file(m["name"], f"{at}: model.name", "model", MODEL_EXTENSIONS)
        if lod is not None:
            if "lods" in lod:
                raise ctx.fail(f"{at}: model", "give either name or lod.lods, not both")
            generate = lod.get("generate", True)
            if not isinstance(generate, bool):
                raise ctx.fail(f"{at}: model.lod.generate", f"must be true or false, not {_show(generate)}")
            if not generate:
                if lod.get("ratios") is not None:
                    raise ctx.fail(f"{at}: model.lod", "ratios given with generate false")
                ratios = (1.0,)
            elif lod.get("ratios") is not None:
                ratios = _ratios(ctx, lod["ratios"], f"{at}: model.lod.ratios")
    else:
        if lod is None or "lods" not in lod:
            raise ctx.fail(f"{at}: model", "needs name (a model file) or lod.lods (a list of model files)")
        for k in ("generate", "ratios"):
            if k in lod:
                raise ctx.fail(f"{at}: model.lod", f"{k!r} only applies to a model given by name, "
                                                    "not to a hand-made lods list")
        files = lod["lods"]
        if not isinstance(files, list) or not files:
            raise ctx.fail(f"{at}: model.lod.lods", f"must be a list of at least one model file, not {_show(files)}")
        lod_files = tuple(ctx.file(f, f"{at}: model.lod.lods[{i}]", "model", MODEL_EXTENSIONS)
                          for i, f in enumerate(files))
        seen: dict[Path, int] = {}
        for i, p in enumerate(lod_files):
            if p in seen:
                raise ctx.fail(f"{at}: model.lod.lods[{i}]", f"{files[i]} is also level {seen[p]}")
            seen[p] = i

    texture = None
    if o.get("texture") is not None:
        texture = ctx.file(o["texture"], f"{at}: texture", "texture", TEXTURE_EXTENSIONS)

    if "instances" in o:
        inst = o["instances"]
        if not isinstance(inst, list):
            raise ctx.fail(f"{at}: instances", f"must be a list of instances, not {_type_name(inst)}")
        if not inst:
            raise ctx.fail(f"{at}: instances", "is empty: the object would draw nothing "
                                               "(leave instances out for one untransformed instance)")
        instances = tuple(_instance(ctx, v, f"{at}: instances[{i}]") for i, v in enumerate(inst))
    else:
        instances = (np.eye(4),)

    view = None
    if o.get("view_distance") is not None:
        v = o["view_distance"]
        if not isinstance(v, list) or len(v) != 2:
            raise ctx.fail(f"{at}: view_distance", f"must be [near, far] (far may be null), not {_show(v)}")
        near = ctx.number(v[0], f"{at}: view_distance[0]", min_value=0.0)
        far = math.inf if v[1] is None else ctx.number(v[1], f"{at}: view_distance[1]", positive=True)
        if far < near:
            raise ctx.fail(f"{at}: view_distance", f"far {far:g} is nearer than near {near:g}")
        view = (near, far)
    screen = None
    if o.get("max_screen_px") is not None:
        screen = ctx.number(o["max_screen_px"], f"{at}: max_screen_px", positive=True)
    light = None
    if o.get("light") is not None:
        lt = ctx.obj(o["light"], f"{at}: light", _LIGHT_KEYS, required=("color",))
        light = {"color": list(ctx.vector(lt["color"], f"{at}: light.color", (3, 4)))}
    return SceneObject(index=index, model=model, lod_files=lod_files, final_clamp=clamp, texture=texture,
                       instances=instances, view_distance=view, max_screen_px=screen, lod_ratios=ratios,
                       light=light)


def _ratios(ctx: _Ctx, value: Any, where: str) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise ctx.fail(where, f"must be a non-empty list of numbers, not {_show(value)}")
    r = tuple(ctx.number(x, f"{where}[{i}]") for i, x in enumerate(value))
    if r[0] != 1.0:
        raise ctx.fail(where, f"must start with 1 (level 0 is the model itself), not {r[0]:g}")
    for i in range(1, len(r)):
        if not 0.0 < r[i] < r[i - 1]:
            raise ctx.fail(f"{where}[{i}]", f"must be in (0, {r[i - 1]:g}) (each level coarser), not {r[i]:g}")
    return r
