"""Compiled kernels of the surface-error bound (numba, float64, IEEE: no fast-math).

The branch and bound of :mod:`pipelines.surface_error` spends its time in three small
computations repeated millions of times: the distance from a point to a *given* triangle, the
convexity bound of a cell over a few candidate triangles, and the two-triangle ("pair") bound
of a cell cut by the plane between them. In numpy each of them builds a dozen temporaries per
call (about 500 ns per point-triangle distance here); compiled, the same arithmetic in the
same order costs 20-100 ns. The formulas are those the module docstring of
:mod:`pipelines.surface_error` proves; every result is an *upper* value (the distance to a
real triangle, or a bound), rounded up by a relative 1e-12 where the bound needs it.

Array contracts (all C-contiguous): points ``(K, 3) float64``; triangle corners ``a, b, c``
``(F, 3) float64`` (the target mesh, one row per triangle); face indices ``(K,) int64`` in
``[0, F)``; cells ``(K, 3, 3) float64`` (three corners each).

Compiled on first use and cached beside this file (numba ``cache=True``), so a process pays
the compilation once per machine and about 0.3 s to load afterwards.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from assetpipe.pipelines.kernel_arrays import borrow

# error_model="numpy" on every kernel: a division by zero gives inf or NaN instead of raising, which
# drops numba's zero-divisor checks from the inner loops (the corpus's cold build 0.969x the time,
# outputs bit-identical); a NaN bound settles nothing (pipelines.surface_error._settle). The kernels
# called from Python borrow their array arguments (pipelines.kernel_arrays: no reference counting
# at each helper call in their loops)

_UP = 1.0 + 1e-12  # relative round-up of a bound assembled from rounded float64 values
# two triangles this close to parallel (the sine of the angle between their planes) are cut
# by a wall of one of them in the pair bound too (:func:`_pair`): T-junctions on flat faces
COPLANAR_SIN = 1e-3


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def dist2_parts(apx, apy, apz, abx, aby, abz, acx, acy, acz, d00, d01, d11, det, dd, plane):
    """Squared distance from a point to a triangle given by what does not depend on the point:
    ``ap`` = point - a, edges ``ab`` and ``ac``, their dot products ``d00 = ab.ab``,
    ``d01 = ab.ac``, ``d11 = ac.ac``, ``det = d00 d11 - d01^2``, ``dd = |bc|^2`` and ``plane``
    (the triangle is not (nearly) degenerate). The plane where the point projects inside, else
    the nearest of the three edges. One body for :func:`_dist2` and the BVH's precomputed
    table (:mod:`pipelines.closest_point`), so both give bit-identical distances."""
    d20 = apx * abx + apy * aby + apz * abz
    d21 = apx * acx + apy * acy + apz * acz
    if plane:
        v = (d11 * d20 - d01 * d21) / det
        w = (d00 * d21 - d01 * d20) / det
        if v >= 0.0 and w >= 0.0 and v + w <= 1.0:
            qx = apx - v * abx - w * acx
            qy = apy - v * aby - w * acy
            qz = apz - v * abz - w * acz
            return qx * qx + qy * qy + qz * qz
    t = d20 / d00 if d00 > 0.0 else 0.0
    t = min(max(t, 0.0), 1.0)
    rx, ry, rz = apx - t * abx, apy - t * aby, apz - t * abz
    best = rx * rx + ry * ry + rz * rz
    t = d21 / d11 if d11 > 0.0 else 0.0
    t = min(max(t, 0.0), 1.0)
    rx, ry, rz = apx - t * acx, apy - t * acy, apz - t * acz
    best = min(best, rx * rx + ry * ry + rz * rz)
    bcx, bcy, bcz = acx - abx, acy - aby, acz - abz
    wx, wy, wz = apx - abx, apy - aby, apz - abz
    t = (wx * bcx + wy * bcy + wz * bcz) / dd if dd > 0.0 else 0.0
    t = min(max(t, 0.0), 1.0)
    rx, ry, rz = wx - t * bcx, wy - t * bcy, wz - t * bcz
    return min(best, rx * rx + ry * ry + rz * rz)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def triangle_parts(a, b, c, f):
    """What :func:`dist2_parts` needs of triangle f besides the point: (a, ab, ac, d00, d01,
    d11, det, dd, plane). Degenerate (``det <= 1e-12 d00 d11``): edges only; never below the
    true distance (edges belong to the triangle), above it by at most the sliver's width."""
    ax, ay, az = a[f, 0], a[f, 1], a[f, 2]
    abx, aby, abz = b[f, 0] - ax, b[f, 1] - ay, b[f, 2] - az
    acx, acy, acz = c[f, 0] - ax, c[f, 1] - ay, c[f, 2] - az
    d00 = abx * abx + aby * aby + abz * abz
    d01 = abx * acx + aby * acy + abz * acz
    d11 = acx * acx + acy * acy + acz * acz
    det = d00 * d11 - d01 * d01
    bcx, bcy, bcz = acx - abx, acy - aby, acz - abz
    dd = bcx * bcx + bcy * bcy + bcz * bcz
    return ax, ay, az, abx, aby, abz, acx, acy, acz, d00, d01, d11, det, dd, det > 1e-12 * d00 * d11


@njit(cache=True, nogil=True, error_model="numpy")
def _dist2(px, py, pz, a, b, c, f):
    """Squared distance from (px, py, pz) to triangle f (see :func:`dist2_parts`)."""
    ax, ay, az, abx, aby, abz, acx, acy, acz, d00, d01, d11, det, dd, plane = triangle_parts(a, b, c, f)
    return dist2_parts(px - ax, py - ay, pz - az, abx, aby, abz, acx, acy, acz,
                       d00, d01, d11, det, dd, plane)


@njit(cache=True, nogil=True, error_model="numpy")
def tri_distance(p, faces, a, b, c):
    """Exact float64 distance from p[i] to triangle faces[i]: (K,) float64."""
    p, faces, a, b, c = borrow(p), borrow(faces), borrow(a), borrow(b), borrow(c)
    k = p.shape[0]
    out = np.empty(k)
    for i in range(k):
        out[i] = np.sqrt(_dist2(p[i, 0], p[i, 1], p[i, 2], a, b, c, faces[i]))
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _cell_max(v, i, a, b, c, f):
    """max over the corners of cell i of the distance to triangle f (d_f is convex on the
    cell, so this is its maximum over the whole cell)."""
    m = 0.0
    for j in range(3):
        m = max(m, _dist2(v[i, j, 0], v[i, j, 1], v[i, j, 2], a, b, c, f))
    return np.sqrt(m)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _seen_before(row, j):
    """Whether row[j] is among row[:j] (a triangle listed twice is evaluated once)."""
    for q in range(j):
        if row[q] == row[j]:
            return True
    return False


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _convex_cell(v, i, cand, a, b, c):
    """:func:`convex_bound` of cell i over the triangles ``cand`` (C,): (bound, triangle)."""
    bv = np.inf
    bf = cand[0]
    for j in range(cand.shape[0]):
        f = cand[j]
        if _seen_before(cand, j):
            continue
        m = _cell_max(v, i, a, b, c, f) * _UP
        if m < bv:
            bv = m
            bf = f
    return bv, bf


@njit(cache=True, nogil=True, error_model="numpy")
def convex_bound(v, cand, a, b, c):
    """Convexity bound of every cell over its candidate triangles.

    Args: v (K, 3, 3) cells; cand (K, C) int64 candidate target triangles (repeats are
    evaluated once). Returns (bound (K,), the candidate that gave it (K,) int64): the smallest
    over candidates F of ``max over corners of d_F``, an upper bound of the distance to the
    target on the whole cell (``d_target <= d_F``, and ``d_F`` is convex)."""
    v, cand, a, b, c = borrow(v), borrow(cand), borrow(a), borrow(b), borrow(c)
    k = cand.shape[0]
    val = np.empty(k)
    best = np.empty(k, dtype=np.int64)
    for i in range(k):
        val[i], best[i] = _convex_cell(v, i, cand[i], a, b, c)
    return val, best


@njit(cache=True, nogil=True, error_model="numpy")
def _closest_point(px, py, pz, a, b, c, f):
    """Closest point of triangle f to p (Ericson, Real-Time Collision Detection 5.1.5);
    degenerate triangles fall back to the nearest of the three edges."""
    ax, ay, az = a[f, 0], a[f, 1], a[f, 2]
    bx, by, bz = b[f, 0], b[f, 1], b[f, 2]
    cx, cy, cz = c[f, 0], c[f, 1], c[f, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 != 0.0:
        t = d1 / (d1 - d3)
        return ax + t * abx, ay + t * aby, az + t * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 != 0.0:
        t = d2 / (d2 - d6)
        return ax + t * acx, ay + t * acy, az + t * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and (d4 - d3) + (d5 - d6) != 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + t * (cx - bx), by + t * (cy - by), bz + t * (cz - bz)
    den = va + vb + vc
    d00 = abx * abx + aby * aby + abz * abz
    d01 = abx * acx + aby * acy + abz * acz
    d11 = acx * acx + acy * acy + acz * acz
    if den != 0.0 and d00 * d11 - d01 * d01 > 1e-12 * d00 * d11:  # not a sliver (as _dist2)
        v = vb / den
        w = vc / den
        qx, qy, qz = ax + v * abx + w * acx, ay + v * aby + w * acy, az + v * abz + w * acz
        if np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz):
            return qx, qy, qz
    # degenerate: the nearest point of the three edges
    bestd = np.inf
    rx, ry, rz = ax, ay, az
    for e in range(3):
        if e == 0:
            sx, sy, sz, ex, ey, ez = ax, ay, az, bx, by, bz
        elif e == 1:
            sx, sy, sz, ex, ey, ez = bx, by, bz, cx, cy, cz
        else:
            sx, sy, sz, ex, ey, ez = cx, cy, cz, ax, ay, az
        dx, dy, dz = ex - sx, ey - sy, ez - sz
        dd = dx * dx + dy * dy + dz * dz
        t = ((px - sx) * dx + (py - sy) * dy + (pz - sz) * dz) / dd if dd > 0.0 else 0.0
        t = min(max(t, 0.0), 1.0)
        qx, qy, qz = sx + t * dx, sy + t * dy, sz + t * dz
        d = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
        if d < bestd:
            bestd = d
            rx, ry, rz = qx, qy, qz
    return rx, ry, rz


@njit(cache=True, nogil=True, error_model="numpy")
def closest_points(p, faces, a, b, c):
    """Closest point of triangle faces[i] to p[i]: (K, 3) float64."""
    p, faces, a, b, c = borrow(p), borrow(faces), borrow(a), borrow(b), borrow(c)
    k = p.shape[0]
    out = np.empty((k, 3))
    for i in range(k):
        x, y, z = _closest_point(p[i, 0], p[i, 1], p[i, 2], a, b, c, faces[i])
        out[i, 0], out[i, 1], out[i, 2] = x, y, z
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _unit(x, y, z):
    n = np.sqrt(x * x + y * y + z * z)
    n = max(n, 1e-300)
    return x / n, y / n, z / n


@njit(cache=True, nogil=True, error_model="numpy")
def _corner(a, b, c, f, j):
    if j == 0:
        return a[f, 0], a[f, 1], a[f, 2]
    if j == 1:
        return b[f, 0], b[f, 1], b[f, 2]
    return c[f, 0], c[f, 1], c[f, 2]


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cut_bound(v, i, f1, f2, ox, oy, oz, mx, my, mz, a, b, c):
    """Bound over cell i cut by the plane through o with normal m: ``d <= d_f1`` on the side
    m points to (s >= 0), ``d <= d_f2`` on the other; inf when the plane is unusable."""
    if not (np.isfinite(mx) and np.isfinite(my) and np.isfinite(mz)) or (mx == 0.0 and my == 0.0 and mz == 0.0):
        return np.inf
    # signed side of each corner (>= 0: f1's side), as scalars: no heap array per call
    s0 = (v[i, 0, 0] - ox) * mx + (v[i, 0, 1] - oy) * my + (v[i, 0, 2] - oz) * mz
    s1 = (v[i, 1, 0] - ox) * mx + (v[i, 1, 1] - oy) * my + (v[i, 1, 2] - oz) * mz
    s2 = (v[i, 2, 0] - ox) * mx + (v[i, 2, 1] - oy) * my + (v[i, 2, 2] - oz) * mz
    best = 0.0
    for j in range(3):
        sj = s0 if j == 0 else (s1 if j == 1 else s2)
        f = f1 if sj >= 0.0 else f2
        best = max(best, _dist2(v[i, j, 0], v[i, j, 1], v[i, j, 2], a, b, c, f))
    for j in range(3):
        k = (j + 1) % 3
        sj = s0 if j == 0 else (s1 if j == 1 else s2)
        sk = s0 if k == 0 else (s1 if k == 1 else s2)
        if (sj >= 0.0) != (sk >= 0.0):
            den = sj - sk
            t = sj / den if den != 0.0 else 0.0
            t = min(max(t, 0.0), 1.0)
            x = v[i, j, 0] + t * (v[i, k, 0] - v[i, j, 0])
            y = v[i, j, 1] + t * (v[i, k, 1] - v[i, j, 1])
            z = v[i, j, 2] + t * (v[i, k, 2] - v[i, j, 2])
            best = max(best, _dist2(x, y, z, a, b, c, f1), _dist2(x, y, z, a, b, c, f2))
    r = np.sqrt(best)
    if not np.isfinite(r):
        return np.inf
    return r * _UP


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _normal(a, b, c, f):
    ux, uy, uz = b[f, 0] - a[f, 0], b[f, 1] - a[f, 1], b[f, 2] - a[f, 2]
    wx, wy, wz = c[f, 0] - a[f, 0], c[f, 1] - a[f, 1], c[f, 2] - a[f, 2]
    return uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _coplanar(a, b, c, f1, f2):
    """Whether triangles f1 and f2 lie in parallel planes to within COPLANAR_SIN (both with an
    area)."""
    n1x, n1y, n1z = _normal(a, b, c, f1)
    n2x, n2y, n2z = _normal(a, b, c, f2)
    cx = n1y * n2z - n1z * n2y
    cy = n1z * n2x - n1x * n2z
    cz = n1x * n2y - n1y * n2x
    l1 = n1x * n1x + n1y * n1y + n1z * n1z
    l2 = n2x * n2x + n2y * n2y + n2z * n2z
    return l1 > 0.0 and l2 > 0.0 and cx * cx + cy * cy + cz * cz <= COPLANAR_SIN * COPLANAR_SIN * l1 * l2


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _wall(a, b, c, f, j):
    """The wall of triangle f's edge j (corner j to corner j + 1): a point of it and its unit
    normal pointing into f, in f's plane; a zero normal for a degenerate triangle (the plane is
    then refused)."""
    e0x, e0y, e0z = _corner(a, b, c, f, j)
    e1x, e1y, e1z = _corner(a, b, c, f, (j + 1) % 3)
    o_x, o_y, o_z = _corner(a, b, c, f, (j + 2) % 3)
    mx, my, mz = _into(e0x, e0y, e0z, e1x, e1y, e1z, o_x, o_y, o_z)
    return e0x, e0y, e0z, mx, my, mz


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _into(e0x, e0y, e0z, e1x, e1y, e1z, ox, oy, oz):
    """The unit normal of the line through e0 and e1 towards o, in the plane of the three (the
    zero vector when o is on the line)."""
    edx, edy, edz = _unit(e1x - e0x, e1y - e0y, e1z - e0z)
    wx, wy, wz = ox - e0x, oy - e0y, oz - e0z
    t = wx * edx + wy * edy + wz * edz
    return _unit(wx - t * edx, wy - t * edy, wz - t * edz)


@njit(cache=True, nogil=True, error_model="numpy")
def _pair(v, i, f1, f2, a, b, c, wtri, thr):
    """Bound of the distance to the target over cell i from two target triangles f1 != f2:
    the cell is cut by a plane; on f1's side ``d <= d_f1``, on the other ``d <= d_f2``, both
    convex, so each side's maximum is at its polygon's corners (the cell's corners on that
    side and the cut points on its edges). Valid for any plane. Triangles sharing an edge
    (welded vertex ids ``wtri``, so also across a seam of split vertices) are cut by the plane
    through the edge halfway between their walls; others by the mid-plane of their points
    nearest to the cell's centroid, and, where that leaves the cell above ``thr`` and the two
    lie in one plane (:data:`COPLANAR_SIN`), by each wall of f1 (the plane through an edge,
    square to the triangle) until one settles it: the smallest value. The walls settle a cell
    over a T-junction, where one triangle's edge runs along a part of the other's or the two
    meet at a vertex on a line (meshoptimizer leaves them on flat faces, with a zero-area
    triangle between): the mid-plane of two points on that line cuts nowhere near it.
    inf when no plane is usable."""
    # which corners of f1 does f2 have too (bit j: corner j), without a heap array per call
    mask = 0
    shared = 0
    for j in range(3):
        for q in range(3):
            if wtri[f1, j] == wtri[f2, q]:
                mask |= 1 << j
                shared += 1
                break
    if shared == 2:
        # the shared edge (e0, e1) in f1's corner order, f1's third corner o1, f2's o2
        o1 = 0 if not mask & 1 else (1 if not mask & 2 else 2)
        e0 = 1 if o1 == 0 else 0
        e1 = 1 if o1 == 2 else 2
        o2 = 0
        for q in range(3):
            found = False
            for j in range(3):
                if wtri[f2, q] == wtri[f1, j]:
                    found = True
            if not found:
                o2 = q
                break
        # corner coordinates (the welded positions equal the triangles' own corners)
        e0x, e0y, e0z = _corner(a, b, c, f1, e0)
        e1x, e1y, e1z = _corner(a, b, c, f1, e1)
        o1x, o1y, o1z = _corner(a, b, c, f1, o1)
        o2x, o2y, o2z = _corner(a, b, c, f2, o2)
        # unit in-plane normals of the edge, pointing into each triangle
        w1x, w1y, w1z = _into(e0x, e0y, e0z, e1x, e1y, e1z, o1x, o1y, o1z)
        w2x, w2y, w2z = _into(e0x, e0y, e0z, e1x, e1y, e1z, o2x, o2y, o2z)
        return _cut_bound(v, i, f1, f2, e0x, e0y, e0z, w1x - w2x, w1y - w2y, w1z - w2z, a, b, c)
    cx_ = (v[i, 0, 0] + v[i, 1, 0] + v[i, 2, 0]) / 3.0
    cy_ = (v[i, 0, 1] + v[i, 1, 1] + v[i, 2, 1]) / 3.0
    cz_ = (v[i, 0, 2] + v[i, 1, 2] + v[i, 2, 2]) / 3.0
    q1x, q1y, q1z = _closest_point(cx_, cy_, cz_, a, b, c, f1)
    q2x, q2y, q2z = _closest_point(cx_, cy_, cz_, a, b, c, f2)
    r = _cut_bound(v, i, f1, f2, 0.5 * (q1x + q2x), 0.5 * (q1y + q2y), 0.5 * (q1z + q2z),
                   q1x - q2x, q1y - q2y, q1z - q2z, a, b, c)
    if r <= thr or not _coplanar(a, b, c, f1, f2):
        return r
    for j in range(3):  # f1's walls (normals into f1: f1's side)
        ox, oy, oz, mx, my, mz = _wall(a, b, c, f1, j)
        r = min(r, _cut_bound(v, i, f1, f2, ox, oy, oz, mx, my, mz, a, b, c))
        if r <= thr:
            break
    return r


@njit(cache=True, nogil=True, error_model="numpy")
def pair_bound(v, hint, others, a, b, c, wtri, thr):
    """Smallest pair bound of every cell: (K,) float64, inf where no pair applies.

    Args: v (K, 3, 3) cells; hint (K,) int64 the cell's best single triangle; others (K, C)
    int64 triangles to pair it with (each distinct one != hint tried once); wtri (F, 3) int64
    the target's triangles over welded vertex ids (equal ids: same position); thr: the value
    that settles a cell (a pair's wall cuts are tried only above it, :func:`_pair`)."""
    v, hint, others, a, b, c, wtri = borrow(v), borrow(hint), borrow(others), borrow(a), borrow(b), borrow(c), borrow(wtri)
    k = others.shape[0]
    out = np.empty(k)
    for i in range(k):
        out[i] = _pair_cell(v, i, hint[i], others[i], a, b, c, wtri, thr)
    return out


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _pair_cell(v, i, h, others, a, b, c, wtri, thr):
    """:func:`pair_bound` of cell i: its best triangle ``h`` paired with each of ``others`` (C,);
    where that leaves the cell above ``thr``, also two of ``others`` that lie in one plane
    (:func:`_coplanar`), until a pair settles it. A cell across a vertex of a flat face lies
    over two triangles that meet only there, and the best single triangle ``h`` may be a third
    one touching the vertex: a zero-area cell of the box's levels (a subdivided box, 3,072
    triangles) split around such a vertex until the work ran out."""
    bv = np.inf
    n = others.shape[0]
    for j in range(n):
        f = others[j]
        if f == h or _seen_before(others, j):
            continue
        bv = min(bv, _pair(v, i, h, f, a, b, c, wtri, thr))
    if bv <= thr:
        return bv
    for j in range(n):
        f = others[j]
        if f == h or _seen_before(others, j):
            continue
        for k in range(j + 1, n):
            g = others[k]
            if g == h or g == f or _seen_before(others, k) or not _coplanar(a, b, c, f, g):
                continue
            bv = min(bv, _pair(v, i, f, g, a, b, c, wtri, thr))
            if bv <= thr:
                return bv
    return bv


@njit(cache=True, nogil=True, error_model="numpy")
def _cover(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Covering radius of a triangle's corners, ``max over p in T of min_i |p - v_i|``,
    rounded up. Non-obtuse: the circumradius (the circumcentre lies in T). Obtuse at C (AB the
    longest side): where the perpendicular bisector of CA or CB meets AB, at ``|CA| / (2 cos A)``
    resp. ``|CB| / (2 cos B)``. Degenerate (collinear) triangles fall in the obtuse case and
    give half the largest gap along the segment; a value rounding leaves unusable becomes the
    longest side (every point of T is within it of every corner)."""
    la2 = (bx - cx) ** 2 + (by - cy) ** 2 + (bz - cz) ** 2  # |BC|^2, opposite A
    lb2 = (cx - ax) ** 2 + (cy - ay) ** 2 + (cz - az) ** 2  # |CA|^2, opposite B
    lc2 = (ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2  # |AB|^2, opposite C
    # the longest side L2 and the two others s1, s2 (in cyclic order after it)
    if la2 >= lb2 and la2 >= lc2:
        L2, s1, s2 = la2, lb2, lc2
    elif lb2 >= lc2:
        L2, s1, s2 = lb2, lc2, la2
    else:
        L2, s1, s2 = lc2, la2, lb2
    L, l1, l2 = np.sqrt(L2), np.sqrt(s1), np.sqrt(s2)
    if L2 >= s1 + s2:  # obtuse, right or degenerate
        # side l1 meets the longest side at an angle with cos = (l1^2 + L^2 - l2^2) / (2 l1 L):
        # its bisector meets the longest side at l1^2 L / (l1^2 + L^2 - l2^2)
        den1 = s1 + L2 - s2
        den2 = s2 + L2 - s1
        # (a denominator that rounds to 0, a side far below the others' rounding, gives inf:
        # the longest side below)
        r1 = (s1 * L / den1 if den1 > 0.0 else np.inf) if s1 > 0.0 else 0.0
        r2 = (s2 * L / den2 if den2 > 0.0 else np.inf) if s2 > 0.0 else 0.0
        r = max(r1, r2)
    else:
        ux, uy, uz = bx - ax, by - ay, bz - az
        wx, wy, wz = cx - ax, cy - ay, cz - az
        crx = uy * wz - uz * wy
        cry = uz * wx - ux * wz
        crz = ux * wy - uy * wx
        # abc / (4 area); an area that rounds to 0 is unusable: the longest side below (numba
        # raises on a division by zero: a UV sphere's pole cells stopped a chain)
        den = 2.0 * np.sqrt(crx * crx + cry * cry + crz * crz)
        r = L * l1 * l2 / den if den > 0.0 else np.inf
    if not (np.isfinite(r) and r >= 0.0):
        r = L
    return min(r, L) * _UP


@njit(cache=True, nogil=True, error_model="numpy")
def covering_radius(a, b, c):
    """Covering radius of each triangle's corners (a, b, c: (K, 3) float64): (K,) float64,
    exact up to rounding and rounded up (see :func:`_cover`)."""
    k = a.shape[0]
    out = np.empty(k)
    for i in range(k):
        out[i] = _cover(a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2], c[i, 0], c[i, 1], c[i, 2])
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def lipschitz_bound(v, d):
    """Upper bound of a 1-Lipschitz function on cells v (K, 3, 3) with corner values d (K, 3):
    ``min(max_i d_i + R, min_i (d_i + max_j |v_j - v_i|))``, R the covering radius of the
    corners on the cell (from corner i the farthest point of the cell is a corner).
    (K,) float64."""
    k = v.shape[0]
    out = np.empty(k)
    for i in range(k):
        ax, ay, az = v[i, 0, 0], v[i, 0, 1], v[i, 0, 2]
        bx, by, bz = v[i, 1, 0], v[i, 1, 1], v[i, 1, 2]
        cx, cy, cz = v[i, 2, 0], v[i, 2, 1], v[i, 2, 2]
        da, db, dc = d[i, 0], d[i, 1], d[i, 2]
        ub = max(da, db, dc) + _cover(ax, ay, az, bx, by, bz, cx, cy, cz)
        ea = np.sqrt((bx - cx) ** 2 + (by - cy) ** 2 + (bz - cz) ** 2)  # opposite a
        eb = np.sqrt((cx - ax) ** 2 + (cy - ay) ** 2 + (cz - az) ** 2)  # opposite b
        ec = np.sqrt((ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2)  # opposite c
        far = min(da + max(eb, ec), db + max(ea, ec), dc + max(ea, eb)) * _UP
        out[i] = min(ub, far)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def near_bounds(v, d, f, hint, thr, a, b, c, wtri, pair):
    """The first bounds of every cell in turn, each only where the ones before leave it above
    ``thr``: :func:`lipschitz_bound`; then :func:`convex_bound` over (hint, f0, f1, f2) (the
    best of them becomes the cell's hint); then, with ``pair``, :func:`pair_bound` of that hint
    with f0, f1, f2. Each is taken as the minimum with the ones before. Returns (bound (K,),
    hint (K,) int64): the values the three kernels give one after another with the cells
    settled in between dropped (:func:`pipelines.surface_error._bound_direction`), in one
    pass (no arrays compacted between them).

    Args: v (K, 3, 3) cells; d (K, 3) upper values of the corners' distances; f (K, 3) int64 a
    target triangle near each corner; hint (K,) int64; a, b, c (F, 3) the target's corners;
    wtri (F, 3) its triangles over welded vertex ids."""
    v, d, f, hint, a, b, c, wtri = (borrow(v), borrow(d), borrow(f), borrow(hint), borrow(a), borrow(b),
                                    borrow(c), borrow(wtri))
    k = v.shape[0]
    ub = lipschitz_bound(v, d)
    out_hint = hint.copy()
    cand = np.empty(4, dtype=np.int64)
    for i in range(k):
        if ub[i] <= thr:
            continue
        cand[0], cand[1], cand[2], cand[3] = hint[i], f[i, 0], f[i, 1], f[i, 2]
        bv, bf = _convex_cell(v, i, cand, a, b, c)
        ub[i] = min(ub[i], bv)
        out_hint[i] = bf
        if ub[i] <= thr or not pair:
            continue
        ub[i] = min(ub[i], _pair_cell(v, i, bf, f[i], a, b, c, wtri, thr))
    return ub, out_hint


@njit(cache=True, nogil=True, error_model="numpy")
def area_cumsum(pos, tri):
    """(M,) float64: the running sum of the triangles' areas (a non-finite area counts 0),
    bit for bit numpy's ``cumsum(0.5 * norm(cross(b - a, c - a), axis=1))``, without the
    (M, 3) arrays it makes. pos (N, 3) float64, tri (M, 3) int64."""
    m = tri.shape[0]
    out = np.empty(m)
    s = 0.0
    for t in range(m):
        i, j, k = tri[t, 0], tri[t, 1], tri[t, 2]
        ux, uy, uz = pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1], pos[j, 2] - pos[i, 2]
        wx, wy, wz = pos[k, 0] - pos[i, 0], pos[k, 1] - pos[i, 1], pos[k, 2] - pos[i, 2]
        cx = uy * wz - uz * wy
        cy = uz * wx - ux * wz
        cz = ux * wy - uy * wx
        ar = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
        if not np.isfinite(ar):
            ar = 0.0
        s += ar
        out[t] = s
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def area_samples(pos, tri, cum, u, r1, r2):
    """(P, 3) float64 points on the triangles, drawn by area: point i on the triangle where
    ``u[i] * cum[-1]`` falls in ``cum`` (numpy's searchsorted, side right, clipped to the
    last), at barycentric weights (1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2): bit for bit
    what :func:`pipelines.surface_error.sample_surface` computed in numpy."""
    m = tri.shape[0]
    n = u.shape[0]
    total = cum[m - 1]
    out = np.empty((n, 3))
    for q in range(n):
        x = u[q] * total
        lo, hi = 0, m
        while lo < hi:
            mid = (lo + hi) >> 1
            if cum[mid] <= x:
                lo = mid + 1
            else:
                hi = mid
        t = min(lo, m - 1)
        s1 = np.sqrt(r1[q])
        wa, wb, wc = 1.0 - s1, s1 * (1.0 - r2[q]), s1 * r2[q]
        i, j, k = tri[t, 0], tri[t, 1], tri[t, 2]
        for e in range(3):
            out[q, e] = wa * pos[i, e] + wb * pos[j, e] + wc * pos[k, e]
    return out
