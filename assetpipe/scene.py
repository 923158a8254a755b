"""Scene files (docs/SCENES.md): parse, validate and plan; encode ``OUT/<name>.scene.json``.

Pure: reads only the scene JSON and checks that the files it names exist; writes nothing.

* :func:`load_scene` parses one scene file into a :class:`Scene` (strict: an unknown key, a
  wrong type, a missing file or a bad transform is a :class:`SceneError` whose one line names
  the scene, the object index and the problem).
* :func:`plan_scene` turns the scenes of one build into what to build: one
  :class:`ModelPlan` per distinct model (a file, or a hand-made LOD list), with the union of
  every object's needs (view distances, on-screen size, texture budget), the LOD distance
  range whose levels can be selected, the texture size, and human-readable skip reasons.
* :func:`select_levels` says which LOD levels can be selected for a distance range;
  :func:`attributes_needed` which vertex attributes the materials use;
  :func:`check_shared_materials` whether the files of a hand-made LOD list share materials.
* :func:`encode_scene_output` writes the engine's scene file.

Conventions (see docs/SCENES.md): column vectors (``p' = M @ p``); the ops of an instance
compose in list order as ``M = O1 @ O2 @ ... @ On`` (each op post-multiplies, as glm's
``translate(M, t)`` / ``scale(M, s)`` / ``rotate(M, a, axis)``), so the *last* op acts on the
vertex first: ``[{"translation": t}, {"scaling": s}]`` scales in place, then places at ``t``.
Rotations are in degrees, right-handed (counter-clockwise looking down the axis towards the
origin). Distances are from the camera to the instance's origin, world units.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from assetpipe.core.errors import SceneError
from assetpipe.pipelines.lod_options import LodOptions
from assetpipe.pipelines.mesh_options import SEED_LAYOUT
from assetpipe.pipelines.texture_options import TextureOptions

SCENE_FORMAT_VERSION = 1
MODEL_EXTENSIONS = (".gltf", ".glb", ".obj")
# what pipelines/texture_decode.py decodes (farbfeld ".ff", the seed blog's example, is not)
TEXTURE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tga", ".bmp", ".gif", ".webp")
INSTANCE_OPS = ("translation", "scaling", "rotationX", "rotationY", "rotationZ")

_TOP_KEYS = ("scene",)
_SCENE_KEYS = ("ambient_light", "objects", "texture_budget")
_OBJECT_KEYS = ("model", "texture", "instances", "light", "view_distance", "max_screen_px")
_MODEL_KEYS = ("name", "lod")
_LOD_KEYS = ("final_clamp", "lods", "generate", "ratios")
_LIGHT_KEYS = ("color",)


# -- data -----------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SceneObject:
    """One entry of ``scene.objects`` (``index`` is its 0-based position in that list).

    model: the file given by ``model.name`` (absolute), or None for a hand-made LOD list.
    lod_files: the hand-made LOD list (``model.lod.lods``, LOD0 first), or ().
    final_clamp: ``model.lod.final_clamp`` (world units): distances beyond it select the level
      selected at it. None: no clamp.
    lod_ratios: for a model given by ``name``: None = the build's LOD options; ``(1.0,)`` =
      no generated levels (``"generate": false``); else the ``ratios`` to generate.
    texture: the object's base-colour texture (absolute), or None.
    instances: one 4x4 float64 matrix per instance (an object without ``instances`` has one
      identity instance).
    view_distance: (near, far) in world units (far may be ``math.inf``), or None (any).
    max_screen_px: the largest on-screen size of the object in pixels, or None (unbounded).
    light: the seed's ``light`` object (``{"color": [...]}``), passed through, or None.
    """

    index: int
    model: Path | None
    lod_files: tuple[Path, ...]
    final_clamp: float | None
    texture: Path | None
    instances: tuple[np.ndarray, ...]
    view_distance: tuple[float, float] | None
    max_screen_px: float | None
    lod_ratios: tuple[float, ...] | None = None
    light: dict | None = None

    @property
    def sources(self) -> tuple[Path, ...]:
        """The model files this object reads, LOD0 first."""
        return self.lod_files if self.lod_files else (self.model,)  # type: ignore[return-value]

    @property
    def key(self) -> "ModelKey":
        if self.lod_files:
            return ModelKey(self.lod_files, None, handmade=True)
        return ModelKey((self.model,), self.lod_ratios, handmade=False)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class Scene:
    """A parsed scene file. ``name`` is the file name without ``.json`` and ``.scene``
    (``town.scene.json`` and ``town.json`` are both ``town``): the output is
    ``OUT/<name>.scene.json``."""

    path: Path
    name: str
    ambient_light: tuple[float, ...] | None
    objects: tuple[SceneObject, ...]
    texture_budget: int | None


@dataclass(frozen=True)
class ModelKey:
    """What makes one built model: its source files (one file, or a hand-made LOD list with
    LOD0 first), the generated-LOD ratios override (None: the build's options; only for a
    single file), and whether the files are a hand-made list (a one-file list is still one)."""

    sources: tuple[Path, ...]
    ratios: tuple[float, ...] | None = None
    handmade: bool = False

    def label(self) -> str:
        """Short, readable name for reports."""
        if self.handmade:
            names = [p.name for p in self.sources]
            return f"LOD list [{', '.join(names)}]"
        extra = "" if self.ratios is None else (" (no generated LODs)" if self.ratios == (1.0,)
                                                 else f" (LOD ratios {', '.join(f'{r:g}' for r in self.ratios)})")
        return f"{self.sources[0].name}{extra}"

    def sort_key(self) -> tuple:
        return (tuple(str(p) for p in self.sources), self.handmade, self.ratios is not None, self.ratios or ())


@dataclass(frozen=True)
class ModelUse:
    """One object's use of a model (world units; far/clamp may be inf)."""

    scene: str
    object_index: int
    near: float
    far: float
    final_clamp: float | None
    scales: tuple[float, ...]          # per instance: the largest stretch of its matrix
    max_screen_px: float | None
    texture_budget: int | None
    texture: Path | None               # the object's own base-colour texture

    def where(self) -> str:
        return f"scene {self.scene} object {self.object_index}"


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
    objects_raw = body["objects"]
    if not isinstance(objects_raw, list):
        raise ctx.fail("scene.objects", f"must be a list, not {_type_name(objects_raw)}")
    objects = tuple(_object(ctx, raw, i) for i, raw in enumerate(objects_raw))
    return Scene(path=path, name=scene_name(path), ambient_light=ambient, objects=objects,
                 texture_budget=budget)


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


# -- LOD level selection ---------------------------------------------------------------------

def level_at(switch_distances: Sequence[float], distance: float) -> int:
    """The level selected at ``distance``: the last k with ``switch[k] <= distance`` (level 0
    when none is). Level k is used for distances in ``[switch[k], switch[k+1])``."""
    k = 0
    for i, s in enumerate(switch_distances):
        if s <= distance:
            k = i
        else:
            break
    return k


def select_levels(switch_distances: Sequence[float], near: float, far: float) -> list[int]:
    """The level indices that can be selected for distances in ``[near, far]`` (far may be
    inf): levels whose interval ``[switch[k], switch[k+1])`` meets the range. A level with the
    same switch distance as the next one (an empty interval) is never selected."""
    s = [float(x) for x in switch_distances]
    if not s:
        raise ValueError("no LOD levels")
    if any(math.isnan(x) for x in s):
        raise ValueError("switch distances are not measured (NaN)")
    if any(b < a for a, b in zip(s, s[1:])):
        raise ValueError(f"switch distances must not decrease: {s}")
    if not near <= far:
        raise ValueError(f"near {near} is beyond far {far}")
    lo, hi = level_at(s, near), level_at(s, far)
    return [k for k in range(lo, hi + 1) if k == lo or k == len(s) - 1 or s[k + 1] > s[k]]


# -- planning --------------------------------------------------------------------------------

def next_pow2(px: float) -> int:
    """The smallest power of two >= px (1 for px <= 1)."""
    if px <= 1:
        return 1
    return 1 << math.ceil(math.log2(px) - 1e-12)


def sphere_screen_px(radius: float, distance: float, lod_options: LodOptions) -> float | None:
    """On-screen diameter (px, reference view) of a sphere of ``radius`` whose centre is at
    ``distance``: ``2 * ppu * r / sqrt(d^2 - r^2)``. None when the camera may be inside it."""
    if not distance > radius:
        return None
    return 2.0 * lod_options.pixels_per_unit_at_unit_distance() * radius / math.sqrt(distance ** 2 - radius ** 2)


def distance_for_screen_px(radius: float, px: float, lod_options: LodOptions) -> float:
    """The centre distance at which a sphere of ``radius`` is ``px`` pixels across (inverse of
    :func:`sphere_screen_px`)."""
    k = 2.0 * lod_options.pixels_per_unit_at_unit_distance() / px
    return radius * math.sqrt(1.0 + k * k)


@dataclass(frozen=True)
class ModelPlan:
    """Everything the build needs to know about one model of the scenes.

    Distances are **model units** (the units of the sidecar's ``switchDistance``): a world
    distance d of an instance whose matrix stretches lengths by at most s is d / s.
    max_lod_distance: levels whose switch distance exceeds it are never selected (inf: all
      may be). min_lod_distance: levels finer than the one selected at it are never selected.
      Both without the model's bounds; :meth:`lod_range` refines them with its radius.
    texture_max_size: the largest texture size (px) any use can sample (the next power of two
      of its on-screen size), min'd with the scene budgets and the build's
      ``TextureOptions.max_size``; None: unbounded.
      Without bounds; :meth:`texture_size` refines it with the radius.
    needs_uv: True when an object gives its own texture; None: decide from the imported
      materials with :func:`attributes_needed`.
    """

    key: ModelKey
    uses: tuple[ModelUse, ...]
    max_lod_distance: float
    min_lod_distance: float
    texture_max_size: int | None
    needs_uv: bool | None
    lod_options: LodOptions
    texture_options: TextureOptions

    @property
    def label(self) -> str:
        return self.key.label()

    def lod_range(self, radius: float | None = None) -> tuple[float, float]:
        """(min_lod_distance, max_lod_distance) in model units; with the model's bounding
        radius (model units), an object's ``max_screen_px`` also bounds how near it gets."""
        return _lod_range(self.uses, radius, self.lod_options)

    def kept_levels(self, switch_distances: Sequence[float], radius: float | None = None) -> list[int]:
        """The levels of a measured chain that some use can select (build only these)."""
        lo, hi = self.lod_range(radius)
        return select_levels(switch_distances, lo, hi)

    def texture_size(self, radius: float | None = None) -> int | None:
        """The texture size limit for this model's textures (None: keep the source size)."""
        return _texture_size(self.uses, radius, self.lod_options, self.texture_options.max_size)

    def lod_options_for(self, base: LodOptions | None = None) -> LodOptions:
        """The LOD options to build this model with: ``base`` with the scene's ratios."""
        import dataclasses

        base = base or self.lod_options
        if self.key.ratios is None:
            return base
        return dataclasses.replace(base, ratios=self.key.ratios, target_errors=None)

    def texture_options_for(self, radius: float | None = None, base: TextureOptions | None = None) -> TextureOptions:
        import dataclasses

        base = base or self.texture_options
        return dataclasses.replace(base, max_size=_min_none(self.texture_size(radius), base.max_size))

    def level_reasons(self, switch_distances: Sequence[float], radius: float | None = None) -> list[str]:
        """Why levels of a measured chain are not built (one line each)."""
        kept = self.kept_levels(switch_distances, radius)
        lo, hi = self.lod_range(radius)
        out = []
        coarse = [k for k in range(len(switch_distances)) if k > kept[-1]]
        fine = [k for k in range(len(switch_distances)) if k < kept[0]]
        empty = [k for k in range(kept[0], kept[-1] + 1) if k not in kept]
        if coarse:
            out.append(f"{self.label}: LOD level{_s(coarse)} {_levels(coarse)} not built: they switch in beyond "
                       f"{hi:.6g} model units, the farthest distance they are selected at ({self._far_why()})")
        if fine:
            out.append(f"{self.label}: LOD level{_s(fine)} {_levels(fine)} not built: finer than level {kept[0]}, "
                       f"which is selected at the nearest distance {lo:.6g} model units ({self._near_why()})")
        if empty:
            out.append(f"{self.label}: LOD level{_s(empty)} {_levels(empty)} not built: they switch in at the same "
                       "distance as the next level, so they are never selected")
        return out

    def _far_why(self) -> str:
        parts = []
        for u in self.uses:
            if u.final_clamp is not None and u.final_clamp <= u.far:
                parts.append(f"final_clamp {u.final_clamp:g} in {u.where()}")
            elif math.isfinite(u.far):
                parts.append(f"view distance <= {u.far:g} in {u.where()}")
        return "; ".join(parts[:3]) + ("; ..." if len(parts) > 3 else "")

    def _near_why(self) -> str:
        parts = []
        for u in self.uses:
            if u.near > 0:
                parts.append(f"view distance >= {u.near:g} in {u.where()}")
            if u.max_screen_px is not None:
                parts.append(f"at most {u.max_screen_px:g} px on screen in {u.where()}")
        return "; ".join(parts[:3]) + ("; ..." if len(parts) > 3 else "")


def _s(ks: list[int]) -> str:
    return "s" if len(ks) > 1 else ""


def _levels(ks: list[int]) -> str:
    return ", ".join(str(k) for k in ks)


def _min_none(a: int | None, b: int | None) -> int | None:
    if a is None:
        return b
    if b is None:
        return a
    return min(a, b)


def _lod_range(uses: Iterable[ModelUse], radius: float | None, lod_options: LodOptions) -> tuple[float, float]:
    lo, hi = math.inf, 0.0
    for u in uses:
        clamp = math.inf if u.final_clamp is None else u.final_clamp
        near_model_px = 0.0
        if radius is not None and u.max_screen_px is not None:
            near_model_px = distance_for_screen_px(radius, u.max_screen_px, lod_options)
        for s in u.scales:
            near = min(max(u.near / s, near_model_px), clamp / s)
            lo = min(lo, near)
            hi = max(hi, min(u.far, clamp) / s)
    if lo == math.inf:  # no uses
        lo = 0.0
    return lo, max(hi, lo)


def _use_texture_size(u: ModelUse, radius: float | None, lod_options: LodOptions) -> int | None:
    px = u.max_screen_px
    if radius is not None and radius > 0:
        from_distance = [sphere_screen_px(radius, u.near / s, lod_options) for s in u.scales]
        if all(p is not None for p in from_distance):
            worst = max(from_distance)  # type: ignore[type-var]
            px = worst if px is None else min(px, worst)
    size = None if px is None else next_pow2(px)
    return _min_none(size, u.texture_budget)


def _texture_size(uses: Iterable[ModelUse], radius: float | None, lod_options: LodOptions,
                  global_max: int | None) -> int | None:
    sizes = [_use_texture_size(u, radius, lod_options) for u in uses]
    if not sizes or any(s is None for s in sizes):
        return global_max
    return _min_none(max(sizes), global_max)  # type: ignore[type-var]


@dataclass(frozen=True)
class ScenePlan:
    """What a build of ``scenes`` must build. ``models`` is sorted by key; ``textures`` maps
    each object texture to the objects using it (for :meth:`object_texture_size`);
    ``reasons`` are the skip reasons known before building (one line each)."""

    scenes: tuple[Scene, ...]
    models: dict[ModelKey, ModelPlan]
    textures: dict[Path, tuple[tuple[ModelKey, ModelUse], ...]]
    reasons: tuple[str, ...]
    lod_options: LodOptions = field(default_factory=LodOptions)
    texture_options: TextureOptions = field(default_factory=TextureOptions)

    def sources(self) -> list[Path]:
        """Every model file the scenes reference (each once, sorted)."""
        return sorted({p for k in self.models for p in k.sources})

    def referenced(self, path: str | Path) -> bool:
        p = Path(path).resolve()
        return any(p in k.sources for k in self.models) or p in self.textures

    def unreferenced_reasons(self, paths: Iterable[str | Path]) -> list[str]:
        """Skip reasons for candidate inputs (e.g. the models of a folder) no scene uses."""
        return [f"{p}: not built: no scene references it" for p in paths if not self.referenced(p)]

    def object_texture_size(self, path: str | Path, radii: Mapping[ModelKey, float] | None = None) -> int | None:
        """Size limit of an object's own texture: the largest over the objects using it."""
        p = Path(path).resolve()
        uses = self.textures.get(p, ())
        if not uses:
            raise KeyError(p)
        sizes = [_use_texture_size(u, (radii or {}).get(key), self.lod_options) for key, u in uses]
        if any(s is None for s in sizes):
            return self.texture_options.max_size
        return _min_none(max(sizes), self.texture_options.max_size)  # type: ignore[type-var]


def plan_scene(scenes: Sequence[Scene], lod_options: LodOptions | None = None,
               texture_options: TextureOptions | None = None) -> ScenePlan:
    """Group the objects of every scene by model and union their needs (see :class:`ModelPlan`).
    Two scenes with the same name are a :class:`SceneError` (their outputs would collide)."""
    lod_options = lod_options or LodOptions()
    texture_options = texture_options or TextureOptions()
    names: dict[str, Path] = {}
    for sc in scenes:
        if sc.name in names:
            raise SceneError(sc.path, f"scene name {sc.name!r} is also the name of {names[sc.name]} "
                                      f"(both would write {sc.name}.scene.json)")
        names[sc.name] = sc.path

    by_key: dict[ModelKey, list[ModelUse]] = {}
    textures: dict[Path, list[tuple[ModelKey, ModelUse]]] = {}
    for sc in scenes:
        for ob in sc.objects:
            near, far = ob.view_distance if ob.view_distance is not None else (0.0, math.inf)
            use = ModelUse(scene=sc.name, object_index=ob.index, near=near, far=far,
                           final_clamp=ob.final_clamp, scales=tuple(max_stretch(m) for m in ob.instances),
                           max_screen_px=ob.max_screen_px, texture_budget=sc.texture_budget,
                           texture=ob.texture)
            by_key.setdefault(ob.key, []).append(use)
            if ob.texture is not None:
                textures.setdefault(ob.texture, []).append((ob.key, use))

    models: dict[ModelKey, ModelPlan] = {}
    reasons: list[str] = []
    for key in sorted(by_key, key=ModelKey.sort_key):
        uses = tuple(by_key[key])
        lo, hi = _lod_range(uses, None, lod_options)
        tex = _texture_size(uses, None, lod_options, texture_options.max_size)
        needs_uv = True if any(u.texture is not None for u in uses) else None
        plan = ModelPlan(key=key, uses=uses, max_lod_distance=hi, min_lod_distance=lo,
                         texture_max_size=tex, needs_uv=needs_uv, lod_options=lod_options,
                         texture_options=texture_options)
        models[key] = plan
        if math.isfinite(hi):
            reasons.append(f"{plan.label}: LOD levels switching in beyond {hi:.6g} model units are never "
                           f"selected ({plan._far_why()}) and are not built")
        if lo > 0:
            reasons.append(f"{plan.label}: LOD levels finer than the one selected at {lo:.6g} model units "
                           f"are never selected ({plan._near_why()}) and are not built")
        if tex is not None and tex != texture_options.max_size:
            reasons.append(f"{plan.label}: textures capped at {tex} px ({_tex_why(uses)}): "
                           "mip levels above it are not built")
    for path in sorted(textures):
        pairs = tuple(textures[path])
        sizes = [_use_texture_size(u, None, lod_options) for _, u in pairs]
        if sizes and all(s is not None for s in sizes):
            size = _min_none(max(sizes), texture_options.max_size)  # type: ignore[type-var]
            if size != texture_options.max_size:
                reasons.append(f"texture {path.name}: capped at {size} px ({_tex_why([u for _, u in pairs])}): "
                               "mip levels above it are not built")
    return ScenePlan(scenes=tuple(scenes), models=models,
                     textures={p: tuple(v) for p, v in sorted(textures.items())}, reasons=tuple(reasons),
                     lod_options=lod_options, texture_options=texture_options)


def _tex_why(uses: Iterable[ModelUse]) -> str:
    parts = []
    for u in uses:
        bits = []
        if u.max_screen_px is not None:
            bits.append(f"at most {u.max_screen_px:g} px on screen")
        if u.texture_budget is not None:
            bits.append(f"texture budget {u.texture_budget}")
        if bits:
            parts.append(f"{' and '.join(bits)} in {u.where()}")
    return "; ".join(parts[:3]) + ("; ..." if len(parts) > 3 else "")


# -- materials -------------------------------------------------------------------------------

def attributes_needed(materials: Sequence[Mapping], layout: Sequence[str] = SEED_LAYOUT,
                      object_texture: bool = False) -> tuple[str, ...]:
    """The attributes of ``layout`` that the given materials (the import step's material
    dicts, ``meta["materials"]``; pass only those the mesh or model uses) need computed:
    ``uv0``/``uv1`` only when some texture samples that set (or ``object_texture``: the scene
    gives the object a texture, sampled with uv0), ``tangent`` only with a normal map.
    position, normal and color do not depend on materials and are kept when in the layout."""
    sets: set[int] = set()
    normal_map = False
    for m in materials:
        for role, tex in (m.get("textures") or {}).items():
            sets.add(int(tex.get("texCoord", 0)))
            if role == "normal":
                normal_map = True
    if object_texture:
        sets.add(0)
    out = []
    for a in layout:
        if (a == "uv0" and 0 not in sets) or (a == "uv1" and 1 not in sets) or (a == "tangent" and not normal_map):
            continue
        out.append(a)
    return tuple(out)


def attribute_reasons(label: str, layout: Sequence[str], needed: Sequence[str]) -> list[str]:
    """Skip reasons for the layout attributes :func:`attributes_needed` left out."""
    why = {"uv0": "no material samples a texture with UV set 0", "uv1": "no material samples UV set 1",
           "tangent": "no material has a normal map"}
    return [f"{label}: {a} not computed ({why.get(a, 'not used')})" for a in layout if a not in needed]


def _texture_identity(tex: Mapping, images: Sequence[Mapping] | None) -> tuple:
    img = tex.get("image")
    if images is not None and isinstance(img, int) and 0 <= img < len(images):
        im = images[img]
        ident = im.get("digest") or im.get("path")
    else:
        ident = img
    return (ident, int(tex.get("texCoord", 0)))


def check_shared_materials(levels: Sequence[Mapping | Sequence[Mapping]], names: Sequence[str] | None = None,
                           tolerance: float = 1e-6) -> list[str]:
    """Problems (one line each; [] when fine) with the materials of a hand-made LOD list.

    ``levels[k]`` is level k's import record meta (a dict with ``materials``, ``images`` and
    optionally ``meshMaterials``) or just its material list. Every level must have as many
    materials as LOD0, each with the same base colour factor, alpha mode and, per texture
    role, the same image (by content digest, else by path) and UV set; the materials a level's
    meshes use must be materials LOD0's meshes use."""
    def unpack(x):
        if isinstance(x, Mapping):
            return list(x.get("materials", [])), x.get("images"), x.get("meshMaterials")
        return list(x), None, None

    if not levels:
        return []
    names = list(names) if names is not None else [f"LOD{k}" for k in range(len(levels))]
    base_mats, base_imgs, base_used = unpack(levels[0])
    problems = []
    for k in range(1, len(levels)):
        mats, imgs, used = unpack(levels[k])
        who = names[k]
        if len(mats) != len(base_mats):
            problems.append(f"{who}: {len(mats)} materials, {names[0]} has {len(base_mats)}")
            continue
        for i, (a, b) in enumerate(zip(base_mats, mats)):
            ca, cb = a.get("baseColorFactor", [1, 1, 1, 1]), b.get("baseColorFactor", [1, 1, 1, 1])
            if len(ca) != len(cb) or any(abs(float(x) - float(y)) > tolerance for x, y in zip(ca, cb)):
                problems.append(f"{who}: material {i} base colour {_show(cb)} differs from {names[0]}'s {_show(ca)}")
            if a.get("alphaMode", "OPAQUE") != b.get("alphaMode", "OPAQUE"):
                problems.append(f"{who}: material {i} alpha mode {b.get('alphaMode')} differs from "
                                f"{names[0]}'s {a.get('alphaMode')}")
            ta, tb = a.get("textures") or {}, b.get("textures") or {}
            for role in sorted(set(ta) | set(tb)):
                if role not in ta or role not in tb:
                    has, lacks = (who, names[0]) if role in tb else (names[0], who)
                    problems.append(f"{who}: material {i} {role} texture: {has} has one, {lacks} does not")
                elif _texture_identity(ta[role], base_imgs) != _texture_identity(tb[role], imgs):
                    problems.append(f"{who}: material {i} {role} texture differs from {names[0]}'s")
        if used is not None and base_used is not None:
            extra = sorted(set(used) - set(base_used))
            if extra:
                problems.append(f"{who}: meshes use material(s) {_levels(extra)}, which {names[0]}'s meshes do not")
    return problems


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
