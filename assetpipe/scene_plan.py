"""Scene planning: which LOD levels a distance range can select (:func:`select_levels`) and what to
build of each model the scenes use (:func:`plan_scene`: one :class:`ModelPlan` per distinct model,
with the union of every object's needs and human-readable skip reasons).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from assetpipe.core.errors import SceneError
from assetpipe.pipelines.lod_options import LodOptions
from assetpipe.pipelines.texture_options import TextureOptions
from assetpipe.scene_load import max_stretch
from assetpipe.scene_types import ModelKey, ModelUse, Scene


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

    @property
    def texture_compression(self) -> str | None:
        """The codec the scenes ask for this model's textures (``texture_compression``), or None
        (the build's). :func:`plan_scene` refuses uses that disagree."""
        return _scene_codec(self.uses)

    def texture_options_for(self, radius: float | None = None, base: TextureOptions | None = None) -> TextureOptions:
        import dataclasses

        base = base or self.texture_options
        codec = self.texture_compression
        return dataclasses.replace(base, max_size=_min_none(self.texture_size(radius), base.max_size),
                                   compression=base.compression if codec is None else codec)

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


def _scene_codec(uses: Iterable[ModelUse]) -> str | None:
    codecs = {u.texture_compression for u in uses} - {None}
    return codecs.pop() if len(codecs) == 1 else None


def _codec_conflict(what: str, uses: Sequence[ModelUse], scene_paths: Mapping[str, Path]) -> SceneError | None:
    """A SceneError when the scenes using ``what`` ask for different texture codecs."""
    by = {}
    for u in uses:
        if u.texture_compression is not None:
            by.setdefault(u.texture_compression, u)
    if len(by) < 2:
        return None
    first = next(iter(by.values()))
    asks = ", ".join(f"{c} in {u.where()}" for c, u in sorted(by.items()))
    return SceneError(scene_paths[first.scene], f"{what}: scenes ask for different texture_compression ({asks}); "
                                             "a model's or texture's files are built once")


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

    def object_texture_options(self, path: str | Path, radii: Mapping[ModelKey, float] | None = None,
                               base: TextureOptions | None = None) -> TextureOptions:
        """The texture options for an object's own texture: ``base`` (default the plan's) with
        :meth:`object_texture_size` and the codec its scenes ask for (``texture_compression``)."""
        import dataclasses

        base = base or self.texture_options
        codec = _scene_codec(u for _, u in self.textures.get(Path(path).resolve(), ()))
        return dataclasses.replace(base, max_size=self.object_texture_size(path, radii),
                                   compression=base.compression if codec is None else codec)


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
                           texture=ob.texture, texture_compression=sc.texture_compression)
            by_key.setdefault(ob.key, []).append(use)
            if ob.texture is not None:
                textures.setdefault(ob.texture, []).append((ob.key, use))

    scene_paths = {sc.name: sc.path for sc in scenes}
    for what, uses_of in ([(k.label(), v) for k, v in by_key.items()]
                          + [(f"texture {p.name}", [u for _, u in v]) for p, v in textures.items()]):
        conflict = _codec_conflict(what, uses_of, scene_paths)
        if conflict is not None:
            raise conflict
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
