"""An independent reading of the *source* model (glTF/OBJ via trimesh), for comparison renders.

This path shares nothing with the build's importers: trimesh parses the source, its scene
graph is flattened with trimesh's own transforms (``Scene.dump``), and the result becomes a
:class:`~renderer.loader.RenderModel` drawn by the same renderer. Each geometry keeps its
base colour factor and base-colour image (level 0 only, no mips) when trimesh provides them,
so renders can be compared in colour as well as in silhouette; anything trimesh cannot
describe is drawn white.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import AssetError, MissingFileError

from .loader import VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM, Lod, Material, Mesh, RenderModel, Texture

#: threads decoding and mipping a source model's images (:func:`_make_textures`)
TEXTURE_THREADS = min(4, os.cpu_count() or 1)


def _rgba_of(image: Any, decoded: dict[str, Any] | None) -> np.ndarray:
    """(H, W, 4) uint8 of a PIL image trimesh opened (lazily: still undecoded). With ``decoded``
    (a validation run's per-model cache) its file bytes go through the checks' one decoder, so
    the ``textures`` and ``roles`` checks reuse this decode instead of repeating it."""
    fp = getattr(image, "fp", None)
    if decoded is not None and hasattr(fp, "getvalue"):
        from .checks.images import decode_rgba  # noqa: PLC0415

        try:
            return decode_rgba(fp.getvalue(), decoded)
        except Exception:  # noqa: BLE001 - Pillow below reports what is wrong with the image
            pass
    return np.asarray(image.convert("RGBA"), np.uint8)


def _source_texture(img: Any, role: str, name: str, decoded: dict[str, Any] | None) -> Texture:
    """The source image of ``role`` with a mip chain of its own (:mod:`renderer.ref_mips`)."""
    from .ref_mips import mip_chain  # noqa: PLC0415

    fmt = VK_FORMAT_R8G8B8A8_SRGB if role in ("baseColor", "emissive") else VK_FORMAT_R8G8B8A8_UNORM
    return Texture(name=f"{name} source {role}", levels=mip_chain(_rgba_of(img, decoded), role),
                   vk_format=fmt, sampler={"minFilter": 9987}, from_ktx2=False)


def _make_textures(pending: list[tuple], images: dict, decoded: dict[str, Any] | None) -> None:
    """Decode and mip the images a planning pass of :func:`_material_of` asked for, on up to
    :data:`TEXTURE_THREADS` threads (OpenCV's decoders and filters release the GIL), into
    ``images`` by key. One that fails is left out: the drawing pass then tries it again and
    notes why it is not usable."""
    todo: dict[Any, tuple] = {}
    for key, img, role, name in pending:
        todo.setdefault(key, (img, role, name))
    if len(todo) < 2:
        return  # nothing to do side by side: the drawing pass makes it

    def make(item: tuple) -> Texture | None:
        try:
            return _source_texture(*item, decoded)
        except Exception:  # noqa: BLE001 - reported by the drawing pass
            return None

    from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

    with ThreadPoolExecutor(max_workers=min(TEXTURE_THREADS, len(todo))) as pool:
        made = list(pool.map(make, todo.values()))
    for key, tex in zip(todo, made):
        if tex is not None:
            images[key] = tex


def _material_of(geom: Any, name: str, notes: list[str], images: dict[int, Texture] | None = None,
                 decoded: dict[str, Any] | None = None, skip_roles: set[str] | None = None,
                 sampler_of: dict[str, dict[str, dict[str, Any]]] | None = None,
                 uv1_roles: set[str] | None = None, pending: list[tuple] | None = None,
                 ) -> tuple[Material, np.ndarray | None, np.ndarray | None]:
    """(material, uv (N,2) top-left origin or None, vertex colours (N,4) or None) of a trimesh geometry.
    Every texture role trimesh reads is drawn (on TEXCOORD_0, the only UV set trimesh reads; those
    in ``uv1_roles`` on TEXCOORD_1, which the reference reads itself: :func:`_second_uvs`) but those
    in ``skip_roles`` (a source material samples them from a UV set the reference does not draw),
    each with a mip chain of its own and, when ``sampler_of`` names the material (glTF, unique
    material names), the glTF sampler of that role (wrap modes and filters); else trilinear, repeating."""
    visual = getattr(geom, "visual", None)
    kind = getattr(visual, "kind", None)
    n = len(geom.vertices)
    colors = None
    if kind == "vertex":
        vc = np.asarray(visual.vertex_colors, np.float32)
        if vc.shape == (n, 4):
            colors = vc / 255.0
    mat = getattr(visual, "material", None) if kind == "texture" else None
    uv = None
    if kind == "texture" and getattr(visual, "uv", None) is not None and len(visual.uv) == n:
        uv = np.asarray(visual.uv, np.float32).copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # trimesh stores bottom-left (OpenGL) UVs
    attrs = getattr(visual, "vertex_attributes", None) or getattr(geom, "vertex_attributes", None) or {}
    col = attrs.get("color") if hasattr(attrs, "get") else None
    if col is not None and len(col) == n:
        c = np.asarray(col, np.float32)
        c = c / 255.0 if c.max(initial=0) > 1.0 else c
        colors = np.ones((n, 4), np.float32)
        colors[:, : min(4, c.shape[1])] = c[:, :4]
    factor = (1.0, 1.0, 1.0, 1.0)
    image = None
    alpha_mode, cutoff, double_sided = "OPAQUE", 0.5, False
    if mat is not None:
        f = getattr(mat, "baseColorFactor", None)
        if f is None and getattr(mat, "diffuse", None) is not None:
            f = mat.diffuse
        if f is not None:
            fa = np.asarray(f, np.float64).reshape(-1)
            if fa.dtype.kind in "ui" or fa.max(initial=0) > 1.0:
                fa = fa / 255.0
            factor = tuple(float(x) for x in np.r_[fa, [1.0] * 4][:4])  # type: ignore[assignment]
        kw = getattr(mat, "kwargs", None) or {}
        if getattr(mat, "baseColorFactor", None) is None and ("d" in kw or "tr" in kw):
            # an MTL's dissolve (d, or Tr = 1 - d), which trimesh keeps but does not apply
            try:
                raw = kw["d"] if "d" in kw else kw["tr"]
                d = float((raw if isinstance(raw, (list, tuple)) else [raw])[0])
                d = d if "d" in kw else 1.0 - d
                factor = (*factor[:3], min(max(d, 0.0), 1.0))  # type: ignore[assignment]
            except (TypeError, ValueError, IndexError):
                pass
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        # glTF (trimesh's PBRMaterial): no alphaMode means OPAQUE, whatever the factor's alpha;
        # an MTL's dissolve below 1 (a SimpleMaterial) is drawn blended, as the build does
        gltf_material = getattr(mat, "baseColorFactor", None) is not None
        alpha_mode = str(getattr(mat, "alphaMode", None)
                         or ("OPAQUE" if gltf_material or factor[3] >= 1.0 else "BLEND"))
        cutoff = float(getattr(mat, "alphaCutoff", None) or 0.5)
        double_sided = bool(getattr(mat, "doubleSided", False))
    skip = skip_roles or set()
    samplers = (sampler_of or {}).get(str(getattr(mat, "name", None))) if mat is not None else None

    def role_texture(img: Any, role: str) -> Texture | None:
        """The source image of ``role`` with a mip chain of its own (:mod:`renderer.ref_mips`)."""
        if img is None or uv is None or role in skip:
            return None
        # metallic-roughness and occlusion are both linear data: a packed image gets one chain
        key = (id(img), "data" if role in ("metallicRoughness", "occlusion") else role)
        sampler = (samplers or {}).get(role)
        if images is not None and key in images:  # type: ignore[operator]
            tex = images[key]  # type: ignore[index]
            return dataclasses.replace(tex, sampler=sampler) if sampler else tex
        if pending is not None:  # planning pass: made first, in parallel (_make_textures)
            pending.append((key, img, role, name))
            return None
        try:
            tex = _source_texture(img, role, name, decoded)
        except Exception as exc:  # noqa: BLE001
            notes.append(f"{name}: source {role} image not usable ({exc})")
            return None
        if images is not None:
            images[key] = tex  # type: ignore[index]
        return dataclasses.replace(tex, sampler=sampler) if sampler else tex

    def attr(a: str) -> Any:
        return getattr(mat, a, None) if mat is not None else None

    on_uv1 = uv1_roles or set()
    return (Material(id=name, base_color=factor, alpha_mode=alpha_mode, alpha_cutoff=cutoff,  # type: ignore[arg-type]
                     double_sided=double_sided, texture=role_texture(image, "baseColor"),
                     normal_texture=role_texture(attr("normalTexture"), "normal"),
                     metallic_roughness_texture=role_texture(attr("metallicRoughnessTexture"), "metallicRoughness"),
                     occlusion_texture=role_texture(attr("occlusionTexture"), "occlusion"),
                     emissive_texture=role_texture(attr("emissiveTexture"), "emissive"),
                     role_uv=tuple(int(r in on_uv1) for r in ("normal", "metallicRoughness", "occlusion",  # type: ignore[arg-type]
                                                              "emissive"))), uv, colors)


def load_source_model(path: Path, flat: bool = False, decoded: dict[str, Any] | None = None,
                      origin: np.ndarray | None = None) -> RenderModel:
    """Import ``path`` with trimesh, flatten its scene, and return it as a RenderModel.

    ``flat=True`` ignores materials (one white opaque material). Points and lines are dropped.
    ``decoded``: a per-model cache shared with the checks (see ``_rgba_of``). ``origin``
    (float64 (3,)): positions, bounds and centres are made relative to it in float64, before
    float32, as the built model's are (``loader.frame_origin``; recorded as ``position_offset``).
    """
    import trimesh  # noqa: PLC0415

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(path, "source file is missing")
    try:
        diffuse = _spec_gloss_as_diffuse(path)
        if diffuse is None and path.suffix.lower() == ".obj":
            scene = trimesh.load(str(path), force="scene", process=False,
                                 resolver=_backslash_resolver(path.parent))
        elif diffuse is None:
            scene = trimesh.load(str(path), force="scene", process=False)
        else:
            import io  # noqa: PLC0415

            from trimesh.resolvers import FilePathResolver  # noqa: PLC0415

            scene = trimesh.load(io.BytesIO(diffuse[0]), file_type=diffuse[1], force="scene", process=False,
                                 resolver=FilePathResolver(str(path.parent) + "/"))
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds
        raise AssetError(path, f"trimesh cannot import the source: {exc}") from exc
    # Instances of the scene graph, transformed here (Scene.dump copies every geometry with its
    # material images: about 1 s for four 2048^2 textures). A reflecting transform flips the
    # winding back, as trimesh's apply_transform does.
    instances = []
    for node in scene.graph.nodes_geometry:
        transform, gname = scene.graph[node]
        g = scene.geometry.get(gname)
        if isinstance(g, trimesh.Trimesh) and len(g.faces):
            instances.append((np.asarray(transform, np.float64), gname, g))
    geoms = instances
    notes: list[str] = []
    positions, uvs, colors, indices = [], [], [], []
    ref_uvs: list[np.ndarray] = []  # per vertex: the UVs the base colour samples (see _reference_uvs)
    ref_mask: list[np.ndarray] = []  # per vertex: it has such UVs
    from_gltf = False
    meshes: list[Mesh] = []
    materials: list[Material] = [Material(id="flat")] if flat else []
    mat_cache: dict[str, tuple[int, Any, Any]] = {}
    image_cache: dict[int, Texture] = {}
    on_uv1 = second_uv_roles(path)
    skip = other_uv_roles(path) - on_uv1
    samplers = role_samplers(path)
    uvs1: list[np.ndarray] = []  # per vertex: TEXCOORD_1 (the reference's own reading), zeros without
    if skip:
        notes.append(f"the source samples {sorted(skip)} from a UV set other than TEXCOORD_0 (trimesh reads "
                     "TEXCOORD_0 only) and TEXCOORD_1 (read by the reference where every material samples the "
                     "role there with the base colour on TEXCOORD_0): not drawn")
    if not flat and TEXTURE_THREADS > 1:  # the textures every material will draw, made side by side first
        pending: list[tuple] = []
        planned: set[str] = set()
        for k, (_, gname, g) in enumerate(instances):
            if gname not in planned:
                planned.add(gname)
                _material_of(g, f"source-{k}", [], image_cache, decoded, skip, samplers, on_uv1, pending)
        _make_textures(pending, image_cache, decoded)
    base = first = 0
    for k, (transform, gname, g) in enumerate(instances):
        v = np.asarray(g.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
        if origin is not None:
            v = v - origin
        f = np.asarray(g.faces, np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:
            f = f[:, ::-1]
        n = len(v)
        if flat:
            mat_index, uv, col = 0, None, None
        elif gname in mat_cache:
            mat_index, uv, col = mat_cache[gname]
        else:
            mat, uv, col = _material_of(g, f"source-{k}", notes, image_cache, decoded, skip, samplers, on_uv1)
            mat_index = len(materials)
            materials.append(mat)
            mat_cache[gname] = (mat_index, uv, col)
        positions.append(v.astype(np.float32))
        uvs.append(uv if uv is not None else np.zeros((n, 2), np.float32))
        ref = (getattr(g, "vertex_attributes", None) or {}).get(REFERENCE_UV)
        if ref is not None and len(ref) == n:
            ref_uvs.append(np.asarray(ref, np.float32).reshape(n, -1)[:, :2])
            from_gltf = True
        else:
            ref_uvs.append(uvs[-1])
        ref_mask.append(np.full(n, ref is not None or uv is not None))
        uv1 = (getattr(g, "vertex_attributes", None) or {}).get(SECOND_UV)
        uvs1.append(np.asarray(uv1, np.float32).reshape(n, -1)[:, :2] if uv1 is not None and len(uv1) == n
                    else np.zeros((n, 2), np.float32))
        colors.append(col if col is not None else np.ones((n, 4), np.float32))
        indices.append(f.astype(np.uint32).reshape(-1))
        center = (v.min(0) + v.max(0)) / 2
        meshes.append(Mesh(id=f"source-{k}", material=mat_index, vertex_base=base, vertex_count=n,
                           lods=[Lod(level=0, first_index=first, index_count=f.size)], center=center))
        base += n
        first += f.size
    if not geoms:
        raise AssetError(path, "the source has no triangles trimesh can read")
    pos = np.concatenate(positions)
    lo, hi = pos.min(0).astype(np.float64), pos.max(0).astype(np.float64)
    return RenderModel(id=path.stem, positions=pos, uvs=np.concatenate(uvs).astype(np.float32),
                       colors=np.concatenate(colors).astype(np.float32),
                       indices=np.concatenate(indices).astype(np.uint32), meshes=meshes, materials=materials,
                       bounds_min=lo, bounds_max=hi, center=(lo + hi) / 2,
                       radius=float(np.linalg.norm(hi - lo) / 2), notes=notes, root=path.parent,
                       uvs1=np.concatenate(uvs1) if on_uv1 else None,
                       position_offset=np.zeros(3) if origin is None else np.asarray(origin, np.float64),
                       sidecar={"undrawnRoles": sorted(skip),
                                "referenceUvs": np.concatenate(ref_uvs) if from_gltf else None,
                                "referenceUvMask": np.concatenate(ref_mask) if from_gltf else None, "sparseApplied": diffuse is not None and any(
                           isinstance(a, dict) and "sparse" in a for a in (_gltf_json(path) or {}).get("accessors", []))})


# glTF material texture slots by the sidecar's role names
GLTF_ROLE_PATHS = {"baseColor": (("pbrMetallicRoughness", "baseColorTexture"),
                                 ("extensions", "KHR_materials_pbrSpecularGlossiness", "diffuseTexture")),
                   "metallicRoughness": (("pbrMetallicRoughness", "metallicRoughnessTexture"),),
                   "normal": (("normalTexture",),), "occlusion": (("occlusionTexture",),),
                   "emissive": (("emissiveTexture",),)}


def other_uv_roles(path: Path) -> set[str]:
    """The roles some material of the glTF at ``path`` samples from a UV set other than TEXCOORD_0."""
    doc = _gltf_json(path)
    out: set[str] = set()
    for mat in (doc or {}).get("materials") or []:
        for role, paths in GLTF_ROLE_PATHS.items():
            for keys in paths:
                node: Any = mat
                for k in keys:
                    node = node.get(k) if isinstance(node, dict) else None
                if isinstance(node, dict) and int(node.get("texCoord", 0) or 0) != 0:
                    out.add(role)
    return out


def _role_tex_coords(doc: dict[str, Any] | None) -> dict[str, set[tuple[int, int]]]:
    """Per role (not the base colour), the (role texCoord, base colour texCoord) pairs the
    document's materials use."""
    out: dict[str, set[tuple[int, int]]] = {}
    for mat in (doc or {}).get("materials") or []:
        infos = {}
        for role, paths in GLTF_ROLE_PATHS.items():
            for keys in paths:
                node: Any = mat
                for k in keys:
                    node = node.get(k) if isinstance(node, dict) else None
                if isinstance(node, dict):
                    infos[role] = node
                    break
        base = int((infos.get("baseColor") or {}).get("texCoord", 0) or 0)
        for role, info in infos.items():
            if role != "baseColor":
                out.setdefault(role, set()).add((int(info.get("texCoord", 0) or 0), base))
    return out


def second_uv_roles(path: Path) -> set[str]:
    """The roles the reference draws from TEXCOORD_1, which it reads itself (:func:`_second_uvs`):
    those every material of the glTF at ``path`` samples from TEXCOORD_1 while its base colour is
    on TEXCOORD_0 (what the build's layout stores in ``uv1``)."""
    return {role for role, pairs in _role_tex_coords(_gltf_json(path)).items() if pairs == {(1, 0)}}


def _backslash_resolver(folder: Path) -> Any:
    """A trimesh resolver for an OBJ's folder that also reads Windows paths (``map_Kd .\\tex.jpg``),
    as MTL files written on Windows name them and the build reads them; trimesh alone finds no file."""
    from trimesh.resolvers import FilePathResolver  # noqa: PLC0415

    class Resolver(FilePathResolver):
        def get(self, name: str) -> bytes:
            return super().get(name.replace("\\", "/"))

    return Resolver(str(folder) + "/")


_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_DTYPES = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}


def _buffer_bytes(doc: dict[str, Any], path: Path, index: int) -> bytes:
    """The bytes of buffer ``index`` of the glTF at ``path`` (GLB chunk, file or data URI)."""
    import base64  # noqa: PLC0415
    import struct  # noqa: PLC0415
    from urllib.parse import unquote  # noqa: PLC0415

    uri = (doc.get("buffers") or [])[index].get("uri")
    if uri is None:  # the GLB's BIN chunk
        data = path.read_bytes()
        off = 12
        while off + 8 <= len(data):
            clen, ctype = struct.unpack_from("<II", data, off)
            if ctype == 0x004E4942:
                return data[off + 8: off + 8 + clen]
            off += 8 + clen
        return b""
    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[1])
    return (path.parent / unquote(uri)).read_bytes()


class _DocData:
    """Reads accessor data of a glTF document and appends new data to one extra data-URI buffer."""

    def __init__(self, doc: dict[str, Any], path: Path) -> None:
        self.doc, self.path = doc, path
        self.views = doc.setdefault("bufferViews", [])
        self.cache: dict[int, bytes] = {}
        self.blob = bytearray()

    def read(self, view_index: int | None, offset: int, dtype: str, count: int, comps: int) -> np.ndarray:
        out = np.zeros((count, comps), dtype)
        if view_index is None or not count:
            return out
        view = self.views[view_index]
        if view["buffer"] not in self.cache:
            self.cache[view["buffer"]] = _buffer_bytes(self.doc, self.path, view["buffer"])
        data = self.cache[view["buffer"]]
        item = np.dtype(dtype).itemsize * comps
        stride = int(view.get("byteStride", 0) or item)
        raw = np.frombuffer(data, np.uint8, count=(count - 1) * stride + item,
                            offset=int(view.get("byteOffset", 0)) + int(offset))
        rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, comps).copy()

    def accessor(self, index: int) -> np.ndarray:
        """Accessor ``index`` as float64 (normalised integers scaled to 0..1 / -1..1)."""
        acc = self.doc["accessors"][index]
        dtype = _DTYPES[acc["componentType"]]
        a = self.read(acc.get("bufferView"), acc.get("byteOffset", 0), dtype, int(acc["count"]),
                      _COMPONENTS[acc["type"]]).astype(np.float64)
        if acc.get("normalized") and np.dtype(dtype).kind in "iu":
            info = np.iinfo(np.dtype(dtype))
            a = np.maximum(a / info.max, -1.0)
        return a

    def append(self, values: np.ndarray) -> int:
        """A new buffer view holding ``values``' bytes; its index."""
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.views.append({"buffer": len(self.doc["buffers"]), "byteOffset": len(self.blob),
                           "byteLength": values.nbytes})
        self.blob += values.tobytes()
        return len(self.views) - 1

    def finish(self) -> None:
        import base64  # noqa: PLC0415

        if self.blob:
            self.doc["buffers"].append({"byteLength": len(self.blob), "uri": "data:application/octet-stream;base64,"
                                        + base64.b64encode(bytes(self.blob)).decode()})


def _densify_sparse(doc: dict[str, Any], data: _DocData) -> bool:
    """Rewrite every sparse accessor of ``doc`` as a plain one (its base values, or zeros, with
    the sparse substitutions applied): trimesh ignores ``sparse`` and would read the base values
    only. True when something was rewritten."""
    changed = False
    for acc in doc.get("accessors") or []:
        sp = acc.get("sparse") if isinstance(acc, dict) else None
        if sp is None:
            continue
        comps, dtype = _COMPONENTS[acc["type"]], _DTYPES[acc["componentType"]]
        values = data.read(acc.get("bufferView"), acc.get("byteOffset", 0), dtype, int(acc["count"]), comps)
        n = int(sp["count"])
        idx = data.read(sp["indices"]["bufferView"], sp["indices"].get("byteOffset", 0),
                        _DTYPES[sp["indices"]["componentType"]], n, 1).reshape(-1).astype(np.int64)
        values[idx] = data.read(sp["values"]["bufferView"], sp["values"].get("byteOffset", 0), dtype, n, comps)
        acc.pop("sparse")
        acc["bufferView"], acc["byteOffset"] = data.append(values), 0
        changed = True
    return changed


REFERENCE_UV = "_REF_UV"  # trimesh keeps attributes named with a leading underscore as vertex attributes
SECOND_UV = "_REF_UV1"  # TEXCOORD_1, for the roles of second_uv_roles (trimesh reads TEXCOORD_0 only)


def _second_uvs(doc: dict[str, Any], data: _DocData) -> bool:
    """Give every primitive with a ``TEXCOORD_1`` a ``_REF_UV1`` attribute holding it (as stored:
    glTF's top-left origin), when some role is drawn from that set (:func:`second_uv_roles`).
    True when something was added."""
    if not any(pairs == {(1, 0)} for pairs in _role_tex_coords(doc).values()):
        return False
    changed = False
    for mesh in doc.get("meshes") or []:
        for prim in (mesh or {}).get("primitives") or []:
            acc = (prim.get("attributes") or {}).get("TEXCOORD_1")
            if acc is None:
                continue
            uv = data.accessor(acc)[:, :2]
            doc["accessors"].append({"bufferView": data.append(np.ascontiguousarray(uv, "<f4")), "byteOffset": 0,
                                     "componentType": 5126, "count": len(uv), "type": "VEC2"})
            prim["attributes"][SECOND_UV] = len(doc["accessors"]) - 1
            changed = True
    return changed


def _reference_uvs(doc: dict[str, Any], data: _DocData) -> bool:
    """Give every primitive whose base colour samples a UV set other than TEXCOORD_0, or through a
    KHR_texture_transform, a ``_REF_UV`` attribute: that set with the transform applied (glTF's
    ``T * R * S``), i.e. the UVs the base colour is sampled with, which the build bakes into uv0.
    trimesh reads TEXCOORD_0 untransformed only. True when something was added."""
    materials, changed = doc.get("materials") or [], False
    for mesh in doc.get("meshes") or []:
        for prim in (mesh or {}).get("primitives") or []:
            mi = prim.get("material")
            if not isinstance(mi, int) or not 0 <= mi < len(materials):
                continue
            mat = materials[mi] or {}
            info = ((mat.get("pbrMetallicRoughness") or {}).get("baseColorTexture")
                    or ((mat.get("extensions") or {}).get("KHR_materials_pbrSpecularGlossiness") or {}).get(
                        "diffuseTexture"))
            if not isinstance(info, dict):
                continue
            tt = (info.get("extensions") or {}).get("KHR_texture_transform")
            n = int((tt or {}).get("texCoord", info.get("texCoord", 0)) or 0)
            acc = (prim.get("attributes") or {}).get(f"TEXCOORD_{n}")
            if (n == 0 and tt is None) or acc is None:
                continue
            uv = data.accessor(acc)[:, :2]
            if tt is not None:
                ox, oy = (tt.get("offset") or (0.0, 0.0))[:2]
                sx, sy = (tt.get("scale") or (1.0, 1.0))[:2]
                c, s_ = np.cos(float(tt.get("rotation", 0.0))), np.sin(float(tt.get("rotation", 0.0)))
                u, v = uv[:, 0] * sx, uv[:, 1] * sy
                uv = np.stack([c * u + s_ * v + ox, -s_ * u + c * v + oy], axis=1)
            doc["accessors"].append({"bufferView": data.append(np.ascontiguousarray(uv, "<f4")), "byteOffset": 0,
                                     "componentType": 5126, "count": len(uv), "type": "VEC2"})
            prim["attributes"][REFERENCE_UV] = len(doc["accessors"]) - 1
            changed = True
    return changed


_GL_TRIANGLE_FAN = 6


def _fans_as_triangles(doc: dict[str, Any], data: _DocData) -> bool:
    """Every TRIANGLE_FAN primitive (mode 6), which trimesh's reader drops, as TRIANGLES over
    the same vertices: the fan's triangles ``{v[i+1], v[i+2], v[0]}`` of its index list (its
    indices, or the vertices in order; glTF 2.0, 3.7.2.1), in a new uint32 indices accessor.
    Without this the source of a fan had no triangles to compare, and a reversed winding
    in the build went unseen (the Mesh_PrimitiveMode fans: 4 missed mutations). A fan of
    fewer than three vertices draws nothing and is left as it is. Whether any changed.

    Written here, not taken from the importer (``pipelines.import_gltf``, which triangulates
    fans the same way): the source reference checks the build independently of it, and the
    renderer's layer does not import the pipelines' (docs/ARCHITECTURE.md)."""
    changed = False
    for mesh in doc.get("meshes") or []:
        for prim in mesh.get("primitives") or []:
            pos = (prim.get("attributes") or {}).get("POSITION")
            if prim.get("mode") != _GL_TRIANGLE_FAN or pos is None:
                continue
            if prim.get("indices") is not None:
                order = data.accessor(prim["indices"]).reshape(-1).astype(np.int64)
            else:
                order = np.arange(int(doc["accessors"][pos]["count"]), dtype=np.int64)
            if order.size < 3:
                continue
            i = np.arange(order.size - 2)
            tri = np.stack([order[i + 1], order[i + 2], np.full(i.size, order[0])], 1)
            flat = np.ascontiguousarray(tri.reshape(-1), "<u4")
            doc["accessors"].append({"bufferView": data.append(flat), "byteOffset": 0,
                                     "componentType": 5125, "count": int(flat.size), "type": "SCALAR"})
            prim["indices"] = len(doc["accessors"]) - 1
            prim["mode"] = 4
            changed = True
    return changed


def _spec_gloss_as_diffuse(path: Path) -> tuple[bytes, str] | None:
    """The source with every KHR_materials_pbrSpecularGlossiness material read as its diffuse
    (baseColor = diffuseFactor x diffuseTexture), every sparse accessor made plain
    (:func:`_densify_sparse`) and every triangle fan made a triangle list
    (:func:`_fans_as_triangles`), or None when it has none of them.

    The renderer draws albedo (factor x texture x vertex colour, no metallic or specular term),
    and the build stores a spec-gloss material's diffuse as its base colour. trimesh instead
    converts spec-gloss to metal-rough (KHR's Babylon formula), whose baseColor differs from the
    diffuse wherever the specular colour is above 0.04 (the default specularFactor is 1): drawn
    without the metallic term that conversion relies on, it is not the same material. So the
    reference reads the diffuse, as a spec-gloss renderer's diffuse term does.
    """
    import json  # noqa: PLC0415
    import struct  # noqa: PLC0415

    doc = _gltf_json(path)
    if doc is None:
        return None
    data = _DocData(doc, path)
    sparse = _densify_sparse(doc, data)
    ref_uv = _reference_uvs(doc, data)
    ref_uv = _second_uvs(doc, data) or ref_uv
    fans = _fans_as_triangles(doc, data)
    data.finish()
    if not (sparse or ref_uv or fans) and "KHR_materials_pbrSpecularGlossiness" not in (doc.get("extensionsUsed") or []):
        return None
    for mat in doc.get("materials") or []:
        sg = (mat.get("extensions") or {}).pop("KHR_materials_pbrSpecularGlossiness", None)
        if sg is None:
            continue
        pbr = mat.setdefault("pbrMetallicRoughness", {})
        pbr.pop("baseColorTexture", None)
        pbr["baseColorFactor"] = list(sg.get("diffuseFactor", [1.0, 1.0, 1.0, 1.0]))
        if sg.get("diffuseTexture") is not None:
            pbr["baseColorTexture"] = sg["diffuseTexture"]
    doc["extensionsUsed"] = [e for e in doc.get("extensionsUsed") or [] if e != "KHR_materials_pbrSpecularGlossiness"]
    doc["extensionsRequired"] = [e for e in doc.get("extensionsRequired") or []
                                 if e != "KHR_materials_pbrSpecularGlossiness"]
    js = json.dumps(doc).encode()
    if path.suffix.lower() == ".gltf":
        return js, "gltf"
    data = path.read_bytes()
    off, blob = 12, b""
    while off + 8 <= len(data):
        clen, ctype = struct.unpack_from("<II", data, off)
        if ctype == 0x004E4942:
            blob = data[off + 8: off + 8 + clen]
        off += 8 + clen
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks, "glb"


def _gltf_json(path: Path) -> dict[str, Any] | None:
    """The JSON of a .gltf or .glb file (None for other formats or on errors)."""
    import json  # noqa: PLC0415
    import struct  # noqa: PLC0415

    try:
        if path.suffix.lower() == ".gltf":
            return json.loads(path.read_text(encoding="utf-8"))
        if path.suffix.lower() == ".glb":
            with path.open("rb") as f:
                head = f.read(20)
                length = struct.unpack_from("<I", head, 12)[0]
                return json.loads(f.read(length))
    except (OSError, ValueError, struct.error):
        return None
    return None


def uv_caveat(path: Path) -> str | None:
    """Why the source's uv0 as trimesh reads it is not the build's uv0 (None when it is)."""
    doc = _gltf_json(path)
    if doc is None:
        return None
    if "KHR_texture_transform" in set(doc.get("extensionsUsed", [])):
        return "the source uses KHR_texture_transform (baked into the built UVs): UVs not compared"
    for mat in doc.get("materials") or []:
        pbr = (mat or {}).get("pbrMetallicRoughness") or {}
        sg = ((mat or {}).get("extensions") or {}).get("KHR_materials_pbrSpecularGlossiness") or {}
        info = pbr.get("baseColorTexture") or sg.get("diffuseTexture") or {}
        if int(info.get("texCoord", 0) or 0) != 0:
            return "a base colour texture uses a TEXCOORD other than 0, which trimesh does not read: UVs not compared"
    return None


def source_caveats(path: Path, built: RenderModel, source: RenderModel) -> tuple[bool, bool, list[str]]:
    """(compare geometry?, compare colours?, notes): where trimesh's reading is known to differ.

    * glTF sparse accessors: trimesh ignores them, so its geometry is not a reference.
    * KHR_texture_transform: trimesh ignores it; colours are not compared.
    * OBJ without ``mtllib``: trimesh invents a grey material where the build uses white.
    * The build has textures but trimesh loaded none (unresolvable paths, e.g. backslashes).
    """
    notes: list[str] = []
    geometry, colour = True, True
    doc = _gltf_json(path)
    if doc is not None:
        if any(isinstance(a, dict) and "sparse" in a for a in doc.get("accessors", [])) and not \
                source.sidecar.get("sparseApplied"):
            geometry = False
            notes.append("the source uses sparse accessors, which trimesh ignores: no source comparison")
        used = set(doc.get("extensionsUsed", []))
        if "KHR_texture_transform" in used:
            colour = False
            notes.append("the source uses KHR_texture_transform, which trimesh ignores: colours not compared")
        for mat in doc.get("materials") or []:
            pbr = (mat or {}).get("pbrMetallicRoughness") or {}
            sg = ((mat or {}).get("extensions") or {}).get("KHR_materials_pbrSpecularGlossiness") or {}
            info = pbr.get("baseColorTexture") or sg.get("diffuseTexture") or {}
            if colour and int(info.get("texCoord", 0) or 0) != 0:
                colour = False
                notes.append("a base colour texture uses a TEXCOORD other than 0, which trimesh does not read: "
                             "colours not compared (the roles check still compares the textures)")
    elif path.suffix.lower() == ".obj":
        try:
            with path.open("rb") as f:
                has_mtl = b"mtllib" in f.read(1 << 22)
        except OSError:
            has_mtl = False
        if not has_mtl:
            colour = False
            notes.append("the OBJ has no mtllib (trimesh's default material is grey): colours not compared")
    if colour and any(m.texture is not None for m in built.materials) and not any(
            m.texture is not None for m in source.materials):
        colour = False
        notes.append("trimesh loaded none of the source's textures: colours not compared")
    return geometry, colour, notes


def role_samplers(path: Path) -> dict[str, dict[str, dict[str, Any]]]:
    """{material name: {role: glTF sampler}} of the glTF at ``path``, for the materials whose name
    is unique (trimesh keeps a material's name, not its index, nor its samplers). A role without a
    sampler gets glTF's default (repeat, the viewer's choice of filter: trilinear here)."""
    doc = _gltf_json(path) or {}
    mats = doc.get("materials") or []
    names = [str(m.get("name")) for m in mats if isinstance(m, dict) and m.get("name") is not None]
    textures, samplers = doc.get("textures") or [], doc.get("samplers") or []
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for mat in mats:
        if not isinstance(mat, dict) or mat.get("name") is None or names.count(str(mat["name"])) != 1:
            continue
        roles: dict[str, dict[str, Any]] = {}
        for role, paths in GLTF_ROLE_PATHS.items():
            for keys in paths:
                node: Any = mat
                for k in keys:
                    node = node.get(k) if isinstance(node, dict) else None
                if isinstance(node, dict) and isinstance(node.get("index"), int) and 0 <= node["index"] < len(textures):
                    si = (textures[node["index"]] or {}).get("sampler")
                    smp = dict(samplers[si]) if isinstance(si, int) and 0 <= si < len(samplers) else {}
                    smp.setdefault("minFilter", 9987)
                    roles[role] = smp
                    break
        out[str(mat["name"])] = roles
    return out
