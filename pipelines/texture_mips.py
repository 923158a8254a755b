"""Correct mip chains: gamma-correct colour, alpha-weighted colour, coverage-preserving alpha
test, renormalised normals, linear data.

Pure functions over numpy arrays; OpenCV does the filtering (``cv2.resize`` with
``INTER_AREA``, which averages exact pixel areas, including non-integer ratios), numpy and
lookup tables do the conversions. No Python loop runs over texels (only over levels).

Sizes
-----
Level 0 is ``(H, W)``; level ``k`` is ``(max(1, H >> k), max(1, W >> k))``; there are
``floor(log2(max(W, H))) + 1`` levels (non-square and non-power-of-two included), the full
chain down to 1x1, as Vulkan and KTX2 define it.

Filtering
---------
Every level is the exact area average of level 0 over the level's texel footprint (in the
role's filtering space), up to 16-bit rounding. It is computed from the most recent level whose
size is an integer multiple of its own (exact box filter, cheap: usually the previous level),
or from level 0 with INTER_AREA's fractional area weights when no level divides it (odd sizes:
211 -> 105 cannot be made from 2x2 boxes without dropping a row).

* ``baseColor``, ``emissive`` (sRGB roles): sRGB -> linear 16-bit by lookup table, filtered in
  linear light, linear -> sRGB by a 65536-entry table (exact function, rounded).
* ``baseColor`` with any alpha below 255 (BLEND, MASK, or an OPAQUE material whose texture has
  alpha; the seed format treats those as transparent): colour is weighted by alpha
  (premultiplied filtering, float32) and un-premultiplied, so transparent texels do not bleed
  dark fringes; texels whose footprint is entirely transparent keep the unweighted average
  colour. Alpha itself is filtered linearly.
* ``alphaMode == "MASK"``: each level's alpha is additionally scaled so the fraction of texels
  with ``alpha >= alphaCutoff`` equals level 0's (alpha-tested foliage keeps its coverage).
  The scale is found exactly with an order statistic (``np.partition``), which is what a
  binary search over the scale converges to, in O(N).
* ``metallicRoughness``, ``occlusion``: every channel linear (16-bit intermediate).
* ``normal``: texels decode as ``n = v * 2 / 255 - 1``; vectors are averaged (their
  unnormalised mean is carried down the chain), renormalised and re-encoded with rounding.
  Level 0 is renormalised too. 8-bit storage cannot hold exact unit vectors: after decoding,
  ``| |n| - 1 |`` is bounded by the rounding error, at most ``sqrt(3) / 255`` (0.0068).
  The vectors before quantisation are unit length to float32 precision.
* Alpha of every non-baseColor role is filtered linearly.

Accuracy (tests): mean absolute error per level <= 0.5 (8-bit units) against a float64 exact
area average in linear light; the rounding to 8 bits alone accounts for ~0.25.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from assetpipe.pipelines.texture_options import DEFAULT_TEXTURE_OPTIONS, TextureOptions  # noqa: F401 (re-exported)
from assetpipe.pipelines.model import (ROLE_BASE_COLOR, ROLE_EMISSIVE, ROLE_METALLIC_ROUGHNESS, ROLE_NORMAL,
                             ROLE_OCCLUSION, SRGB_ROLES, TEXTURE_ROLES)




@dataclass(frozen=True, eq=False)
class MipChain:
    """A full mip chain.

    ``levels[k]``: ``(max(1, H >> k), max(1, W >> k), 4)`` uint8 RGBA, level 0 first.
    ``srgb``: the RGB channels are sRGB-encoded (store as ``R8G8B8A8_SRGB``); else linear.
    ``coverage``: for alphaMode MASK on baseColor, per level, the fraction of texels with
    ``alpha/255 >= alpha_cutoff``; else ``None``.
    ``mean_drift``: per level, the largest over R, G, B, A of
    ``|mean(level k) - mean(level 0)|`` in linear light (sRGB roles decoded), in 1/255 units;
    for alpha-weighted chains over R*A, G*A, B*A and A (what such filtering conserves). A
    cheap check that filtering preserves energy: naive sRGB averaging drifts by several units,
    8-bit rounding of the smallest levels by up to ~1; coverage scaling for MASK changes the
    alpha mean on purpose. Normal maps: the encoded values' plain means.
    ``alpha_weighted``: colour was filtered premultiplied by alpha.
    ``dropped_levels``: top levels removed to honour ``max_size``.
    """

    levels: tuple[np.ndarray, ...]
    role: str
    srgb: bool
    alpha_mode: str = "OPAQUE"
    alpha_weighted: bool = False
    coverage: tuple[float, ...] | None = None
    mean_drift: tuple[float, ...] = field(default=())
    dropped_levels: int = 0

    @property
    def width(self) -> int:
        return int(self.levels[0].shape[1])

    @property
    def height(self) -> int:
        return int(self.levels[0].shape[0])


# ----------------------------------------------------------------------------- sizes

def mip_level_count(width: int, height: int) -> int:
    """``floor(log2(max(width, height))) + 1``."""
    return max(int(width), int(height)).bit_length()


def mip_sizes(width: int, height: int) -> list[tuple[int, int]]:
    """``[(w, h), ...]`` of every level, level 0 first, each side halved with floor, min 1."""
    return [(max(1, width >> k), max(1, height >> k)) for k in range(mip_level_count(width, height))]


# ----------------------------------------------------------------------------- colour tables

def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The sRGB EOTF on values in [0, 1] (float64 in, float64 out)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(y: np.ndarray) -> np.ndarray:
    """The inverse sRGB EOTF on values in [0, 1] (float64 in, float64 out)."""
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    return np.where(y <= 0.0031308, y * 12.92, 1.055 * np.power(y, 1.0 / 2.4) - 0.055)


_LIN16_FROM_SRGB8 = np.rint(srgb_to_linear(np.arange(256) / 255.0) * 65535.0).astype(np.uint16)
_ID16_FROM_8 = (np.arange(256, dtype=np.uint16) * 257).astype(np.uint16)
# 4-channel tables for cv2.LUT: colour via sRGB, alpha linear; or all linear.
_LUT_SRGB_RGB_LIN_A = np.stack([_LIN16_FROM_SRGB8] * 3 + [_ID16_FROM_8], axis=-1).reshape(1, 256, 4)
_SRGB8_FROM_LIN16 = np.rint(linear_to_srgb(np.arange(65536) / 65535.0) * 255.0).astype(np.uint8)
_LIN16_FROM_SRGB16: np.ndarray | None = None  # built on first use (16-bit sRGB sources are rare)


def _lin16_from_srgb16() -> np.ndarray:
    global _LIN16_FROM_SRGB16
    if _LIN16_FROM_SRGB16 is None:
        _LIN16_FROM_SRGB16 = np.rint(srgb_to_linear(np.arange(65536) / 65535.0) * 65535.0).astype(np.uint16)
    return _LIN16_FROM_SRGB16


def _to_work16(rgba: np.ndarray, srgb: bool) -> np.ndarray:
    """uint8/uint16 RGBA -> uint16 working values (linear light for sRGB colour; alpha linear)."""
    if rgba.dtype == np.uint8:
        if srgb:
            return cv2.LUT(rgba, _LUT_SRGB_RGB_LIN_A)
        return cv2.LUT(rgba, np.stack([_ID16_FROM_8] * 4, axis=-1).reshape(1, 256, 4))
    if srgb:
        out = np.take(_lin16_from_srgb16(), rgba)
        out[..., 3] = rgba[..., 3]
        return out
    return rgba.copy()


def _u16_to_u8(x: np.ndarray) -> np.ndarray:
    """Linear 16-bit -> 8-bit, rounded (x / 257); any shape."""
    return cv2.convertScaleAbs(x, alpha=1.0 / 257.0)


def _encode_work16(w: np.ndarray, srgb: bool, opaque: bool = False) -> np.ndarray:
    """uint16 working values (h, w, 4) -> uint8 RGBA. ``opaque``: every alpha is 65535 (the
    sRGB table maps it to 255 already, no separate alpha pass)."""
    if not srgb:
        return _u16_to_u8(w)
    out = _SRGB8_FROM_LIN16[w]
    if not opaque:
        out[..., 3] = _u16_to_u8(np.ascontiguousarray(w[..., 3]))
    return out


def _resize_area(src: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Exact area average of ``src`` (h, w, C) down to ``size`` = (w', h'); keeps dtype and C."""
    if (src.shape[1], src.shape[0]) == size:
        return src
    out = cv2.resize(src, size, interpolation=cv2.INTER_AREA)
    if out.ndim == 2:
        out = out[..., None]
    return out


def _source_index(sizes: list[tuple[int, int]], k: int) -> int:
    """The most recent level j < k whose sides are integer multiples of level k's (box filter
    from it is exact), else 0 (INTER_AREA from level 0 with fractional weights, also exact)."""
    wk, hk = sizes[k]
    for j in range(k - 1, 0, -1):
        wj, hj = sizes[j]
        if wj % wk == 0 and hj % hk == 0:
            return j
    return 0


def _chain(work0: np.ndarray, sizes: list[tuple[int, int]]) -> list[np.ndarray]:
    """Filtered working levels (each the exact area average of level 0), level 0 included."""
    works = [work0]
    for k in range(1, len(sizes)):
        works.append(_resize_area(works[_source_index(sizes, k)], sizes[k]))
    return works


# ----------------------------------------------------------------------------- role filters

def _linear_means(levels8: list[np.ndarray], srgb: bool, mean0: np.ndarray | None = None) -> list[np.ndarray]:
    """Per level, the mean of each channel in linear light, in [0, 255] units (float64 (4,)).

    Computed from 256-bin histograms (cheap); ``mean0`` replaces level 0's when known.
    """
    tables = [(_LIN16_FROM_SRGB8 if srgb and c < 3 else _ID16_FROM_8).astype(np.float64) / 257.0
              for c in range(4)]
    means = []
    for k, lv in enumerate(levels8):
        if k == 0 and mean0 is not None:
            means.append(mean0)
            continue
        n = lv.shape[0] * lv.shape[1]
        m = [float(cv2.calcHist([lv], [c], None, [256], [0, 256]).reshape(-1) @ tables[c]) / n for c in range(4)]
        means.append(np.asarray(m))
    return means


def _premultiplied_means(levels8: list[np.ndarray], srgb: bool) -> list[np.ndarray]:
    """Per level, the mean of linear R*A, G*A, B*A and of A, in [0, 255] units (float64 (4,)):
    the quantities alpha-weighted filtering conserves."""
    table = ((_LIN16_FROM_SRGB8 if srgb else _ID16_FROM_8).astype(np.float32) / 65535.0)
    lut = np.stack([table, table, table, np.arange(256, dtype=np.float32) / 255.0], axis=-1).reshape(1, 256, 4)
    means = []
    for lv in levels8:
        f = cv2.LUT(lv, lut)
        f[..., :3] *= f[..., 3:4]
        means.append(np.asarray(cv2.mean(f)[:4], dtype=np.float64) * 255.0)
    return means


_BAND_TEXELS = 1 << 20  # level-0 texels converted per band (8 MiB of uint16 RGBA)


def _first_level_banded(rgba: np.ndarray, lut: np.ndarray, size1: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Level 1 working values straight from uint8 level 0, band by band (level 0's 16-bit
    copy is never held whole: less memory traffic). Needs integer ratios level 0 / level 1.

    Returns ``(work1 (h1, w1, 4) uint16, mean0 (4,) float64 in 1/255 units)``.
    """
    h0, w0 = rgba.shape[:2]
    w1, h1 = size1
    ry = h0 // h1
    rows = max(ry, (_BAND_TEXELS // max(1, w0)) // ry * ry)
    work1 = np.empty((h1, w1, 4), np.uint16)
    total = np.zeros(4, np.float64)
    for r0 in range(0, h0, rows):  # loop over bands of rows, not texels
        band = cv2.LUT(rgba[r0:r0 + rows], lut)
        total += cv2.sumElems(band)[:4]
        out = cv2.resize(band, (w1, band.shape[0] // ry), interpolation=cv2.INTER_AREA)
        work1[r0 // ry:r0 // ry + out.shape[0]] = out.reshape(out.shape[0], w1, 4)
    return work1, total / (h0 * w0 * 257.0)


def _colour_chain(rgba: np.ndarray, srgb: bool, sizes, opaque: bool) -> tuple[list[np.ndarray], np.ndarray]:
    """Levels and level 0's linear mean per channel (in 1/255 units)."""
    if rgba.dtype == np.uint8:
        level0 = rgba.view()  # shared, read-only view of the caller's array
    else:
        level0 = _u16_to_u8(rgba)
    banded = (rgba.dtype == np.uint8 and len(sizes) > 1
              and sizes[0][0] % sizes[1][0] == 0 and sizes[0][1] % sizes[1][1] == 0
              and all(_source_index(sizes, k) != 0 for k in range(2, len(sizes))))
    if banded:
        lut = _LUT_SRGB_RGB_LIN_A if srgb else np.stack([_ID16_FROM_8] * 4, axis=-1).reshape(1, 256, 4)
        work1, mean0 = _first_level_banded(rgba, lut, sizes[1])
        works = [None, work1]
        for k in range(2, len(sizes)):
            works.append(_resize_area(works[_source_index(sizes, k)], sizes[k]))
    else:
        work0 = _to_work16(rgba, srgb)
        works = _chain(work0, sizes)
        mean0 = np.asarray(cv2.mean(work0)[:4], dtype=np.float64) / 257.0
    return [level0] + [_encode_work16(w, srgb, opaque) for w in works[1:]], mean0


def _premultiplied_chain(rgba: np.ndarray, srgb: bool, sizes, alpha_mode: str,
                         alpha_cutoff: float) -> tuple[list[np.ndarray], tuple[float, ...] | None]:
    """Alpha-weighted colour filtering (float32), alpha linear, optional coverage scaling."""
    w16 = _to_work16(rgba, srgb)
    lin = w16.astype(np.float32) * np.float32(1.0 / 65535.0)  # (H, W, 4) linear, alpha in [0, 1]
    a = lin[..., 3:4]
    pre = np.empty_like(lin)
    np.multiply(lin[..., :3], a, out=pre[..., :3])
    pre[..., 3:4] = a
    pres = _chain(pre, sizes)          # premultiplied colour + alpha
    straights = _chain(w16[..., :3].copy(), sizes)  # unweighted colour for fully transparent texels

    level0 = rgba.view() if rgba.dtype == np.uint8 else _u16_to_u8(rgba)
    cutoff8 = None
    coverage: list[float] | None = None
    target = 0.0
    if alpha_mode == "MASK":
        cutoff8 = _cutoff_threshold8(alpha_cutoff)
        target = float(np.count_nonzero(level0[..., 3] >= cutoff8)) / level0[..., 3].size
        coverage = [target]
    out = [level0]
    for pre_k, straight_k in zip(pres[1:], straights[1:]):
        alpha = pre_k[..., 3]
        empty = alpha <= (0.5 / 65535.0)
        colour = np.divide(pre_k[..., :3], alpha[..., None], out=np.zeros(alpha.shape + (3,), np.float32),
                           where=~empty[..., None])
        colour16 = np.rint(np.clip(colour, 0.0, 1.0) * 65535.0).astype(np.uint16)
        if empty.any():
            colour16[empty] = straight_k[empty]
        lv = np.empty(alpha.shape + (4,), dtype=np.uint8)
        lv[..., :3] = _SRGB8_FROM_LIN16[colour16] if srgb else _u16_to_u8(colour16)
        if cutoff8 is not None:
            alpha = _scale_alpha_for_coverage(alpha, target, cutoff8)
        lv[..., 3] = np.rint(np.clip(alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
        if coverage is not None:
            coverage.append(float(np.count_nonzero(lv[..., 3] >= cutoff8)) / alpha.size)
        out.append(lv)
    return out, (tuple(coverage) if coverage is not None else None)


def _cutoff_threshold8(alpha_cutoff: float) -> int:
    """The smallest 8-bit alpha that passes ``alpha >= cutoff`` (alpha = a8 / 255)."""
    return int(min(256, max(0, math.ceil(alpha_cutoff * 255.0 - 1e-9))))


def _scale_alpha_for_coverage(alpha: np.ndarray, target: float, cutoff8: int) -> np.ndarray:
    """Scale ``alpha`` (h, w) float32 in [0, 1] so that the fraction of texels whose rounded
    8-bit value is >= ``cutoff8`` is as close as possible to ``target``.

    A texel passes when ``rint(alpha * s * 255) >= cutoff8``, i.e. ``alpha >= t / s`` with
    ``t = (cutoff8 - 0.5) / 255``; coverage is monotone in ``s``, so the best ``s`` puts the
    threshold just at or below the k-th largest alpha, k = round(target * N): an order
    statistic (``np.partition``), the fixed point of a binary search on ``s``.
    """
    n = alpha.size
    if cutoff8 <= 0 or cutoff8 > 255 or target <= 0.0 or target >= 1.0 or n == 0:
        return alpha
    k = int(round(target * n))
    flat = alpha.reshape(-1)
    if k <= 0:
        kth = float(flat.max())
        if kth <= 0.0:
            return alpha
        thr = (cutoff8 - 0.5) / 255.0
        s = thr / kth * (1.0 - 1e-6)  # everything just below the threshold
        return alpha * np.float32(s)
    kth = float(np.partition(flat, n - k)[n - k])  # the k-th largest
    if kth <= 0.0:
        return alpha  # coverage cannot be raised by scaling zeros
    thr = (cutoff8 - 0.5) / 255.0
    s = thr / kth * (1.0 + 1e-6)  # kth (and all above it) pass
    return alpha * np.float32(s)


def normal_unit_levels(rgba: np.ndarray) -> list[np.ndarray]:
    """The renormalised vectors of every level of a normal map, before 8-bit quantisation.

    ``rgba``: ``(H, W, 4)`` uint8 or uint16; returns ``[(h, w, 4) float32, ...]``, xyz unit
    length (a zero mean becomes +Z), w = linear alpha in [0, 1]. :func:`build_mip_chain`
    stores ``rint((xyz + 1) * 127.5)``.
    """
    height, width = rgba.shape[:2]
    if rgba.dtype == np.uint8:
        table = np.arange(256, dtype=np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
        vec = cv2.LUT(rgba, np.stack([table, table, table, np.arange(256, dtype=np.float32) / 255.0],
                                     axis=-1).reshape(1, 256, 4))
    else:
        vec = rgba.astype(np.float32) * np.float32(1.0 / 65535.0)
        vec[..., :3] = vec[..., :3] * 2.0 - 1.0
    # The unnormalised means are carried down the chain (the exact area average of level 0's
    # vectors); each level is normalised only for output.
    return [_unit(w) for w in _chain(vec, mip_sizes(width, height))]


def _unit(w: np.ndarray) -> np.ndarray:
    xyz = w[..., :3]
    length = np.sqrt(np.einsum("...i,...i->...", xyz, xyz))
    ok = length > 1e-12
    out = np.empty_like(w)
    np.divide(xyz, np.where(ok, length, 1.0)[..., None], out=out[..., :3])
    if not ok.all():
        out[~ok, :3] = (0.0, 0.0, 1.0)
    out[..., 3] = w[..., 3]
    return out


def _encode_normals(u: np.ndarray) -> np.ndarray:
    """(h, w, 4) float32 unit vectors + alpha -> uint8 RGBA (round to nearest)."""
    out = np.empty(u.shape[:2] + (4,), dtype=np.uint8)
    out[..., :3] = np.rint(np.clip((u[..., :3] + 1.0) * 127.5, 0.0, 255.0))
    out[..., 3] = np.rint(np.clip(u[..., 3], 0.0, 1.0) * 255.0)
    return out


# ----------------------------------------------------------------------------- entry point

def build_mip_chain(rgba: np.ndarray, role: str, alpha_mode: str = "OPAQUE", alpha_cutoff: float = 0.5,
                    options: TextureOptions = DEFAULT_TEXTURE_OPTIONS) -> MipChain:
    """The full mip chain of ``rgba`` filtered as ``role`` requires (see the module docstring).

    ``rgba``: ``(H, W, 4)`` uint8 or uint16 (as :func:`pipelines.texture_decode.decode_image`
    returns); not modified. Returns levels of uint8 RGBA (16-bit sources are reduced to 8 bits
    with rounding after filtering; level 0 by rounding).
    """
    if role not in TEXTURE_ROLES:
        raise ValueError(f"unknown texture role {role!r}")
    if alpha_mode not in ("OPAQUE", "MASK", "BLEND"):
        raise ValueError(f"unknown alpha mode {alpha_mode!r}")
    if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"expected (H, W, 4) uint8/uint16 RGBA, got {rgba.shape} {rgba.dtype}")
    height, width = rgba.shape[:2]
    if width < 1 or height < 1:
        raise ValueError("empty image")
    rgba = np.ascontiguousarray(rgba)
    srgb = role in SRGB_ROLES
    sizes = mip_sizes(width, height)

    alpha_weighted = False
    coverage = None
    mean0 = None
    if role == ROLE_NORMAL:
        levels = [_encode_normals(u) for u in normal_unit_levels(rgba)]
    else:
        has_alpha = _any_alpha_below_max(rgba)
        if role == ROLE_BASE_COLOR and has_alpha:
            alpha_weighted = True
            levels, coverage = _premultiplied_chain(rgba, srgb, sizes, alpha_mode, alpha_cutoff)
        else:  # opaque colour, emissive, metallicRoughness, occlusion
            levels, mean0 = _colour_chain(rgba, srgb, sizes, opaque=not has_alpha)
    if role == ROLE_BASE_COLOR and alpha_mode == "MASK" and coverage is None:
        # fully opaque texture: every texel passes at every level
        coverage = tuple(1.0 if alpha_cutoff <= 1.0 else 0.0 for _ in levels)

    dropped = 0
    if options.max_size is not None:
        while dropped < len(levels) - 1 and max(levels[dropped].shape[:2]) > options.max_size:
            dropped += 1
        levels = levels[dropped:]
        if coverage is not None:
            coverage = coverage[dropped:]

    if alpha_weighted:
        means = _premultiplied_means(levels, srgb)
    else:
        means = _linear_means(levels, srgb and role != ROLE_NORMAL, mean0 if dropped == 0 else None)
    drift = tuple(float(np.max(np.abs(m - means[0]))) for m in means)
    for lv in levels:
        lv.setflags(write=False)
    return MipChain(levels=tuple(levels), role=role, srgb=srgb, alpha_mode=alpha_mode,
                    alpha_weighted=alpha_weighted, coverage=coverage, mean_drift=drift,
                    dropped_levels=dropped)


def _any_alpha_below_max(rgba: np.ndarray) -> bool:
    top = 65535 if rgba.dtype == np.uint16 else 255
    return bool(rgba[..., 3].min() < top)


__all__ = [
    "TextureOptions", "DEFAULT_TEXTURE_OPTIONS", "MipChain", "build_mip_chain", "mip_level_count",
    "mip_sizes", "normal_unit_levels", "srgb_to_linear", "linear_to_srgb", "ROLE_BASE_COLOR", "ROLE_EMISSIVE",
    "ROLE_METALLIC_ROUGHNESS", "ROLE_OCCLUSION",
]
