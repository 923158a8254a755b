"""The height-field ("patch") bound: the largest distance from a triangle cell to a target
mesh, bounded in one step when the target's nearby patch lies over the whole cell.

Why: the branch and bound of :mod:`pipelines.surface_error` settles a cell by convexity
(``d_target <= d_F`` for one target triangle F) or by the two-triangle pair bound. A cell of a
coarse level spans many level-0 triangles, and near a level-0 vertex where several faces meet
neither bound is tight, so cells had to shrink to about level 0's triangle size before they
settled: on the bunny the level -> level-0 direction made 80% of the bound's queries, about 29
a cell (docs/BUILD.md). This bound settles such a cell without splitting it.

The bound. Put the cell T in its own frame: T in the plane z = 0, its normal the z axis. Let P
be the target triangles whose boxes meet T's box grown by ``rho`` and that reach within ``rho``
of T's plane (the patch; a triangle farther than ``rho`` from the plane is farther than
``rho`` from T, and leaving triangles out can only make the proof fail). For a point p of
T and a triangle F of P whose projection onto the plane contains p, the vertical line through
p meets F at height ``z_F(p)``, so ``d_target(p) <= |z_F(p)|`` (a point of F at that distance).
If the projections of the triangles of a sheet S of P (below) *cover* T, then

    max over T of d_target  <=  max over F in S of  max over pi(F) n T of |z_F|,

and ``z_F`` is linear over ``pi(F) n T`` (a convex polygon: F's projection clipped by T), so
its largest ``|z_F|`` is at one of the polygon's corners. That is the value returned, except
where a triangle's largest height there exceeds ``rho``: then the largest *exact* distance from
the polygon's corners to F is taken where it is smaller (``d(., F)`` is convex, so it bounds the
whole polygon; for a steep F, nearly edge-on, the height can be many times the distance).

Coverage, proven from the patch's combinatorics (no sampling). Of P, the sheet S is kept:
the triangles reaching into T (by more than a margin ``m``, 1e-12 of T's size) that face the
way most of the projected area faces (so the far side of a thin part and faces seen edge-on
stay out: leaving triangles out can only make the proof fail, never wrong). Let ``c(p)`` be
the number of S's projected triangles containing p. Moving p across T, ``c`` changes only
where p crosses the projection of an edge of S. Every edge of S reaching into T is checked to
be *interior and unfolded*: shared by exactly two triangles of S (over welded vertices) whose
third corners project strictly on opposite sides of its line; crossing it, one triangle ends
and the other begins, so ``c`` does not change. Where an edge reaching into T is a border or
a fold, the *component* of S it belongs to (the triangles joined to it through edges shared by
two triangles of S) is left out, and the proof is made for the rest: each of its edges reaching
into T has both triangles in the rest (they share a component), so the rest is a sheet as
above. (CAD parts lie on one another: a washer's open rim over a plate's face made the plate's
cells fail.) A non-manifold edge reaching into T still fails the cell. Hence ``c`` (of the
sheet kept) is one constant ``k`` on T shrunk by ``m``, the clipped areas of its triangles sum
to about ``k * area(T)``, and ``k >= 1`` when that sum is at least half of T's area (the strip
within ``m`` of the border holds at most a quarter of it, counted once per triangle: cells
thinner than that, inradius <= 8 PATCH_MAX m, are skipped).

Borders kept. A border edge E over T is kept instead, with its piece, when the part of T on
the side of E's line away from E's triangle is near E: its largest distance ``h_E`` to E (at
that convex polygon's corners) is at most ``rho``. (An in-place level's chord cuts over a
hole's rim: a sliver of the cell lies beyond the rim.) Then ``c`` changes across the borders
kept, by one, and nowhere else; the area test still gives a covered point q of T shrunk by
``m``. For a point p there that is not covered, walk from p to q: where ``c`` first rises, the
walk enters a border's triangle, so p lies on the side of that border's line away from its
triangle, and ``d(p) <= d(p, E) <= h_E`` (E is part of the target). The value returned is at
least every such ``h_E``.

The patch grown from seeds (:func:`patch_bound_seeded`, what the bound calls). The patch is
first grown from the target triangles known near the cell's corners, across the edges exactly
two triangles share, taking a triangle (and trying its neighbours) only where its box meets the
cell's grown by ``rho``, it reaches within ``rho`` of the cell's plane and its projection's box
meets the cell's: a subset of what the BVH gathers, so the proof above holds over it as it is
(leaving triangles out can only make the proof fail), and a triangle across a non-manifold edge
is never reached (its sheet is proven without it). Of the triangles the BVH gathers for a level
-> level-0 cell, 31% reach into the cell (42.8 a cell on the bunny, beast and 2CylinderEngine);
the grown patch skips the descent and most of the rest. Only where the grown patch is empty or
covers too little of the cell is the BVH's gathered instead (the corpus: the height field 1.69-1.76
-> 1.42-1.43 s, and 984 more cells bounded).

A point of T within ``m`` of its border (where edges reaching less than ``m`` in were not
checked) is within ``m * size / inradius`` of a point of T shrunk by ``m``, and the distance is
1-Lipschitz: that much is added. Anything else (a non-manifold edge over T, no sheet left
covering it (the reason then: the last border or fold left out), too many triangles, a sliver
cell) returns ``inf`` with the reason (``WHY_*``): the caller's other bounds and subdivision
take the cell, as before.

Rounding: corner heights are direct dot products (relative error ~1e-16 of coordinates of
order 1: the local frame has a unit diagonal). The height at a clip corner is interpolated
only over a well-conditioned projected triangle (its projected area at least ``1e-3`` of its
longest projected edge squared, and its plane's normal within ``acos(0.1)`` of the z axis, so
the slope is at most about 10); otherwise the triangle's largest corner height is used, which
bounds ``|z_F|`` on all of ``pi(F)`` (linear, so largest at a corner). An exact distance is
taken at a corner mapped back to the target's frame (rounding ~1e-16 of its coordinates; the
distance is 1-Lipschitz), rounded up like the result. Side tests require a
margin of ``1e-12`` of the cell's size squared. The result is rounded up by a relative
``1e-12`` and an absolute ``1e-13``.

Array contracts (``patch_bound_seeded`` also takes ``nbr (F, 3) int64``, per target triangle and
edge the other triangle of an edge exactly two share or -1 (:func:`pipelines.surface_error.edge_neighbours`),
and ``seeds (K, S) int64``, target triangles per cell or -1): cells ``v (K, 3, 3) float64``; ``rho (K,) float64`` (>= 0; inf: skip the cell);
the target's BVH arrays as :class:`pipelines.closest_point.ClosestTriangles` holds them
(``box (N, 6)``, ``left``, ``first``, ``count``, ``order`` int64); corners ``a, b, c (F, 3)
float64``; ``wtri (F, 3) int64`` the target's triangles over welded vertex ids (equal id: equal
position). Returns ``(K,) float64``: an upper bound of the cell's largest distance, or inf.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# error_model="numpy" on every kernel: a division by zero gives inf or NaN instead of raising, which
# drops numba's zero-divisor checks from the inner loops (the corpus's cold build 0.969x the time,
# outputs bit-identical); a NaN bound settles nothing (pipelines.surface_error._settle)

from assetpipe.pipelines.distance_kernels import _dist2
from assetpipe.pipelines.kernel_arrays import borrow

#: triangles of a patch at most (more: the cell is left to subdivision)
PATCH_MAX = 192
# slots of the per-cell edge table (open addressing, at most 3 * PATCH_MAX = 576 edges: load <= 0.56)
_HASH = 1024
_STACK = 128
_ORIENT_MARGIN = 1e-12   # side tests: margin, times the cell's size squared
_WELL_SHAPED = 1e-3      # projected area >= this x longest projected edge^2: interpolate
_MIN_COS = 0.1           # and the plane's normal within acos(0.1) of the cell's normal
_UP_REL = 1e-12
_UP_ABS = 1e-13

# why a cell got its value
WHY_BOUNDED = 0    # bounded
WHY_SKIPPED = 1    # no radius, or a sliver cell
WHY_TOO_MANY = 2   # more than PATCH_MAX triangles near the cell
WHY_UNCOVERED = 3  # no triangle near, or the projections cover no point of it
WHY_BORDER = 4     # an edge over the cell has one triangle of the patch (a border)
WHY_NON_MANIFOLD = 5  # an edge over the cell has more than two
WHY_FOLDED = 6     # an edge over the cell has both triangles on one side (a fold)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _in_slab(a, b, c, f, nx, ny, nz, off, r):
    """Whether triangle f reaches within ``r`` of the plane ``n . p = off`` (unit n): a triangle
    wholly farther is farther than ``r`` from the cell in it."""
    za = nx * a[f, 0] + ny * a[f, 1] + nz * a[f, 2] - off
    zb = nx * b[f, 0] + ny * b[f, 1] + nz * b[f, 2] - off
    zc = nx * c[f, 0] + ny * c[f, 1] + nz * c[f, 2] - off
    return not ((za > r and zb > r and zc > r) or (za < -r and zb < -r and zc < -r))


@njit(cache=True, nogil=True, error_model="numpy")
def _overlap(box, left, first, count, order, lo, hi, out, stack, p0, n, r, a, b, c):
    """Triangles whose box meets [lo, hi] and that reach into the slab within ``r`` of the
    plane through ``p0`` with unit normal ``n`` (a triangle wholly farther than ``r`` from the
    cell's plane is farther than ``r`` from the cell: leaving it out of the patch can only
    make the proof fail, never wrong), into ``out``; their number, or -1 if more than ``out``
    holds."""
    nx, ny, nz = n[0], n[1], n[2]
    ax_, ay_, az_ = abs(nx), abs(ny), abs(nz)
    off = nx * p0[0] + ny * p0[1] + nz * p0[2]
    n_out = 0
    top = 1
    stack[0] = 0
    while top > 0:
        top -= 1
        node = stack[top]
        if (box[node, 0] > hi[0] or box[node, 1] > hi[1] or box[node, 2] > hi[2]
                or box[node, 3] < lo[0] or box[node, 4] < lo[1] or box[node, 5] < lo[2]):
            continue
        # the box's extent along n against the slab
        s = nx * (box[node, 0] + box[node, 3]) * 0.5 + ny * (box[node, 1] + box[node, 4]) * 0.5 \
            + nz * (box[node, 2] + box[node, 5]) * 0.5 - off
        rb = (ax_ * (box[node, 3] - box[node, 0]) + ay_ * (box[node, 4] - box[node, 1])
              + az_ * (box[node, 5] - box[node, 2])) * 0.5
        if s - rb > r or s + rb < -r:
            continue
        l = left[node]
        if l < 0:
            for j in range(first[node], first[node] + count[node]):
                f = order[j]
                if not _in_slab(a, b, c, f, nx, ny, nz, off, r):
                    continue
                if n_out >= out.shape[0]:
                    return -1
                out[n_out] = f
                n_out += 1
            continue
        if top + 2 > stack.shape[0]:
            return -1
        stack[top] = l
        stack[top + 1] = l + 1
        top += 2
    return n_out


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True, nogil=True, error_model="numpy")
def _separated(px, py, m, tx, ty, margin):
    """Whether the convex polygon (px, py)[:m] is separated from triangle (tx, ty) (CCW) by
    more than ``margin`` along one of the edge normals of either (exact separating-axis test
    for convex shapes in 2D; a segment is a 2-gon). False means they may touch. (Each side
    value is compared with ``margin`` times the edge's length instead of being divided by it:
    the same test, without a division per corner.)"""
    # the triangle's edges: the polygon entirely to the right of one of them
    for e in range(3):
        x0, y0 = tx[e], ty[e]
        x1, y1 = tx[(e + 1) % 3], ty[(e + 1) % 3]
        ex, ey = x1 - x0, y1 - y0
        ln = np.sqrt(ex * ex + ey * ey)
        if not ln > 0.0:
            continue
        lim = -margin * ln
        allout = True
        for q in range(m):
            if ex * (py[q] - y0) - ey * (px[q] - x0) > lim:
                allout = False
                break
        if allout:
            return True
    return _separated_by_own(px, py, m, tx, ty, margin)


@njit(cache=True, nogil=True, error_model="numpy")
def _separated_by_own(px, py, m, tx, ty, margin):
    """The polygon's half of :func:`_separated`: separated along one of its own edge normals
    (either direction: the polygon's orientation is not known)."""
    for e in range(m if m > 2 else 1):
        x0, y0 = px[e], py[e]
        x1, y1 = px[(e + 1) % m], py[(e + 1) % m]
        ex, ey = x1 - x0, y1 - y0
        ln = np.sqrt(ex * ex + ey * ey)
        if not ln > 0.0:
            continue
        smin, smax = np.inf, -np.inf
        for q in range(m):
            s = ex * (py[q] - y0) - ey * (px[q] - x0)
            smin, smax = min(smin, s), max(smax, s)
        tmin, tmax = np.inf, -np.inf
        for q in range(3):
            s = ex * (ty[q] - y0) - ey * (tx[q] - x0)
            tmin, tmax = min(tmin, s), max(tmax, s)
        lim = margin * ln
        if tmin > smax + lim or tmax < smin - lim:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _clip(px, py, tx, ty, ox, oy, bx, by):
    """Triangle (px, py) clipped by triangle (tx, ty) (CCW): the polygon's corners into
    (ox, oy) (at most 9), their number. ``bx, by`` scratch of the same size."""
    m = 3
    for q in range(3):
        ox[q], oy[q] = px[q], py[q]
    for e in range(3):
        x0, y0 = tx[e], ty[e]
        x1, y1 = tx[(e + 1) % 3], ty[(e + 1) % 3]
        ex, ey = x1 - x0, y1 - y0
        n = 0
        for q in range(m):
            cx, cy = ox[q], oy[q]
            dx, dy = ox[(q + 1) % m], oy[(q + 1) % m]
            sc = ex * (cy - y0) - ey * (cx - x0)
            sd = ex * (dy - y0) - ey * (dx - x0)
            if sc >= 0.0:
                bx[n], by[n] = cx, cy
                n += 1
            if (sc >= 0.0) != (sd >= 0.0):
                t = sc / (sc - sd)
                bx[n], by[n] = cx + t * (dx - cx), cy + t * (dy - cy)
                n += 1
        m = n
        for q in range(m):
            ox[q], oy[q] = bx[q], by[q]
        if m == 0:
            return 0
    return m


@njit(cache=True, nogil=True, error_model="numpy")
def _height(fx, fy, fz, j, ar, ox, oy, mc):
    """Largest |z| of triangle j's plane over its projection clipped to (ox, oy)[:mc]:
    interpolated at the polygon's corners when the projection is well-shaped and not too
    steep, else (and never above) the triangle's largest corner height."""
    zc = max(abs(fz[j, 0]), abs(fz[j, 1]), abs(fz[j, 2]))
    l01 = (fx[j, 1] - fx[j, 0]) ** 2 + (fy[j, 1] - fy[j, 0]) ** 2
    l12 = (fx[j, 2] - fx[j, 1]) ** 2 + (fy[j, 2] - fy[j, 1]) ** 2
    l20 = (fx[j, 0] - fx[j, 2]) ** 2 + (fy[j, 0] - fy[j, 2]) ** 2
    # twice F's true area, for its plane's tilt: cos = projected / true area
    ux, uy, uz = fx[j, 1] - fx[j, 0], fy[j, 1] - fy[j, 0], fz[j, 1] - fz[j, 0]
    wx, wy, wz = fx[j, 2] - fx[j, 0], fy[j, 2] - fy[j, 0], fz[j, 2] - fz[j, 0]
    cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    a3 = np.sqrt(cx * cx + cy * cy + cz * cz)
    if abs(ar) >= _WELL_SHAPED * max(l01, l12, l20) and abs(ar) >= _MIN_COS * a3:
        zmax = 0.0
        for q in range(mc):
            w1 = _orient(fx[j, 0], fy[j, 0], ox[q], oy[q], fx[j, 2], fy[j, 2]) / ar
            w2 = _orient(fx[j, 0], fy[j, 0], fx[j, 1], fy[j, 1], ox[q], oy[q]) / ar
            z = fz[j, 0] + w1 * (fz[j, 1] - fz[j, 0]) + w2 * (fz[j, 2] - fz[j, 0])
            zmax = max(zmax, abs(z))
        zc = min(zc, zmax)
    return zc


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _seg_d2(px, py, ax, ay, az, bx, by, bz):
    """Squared distance from (px, py, 0) to the segment (ax, ay, az)-(bx, by, bz)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, -az
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = min(1.0, max(0.0, (wx * ex + wy * ey + wz * ez) / ee))
    dx, dy, dz = wx - t * ex, wy - t * ey, wz - t * ez
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True, error_model="numpy")
def _beyond_edge(tx, ty, x0, y0, z0, x1, y1, z1, sig, tol):
    """The largest distance from the part of T (tx, ty) on the side of the line (x0, y0)-(x1, y1)
    away from its triangle (``sig``: the sign of ``_orient`` for the triangle's third corner),
    grown by ``tol`` (in ``_orient``'s units), to the segment (x0, y0, z0)-(x1, y1, z1): at that
    convex polygon's corners (the distance to a segment is convex)."""
    best = 0.0
    for q in range(3):
        ax_, ay_ = tx[q], ty[q]
        bx_, by_ = tx[(q + 1) % 3], ty[(q + 1) % 3]
        ga = sig * _orient(x0, y0, x1, y1, ax_, ay_) - tol
        gb = sig * _orient(x0, y0, x1, y1, bx_, by_) - tol
        if ga <= 0.0:
            best = max(best, _seg_d2(ax_, ay_, x0, y0, z0, x1, y1, z1))
        if (ga <= 0.0) != (gb <= 0.0):
            t = ga / (ga - gb)
            best = max(best, _seg_d2(ax_ + t * (bx_ - ax_), ay_ + t * (by_ - ay_), x0, y0, z0, x1, y1, z1))
    return np.sqrt(best)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _root(parent, j):
    """The component of triangle j (union-find without path compression: at most PATCH_MAX)."""
    while parent[j] != j:
        j = parent[j]
    return j


@njit(cache=True, nogil=True, error_model="numpy")
def patch_bound_seeded(v, rho, box, left, first, count, order, a, b, c, wtri, nbr, seeds):
    """See the module docstring. Returns ((K,) float64 upper bounds, inf where the patch bound
    does not apply; (K,) int8 why: one of the ``WHY_*`` codes)."""
    k = v.shape[0]
    out = np.full(k, np.inf)
    why = np.full(k, WHY_SKIPPED, dtype=np.int8)
    first_attempt = 0 if (seeds.shape[1] > 0 and nbr.shape[0] == a.shape[0]) else 1
    nvis = nbr.shape[0] if first_attempt == 0 else 0
    # the work space, made here and handed over as arguments: the kernel borrows every array it
    # gets (pipelines.kernel_arrays), so its helper calls on every patch triangle count no
    # references, and these outlive it
    _patch_bound_into(
        v, rho, box, left, first, count, order, a, b, c, wtri, nbr, seeds, out, why, first_attempt,
        np.empty(PATCH_MAX, dtype=np.int64),  # sel
        np.empty(_STACK, dtype=np.int64),  # stack
        np.empty((PATCH_MAX, 3)),  # fx
        np.empty((PATCH_MAX, 3)),  # fy
        np.empty((PATCH_MAX, 3)),  # fz
        np.empty(PATCH_MAX),  # far_: twice the signed projected area
        np.zeros(PATCH_MAX, dtype=np.int8),  # side: +1 / -1: reaches into T, facing so; 0: not
        np.empty(PATCH_MAX),  # zmax
        np.zeros(PATCH_MAX),  # carea: the area of its projection clipped by T
        np.empty(PATCH_MAX, dtype=np.int64),  # comp: union-find parent: the sheet's components
        np.zeros(PATCH_MAX, dtype=np.bool_),  # dropc: a component left out (a border or fold over T)
        np.zeros(PATCH_MAX),  # comp_area: per component (at its root): its triangles' clipped areas
        np.empty(3),  # lo
        np.empty(3),  # hi
        np.empty(3),  # nv
        np.empty(3),  # tx
        np.empty(3),  # ty
        np.empty(12),  # ox
        np.empty(12),  # oy
        np.empty(12),  # bx
        np.empty(12),  # by
        np.empty(2),  # sx
        np.empty(2),  # sy
        np.zeros(_HASH, dtype=np.int64),  # hstamp
        np.empty(_HASH, dtype=np.int64),  # hkey
        np.empty(_HASH, dtype=np.int64),  # hidx
        np.empty(3 * PATCH_MAX, dtype=np.int64),  # uslot
        np.empty(3 * PATCH_MAX, dtype=np.int64),  # ucount
        np.empty(3 * PATCH_MAX, dtype=np.int64),  # uref0
        np.empty(3 * PATCH_MAX, dtype=np.int64),  # uref1
        np.empty(3),  # tex
        np.empty(3),  # tey
        np.empty(3),  # tln
        np.empty(3),  # tlim
        np.empty((3, 3)),  # vq
        np.zeros(nvis, dtype=np.int32),  # vis: the grown patch's visit stamps
        np.empty(3 * PATCH_MAX + seeds.shape[1], dtype=np.int64),  # fstack
    )
    return out, why


@njit(cache=True, nogil=True, error_model="numpy")
def _patch_bound_into(v, rho, box, left, first, count, order, a, b, c, wtri, nbr, seeds, out, why,
                      first_attempt,
                      sel, stack, fx, fy, fz, far_, side, zmax, carea, comp, dropc, comp_area, lo,
                      hi, nv, tx, ty, ox, oy, bx, by, sx, sy, hstamp, hkey, hidx, uslot, ucount,
                      uref0, uref1, tex, tey, tln, tlim, vq, vis, fstack):
    """:func:`patch_bound_seeded` into ``out`` and ``why``, with its work space given (every
    array borrowed)."""
    (v, rho, box, left, first, count, order, a, b, c, wtri, nbr, seeds, out, why, sel, stack, fx, fy,
     fz, far_, side, zmax, carea, comp, dropc, comp_area, lo, hi, nv, tx, ty, ox, oy, bx, by, sx, sy,
     hstamp, hkey, hidx, uslot, ucount, uref0, uref1, tex, tey, tln, tlim, vq, vis, fstack) = (
        borrow(v), borrow(rho), borrow(box), borrow(left), borrow(first), borrow(count), borrow(order),
        borrow(a), borrow(b), borrow(c), borrow(wtri), borrow(nbr), borrow(seeds), borrow(out),
        borrow(why), borrow(sel), borrow(stack), borrow(fx), borrow(fy), borrow(fz), borrow(far_),
        borrow(side), borrow(zmax), borrow(carea), borrow(comp), borrow(dropc), borrow(comp_area),
        borrow(lo), borrow(hi), borrow(nv), borrow(tx), borrow(ty), borrow(ox), borrow(oy), borrow(bx),
        borrow(by), borrow(sx), borrow(sy), borrow(hstamp), borrow(hkey), borrow(hidx), borrow(uslot),
        borrow(ucount), borrow(uref0), borrow(uref1), borrow(tex), borrow(tey), borrow(tln),
        borrow(tlim), borrow(vq), borrow(vis), borrow(fstack)
    )
    k = v.shape[0]
    stamp = 0
    vstamp = 0
    for i in range(k):
        r = rho[i]
        if not (r >= 0.0 and r < np.inf):
            continue
        p0x, p0y, p0z = v[i, 0, 0], v[i, 0, 1], v[i, 0, 2]
        e1x, e1y, e1z = v[i, 1, 0] - p0x, v[i, 1, 1] - p0y, v[i, 1, 2] - p0z
        gx, gy, gz = v[i, 2, 0] - p0x, v[i, 2, 1] - p0y, v[i, 2, 2] - p0z
        nx, ny, nz = e1y * gz - e1z * gy, e1z * gx - e1x * gz, e1x * gy - e1y * gx
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        l1 = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        if not (nn > 0.0 and l1 > 0.0):
            continue
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        e1x, e1y, e1z = e1x / l1, e1y / l1, e1z / l1
        # e2 = n x e1
        e2x, e2y, e2z = ny * e1z - nz * e1y, nz * e1x - nx * e1z, nx * e1y - ny * e1x
        tx[0], ty[0] = 0.0, 0.0
        tx[1], ty[1] = l1, 0.0
        tx[2], ty[2] = gx * e1x + gy * e1y + gz * e1z, gx * e2x + gy * e2y + gz * e2z
        area_t = 0.5 * _orient(tx[0], ty[0], tx[1], ty[1], tx[2], ty[2])
        l2 = np.sqrt(gx * gx + gy * gy + gz * gz)
        l3 = np.sqrt((tx[2] - l1) ** 2 + ty[2] ** 2)
        size = max(l1, l2, l3)
        perim = l1 + l2 + l3
        margin = _ORIENT_MARGIN * size
        margin2 = _ORIENT_MARGIN * size * size
        # a sliver cell (inradius 2 area / perimeter): left to the other bounds
        if not 2.0 * area_t / perim > 8.0 * PATCH_MAX * margin:
            continue
        for q in range(3):
            lo[q] = min(v[i, 0, q], v[i, 1, q], v[i, 2, q]) - r
            hi[q] = max(v[i, 0, q], v[i, 1, q], v[i, 2, q]) + r
        nv[0], nv[1], nv[2] = nx, ny, nz
        for e in range(3):  # T's edges, for every triangle's side tests
            tex[e] = tx[(e + 1) % 3] - tx[e]
            tey[e] = ty[(e + 1) % 3] - ty[e]
            tln[e] = np.sqrt(tex[e] * tex[e] + tey[e] * tey[e])
            tlim[e] = margin * tln[e]
        # T's projected box, shrunk by margin: a triangle whose box misses it reaches into T
        # by less than margin (and leaving a triangle out is never wrong)
        txl, txh = min(0.0, tx[2]) + margin, max(l1, tx[2]) - margin
        tyl, tyh = min(0.0, ty[2]) + margin, max(0.0, ty[2]) - margin
        # the patch: first grown from the seed triangles across shared edges (only triangles whose
        # box meets the cell's, that reach its slab and whose projection's box meets its own: a
        # subset of what the BVH gathers, so the proof below holds as well, over fewer triangles);
        # where that does not bound the cell, gathered from the BVH as before
        for attempt in range(first_attempt, 2):
            why[i] = WHY_SKIPPED
            if attempt == 0:
                vstamp += 1
                m = _flood(nbr, seeds, i, lo, hi, sel, fstack, vis, vstamp, p0x, p0y, p0z, e1x, e1y, e1z,
                           e2x, e2y, e2z, nx, ny, nz, r, a, b, c, txl, txh, tyl, tyh)
                if m <= 0:
                    continue
            else:
                m = _overlap(box, left, first, count, order, lo, hi, sel, stack, v[i, 0], nv, r, a, b, c)
                if m <= 0:
                    why[i] = WHY_TOO_MANY if m < 0 else WHY_UNCOVERED
                    continue
            # project; each triangle reaching into T (deeper than margin): the sign of its
            # projected area, the area of its projection clipped by T, its largest height there
            area_pos = 0.0
            area_neg = 0.0
            for j in range(m):
                f = sel[j]
                for q in range(3):
                    if q == 0:
                        qx, qy, qz = a[f, 0] - p0x, a[f, 1] - p0y, a[f, 2] - p0z
                    elif q == 1:
                        qx, qy, qz = b[f, 0] - p0x, b[f, 1] - p0y, b[f, 2] - p0z
                    else:
                        qx, qy, qz = c[f, 0] - p0x, c[f, 1] - p0y, c[f, 2] - p0z
                    fx[j, q] = qx * e1x + qy * e1y + qz * e1z
                    fy[j, q] = qx * e2x + qy * e2y + qz * e2z
                    fz[j, q] = qx * nx + qy * ny + qz * nz
                ar = _orient(fx[j, 0], fy[j, 0], fx[j, 1], fy[j, 1], fx[j, 2], fy[j, 2])
                far_[j] = ar
                side[j] = 0
                if not abs(ar) > margin2:
                    continue  # seen edge-on (no area)
                # not reaching into T: first by the boxes of the projections (a gap between them
                # is a gap between the shapes), then exactly
                if (min(fx[j, 0], fx[j, 1], fx[j, 2]) > txh or max(fx[j, 0], fx[j, 1], fx[j, 2]) < txl
                        or min(fy[j, 0], fy[j, 1], fy[j, 2]) > tyh
                        or max(fy[j, 0], fy[j, 1], fy[j, 2]) < tyl):
                    continue
                # T's edges against F's corners, once: the side values of _separated's first half
                # and of _clip's first pass. F is separated when all its corners lie outside one
                # edge (by margin); it reaches into T when one corner lies inside all three by more
                # than margin (T then holds a disc of radius margin around it, so no axis of F's
                # separates them either: _separated's second half is skipped); when all lie inside,
                # the clipped polygon is F itself (what _clip returns then, bit for bit). On the
                # corpus's captured cells: the same values and reasons, 13% less time.
                allin = True
                anyin = False
                for q in range(3):
                    inq = True
                    for e in range(3):
                        val = tex[e] * (fy[j, q] - ty[e]) - tey[e] * (fx[j, q] - tx[e])
                        vq[e, q] = val
                        if not val > tlim[e]:
                            inq = False
                        if not val >= 0.0:
                            allin = False
                    anyin = anyin or inq
                sep = False
                for e in range(3):
                    if tln[e] > 0.0 and vq[e, 0] <= tlim[e] and vq[e, 1] <= tlim[e] and vq[e, 2] <= tlim[e]:
                        sep = True
                        break
                if sep or (not anyin and _separated_by_own(fx[j], fy[j], 3, tx, ty, -margin)):
                    continue
                if allin:
                    for q in range(3):
                        ox[q], oy[q] = fx[j, q], fy[j, q]
                    mc = 3
                else:
                    mc = _clip(fx[j], fy[j], tx, ty, ox, oy, bx, by)
                if mc == 0:
                    continue
                s = 0.0
                for q in range(mc):
                    s += ox[q] * oy[(q + 1) % mc] - ox[(q + 1) % mc] * oy[q]
                carea[j] = 0.5 * abs(s)
                if ar > 0.0:
                    area_pos += carea[j]
                    side[j] = 1
                else:
                    area_neg += carea[j]
                    side[j] = -1
                zmax[j] = _height(fx, fy, fz, j, ar, ox, oy, mc)
                if zmax[j] > r:
                    # above the threshold by its height: its exact distance at the polygon's corners
                    # (back in the target's frame; d(., F) is convex), where smaller
                    ze = 0.0
                    for q in range(mc):
                        ze = max(ze, _dist2(p0x + ox[q] * e1x + oy[q] * e2x,
                                            p0y + ox[q] * e1y + oy[q] * e2y,
                                            p0z + ox[q] * e1z + oy[q] * e2z, a, b, c, f))
                    zmax[j] = min(zmax[j], np.sqrt(ze) * (1.0 + _UP_REL) + _UP_ABS)
            # the patch S: the triangles reaching into T that face the way most of the projected
            # area faces (one sheet: the facing-away sheet of a thin part and faces seen edge-on
            # stay out; leaving triangles out can only make the proof fail, never wrong)
            sg = 1 if area_pos >= area_neg else -1
            if not max(area_pos, area_neg) >= 0.5 * area_t:
                why[i] = WHY_UNCOVERED
                continue
            best = 0.0
            nu = 0   # unique edges, in first-seen order
            stamp += 1
            for j in range(m):
                if side[j] != sg:
                    continue
                best = max(best, zmax[j])
                f = sel[j]
                for e in range(3):
                    u, w = wtri[f, e], wtri[f, (e + 1) % 3]
                    key = (min(u, w) << 32) | max(u, w)
                    hs = ((key * 0x5851F42D4C957F2D) >> 54) & (_HASH - 1)  # multiplicative hash (odd constant < 2^63; int64 wraps)
                    while True:
                        if hstamp[hs] != stamp:
                            hstamp[hs] = stamp
                            hkey[hs] = key
                            uslot[nu] = hs
                            ucount[nu] = 1
                            uref0[nu] = 3 * j + e
                            hidx[hs] = nu
                            nu += 1
                            break
                        if hkey[hs] == key:
                            q = hidx[hs]
                            if ucount[q] == 1:
                                uref1[q] = 3 * j + e
                            ucount[q] += 1
                            break
                        hs = (hs + 1) & (_HASH - 1)
            # the sheet's components: triangles joined through the edges two of them share, and
            # the area each projects into T
            for j in range(m):
                comp[j] = j
                dropc[j] = False
                comp_area[j] = 0.0
            for q in range(nu):
                if ucount[q] == 2:
                    ra = _root(comp, uref0[q] // 3)
                    rb = _root(comp, uref1[q] // 3)
                    if ra != rb:
                        comp[max(ra, rb)] = min(ra, rb)
            for j in range(m):
                if side[j] == sg:
                    comp_area[_root(comp, j)] += carea[j]
            left_area = area_pos if sg > 0 else area_neg
            # every edge of S reaching into T: interior to S (exactly two triangles of S) and
            # unfolded (their third corners strictly on opposite sides of its line), or its
            # component is left out
            ok = True
            dropped = False
            beyond = 0.0   # the largest distance bounded beyond a border kept
            for q in range(nu):
                cnt = ucount[q]
                # what would be wrong with this edge if it reached into T (cheap), and only then
                # whether it does (testing reaching only for bad edges: 6% less time on the corpus's
                # captured cells, 1.98 -> 1.85 s); a bad edge of a component already left out
                # needs no test
                if cnt <= 2 and dropc[_root(comp, uref0[q] // 3)]:
                    continue
                bad = 0
                if cnt != 2:
                    bad = WHY_BORDER if cnt == 1 else WHY_NON_MANIFOLD
                else:
                    ja, ea = uref0[q] // 3, uref0[q] % 3
                    jb, eb = uref1[q] // 3, uref1[q] % 3
                    if wtri[sel[ja], ea] == wtri[sel[ja], (ea + 1) % 3]:
                        bad = WHY_FOLDED  # a degenerate edge (one welded vertex)
                    else:
                        s1 = _orient(fx[ja, ea], fy[ja, ea], fx[ja, (ea + 1) % 3], fy[ja, (ea + 1) % 3],
                                     fx[ja, (ea + 2) % 3], fy[ja, (ea + 2) % 3])
                        s2 = _orient(fx[ja, ea], fy[ja, ea], fx[ja, (ea + 1) % 3], fy[ja, (ea + 1) % 3],
                                     fx[jb, (eb + 2) % 3], fy[jb, (eb + 2) % 3])
                        if not ((s1 > margin2 and s2 < -margin2) or (s1 < -margin2 and s2 > margin2)):
                            bad = WHY_FOLDED
                if bad == 0:
                    continue
                # reaching: any copy's segment not separated from T (the copies join the same two
                # welded positions, maybe in the other direction, which rounds the side tests
                # differently: each is tried until one reaches, as when the edges were sorted)
                reaching = False
                j, e = uref0[q] // 3, uref0[q] % 3
                sx[0], sy[0] = fx[j, e], fy[j, e]
                sx[1], sy[1] = fx[j, (e + 1) % 3], fy[j, (e + 1) % 3]
                if not _separated(sx, sy, 2, tx, ty, -margin):
                    reaching = True
                elif cnt >= 2:
                    j, e = uref1[q] // 3, uref1[q] % 3
                    sx[0], sy[0] = fx[j, e], fy[j, e]
                    sx[1], sy[1] = fx[j, (e + 1) % 3], fy[j, (e + 1) % 3]
                    if not _separated(sx, sy, 2, tx, ty, -margin):
                        reaching = True
                if not reaching and cnt > 2:  # a non-manifold edge (rare): its other copies
                    key = hkey[uslot[q]]
                    for j in range(m):
                        if side[j] != sg or reaching:
                            continue
                        f = sel[j]
                        for e in range(3):
                            u, w = wtri[f, e], wtri[f, (e + 1) % 3]
                            if ((min(u, w) << 32) | max(u, w)) != key or 3 * j + e == uref0[q] \
                                    or 3 * j + e == uref1[q]:
                                continue
                            sx[0], sy[0] = fx[j, e], fy[j, e]
                            sx[1], sy[1] = fx[j, (e + 1) % 3], fy[j, (e + 1) % 3]
                            if not _separated(sx, sy, 2, tx, ty, -margin):
                                reaching = True
                                break
                if reaching:
                    why[i] = bad
                    if bad == WHY_NON_MANIFOLD:
                        ok = False
                        break
                    if bad == WHY_BORDER:
                        # a border kept where the part of T beyond its line is near it (a level's
                        # chord cutting over a hole's rim): uncovered points lie there (module
                        # docstring), each within that distance of the border, which is level 0's
                        jj, ee = uref0[q] // 3, uref0[q] % 3
                        s1 = _orient(fx[jj, ee], fy[jj, ee], fx[jj, (ee + 1) % 3], fy[jj, (ee + 1) % 3],
                                     fx[jj, (ee + 2) % 3], fy[jj, (ee + 2) % 3])
                        hb = _beyond_edge(tx, ty, fx[jj, ee], fy[jj, ee], fz[jj, ee], fx[jj, (ee + 1) % 3],
                                          fy[jj, (ee + 1) % 3], fz[jj, (ee + 1) % 3],
                                          1.0 if s1 > 0.0 else -1.0, margin2)
                        if hb <= r:
                            beyond = max(beyond, hb)
                            continue
                    # a border or a fold over T: its component is left out (the rest may still
                    # cover T; leaving triangles out can only make the proof fail)
                    rr = _root(comp, uref0[q] // 3)
                    dropc[rr] = True
                    dropped = True
                    left_area -= comp_area[rr]
                    if left_area < 0.5 * area_t * (1.0 - 1e-9):  # clearly too little left (else summed below)
                        ok = False
                        break
            if ok and dropped:
                # the rest of the sheet: its own largest value, and it must cover T by itself
                best = 0.0
                kept = 0.0
                for j in range(m):
                    if side[j] == sg and not dropc[_root(comp, j)]:
                        kept += carea[j]
                        best = max(best, zmax[j])
                ok = kept >= 0.5 * area_t
            if ok:
                # points within ``margin`` of T's border may be uncovered (edges reaching less
                # than that into T are not checked): each is within margin * size / inradius of
                # a covered point, and the distance is 1-Lipschitz
                slack = margin * perim * size / (2.0 * area_t)
                out[i] = (max(best, beyond) + slack) * (1.0 + _UP_REL) + _UP_ABS
                why[i] = WHY_BOUNDED
            # bounded, or given up over a patch: no second gather (one is made only where the
            # grown patch was empty or covered too little of the cell: ``continue`` above)
            break


@njit(cache=True, nogil=True, error_model="numpy")
def patch_bound(v, rho, box, left, first, count, order, a, b, c, wtri):
    """:func:`patch_bound_seeded` without seeds: the patch gathered from the BVH alone."""
    return patch_bound_seeded(v, rho, box, left, first, count, order, a, b, c, wtri,
                              np.zeros((0, 3), dtype=np.int64), np.zeros((v.shape[0], 0), dtype=np.int64))


@njit(cache=True, nogil=True, error_model="numpy")
def _flood(nbr, seeds, i, lo, hi, out, fstack, vis, vstamp, p0x, p0y, p0z, e1x, e1y, e1z, e2x, e2y,
           e2z, nx, ny, nz, r, a, b, c, txl, txh, tyl, tyh):
    """The patch grown from cell ``i``'s seed triangles across the edges two triangles share
    (``nbr``): a triangle is taken, and its neighbours tried, when its box meets [lo, hi], it
    reaches within ``r`` of the cell's plane and its projection's box meets the cell's own
    (shrunk by the margin, ``txl``..``tyh``): each is a test :func:`_overlap` or the projection
    loop applies too, so this is a subset of their patch. Returns the count put in ``out``, or
    -1 if more than it holds."""
    off = nx * p0x + ny * p0y + nz * p0z
    top = 0
    for s in range(seeds.shape[1]):
        f = seeds[i, s]
        if f >= 0 and vis[f] != vstamp:
            vis[f] = vstamp
            fstack[top] = f
            top += 1
    n_out = 0
    while top > 0:
        top -= 1
        f = fstack[top]
        if (min(a[f, 0], b[f, 0], c[f, 0]) > hi[0] or max(a[f, 0], b[f, 0], c[f, 0]) < lo[0]
                or min(a[f, 1], b[f, 1], c[f, 1]) > hi[1] or max(a[f, 1], b[f, 1], c[f, 1]) < lo[1]
                or min(a[f, 2], b[f, 2], c[f, 2]) > hi[2] or max(a[f, 2], b[f, 2], c[f, 2]) < lo[2]):
            continue
        if not _in_slab(a, b, c, f, nx, ny, nz, off, r):
            continue
        ax_ = (a[f, 0] - p0x) * e1x + (a[f, 1] - p0y) * e1y + (a[f, 2] - p0z) * e1z
        bx_ = (b[f, 0] - p0x) * e1x + (b[f, 1] - p0y) * e1y + (b[f, 2] - p0z) * e1z
        cx_ = (c[f, 0] - p0x) * e1x + (c[f, 1] - p0y) * e1y + (c[f, 2] - p0z) * e1z
        if min(ax_, bx_, cx_) > txh or max(ax_, bx_, cx_) < txl:
            continue
        ay_ = (a[f, 0] - p0x) * e2x + (a[f, 1] - p0y) * e2y + (a[f, 2] - p0z) * e2z
        by_ = (b[f, 0] - p0x) * e2x + (b[f, 1] - p0y) * e2y + (b[f, 2] - p0z) * e2z
        cy_ = (c[f, 0] - p0x) * e2x + (c[f, 1] - p0y) * e2y + (c[f, 2] - p0z) * e2z
        if min(ay_, by_, cy_) > tyh or max(ay_, by_, cy_) < tyl:
            continue
        if n_out >= out.shape[0]:
            return -1
        out[n_out] = f
        n_out += 1
        for e in range(3):
            g = nbr[f, e]
            if g >= 0 and vis[g] != vstamp:
                vis[g] = vstamp
                fstack[top] = g
                top += 1
    return n_out
