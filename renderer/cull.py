"""The triangles of a render that can cover a pixel: the others are left out of the draw.

lavapipe's cost for a model of many small triangles is per triangle (vertex shading, clipping and
set-up), whatever the picture's size: MetalRoughSpheresNoTextures (1.04M triangles) cost about
as much at 64 px as at 512 px. A single-sampled render covers a pixel only where the pixel's
centre lies inside a triangle (Vulkan's rasterisation rule), so a triangle whose projected box
holds no pixel centre of the image writes nothing: no colour, no depth, no blending, and no
fragment quad whose derivatives another fragment could read. Drawing only the others gives the
same picture, bit for bit (:func:`cull` keeps every triangle it cannot prove empty: one with a
corner behind the eye, or whose box reaches a pixel centre within the rounding margin below).
At 256 px that model keeps about 11% of its triangles, at 64 px under 1%.

The margin: the GPU transforms the float32 positions in float32 and snaps the result to
lavapipe's sub-pixel grid (1/256 px); the kernel projects the same float32 positions in
float64. A float32 ``clip = M @ [p, 1]`` errs by at most 4u of the magnitudes of its terms
(``|M| @ [|p|, 1]``, u = 2^-24, first order), and ``x / w`` adds ``|x / w|`` times w's relative
error; the kernel bounds both for every vertex at once (the largest ``|p|`` per axis, the smallest
w, the largest ``|x / w|``), takes 16u instead of 4u and doubles it, and adds a full sub-pixel
step and 4 ulps of the picture size (the viewport transform). A model far from the origin
(large ``|p|``, small picture) gets a wide margin and keeps more triangles: nothing is dropped
on a rounding guess.

Compiled with numba (a dependency already, for pipelines/distance_kernels.py): the same test in
numpy cost 50-80 ms a render of that model, a third more than the lavapipe time it saved; the
kernel takes a few milliseconds. Compiled on first use and cached beside this file; the renderer
worker loads it while it sets up (:func:`warm`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# a draw list with fewer triangles than this is drawn whole: the test and what it could save are
# then a few milliseconds (the kernel takes about 10-30 ns a triangle, lavapipe 100-200 ns)
CULL_MIN_TRIANGLES = 1 << 16
_U = 2.0 ** -24       # float32 unit roundoff
_GAMMA = 16 * _U      # a float32 mat4 x vec4 and the division by w, with room (see above)
_SNAP_PX = 1.0 / 256  # lavapipe's sub-pixel step (8 bits of fixed point)


@njit(cache=True, nogil=True)
def _cull(pt, m, extent, width, height, indices, draws, out, counts):  # pragma: no cover - compiled
    n = pt.shape[1]
    px = np.empty(n)
    py = np.empty(n)
    front = np.empty(n, np.bool_)
    w_min = np.inf
    ndc_max = 0.0
    hw, hh = 0.5 * width, 0.5 * height
    for i in range(n):
        p0, p1, p2 = float(pt[0, i]), float(pt[1, i]), float(pt[2, i])
        w = m[3, 0] * p0 + m[3, 1] * p1 + m[3, 2] * p2 + m[3, 3]
        front[i] = w > 0.0
        if w > 0.0:
            x = (m[0, 0] * p0 + m[0, 1] * p1 + m[0, 2] * p2 + m[0, 3]) / w
            y = (m[1, 0] * p0 + m[1, 1] * p1 + m[1, 2] * p2 + m[1, 3]) / w
            w_min = min(w_min, w)
            ndc_max = max(ndc_max, abs(x), abs(y))
            px[i] = (x + 1.0) * hw
            py[i] = (y + 1.0) * hh
    size = max(width, height)
    mag = np.zeros(4)
    for r in range(4):
        mag[r] = abs(m[r, 3])
        for c in range(3):
            mag[r] += abs(m[r, c]) * extent[c]
    margin = _SNAP_PX + 4.0 * _U * size
    if w_min < np.inf:
        margin += 2.0 * _GAMMA * (max(mag[0], mag[1]) + ndc_max * mag[3]) / w_min * 0.5 * size
    # per vertex (lo_x, hi_x, lo_y, hi_y): the first pixel centre (k + 0.5) at or after p - margin
    # and the last at or before p + margin, clamped to the picture; a corner behind the eye spans it all
    box = np.empty((n, 4), np.int16)
    lo_off, hi_off = margin + 0.5, margin - 0.5
    for i in range(n):
        if front[i]:
            box[i, 0] = int(min(max(math.ceil(px[i] - lo_off), 0.0), float(width)))
            box[i, 1] = int(min(max(math.floor(px[i] + hi_off), -1.0), float(width - 1)))
            box[i, 2] = int(min(max(math.ceil(py[i] - lo_off), 0.0), float(height)))
            box[i, 3] = int(min(max(math.floor(py[i] + hi_off), -1.0), float(height - 1)))
        else:
            box[i, 0], box[i, 1], box[i, 2], box[i, 3] = 0, width - 1, 0, height - 1
    k = 0
    for d in range(draws.shape[0]):
        k0 = k
        first, count, base = draws[d, 0], draws[d, 1], draws[d, 2]
        for i in range(first, first + count - 2, 3):
            ia, ib, ic = indices[i], indices[i + 1], indices[i + 2]
            a, b, c = ia + base, ib + base, ic + base
            if (min(box[a, 0], box[b, 0], box[c, 0]) <= max(box[a, 1], box[b, 1], box[c, 1])
                    and min(box[a, 2], box[b, 2], box[c, 2]) <= max(box[a, 3], box[b, 3], box[c, 3])):
                out[k], out[k + 1], out[k + 2] = ia, ib, ic
                k += 3
        counts[d] = k - k0
    return k


class Projector:
    """A model's vertex buffer positions, prepared once for :func:`cull`."""

    def __init__(self, positions: np.ndarray) -> None:
        self.pt = np.ascontiguousarray(np.asarray(positions, np.float32).T)  # (3, N), as the GPU reads them
        self.finite = bool(np.isfinite(self.pt).all())
        self.extent = np.abs(self.pt).max(axis=1).astype(np.float64) if self.pt.size else np.zeros(3)


def cull(proj: Projector, indices: np.ndarray, draws: np.ndarray, view_proj: np.ndarray, width: int,
         height: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of ``draws`` that may cover a pixel centre of a ``width`` x ``height`` picture.

    ``indices`` (M,) uint32: the index buffer; ``draws`` (D, 3) int64: per draw its first index,
    index count (whole triangles) and vertex offset (the indices are local to it); ``view_proj``
    (4, 4) the camera's (row-major, Vulkan clip space; the viewport maps NDC -1..1 to 0..width
    and 0..height). Returns (the kept triangles' indices (K,) uint32 in draw order, indices kept
    per draw (D,) int64). Every triangle is kept when a position is not finite."""
    if not 0 < width <= 16384 or not 0 < height <= 16384:
        raise ValueError(f"picture size {width}x{height} out of range")
    draws = np.ascontiguousarray(draws, np.int64).reshape(-1, 3)
    if not proj.finite:
        return np.concatenate([indices[f:f + n] for f, n, _ in draws] or [indices[:0]]), draws[:, 1].copy()
    out = np.empty(int(draws[:, 1].sum()), np.uint32)
    counts = np.zeros(len(draws), np.int64)
    k = _cull(proj.pt, np.ascontiguousarray(view_proj, np.float64), proj.extent, int(width), int(height),
              np.ascontiguousarray(indices, np.uint32), draws, out, counts)
    return out[:k], counts


def warm() -> None:
    """Load (or compile, the first time) the kernel: part of a renderer process's set-up."""
    p = Projector(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32))
    cull(p, np.array([0, 1, 2], np.uint32), np.array([[0, 3, 0]]), np.eye(4), 4, 4)
