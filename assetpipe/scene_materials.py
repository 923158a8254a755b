"""Scene materials: the vertex attributes a model's materials use (:func:`attributes_needed`) and
whether the files of a hand-made LOD list share their materials (:func:`check_shared_materials`).
"""

from __future__ import annotations

from typing import Mapping, Sequence

from assetpipe.pipelines.mesh_options import SEED_LAYOUT
from assetpipe.scene_load import _show
from assetpipe.scene_plan import _levels


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
