"""The build's steps as tasks: each reads its inputs from the store (or a source file), runs
the pure pipeline function, and writes its outputs to the store as blobs.

Every task takes only plain, picklable arguments (paths, digests, option dicts), so the
graph can run it in this process or in a worker process. Each returns a *record*:
``{"blobs": {name: digest}, "meta": {...}}``. Tasks never raise for a bad asset: the caller
wraps them with :func:`call_task`, which turns an :class:`AssetError` into a result.

Step versions live in :mod:`assetpipe.versions`.
"""

from __future__ import annotations

import dataclasses
import time
import traceback
from pathlib import Path

import numpy as np

from assetpipe import __version__
from assetpipe.core.errors import AssetError
from assetpipe.core.rows import column_bounds
from assetpipe.cache.serialize import pack_chunks, unpack
from assetpipe.cache.store import Store

def call_task(fn, *args) -> tuple[str, object, float]:
    """Run a task: (status, value, seconds) with status "ok" (value: the record), "asset"
    (value: "path: problem") or "internal" (value: the traceback of a bug of ours)."""
    t0 = time.perf_counter()
    try:
        return "ok", fn(*args), time.perf_counter() - t0
    except AssetError as exc:
        return "asset", str(exc), time.perf_counter() - t0
    except MemoryError:  # the graph names the input and the step (no more to say here)
        return "memory", "", time.perf_counter() - t0
    except Exception as exc:  # a bug of ours
        return "internal", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}", time.perf_counter() - t0


def options_from_json(cls, data: dict | None):
    if data is None:
        return None
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for k, v in data.items():
        if k in fields:
            kwargs[k] = tuple(v) if isinstance(v, list) else v
    return cls(**kwargs)


def options_to_json(opts) -> dict | None:
    if opts is None:
        return None
    return dataclasses.asdict(opts)


# -- import ---------------------------------------------------------------------------------

def _relative(path: Path, base: Path) -> str:
    try:
        return Path(path).resolve().relative_to(base.resolve()).as_posix()
    except ValueError:
        return str(path)


def task_import(store_root: str, source: str, budgets: dict | None = None) -> dict:
    """Import a model file; store its geometry and materials (and embedded images).
    ``budgets``: :class:`pipelines.budgets.InputBudgets` as a dict (None: the defaults)."""
    from assetpipe.core.hashing import digest_file
    from assetpipe.model_import import import_model
    from assetpipe.pipelines.budgets import InputBudgets

    store = Store(Path(store_root))
    src = Path(source)
    model = import_model(src, options_from_json(InputBudgets, budgets))
    base = src.parent
    images: list[dict] = []
    image_index: dict[tuple, int] = {}
    blobs: dict[str, str] = {}

    def image_ref(ref) -> int:
        img = ref.image
        key = (img.digest, str(img.path) if img.path else None)
        if key not in image_index:
            entry = {"name": img.name, "mime": img.mime, "digest": img.digest,
                     "path": _relative(img.path, base) if img.path is not None else None}
            if img.path is None:
                blobs[f"image:{img.digest}"] = store.put_blob(img.data)
            image_index[key] = len(images)
            images.append(entry)
        return image_index[key]

    materials = [material_description(m, image_ref) for m in model.materials]
    arrays: dict[str, np.ndarray] = {}
    meshes = []
    for i, mesh in enumerate(model.meshes):
        attrs = []
        for name in ("positions", "indices", "uv0", "uv1", "normals", "tangents", "colors"):
            arr = getattr(mesh, name)
            if arr is not None:
                arrays[f"{i}.{name}"] = arr
                attrs.append(name)
        meshes.append({"name": mesh.name, "material": mesh.material, "attributes": attrs})
    image_paths = {(base / im["path"]).resolve() for im in images if im["path"] is not None}
    deps = [{"path": _relative(d, base), "digest": digest_file(d)}
            for d in model.dependencies if Path(d).resolve() not in image_paths]
    # geometry only: a material or texture edit leaves this blob, and the steps keyed on it, alone
    blobs["geometry"] = store.put_blob(pack_chunks({"meshes": meshes}, arrays))
    if model.meshes:
        pos = np.vstack([m.positions for m in model.meshes])
        lo, hi = column_bounds(pos) if pos.size else (np.zeros(3), np.zeros(3))
        radius = float(np.sqrt(np.max(np.sum((pos - (lo + hi) / 2) ** 2, axis=1)))) if pos.size else 0.0
        center = ((lo + hi) / 2).tolist() if pos.size else [0.0, 0.0, 0.0]
    else:
        radius, center = 0.0, [0.0, 0.0, 0.0]
    return {"blobs": blobs, "meta": {"deps": deps, "images": images, "materials": materials,
                                     "meshMaterials": [m.material for m in model.meshes],
                                     "radius": radius, "center": center, "warnings": list(model.warnings)}}


def load_geometry(store: Store, digest: str):
    """(meta, list of MeshData) from an import step's geometry blob."""
    from assetpipe.pipelines.model import MeshData

    data = store.get_blob(digest)
    if data is None:
        raise FileNotFoundError(digest)
    meta, arrays = unpack(data)
    meshes = []
    for i, m in enumerate(meta["meshes"]):
        get = lambda n: arrays.get(f"{i}.{n}")  # noqa: E731
        meshes.append(MeshData(name=m["name"], positions=get("positions"), indices=get("indices"),
                               material=m["material"], uv0=get("uv0"), uv1=get("uv1"), normals=get("normals"),
                               tangents=get("tangents"), colors=get("colors")))
    return meta, meshes


# -- mesh processing ------------------------------------------------------------------------

def uv_sets(materials: list[dict], mesh_materials: list[int]) -> list[int]:
    """Per mesh, the UV set its material's base colour texture samples (0 without one)."""
    out = []
    for m in mesh_materials:
        mat = materials[m] if 0 <= m < len(materials) else None
        out.append(int(mat["textures"].get("baseColor", {}).get("texCoord", 0)) if mat else 0)
    return out


def task_mesh(store_root: str, geometry_digest: str, uv_set_per_mesh: list[int], mesh_options: dict,
              double_sided: list[bool] | None = None, offset: list[float] | None = None) -> dict:
    """``double_sided[i]``: mesh i's material's flag; ``offset``: the recentring offset (the
    LOD0 file's bounding-box centre) subtracted from positions, or None."""
    from assetpipe.pipelines.mesh_process import (FLOAT32_WARN_FRACTION, MeshOptions, float32_resolution,
                                                   process_mesh)

    store = Store(Path(store_root))
    opts = options_from_json(MeshOptions, mesh_options)
    meta, meshes = load_geometry(store, geometry_digest)
    out_meta, arrays = [], {}
    order_plans: dict = {}  # the model's distinct index buffers, vertex-cache optimised once
    for i, mesh in enumerate(meshes):
        if uv_set_per_mesh[i] < 0:  # no material of the mesh samples a texture: UVs not computed
            mesh = dataclasses.replace(mesh, uv0=None, uv1=None)
        pm = process_mesh(mesh, opts, uv_set=max(uv_set_per_mesh[i], 0),
                          double_sided=bool(double_sided[i]) if double_sided else False, offset=offset,
                          order_plans=order_plans)
        arrays[f"{i}.vertices"] = pm.vertices
        arrays[f"{i}.indices"] = pm.indices
        out_meta.append({"name": pm.name, "material": pm.material, "degenerate": pm.degenerate_dropped,
                         "duplicates": pm.duplicates_dropped, "welded": pm.welded, "warnings": list(pm.warnings),
                         "hasUv": mesh.uv0 is not None})
    warnings = []
    written = [pm_v[:, :3] for k, pm_v in arrays.items() if k.endswith(".vertices") and pm_v.shape[0]]
    step, diag = float32_resolution(np.vstack(written)) if written else (0.0, 0.0)
    if diag > 0 and step > FLOAT32_WARN_FRACTION * diag:
        warnings.append(f"float32 positions are {step:.3g} apart at this distance from the origin, "
                        f"{step / diag:.2g} of the model's size (over {FLOAT32_WARN_FRACTION:g}): shapes are "
                        "distorted" + ("" if offset is not None else
                                      "; build with --recenter to write positions relative to the model's centre"))
    blob = store.put_blob(pack_chunks({"meshes": out_meta}, arrays))
    return {"blobs": {"mesh": blob},
            "meta": {"triangles": int(sum(arrays[f"{i}.indices"].shape[0] for i in range(len(meshes)))),
                     "degenerate": int(sum(m["degenerate"] for m in out_meta)),
                     "float32Step": step, "diagonal": diag, "warnings": warnings}}


# -- LOD ------------------------------------------------------------------------------------

def material_description(m, image_ref) -> dict:
    """The import step's description of a material (``pipelines.model.Material``), its textures'
    images named by ``image_ref(texture ref)``."""
    textures = {role: {"image": image_ref(ref), "texCoord": ref.tex_coord, "sampler": ref.sampler.to_json()}
                for role, ref in m.textures().items()}
    return {"name": m.name, "baseColorFactor": list(m.base_color_factor), "alphaMode": m.alpha_mode,
            "alphaCutoff": m.alpha_cutoff, "doubleSided": m.double_sided, "metallicFactor": m.metallic_factor,
            "roughnessFactor": m.roughness_factor, "emissiveFactor": list(m.emissive_factor),
            "textures": textures}


def material_groups(materials: list[dict], mesh_materials: list[int]) -> list[int]:
    """Per mesh, the first material equal in content to its own (everything but the name, as
    the import step describes it: factors, modes, textures by image and UV set): meshes whose
    materials are equal in content may be merged for LOD (gltfpack does the same; CAD exports
    repeat materials: 2CylinderEngine's 34 are 7). A mesh without a valid material keeps its own
    index."""
    import json

    first: dict[str, int] = {}
    canon = [first.setdefault(json.dumps({k: v for k, v in m.items() if k != "name"}, sort_keys=True), i)
             for i, m in enumerate(materials)]
    return [canon[m] if 0 <= m < len(canon) else m for m in mesh_materials]


def _wasm_cache_in(store: Store) -> None:
    """The WASM simplifier's compiled module is kept in the build cache (``wasmtime/`` beside
    ``objects/``), like everything else the build writes besides its outputs: nothing lands in
    ``~/.cache``."""
    from assetpipe.pipelines import meshopt_wasm

    meshopt_wasm.use_compile_cache(store.root / "wasmtime")


def task_lod(store_root: str, mesh_digest: str, layout: list[str], lod_options: dict | None,
             double_sided: list[bool] | None = None, threads: int | None = None,
             groups: list[int] | None = None) -> dict:
    """LOD chains of a model (pipelines/lod_model.py): meshes sharing a material (``groups[i]``:
    mesh i's material group, :func:`material_groups`; None: its material) and format merged,
    duplicate triangles dropped, affine copies simplified once, vertices reordered so
    that coarser levels use a prefix. ``double_sided[i]``: mesh i's material is double-sided.
    ``threads``: at most this many of the model's meshes measured at once (the build's ``-j``;
    None: ``LOD_THREADS``); the result does not depend on it."""
    from assetpipe.pipelines.lod import LodOptions
    from assetpipe.pipelines.lod_model import LodPart, build_model_lods
    from assetpipe.pipelines.mesh_process import ATTRIBUTE_COMPONENTS

    store = Store(Path(store_root))
    _wasm_cache_in(store)
    data = store.get_blob(mesh_digest)
    if data is None:
        raise FileNotFoundError(mesh_digest)
    meta, arrays = unpack(data)
    opts = options_from_json(LodOptions, lod_options)
    cols, c = {}, 0
    for name in layout:
        cols[name] = slice(c, c + ATTRIBUTE_COMPONENTS[name])
        c += ATTRIBUTE_COMPONENTS[name]
    out_arrays, out_meta = {}, []
    if opts is None:
        for i, m in enumerate(meta["meshes"]):
            verts, idx = arrays[f"{i}.vertices"], arrays[f"{i}.indices"]
            out_arrays[f"{i}.vertices"] = verts
            out_arrays[f"{i}.lod0"] = idx
            out_meta.append({**m, "lods": [{"error": None, "switchDistance": 0.0,
                                            "vertexCount": int(verts.shape[0])}]})
    else:
        parts = []
        for i, m in enumerate(meta["meshes"]):
            verts, idx = arrays[f"{i}.vertices"], arrays[f"{i}.indices"]
            uv = verts[:, cols["uv0"]] if "uv0" in cols and m.get("hasUv") else None
            normals = verts[:, cols["normal"]] if "normal" in cols else None
            # every other written attribute, so welding for simplification never merges
            # vertices that differ in something the simplifier does not weigh
            others = tuple(verts[:, cols[a]] for a in layout if a not in ("position", "normal")
                           and not (a == "uv0" and uv is not None))
            exact = tuple(verts[:, cols[a]] for a in layout
                          if a not in ("position", "normal", "tangent"))
            parts.append(LodPart(vertices=verts, positions=verts[:, :3], indices=idx, uv=uv,
                                 normals=normals, others=others, exact=exact,
                                 group_key=(groups[i] if groups is not None else m["material"],
                                            bool(m.get("hasUv"))),
                                 double_sided=bool(double_sided[i]) if double_sided else False))
        for j, lm in enumerate(build_model_lods(parts, opts, threads=threads)):
            ms = [meta["meshes"][i] for i in lm.parts]
            out_arrays[f"{j}.vertices"] = lm.vertices
            levels_meta = []
            for k, (lv, count) in enumerate(zip(lm.levels, lm.vertex_counts)):
                out_arrays[f"{j}.lod{k}"] = lv.indices
                levels_meta.append({"error": lv.error_json() if k else None, "sloppy": lv.sloppy,
                                    "switchDistance": lv.switch_distance, "vertexCount": count})
                if lm.vertex_starts and lm.vertex_starts[k]:  # its own (moved) vertex rows
                    levels_meta[-1]["vertexStart"] = lm.vertex_starts[k]
            first = ms[0]
            entry = {**first, "degenerate": sum(x["degenerate"] for x in ms),
                     "welded": sum(x["welded"] for x in ms),
                     "warnings": [w for x in ms for w in x["warnings"]], "lods": levels_meta}
            if len(ms) > 1:
                entry["parts"] = [x["name"] for x in ms]
            if lm.duplicates:
                entry["duplicateTriangles"] = lm.duplicates
            out_meta.append(entry)
    blob = store.put_blob(pack_chunks({"meshes": out_meta}, out_arrays))
    return {"blobs": {"lod": blob},
            "meta": {"switchDistances": [[lv["switchDistance"] for lv in m["lods"]] for m in out_meta]}}


def task_lod_handmade(store_root: str, mesh_digests: list[str], lod_options: dict | None) -> dict:
    """A hand-made LOD list: level k of mesh i is mesh i of the k-th file. Levels keep their own
    vertices (appended after LOD0's in one vertex range per mesh); the error of every level is
    measured against LOD0 like generated levels."""
    from assetpipe.pipelines.lod import LodOptions
    from assetpipe.pipelines.surface_error import measure_error

    store = Store(Path(store_root))
    _wasm_cache_in(store)
    opts = options_from_json(LodOptions, lod_options) or LodOptions()
    levels = []
    for d in mesh_digests:
        data = store.get_blob(d)
        if data is None:
            raise FileNotFoundError(d)
        levels.append(unpack(data))
    ppu = opts.pixels_per_unit_at_unit_distance()
    out_arrays, out_meta = {}, []
    for i, m in enumerate(levels[0][0]["meshes"]):
        verts0, idx0 = levels[0][1][f"{i}.vertices"], levels[0][1][f"{i}.indices"]
        all_verts, levels_meta, running = [verts0], [], 0.0
        out_arrays[f"{i}.lod0"] = idx0
        levels_meta.append({"error": None, "switchDistance": 0.0, "vertexCount": int(verts0.shape[0])})
        offset = verts0.shape[0]
        for k, (meta_k, arrays_k) in enumerate(levels[1:], start=1):
            vk, ik = arrays_k[f"{i}.vertices"], arrays_k[f"{i}.indices"]
            e = measure_error(verts0[:, :3], idx0, vk[:, :3], ik, samples=opts.bound_samples_for(idx0.shape[0]),
                              seed=opts.error_seed)
            running = max(running, e.hausdorff)
            out_arrays[f"{i}.lod{k}"] = (ik.astype(np.int64) + offset).astype(np.uint32)
            offset += vk.shape[0]
            all_verts.append(vk)
            levels_meta.append({"error": {"simplifier": None, "hausdorff": e.hausdorff, "rms": e.rms,
                                          "hausdorffRel": e.hausdorff_rel, "rmsRel": e.rms_rel,
                                          "hausdorffLowerRel": e.hausdorff_lower_rel, "boundConverged": e.converged},
                                "switchDistance": running * ppu, "vertexCount": int(offset), "handmade": True})
        out_arrays[f"{i}.vertices"] = np.vstack(all_verts)
        out_meta.append({**m, "lods": levels_meta})
    blob = store.put_blob(pack_chunks({"meshes": out_meta}, out_arrays))
    return {"blobs": {"lod": blob},
            "meta": {"switchDistances": [[lv["switchDistance"] for lv in m["lods"]] for m in out_meta]}}


# -- textures -------------------------------------------------------------------------------

#: libraries no texture step uses: their versions stay out of its key (installing or removing
#: meshoptimizer's WASM simplifier, which only the LOD step runs, rebuilt every texture)
NOT_TEXTURE_LIBS = ("meshoptimizer-wasm",)


def texture_key_libs(libs: dict, tex_opts: dict | None) -> dict:
    """The library versions a texture step's key holds: ``libs`` but :data:`NOT_TEXTURE_LIBS`,
    plus for ETC2 the etcpak build that encodes it (``avx512``/``avx2``/``sse41``/``none``):
    those builds write different (equally valid) blocks, so a cache shared by machines with
    different CPUs must not mix them. BC and RGBA8 output does not depend on the CPU (etcpak's
    own module, numpy, OpenCV)."""
    libs = {k: v for k, v in libs.items() if k not in NOT_TEXTURE_LIBS}
    if (tex_opts or {}).get("compression") != "etc2":
        return libs
    from assetpipe.pipelines.texture_compress import etcpak_variant  # noqa: PLC0415

    return {**libs, "etcpak-build": etcpak_variant()}


def _read_image(store, image: dict, model_dir: str):
    """The ImageSource of a texture step's ``image`` (read from the model's folder, or the
    store for an embedded one)."""
    from assetpipe.core.errors import MissingFileError
    from assetpipe.core.hashing import digest_bytes
    from assetpipe.pipelines.model import ImageSource

    if image["path"] is not None:
        path = Path(model_dir) / image["path"]
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise MissingFileError(path, "image disappeared during the build") from None
    else:
        data = store.get_blob(image["digest"])
        if data is None:
            raise FileNotFoundError(image["digest"])
    return ImageSource(name=image["name"], data=data, mime=image["mime"], origin=image["path"] or image["name"],
                       digest=digest_bytes(data))


def _texture_result(store, src, pt, stored: dict | None = None) -> dict:
    """A texture use's record. ``stored``: id of bytes -> (bytes, digest) of the blobs this task
    put already: uses that share a chain (or level 0's source bytes) share the same bytes
    objects, which ``put_blob`` would hash again and, finding them stored, read back and hash a
    third time (22 MB for a 2048^2 chain)."""
    def put(data: bytes) -> str:
        if stored is None:
            return store.put_blob(data)
        if id(data) not in stored:
            stored[id(data)] = (data, store.put_blob(data))  # the bytes kept: their id stays theirs
        return stored[id(data)][1]

    blobs = {"ktx2": put(pt.ktx2), "level0": put(pt.level0)}
    meta = {"width": pt.width, "height": pt.height, "levels": pt.levels, "vkFormat": pt.vk_format,
            "colorSpace": pt.color_space, "level0Ext": pt.level0_ext, "level0Shared": pt.level0_shared,
            "hasAlphaBelow255": pt.has_alpha_below_255, "meanDrift": list(pt.mean_drift),
            "coverage": list(pt.coverage) if pt.coverage is not None else None,
            "sourceDigest": src.digest, "sourceWidth": pt.source_width, "sourceHeight": pt.source_height}
    if pt.warnings:  # levels dropped for max_size (#13)
        meta["warnings"] = list(pt.warnings)
    return {"blobs": blobs, "meta": meta}


def task_texture(store_root: str, image: dict, model_dir: str, role: str, alpha_mode: str,
                 alpha_cutoff: float, texture_options: dict) -> dict:
    """One use of an image: ``{"blobs": {"ktx2", "level0"}, "meta": {...}}``."""
    from assetpipe.pipelines.texture_options import TextureOptions
    from assetpipe.pipelines.texture_process import process_texture

    store = Store(Path(store_root))
    src = _read_image(store, image, model_dir)
    pt = process_texture(src, role, alpha_mode, alpha_cutoff, options_from_json(TextureOptions, texture_options))
    return _texture_result(store, src, pt)


def task_texture_uses(store_root: str, image: dict, model_dir: str, uses: list, texture_options: dict) -> dict:
    """Every use ``(role, alphaMode, alphaCutoff)`` a model makes of one image, the image read
    and decoded once (:func:`pipelines.texture_process.process_texture_uses`): ``{"blobs":
    {"ktx2.I", "level0.I"}, "meta": {"uses": [meta of use I, ...]}}``, each use's blobs and meta
    as :func:`task_texture` gives them (:func:`texture_use_record` takes one out)."""
    from assetpipe.pipelines.texture_options import TextureOptions
    from assetpipe.pipelines.texture_process import process_texture_uses

    store = Store(Path(store_root))
    src = _read_image(store, image, model_dir)
    results = process_texture_uses(src, [tuple(u) for u in uses], options_from_json(TextureOptions, texture_options))
    blobs, metas, stored = {}, [], {}
    for i, pt in enumerate(results):
        one = _texture_result(store, src, pt, stored)
        blobs.update({f"{k}.{i}": v for k, v in one["blobs"].items()})
        metas.append(one["meta"])
    return {"blobs": blobs, "meta": {"uses": metas}}


def texture_use_record(record: dict, i: int) -> dict:
    """Use ``i``'s record (as :func:`task_texture` makes it) out of a :func:`task_texture_uses` one."""
    return {"blobs": {k: record["blobs"][f"{k}.{i}"] for k in ("ktx2", "level0")}, "meta": record["meta"]["uses"][i]}


# -- encode ---------------------------------------------------------------------------------

def _kept_rows(vertices: np.ndarray, lods: tuple) -> tuple[np.ndarray, tuple]:
    """The rows a scene's kept levels use (LOD0 dropped): the prefix the kept levels over
    LOD0's vertices use, then each kept moved level's own rows, moved down to follow it (its
    indices, ``vertex_start`` and ``vertex_count`` shifted alike). ``lods``: ``OutputLod``s."""
    import dataclasses

    head = max((lod.vertex_count for lod in lods if not lod.vertex_start), default=0)
    rows, out, end = [vertices[:head]], [], head
    for lod in lods:
        if lod.vertex_start:
            n = lod.vertex_count - lod.vertex_start
            rows.append(vertices[lod.vertex_start:lod.vertex_count])
            shift = lod.vertex_start - end
            lod = dataclasses.replace(lod, indices=(lod.indices.astype(np.int64) - shift).astype(np.uint32),
                                      vertex_start=end, vertex_count=end + n)
            end += n
        out.append(lod)
    return np.concatenate(rows), tuple(out)


def task_encode(store_root: str, model_id: str, lod_digest: str, layout: list[str],
                materials: list[dict], sources: list[dict], warnings: list[str],
                keep: list[list[int]] | None = None, position_offset: list[float] | None = None) -> dict:
    """Encode the output files of one model; each file becomes a blob. ``position_offset``:
    a recentred model's offset (the sidecar's ``positionOffset``).

    ``keep[i]``: the levels of mesh i's chain to write (contiguous; its first becomes the
    output LOD0, with the vertex prefix it uses); None keeps every level."""
    from assetpipe.format import OutputLod, OutputMaterial, OutputMesh, encode_model
    from assetpipe.pipelines.mesh_process import ATTRIBUTE_COMPONENTS

    store = Store(Path(store_root))
    data = store.get_blob(lod_digest)
    if data is None:
        raise FileNotFoundError(lod_digest)
    meta, arrays = unpack(data)
    warnings = list(warnings)
    n_mats = len(materials)
    meshes = []
    degenerate = welded = duplicates = 0
    for i, m in enumerate(meta["meshes"]):
        warnings.extend(m["warnings"])
        degenerate += m["degenerate"]
        duplicates += m.get("duplicates", 0)
        welded += m["welded"]
        kept = keep[i] if keep is not None else list(range(len(m["lods"])))
        lods = tuple(OutputLod(indices=arrays[f"{i}.lod{k}"], vertex_count=m["lods"][k]["vertexCount"],
                               error=m["lods"][k]["error"] or {}, switch_distance=m["lods"][k]["switchDistance"],
                               chain_level=k, vertex_start=int(m["lods"][k].get("vertexStart", 0)))
                     for k in kept)
        vertices = arrays[f"{i}.vertices"]
        if kept and kept[0] > 0 and not m["lods"][kept[0]].get("handmade"):
            vertices, lods = _kept_rows(vertices, lods)
        if lods[0].indices.shape[0] == 0:
            warnings.append(f"{m['name']}: no triangles left after dropping degenerate ones; mesh skipped")
            continue
        mat = m["material"] if 0 <= m["material"] < n_mats else n_mats - 1
        meshes.append(OutputMesh(id=m["name"], name=m["name"], material_id=f"{model_id}-mat-{mat}",
                                 vertices=vertices, lods=lods))
    if not meshes:
        warnings.append("the model has no triangle geometry: its outputs hold no meshes")
    out_mats = [OutputMaterial(id=f"{model_id}-mat-{i}", name=m["name"], color=tuple(m["baseColorFactor"]),
                               texture_path=m["texturePath"], alpha_mode=m["alphaMode"],
                               alpha_cutoff=m["alphaCutoff"], double_sided=m["doubleSided"],
                               transparent=m["transparent"], textures=m["textures"])
                for i, m in enumerate(materials)]
    stats = {"meshes": len(meshes), "triangles": int(sum(x.lods[0].indices.shape[0] for x in meshes)),
             "vertices": int(sum(x.vertices.shape[0] for x in meshes)),
             "degenerateTriangles": degenerate, "duplicateTriangles": duplicates, "weldedVertices": welded,
             "lodLevels": max((len(x.lods) for x in meshes), default=0)}
    files = encode_model(model_id, meshes, out_mats, tuple(layout), ATTRIBUTE_COMPONENTS, stats=stats,
                         warnings=list(dict.fromkeys(warnings)), sources=sources,
                         generator=f"assetpipe {__version__}",
                         extra={"positionOffset": list(position_offset)} if position_offset is not None else None)
    return {"blobs": {name: store.put_blob(b) for name, b in files.items()},
            "meta": {"stats": stats, "warnings": list(dict.fromkeys(warnings))}}
