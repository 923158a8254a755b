"""Load a *built* model (ID.json, ID-mat.json, ID.asset.json, ID.idx, ID.vtx, textures) for drawing.

Only the build's output is read, never the source. Every size, offset and index range is
checked while loading, so a broken build is reported by name instead of drawing garbage:

* ``.idx`` / ``.vtx`` sizes against the meshes' byte ranges and the vertex stride,
* every LOD's indices against its mesh's vertex count,
* every ``materialId`` against ``ID-mat.json`` and the sidecar,
* the vertex layout's attributes (position required; uv0 and a colour optional).

Textures (base colour, and normal, metallic-roughness, occlusion and emissive, each on the layout's
uv0 or, for a role on the other UV set, its uv1; a role whose UV set the layout does not carry is
not drawn, and a note says which and why): each KTX2 is uploaded with all its levels exactly as stored (no
mip generation here), block-compressed formats (BC7, ETC2, ...) as blocks; a device that cannot
sample a block format gets the levels decoded on the CPU, and a note says so. A material without a KTX2 falls back to its ``texturePath`` PNG/JPEG
decoded with Pillow as level 0 only, and a note says so.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import (
    AssetError, AssetpipeError, InvalidGeometryError, InvalidTextureError, MissingFileError)
from assetpipe.core.sidecar_shape import sidecar_problem

VK_FORMAT_R8G8B8A8_UNORM = 37
VK_FORMAT_R8G8B8A8_SRGB = 43
ALPHA_MODE_CODES = {"OPAQUE": 0, "MASK": 1, "BLEND": 2}

_FORMATS: dict[str, tuple[np.dtype, int, float | None]] = {
    # name: (dtype, components, normalisation divisor or None)
    "float32": (np.dtype("<f4"), 0, None),
    "unorm8": (np.dtype("u1"), 0, 255.0),
    "unorm16": (np.dtype("<u2"), 0, 65535.0),
    "uint8": (np.dtype("u1"), 0, None),
    "uint16": (np.dtype("<u2"), 0, None),
    "snorm8": (np.dtype("i1"), 0, 127.0),
    "snorm16": (np.dtype("<i2"), 0, 32767.0),
}


def read_ktx2(data: Any, copy: bool = True) -> Any:
    """The project's KTX2 reader (``assetpipe.core.ktx2.read_ktx2``): .vk_format, .width, .height, .levels."""
    from assetpipe.core.ktx2 import read_ktx2 as project_reader  # noqa: PLC0415

    return project_reader(data, copy=copy)


def map_file(path: Path) -> Any:
    """``assetpipe.core.ktx2.map_file``: a large file mapped read-only, a small one read."""
    from assetpipe.core.ktx2 import map_file as project_map  # noqa: PLC0415

    return project_map(path)


@dataclass
class Texture:
    """A texture ready for upload: levels (h, w, 4) uint8, level 0 first; for a block format
    (``assetpipe.core.ktx2.BLOCK_FORMATS``) each level's blocks ``(ceil(h/4), ceil(w/4), bytes)``
    and ``size`` = level 0's (width, height) in texels."""

    name: str
    levels: list[np.ndarray]
    vk_format: int
    sampler: dict[str, Any] = field(default_factory=dict)
    from_ktx2: bool = True
    size: tuple[int, int] | None = None

    @property
    def width(self) -> int:
        return int(self.size[0]) if self.size else int(self.levels[0].shape[1])

    @property
    def height(self) -> int:
        return int(self.size[1]) if self.size else int(self.levels[0].shape[0])

    def level_size(self, k: int) -> tuple[int, int]:
        """(width, height) of level ``k`` in texels."""
        return max(1, self.width >> k), max(1, self.height >> k)


@dataclass
class Material:
    """What the shader needs of a material."""

    id: str
    base_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    texture: Texture | None = None
    normal_texture: Texture | None = None  # tangent-space normal map (UNORM), on the same UV set as ``texture``
    # the other roles the shaded picture draws, each on the same UV set as ``texture``:
    metallic_roughness_texture: Texture | None = None  # UNORM: G roughness, B metallic (glTF)
    occlusion_texture: Texture | None = None           # UNORM: R occlusion
    emissive_texture: Texture | None = None            # sRGB emissive colour
    # the vertex UV slot each of (normal, metallic-roughness, occlusion, emissive) samples: 0 the
    # layout's uv0 (the base colour's set), 1 its uv1 (the other set: docs/FORMAT.md)
    role_uv: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def blended(self) -> bool:
        return self.alpha_mode == "BLEND"


@dataclass
class Lod:
    """One index range of a mesh: ``first_index``/``index_count`` in uint32 units of the idx."""

    level: int
    first_index: int
    index_count: int
    switch_distance: float = 0.0
    error: dict[str, float] = field(default_factory=dict)

    @property
    def triangles(self) -> int:
        return self.index_count // 3


@dataclass
class Mesh:
    """A drawable mesh: its vertex range in the model's vertex arrays, material, LODs."""

    id: str
    material: int
    vertex_base: int
    vertex_count: int
    lods: list[Lod]
    center: np.ndarray


@dataclass
class RenderModel:
    """Everything the renderer draws. Vertex arrays are float32; ``indices`` is uint32 (whole file)."""

    id: str
    positions: np.ndarray  # (N, 3)
    uvs: np.ndarray        # (N, 2)
    colors: np.ndarray     # (N, 4) linear RGBA, ones when the layout has no colour
    indices: np.ndarray    # (M,) uint32, local to each mesh's vertex range
    meshes: list[Mesh]
    materials: list[Material]
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    center: np.ndarray
    radius: float
    notes: list[str] = field(default_factory=list)
    sidecar: dict[str, Any] = field(default_factory=dict)
    root: Path = Path(".")
    # the drawing frame's origin in the model's frame (float64, :func:`frame_origin`): positions,
    # bounds and centres are relative to it, so the GPU's float32 transforms work on small
    # numbers (camera-relative drawing); add it for the model's (and the source's) frame. Zero
    # for a model near the origin; a recentred model's positionOffset; a far model's centre
    position_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    uvs1: np.ndarray | None = None  # (N, 2) the layout's uv1 (the second UV set), when it has one

    @property
    def lod_count(self) -> int:
        return max((len(m.lods) for m in self.meshes), default=0)

    def triangles(self, lod: int = 0) -> int:
        """Triangles drawn at LOD ``lod`` (meshes with fewer levels use their coarsest)."""
        return sum(m.lods[min(lod, len(m.lods) - 1)].triangles for m in self.meshes if m.lods)


def _read_json(path: Path) -> Any:
    if not path.is_file():
        raise MissingFileError(path, "file is missing")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AssetError(path, f"not valid JSON: {exc}") from exc


#: a model whose bounding-box centre is farther from the origin than this many bounding-sphere
#: radii is drawn relative to that centre: float32 arithmetic at a distance |c| rounds by up to
#: |c| x 2^-24, which is then over 1e-6 of the radius, and a 2e6-unit offset put a 3-unit model's
#: silhouette 4-6 px (of 256) from its CPU projection by the GPU's transform alone
FAR_RADII = 16.0


def frame_origin(side: dict[str, Any] | None) -> np.ndarray:
    """The origin the validator draws a built model relative to (float64 (3,), model frame):
    the sidecar's ``positionOffset`` for a recentred model (its stored positions are already
    relative to it); for a model whose bounds centre is more than :data:`FAR_RADII` radii from
    the origin, that centre rounded to float32 (so a stored float32 position minus it is exact
    on the far axes); else zero. The same origin is taken from the source (the source check
    draws both in one frame)."""
    side = side if isinstance(side, dict) else {}
    off = side.get("positionOffset")
    b = side.get("bounds") if isinstance(side.get("bounds"), dict) else {}
    try:  # a malformed sidecar draws from the origin here; the loader names what is wrong
        if off is not None:
            o = np.asarray(off, np.float64).reshape(-1)
            return o if o.shape == (3,) and np.isfinite(o).all() else np.zeros(3)
        c = np.asarray(b.get("center", (0.0, 0.0, 0.0)), np.float64).reshape(3)
        r = float(b.get("radius", 0.0) or 0.0)
    except (TypeError, ValueError):
        return np.zeros(3)
    if not (np.isfinite(c).all() and math.isfinite(r)) or float(np.abs(c).max()) <= FAR_RADII * max(r, 1e-30):
        return np.zeros(3)
    return c.astype(np.float32).astype(np.float64)


def read_sidecar(model_json: Path) -> dict[str, Any] | None:
    """The sidecar of a built model as a dict, or None when it is missing or not a JSON object
    (:func:`load_built_model` says what is wrong with it)."""
    try:
        side = _read_json(sidecar_path(model_json))
    except (AssetpipeError, OSError):
        return None
    return side if sidecar_problem(side) is None else None


def sidecar_path(model_json: Path) -> Path:
    """``ID.asset.json`` beside ``ID.json``."""
    p = Path(model_json)
    return p.with_name(p.name[: -len(".json")] + ".asset.json")


def material_list_path(model_json: Path) -> Path:
    """``ID-mat.json`` beside ``ID.json``."""
    p = Path(model_json)
    return p.with_name(p.name[: -len(".json")] + "-mat.json")


def decode_vertices(raw: bytes, layout: dict[str, Any], where: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (N,3), uvs (N,2), colours (N,4) as float32 from interleaved ``raw``."""
    pos, uvs, colors, _ = decode_vertex_arrays(raw, layout, where)
    return pos, uvs, colors


def decode_vertex_arrays(raw: bytes, layout: dict[str, Any], where: Path,
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """As :func:`decode_vertices`, and the layout's ``uv1`` (N,2) float32, or None without one."""
    stride = int(layout.get("stride", 0))
    if stride <= 0:
        raise AssetError(where, f"vertexLayout stride {stride} is not positive")
    if len(raw) % stride:
        raise InvalidGeometryError(where, f"size {len(raw)} is not a multiple of the vertex stride {stride} "
                                          "(truncated?)")
    n = len(raw) // stride
    rows = np.frombuffer(raw, np.uint8).reshape(n, stride)
    found: dict[str, np.ndarray] = {}
    for attr in layout.get("attributes", []):
        name, fmt, offset = str(attr.get("name", "")), str(attr.get("format", "")), int(attr.get("offset", -1))
        base, _, count_s = fmt.partition("x")
        if base not in _FORMATS or not count_s.isdigit():
            if name == "position":
                raise AssetError(where, f"position format {fmt!r} is not supported")
            continue
        dtype, _, divisor = _FORMATS[base]
        count = int(count_s)
        size = dtype.itemsize * count
        if offset < 0 or offset + size > stride:
            raise AssetError(where, f"attribute {name} ({fmt} at {offset}) lies outside the stride {stride}")
        values = rows[:, offset:offset + size].copy().view(dtype).reshape(n, count).astype(np.float32)
        if divisor is not None:
            values /= np.float32(divisor)
        found[name.lower()] = values
    if "position" not in found or found["position"].shape[1] < 3:
        raise AssetError(where, "vertexLayout has no float32x3 position attribute")
    pos = np.ascontiguousarray(found["position"][:, :3])
    uv_key = next((k for k in ("uv0", "texcoord0", "texcoord_0", "uv") if k in found), None)
    uvs = found[uv_key][:, :2] if uv_key else np.zeros((n, 2), np.float32)
    col_key = next((k for k in ("color0", "color", "color_0", "colour0") if k in found), None)
    colors = np.ones((n, 4), np.float32)
    if col_key:
        c = found[col_key]
        colors[:, : min(4, c.shape[1])] = c[:, :4]
    uv1 = np.ascontiguousarray(found["uv1"][:, :2], np.float32) if "uv1" in found else None
    return pos, np.ascontiguousarray(uvs, np.float32), colors, uv1


def _load_texture(root: Path, mat_id: str, tex: dict[str, Any] | None, texture_path: str,
                  notes: list[str], parsed: dict[Path, Any] | None = None) -> Texture | None:
    """The base-colour texture: its KTX2 (all levels), else level 0 of ``texturePath``.
    ``parsed``: receives each KTX2 read, by path (for the checks, which then need not read it)."""
    sampler = dict(tex.get("sampler") or {}) if tex else {}
    ktx_rel = tex.get("ktx2") if tex else None
    if ktx_rel:
        ktx_path = root / ktx_rel
        if not ktx_path.is_file():
            raise MissingFileError(ktx_path, f"KTX2 texture of material {mat_id} is missing")
        try:
            # mapped, not copied: the upload reads the levels the views can sample, the checks
            # sample the rest (a 4096^2 chain is 89 MB)
            img = read_ktx2(map_file(ktx_path), copy=False)
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad texture
            raise InvalidTextureError(ktx_path, f"cannot read KTX2: {exc}") from exc
        if parsed is not None:
            parsed[ktx_path] = img
        levels = [np.ascontiguousarray(lv, np.uint8) for lv in img.levels]
        if not levels:
            raise InvalidTextureError(ktx_path, "KTX2 has no levels")
        if getattr(img, "block_format", None) is not None:  # shapes checked by the reader
            return Texture(name=str(ktx_rel), levels=levels, vk_format=int(img.vk_format), sampler=sampler,
                           size=(int(img.width), int(img.height)))
        if int(img.vk_format) not in (VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM):
            raise InvalidTextureError(ktx_path, f"vkFormat {img.vk_format} cannot be drawn "
                                                "(R8G8B8A8 SRGB/UNORM or a BC/ETC2 block format expected)")
        for i, lv in enumerate(levels):
            expect = (max(int(img.height) >> i, 1), max(int(img.width) >> i, 1), 4)
            if lv.shape != expect:
                raise InvalidTextureError(ktx_path, f"level {i} is {lv.shape}, expected {expect}")
        return Texture(name=str(ktx_rel), levels=levels, vk_format=int(img.vk_format), sampler=sampler)
    rel = texture_path or (tex.get("path") if tex else "")
    if not rel:
        return None
    path = root / rel
    if not path.is_file():
        raise MissingFileError(path, f"texture of material {mat_id} is missing")
    from PIL import Image  # noqa: PLC0415

    try:
        with Image.open(path) as im:
            rgba = np.asarray(im.convert("RGBA"), np.uint8)
    except Exception as exc:  # noqa: BLE001
        raise InvalidTextureError(path, f"cannot decode: {exc}") from exc
    notes.append(f"material {mat_id}: no KTX2, drew level 0 of {rel} (decoded with Pillow, no mips)")
    return Texture(name=str(rel), levels=[rgba], vk_format=VK_FORMAT_R8G8B8A8_SRGB, sampler=sampler,
                   from_ktx2=False)


# the roles drawn besides the base colour: sidecar role name -> the format of a level-0 fallback image
DRAWN_ROLES = {"normal": VK_FORMAT_R8G8B8A8_UNORM, "metallicRoughness": VK_FORMAT_R8G8B8A8_UNORM,
               "occlusion": VK_FORMAT_R8G8B8A8_UNORM, "emissive": VK_FORMAT_R8G8B8A8_SRGB}


def role_uv_slot(side_mat: dict[str, Any], role: str, layout_names: set[str]) -> tuple[int | None, str]:
    """(the layout UV slot ``role``'s texture samples: 0 uv0, 1 uv1, None when the build does not carry
    its UV set; why not). The build writes the base colour's UV set into uv0 and the other set
    into uv1 (docs/FORMAT.md), so a role on the base colour's ``texCoord`` samples uv0, a role on
    the other of TEXCOORD_0/1 samples uv1, which only a layout listing ``uv1`` carries."""
    textures = side_mat.get("textures") or {}
    tex = textures.get(role) or {}
    base_set = int((textures.get("baseColor") or {}).get("texCoord", 0) or 0)
    own = int(tex.get("texCoord", 0) or 0)
    if own == base_set:
        return 0, ""
    if {own, base_set} != {0, 1}:
        return None, f"it samples TEXCOORD_{own}, and the build carries TEXCOORD_0 and TEXCOORD_1 only"
    if "uv1" not in layout_names:
        return None, (f"it samples TEXCOORD_{own}, which the build's vertex layout does not carry (no uv1 "
                      "attribute; build with --layout ...,uv1 to carry it)")
    return 1, ""


def _load_role_texture(root: Path, mat_id: str, side_mat: dict[str, Any], role: str,
                       notes: list[str], loaded: dict[tuple, Texture | None] | None = None,
                       layout_names: set[str] | None = None,
                       parsed: dict[Path, Any] | None = None) -> tuple[Texture | None, int]:
    """(the material's texture in ``role`` (its KTX2, else level 0 of its image), the UV slot it
    samples (:func:`role_uv_slot`)); no texture when the build does not carry its UV set (a note
    says which role and why). ``loaded``: the model's textures read so far, by file and sampler (a
    packed occlusion-roughness-metallic KTX2 that two roles name is read and uploaded once)."""
    textures = side_mat.get("textures") or {}
    tex = textures.get(role)
    if not tex:
        return None, 0
    slot, why = role_uv_slot(side_mat, role, layout_names if layout_names is not None else {"uv0"})
    if slot is None:
        notes.append(f"material {mat_id}: the {role} texture is not drawn: {why}")
        return None, 0
    key = (tex.get("ktx2") or tex.get("path"), repr(sorted((tex.get("sampler") or {}).items())),
           DRAWN_ROLES[role])
    if loaded is not None and key in loaded:
        return loaded[key], slot
    out = _load_texture(root, mat_id, tex, "", notes, parsed)
    if out is not None and not out.from_ktx2:
        out.vk_format = DRAWN_ROLES[role]
    if loaded is not None:
        loaded[key] = out
    return out, slot


def load_built_model(model_json: Path, load_textures: bool = True,
                     parsed: dict[Path, Any] | None = None) -> RenderModel:
    """Read and check a built model; raises an :class:`AssetError` subclass naming the problem.
    ``parsed``: receives every KTX2 read, by path (the validator's checks reuse them)."""
    try:
        return _load_built_model(Path(model_json), load_textures, parsed)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        # a value of another shape than the format's (a file edited or cut: an offset that is
        # a string, a material that is a number): that is the problem with the model
        raise AssetError(Path(model_json), "the model files do not have the format's shape "
                                           f"({type(exc).__name__}: {exc})") from None


def _load_built_model(model_json: Path, load_textures: bool,
                      parsed: dict[Path, Any] | None) -> RenderModel:
    """:func:`load_built_model` without the shape check of its values."""
    root = model_json.parent
    seed = _read_json(model_json)
    mats_seed = _read_json(material_list_path(model_json))
    side = _read_json(sidecar_path(model_json))
    problem = sidecar_problem(side)
    if problem:
        raise AssetError(sidecar_path(model_json), problem)
    if not isinstance(seed, dict) or not isinstance(seed.get("meshes"), list):
        raise AssetError(model_json, "no 'meshes' list")
    if not isinstance(mats_seed, list):
        raise AssetError(material_list_path(model_json), "not a list of materials")
    notes: list[str] = []

    layout = side.get("vertexLayout") or {"stride": 20, "attributes": [
        {"name": "position", "format": "float32x3", "offset": 0},
        {"name": "uv0", "format": "float32x2", "offset": 12}]}
    if "vertexLayout" not in side:
        notes.append("sidecar has no vertexLayout: assumed the default x y z u v")
    stride = int(layout.get("stride", 0))
    idx_path = root / str(seed.get("idxFilename", ""))
    vtx_path = root / str(seed.get("vtxFilename", ""))
    for p in (idx_path, vtx_path):
        if not p.is_file():
            raise MissingFileError(p, "file is missing")
    idx_raw = idx_path.read_bytes()
    vtx_raw = vtx_path.read_bytes()
    if len(idx_raw) % 4:
        raise InvalidGeometryError(idx_path, f"size {len(idx_raw)} is not a multiple of 4 (truncated?)")
    positions, uvs, colors, uvs1 = decode_vertex_arrays(vtx_raw, layout, vtx_path)
    layout_names = {str(a.get("name", "")).lower() for a in layout.get("attributes", [])}
    if not np.isfinite(positions).all():
        raise InvalidGeometryError(vtx_path, "non-finite vertex positions")
    indices = np.frombuffer(idx_raw, "<u4").astype(np.uint32)

    side_mats = {m.get("id"): m for m in side.get("materials", []) if isinstance(m, dict)}
    loaded: dict[tuple, Texture | None] = {}  # data-role textures read so far (see _load_role_texture)
    materials: list[Material] = []
    mat_index: dict[str, int] = {}
    for m in mats_seed:
        mid = str(m.get("id"))
        sm = side_mats.get(mid, {})
        if mid not in side_mats:
            notes.append(f"material {mid} is not in the sidecar: drawn opaque, single-sided")
        color = m.get("color") or sm.get("baseColorFactor") or [1, 1, 1, 1]
        tex = (sm.get("textures") or {}).get("baseColor")
        texture = _load_texture(root, mid, tex, str(m.get("texturePath") or ""), notes,
                                parsed) if load_textures else None
        roles = {r: _load_role_texture(root, mid, sm, r, notes, loaded if r != "normal" else None, layout_names,
                                       parsed)
                 if load_textures else (None, 0) for r in ("normal", "metallicRoughness", "occlusion", "emissive")}
        mat_index[mid] = len(materials)
        materials.append(Material(id=mid, base_color=tuple(float(c) for c in color[:4]),  # type: ignore[arg-type]
                                  alpha_mode=str(sm.get("alphaMode", "OPAQUE")),
                                  alpha_cutoff=float(sm.get("alphaCutoff", 0.5)),
                                  double_sided=bool(sm.get("doubleSided", False)), texture=texture,
                                  normal_texture=roles["normal"][0],
                                  metallic_roughness_texture=roles["metallicRoughness"][0],
                                  occlusion_texture=roles["occlusion"][0], emissive_texture=roles["emissive"][0],
                                  role_uv=tuple(roles[r][1] for r in ("normal", "metallicRoughness", "occlusion",  # type: ignore[arg-type]
                                                                      "emissive"))))

    side_meshes = {m.get("id"): m for m in side.get("meshes", []) if isinstance(m, dict)}
    meshes: list[Mesh] = []
    for i, m in enumerate(seed["meshes"]):
        mid = str(m.get("id", f"#{i}"))
        where = f"mesh {mid}"
        mat = m.get("materialId")
        if mat not in mat_index:
            raise AssetError(model_json, f"{where}: materialId {mat!r} is not in {material_list_path(model_json).name}")
        vo, vs = int(m.get("vtxOffset", -1)), int(m.get("vtxSize", -1))
        if vo < 0 or vs < 0 or vo + vs > len(vtx_raw):
            raise InvalidGeometryError(vtx_path, f"{where}: vertex bytes {vo}..{vo + vs} exceed the file's "
                                                 f"{len(vtx_raw)} bytes (truncated?)")
        if vo % stride or vs % stride:
            raise InvalidGeometryError(vtx_path, f"{where}: vtxOffset {vo} / vtxSize {vs} are not multiples "
                                                 f"of the stride {stride}")
        vbase, vcount = vo // stride, vs // stride
        sm = side_meshes.get(mid, {})
        lod_specs = sm.get("lods") or [{"level": 0, "idxOffset": m.get("idxOffset"), "idxSize": m.get("idxSize")}]
        if sm.get("lods") and (int(lod_specs[0].get("idxOffset", -1)) != int(m.get("idxOffset", -2))
                               or int(lod_specs[0].get("idxSize", -1)) != int(m.get("idxSize", -2))):
            raise AssetError(model_json, f"{where}: sidecar lods[0] differs from the seed's idxOffset/idxSize")
        if sm and sm.get("materialId") not in (None, mat):
            raise AssetError(model_json, f"{where}: materialId {mat!r} differs from the sidecar's "
                                         f"{sm.get('materialId')!r}")
        lods: list[Lod] = []
        for spec in lod_specs:
            io, isz = int(spec.get("idxOffset", -1)), int(spec.get("idxSize", -1))
            level = int(spec.get("level", len(lods)))
            if io < 0 or isz < 0 or io + isz > len(idx_raw):
                raise InvalidGeometryError(idx_path, f"{where} LOD{level}: index bytes {io}..{io + isz} exceed "
                                                     f"the file's {len(idx_raw)} bytes (truncated?)")
            if io % 4 or isz % 12:
                raise InvalidGeometryError(idx_path, f"{where} LOD{level}: idxOffset {io} / idxSize {isz} are not "
                                                     "whole uint32 triangles")
            rng = indices[io // 4:(io + isz) // 4]
            if rng.size:
                top = int(rng.max())
                if top >= vcount:
                    raise InvalidGeometryError(idx_path, f"{where} LOD{level}: index {top} out of range "
                                                         f"(the mesh has {vcount} vertices)")
                declared = spec.get("vertexCount")
                if declared is not None and top >= int(declared):
                    raise InvalidGeometryError(idx_path, f"{where} LOD{level}: index {top} beyond the level's "
                                                         f"vertexCount {declared}")
            lods.append(Lod(level=level, first_index=io // 4, index_count=isz // 4,
                            switch_distance=float(spec.get("switchDistance", 0.0) or 0.0),
                            error=dict(spec.get("error") or {})))
        used = positions[vbase:vbase + vcount]
        center = (used.min(0) + used.max(0)) / 2 if vcount else np.zeros(3, np.float32)
        meshes.append(Mesh(id=mid, material=mat_index[mat], vertex_base=vbase, vertex_count=vcount,
                           lods=lods, center=center.astype(np.float64)))

    b = side.get("bounds") or {}
    if "min" in b and "max" in b:
        bmin, bmax = np.asarray(b["min"], np.float64), np.asarray(b["max"], np.float64)
    else:
        notes.append("sidecar has no bounds: computed from the vertices")
        bmin = positions.min(0).astype(np.float64) if len(positions) else np.zeros(3)
        bmax = positions.max(0).astype(np.float64) if len(positions) else np.zeros(3)
    center = np.asarray(b.get("center", (bmin + bmax) / 2), np.float64)
    radius = float(b.get("radius", np.linalg.norm(bmax - bmin) / 2))
    if side.get("positionOffset") is not None:  # a recentred model (docs/FORMAT.md, "Precision")
        try:
            stored = np.asarray(side["positionOffset"], np.float64).reshape(-1)
        except (TypeError, ValueError):
            stored = np.zeros(0)
        if stored.shape != (3,) or not np.isfinite(stored).all():
            raise AssetError(model_json, "sidecar positionOffset is not three finite numbers")
    # drawn relative to frame_origin: a recentred model as stored (positions, bounds and centres
    # are relative to its positionOffset), a far one shifted here in float64
    offset = frame_origin(side)
    if side.get("positionOffset") is None and offset.any():
        positions = (positions.astype(np.float64) - offset).astype(np.float32)
        bmin, bmax, center = bmin - offset, bmax - offset, center - offset
        for m in meshes:
            m.center = m.center - offset
    return RenderModel(id=str(seed.get("id", model_json.stem)), positions=positions, uvs=uvs, colors=colors,
                       indices=indices, meshes=meshes, materials=materials, bounds_min=bmin, bounds_max=bmax,
                       center=center, radius=radius, notes=notes, sidecar=side, root=root, position_offset=offset,
                       uvs1=uvs1)
