"""``roles``: the texture built in each material role is the source's image for that role.

An independent reading of the source glTF JSON (no importer of ours): material N's
baseColor (or KHR_materials_pbrSpecularGlossiness diffuse), metallicRoughness, normal,
occlusion and emissive textures are found by index, their images decoded, area-reduced to the
size of the KTX2 mip level nearest ``ROLE_PX`` and compared with that level (already in memory:
no full-size decode of the build's textures). A wrong or swapped texture in any role shows,
including roles the shaded render does not draw.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..results import CheckResult
from .base import Check, Context
from .images import decode_rgba
from .ktx2_levels import open_ktx2
from .textures import SRGB_TO_LINEAR, VK_SRGB, linear_to_srgb_code

# The comparison level: the KTX2 level nearest 256 px (level 0 of smaller textures). Finer than
# 64 px both ways: fewer mip steps of rounding between level 0 and it (the worst good texture of
# the corpus: 0.0098 at 64 px, 0.0037 at 128, 0.0019 at 256), and subtle wrong images show (Avocado's
# normal map turned 180 degrees: 0.0166 at 64 px, 0.0188 at 256); reducing the source image costs
# the same at any size (one pass over its texels), and the KTX2 level is already in memory.
ROLE_PX = 256
ROLE_PATHS = {
    "baseColor": (("pbrMetallicRoughness", "baseColorTexture"),
                  ("extensions", "KHR_materials_pbrSpecularGlossiness", "diffuseTexture")),
    "metallicRoughness": (("pbrMetallicRoughness", "metallicRoughnessTexture"),),
    "normal": (("normalTexture",),),
    "occlusion": (("occlusionTexture",),),
    "emissive": (("emissiveTexture",),),
}


def _gltf(path: Path) -> tuple[dict[str, Any], bytes | None] | None:
    data = path.read_bytes()
    if data[:4] == b"glTF":
        length = struct.unpack_from("<I", data, 8)[0]
        off = 12
        doc, blob = None, None
        while off + 8 <= min(len(data), length):
            clen, ctype = struct.unpack_from("<II", data, off)
            chunk = data[off + 8: off + 8 + clen]
            if ctype == 0x4E4F534A:
                doc = json.loads(chunk)
            elif ctype == 0x004E4942:
                blob = bytes(chunk)
            off += 8 + clen
        return (doc, blob) if doc is not None else None
    if path.suffix.lower() == ".gltf":
        return json.loads(data), None
    return None


def _image_bytes(doc: dict[str, Any], blob: bytes | None, root: Path, tex_index: int) -> bytes | None:
    textures = doc.get("textures") or []
    if not 0 <= tex_index < len(textures):
        return None
    tex = textures[tex_index]
    src = tex.get("source")
    if src is None:
        src = next((e.get("source") for e in (tex.get("extensions") or {}).values()
                    if isinstance(e, dict) and e.get("source") is not None), None)
    images = doc.get("images") or []
    if src is None or not 0 <= src < len(images):
        return None
    img = images[src]
    uri = img.get("uri")
    if uri:
        if uri.startswith("data:"):
            return base64.b64decode(uri.split(",", 1)[1])
        from urllib.parse import unquote  # noqa: PLC0415

        p = root / unquote(uri)
        return p.read_bytes() if p.is_file() else None
    view = (doc.get("bufferViews") or [])[img.get("bufferView", -1)] if img.get("bufferView") is not None else None
    if view is None:
        return None
    buf = (doc.get("buffers") or [{}])[view.get("buffer", 0)]
    data = blob if buf.get("uri") is None else (
        base64.b64decode(buf["uri"].split(",", 1)[1]) if buf["uri"].startswith("data:")
        else (root / buf["uri"]).read_bytes())
    if data is None:
        return None
    o = int(view.get("byteOffset", 0))
    return data[o:o + int(view["byteLength"])]


# 8-bit code -> 16-bit value tables for cv2.LUT: linear (code * 257) and sRGB decoded to linear.
# Area-averaging 16-bit values rounds each mean to 1/65535 (0.004 of an 8-bit code), 1500x below
# role_tolerance; cv2 averages 16-bit images about 10x faster than float32 ones (no float copy
# of a 2048^2 image: 0.04 s instead of 0.4 s measured on Avocado's textures).
_LINEAR16 = np.tile((np.arange(256) * 257).astype(np.uint16).reshape(256, 1), (1, 3)).reshape(1, 256, 3)
_SRGB16 = np.tile(np.rint(SRGB_TO_LINEAR.astype(np.float64) * 65535).astype(np.uint16).reshape(256, 1),
                  (1, 3)).reshape(1, 256, 3)


def _reduce(rgba: np.ndarray, size: tuple[int, int], role: str, fmt: int) -> np.ndarray:
    """The source image area-averaged to ``size`` (w, h) the way the mip chain filters ``role``; RGB codes
    (float, 0..255): sRGB roles averaged in linear light, normals averaged as vectors and renormalised."""
    import cv2  # noqa: PLC0415

    rgb = cv2.cvtColor(np.ascontiguousarray(rgba), cv2.COLOR_RGBA2RGB)
    table = _SRGB16 if (role != "normal" and fmt == VK_SRGB) else _LINEAR16
    avg = cv2.resize(cv2.LUT(rgb, table), size, interpolation=cv2.INTER_AREA)
    avg = avg.reshape(size[1], size[0], 3).astype(np.float32) / np.float32(65535.0)
    if role == "normal":  # the mean of 2c/255 - 1 is 2 mean(c)/255 - 1: average codes, then map
        m = avg * 2 - 1
        m /= np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-12)
        return (m + 1) * 127.5
    if fmt == VK_SRGB:
        return linear_to_srgb_code(avg)
    return avg * 255.0


class RolesCheck(Check):
    name = "roles"
    beside = True
    measures = ("for each material texture role (baseColor, metallicRoughness, normal, occlusion, emissive): "
                "mean absolute difference (0..1 of the stored codes, RGB) between the KTX2 mip level nearest "
                f"{ROLE_PX} px and the source glTF's image for that material and role, area-reduced the same "
                "way (gamma-correct for sRGB roles, renormalised for normals); a role present in one and not "
                "the other")
    tolerance = ("role_tolerance 2/255 (0.0078); block-compressed textures 4/255 more (the encoders' error, "
                 "as texture_compressed_png_tolerance), over the channels the format stores")
    reason = ("both sides are area averages of the same texels, so they differ by rounding (at most half a code "
              "per level step, 3 steps from 2048 to 256 px) and by alpha handling (premultiplied or MASK-scaled "
              "chains weigh colour by alpha); at 256 px the worst good texture of the 38 corpus models measured "
              "0.0019 (AlphaBlendModeTest: JPEG with alpha), 2/255 leaves 4x; two different images of a material "
              "differ by 0.01 (a near-flat normal map turned around) to tens of codes")

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model = ctx.model
        assert model is not None
        src, _, why = load_source_path(ctx)
        if src is None or src.suffix.lower() not in (".gltf", ".glb"):
            r.status = "skip"
            r.messages.append(why or "the source is not glTF: texture roles not compared")
            return r.finish()
        parsed = _gltf(src)
        if parsed is None:
            r.status = "skip"
            r.messages.append("the source glTF does not parse")
            return r.finish()
        doc, blob = parsed
        src_mats = doc.get("materials") or []
        figures: dict[str, Any] = {}
        # one reduction per image, size and filter: a packed occlusion-roughness-metallic image
        # serves two roles (decode_rgba gives the same array for the same bytes)
        reduced: dict[tuple, np.ndarray] = {}
        for mat in model.sidecar.get("materials", []):
            mid = str(mat.get("id", ""))
            tail = mid.rsplit("-mat-", 1)
            if len(tail) != 2 or not tail[1].isdigit() or int(tail[1]) >= len(src_mats):
                continue  # the build's default material
            smat = src_mats[int(tail[1])]
            built = mat.get("textures") or {}
            for role, paths in ROLE_PATHS.items():
                info = None
                for path in paths:
                    node: Any = smat
                    for k in path:
                        node = node.get(k) if isinstance(node, dict) else None
                    if isinstance(node, dict) and node.get("index") is not None:
                        info = node
                        break
                key = f"{mid}/{role}"
                raw = _image_bytes(doc, blob, src.parent, int(info["index"])) if info else None
                tex = built.get(role)
                if info is None and tex is None:
                    continue
                if raw is None or tex is None or not tex.get("ktx2"):
                    if (raw is None) != (tex is None):
                        r.worst("roleMismatch", 1, 0)
                        r.messages.append(f"{key}: the source {'has' if raw is not None else 'has no'} texture "
                                          f"in this role, the build {'has' if tex is not None else 'has none'}")
                    continue
                try:
                    with ctx.timer("compare"):
                        ktx = open_ktx2(model.root / tex["ktx2"], ctx.cache)
                        k = ktx.nearest(ROLE_PX)
                        lv = ktx.level(k)
                        n, tol = 3, ctx.options.role_tolerance
                        if ktx.block is not None:  # BC / ETC2: compared over the stored channels
                            n = min(3, ktx.stored)
                            # plus the encoders' own error, as the textures check allows for level 0
                            tol += ctx.options.texture_compressed_png_tolerance - ctx.options.texture_png_tolerance
                        rgba = decode_rgba(raw, ctx.cache)
                        fmt = 43 if ktx.srgb else 37
                        rkey = (id(rgba), lv.shape[1], lv.shape[0], role == "normal", fmt)
                        if rkey not in reduced:
                            reduced[rkey] = _reduce(rgba, (lv.shape[1], lv.shape[0]), role, fmt)
                        ref = reduced[rkey]
                        d = float(np.abs(ref[..., :n] - lv[..., :n].astype(np.float32)).mean()) / 255.0
                except Exception as exc:  # noqa: BLE001 - the textures check reports unreadable KTX2s
                    figures[key] = {"error": str(exc)[:200]}
                    continue
                figures[key] = {"level": k, "difference": round(d, 5)}
                if r.worst("difference", d, tol):
                    r.messages.append(f"{key}: the built texture differs from the source's {role} image by "
                                      f"{d:.3f} (> {tol:.3f}; wrong or swapped texture?)")
        r.figures = figures
        return r.finish()


def load_source_path(ctx: Context) -> tuple[Path | None, None, str | None]:
    """The source path (no import): reuse the source check's lookup."""
    from .source import find_source  # noqa: PLC0415

    assert ctx.model is not None
    if "source" in ctx.cache:
        return ctx.cache["source"][0], None, ctx.cache["source"][2]
    src = find_source(ctx.model_json, ctx.model.sidecar, ctx.options)
    return src, None, None if src else "source not found (set source_root)"


CHECK = RolesCheck()
