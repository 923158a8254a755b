"""The in-memory model that flows between pipeline steps.

Every step is a pure function from these types to these types. Arrays are numpy with the shape
and dtype documented on each field; steps never mutate an array they were given (they copy or
build new ones), so a value can be cached and shared safely.

Conventions
-----------
* Positions are float64 in *model space* (the node hierarchy already flattened), so that
  processing and error measurement keep precision for huge or tiny coordinates. The writer
  casts to float32 at the very end.
* Texture coordinates use the glTF / Vulkan convention: origin at the top-left of the image,
  v growing downwards. OBJ's bottom-left ``vt`` are flipped (v' = 1 - v) on import, as the
  seed generator does (it writes ``1 - y`` of Assimp's flipped coordinates).
* Triangles are counter-clockwise front faces (glTF convention).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")

# glTF sampler enums (they are also the OpenGL enums): kept as ints in the sidecar.
NEAREST, LINEAR = 9728, 9729
NEAREST_MIPMAP_NEAREST, LINEAR_MIPMAP_NEAREST = 9984, 9985
NEAREST_MIPMAP_LINEAR, LINEAR_MIPMAP_LINEAR = 9986, 9987
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648

# Texture roles: decide the filtering of the mip chain and the colour space of the output.
ROLE_BASE_COLOR = "baseColor"
ROLE_EMISSIVE = "emissive"
ROLE_NORMAL = "normal"
ROLE_METALLIC_ROUGHNESS = "metallicRoughness"
ROLE_OCCLUSION = "occlusion"
TEXTURE_ROLES = (ROLE_BASE_COLOR, ROLE_NORMAL, ROLE_METALLIC_ROUGHNESS, ROLE_OCCLUSION, ROLE_EMISSIVE)
SRGB_ROLES = frozenset({ROLE_BASE_COLOR, ROLE_EMISSIVE})


@dataclass(frozen=True)
class Sampler:
    """A glTF sampler; ``None`` filters mean "implementation's choice" as in glTF."""

    mag_filter: int | None = None
    min_filter: int | None = None
    wrap_s: int = REPEAT
    wrap_t: int = REPEAT

    def to_json(self) -> dict:
        return {"magFilter": self.mag_filter, "minFilter": self.min_filter,
                "wrapS": self.wrap_s, "wrapT": self.wrap_t}


@dataclass(frozen=True)
class ImageSource:
    """An encoded image as found in the source (file, buffer view or data URI).

    ``data`` holds the encoded bytes exactly as stored (PNG, JPEG, ...). ``digest`` is the
    content digest of ``data`` (see :mod:`assetpipe.core.hashing`), so identical images used by
    several materials or models are recognised as one.
    """

    name: str  # a readable name: file name, or "<model>#image<N>" for embedded images
    data: bytes = field(repr=False)
    mime: str  # "image/png", "image/jpeg", ... (sniffed from the bytes, not trusted from the file)
    origin: str  # the path read, or "<source file>#images[N]" for embedded images
    digest: str
    path: Path | None = None  # the image file, or None when embedded in the model file


@dataclass(frozen=True)
class TextureRef:
    """A material's use of an image: which image, how it is sampled, and which UV set."""

    image: ImageSource
    sampler: Sampler = Sampler()
    tex_coord: int = 0


@dataclass(frozen=True)
class Material:
    name: str
    base_color_factor: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    base_color_texture: TextureRef | None = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    metallic_factor: float = 1.0
    roughness_factor: float = 1.0
    metallic_roughness_texture: TextureRef | None = None
    normal_texture: TextureRef | None = None
    occlusion_texture: TextureRef | None = None
    emissive_texture: TextureRef | None = None
    emissive_factor: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def textures(self) -> dict[str, TextureRef]:
        """The textures this material uses, by role (only those present)."""
        by_role = {
            ROLE_BASE_COLOR: self.base_color_texture,
            ROLE_NORMAL: self.normal_texture,
            ROLE_METALLIC_ROUGHNESS: self.metallic_roughness_texture,
            ROLE_OCCLUSION: self.occlusion_texture,
            ROLE_EMISSIVE: self.emissive_texture,
        }
        return {role: ref for role, ref in by_role.items() if ref is not None}


DEFAULT_MATERIAL = Material(name="default")


@dataclass(frozen=True, eq=False)
class MeshData:
    """One drawable mesh: a glTF primitive placed by one node, or one OBJ usemtl group.

    Shapes and dtypes (N vertices, M triangles):
      positions  (N, 3) float64, model space
      indices    (M, 3) uint32, each < N
      uv0, uv1   (N, 2) float32 or None
      normals    (N, 3) float32 or None (unit length where present)
      tangents   (N, 4) float32 or None (xyz unit, w = handedness +-1)
      colors     (N, 4) float32 or None (linear RGBA)
    ``material`` indexes ``ImportedModel.materials``; -1 means the default material.
    """

    name: str
    positions: np.ndarray
    indices: np.ndarray
    material: int = -1
    uv0: np.ndarray | None = None
    uv1: np.ndarray | None = None
    normals: np.ndarray | None = None
    tangents: np.ndarray | None = None
    colors: np.ndarray | None = None

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def triangle_count(self) -> int:
        return int(self.indices.shape[0])


@dataclass(frozen=True, eq=False)
class ImportedModel:
    """What an importer returns: meshes in model space, materials, and what it read."""

    source: Path
    meshes: tuple[MeshData, ...]
    materials: tuple[Material, ...]
    warnings: tuple[str, ...] = ()
    # every file read besides ``source`` (.bin, .mtl, images), for content hashing
    dependencies: tuple[Path, ...] = ()
