"""Mutations: break a built model the ways a pipeline breaks assets, for the validator's catch rate.

Each mutation edits a *copy* of a built output folder in place and names what it breaks;
:data:`MUTATIONS` maps a kind to (function, the checks expected to catch it, a phrase the
failure message must contain). A mutation that does not apply to a model (no normal map, one
LOD...) raises :class:`NotApplicable`.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Callable

import numpy as np

from assetpipe.core.ktx2 import read_ktx2, write_ktx2


class NotApplicable(Exception):
    pass


def _json(p: Path) -> dict:
    return json.loads(p.read_text())


def _files(model_json: Path):
    stem = model_json.name[: -len(".json")]
    return (model_json, model_json.with_name(stem + ".asset.json"), model_json.with_name(stem + "-mat.json"))


def _vertices(model_json: Path):
    seed, side, _ = map(_json, _files(model_json))
    vtx = model_json.parent / seed["vtxFilename"]
    raw = np.fromfile(vtx, np.uint8)
    stride = side["vertexLayout"]["stride"]
    return vtx, raw.reshape(-1, stride), {a["name"]: a for a in side["vertexLayout"]["attributes"]}


def _texture(model_json: Path, role: str) -> tuple[dict, dict]:
    _, side_p, _ = _files(model_json)
    side = _json(side_p)
    for mat in side["materials"]:
        tex = (mat.get("textures") or {}).get(role)
        if tex and tex.get("ktx2"):
            return side, tex
    raise NotApplicable(f"no {role} texture")


def _rewrite_ktx2(model_json: Path, role: str, edit: Callable[[list[np.ndarray], int], tuple[list[np.ndarray], int]]):
    _, tex = _texture(model_json, role)
    path = model_json.parent / tex["ktx2"]
    img = read_ktx2(path.read_bytes())
    levels, fmt = edit([np.array(lv) for lv in img.levels], int(img.vk_format))
    path.write_bytes(write_ktx2(levels, fmt))


# -------------------------------------------------------------------------------- mutations
def index_out_of_range(m: Path) -> None:
    seed = _json(m)
    idx = m.parent / seed["idxFilename"]
    a = np.fromfile(idx, "<u4")
    a[len(a) // 2] = 1_000_000
    a.tofile(idx)


def nan_vertex(m: Path) -> None:
    vtx, rows, attrs = _vertices(m)
    off = attrs["position"]["offset"]
    rows[len(rows) // 2, off:off + 4] = np.frombuffer(np.float32(np.nan).tobytes(), np.uint8)
    rows.tofile(vtx)


def inf_vertex(m: Path) -> None:
    vtx, rows, attrs = _vertices(m)
    off = attrs["position"]["offset"] + 4
    rows[0, off:off + 4] = np.frombuffer(np.float32(np.inf).tobytes(), np.uint8)
    rows.tofile(vtx)


def _textured(m: Path) -> bool:
    side = _json(_files(m)[1])
    return any((mat.get("textures") or {}).get("baseColor") for mat in side["materials"])


def flipped_v(m: Path) -> None:
    vtx, rows, attrs = _vertices(m)
    if "uv0" not in attrs or attrs["uv0"]["format"] != "float32x2":
        raise NotApplicable("no float uv0")
    if not _textured(m):
        raise NotApplicable("no texture: UVs are not drawn")
    off = attrs["uv0"]["offset"] + 4
    v = rows[:, off:off + 4].copy().view("<f4")
    rows[:, off:off + 4] = (1.0 - v).astype("<f4").view(np.uint8)
    rows.tofile(vtx)


def swapped_textures(m: Path) -> None:
    """The base colour's and the emissive's KTX2 files swapped (both sRGB, same size)."""
    _, a = _texture(m, "baseColor")
    _, b = _texture(m, "emissive")
    pa, pb = m.parent / a["ktx2"], m.parent / b["ktx2"]
    ra = read_ktx2(pa.read_bytes())
    rb = read_ktx2(pb.read_bytes())
    pa.write_bytes(write_ktx2([np.asarray(lv) for lv in rb.levels], int(rb.vk_format)))
    pb.write_bytes(write_ktx2([np.asarray(lv) for lv in ra.levels], int(ra.vk_format)))


def wrong_texture(m: Path) -> None:
    """Consistently wrong: the sidecar's normal map entry names the occlusion texture's files."""
    side_p = _files(m)[1]
    side = _json(side_p)
    for mat in side["materials"]:
        t = mat.get("textures") or {}
        if "normal" in t and "occlusion" in t:
            for k in ("path", "ktx2", "width", "height", "levels"):
                t["normal"][k] = t["occlusion"][k]
            side_p.write_text(json.dumps(side))
            return
    raise NotApplicable("no normal + occlusion")


def _wrong_in_role(role: str) -> Callable[[Path], None]:
    """Consistently wrong in ``role``: its texture replaced by another image (the same one turned
    180 degrees), the KTX2 chain and the level-0 image alike, so the files agree with each other
    and only a comparison with the source can tell."""

    def mutate(m: Path) -> None:
        import cv2  # noqa: PLC0415

        _, tex = _texture(m, role)
        path = m.parent / tex["ktx2"]
        img = read_ktx2(path.read_bytes())
        if img.block_format is not None:
            raise NotApplicable("block-compressed texture")
        levels = [np.ascontiguousarray(np.asarray(lv)[::-1, ::-1]) for lv in img.levels]
        if all(np.array_equal(a, b) for a, b in zip(levels, img.levels)):
            raise NotApplicable(f"the {role} texture looks the same turned 180 degrees")
        path.write_bytes(write_ktx2(levels, int(img.vk_format)))
        if tex.get("path"):
            png = m.parent / tex["path"]
            data = cv2.imdecode(np.fromfile(png, np.uint8), cv2.IMREAD_UNCHANGED)
            ok, enc = cv2.imencode(".png", np.ascontiguousarray(data[::-1, ::-1]))
            assert ok
            png.with_suffix(".png").write_bytes(enc.tobytes())
            if png.suffix.lower() != ".png":  # keep the sidecar's name pointing at the new bytes
                side_p = _files(m)[1]
                side = _json(side_p)
                for mat in side["materials"]:
                    t = (mat.get("textures") or {}).get(role)
                    if t and t.get("path") == tex["path"]:
                        t["path"] = str(Path(tex["path"]).with_suffix(".png"))
                side_p.write_text(json.dumps(side))

    return mutate


def wrong_emissive(m: Path) -> None:
    """Consistently wrong emissive: the sidecar's emissive entry names the base colour's files
    (both sRGB). (Turning a mostly-black emissive map 180 degrees moves a few bright texels,
    which a 64 px comparison of means cannot see, nor would a viewer: not used here.)"""
    side_p = _files(m)[1]
    side = _json(side_p)
    for mat in side["materials"]:
        t = mat.get("textures") or {}
        if "emissive" in t and "baseColor" in t and t["emissive"].get("ktx2") != t["baseColor"].get("ktx2"):
            for k in ("path", "ktx2", "width", "height", "levels", "vkFormat"):
                if k in t["baseColor"]:
                    t["emissive"][k] = t["baseColor"][k]
            side_p.write_text(json.dumps(side))
            return
    raise NotApplicable("no separate emissive and base colour textures")


def srgb_linear_swapped(m: Path) -> None:
    """The base colour stored (and declared) as UNORM: sRGB data read as linear."""
    side, tex = _texture(m, "baseColor")
    _rewrite_ktx2(m, "baseColor", lambda lv, fmt: (lv, 37))
    tex["vkFormat"] = 37
    tex["colorSpace"] = "linear"
    _files(m)[1].write_text(json.dumps(side))


def normal_channels_swapped(m: Path) -> None:
    _rewrite_ktx2(m, "normal", lambda lv, fmt: ([x[..., [1, 0, 2, 3]].copy() for x in lv], fmt))


def normal_xz_swapped(m: Path) -> None:
    _rewrite_ktx2(m, "normal", lambda lv, fmt: ([x[..., [2, 1, 0, 3]].copy() for x in lv], fmt))


def normal_not_renormalised(m: Path) -> None:
    """Mips box-filtered as plain data (vectors averaged, never renormalised)."""
    def edit(levels, fmt):
        out = [levels[0]]
        v = levels[0].astype(np.float64)
        while len(out) < len(levels):
            h, w = max(v.shape[0] // 2, 1), max(v.shape[1] // 2, 1)
            v = v[: h * 2, : w * 2].reshape(h, 2, w, 2, 4).mean(axis=(1, 3)) if v.shape[0] > 1 else v
            out.append(np.rint(v).astype(np.uint8))
        return out, fmt
    _rewrite_ktx2(m, "normal", edit)


def missing_mip_level(m: Path) -> None:
    _rewrite_ktx2(m, "baseColor", lambda lv, fmt: (lv[:-1], fmt))


def truncated_mip(m: Path) -> None:
    _, tex = _texture(m, "baseColor")
    p = m.parent / tex["ktx2"]
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - max(len(data) // 10, 8)])


def black_mip_level(m: Path) -> None:
    _rewrite_ktx2(m, "baseColor", lambda lv, fmt: (lv[:2] + [np.zeros_like(lv[2])] + lv[3:], fmt))


def wrong_winding(m: Path) -> None:
    if all(mat.get("doubleSided") for mat in _json(_files(m)[1])["materials"]):
        raise NotApplicable("every material is double-sided: winding does not show")
    seed = _json(m)
    idx = m.parent / seed["idxFilename"]
    a = np.fromfile(idx, "<u4").reshape(-1, 3)
    a[:, [1, 2]] = a[:, [2, 1]]
    a.tofile(idx)


def lod_hole(m: Path) -> None:
    """A tenth of LOD1's triangles (a contiguous run) collapsed to a point."""
    side = _json(_files(m)[1])
    seed = _json(m)
    idx = m.parent / seed["idxFilename"]
    a = np.fromfile(idx, "<u4")
    for mesh in side["meshes"]:
        if len(mesh.get("lods", [])) > 1:
            lod = mesh["lods"][1]
            first, count = lod["idxOffset"] // 4, lod["idxSize"] // 4
            tris = count // 3
            k0 = tris // 3
            k = max(tris // 10, 1)
            a[first + 3 * k0: first + 3 * (k0 + k)] = a[first + 3 * k0]
            a.tofile(idx)
            return
    raise NotApplicable("single LOD")


def bounds_too_small(m: Path) -> None:
    side_p = _files(m)[1]
    side = _json(side_p)
    b = side["bounds"]
    c = np.asarray(b["center"])
    b["max"] = list(c + (np.asarray(b["max"]) - c) * 0.8)
    b["radius"] = b["radius"] * 0.8
    side_p.write_text(json.dumps(side))


def shrunk(m: Path) -> None:
    """Every vertex moved a tenth of the way to the centre of the positions' box: inside the
    sidecar's bounds, every file consistent; only the pictures show it."""
    vtx, rows, attrs = _vertices(m)
    off = attrs["position"]["offset"]
    pos = rows[:, off:off + 12].copy().view("<f4").reshape(-1, 3)
    centre = (pos.max(axis=0) + pos.min(axis=0)) / 2
    rows[:, off:off + 12] = (centre + (pos - centre) * 0.9).astype("<f4").view(np.uint8).reshape(-1, 12)
    rows.tofile(vtx)


def material_id_nowhere(m: Path) -> None:
    seed = _json(m)
    seed["meshes"][0]["materialId"] = "no-such-material"
    m.write_text(json.dumps(seed))


# kind: (mutation, checks that must catch it, a phrase its message contains)
MUTATIONS: dict[str, tuple[Callable[[Path], None], tuple[str, ...], str]] = {
    "index out of range": (index_out_of_range, ("load",), "out of range"),
    "NaN vertex": (nan_vertex, ("load",), "non-finite"),
    "Inf vertex": (inf_vertex, ("load",), "non-finite"),
    "flipped V": (flipped_v, ("source", "uvs"), "shaded colours differ|flipped or shifted UVs"),
    "swapped textures": (swapped_textures, ("textures", "roles", "source"), "differs|shaded colours differ"),
    "wrong texture (consistent)": (wrong_texture, ("roles", "source"),
                                   "differs from the source's normal image|shaded colours differ"),
    "wrong normal map (consistent)": (_wrong_in_role("normal"), ("roles", "source"),
                                      "differs from the source's normal|shaded colours differ"),
    "wrong metallic-roughness (consistent)": (_wrong_in_role("metallicRoughness"), ("roles", "source"),
                                              "differs from the source's metallicRoughness|shaded colours differ"),
    "wrong occlusion (consistent)": (_wrong_in_role("occlusion"), ("roles", "source"),
                                     "differs from the source's occlusion|shaded colours differ"),
    "wrong emissive (consistent)": (wrong_emissive, ("roles", "source"),
                                    "differs from the source's emissive|shaded colours differ"),
    "sRGB and linear swapped": (srgb_linear_swapped, ("textures",), "sRGB and linear swapped"),
    "normal channels swapped (x/y)": (normal_channels_swapped, ("textures",), "swapped texture or channels"),
    "normal channels swapped (x/z)": (normal_xz_swapped, ("textures",), "mean z"),
    "normal map not renormalised": (normal_not_renormalised, ("textures",), "not renormalised"),
    "missing mip level": (missing_mip_level, ("textures",), "missing levels"),
    "truncated mip level": (truncated_mip, ("textures", "load"), "KTX"),
    "black mip level": (black_mip_level, ("textures",), "all black"),
    "wrong winding": (wrong_winding, ("source", "lods"), "flipped winding|LOD0 covers no pixel|only back faces"),
    "LOD level with a hole": (lod_hole, ("lods",), "differ from LOD0|a hole?"),
    "bounds do not contain the vertices": (bounds_too_small, ("bounds",), "outside the sidecar bounds"),
    "material id points nowhere": (material_id_nowhere, ("load",), "materialId"),
    "shrunk by a tenth": (shrunk, ("source",), "of the silhouette differs from the source"),
}


def caught_by(result, checks: tuple[str, ...], phrase: str) -> list[str]:
    """The checks among ``checks`` that failed ``result`` with ``phrase`` in a message."""
    phrases = phrase.split("|")
    return [c.name for c in result.checks
            if c.name in checks and c.status == "fail" and any(p in msg for msg in c.messages for p in phrases)]


def caught(result, checks: tuple[str, ...], phrase: str) -> tuple[bool, str]:
    """(caught by one of ``checks`` with ``phrase`` in a message, the failure lines)."""
    lines = result.failures()
    phrases = phrase.split("|")
    ok = any(c.name in checks and c.status == "fail" and any(p in msg for msg in c.messages for p in phrases)
             for c in result.checks)
    return ok, " | ".join(lines)[:400]
