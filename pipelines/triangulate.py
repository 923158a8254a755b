"""Polygon triangulation: vectorised for convex polygons and quads, earcut for the rest.

Every function works on polygon *corners* and returns corner numbers (0..n-1) rather than
vertex indices, so a caller can map the triangles onto whatever per-corner data it has
(OBJ position/uv/normal triples, glTF vertices, ...).

Precision: each polygon is moved to a local frame centred on its own centroid and its
normal is computed there with Newell's method in float64, so polygons far from the origin
(coordinates ~1e4 and more, e.g. tinyobjloader issue 295) are measured as precisely as
polygons at the origin. The polygon is then projected onto the plane of that normal, and
the triangles keep the polygon's winding (counter-clockwise around the Newell normal).

Concave polygons go through ``mapbox_earcut`` (the C++ port of Mapbox's earcut, z-order
hashed: a 2,000-corner face takes about a millisecond where the former pure-Python ear clipper
took 28 s, issue #13). When earcut cannot triangulate a polygon whole (self-intersecting or
degenerate input, where it returns fewer than ``n - 2`` triangles), small polygons fall back to
:func:`ear_clip` and larger ones to a fan, so the work is bounded for any input.

Degenerate polygons (zero area, collinear or repeated corners) still produce ``n - 2``
triangles (some of zero area), so triangle counts only depend on the polygon sizes.
"""

from __future__ import annotations

import mapbox_earcut
import numpy as np

# A corner turns "right" (is reflex) when sin(turn angle) is below -_REFLEX_SIN: tiny
# negative turns from rounding on straight edges are not reflex.
_REFLEX_SIN = 1e-9
# Polygons earcut cannot finish whole fall back to the O(n^2..n^3) ear clipper only up to
# this many corners (about 10 ms at 64 corners); larger ones are fanned.
_EAR_CLIP_FALLBACK_MAX = 64


def newell_normals(points: np.ndarray) -> np.ndarray:
    """Newell normals of polygons, computed about each polygon's centroid.

    points: (P, n, 3) float, P polygons of n corners each.
    Returns (P, 3) float64: the (unnormalised) normal whose length is twice the polygon's
    vector area; its direction follows the polygon's winding (right-hand rule).
    """
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=1, keepdims=True)
    q = np.roll(p, -1, axis=1)
    return np.cross(p, q).sum(axis=1)


def _turns(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """sin of the turn angle at each corner, signed against the polygon normal.

    points (P, n, 3) float64 centred, normals (P, 3) unit (or zero). Returns (P, n) float64:
    positive for a left (convex) turn, negative for a right (reflex) turn, 0 when straight or
    degenerate.
    """
    e_in = points - np.roll(points, 1, axis=1)  # edge arriving at corner k
    e_out = np.roll(points, -1, axis=1) - points  # edge leaving corner k
    c = np.einsum("pkj,pj->pk", np.cross(e_in, e_out), normals)
    scale = np.linalg.norm(e_in, axis=2) * np.linalg.norm(e_out, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(scale > 0, c / np.where(scale > 0, scale, 1.0), 0.0)
    return s


def _fan(n: int) -> np.ndarray:
    """Fan triangles of an n-gon from corner 0: (n-2, 3) int64."""
    k = np.arange(n - 2, dtype=np.int64)
    return np.stack([np.zeros(n - 2, np.int64), k + 1, k + 2], axis=1)


def triangulate_polygons(points: np.ndarray) -> np.ndarray:
    """Triangulate P polygons of n corners each.

    points: (P, n, 3) float (positions of the corners, in winding order), n >= 3.
    Returns (P, n-2, 3) int64 corner numbers in [0, n). Triangles wind like their polygon.

    Triangles (n == 3) are returned as they are. Quads are fully vectorised (see
    :func:`_triangulate_quads`). Convex n-gons are fanned from corner 0 (vectorised); other
    non-convex n-gons go through :func:`triangulate_polygon` (earcut) one at a time (they are
    rare in real files).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] < 3:
        raise ValueError(f"expected (P, n>=3, 3) points, got shape {p.shape}")
    count, n = p.shape[0], p.shape[1]
    if n == 4:
        return _triangulate_quads(p)
    out = np.broadcast_to(_fan(n), (count, n - 2, 3)).copy()
    if n == 3 or count == 0:
        return out
    centred = p - p.mean(axis=1, keepdims=True)
    normals = np.cross(centred, np.roll(centred, -1, axis=1)).sum(axis=1)
    length = np.linalg.norm(normals, axis=1)
    unit = normals / np.where(length > 0, length, 1.0)[:, None]
    reflex = _turns(centred, unit) < -_REFLEX_SIN
    for i in np.flatnonzero(reflex.any(axis=1)):
        out[i] = triangulate_polygon(p[i])
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (P, 3) arrays (cheaper than np.cross for this shape)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


_SPLIT_02 = np.array([[0, 1, 2], [0, 2, 3]], np.int64)  # diagonal 0-2 (the fan from corner 0)
_SPLIT_13 = np.array([[1, 2, 3], [1, 3, 0]], np.int64)  # diagonal 1-3


def _triangulate_quads(p: np.ndarray) -> np.ndarray:
    """Split each quad along the diagonal that keeps both triangles facing the quad's normal.

    p: (P, 4, 3) float64. Returns (P, 2, 3) int64 corner numbers.

    The Newell normal of a quad is exactly the cross product of its diagonals (built from
    coordinate differences, so far-from-origin quads lose no precision). Corner k's
    triangle (k-1, k, k+1) faces against that normal exactly when k is reflex; the diagonal
    0-2 is used unless one of its triangles (corners 1 and 3) faces backwards while the 1-3
    split does better. This is the only correct split of a planar concave quad, and the
    least bad one for a twisted (non-planar) or bow-tie quad.
    """
    normal = _cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])  # (P, 3)
    n2 = np.einsum("ij,ij->i", normal, normal)
    facing = np.empty((p.shape[0], 4))
    for k in range(4):
        a, b, c = p[:, k - 1], p[:, k], p[:, (k + 1) % 4]
        facing[:, k] = np.einsum("ij,ij->i", _cross(b - a, c - b), normal)
    tol = 1e-12 * n2
    worst_02 = np.minimum(facing[:, 1], facing[:, 3])
    worst_13 = np.minimum(facing[:, 0], facing[:, 2])
    use_13 = (worst_02 < -tol) & (worst_13 > worst_02)
    return np.where(use_13[:, None, None], _SPLIT_13, _SPLIT_02)


def triangulate_polygon(points: np.ndarray) -> np.ndarray:
    """Triangulate one simple polygon (convex or concave) with earcut in its best-fit plane.

    points: (n, 3) float corner positions in winding order, n >= 3.
    Returns (n-2, 3) int64 corner numbers, wound like the polygon (counter-clockwise around
    its Newell normal). A polygon with no area, or one where no ear can be found (self-
    intersecting input), is finished with a fan so the count is always n - 2.
    """
    p = np.asarray(points, dtype=np.float64)
    n = p.shape[0]
    if n < 3:
        raise ValueError("a polygon needs at least 3 corners")
    if n == 3:
        return _fan(3)
    centred = p - p.mean(axis=0)
    normal = np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)
    length = float(np.linalg.norm(normal))
    if not length > 0:
        return _fan(n)
    normal /= length
    # An orthonormal basis (u, w) of the plane with u x w = normal: the projected polygon is
    # then counter-clockwise (positive signed area) by construction.
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    xy = np.stack([centred @ u, centred @ w], axis=1)
    return earcut_2d(xy)


def earcut_2d(xy: np.ndarray) -> np.ndarray:
    """Triangulate a counter-clockwise simple polygon in 2D with ``mapbox_earcut``.

    xy: (n, 2) float64 corners. Returns (n-2, 3) int64 corner numbers, counter-clockwise.
    When earcut returns fewer than n - 2 triangles (self-intersecting or degenerate input),
    falls back to :func:`ear_clip` for n <= ``_EAR_CLIP_FALLBACK_MAX`` and to a fan above.
    """
    n = xy.shape[0]
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    if not np.isfinite(xy).all():
        return _fan(n)
    tris = mapbox_earcut.triangulate_float64(xy, np.array([n], dtype=np.uint32)).astype(np.int64).reshape(-1, 3)
    if tris.shape[0] != n - 2:
        return ear_clip(xy) if n <= _EAR_CLIP_FALLBACK_MAX else _fan(n)
    a, b, c = xy[tris[:, 0]], xy[tris[:, 1]], xy[tris[:, 2]]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    flip = area < 0  # earcut winds its triangles one way; ours follow the polygon (CCW)
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris


def ear_clip(xy: np.ndarray) -> np.ndarray:
    """Ear clipping of a counter-clockwise simple polygon in 2D.

    xy: (n, 2) float64 corners, counter-clockwise. Returns (n-2, 3) int64 corner numbers,
    counter-clockwise. O(n^2..n^3) Python: only the fallback for small polygons earcut
    cannot finish (see :func:`earcut_2d`).
    """
    n = xy.shape[0]
    pts = [(float(x), float(y)) for x, y in xy]
    extent = float(np.ptp(xy, axis=0).max()) if n else 0.0
    eps = (extent * extent) * 1e-14  # area tolerance for "convex enough" and "inside"

    def cross(a: int, b: int, c: int) -> float:
        (ax, ay), (bx, by), (cx, cy) = pts[a], pts[b], pts[c]
        return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)

    remaining = list(range(n))
    tris: list[tuple[int, int, int]] = []
    while len(remaining) > 3:
        m = len(remaining)
        ear = -1
        best_degenerate = -1
        for k in range(m):
            a, b, c = remaining[k - 1], remaining[k], remaining[(k + 1) % m]
            area = cross(a, b, c)
            if area <= eps:
                if best_degenerate < 0 and abs(area) <= eps:
                    best_degenerate = k  # a straight / zero-length corner: clipping it is harmless
                continue
            inside = False
            for j in remaining:
                if j in (a, b, c) or pts[j] in (pts[a], pts[b], pts[c]):
                    continue
                # inside or on the boundary of triangle (a, b, c)
                if cross(a, b, j) >= -eps and cross(b, c, j) >= -eps and cross(c, a, j) >= -eps:
                    inside = True
                    break
            if not inside:
                ear = k
                break
        if ear < 0:
            ear = best_degenerate if best_degenerate >= 0 else 0  # self-intersecting: give up gracefully
        tris.append((remaining[ear - 1], remaining[ear], remaining[(ear + 1) % m]))
        del remaining[ear]
    tris.append((remaining[0], remaining[1], remaining[2]))
    return np.asarray(tris, dtype=np.int64)
