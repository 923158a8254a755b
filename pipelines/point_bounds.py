"""The box and bounding sphere of a point set, in one compiled pass (no float64 copy).

:func:`assetpipe.format.bounds_of` reported each mesh's box and the sphere about its centre from
a float64 copy of the positions and two more arrays of that size (``p - c`` and its squares):
0.22 s of a 1.7 s build of MetalRoughSpheresNoTextures (99 meshes, 20 MB of vertices). Here the
float32 rows (any strides) are read once for the box and once for the radius, with the same
float64 arithmetic in the same order: the same values, bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def box_and_radius2(p):
    """(lo (3,) float64, hi (3,) float64, the largest squared distance from the box's centre
    ``(lo + hi) * 0.5``, the count of non-finite coordinates) of ``p`` (N >= 1, >= 3) rows,
    columns 0-2. Each squared distance is ``(dx * dx + dz * dz) + dy * dy`` in float64: the
    order in which numpy 2.4's ``einsum("ij,ij->i", d, d)`` (what this replaced) adds them here,
    on all of 3,000 random point sets (``tests/test_point_bounds.py``), so the written radii stay
    as they were. Where the count is not 0 the values are not numpy's (NaN propagates there):
    the caller computes them the numpy way instead."""
    n = p.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    bad = 0
    for j in range(3):
        lo[j] = np.float64(p[0, j])
        hi[j] = lo[j]
    for i in range(n):
        for j in range(3):
            x = np.float64(p[i, j])
            if not np.isfinite(x):
                bad += 1
            if x < lo[j]:
                lo[j] = x
            if x > hi[j]:
                hi[j] = x
    cx, cy, cz = (lo[0] + hi[0]) * 0.5, (lo[1] + hi[1]) * 0.5, (lo[2] + hi[2]) * 0.5
    m = 0.0
    for i in range(n):
        dx = np.float64(p[i, 0]) - cx
        dy = np.float64(p[i, 1]) - cy
        dz = np.float64(p[i, 2]) - cz
        s = (dx * dx + dz * dz) + dy * dy
        if s > m:
            m = s
    return lo, hi, m, bad


__all__ = ["box_and_radius2"]
