"""An independent reading of the *source* model (glTF/OBJ via trimesh), for comparison renders.

This path shares nothing with the build's importers: trimesh parses the source, its scene
graph is flattened with trimesh's own transforms (``Scene.dump``), and the result becomes a
:class:`~renderer.loader.RenderModel` drawn by the same renderer. Each geometry keeps its
base colour factor and base-colour image (level 0 only, no mips) when trimesh provides them,
so renders can be compared in colour as well as in silhouette; anything trimesh cannot
describe is drawn white.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import AssetError, MissingFileError

from .loader import VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM, Lod, Material, Mesh, RenderModel, Texture


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


def _material_of(geom: Any, name: str, notes: list[str], images: dict[int, Texture] | None = None,
                 decoded: dict[str, Any] | None = None,
                 ) -> tuple[Material, np.ndarray | None, np.ndarray | None]:
    """(material, uv (N,2) top-left origin or None, vertex colours (N,4) or None) of a trimesh geometry."""
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
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        alpha_mode = str(getattr(mat, "alphaMode", None) or ("BLEND" if factor[3] < 1.0 else "OPAQUE"))
        cutoff = float(getattr(mat, "alphaCutoff", None) or 0.5)
        double_sided = bool(getattr(mat, "doubleSided", False))
    texture = None
    if image is not None and uv is not None and images is not None and id(image) in images:
        texture = images[id(image)]
    elif image is not None and uv is not None:
        try:
            rgba = _rgba_of(image, decoded)
            texture = Texture(name=f"{name} source image", levels=[rgba], vk_format=VK_FORMAT_R8G8B8A8_SRGB,
                              sampler={"minFilter": 9729}, from_ktx2=False)
            if images is not None:
                images[id(image)] = texture
        except Exception as exc:  # noqa: BLE001
            notes.append(f"{name}: source image not usable ({exc})")
    normal = None
    nimage = getattr(mat, "normalTexture", None) if mat is not None else None
    if nimage is not None and uv is not None:  # level 0 only, as UNORM data (the shaded check draws it)
        key = (id(nimage), "normal")
        try:
            if images is not None and key in images:  # type: ignore[operator]
                normal = images[key]  # type: ignore[index]
            else:
                normal = Texture(name=f"{name} source normal map", levels=[_rgba_of(nimage, decoded)],
                                 vk_format=VK_FORMAT_R8G8B8A8_UNORM, sampler={"minFilter": 9729}, from_ktx2=False)
                if images is not None:
                    images[key] = normal  # type: ignore[index]
        except Exception as exc:  # noqa: BLE001
            notes.append(f"{name}: source normal map not usable ({exc})")
    return (Material(id=name, base_color=factor, alpha_mode=alpha_mode, alpha_cutoff=cutoff,  # type: ignore[arg-type]
                     double_sided=double_sided, texture=texture, normal_texture=normal), uv, colors)


def load_source_model(path: Path, flat: bool = False, decoded: dict[str, Any] | None = None) -> RenderModel:
    """Import ``path`` with trimesh, flatten its scene, and return it as a RenderModel.

    ``flat=True`` ignores materials (one white opaque material). Points and lines are dropped.
    ``decoded``: a per-model cache shared with the checks (see ``_rgba_of``).
    """
    import trimesh  # noqa: PLC0415

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(path, "source file is missing")
    try:
        diffuse = _spec_gloss_as_diffuse(path)
        if diffuse is None:
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
    meshes: list[Mesh] = []
    materials: list[Material] = [Material(id="flat")] if flat else []
    mat_cache: dict[str, tuple[int, Any, Any]] = {}
    image_cache: dict[int, Texture] = {}
    base = first = 0
    for k, (transform, gname, g) in enumerate(instances):
        v = np.asarray(g.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
        f = np.asarray(g.faces, np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:
            f = f[:, ::-1]
        n = len(v)
        if flat:
            mat_index, uv, col = 0, None, None
        elif gname in mat_cache:
            mat_index, uv, col = mat_cache[gname]
        else:
            mat, uv, col = _material_of(g, f"source-{k}", notes, image_cache, decoded)
            mat_index = len(materials)
            materials.append(mat)
            mat_cache[gname] = (mat_index, uv, col)
        positions.append(v.astype(np.float32))
        uvs.append(uv if uv is not None else np.zeros((n, 2), np.float32))
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
                       radius=float(np.linalg.norm(hi - lo) / 2), notes=notes, root=path.parent)


def _spec_gloss_as_diffuse(path: Path) -> tuple[bytes, str] | None:
    """The source with every KHR_materials_pbrSpecularGlossiness material read as its diffuse
    (baseColor = diffuseFactor x diffuseTexture), or None when it has none.

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
    if doc is None or "KHR_materials_pbrSpecularGlossiness" not in (doc.get("extensionsUsed") or []):
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
    doc["extensionsUsed"] = [e for e in doc["extensionsUsed"] if e != "KHR_materials_pbrSpecularGlossiness"]
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
        if any(isinstance(a, dict) and "sparse" in a for a in doc.get("accessors", [])):
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
