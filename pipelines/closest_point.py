"""Exact closest-triangle queries in float64: a BVH built and traversed in compiled code.

Why our own: the surface-error bound (:mod:`pipelines.surface_error`) asks millions of
point-to-mesh queries per model. fcpw, the fastest engine measured for this (issue #11), has two
faults for that use: its float32 triangle test picks a triangle up to 15x too far for points
near thin slivers (116 of 20,000 points on a 2CylinderEngine part, docs/BUILD.md), and its
Python binding returns one object per answer. Here every distance is computed in IEEE float64
by the same kernel the bound uses (:func:`pipelines.distance_kernels._dist2`), so the triangle
returned is the nearest up to float64 rounding, and answers come back as arrays.

Array contracts: positions ``(N, 3) float64``; triangles ``(M, 3) int64`` in ``[0, N)``;
query points ``(P, 3) float64``; ``hint`` ``(P,) int64``, a triangle to try first per point
(``-1``: none); ``radius`` ``(P,) float64``, a known upper value of each point's distance
(``inf``: none). Results: distance ``(P,) float64`` and triangle ``(P,) int64``.

The tree: axis-aligned boxes, split at the median centroid along the box's longest centroid
extent, at most :data:`LEAF_SIZE` triangles a leaf; children visited nearest box first, and
a box is skipped once its distance reaches the best found (squared distances throughout).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

# error_model="numpy" on every kernel: a division by zero gives inf or NaN instead of raising, which
# drops numba's zero-divisor checks from the inner loops (the corpus's cold build 0.969x the time,
# outputs bit-identical); a NaN bound settles nothing (pipelines.surface_error._settle)

from assetpipe.core.rows import column_bounds
from assetpipe.pipelines.distance_kernels import _dist2, dist2_parts, triangle_parts
from assetpipe.pipelines.kernel_arrays import borrow

#: triangles per leaf at most: 4 measured fastest on the bunny (69k triangles) among 2, 4, 8
LEAF_SIZE = 4
_SORT_MIN = 64  # fewer queries than this are asked in the order given (sorting costs more)
_STACK = 128  # traversal stack depth: the median split gives depth ~log2(M / LEAF_SIZE) < 40


_BINS = 16      # SAH candidate planes per axis
_SAH_DEPTH = 48  # below this depth, median splits only: depth <= 48 + log2(M) < _STACK


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _area(lx, ly, lz, hx, hy, hz):
    dx, dy, dz = hx - lx, hy - ly, hz - lz
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, nogil=True, error_model="numpy")
def _sah_split(order, d, s, e, cl, ch, ax_out, cnt, blo, bhi, rarea, rcnt, scratch, dscratch, cb):
    """Best binned-SAH plane over the three axes: returns the split position in
    ``order[s:e]`` (and the rows ``d[s:e]`` with it) after partitioning it (0 if no plane
    beats a median split's caller). ``d`` (M, 9): per slot, the triangle's centroid, box low
    and box high (kept in slot order: the passes read memory in sequence). ``cnt`` (3, B)
    int64, ``blo``/``bhi`` (3, B, 3), ``rarea`` (B,), ``rcnt`` (B,) int64, ``scratch`` (M,)
    int64 and ``dscratch`` (M, 9): work space, overwritten. One pass bins the triangles on all
    three axes; one pass partitions (stable: each side keeps its order) and gives each side's
    bounds in ``cb`` (2, 12): box low, box high, centroid low, centroid high (what
    :func:`_build` would compute from the side's rows: min and max are exact)."""
    best_cost = np.inf
    best_ax = -1
    best_bin = -1
    scale = np.zeros(3)
    for ax in range(3):
        ext = ch[ax] - cl[ax]
        if ext > 0.0:
            scale[ax] = _BINS / ext
        for j in range(_BINS):
            cnt[ax, j] = 0
            for k in range(3):
                blo[ax, j, k] = np.inf
                bhi[ax, j, k] = -np.inf
    for i in range(s, e):
        for ax in range(3):
            if scale[ax] == 0.0:
                continue
            bi = min(int((d[i, ax] - cl[ax]) * scale[ax]), _BINS - 1)
            cnt[ax, bi] += 1
            for k in range(3):
                blo[ax, bi, k] = min(blo[ax, bi, k], d[i, 3 + k])
                bhi[ax, bi, k] = max(bhi[ax, bi, k], d[i, 6 + k])
    for ax in range(3):
        if scale[ax] == 0.0:
            continue
        # sweep from the right: area and count of bins > j
        lx = ly = lz = np.inf
        hx = hy = hz = -np.inf
        n = 0
        for j in range(_BINS - 1, 0, -1):
            if cnt[ax, j]:
                lx, ly, lz = min(lx, blo[ax, j, 0]), min(ly, blo[ax, j, 1]), min(lz, blo[ax, j, 2])
                hx, hy, hz = max(hx, bhi[ax, j, 0]), max(hy, bhi[ax, j, 1]), max(hz, bhi[ax, j, 2])
            n += cnt[ax, j]
            rarea[j - 1] = _area(lx, ly, lz, hx, hy, hz) if n else 0.0
            rcnt[j - 1] = n
        lx = ly = lz = np.inf
        hx = hy = hz = -np.inf
        n = 0
        for j in range(_BINS - 1):
            if cnt[ax, j]:
                lx, ly, lz = min(lx, blo[ax, j, 0]), min(ly, blo[ax, j, 1]), min(lz, blo[ax, j, 2])
                hx, hy, hz = max(hx, bhi[ax, j, 0]), max(hy, bhi[ax, j, 1]), max(hz, bhi[ax, j, 2])
            n += cnt[ax, j]
            if n == 0 or rcnt[j] == 0:
                continue
            cost = _area(lx, ly, lz, hx, hy, hz) * n + rarea[j] * rcnt[j]
            if cost < best_cost:
                best_cost, best_ax, best_bin = cost, ax, j
    if best_ax < 0:
        return 0
    ax_out[0] = best_ax
    sc = scale[best_ax]
    # stable partition: bins <= best_bin first, in order; the others after them, in order
    for side in range(2):
        for k in range(3):
            cb[side, k] = np.inf
            cb[side, 3 + k] = -np.inf
            cb[side, 6 + k] = np.inf
            cb[side, 9 + k] = -np.inf
    w = s
    r = 0
    for i in range(s, e):
        side = 0 if min(int((d[i, best_ax] - cl[best_ax]) * sc), _BINS - 1) <= best_bin else 1
        for k in range(3):
            cb[side, k] = min(cb[side, k], d[i, 3 + k])
            cb[side, 3 + k] = max(cb[side, 3 + k], d[i, 6 + k])
            cb[side, 6 + k] = min(cb[side, 6 + k], d[i, k])
            cb[side, 9 + k] = max(cb[side, 9 + k], d[i, k])
        if side == 0:
            order[w] = order[i]
            for k in range(9):
                d[w, k] = d[i, k]
            w += 1
        else:
            scratch[r] = order[i]
            for k in range(9):
                dscratch[r, k] = d[i, k]
            r += 1
    for i in range(r):
        order[w + i] = scratch[i]
        for k in range(9):
            d[w + i, k] = dscratch[i, k]
    return w


@njit(cache=True, nogil=True, error_model="numpy")
def _build(a, b, c, leaf):
    m = a.shape[0]
    # per slot (permuted along with ``order``): centroid, box low, box high
    d = np.empty((m, 9))
    d[:, 0:3] = (a + b + c) / 3.0
    d[:, 3:6] = np.minimum(np.minimum(a, b), c)
    d[:, 6:9] = np.maximum(np.maximum(a, b), c)
    order = np.arange(m)
    cap = 2 * m + 1  # a binary tree with at least one triangle a leaf has < 2m nodes
    nlo = np.empty((cap, 3))
    nhi = np.empty((cap, 3))
    left = np.full(cap, -1, dtype=np.int64)     # first child (the second is left + 1); -1: leaf
    first = np.zeros(cap, dtype=np.int64)       # leaf: first index into order
    count = np.zeros(cap, dtype=np.int64)       # leaf: triangles
    sn = np.empty(_STACK * 2, dtype=np.int64)
    ss = np.empty(_STACK * 2, dtype=np.int64)
    se = np.empty(_STACK * 2, dtype=np.int64)
    sdp = np.empty(_STACK * 2, dtype=np.int64)
    ax_out = np.zeros(1, dtype=np.int64)
    cnt = np.zeros((3, _BINS), dtype=np.int64)  # the SAH split's work space
    blo = np.empty((3, _BINS, 3))
    bhi = np.empty((3, _BINS, 3))
    rarea = np.empty(_BINS)
    rcnt = np.empty(_BINS, dtype=np.int64)
    scratch = np.empty(m, dtype=np.int64)
    dscratch = np.empty((m, 9))
    sbd = np.empty((_STACK * 2, 12))  # a pending node's bounds, when its parent's split gave them
    skn = np.zeros(_STACK * 2, dtype=np.bool_)
    cb = np.empty((2, 12))
    sn[0], ss[0], se[0], sdp[0] = 0, 0, m, 0
    top = 1
    used = 1
    bl = np.empty(3)
    bh = np.empty(3)
    cl = np.empty(3)
    ch = np.empty(3)
    while top > 0:
        top -= 1
        node, s, e, depth = sn[top], ss[top], se[top], sdp[top]
        if skn[top]:
            for k in range(3):
                bl[k] = sbd[top, k]
                bh[k] = sbd[top, 3 + k]
                cl[k] = sbd[top, 6 + k]
                ch[k] = sbd[top, 9 + k]
        else:
            bl[:] = np.inf
            bh[:] = -np.inf
            cl[:] = np.inf
            ch[:] = -np.inf
            for i in range(s, e):
                for k in range(3):
                    bl[k] = min(bl[k], d[i, 3 + k])
                    bh[k] = max(bh[k], d[i, 6 + k])
                    cl[k] = min(cl[k], d[i, k])
                    ch[k] = max(ch[k], d[i, k])
        for k in range(3):
            nlo[node, k] = bl[k]
            nhi[node, k] = bh[k]
        if e - s <= leaf:
            first[node] = s
            count[node] = e - s
            continue
        mid = _sah_split(order, d, s, e, cl, ch, ax_out, cnt, blo, bhi, rarea, rcnt, scratch,
                         dscratch, cb) if depth < _SAH_DEPTH else 0
        known = s < mid < e  # the partition gave both sides' bounds
        if mid <= s or mid >= e:
            # no SAH plane (all centroids in one bin) or too deep: the median of the longest
            # centroid extent (stable sort: the same tree on every machine)
            ax = 0
            ext = ch[0] - cl[0]
            for k in range(1, 3):
                if ch[k] - cl[k] > ext:
                    ax, ext = k, ch[k] - cl[k]
            mid = (s + e) // 2
            perm = np.argsort(d[s:e, ax], kind="mergesort")
            order[s:e] = order[s:e][perm]
            d[s:e] = d[s:e][perm]
        left[node] = used
        sn[top], ss[top], se[top], sdp[top] = used, s, mid, depth + 1
        sn[top + 1], ss[top + 1], se[top + 1], sdp[top + 1] = used + 1, mid, e, depth + 1
        skn[top] = known
        skn[top + 1] = known
        if known:
            for k in range(12):
                sbd[top, k] = cb[0, k]
                sbd[top + 1, k] = cb[1, k]
        top += 2
        used += 2
    box = np.empty((used, 6))
    box[:, :3] = nlo[:used]
    box[:, 3:] = nhi[:used]
    # the triangles' corners in leaf order: a leaf's triangles are contiguous in memory
    return box, left[:used].copy(), first[:used].copy(), count[:used].copy(), order, \
        _table(a, b, c, order)


@njit(cache=True, nogil=True, error_model="numpy")
def _table(a, b, c, order):
    """Per triangle, in leaf order (a leaf's triangles contiguous in memory), what
    :func:`pipelines.distance_kernels.dist2_parts` needs that does not depend on the point
    (:func:`pipelines.distance_kernels.triangle_parts`): corner a, edges ab and ac, their dot
    products, the determinant, |bc|^2 and whether the triangle is not degenerate. (M, 15)
    float64; the distances are bit-identical to ``_dist2``'s."""
    m = order.shape[0]
    t = np.empty((m, 15))
    for j in range(m):
        ax, ay, az, abx, aby, abz, acx, acy, acz, d00, d01, d11, det, dd, plane = \
            triangle_parts(a, b, c, order[j])
        t[j, 0], t[j, 1], t[j, 2] = ax, ay, az
        t[j, 3], t[j, 4], t[j, 5] = abx, aby, abz
        t[j, 6], t[j, 7], t[j, 8] = acx, acy, acz
        t[j, 9], t[j, 10], t[j, 11], t[j, 12], t[j, 13] = d00, d01, d11, det, dd
        t[j, 14] = 1.0 if plane else 0.0
    return t


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _dist2_table(px, py, pz, t, f):
    """:func:`pipelines.distance_kernels._dist2` on row f of :func:`_table`."""
    return dist2_parts(px - t[f, 0], py - t[f, 1], pz - t[f, 2], t[f, 3], t[f, 4], t[f, 5],
                       t[f, 6], t[f, 7], t[f, 8], t[f, 9], t[f, 10], t[f, 11], t[f, 12],
                       t[f, 13], t[f, 14] > 0.0)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _box2(px, py, pz, box, n):
    d = 0.0
    v = box[n, 0] - px
    if v > 0.0:
        d += v * v
    else:
        v = px - box[n, 3]
        if v > 0.0:
            d += v * v
    v = box[n, 1] - py
    if v > 0.0:
        d += v * v
    else:
        v = py - box[n, 4]
        if v > 0.0:
            d += v * v
    v = box[n, 2] - pz
    if v > 0.0:
        d += v * v
    else:
        v = pz - box[n, 5]
        if v > 0.0:
            d += v * v
    return d


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _nearest(px, py, pz, h, r, box, left, first, count, order, table, a, b, c, stack, sd):
    """(squared distance, triangle) of the triangle nearest (px, py, pz) within radius r
    (inf: none; (inf, -1) when nothing is within it); h: a triangle to try first (-1: none).
    Ties go to the lowest triangle index, so the answer does not depend on the order boxes
    are visited in."""
    best = r * r if r < np.inf else np.inf
    bf = -1
    if h >= 0:
        d2 = _dist2(px, py, pz, a, b, c, h)
        if d2 <= best:
            best, bf = d2, h
    stack[0] = 0
    sd[0] = _box2(px, py, pz, box, 0)
    top = 1
    while top > 0:
        top -= 1
        n = stack[top]
        if sd[top] > best or (sd[top] == best and bf >= 0):
            continue
        l = left[n]
        if l < 0:
            for j in range(first[n], first[n] + count[n]):
                d2 = _dist2_table(px, py, pz, table, j)
                if d2 < best or (d2 == best and (bf < 0 or order[j] < bf)):
                    best, bf = d2, order[j]
            continue
        d0 = _box2(px, py, pz, box, l)
        d1 = _box2(px, py, pz, box, l + 1)
        if d0 <= d1:
            if d1 <= best:
                stack[top], sd[top] = l + 1, d1
                top += 1
            if d0 <= best:
                stack[top], sd[top] = l, d0
                top += 1
        else:
            if d0 <= best:
                stack[top], sd[top] = l, d0
                top += 1
            if d1 <= best:
                stack[top], sd[top] = l + 1, d1
                top += 1
    return best, bf


@njit(cache=True, nogil=True, error_model="numpy")
def _query(p, hint, radius, box, left, first, count, order, table, a, b, c):
    k = p.shape[0]
    out_d = np.empty(k)
    out_f = np.empty(k, dtype=np.int64)
    _query_into(p, hint, radius, box, left, first, count, order, table, a, b, c,
                np.empty(_STACK, dtype=np.int64), np.empty(_STACK), out_d, out_f)
    return out_d, out_f


@njit(cache=True, nogil=True, error_model="numpy")
def _query_into(p, hint, radius, box, left, first, count, order, table, a, b, c, stack, sd, out_d, out_f):
    """:func:`_query` into ``out_d``, ``out_f``, with the traversal's stacks given: every array
    is an argument, borrowed (:mod:`pipelines.kernel_arrays`)."""
    p, hint, radius, box, left, first, count, order, table, a, b, c, stack, sd, out_d, out_f = (
        borrow(p), borrow(hint), borrow(radius), borrow(box), borrow(left), borrow(first), borrow(count),
        borrow(order), borrow(table), borrow(a), borrow(b), borrow(c), borrow(stack), borrow(sd),
        borrow(out_d), borrow(out_f))
    k = p.shape[0]
    for i in range(k):
        best, bf = _nearest(p[i, 0], p[i, 1], p[i, 2], hint[i], radius[i], box, left, first,
                            count, order, table, a, b, c, stack, sd)
        out_d[i] = np.sqrt(best) if bf >= 0 else np.inf
        out_f[i] = bf


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _within(px, py, pz, r2, box, left, first, count, table, stack):
    """The slot (in :func:`_table`) of some triangle within squared distance r2 of
    (px, py, pz), or -1: the first one found ends the walk (nearest box first)."""
    if _box2(px, py, pz, box, 0) > r2:
        return -1
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        n = stack[top]
        l = left[n]
        if l < 0:
            for j in range(first[n], first[n] + count[n]):
                if _dist2_table(px, py, pz, table, j) <= r2:
                    return j
            continue
        d0 = _box2(px, py, pz, box, l)
        d1 = _box2(px, py, pz, box, l + 1)
        if d0 <= d1:
            if d1 <= r2:
                stack[top] = l + 1
                top += 1
            if d0 <= r2:
                stack[top] = l
                top += 1
        else:
            if d0 <= r2:
                stack[top] = l
                top += 1
            if d1 <= r2:
                stack[top] = l + 1
                top += 1
    return -1


#: points the largest-distance walk first asks in full (spread over the points): their
#: largest distance is the bar every other point is first tested against
_MAX_SEEDS = 64


@njit(cache=True, nogil=True, error_model="numpy")
def _max_query(p, stop, box, left, first, count, order, table, a, b, c):
    """The largest squared nearest distance of the points (exact: the largest of what
    :func:`_query` gives them), and whether it stopped early because its square root
    exceeded ``stop`` (compared after the root, which rounds: a stopped value is > stop).

    A point is asked in full only when no triangle lies within the largest distance found so
    far (the previous point's triangle tried first): a point with one nearer cannot raise
    the maximum."""
    return _max_query_with(p, stop, box, left, first, count, order, table, a, b, c,
                           np.empty(_STACK, dtype=np.int64), np.empty(_STACK))


@njit(cache=True, nogil=True, error_model="numpy")
def _max_query_with(p, stop, box, left, first, count, order, table, a, b, c, stack, sd):
    """:func:`_max_query` with the traversal's stacks given: every array is an argument,
    borrowed (:mod:`pipelines.kernel_arrays`)."""
    p, box, left, first, count, order, table, a, b, c, stack, sd = (
        borrow(p), borrow(box), borrow(left), borrow(first), borrow(count), borrow(order),
        borrow(table), borrow(a), borrow(b), borrow(c), borrow(stack), borrow(sd))
    k = p.shape[0]
    m2 = 0.0
    last = -1  # the slot of the triangle the previous point found within (points come in
    # spatial order: often within of the next one too)
    step = max(1, k // _MAX_SEEDS)
    for i in range(0, k, step):
        d2, _ = _nearest(p[i, 0], p[i, 1], p[i, 2], -1, np.inf, box, left, first, count,
                         order, table, a, b, c, stack, sd)
        m2 = max(m2, d2)
        if np.sqrt(m2) > stop:
            return m2, True
    for i in range(k):
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        if last >= 0 and _dist2_table(px, py, pz, table, last) <= m2:
            continue
        j = _within(px, py, pz, m2, box, left, first, count, table, stack)
        if j >= 0:
            last = j
            continue
        d2, _ = _nearest(px, py, pz, -1, np.inf, box, left, first, count, order, table, a, b, c,
                         stack, sd)
        if d2 > m2:
            m2 = d2
            if np.sqrt(m2) > stop:
                return m2, True
    return m2, False


@njit(cache=True, nogil=True, error_model="numpy")
def _spread10(x):
    x &= 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


@njit(cache=True, nogil=True, error_model="numpy")
def _morton(p, lo, scale):
    k = p.shape[0]
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        code = 0
        for j in range(3):
            q = int((p[i, j] - lo[j]) * scale)
            q = min(max(q, 0), 1023)
            code |= _spread10(q) << j
        out[i] = code
    return out


def spatial_order(points: np.ndarray) -> np.ndarray:
    """A permutation (P,) int64 putting points in Morton (Z-curve) order on a 1024^3 grid over
    their box: consecutive queries then touch the same tree nodes and triangles (on the bunny,
    1.1 us a query against 4-5 us in random order, both engines)."""
    if points.shape[0] < 2:
        return np.arange(points.shape[0])
    lo, hi = column_bounds(points)
    ext = float((hi - lo).max())
    scale = 1023.999 / ext if ext > 0 and np.isfinite(ext) else 0.0
    # any order of equal codes will do (each answer is independent of the others): numpy's
    # default sort is the fastest
    return np.argsort(_morton(points, lo, scale))


@dataclass(frozen=True, eq=False)
class ClosestTriangles:
    """A BVH over one triangle mesh; :meth:`query` finds each point's nearest triangle.

    ``a, b, c`` ``(M, 3) float64``: the triangles' corners (C-contiguous), also what the
    bound's kernels take."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    _tree: tuple

    @classmethod
    def build(cls, positions: np.ndarray, triangles: np.ndarray) -> "ClosestTriangles":
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        pos = np.asarray(positions, dtype=np.float64)
        a = pos.take(tri[:, 0], axis=0)  # row gathers (C-contiguous): 3x fancy indexing's speed here
        b = pos.take(tri[:, 1], axis=0)
        c = pos.take(tri[:, 2], axis=0)
        if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(c).all()):
            raise ValueError("closest-point tree: non-finite triangle corners (filter them first)")
        tree = _build(a, b, c, LEAF_SIZE) if tri.shape[0] else None
        return cls(a, b, c, tree)

    @property
    def nodes(self) -> tuple | None:
        """The tree as arrays, for other kernels walking it: ``(box (N, 6) float64: lo xyz,
        hi xyz; left (N,) int64: first child, -1 for a leaf (the second child is left + 1);
        first, count (N,) int64: a leaf's slots in order; order (M,) int64: triangle of each
        slot)``; None for an empty mesh."""
        return None if self._tree is None else self._tree[:5]

    def query(self, points: np.ndarray, radius: np.ndarray | None = None,
              hint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(distance (P,) float64, nearest triangle (P,) int64) of each point.

        ``radius``: known upper values of the distances (prune only: a point with nothing
        within its radius gets ``inf`` and ``-1``); ``hint``: a triangle to try first."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = p.shape[0]
        if not np.isfinite(p).all():
            raise ValueError("closest-point query: non-finite points")
        if self._tree is None or n == 0:
            return np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        r = np.full(n, np.inf) if radius is None else \
            np.ascontiguousarray(radius, dtype=np.float64)
        h = np.full(n, -1, dtype=np.int64) if hint is None else \
            np.ascontiguousarray(hint, dtype=np.int64)
        if n < _SORT_MIN:
            return _query(p, h, r, *self._tree, self.a, self.b, self.c)
        o = spatial_order(p)
        d, f = _query(p.take(o, axis=0), h[o], r[o], *self._tree, self.a, self.b, self.c)
        out_d, out_f = np.empty_like(d), np.empty_like(f)
        out_d[o], out_f[o] = d, f
        return out_d, out_f

    def max_distance(self, points: np.ndarray, stop: float = np.inf) -> tuple[float, bool]:
        """(the largest distance from the points to their nearest triangles, stopped).

        Bit for bit ``query(points)[0].max()`` when not stopped, without finding each point's
        nearest triangle: a point with some triangle within the largest distance found so far
        cannot raise it (nearly every point, after the first few). ``stop``: once the largest
        distance found exceeds it, that distance (one evaluated, so at most the true largest)
        is returned with ``stopped`` True. No points: (0.0, False)."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = p.shape[0]
        if n == 0:
            return 0.0, False
        if not np.isfinite(p).all():
            raise ValueError("closest-point query: non-finite points")
        if self._tree is None:
            return np.inf, np.inf > stop
        if n >= _SORT_MIN:
            p = p.take(spatial_order(p), axis=0)
        m2, stopped = _max_query(p, float(stop), *self._tree, self.a, self.b, self.c)
        return float(np.sqrt(m2)), bool(stopped)
