"""Building one model: import -> mesh processing -> LODs -> textures -> encoded files.

``build_model(source, model_id, options) -> ModelOutput`` reads the source (through the
importers) and returns every output file's bytes; it writes nothing. The orchestration in
:mod:`assetpipe.build` caches, writes and reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from assetpipe import __version__
from assetpipe.errors import AssetError
from assetpipe.format import OutputLod, OutputMaterial, OutputMesh, encode_model
from assetpipe.hashing import digest_bytes, digest_file
from pipelines.mesh_process import ATTRIBUTE_COMPONENTS, DEFAULT_MESH_OPTIONS, MeshOptions, process_mesh
from pipelines.model import DEFAULT_MATERIAL, ImportedModel, Material, SRGB_ROLES

TEXTURE_DIR = "textures"


@dataclass(frozen=True)
class BuildOptions:
    mesh: MeshOptions = DEFAULT_MESH_OPTIONS


DEFAULT_BUILD_OPTIONS = BuildOptions()


@dataclass(frozen=True, eq=False)
class ModelOutput:
    """Every file of one built model: ``files`` (model files by name), ``textures`` (by path
    relative to OUT, shared between models), plus warnings and statistics for the report."""

    files: dict[str, bytes]
    textures: dict[str, bytes]
    warnings: tuple[str, ...]
    stats: dict = field(default_factory=dict)


def import_model(source: Path) -> ImportedModel:
    suffix = source.suffix.lower()
    if suffix in (".gltf", ".glb"):
        from pipelines.import_gltf import import_gltf
        return import_gltf(source)
    if suffix == ".obj":
        from pipelines.import_obj import import_obj
        return import_obj(source)
    raise AssetError(source, f"unsupported file type {suffix!r}")


def build_model(source: Path, model_id: str, options: BuildOptions = DEFAULT_BUILD_OPTIONS) -> ModelOutput:
    model = import_model(source)
    warnings = list(model.warnings)
    n_mats = len(model.materials)

    # a default material is appended only when some mesh has none
    needs_default = any(m.material < 0 or m.material >= n_mats for m in model.meshes)
    materials = list(model.materials) + ([DEFAULT_MATERIAL] if needs_default else [])

    out_meshes: list[OutputMesh] = []
    degenerate = welded = 0
    for mesh in model.meshes:
        mat_index = mesh.material if 0 <= mesh.material < n_mats else n_mats
        pm = process_mesh(mesh, materials[mat_index], options.mesh)
        warnings.extend(pm.warnings)
        degenerate += pm.degenerate_dropped
        welded += pm.welded
        if pm.indices.shape[0] == 0:
            warnings.append(f"{mesh.name}: no triangles left after dropping degenerate ones; mesh skipped")
            continue
        lod0 = OutputLod(indices=pm.indices, vertex_count=pm.vertices.shape[0])
        out_meshes.append(OutputMesh(id=mesh.name, name=mesh.name, material_id=f"{model_id}-mat-{mat_index}",
                                     vertices=pm.vertices, lods=(lod0,)))
    if not out_meshes:
        warnings.append("the model has no triangle geometry: its outputs hold no meshes")

    out_materials, textures = material_outputs(model_id, materials, warnings)
    sources = [{"path": source.name, "digest": digest_file(source)}]
    base = source.parent
    for dep in model.dependencies:
        try:
            rel = str(Path(dep).resolve().relative_to(base.resolve()))
        except ValueError:
            rel = str(dep)
        sources.append({"path": rel, "digest": digest_file(dep)})
    stats = {"degenerateTriangles": degenerate, "weldedVertices": welded,
             "meshes": len(out_meshes), "triangles": int(sum(m.lods[0].indices.shape[0] for m in out_meshes)),
             "vertices": int(sum(m.vertices.shape[0] for m in out_meshes))}
    files = encode_model(model_id, out_meshes, out_materials, options.mesh.layout, ATTRIBUTE_COMPONENTS,
                         stats=stats, warnings=warnings, sources=sources,
                         generator=f"assetpipe {__version__}")
    return ModelOutput(files=files, textures=textures, warnings=tuple(warnings), stats=stats)


def _texture_name(data: bytes, ext: str) -> str:
    return f"{TEXTURE_DIR}/{digest_bytes(data).split(':', 1)[1][:20]}{ext}"


def material_outputs(model_id: str, materials: list[Material], warnings: list[str]):
    """(OutputMaterial list, texture files by relative path) for a model's materials."""
    textures: dict[str, bytes] = {}
    out = []
    for i, mat in enumerate(materials):
        tex_json: dict = {}
        texture_path = ""
        transparent = mat.alpha_mode == "BLEND"
        for role, ref in mat.textures().items():
            from pipelines.texture_process import DEFAULT_TEXTURE_OPTIONS, process_texture

            try:
                pt = process_texture(ref.image, role, mat.alpha_mode, mat.alpha_cutoff, DEFAULT_TEXTURE_OPTIONS)
            except AssetError as exc:
                warnings.append(f"material {i} ({mat.name}): {role} texture {ref.image.name!r} skipped: {exc.problem}")
                continue
            png_path = _texture_name(pt.level0, pt.level0_ext)
            ktx_path = _texture_name(pt.ktx2, ".ktx2")
            textures[png_path] = pt.level0
            textures[ktx_path] = pt.ktx2
            tex_json[role] = {"path": png_path, "ktx2": ktx_path, "width": pt.width, "height": pt.height,
                              "levels": pt.levels, "colorSpace": "srgb" if role in SRGB_ROLES else "linear",
                              "vkFormat": pt.vk_format, "texCoord": ref.tex_coord, "sampler": ref.sampler.to_json(),
                              "source": ref.image.name}
            if role == "baseColor":
                texture_path = png_path
                transparent = transparent or pt.has_alpha_below_255
        out.append(OutputMaterial(
            id=f"{model_id}-mat-{i}", name=mat.name, color=tuple(mat.base_color_factor),
            texture_path=texture_path, alpha_mode=mat.alpha_mode, alpha_cutoff=mat.alpha_cutoff,
            double_sided=mat.double_sided, transparent=bool(transparent), textures=tex_json))
    return out, textures
