"""glTF 2.0 importer (.gltf with external or embedded buffers, .glb).

``import_gltf(path) -> ImportedModel``: parses the JSON (:mod:`pipelines.gltf_document`: a
checked, read-only view; pygltflib's dataclass decoding was 200x slower), decodes accessors with numpy
(:mod:`pipelines.gltf_accessors`), flattens the node hierarchy into model space the way
Assimp's ``aiProcess_PreTransformVertices`` does (one mesh per primitive per placing node),
triangulates strips and fans, and maps materials to :class:`pipelines.model.Material`.

What is dropped is said in warnings: POINTS/LINES primitives, skins (the bind pose is kept),
morph targets (default weights applied), animations.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from assetpipe.core.errors import AssetError, InvalidGeometryError, UnsupportedError
from assetpipe.pipelines.gltf_document import GltfObject, JsonError, check_structure, load_json
from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, InputBudgets, describe_bytes
from assetpipe.pipelines.gltf_accessors import COMPONENT_DTYPES, AccessorReader, check_uri, data_uri_mime, decode_data_uri
from assetpipe.pipelines.image_source import image_from_bytes, read_image_file, resolve_inside
from assetpipe.pipelines.model import ImageSource, ImportedModel, Material, MeshData, Sampler, TextureRef

SUPPORTED_EXTENSIONS = frozenset({
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_materials_pbrSpecularGlossiness",
})

MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES",
              5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}
GLB_MAGIC = b"glTF"


# -- parsing ------------------------------------------------------------------------------

def _parse(path: Path):
    """(document view, glb binary chunk or None) for a .gltf or .glb file."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise AssetError(path, "file not found") from None
    if data.startswith(b"version https://git-lfs"):
        raise AssetError(path, "is a Git LFS pointer, not a model (fetch it with git lfs pull)")
    blob = None
    if data.startswith(GLB_MAGIC):
        json_bytes, blob = _split_glb(path, data)
    elif path.suffix.lower() == ".glb":
        raise AssetError(path, "is not a GLB file (no 'glTF' magic)")
    else:
        json_bytes = data
    try:
        doc = load_json(json_bytes.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise AssetError(path, f"is not valid glTF JSON ({exc})") from None
    except JsonError as exc:
        raise AssetError(path, str(exc)) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        raise AssetError(path, "is not a glTF document (no 'asset' object)")
    version = str(doc["asset"].get("version", ""))
    if not version.startswith("2."):
        raise UnsupportedError(path, f"is glTF {version or '(no version)'}; only glTF 2.0 is supported")
    problem = check_structure(doc)
    if problem:
        raise AssetError(path, f"has a malformed glTF structure: {problem}")
    return GltfObject(doc), blob


def _split_glb(path: Path, data: bytes) -> tuple[bytes, bytes | None]:
    if len(data) < 20:
        raise AssetError(path, "GLB file is truncated (shorter than its header)")
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise UnsupportedError(path, f"GLB container version {version}; only version 2 is supported")
    if length > len(data):
        raise AssetError(path, f"GLB file is truncated: header says {length} bytes, file has {len(data)}")
    offset, json_bytes, blob = 12, None, None
    while offset + 8 <= length:
        chunk_len, chunk_type = struct.unpack_from("<II", data, offset)
        start, end = offset + 8, offset + 8 + chunk_len
        if end > length:
            raise AssetError(path, "GLB chunk runs past the end of the file")
        if chunk_type == 0x4E4F534A and json_bytes is None:
            json_bytes = data[start:end]
        elif chunk_type == 0x004E4942 and blob is None:
            blob = data[start:end]
        offset = end + (-chunk_len % 4)
    if json_bytes is None:
        raise AssetError(path, "GLB file has no JSON chunk")
    return json_bytes, blob


# -- transforms ---------------------------------------------------------------------------

def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = (float(c) for c in q)
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def node_matrix(node) -> np.ndarray:
    """The node's local 4x4 matrix (float64), from ``matrix`` or T * R * S."""
    if node.matrix is not None and len(node.matrix) == 16:
        return np.array(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    rs = np.eye(3)
    if node.rotation is not None:
        rs = _quat_matrix(node.rotation)
    if node.scale is not None:
        rs = rs * np.asarray(node.scale, dtype=np.float64)[None, :]
    m[:3, :3] = rs
    if node.translation is not None:
        m[:3, 3] = node.translation
    return m


def _given(obj: dict, key: str, default):
    """``obj[key]``, or ``default`` when absent or null."""
    value = obj.get(key)
    return default if value is None else value


def _uv_transform(ext: dict) -> np.ndarray:
    """KHR_texture_transform as a 3x3 matrix acting on (u, v, 1)."""
    # (a property given as null counts as absent, as everywhere else in the document)
    ox, oy = _given(ext, "offset", (0.0, 0.0))
    r = float(_given(ext, "rotation", 0.0))
    sx, sy = _given(ext, "scale", (1.0, 1.0))
    t = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1]], dtype=np.float64)
    c, s = math.cos(r), math.sin(r)
    rot = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], dtype=np.float64)
    sc = np.diag([sx, sy, 1.0])
    return t @ rot @ sc


# -- primitive topology --------------------------------------------------------------------

def triangles_from_mode(indices: np.ndarray, mode: int) -> np.ndarray:
    """(M, 3) triangles from a flat index list for TRIANGLES, TRIANGLE_STRIP or TRIANGLE_FAN."""
    n = indices.shape[0]
    if mode == 4:
        m = n // 3
        return indices[: m * 3].reshape(m, 3)
    if n < 3:
        return np.zeros((0, 3), dtype=indices.dtype)
    i = np.arange(n - 2)
    if mode == 5:  # strip: odd triangles swap their first two vertices to keep the winding
        odd = (i & 1).astype(bool)
        a = np.where(odd, indices[i + 1], indices[i])
        b = np.where(odd, indices[i], indices[i + 1])
        return np.stack([a, b, indices[i + 2]], axis=1)
    if mode == 6:  # fan: (v[i+1], v[i+2], v[0]) as the spec writes it
        return np.stack([indices[i + 1], indices[i + 2], np.full(n - 2, indices[0])], axis=1)
    raise ValueError(mode)


# -- the importer ---------------------------------------------------------------------------

@dataclass
class _Ctx:
    source: Path
    gltf: object
    reader: AccessorReader
    warnings: list[str]
    images: dict[int, ImageSource | None]
    image_deps: list[Path]
    budgets: InputBudgets = DEFAULT_INPUT_BUDGETS


def import_gltf(path: Path, budgets: InputBudgets = DEFAULT_INPUT_BUDGETS) -> ImportedModel:
    """Import a .gltf or .glb file.

    Before any accessor is decoded, the node hierarchy's placements and the declared sizes of
    every accessor a placed mesh uses are checked against ``budgets`` (see
    :mod:`pipelines.budgets`); a model over them is refused with one line.
    """
    path = Path(path)
    gltf, blob = _parse(path)
    required = set(gltf.extensionsRequired or [])
    unsupported = sorted(required - SUPPORTED_EXTENSIONS)
    if unsupported:
        raise UnsupportedError(path, f"requires extension{'s' if len(unsupported) > 1 else ''} "
                                     f"{', '.join(unsupported)}, which assetpipe cannot decode")
    ctx = _Ctx(path, gltf, AccessorReader(gltf, path, blob, budgets.max_model_bytes), [], {}, [], budgets)

    _check_budgets(ctx)
    materials, uv_transforms = _materials(ctx)
    meshes = _flatten(ctx, uv_transforms)

    if gltf.animations:
        ctx.warnings.append(f"{len(gltf.animations)} animation(s) dropped: the static pose is built")
    deps = list(dict.fromkeys(ctx.reader.dependencies + ctx.image_deps))
    return ImportedModel(source=path, meshes=tuple(meshes), materials=tuple(materials),
                         warnings=tuple(dict.fromkeys(ctx.warnings)), dependencies=tuple(deps))


def _scene_roots(gltf) -> list[int]:
    nodes = gltf.nodes or []
    if gltf.scenes:
        scene = gltf.scene if gltf.scene is not None else 0
        if not 0 <= scene < len(gltf.scenes):
            scene = 0
        return list(gltf.scenes[scene].nodes or [])
    children = {c for n in nodes for c in (n.children or [])}
    return [i for i in range(len(nodes)) if i not in children]


_ATTRIBUTE_TYPES = {"POSITION": ("VEC3",), "NORMAL": ("VEC3",), "TANGENT": ("VEC4",),
                    "TEXCOORD_0": ("VEC2",), "TEXCOORD_1": ("VEC2",), "COLOR_0": ("VEC3", "VEC4")}
_INDEX_TYPES = frozenset({5121, 5123, 5125})


def _placements(ctx: _Ctx) -> tuple[dict[int, int], int]:
    """How many times each mesh is placed, and how many node visits the flattening makes.

    Counted over the DAG (paths from the scene roots, by dynamic programming in topological
    order) without walking the paths, so 24 levels of shared subtrees (2^24 placements) are
    counted in microseconds. Raises for a cycle or a child that does not exist.
    """
    gltf = ctx.gltf
    nodes = gltf.nodes or []
    roots = _scene_roots(gltf)
    if not gltf.scenes and nodes and not roots:
        raise AssetError(ctx.source, "node hierarchy has a cycle: every node is another node's child")
    cap = ctx.budgets.max_placements + 1  # counts saturate here: big enough to refuse, never huge
    paths = [0] * len(nodes)
    for r in roots:
        if not 0 <= r < len(nodes):
            raise AssetError(ctx.source, f"node {r} does not exist")
        paths[r] = min(cap, paths[r] + 1)
    # reachable nodes and their in-degrees (edges counted with multiplicity)
    indeg = [0] * len(nodes)
    reached = set(roots)
    todo = list(dict.fromkeys(roots))
    while todo:
        ni = todo.pop()
        for c in nodes[ni].children or []:
            if not 0 <= c < len(nodes):
                raise AssetError(ctx.source, f"node {c} does not exist")
            indeg[c] += 1
            if c not in reached:
                reached.add(c)
                todo.append(c)
    ready = [r for r in dict.fromkeys(roots) if indeg[r] == 0]
    done = 0
    visits = 0
    per_mesh: dict[int, int] = {}
    while ready:
        ni = ready.pop()
        done += 1
        visits = min(cap, visits + paths[ni])
        node = nodes[ni]
        if node.mesh is not None:
            per_mesh[node.mesh] = min(cap, per_mesh.get(node.mesh, 0) + paths[ni])
        for c in node.children or []:
            paths[c] = min(cap, paths[c] + paths[ni])
            indeg[c] -= 1
            if indeg[c] == 0:
                ready.append(c)
    if done < len(reached):
        stuck = min(i for i in reached if indeg[i] > 0)
        raise AssetError(ctx.source, f"node hierarchy has a cycle: node {stuck} is its own ancestor")
    return per_mesh, visits


def _check_budgets(ctx: _Ctx) -> None:
    """Refuse a model whose declared geometry is over the budgets, before decoding any of it."""
    b = ctx.budgets
    per_mesh, visits = _placements(ctx)
    if visits > b.max_placements:
        raise AssetError(ctx.source, f"node hierarchy places more than {b.max_placements} nodes "
                                     "(shared subtrees?): over the placement budget")
    meshes = ctx.gltf.meshes or []
    total_bytes = total_tris = 0
    for mi, placed in sorted(per_mesh.items()):
        if not 0 <= mi < len(meshes):
            raise AssetError(ctx.source, f"node references mesh {mi}, which does not exist")
        for pi, prim in enumerate(meshes[mi].primitives or []):
            where = f"mesh {mi} primitive {pi}"
            accs = [a for a in (prim.get("attributes") or {}).values()]
            for target in prim.get("targets") or []:
                accs.extend(target.values())
            size = 0
            for a in accs:
                size += ctx.reader.decoded_bytes(a)
            vertices = 0
            position = (prim.get("attributes") or {}).get("POSITION")
            if position is not None:
                vertices = ctx.reader.info(position)[2]
            if prim.get("indices") is not None:
                size += ctx.reader.decoded_bytes(prim.get("indices"))
                corners = ctx.reader.info(prim.get("indices"))[2]
            else:
                corners = vertices
            total_bytes += size * placed
            total_tris += (corners // 3 if prim.get("mode") in (None, 4) else max(corners - 2, 0)) * placed
            if total_bytes > b.max_model_bytes:
                raise AssetError(ctx.source, f"{where}: the declared accessors, placed {placed} time(s), need "
                                             f"{describe_bytes(total_bytes)} or more decoded: over the model's "
                                             f"memory budget of {describe_bytes(b.max_model_bytes)}")
            if total_tris > b.max_triangles:
                raise AssetError(ctx.source, f"{where}: the model declares {total_tris} triangles or more: "
                                             f"over the triangle budget of {b.max_triangles}")


def _flatten(ctx: _Ctx, uv_transforms: dict[int, tuple[int, np.ndarray]]) -> list[MeshData]:
    gltf = ctx.gltf
    nodes = gltf.nodes or []
    meshes: list[MeshData] = []
    placements: dict[int, int] = {}
    decoded: dict[tuple, tuple | None] = {}
    # iterative DFS: (node index, parent world matrix, ancestors)
    roots = _scene_roots(gltf)
    if not gltf.scenes and nodes and not roots:
        raise AssetError(ctx.source, "node hierarchy has a cycle: every node is another node's child")
    stack = [(r, np.eye(4), frozenset()) for r in reversed(roots)]
    visits = 0
    skin_warned = False
    while stack:
        ni, parent, ancestors = stack.pop()
        if not 0 <= ni < len(nodes):
            raise AssetError(ctx.source, f"node {ni} does not exist")
        if ni in ancestors:
            raise AssetError(ctx.source, f"node hierarchy has a cycle: node {ni} is its own ancestor")
        visits += 1
        if visits > ctx.budgets.max_placements:  # _check_budgets counted them already: never true
            raise AssetError(ctx.source, f"node hierarchy places more than {ctx.budgets.max_placements} nodes")
        node = nodes[ni]
        with np.errstate(over="ignore", invalid="ignore"):
            world = parent @ node_matrix(node)
        if node.mesh is not None:
            if node.skin is not None and not skin_warned:
                ctx.warnings.append("skin dropped: skinned meshes are built in their bind pose")
                skin_warned = True
            k = placements.get(node.mesh, 0)
            placements[node.mesh] = k + 1
            meshes.extend(_place_mesh(ctx, node, node.mesh, k, world, decoded, uv_transforms))
        anc = ancestors | {ni}
        for c in reversed(node.children or []):
            stack.append((c, world, anc))
    return meshes


def _place_mesh(ctx, node, mesh_index: int, placement: int, world: np.ndarray,
                decoded: dict, uv_transforms) -> list[MeshData]:
    gltf = ctx.gltf
    if not 0 <= mesh_index < len(gltf.meshes or []):
        raise AssetError(ctx.source, f"node references mesh {mesh_index}, which does not exist")
    mesh = gltf.meshes[mesh_index]
    out = []
    lin = world[:3, :3]
    if not np.isfinite(world).all():
        raise InvalidGeometryError(ctx.source, f"mesh {mesh_index}: its node transform overflows to infinity or NaN")
    with np.errstate(all="ignore"):
        det = float(np.linalg.det(lin))
        normal_m = np.linalg.inv(lin).T if 1e-300 < abs(det) < 1e300 else lin
    weights = getattr(node, "weights", None)
    if weights is None:
        weights = getattr(mesh, "weights", None)
    for pi, prim in enumerate(mesh.primitives or []):
        # morphed primitives depend on the placing node's weights
        key = (mesh_index, pi, tuple(weights or ()) if prim.targets else None)
        if key not in decoded:
            decoded[key] = _decode_primitive(ctx, mesh_index, pi, prim, weights, uv_transforms)
        d = decoded[key]
        if d is None:
            continue
        pos, tris, attrs = d
        with np.errstate(all="ignore"):
            pos_w = pos @ lin.T + world[:3, 3]
            big = ~(np.abs(pos_w) <= ctx.budgets.max_coordinate).all(axis=1)  # NaN counts as too big
        if big.any():
            raise InvalidGeometryError(
                ctx.source, f"mesh {mesh_index} primitive {pi}: {int(big.sum())} of {big.size} positions are "
                            f"non-finite or beyond +-{ctx.budgets.max_coordinate:g} under the node transforms "
                            f"(float32 arithmetic on them would overflow)")
        if det < 0:  # mirrored: keep front faces front
            tris = tris[:, [0, 2, 1]]
        normals = attrs.get("normals")
        with np.errstate(all="ignore"):  # a huge or tiny node scale: non-finite results become 0
            if normals is not None:
                n = normals @ normal_m.T
                norm = np.linalg.norm(n, axis=1, keepdims=True)
                ok = np.isfinite(norm) & (norm > 0)
                normals = np.where(ok, n / np.where(ok, norm, 1.0), 0.0).astype(np.float32)
            tangents = attrs.get("tangents")
            if tangents is not None:
                t = tangents[:, :3] @ lin.T
                norm = np.linalg.norm(t, axis=1, keepdims=True)
                ok = np.isfinite(norm) & (norm > 0)
                t = np.where(ok, t / np.where(ok, norm, 1.0), 0.0)
                w = tangents[:, 3:4] * (-1.0 if det < 0 else 1.0)
                tangents = np.hstack([t, w]).astype(np.float32)
        name = f"mesh-{mesh_index}-{pi}" + (f"-n{placement}" if placement else "")
        out.append(MeshData(
            name=name, positions=pos_w, indices=tris,
            material=prim.material if prim.material is not None else -1,
            uv0=attrs.get("uv0"), uv1=attrs.get("uv1"), normals=normals, tangents=tangents,
            colors=attrs.get("colors"),
        ))
    return out


def _decode_primitive(ctx, mi: int, pi: int, prim, weights, uv_transforms):
    """(positions (N,3) f64, triangles (M,3) u32, attrs) in mesh space, or None if skipped."""
    where = f"mesh {mi} primitive {pi}"
    mode = 4 if prim.mode is None else prim.mode
    if mode not in (4, 5, 6):
        ctx.warnings.append(f"{where}: {MODE_NAMES.get(mode, f'mode {mode}')} primitive skipped (only triangles are built)")
        return None
    exts = prim.extensions or {}
    attrs_in = prim.attributes
    get = lambda name: getattr(attrs_in, name, None)  # noqa: E731
    if "KHR_draco_mesh_compression" in exts:
        pos, flat_idx, raw = _decode_draco(ctx, where, exts["KHR_draco_mesh_compression"])
    else:
        if get("POSITION") is None:
            ctx.warnings.append(f"{where}: no POSITION attribute, skipped")
            return None
        for name, types in _ATTRIBUTE_TYPES.items():
            if get(name) is not None and ctx.gltf.accessors[get(name)].type not in types:
                raise AssetError(ctx.source, f"{where}: attribute {name} is a {ctx.gltf.accessors[get(name)].type} "
                                             f"accessor, not {' or '.join(types)}")
        if prim.indices is not None:
            ctx.reader.info(prim.indices)
            acc = ctx.gltf.accessors[prim.indices]
            if acc.type != "SCALAR" or acc.componentType not in _INDEX_TYPES:
                raise AssetError(ctx.source, f"{where}: indices accessor {prim.indices} is {acc.type} of "
                                             f"{COMPONENT_DTYPES[acc.componentType].name}, not SCALAR unsigned "
                                             "byte, short or int")
        pos = ctx.reader.accessor(get("POSITION"))
        flat_idx = None if prim.indices is None else ctx.reader.accessor(prim.indices, as_float=False)
        raw = {}
        for name in ("NORMAL", "TANGENT", "TEXCOORD_0", "TEXCOORD_1", "COLOR_0"):
            if get(name) is not None:
                raw[name] = ctx.reader.accessor(get(name))
    n = pos.shape[0]
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise AssetError(ctx.source, f"{where}: POSITION is not VEC3")
    if not np.isfinite(pos).all():
        bad = int((~np.isfinite(pos).all(axis=1)).sum())
        raise InvalidGeometryError(ctx.source, f"{where}: {bad} of {n} vertex positions are NaN or infinite")
    for name, arr in raw.items():
        if arr.shape[0] != n:
            raise AssetError(ctx.source, f"{where}: attribute {name} has {arr.shape[0]} elements, POSITION has {n}")

    # morph targets: apply the default weights, drop the targets
    if prim.targets:
        w = list(weights or [])
        for ti, target in enumerate(prim.targets):
            t_pos = target.get("POSITION") if isinstance(target, dict) else getattr(target, "POSITION", None)
            if ti < len(w) and isinstance(w[ti], (int, float)) and w[ti] and t_pos is not None:
                if ctx.reader.info(t_pos)[1:] != (3, n):
                    raise AssetError(ctx.source, f"{where}: morph target {ti} POSITION is not VEC3 with {n} elements")
                with np.errstate(all="ignore"):  # overflow is caught by the coordinate check
                    pos = pos + float(w[ti]) * ctx.reader.accessor(t_pos)
        ctx.warnings.append(f"{where}: {len(prim.targets)} morph target(s) dropped (default weights applied)")

    if flat_idx is None:
        flat_idx = np.arange(n, dtype=np.uint32)
    flat_idx = flat_idx.reshape(-1)
    if flat_idx.size and int(flat_idx.max()) >= n:
        raise InvalidGeometryError(ctx.source, f"{where}: index {int(flat_idx.max())} is out of range ({n} vertices)")
    tris = triangles_from_mode(flat_idx.astype(np.uint32), mode)

    attrs: dict[str, np.ndarray] = {}
    if "NORMAL" in raw:
        attrs["normals"] = raw["NORMAL"]
    if "TANGENT" in raw and raw["TANGENT"].shape[1] == 4:
        attrs["tangents"] = raw["TANGENT"]
    for set_i in (0, 1):
        uv = raw.get(f"TEXCOORD_{set_i}")
        if uv is None:
            continue
        tr = uv_transforms.get(prim.material) if prim.material is not None else None
        if tr is not None and tr[0] == set_i:
            uv = np.hstack([uv, np.ones((uv.shape[0], 1))]) @ tr[1].T
            uv = uv[:, :2]
        attrs[f"uv{set_i}"] = np.ascontiguousarray(uv, dtype=np.float32)
    if "COLOR_0" in raw:
        c = raw["COLOR_0"]
        if c.shape[1] == 3:
            c = np.hstack([c, np.ones((c.shape[0], 1))])
        attrs["colors"] = c.astype(np.float32)
    return pos, tris, attrs


def _decode_draco(ctx, where: str, ext: dict):
    try:
        import DracoPy
    except ImportError:  # pragma: no cover - DracoPy is a dependency
        raise UnsupportedError(ctx.source, f"{where}: requires KHR_draco_mesh_compression and the DracoPy library is not installed") from None
    data = bytes(ctx.reader.buffer_view(ext["bufferView"]))
    try:
        mesh = DracoPy.decode(data)
    except Exception as exc:
        raise AssetError(ctx.source, f"{where}: KHR_draco_mesh_compression data does not decode ({exc})") from None
    pos = np.asarray(mesh.points, dtype=np.float64).reshape(-1, 3)
    faces = getattr(mesh, "faces", None)
    flat_idx = None if faces is None else np.asarray(faces, dtype=np.uint32).reshape(-1)
    raw = {}
    for name, uid in (ext.get("attributes") or {}).items():
        if name == "POSITION" or name not in ("NORMAL", "TEXCOORD_0", "TEXCOORD_1", "COLOR_0", "TANGENT"):
            continue
        att = mesh.get_attribute_by_unique_id(uid)
        if att is None:
            continue
        arr = np.asarray(att["data"] if isinstance(att, dict) else att, dtype=np.float64)
        arr = arr.reshape(pos.shape[0], -1)
        raw[name] = arr
    return pos, flat_idx, raw


# -- materials ------------------------------------------------------------------------------

def _materials(ctx: _Ctx):
    gltf = ctx.gltf
    out = []
    uv_transforms: dict[int, tuple[int, np.ndarray]] = {}
    for mi, mat in enumerate(gltf.materials or []):
        pbr = mat.pbrMetallicRoughness
        exts = mat.extensions or {}
        sg = exts.get("KHR_materials_pbrSpecularGlossiness")
        base_factor = tuple(pbr.baseColorFactor) if pbr and pbr.baseColorFactor else (1.0, 1.0, 1.0, 1.0)
        base_info = _info_dict(pbr.baseColorTexture) if pbr else None
        if sg is not None:
            base_factor = tuple(_given(sg, "diffuseFactor", base_factor))
            base_info = _given(sg, "diffuseTexture", base_info)
        where = f"material {mi} ({mat.name or 'unnamed'})"
        base = _texture_ref(ctx, base_info, where)
        if base is not None:
            tt = (base_info.get("extensions") or {}).get("KHR_texture_transform")
            if tt is not None:
                tex_coord = int(_given(tt, "texCoord", base.tex_coord))
                uv_transforms[mi] = (tex_coord, _uv_transform(tt))
                base = TextureRef(base.image, base.sampler, tex_coord)
        others = {}
        for role, info in (("metallic_roughness_texture", _info_dict(pbr.metallicRoughnessTexture) if pbr else None),
                           ("normal_texture", _info_dict(mat.normalTexture)),
                           ("occlusion_texture", _info_dict(mat.occlusionTexture)),
                           ("emissive_texture", _info_dict(mat.emissiveTexture))):
            others[role] = _texture_ref(ctx, info, where)
            if info and (info.get("extensions") or {}).get("KHR_texture_transform") and mi in uv_transforms:
                ctx.warnings.append(f"{where}: KHR_texture_transform is applied for the base colour texture only")
        alpha_mode = mat.alphaMode or "OPAQUE"
        if alpha_mode not in ("OPAQUE", "MASK", "BLEND"):
            ctx.warnings.append(f"{where}: unknown alphaMode {alpha_mode!r}, treated as OPAQUE")
            alpha_mode = "OPAQUE"
        out.append(Material(
            name=mat.name or f"material{mi}",
            base_color_factor=tuple(float(c) for c in base_factor),
            base_color_texture=base,
            alpha_mode=alpha_mode,
            alpha_cutoff=float(mat.alphaCutoff if mat.alphaCutoff is not None else 0.5),
            double_sided=bool(mat.doubleSided),
            metallic_factor=float(pbr.metallicFactor if pbr and pbr.metallicFactor is not None else 1.0),
            roughness_factor=float(pbr.roughnessFactor if pbr and pbr.roughnessFactor is not None else 1.0),
            emissive_factor=tuple(float(c) for c in (mat.emissiveFactor or (0.0, 0.0, 0.0))),
            **others,
        ))
    return out, uv_transforms


def _info_dict(info) -> dict | None:
    if info is None:
        return None
    if isinstance(info, dict):
        return info
    d = {"index": info.index, "texCoord": info.texCoord or 0}
    if getattr(info, "extensions", None):
        d["extensions"] = info.extensions
    return d


def _texture_ref(ctx: _Ctx, info: dict | None, where: str) -> TextureRef | None:
    if not info or info.get("index") is None:
        return None
    gltf = ctx.gltf
    ti = int(info["index"])
    if not 0 <= ti < len(gltf.textures or []):
        ctx.warnings.append(f"{where}: texture {ti} does not exist; ignored")
        return None
    tex = gltf.textures[ti]
    source = tex.source
    if source is None:
        for ext in (tex.extensions or {}).values():  # e.g. KHR_texture_basisu / EXT_texture_webp
            if isinstance(ext, dict) and ext.get("source") is not None:
                source = ext["source"]
                break
    if source is None:
        ctx.warnings.append(f"{where}: texture {ti} has no image source; ignored")
        return None
    image = _image(ctx, int(source), where)
    if image is None:
        return None
    sampler = Sampler()
    if tex.sampler is not None and 0 <= tex.sampler < len(gltf.samplers or []):
        s = gltf.samplers[tex.sampler]
        sampler = Sampler(s.magFilter, s.minFilter, s.wrapS or 10497, s.wrapT or 10497)
    return TextureRef(image=image, sampler=sampler, tex_coord=int(info.get("texCoord") or 0))


def _image(ctx: _Ctx, index: int, where: str) -> ImageSource | None:
    if index in ctx.images:
        return ctx.images[index]
    gltf = ctx.gltf
    result = None
    if not 0 <= index < len(gltf.images or []):
        ctx.warnings.append(f"{where}: image {index} does not exist; texture ignored")
    else:
        img = gltf.images[index]
        label = f"{ctx.source.stem}#image{index}"
        # One policy for references (docs/BUILD.md, "Missing and broken references"): a file
        # that is absent is a warning (the texture is dropped; buffers are required, so a
        # missing .bin is an error); a reference that is refused (outside the folder, a URI
        # scheme) or data that is present but broken (bad base64, not an image) is an error.
        if img.uri is not None and img.uri.startswith("data:"):
            data = decode_data_uri(img.uri, ctx.source, f"image {index}")
            result = image_from_bytes(data, img.name or label, f"{ctx.source}#images[{index}]", ctx.source,
                                      declared_mime=data_uri_mime(img.uri))
        elif img.uri is not None:
            check_uri(img.uri, ctx.source, f"image {index}")
            rel = unquote(img.uri)
            p = resolve_inside(ctx.source.parent, rel, ctx.source)
            if not p.is_file():
                ctx.warnings.append(f"{where}: image {rel!r} not found; texture ignored")
            else:
                result = read_image_file(p, ctx.source)
                ctx.image_deps.append(p)
        elif img.bufferView is not None:
            data = bytes(ctx.reader.buffer_view(img.bufferView))
            result = image_from_bytes(data, img.name or label, f"{ctx.source}#images[{index}]", ctx.source,
                                      declared_mime=img.mimeType)
        else:
            ctx.warnings.append(f"{where}: image {index} has neither uri nor bufferView; texture ignored")
    ctx.images[index] = result
    return result
