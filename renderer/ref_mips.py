"""Mip chains for the *source* reference's images, made independently of the build's mip step.

The build samples its KTX2 mip chains; a reference drawn from level 0 alone aliases where the
build filters (a 2048^2 texture on a 256 px picture), and that aliasing, not a fault, set the
shaded colour tolerance. The reference therefore gets a chain too, made here with OpenCV's area
filter (each level the area mean of the one above, as glTF viewers and the build filter):

* colour roles (base colour, emissive; sRGB): averaged in linear light, alpha linearly,
* data roles (metallic-roughness, occlusion): averaged as stored,
* normal maps: codes averaged (the mean of ``2c/255 - 1`` is ``2 mean(c)/255 - 1``), the vectors
  renormalised.

Every level is averaged from the previous one in 16-bit (0.004 of an 8-bit code per step), then
rounded to 8 bits once. Shapes: (H, W, 4) uint8 in, a list of (h_k, w_k, 4) uint8 out, level 0
first, down to 1x1 (``max(1, size >> k)``, the KTX2 rule).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_CODES = np.arange(256, dtype=np.float64) / 255.0
# 8-bit sRGB code -> 16-bit linear value, and 16-bit linear -> nearest 8-bit sRGB code
SRGB8_TO_LIN16 = np.rint(np.where(_CODES <= 0.04045, _CODES / 12.92, ((_CODES + 0.055) / 1.055) ** 2.4)
                         * 65535).astype(np.uint16)
_LIN = np.arange(65536, dtype=np.float64) / 65535.0
LIN16_TO_SRGB8 = np.rint(np.where(_LIN <= 0.0031308, _LIN * 12.92, 1.055 * _LIN ** (1 / 2.4) - 0.055)
                         * 255).clip(0, 255).astype(np.uint8)
LINEAR8_TO_16 = (np.arange(256) * 257).astype(np.uint16)
COLOUR_ROLES = ("baseColor", "emissive")
_COLOUR_TABLE = np.stack([SRGB8_TO_LIN16] * 3 + [LINEAR8_TO_16], -1).reshape(1, 256, 4)
_DATA_TABLE = np.stack([LINEAR8_TO_16] * 4, -1).reshape(1, 256, 4)


def level_count(width: int, height: int) -> int:
    """Levels of a full chain: down to 1x1."""
    return int(max(width, height)).bit_length()


def mip_chain(rgba: np.ndarray, role: str) -> list[np.ndarray]:
    """The full chain of ``rgba`` (H, W, 4) uint8 for ``role`` (see the module's rules)."""
    import cv2  # noqa: PLC0415

    rgba = np.ascontiguousarray(rgba, np.uint8)
    h, w = rgba.shape[:2]
    n = level_count(w, h)
    if n == 1:
        return [rgba]
    # cv2.LUT with a 16-bit table: 3x faster than numpy indexing on a 2048^2 image (0.05 s, not 0.16)
    wide = cv2.LUT(rgba, _COLOUR_TABLE if role in COLOUR_ROLES else _DATA_TABLE)
    out = [rgba]
    cur = wide
    for k in range(1, n):
        size = (max(1, w >> k), max(1, h >> k))
        cur = cv2.resize(cur, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], 4)
        if role in COLOUR_ROLES:
            lv = _colour8(cur.reshape(-1, 4), LIN16_TO_SRGB8).reshape(cur.shape)
        elif role == "normal":
            lv = _normal8(cur.reshape(-1, 4)).reshape(cur.shape)
        else:
            lv = _data8(cur.reshape(-1)).reshape(cur.shape)
        out.append(np.ascontiguousarray(lv))
    return out


# The per-texel rounding of a level, compiled (numba): the numpy expressions they replace, in
# the same float arithmetic, took 21 ms (colour) and 90 ms (normal) for a 1024^2 level.
# tests/test_ref_mips.py holds them equal, bit for bit, to those expressions.

@njit(cache=True, nogil=True, inline="always")
def _div257(x):
    """``rint(x / 257)`` of a uint16 in integers: ``x / 257`` is never a half (257 is odd), so
    the nearest integer is ``floor((2x + 257) / 514)`` exactly."""
    return np.uint8((np.int64(x) * 2 + 257) // 514)


@njit(cache=True, nogil=True)
def _colour8(cur, table):
    """(P, 4) uint16 linear -> (P, 4) uint8: rgb the nearest sRGB code, alpha rint(a / 257)
    (:func:`_div257`)."""
    out = np.empty(cur.shape, np.uint8)
    for i in range(cur.shape[0]):
        for c in range(3):
            out[i, c] = table[cur[i, c]]
        out[i, 3] = _div257(cur[i, 3])
    return out


@njit(cache=True, nogil=True)
def _data8(cur):
    """(P,) uint16 -> (P,) uint8 ``rint(x / 257)`` (:func:`_div257`). The numpy expression took
    0.3 s on a 2048^2 level (float64 temporaries)."""
    out = np.empty(cur.shape, np.uint8)
    for i in range(cur.shape[0]):
        out[i] = _div257(cur[i])
    return out


@njit(cache=True, nogil=True)
def _normal8(cur):
    """(P, 4) uint16 averaged codes -> (P, 4) uint8: the vector renormalised (float32), coded
    ``rint((v + 1) * 127.5)``; alpha rint(a / 257) (:func:`_div257`)."""
    out = np.empty(cur.shape, np.uint8)
    scale = np.float32(2 / 65535)
    one = np.float32(1.0)
    half = np.float32(127.5)
    tiny = np.float32(1e-12)
    v = np.empty(3, np.float32)
    for i in range(cur.shape[0]):
        for c in range(3):
            v[c] = np.float32(cur[i, c]) * scale - one
        n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if n < tiny:
            n = tiny
        for c in range(3):
            q = np.rint((v[c] / n + one) * half)
            out[i, c] = np.uint8(min(max(q, np.float32(0.0)), np.float32(255.0)))
        out[i, 3] = _div257(cur[i, 3])
    return out


def warm() -> None:
    """Load (or compile, the first time) the kernels: part of a renderer process's set-up."""
    tiny = np.zeros((1, 4), np.uint16)
    _colour8(tiny, LIN16_TO_SRGB8)
    _normal8(tiny)
    _data8(tiny.reshape(-1))
