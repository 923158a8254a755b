"""Which mip levels of a texture a set of shaded renders can sample, from the geometry alone.

Why: a 256 px picture of a model with 4096^2 textures samples levels about 4 and coarser; the
finer levels hold 99.6% of the texels, and uploading them (the build's KTX2 chains and the
reference's chains) was 2.0 of 5.0 s of a model with three 4096^2 textures. The renderer uploads
a texture from its first level a render can sample (:func:`first_sampled_level`); level ``k`` of
what is uploaded is then level ``k + L`` of the chain, the sampler's level of detail is computed
from the uploaded size, so the same texels are fetched with the same weights as with the whole
chain, as long as both sides of level 0 divide by ``2^L`` (else fewer levels are left out).
Measured (both uploads of the same model rendered by the same views): every textured corpus
model, build and source, at 256, 128, 64 and 32 px: identical, bit for bit; a generated sphere
with three 4096^2 textures: identical at 256, 200, 160, 96 and 64 px, and at 128 px one pixel of
16,384 differed by one code in one channel (rounding inside lavapipe's sampler; it did so with
one level left out where the bound allowed two, so it is not a level the bound should have
kept). tests/test_texture_levels.py holds pictures to at most one code at 0.1% of pixels.

The bound. Vulkan selects the level from ``lambda = log2(rho)``, ``rho`` the larger of the two
screen-axis footprints of a pixel in texels, each at least the larger component of its axis
(the approximations the specification allows, e.g. ``max(|du/dx|, |dv/dx|)``), so at least
``1/sqrt(2)`` of the axis length; the product of the two axis lengths is at least ``|det J|``,
``J`` the Jacobian of texel coordinates by pixel coordinates. Hence ``rho >= sqrt(|det J| / 2)``.
On a triangle the texture map is affine in *surface* terms: ``|det J|`` is the triangle's texel
area over its world area, times world area per screen area at the point. A pinhole camera with
focal length ``f`` pixels maps a surface element at view depth ``z`` to at most
``f^2 / (z^2 cos(alpha))`` its area on screen (``alpha``: the ray's angle off the axis, at most
the corner ray's). So on every pixel of the triangle

    lambda >= 0.5 * log2( texel_area / world_area * z_min^2 * cos(alpha_max) / f^2 ) - 0.5,

``z_min`` its nearest corner's depth (depth is linear over it). The finest level a trilinear or
nearest-mipmap filter can touch is ``floor(lambda)`` (nearest-mipmap rounds up from there);
half a level more is kept (:data:`MARGIN_LEVELS`) for the rasteriser's rounding. Triangles
with no texel area (collapsed UVs), crossing the eye's plane, or a filter without mipmaps give 0
(everything uploaded).
"""

from __future__ import annotations

import math

import numpy as np

#: levels of detail kept finer than the bound: rounding of the level of detail, derivatives taken
#: over 2x2 pixel quads (helper pixels extend a triangle's plane by a pixel). The bound's own
#: slack comes on top: half a level for the sqrt(2) of the footprint, and the corner ray's
#: cosine and the nearest corner's depth taken for every pixel of the triangle
MARGIN_LEVELS = 0.5
_NO_MIPMAP_FILTERS = (9728, 9729)  # glTF NEAREST / LINEAR minification: level 0 only


def first_sampled_level(positions: np.ndarray, uvs: np.ndarray, triangles: np.ndarray,
                        size: tuple[int, int], cams: list, levels: int,
                        min_filter: int | None = None) -> int:
    """The first level of a ``levels``-level chain that shaded renders by ``cams`` can sample.

    positions ``(N, 3)`` float (the frame the cameras see), uvs ``(N, 2)`` float (the set the
    texture is sampled with, texture units), triangles ``(M, 3)`` int (every triangle drawn with
    the texture), ``size`` level 0's (width, height) in texels. Returns 0 when nothing can be
    bounded (see the module docstring)."""
    if levels <= 1 or not cams or min_filter in _NO_MIPMAP_FILTERS:
        return 0
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    if tri.shape[0] == 0:
        return 0
    p = np.asarray(positions, np.float64)[tri]        # (M, 3, 3)
    t = np.asarray(uvs, np.float64)[tri]              # (M, 3, 2)
    world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    texel = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * float(size[0]) * float(size[1])
    drawn = world > 0  # zero-area triangles cover no pixel
    if not drawn.any():
        return 0
    if not (np.isfinite(texel[drawn]).all() and np.isfinite(world[drawn]).all()):
        return 0
    density = texel[drawn] / world[drawn]             # texels per world area
    if not density.min() > 0:
        return 0
    best = math.inf
    hp = np.c_[p[drawn].reshape(-1, 3), np.ones(3 * int(drawn.sum()))]
    for cam in cams:
        view = np.asarray(cam.view, np.float64)
        z = -(hp @ view[2]).reshape(-1, 3).min(axis=1)  # depth along the view axis, nearest corner
        if not z.min() > 0:
            return 0  # a triangle reaches the eye's plane: no bound
        tan_y = math.tan(math.radians(cam.fov_y_deg) / 2.0)
        f = (cam.height / 2.0) / tan_y
        tan_x = tan_y * cam.width / cam.height
        cos_max = 1.0 / math.sqrt(1.0 + tan_x * tan_x + tan_y * tan_y)
        det = density * z * z * cos_max / (f * f)
        best = min(best, 0.5 * math.log2(float(det.min())) - 0.5)
    if not math.isfinite(best):
        return 0
    first = int(min(max(math.floor(best - MARGIN_LEVELS), 0), levels - 1))
    # the level of detail is computed from the uploaded level's size: that is level 0's over
    # 2^first only while both sides divide (a 211-texel side has a 105-texel level 1, not 105.5:
    # the trilinear weights would move; seen at 64 px on BoxTexturedNonPowerOfTwo)
    while first and (int(size[0]) % (1 << first) or int(size[1]) % (1 << first)):
        first -= 1
    return first
