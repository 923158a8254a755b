"""``textures``: every material texture's KTX2 against its sidecar entry, its role and its level-0 image.

Large textures are *sampled*: the statistics of a level with more than ``SAMPLE_TEXELS``
texels are taken over a fixed pseudo-random set of that many texels (the same positions in the
KTX2 level and the image file), never over a regular grid, so a periodic texture cannot hide
between samples. With 65,536 samples the standard error of a mean of 0..1 values is at most
0.5 / 256 = 0.002, 60x below the mean-drift tolerance. The "all black" test uses every texel
(``ndarray.any`` on the stored bytes, a single pass).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.sidecar_shape import sidecar_problem

from ..loader import material_list_path, sidecar_path
from ..results import CheckResult, ValidateOptions
from .base import Check, Context
from .images import decode_rgba
from .ktx2_levels import open_ktx2

SRGB_ROLES = {"baseColor", "emissive"}
VK_SRGB, VK_UNORM = 43, 37
SAMPLE_TEXELS = 1 << 16
# | |n| - 1 | of an 8-bit normal: each component is rounded to the nearest of 255 steps of 2/255, so it
# is off by at most 1/255 and the length by at most sqrt(3)/255 (the bound texture_mips documents).
NORMAL_LENGTH_BOUND = math.sqrt(3.0) / 255.0 + 1e-6
# A tangent-space normal map's mean vector points out of the surface: a mean z below 0.5 (a mean tilt
# beyond 60 degrees) is not a normal map in glTF's +Z-up convention (channels swapped or a wrong image).
NORMAL_MIN_MEAN_Z = 0.5
# Smallest non-zero 8-bit value is 1; rounding to nearest maps values below 0.5 to 0. A level may
# only be all black when level 0's mean, stored in the level's encoding, stays below 1.5 codes
# (0.5 for rounding plus 1.0 for the filter's and the rounding's error on the mean).
BLACK_MEAN_CODES = 1.5
# the block encoders' error in codes (the RMS error of their 36 dB PSNR goal, as ValidateOptions'
# texture_compressed_png_tolerance - texture_png_tolerance): an ETC2 emissive map of mean 2.2 codes had
# its 2x2 and 1x1 levels encoded black (the generated "pbr" kind built with --texture-compression etc2)
BLOCK_ENCODER_CODES = 4.0

_LIN = np.arange(256) / 255.0
SRGB_TO_LINEAR = np.where(_LIN <= 0.04045, _LIN / 12.92, ((_LIN + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb_code(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055) * 255.0


def sample(arr: np.ndarray, n: int = SAMPLE_TEXELS) -> np.ndarray:
    """(k, C) texels of an (H, W, C) level: all of them, or ``n`` at fixed pseudo-random positions."""
    h, w = arr.shape[:2]
    flat = arr.reshape(h * w, -1)
    if h * w <= n:
        return flat
    idx = np.random.default_rng(h * 65537 + w).integers(0, h * w, n)  # repeats are harmless
    return flat[np.sort(idx)]


def renormalise(rgb: np.ndarray) -> np.ndarray:
    """uint8 normal-map texels (k, 3) -> the same renormalised and re-encoded (texture_mips's rule)."""
    n = rgb.astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    u = np.where(length > 1e-12, n / np.maximum(length, 1e-12), np.array([0, 0, 1], np.float32))
    return np.rint(np.clip((u + 1.0) * 127.5, 0, 255)).astype(np.uint8)


def _rebuild_z(rgba: np.ndarray) -> np.ndarray:
    """A two-channel normal map's texels with z = sqrt(1 - x^2 - y^2) (x, y clamped to the unit
    disc), as the shader rebuilds it; ``(H, W, 4)`` uint8 in and out."""
    xy = rgba[..., :2].astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
    r2 = (xy * xy).sum(axis=-1, keepdims=True)
    xy = xy / np.sqrt(np.maximum(r2, 1.0))
    z = np.sqrt(np.maximum(0.0, 1.0 - (xy * xy).sum(axis=-1, keepdims=True)))
    out = rgba.copy()
    out[..., :3] = np.rint(np.clip((np.concatenate([xy, z], axis=-1) + 1.0) * 127.5, 0, 255)).astype(np.uint8)
    return out


def _linear_premultiplied(texels: np.ndarray, srgb: bool) -> np.ndarray:
    rgb = SRGB_TO_LINEAR[texels[:, :3]] if srgb else texels[:, :3].astype(np.float32) / 255.0
    return rgb * (texels[:, 3:4].astype(np.float32) / 255.0)


def _mean_colour(texels: np.ndarray, srgb: bool, mask: bool) -> np.ndarray | None:
    """(3,) the mean a level must keep: the linear premultiplied mean; for an alpha-tested
    (MASK) texture the alpha-weighted mean of the linear colour (sum of colour x alpha over
    sum of alpha), None when every alpha is 0. A MASK chain scales each level's alpha to keep
    level 0's coverage (FORMAT.md), which moves its premultiplied mean by design (up to 0.27 at
    the 1x1 level of AlphaBlendModeTest's labels with cutoff 0.75); a uniform scale leaves the
    alpha-weighted colour unchanged (0.021 at most there, clipped alphas included)."""
    pm = _linear_premultiplied(texels, srgb)
    if not mask:
        return pm.mean(axis=0)
    total = float(texels[:, 3].astype(np.float64).sum()) / 255.0
    return pm.sum(axis=0) / total if total > 0 else None


def check_one_texture(root: Path, key: str, role: str, tex: dict[str, Any], r: CheckResult,
                      options: ValidateOptions, cache: dict[str, Any] | None = None,
                      ) -> tuple[list[str], dict[str, Any]]:
    """The checks of one KTX2; returns (problems, figures) and records measured values on ``r``."""
    msgs: list[str] = []
    fig: dict[str, Any] = {}
    ktx_rel = tex["ktx2"]
    try:
        img = open_ktx2(root / ktx_rel, cache)
    except OSError as exc:
        r.worst("unreadable", 1, 0)
        return [f"{key}: KTX2 {ktx_rel} missing ({exc.strerror})"], fig
    except Exception as exc:  # noqa: BLE001
        r.worst("unreadable", 1, 0)
        return [f"{key}: KTX2 {ktx_rel} unreadable: {exc}"], fig
    w, h, fmt, srgb, block, stored = img.width, img.height, img.vk_format, img.srgb, img.block, img.stored
    try:  # BC / ETC2 / EAC levels are decoded on the CPU (texture2ddecoder), then checked alike
        levels = [img.level(i) for i in range(img.count)]
    except ValueError as exc:
        r.worst("unreadable", 1, 0)
        return [f"{key}: KTX2 {ktx_rel} blocks unreadable: {exc}"], fig
    if block is not None:
        fig["blockFormat"] = block.name
        if role == "normal" and stored == 2:  # BC5 / EAC RG11 keep x and y; z is rebuilt as the shader does
            levels = [_rebuild_z(lv) for lv in levels]
    full = int(math.floor(math.log2(max(w, h, 1)))) + 1
    fig.update(width=w, height=h, levels=len(levels), fullChain=full, vkFormat=fmt)
    if block is not None and block.srgb != (role in SRGB_ROLES):
        r.worst("formatMismatch", 1, 0)
        msgs.append(f"{key}: vkFormat {fmt} ({block.name}) for a {'colour' if role in SRGB_ROLES else 'data'} role "
                    f"(expected {'an sRGB' if role in SRGB_ROLES else 'a UNORM'} format: sRGB and linear swapped?)")
    if fmt != int(tex.get("vkFormat", fmt)):
        r.worst("formatMismatch", 1, 0)
        msgs.append(f"{key}: vkFormat {fmt} but the sidecar says {tex.get('vkFormat')}")
    expect_fmt = VK_SRGB if role in SRGB_ROLES else VK_UNORM
    if fmt in (VK_SRGB, VK_UNORM) and fmt != expect_fmt:
        r.worst("formatMismatch", 1, 0)
        msgs.append(f"{key}: vkFormat {fmt} ({'sRGB' if fmt == VK_SRGB else 'linear'}) for a "
                    f"{'colour' if role in SRGB_ROLES else 'data'} role (expected {expect_fmt}: sRGB and linear "
                    "swapped?)")
    if (w, h) != (int(tex.get("width", w)), int(tex.get("height", h))):
        r.worst("sizeMismatch", 1, 0)
        msgs.append(f"{key}: {w}x{h} but the sidecar says {tex.get('width')}x{tex.get('height')}")
    if len(levels) != int(tex.get("levels", len(levels))):
        r.worst("levelCountMismatch", 1, 0)
        msgs.append(f"{key}: {len(levels)} levels but the sidecar says {tex.get('levels')}")
    if r.worst("missingLevels", full - len(levels), 0):
        msgs.append(f"{key}: {len(levels)} of {full} mip levels (missing levels)")
    good = []
    for i, lv in enumerate(levels):
        expect = (max(h >> i, 1), max(w >> i, 1))
        if lv.shape[:2] != expect:
            r.worst("badLevelShape", 1, 0)
            msgs.append(f"{key}: level {i} is {lv.shape[1]}x{lv.shape[0]}, expected {expect[1]}x{expect[0]}")
        elif lv.dtype != np.uint8:
            r.worst("unsupportedFormat", 1, 0)
            msgs.append(f"{key}: level {i} is {lv.dtype}, not 8-bit RGBA")
        else:
            good.append((i, lv))
    if not good:
        return msgs, fig
    samples = {i: sample(lv) for i, lv in good}
    if role == "normal":
        _normal_checks(key, samples, r, msgs, fig)
    else:
        # an alpha-tested texture carries its coverage per level (None for every other one)
        mask = tex.get("coverage") is not None
        means = {i: m for i, s in samples.items() if (m := _mean_colour(s, srgb, mask)) is not None}
        if 0 in means:
            m0 = means[0]
            # black levels: only when level 0's mean says the level cannot be black (see BLACK_MEAN_CODES)
            codes = linear_to_srgb_code(m0) if srgb else np.clip(m0, 0, 1) * 255.0
            fig["level0MeanCodes"] = [round(float(c), 2) for c in codes]
            # a block encoder may round a block of a few codes to black: its error (4 codes, as
            # texture_compressed_png_tolerance allows for level 0) is added for block formats
            black_codes = BLACK_MEAN_CODES + (BLOCK_ENCODER_CODES if block is not None else 0.0)
            if float(codes.max()) >= black_codes:
                black = [i for i, lv in good if i > 0 and not lv[..., :3].any()]
                if r.worst("blackLevels", len(black), 0):
                    msgs.append(f"{key}: levels {black} are all black although level 0's mean is "
                                f"{float(codes.max()):.1f}/255 (a mip of it cannot be black)")
            drift = {i: float(np.abs(m - m0).max()) for i, m in means.items()}
            fig["maxMeanDrift"] = round(max(drift.values()), 4)
            bad = [i for i, d in drift.items() if d > options.texture_mean_tolerance]
            if r.worst("meanDrift", max(drift.values()), options.texture_mean_tolerance):
                msgs.append(f"{key}: levels {bad} drift from level 0's mean colour by up to "
                            f"{max(drift.values()):.3f} (> {options.texture_mean_tolerance})")
    png_rel = tex.get("path")
    if png_rel and good and good[0][0] == 0:
        try:
            ref = decode_rgba((root / png_rel).read_bytes(), cache)
        except Exception as exc:  # noqa: BLE001
            r.worst("unreadable", 1, 0)
            return msgs + [f"{key}: level-0 image {png_rel} unreadable: {exc}"], fig
        lv0 = good[0][1]
        if ref.shape != lv0.shape:
            r.worst("level0SizeMismatch", 1, 0)
            msgs.append(f"{key}: {png_rel} is {ref.shape[1]}x{ref.shape[0]}, the KTX2 level 0 "
                        f"{lv0.shape[1]}x{lv0.shape[0]} (swapped texture?)")
        else:
            a, b = sample(ref), samples[0]
            if role == "normal":  # level 0 of a normal map is the image's vectors renormalised (FORMAT.md)
                a = np.concatenate([renormalise(a[:, :3]), a[:, 3:]], axis=1)
            tol = options.texture_png_tolerance if block is None else options.texture_compressed_png_tolerance
            n = 2 if (role == "normal" and stored == 2) else stored  # a rebuilt z is compared through x, y
            d = float(np.abs(a[:, :n].astype(np.int16) - b[:, :n].astype(np.int16)).mean()) / 255.0
            fig["level0VsImage"] = round(d, 5)
            if r.worst("level0VsImage", d, tol):
                what = "the image renormalised" if role == "normal" else png_rel
                msgs.append(f"{key}: KTX2 level 0 differs from {what} (mean {d:.4f} > "
                            f"{tol:.4f}; swapped texture or channels?)")
    return msgs, fig


def _normal_checks(key: str, samples: dict[int, np.ndarray], r: CheckResult, msgs: list[str],
                   fig: dict[str, Any]) -> None:
    worst_len, worst_level = 0.0, 0
    for i, s in samples.items():
        n = s[:, :3].astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
        err = float(np.abs(np.linalg.norm(n, axis=1) - 1.0).max())
        if err > worst_len:
            worst_len, worst_level = err, i
        if i == 0:
            mean_z = float(n[:, 2].mean())
            fig["meanZ"] = round(mean_z, 4)
            if r.worst("lowMeanZ", NORMAL_MIN_MEAN_Z - mean_z, 0.0):
                msgs.append(f"{key}: the normals' mean z is {mean_z:.2f} (< {NORMAL_MIN_MEAN_Z}: channels swapped "
                            "or not a tangent-space normal map?)")
    fig["maxLengthError"] = round(worst_len, 5)
    if r.worst("normalLengthError", worst_len, NORMAL_LENGTH_BOUND):
        msgs.append(f"{key}: level {worst_level} holds normals of length off by {worst_len:.4f} "
                    f"(> sqrt(3)/255 = {NORMAL_LENGTH_BOUND:.4f}: not renormalised)")


class TexturesCheck(Check):
    name = "textures"
    beside = True
    measures = ("every material texture: the KTX2 reads; vkFormat, size and level count match the sidecar and "
                "the role (sRGB for baseColor/emissive, linear otherwise); the full mip chain with the expected "
                "sizes; no level all black unless level 0's mean rounds to black; each level's linear "
                "premultiplied mean (alpha-tested: alpha-weighted colour) against level 0's; level 0 against "
                "the level-0 image (for normal maps: the image's vectors renormalised); normal maps: unit "
                "length and mean z")
    tolerance = ("exact for formats, sizes and counts; texture_mean_tolerance 0.12 (linear 0..1) for mean "
                 "drift; texture_png_tolerance 2/255 mean absolute difference for level 0 vs image (block-compressed: "
                 "texture_compressed_png_tolerance 6/255 over the stored channels); "
                 "sqrt(3)/255 for normal length; mean z >= 0.5; black only when level 0's mean < 1.5 codes (5.5 for block formats)")
    reason = ("mips are exact area averages, so every level keeps level 0's mean up to rounding (FORMAT.md: "
              "meanDrift); a MASK chain scales alpha per level to keep coverage, so for it the alpha-weighted "
              "colour is compared (a uniform alpha scale leaves it unchanged; its premultiplied mean moved by up "
              "to 0.27 at AlphaBlendModeTest's 1x1 level). Worst measured drift: 0.0205 (AlphaBlendModeTest's "
              "labels at cut-off 0.75; the corpus's 38 models and the 10 generated kinds, 2026-11-27). 0.12 was "
              "set at 3x the generated MASK kind's premultiplied drift (0.037) and still catches a wrong level "
              "(the mutation suite). Level 0 is the "
              "image's texels re-stored (a JPEG decoded by another decoder differs by at most 1-2 codes). "
              "Renormalised 8-bit vectors are off unit length by at most sqrt(3)/255 (rounding)")

    def run(self, ctx: Context) -> CheckResult:
        r = self.result()
        model_json = ctx.model_json
        root = Path(model_json).parent
        try:
            side = json.loads(sidecar_path(model_json).read_text())
            mats = json.loads(material_list_path(model_json).read_text())
            problem = sidecar_problem(side)
            if problem is None and not (isinstance(mats, list) and all(
                    isinstance(m, dict) and isinstance(m.get("id"), str) for m in mats)):
                problem = "the material list is not a list of objects with an id"
            if problem:
                raise ValueError(problem)
        except (OSError, ValueError) as exc:
            r.worst("unreadable", 1, 0)
            r.messages.append(f"cannot read the material files: {exc}")
            return r.finish()
        seed_mats = {m["id"]: m for m in mats}
        figures: dict[str, Any] = {}
        seen: dict[str, tuple[dict[str, Any], list[str]]] = {}
        count = 0
        for mat in side.get("materials", []):
            mid = mat.get("id")
            for role, tex in (mat.get("textures") or {}).items():
                count += 1
                key = f"{mid}/{role}"
                seed_path = (seed_mats.get(mid) or {}).get("texturePath", "")
                if role == "baseColor" and seed_path != tex.get("path"):
                    r.worst("texturePathMismatch", 1, 0)
                    r.messages.append(f"{key}: seed texturePath {seed_path!r} differs from the sidecar's "
                                      f"{tex.get('path')!r}")
                ktx_rel = tex.get("ktx2")
                if not ktx_rel:
                    r.worst("missingKtx2", 1, 0)
                    r.messages.append(f"{key}: no KTX2 (mip chain missing)")
                    continue
                if (ktx_rel, role) not in seen:  # a texture shared by several materials is checked once
                    with ctx.timer("compare"):
                        msgs, fig = check_one_texture(root, key, role, tex, r, ctx.options, ctx.cache)
                    seen[(ktx_rel, role)] = (fig, [m.split(": ", 1)[1] for m in msgs])
                fig, tail = seen[(ktx_rel, role)]
                figures[key] = fig
                r.messages += [f"{key}: {m}" for m in tail]
        figures["textures"] = count
        r.figures = figures
        return r.finish()


CHECK = TexturesCheck()
