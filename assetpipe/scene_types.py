"""Scene files: the constants of the format and the parsed types (:class:`Scene`, :class:`SceneObject`,
:class:`ModelKey`, :class:`ModelUse`). See :mod:`assetpipe.scene`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SCENE_FORMAT_VERSION = 1
MODEL_EXTENSIONS = (".gltf", ".glb", ".obj")
# what pipelines/texture_decode.py decodes (farbfeld ".ff", the seed blog's example, is not)
TEXTURE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tga", ".bmp", ".gif", ".webp")
INSTANCE_OPS = ("translation", "scaling", "rotationX", "rotationY", "rotationZ")

_TOP_KEYS = ("scene",)
_SCENE_KEYS = ("ambient_light", "objects", "texture_budget", "texture_compression")
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
    texture_compression: str | None = None  # "none", "bc" or "etc2" for its textures; None: the build's


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
    texture_compression: str | None = None  # the scene's texture_compression (None: the build's)

    def where(self) -> str:
        return f"scene {self.scene} object {self.object_index}"
