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

Oversize sources (``options.max_size``): the top levels are dropped before the chain is built.
The kept levels are byte for byte the full chain's, but neither level 0's working copy (16-bit
or float32: 2x or 4x the 8-bit source) nor a dropped level that no kept level is filtered
from is ever made: the levels filtered from level 0 are computed from bands of its rows
(``_chain_dropping``; one pass over the source for all of them where their working sets are
small). A 12000x12000 RGBA8 source built at 6000x6000: peak RSS growth in build_mip_chain
0.54 GiB instead of 1.61 GiB, same time (10.0 vs 10.4 s, baseColor); normal maps 1.56 GiB
instead of 6.2 GiB (fresh processes, one after the other).

Accuracy (tests): mean absolute error per level <= 0.5 (8-bit units) against a float64 exact
area average in linear light; the rounding to 8 bits alone accounts for ~0.25.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit

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
# x / 257 rounded: the same as _u16_to_u8 (cv2.convertScaleAbs) for every 16-bit value
_LIN8_FROM_LIN16 = np.rint(np.arange(65536) / 257.0).astype(np.uint8)
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


# -- chains whose top levels are dropped (max_size) ----------------------------------------------
# The same levels as _chain(to_work(level 0), sizes)[first:], byte for byte, without the working
# copy of level 0 (16-bit: twice the 8-bit source; float32: four times): every level the chain
# takes from level 0 is computed from bands of rows of the source, converted band by band.
# Integer ratios: INTER_AREA per band, bands aligned to the ratio (what OpenCV computes for a
# row depends only on the rows of its footprint and the scale). Fractional ratios: OpenCV's
# generic INTER_AREA is separable in float32 (each source row resampled horizontally, then the
# rows of a footprint summed with their weights, in order, then rounded); the horizontal pass
# runs per band (cv2.resize with a vertical scale of 1, or the same weights in numpy where the
# horizontal ratio is an integer and OpenCV would take its integer fast path), the vertical sum
# replays OpenCV's weight table in numpy over the band's output rows.

def _area_table(n_src: int, n_dst: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's INTER_AREA weight table (``computeResizeAreaTab``) for ``n_src -> n_dst``.

    Returns ``(src (n_dst, m) int64, alpha (n_dst, m) float32, count (n_dst,) int64)``: output
    ``i`` is ``sum(alpha[i, t] * x[src[i, t]] for t < count[i])``, summed in that order.
    """
    scale = 1.0 / (n_dst / n_src)  # as cv::resize derives it (1 / inv_scale)
    rows: list[list[tuple[int, float]]] = []
    for dx in range(n_dst):  # loop over output rows to build the table, as OpenCV does
        fsx1 = dx * scale
        fsx2 = fsx1 + scale
        cell = min(scale, n_src - fsx1)
        sx1, sx2 = math.ceil(fsx1), math.floor(fsx2)
        sx2 = min(sx2, n_src - 1)
        sx1 = min(sx1, sx2)
        row = []
        if sx1 - fsx1 > 1e-3:
            row.append((sx1 - 1, (sx1 - fsx1) / cell))
        row.extend((sx, 1.0 / cell) for sx in range(sx1, sx2))
        if fsx2 - sx2 > 1e-3:
            row.append((sx2, min(min(fsx2 - sx2, 1.0), cell) / cell))
        rows.append(row)
    count = np.array([len(r) for r in rows], np.int64)
    src = np.zeros((n_dst, int(count.max())), np.int64)
    alpha = np.zeros(src.shape, np.float32)
    for i, row in enumerate(rows):
        src[i, :len(row)] = [e[0] for e in row]
        alpha[i, :len(row)] = [e[1] for e in row]  # float64 -> float32, rounded as C's cast
    return src, alpha, count


def _weighted_sum(x: np.ndarray, axis: int, src: np.ndarray, alpha: np.ndarray, count: np.ndarray,
                  offset: int = 0) -> np.ndarray:
    """``out[i] = 0 + alpha[i, 0] * x[src[i, 0] - offset] + ...`` along ``axis`` (0 or 1) of
    float32 ``x`` (r, c, C), in table order (OpenCV's float32 accumulation, no fused multiply-add)."""
    n = src.shape[0]
    shape = list(x.shape)
    shape[axis] = n
    acc = np.zeros(shape, np.float32)
    for t in range(src.shape[1]):  # loop over table columns (<= ratio + 2), not texels
        sel = np.nonzero(count > t)[0]
        if sel.size == 0:
            break
        idx = src[sel, t] - offset
        a = alpha[sel, t]
        if axis == 0:
            acc[sel] += np.take(x, idx, axis=0) * a[:, None, None]
        else:
            acc[:, sel] += np.take(x, idx, axis=1) * a[None, :, None]
    return acc


def _horizontal_area(band: np.ndarray, w: int) -> np.ndarray:
    """OpenCV's horizontal INTER_AREA pass of float32 rows ``(r, W, C)`` to width ``w`` (float32)."""
    rows, width = band.shape[:2]
    if width == w:
        return band
    if width % w:  # fractional: cv2's generic path (vertical scale 1: each row copied, weight 1)
        return cv2.resize(band, (w, rows), interpolation=cv2.INTER_AREA).reshape(rows, w, band.shape[2])
    return _weighted_sum(band, 1, *_area_table(width, w))


def _level_from_source0(src: np.ndarray, to_work, size: tuple[int, int]) -> np.ndarray:
    """``_resize_area(to_work(src), size)`` computed over bands of rows of ``src``: the working
    copy of ``src`` is never held whole. ``to_work`` maps rows of ``src`` to the working array
    (uint16 or float32, (r, W, C)), row by row."""
    height, width = src.shape[:2]
    w, h = size
    if height % h == 0 and width % w == 0:  # integer ratios: bands aligned to the vertical ratio
        ry = height // h
        rows = max(ry, (_BAND_TEXELS // max(1, width)) // ry * ry)
        out = None
        for r0 in range(0, height, rows):  # loop over bands of rows, not texels
            part = _resize_area(to_work(src[r0:r0 + rows]), (w, min(rows, height - r0) // ry))
            if out is None:
                out = np.empty((h, w, part.shape[2]), part.dtype)
            out[r0 // ry:r0 // ry + part.shape[0]] = part
        return out
    ysrc, yalpha, ycount = _area_table(height, h)
    last = ysrc[np.arange(h), ycount - 1]  # each output row's last source row (ascending)
    per = max(1, int(_BAND_TEXELS // max(1, width) * h // height))  # output rows per band
    out = None
    for i0 in range(0, h, per):  # loop over bands of output rows, not texels
        i1 = min(h, i0 + per)
        lo, hi = int(ysrc[i0, 0]), int(last[i1 - 1]) + 1
        work = to_work(src[lo:hi])
        horiz = _horizontal_area(work.astype(np.float32, copy=False), w)
        part = _weighted_sum(horiz, 0, ysrc[i0:i1], yalpha[i0:i1], ycount[i0:i1], offset=lo)
        if out is None:
            out = np.empty((h, w, part.shape[2]), work.dtype)
        if work.dtype == np.uint16:  # OpenCV's saturate_cast<ushort>(float): round half to even, clamp
            np.clip(np.rint(part), 0, 65535, out=part)
        out[i0:i1] = part
    return out


def _levels_from_source0(src: np.ndarray, to_work, sizes: list[tuple[int, int]]) -> list[np.ndarray]:
    """``[_level_from_source0(src, to_work, size) for size in sizes]``, the same arrays, with one
    conversion of ``src`` for all the levels it can serve: integer ratios (bands aligned to
    every ratio) and fractional levels whose horizontal pass over all rows of ``src`` is small
    (float32, at most 1/8 of ``src``'s bytes; the vertical sum then runs on it whole). The others
    (a fractional level 1 of an odd-width source) take their own banded pass."""
    height, width = src.shape[:2]
    base_rows = max(1, _BAND_TEXELS // max(1, width))
    integer = [i for i, (w, h) in enumerate(sizes) if height % h == 0 and width % w == 0]
    step = math.lcm(*(height // sizes[i][1] for i in integer)) if integer else 1
    if step > 4 * base_rows:
        integer, step = [], 1
    small = max(src.nbytes // 8, _GATHER_MIN_BYTES)
    gathered = [i for i, (w, h) in enumerate(sizes) if i not in integer and (height % h or width % w)
                and height * w * 16 <= small]
    outs: list[np.ndarray | None] = [None] * len(sizes)
    if integer or gathered:
        rows = max(step, base_rows // step * step)
        horiz: dict[int, np.ndarray] = {}
        for r0 in range(0, height, rows):  # loop over bands of rows, not texels
            work = to_work(src[r0:r0 + rows])
            count = work.shape[0]
            for i in integer:
                w, h = sizes[i]
                ry = height // h
                part = _resize_area(work, (w, count // ry))
                if outs[i] is None:
                    outs[i] = np.empty((h, w, part.shape[2]), part.dtype)
                outs[i][r0 // ry:r0 // ry + part.shape[0]] = part
            if gathered:
                work32 = work.astype(np.float32, copy=False)
                for i in gathered:
                    part = _horizontal_area(work32, sizes[i][0])
                    if i not in horiz:
                        horiz[i] = np.empty((height,) + part.shape[1:], np.float32)
                    horiz[i][r0:r0 + count] = part
        for i in gathered:
            w, h = sizes[i]
            part = _weighted_sum(horiz.pop(i), 0, *_area_table(height, h))
            if work.dtype == np.uint16:  # as in _level_from_source0
                np.clip(np.rint(part), 0, 65535, out=part)
            outs[i] = part.astype(work.dtype, copy=False)
    for i, size in enumerate(sizes):
        if outs[i] is None:
            outs[i] = _level_from_source0(src, to_work, size)
    return outs


def _chain_dropping(src: np.ndarray, to_work, sizes: list[tuple[int, int]], first: int) -> list[np.ndarray | None]:
    """``_chain(to_work(src), sizes)`` for levels ``first`` (>= 1) and below, ``None`` above:
    the same arrays, computed without ``to_work(src)`` whole (see above). Dropped levels other
    than level 0 are computed only when a kept level is filtered from them, and freed after."""
    n = len(sizes)
    source = {k: _source_index(sizes, k) for k in range(1, n)}
    needed = set(range(first, n))
    for k in range(n - 1, 0, -1):
        if k in needed and source[k]:
            needed.add(source[k])
    last_use = {source[k]: k for k in sorted(needed) if source[k]}
    works: list[np.ndarray | None] = [None] * n
    from0 = [k for k in sorted(needed) if source[k] == 0]
    for k, work in zip(from0, _levels_from_source0(src, to_work, [sizes[k] for k in from0])):
        works[k] = work
    for k in sorted(needed):
        j = source[k]
        if j == 0:
            continue
        works[k] = _resize_area(works[j], sizes[k])
        if 0 < j < first and last_use[j] == k:
            works[j] = None
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
        hist = _channel_histograms(lv).astype(np.float64)
        m = [float(hist[c] @ tables[c]) / n for c in range(4)]
        means.append(np.asarray(m))
    return means


@njit(cache=True, nogil=True)
def _channel_histograms(lv):
    """(4, 256) int64: the 256-bin histogram of each channel of (H, W, 4) uint8 ``lv``, in one
    pass (OpenCV's calcHist took one call a channel, 4-20x this on the small levels of a chain,
    1.2-1.5x on the large; its float32 counts are exact below 2^24 a bin, these at any size)."""
    h = np.zeros((4, 256), np.int64)
    for y in range(lv.shape[0]):
        for x in range(lv.shape[1]):
            for c in range(4):
                h[c, lv[y, x, c]] += 1
    return h


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
_GATHER_MIN_BYTES = 1 << 24  # a fractional level's horizontal pass is kept whole up to max(this, source/8)


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


def _colour_chain(rgba: np.ndarray, srgb: bool, sizes, opaque: bool,
                  first: int = 0) -> tuple[list[np.ndarray | None], np.ndarray | None]:
    """Levels and level 0's linear mean per channel (in 1/255 units). ``first`` > 0: levels
    above it are dropped (``None``; no mean), level 0's 16-bit copy is never made whole."""
    if first:
        works = _chain_dropping(rgba, lambda band: _to_work16(band, srgb), sizes, first)
        return [None] * first + [_encode_work16(w, srgb, opaque) for w in works[first:]], None
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


def _premultiply(w16: np.ndarray) -> np.ndarray:
    """uint16 working RGBA (h, w, 4) -> float32 linear (R*A, G*A, B*A, A), alpha in [0, 1]."""
    lin = w16.astype(np.float32) * np.float32(1.0 / 65535.0)  # (H, W, 4) linear, alpha in [0, 1]
    a = lin[..., 3:4]
    pre = np.empty_like(lin)
    np.multiply(lin[..., :3], a, out=pre[..., :3])
    pre[..., 3:4] = a
    return pre


@njit(cache=True, nogil=True)
def _premultiply_rows(rgba, colour16):
    """uint8 RGBA rows (n, 4) -> (float32 (n, 4) linear (R*A, G*A, B*A, A), uint16 (n, 3) linear
    colour): :func:`_premultiply` of :func:`_to_work16` and the working colour, in one pass,
    bit for bit (``colour16``: (256,) uint16, the colour channels' table; alpha is x 257)."""
    n = rgba.shape[0]
    pre = np.empty((n, 4), np.float32)
    straight = np.empty((n, 3), np.uint16)
    inv = np.float32(1.0 / 65535.0)
    for i in range(n):
        a = np.float32(np.uint16(rgba[i, 3]) * np.uint16(257)) * inv
        for c in range(3):
            w = colour16[rgba[i, c]]
            straight[i, c] = w
            pre[i, c] = (np.float32(w) * inv) * a
        pre[i, 3] = a
    return pre, straight


@njit(cache=True, nogil=True)
def _unpremultiply_rows(pre, straight, scale, srgb8):
    """One level of :func:`_premultiplied_chain`, compiled: float32 (n, 4) premultiplied rows and
    uint16 (n, 3) straight colour -> uint8 (n, 4) colour (``srgb8``: (65536,) uint8, the encoding
    table: sRGB, or linear for a role stored linear) and alpha x ``scale`` (float32; 1:
    unscaled), each rounded as the numpy expressions it replaced, bit for bit: colour = rint(clip(pre / alpha, 0, 1) x 65535), the
    straight colour where alpha <= 0.5 / 65535; alpha rint(clip(alpha x scale, 0, 1) x 255)."""
    n = pre.shape[0]
    out = np.empty((n, 4), np.uint8)
    empty = np.float32(0.5 / 65535.0)
    zero, one, top16, top8 = np.float32(0.0), np.float32(1.0), np.float32(65535.0), np.float32(255.0)
    for i in range(n):
        a = pre[i, 3]
        if a <= empty:
            for c in range(3):
                out[i, c] = srgb8[straight[i, c]]
        else:
            for c in range(3):
                v = pre[i, c] / a
                out[i, c] = srgb8[np.uint16(np.rint(min(max(v, zero), one) * top16))]
        out[i, 3] = np.uint8(np.rint(min(max(a * scale, zero), one) * top8))
    return out


def _premultiplied_chain(rgba: np.ndarray, srgb: bool, sizes, alpha_mode: str, alpha_cutoff: float,
                         first: int = 0) -> tuple[list[np.ndarray | None], tuple[float | None, ...] | None]:
    """Alpha-weighted colour filtering (float32), alpha linear, optional coverage scaling.
    ``first`` > 0: levels above it are dropped (``None``), level 0's working copies (float32
    and 16-bit) are never made whole."""
    if first:  # (level 0 is dropped: its working copies are made band by band, never whole)
        pres = _chain_dropping(rgba, lambda band: _premultiply(_to_work16(band, srgb)), sizes, first)
        straights = _chain_dropping(rgba, lambda band: _to_work16(band, srgb)[..., :3].copy(), sizes, first)
        alpha0 = rgba[..., 3] if rgba.dtype == np.uint8 else _u16_to_u8(np.ascontiguousarray(rgba[..., 3]))
        level0 = None
    elif rgba.dtype == np.uint8:
        h0, w0 = rgba.shape[:2]
        pre0, straight0 = _premultiply_rows(rgba.reshape(-1, 4), _LIN16_FROM_SRGB8 if srgb else _ID16_FROM_8)
        pres = _chain(pre0.reshape(h0, w0, 4), sizes)  # premultiplied colour + alpha
        straights = _chain(straight0.reshape(h0, w0, 3), sizes)  # unweighted colour for fully transparent texels
        level0 = rgba.view()
        alpha0 = level0[..., 3]
    else:
        w16 = _to_work16(rgba, srgb)
        pres = _chain(_premultiply(w16), sizes)          # premultiplied colour + alpha
        straights = _chain(w16[..., :3].copy(), sizes)  # unweighted colour for fully transparent texels
        level0 = rgba.view() if rgba.dtype == np.uint8 else _u16_to_u8(rgba)
        alpha0 = level0[..., 3]

    cutoff8 = None
    coverage: list[float | None] | None = None
    target = 0.0
    if alpha_mode == "MASK":
        cutoff8 = _cutoff_threshold8(alpha_cutoff)
        target = float(np.count_nonzero(alpha0 >= cutoff8)) / alpha0.size
        coverage = [target]
    out: list[np.ndarray | None] = [level0]
    for pre_k, straight_k in zip(pres[1:], straights[1:]):
        if pre_k is None:  # dropped
            out.append(None)
            if coverage is not None:
                coverage.append(None)
            continue
        alpha = pre_k[..., 3]
        scale = np.float32(1.0)
        if cutoff8 is not None:
            scale = _coverage_scale(alpha, target, cutoff8)
        lv = _unpremultiply_rows(np.ascontiguousarray(pre_k).reshape(-1, 4),
                                 np.ascontiguousarray(straight_k).reshape(-1, 3), scale,
                                 _SRGB8_FROM_LIN16 if srgb else _LIN8_FROM_LIN16).reshape(alpha.shape + (4,))
        if coverage is not None:
            coverage.append(float(np.count_nonzero(lv[..., 3] >= cutoff8)) / alpha.size)
        out.append(lv)
    return out, (tuple(coverage) if coverage is not None else None)


def _cutoff_threshold8(alpha_cutoff: float) -> int:
    """The smallest 8-bit alpha that passes ``alpha >= cutoff`` (alpha = a8 / 255)."""
    return int(min(256, max(0, math.ceil(alpha_cutoff * 255.0 - 1e-9))))


def _coverage_scale(alpha: np.ndarray, target: float, cutoff8: int) -> np.float32:
    """The float32 factor that scales ``alpha`` (h, w) float32 in [0, 1] so that the fraction of
    texels whose rounded 8-bit value is >= ``cutoff8`` is as close as possible to ``target``
    (1: unscaled).

    A texel passes when ``rint(alpha * s * 255) >= cutoff8``, i.e. ``alpha >= t / s`` with
    ``t = (cutoff8 - 0.5) / 255``; coverage is monotone in ``s``, so the best ``s`` puts the
    threshold just at or below the k-th largest alpha, k = round(target * N): an order
    statistic (``np.partition``), the fixed point of a binary search on ``s``.
    """
    n = alpha.size
    if cutoff8 <= 0 or cutoff8 > 255 or target <= 0.0 or target >= 1.0 or n == 0:
        return np.float32(1.0)
    k = int(round(target * n))
    flat = alpha.reshape(-1)
    if k <= 0:
        kth = float(flat.max())
        if kth <= 0.0:
            return np.float32(1.0)
        thr = (cutoff8 - 0.5) / 255.0
        return np.float32(thr / kth * (1.0 - 1e-6))  # everything just below the threshold
    kth = float(np.partition(flat, n - k)[n - k])  # the k-th largest
    if kth <= 0.0:
        return np.float32(1.0)  # coverage cannot be raised by scaling zeros
    thr = (cutoff8 - 0.5) / 255.0
    return np.float32(thr / kth * (1.0 + 1e-6))  # kth (and all above it) pass


def normal_unit_levels(rgba: np.ndarray, first: int = 0) -> list[np.ndarray | None]:
    """The renormalised vectors of every level of a normal map, before 8-bit quantisation.

    ``rgba``: ``(H, W, 4)`` uint8 or uint16; returns ``[(h, w, 4) float32, ...]``, xyz unit
    length (a zero mean becomes +Z), w = linear alpha in [0, 1]. :func:`build_mip_chain`
    stores ``rint((xyz + 1) * 127.5)``. ``first`` > 0: levels above it are ``None`` (dropped;
    the same values below, computed without level 0's float32 vectors whole).
    """
    height, width = rgba.shape[:2]
    # The unnormalised means are carried down the chain (the exact area average of level 0's
    # vectors); each level is normalised only for output.
    if first:
        works = _chain_dropping(rgba, _normal_vectors, mip_sizes(width, height), first)
        return [None] * first + [_unit(w) for w in works[first:]]
    return [_unit(w) for w in _chain(_normal_vectors(rgba), mip_sizes(width, height))]


def _normal_vectors(rgba: np.ndarray) -> np.ndarray:
    """Encoded normal texels (h, w, 4) uint8/uint16 -> float32 (x, y, z, alpha) in [-1, 1] / [0, 1]."""
    if rgba.dtype == np.uint8:
        table = np.arange(256, dtype=np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
        return cv2.LUT(rgba, np.stack([table, table, table, np.arange(256, dtype=np.float32) / 255.0],
                                      axis=-1).reshape(1, 256, 4))
    vec = rgba.astype(np.float32) * np.float32(1.0 / 65535.0)
    vec[..., :3] = vec[..., :3] * 2.0 - 1.0
    return vec


def _unit(w: np.ndarray) -> np.ndarray:
    """(h, w, 4) float32 (x, y, z, alpha) -> xyz divided by its length (float32; a length at
    most 1e-12 becomes +Z), alpha kept. Compiled (:func:`_unit_rows`): the numpy expression it
    replaced, ``xyz / sqrt(einsum(xyz, xyz))``, took 0.51 s of the corpus's texture CPU;
    tests/test_texture_mips.py holds the two equal, bit for bit."""
    w = np.ascontiguousarray(w, np.float32)
    return _unit_rows(w.reshape(-1, 4)).reshape(w.shape)


def _encode_normals(u: np.ndarray) -> np.ndarray:
    """(h, w, 4) float32 unit vectors + alpha -> uint8 RGBA (round to nearest):
    ``rint(clip((xyz + 1) * 127.5, 0, 255))``, ``rint(clip(alpha, 0, 1) * 255)`` in float32
    (compiled: :func:`_encode_rows`)."""
    u = np.ascontiguousarray(u, np.float32)
    return _encode_rows(u.reshape(-1, 4)).reshape(u.shape[:2] + (4,))


@njit(cache=True, nogil=True)
def _unit_rows(w):
    out = np.empty_like(w)
    tiny = np.float32(1e-12)
    for i in range(w.shape[0]):
        x, y, z = w[i, 0], w[i, 1], w[i, 2]
        length = np.sqrt(x * x + y * y + z * z)
        if length > tiny:
            out[i, 0], out[i, 1], out[i, 2] = x / length, y / length, z / length
        else:
            out[i, 0], out[i, 1], out[i, 2] = np.float32(0.0), np.float32(0.0), np.float32(1.0)
        out[i, 3] = w[i, 3]
    return out


@njit(cache=True, nogil=True)
def _encode_rows(u):
    out = np.empty(u.shape, np.uint8)
    one, half, top, zero = np.float32(1.0), np.float32(127.5), np.float32(255.0), np.float32(0.0)
    for i in range(u.shape[0]):
        for c in range(3):
            out[i, c] = np.uint8(np.rint(min(max((u[i, c] + one) * half, zero), top)))
        out[i, 3] = np.uint8(np.rint(min(max(u[i, 3], zero), one) * top))
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
    # top levels dropped for max_size: never filtered whole (only the levels kept, and the
    # levels they are filtered from, are computed; see _chain_dropping)
    dropped = 0
    if options.max_size is not None:
        while dropped < len(sizes) - 1 and max(sizes[dropped]) > options.max_size:
            dropped += 1

    alpha_weighted = False
    coverage = None
    mean0 = None
    if role == ROLE_NORMAL:
        levels = [None if u is None else _encode_normals(u) for u in normal_unit_levels(rgba, dropped)]
    else:
        has_alpha = _any_alpha_below_max(rgba)
        if role == ROLE_BASE_COLOR and has_alpha:
            alpha_weighted = True
            levels, coverage = _premultiplied_chain(rgba, srgb, sizes, alpha_mode, alpha_cutoff, dropped)
        else:  # opaque colour, emissive, metallicRoughness, occlusion
            levels, mean0 = _colour_chain(rgba, srgb, sizes, opaque=not has_alpha, first=dropped)
    if role == ROLE_BASE_COLOR and alpha_mode == "MASK" and coverage is None:
        # fully opaque texture: every texel passes at every level
        coverage = tuple(1.0 if alpha_cutoff <= 1.0 else 0.0 for _ in levels)

    if dropped:
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
