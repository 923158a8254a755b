"""Surface error between two triangle meshes: a proven upper bound of the two-sided Hausdorff
distance, and an RMS estimate.

Method (deterministic)
----------------------
1. Both meshes are put in the *reference's* local frame: centred on the reference's bounding
   box and scaled to a unit diagonal, in float64. The same relative error then comes out for
   a model offset by 1e7 or scaled by 1e-6. Non-finite coordinates are refused
   (``ValueError``): the caller filters them before.
2. Closest points come from fcpw's BVH (``find_closest_points``, float32 SIMD traversal). Its
   float32 distance is not trusted: for every query the distance to the triangle it returned
   is recomputed exactly in float64 (:func:`closest_point_on_triangles`). That value is the
   distance to *a* triangle of the mesh, hence never below the true distance: every number
   the bound is built from is an upper value.
3. One direction, A -> B (reference -> level: what was lost; level -> reference: what was
   added), is bounded by branch and bound over A's triangles. ``d_B`` (distance to B) is
   1-Lipschitz, so on a triangle T with corner values ``d_i``
   ``max_T d_B <= max_i d_i + R(T)``, R the covering radius of the corners on T (the
   circumradius for a non-obtuse triangle; for one obtuse at C, ``max(|CA|/(2 cos A),
   |CB|/(2 cos B))``; exact), and ``<= min_i (d_i + max_j |v_j - v_i|)``. And ``d_B <= d_F``
   for any triangle F of B, where ``d_F`` is convex: ``max_T d_B <= max_i d_F(v_i)``, tried
   for the triangles nearest to T's corners and centroid (exact on a surface that is a
   parallel offset). A global lower value ``L`` is the largest distance evaluated (corners,
   centroids, samples). Triangles whose bound is <= ``(1 + tolerance) L`` (or ``L + 1e-12``)
   are settled; the others are split 4 ways at the edge midpoints and bounded again, until
   none is left or ``work_budget`` queries are spent. The direction's result is the largest
   bound of any settled or remaining triangle: an *upper bound*, within ``(1 + tolerance)``
   of the true maximum when ``converged``.
4. ``hausdorff`` is the larger of the two directions' upper bounds; ``hausdorff_lower`` the
   largest distance evaluated (a lower bound up to the float32 engine's choice of triangle:
   within about 1e-7 of the diagonal). Triangles both meshes share (same three vertices,
   :func:`measure_levels`) are 0 apart and skipped; so are shared vertices.
5. ``rms`` is an *estimate*: ``sqrt((mean_ab + mean_ba) / 2)`` of the squared distances of
   ``samples`` area-weighted random points per side (fixed seed), the mean of the two
   one-sided mean-square distances. Those points also raise ``L``.

Results are in model units and as a fraction of the reference's bounding-box diagonal
(``*_rel``). An empty mesh against a non-empty one is infinitely far (``inf``); two empty
meshes are 0 apart. Degenerate triangles are fine (they count as segments or points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

DEFAULT_SAMPLES = 50_000
DEFAULT_SEED = 0
# The bound stops refining a direction once it is within this factor of the largest distance
# evaluated: the recorded Hausdorff is at most (1 + DEFAULT_TOLERANCE) x the true one.
DEFAULT_TOLERANCE = 0.05
# Absolute slack (fraction of the diagonal) below which a triangle's bound is settled: lets
# identical surfaces (true distance 0, float64 rounding ~1e-16) terminate.
ABS_TOLERANCE = 1e-12
# Engine queries one direction may spend refining: a floor, plus this many per triangle of
# both meshes, at most DEFAULT_WORK_MAX. A 20k-triangle sphere's level at 1/2 needed 27 per
# triangle to converge (level -> reference: cells must get smaller than the reference's
# triangles before the convexity bounds settle them).
DEFAULT_WORK_PER_TRIANGLE = 32.0
# The floor lets a small mesh refine deep where its bound converges slowly (cells near a
# reference vertex where several faces meet must shrink to the tolerance): CesiumMan's LOD1
# (2,336 triangles, with normals) stopped at 6.7x its lower value with a 20,000 floor and
# converged (0.000384 against 0.000366 evaluated) within 356,000 queries.
DEFAULT_WORK_MIN = 400_000
# The cap bounds the time on big meshes (about 2 s a direction here): a 1M-triangle merged
# mesh (MetalRoughSpheresNoTextures) took 128 s for its chain with 4M and its bounds still
# stopped at 9x their lower values; with 1M, 40 s and 18x. The bound holds either way
# (``converged`` False); a tight bound of dense smooth meshes needs about 30 queries a
# triangle, which this Python refinement cannot afford (docs/BUILD.md).
DEFAULT_WORK_MAX = 1_000_000


@dataclass(frozen=True)
class SurfaceError:
    """Two-sided surface distance between a mesh and its reference.

    ``hausdorff`` (model units) and ``hausdorff_rel`` (fraction of the reference's
    bounding-box diagonal) are an *upper bound* of the two-sided Hausdorff distance;
    ``hausdorff_lower(_rel)`` the largest distance actually evaluated (the true value lies
    between). ``rms`` and ``rms_rel`` are a sampled *estimate* of the RMS distance.
    ``forward_max_rel`` is the upper bound from the reference to the mesh (what is lost),
    ``backward_max_rel`` from the mesh to the reference (what is added). ``converged`` is
    False when the refinement ran out of its work budget before reaching its tolerance (the
    bound still holds, but may be looser than ``1 + tolerance``).
    """

    hausdorff: float
    rms: float
    hausdorff_rel: float
    rms_rel: float
    forward_max_rel: float = 0.0
    backward_max_rel: float = 0.0
    hausdorff_lower: float = 0.0
    hausdorff_lower_rel: float = 0.0
    converged: bool = True


ZERO_ERROR = SurfaceError(0.0, 0.0, 0.0, 0.0)
_INF_ERROR = SurfaceError(math.inf, math.inf, math.inf, math.inf, math.inf, math.inf,
                          math.inf, math.inf)


# ----------------------------------------------------------------------------- frame, samples


def local_frame(positions: np.ndarray, indices: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Centre and diagonal of the bounding box of the vertices ``indices`` use (all if None).

    Returns ``(centre (3,) float64, diagonal float)``; the diagonal is 0 for a single point or
    no vertices (callers then use scale 1).
    """
    pos = np.asarray(positions, dtype=np.float64)
    if indices is not None:
        pos = pos[_used_mask(indices, pos.shape[0])]
    if pos.shape[0] == 0:
        return np.zeros(3), 0.0
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    return (lo + hi) * 0.5, float(np.linalg.norm(hi - lo))


def sample_surface(
    positions: np.ndarray, indices: np.ndarray, count: int, seed: int = DEFAULT_SEED
) -> np.ndarray:
    """``count`` points drawn uniformly on the surface (area-weighted), deterministic.

    Args: positions (N, 3) float, indices (M, 3) int. Returns (count, 3) float64 (empty when
    the mesh has no area).
    """
    pos = np.asarray(positions, dtype=np.float64)
    tri = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    if tri.shape[0] == 0 or count <= 0:
        return np.zeros((0, 3))
    a, b, c = pos[tri[:, 0]], pos[tri[:, 1]], pos[tri[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    area = np.where(np.isfinite(area), area, 0.0)
    cum = np.cumsum(area)
    total = cum[-1]
    if not total > 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    which = np.searchsorted(cum, rng.random(count) * total, side="right")
    which = np.minimum(which, tri.shape[0] - 1)
    r1 = np.sqrt(rng.random(count))
    r2 = rng.random(count)
    wa, wb, wc = 1.0 - r1, r1 * (1.0 - r2), r1 * r2
    return wa[:, None] * a[which] + wb[:, None] * b[which] + wc[:, None] * c[which]


# ----------------------------------------------------------------------------- exact geometry


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact closest point on triangle (a, b, c) to p, elementwise (Ericson, RTCD 5.1.5).

    All arguments (K, 3) float64 (broadcastable). Handles degenerate triangles (segments,
    points). Returns (K, 3) float64.
    """
    p, a, b, c = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (p, a, b, c)))
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        out = a + v_in[:, None] * ab + w_in[:, None] * ac  # face region
        # Voronoi regions, applied from lowest to highest priority of Ericson's tests
        # (a, b, ab, c, ac, bc, face): the last np.where that matches wins.
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out = np.where(m[:, None], b + w_bc[:, None] * (c - b), out)
        w_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out = np.where(m[:, None], a + w_ac[:, None] * ac, out)
        out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
        v_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out = np.where(m[:, None], a + v_ab[:, None] * ab, out)
        out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
        out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    # Degenerate triangles (or numerically unusable results): closest point on the 3 edges.
    bad = ~np.all(np.isfinite(out), axis=1) | ~(np.abs(denom) > 0)
    if bad.any():
        cand = np.stack([_closest_on_segment(p[bad], s, e) for s, e in
                         ((a[bad], b[bad]), (b[bad], c[bad]), (c[bad], a[bad]))])
        dist = np.linalg.norm(cand - p[bad][None], axis=2)
        out[bad] = cand[np.argmin(dist, axis=0), np.arange(int(bad.sum()))]
    return out


def _closest_on_segment(p: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    d = e - s
    dd = np.einsum("ij,ij->i", d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dd > 0, np.einsum("ij,ij->i", p - s, d) / dd, 0.0)
    return s + np.clip(t, 0.0, 1.0)[:, None] * d


def _seg_dist2(p: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    d = e - s
    w = p - s
    dd = np.einsum("ij,ij->i", d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(np.einsum("ij,ij->i", w, d) / dd, 0.0, 1.0)
    t = np.where(dd > 0, t, 0.0)
    r = w - t[:, None] * d
    return np.einsum("ij,ij->i", r, r)


def _tri_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact float64 distance from p to triangle (a, b, c), elementwise: (K,).

    The distance to the plane where p projects inside the triangle, else the nearest of the
    three edges (also right for degenerate triangles, which are never "inside")."""
    if p.shape[0] == 0:
        return np.zeros(0)
    ab, ac, ap = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", ab, ab)
    d01 = np.einsum("ij,ij->i", ab, ac)
    d11 = np.einsum("ij,ij->i", ac, ac)
    d20 = np.einsum("ij,ij->i", ap, ab)
    d21 = np.einsum("ij,ij->i", ap, ac)
    det = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):
        v = (d11 * d20 - d01 * d21) / det
        w = (d00 * d21 - d01 * d20) / det
        # (nearly) degenerate: edges only. Never below the true distance (the edges are part
        # of the triangle), above it by at most the sliver's width (sin^2 of its angle < 1e-12)
        inside = (det > 1e-12 * d00 * d11) & (v >= 0) & (w >= 0) & (v + w <= 1)
    out = np.empty(p.shape[0])
    if inside.any():
        q = ap[inside] - v[inside, None] * ab[inside] - w[inside, None] * ac[inside]
        out[inside] = np.einsum("ij,ij->i", q, q)
    o = ~inside
    if o.any():
        po, ao, bo, co = p[o], a[o], b[o], c[o]
        out[o] = np.minimum(np.minimum(_seg_dist2(po, ao, bo), _seg_dist2(po, bo, co)), _seg_dist2(po, co, ao))
    return np.sqrt(out)


def covering_radius(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Covering radius of a triangle's corners: ``max over p in T of min_i |p - v_i|``.

    Args: corners (K, 3) float64. Returns (K,) float64, exact up to rounding (a relative
    1e-12 is added so that rounding never makes it smaller). Non-obtuse triangle: the
    circumradius (the circumcentre lies in T). Obtuse at C (``c`` the longest side AB): the
    farthest point is where the perpendicular bisector of CA or CB meets AB, at
    ``|CA| / (2 cos A)`` resp. ``|CB| / (2 cos B)``. Degenerate (collinear) triangles fall in
    the obtuse case and give half the largest gap along the segment.
    """
    la2 = np.einsum("ij,ij->i", b - c, b - c)  # |BC|^2, opposite A
    lb2 = np.einsum("ij,ij->i", c - a, c - a)  # |CA|^2, opposite B
    lc2 = np.einsum("ij,ij->i", a - b, a - b)  # |AB|^2, opposite C
    sq = np.stack([la2, lb2, lc2], 1)
    k = np.argmax(sq, axis=1)  # the longest side, opposite the largest angle
    rows = np.arange(sq.shape[0])
    L2 = sq[rows, k]                  # longest side^2
    s1 = sq[rows, (k + 1) % 3]        # the other two sides^2
    s2 = sq[rows, (k + 2) % 3]
    L, l1, l2 = np.sqrt(L2), np.sqrt(s1), np.sqrt(s2)
    obtuse = L2 >= s1 + s2
    with np.errstate(divide="ignore", invalid="ignore"):
        # side l1 meets the longest side at an angle with cos = (l1^2 + L^2 - l2^2) / (2 l1 L):
        # the bisector of l1 meets the longest side at l1 / (2 cos) = l1^2 L / (l1^2 + L^2 - l2^2)
        den1 = s1 + L2 - s2
        den2 = s2 + L2 - s1
        r1 = np.where(s1 > 0, s1 * L / den1, 0.0)
        r2 = np.where(s2 > 0, s2 * L / den2, 0.0)
        r_obt = np.maximum(r1, r2)
        cross = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        r_acute = L * l1 * l2 / (2.0 * cross)  # abc / (4 area)
    r = np.where(obtuse, r_obt, r_acute)
    # rounding that leaves no usable value: every point of T is within L of every corner
    r = np.where(np.isfinite(r) & (r >= 0), np.minimum(r, L), L)
    return r * (1.0 + 1e-12)


# ----------------------------------------------------------------------------- the engine


class _Engine:
    """fcpw BVH over one mesh (local frame), exact float64 distances on its answers."""

    def __init__(self, positions: np.ndarray, tri: np.ndarray) -> None:
        import fcpw

        self._fcpw = fcpw
        self.a = positions[tri[:, 0]]
        self.b = positions[tri[:, 1]]
        self.c = positions[tri[:, 2]]
        scene = fcpw.scene_3D()
        scene.set_object_count(1)
        scene.set_object_vertices(np.asfortranarray(positions, dtype=np.float32), 0)
        scene.set_object_triangles(np.asfortranarray(tri, dtype=np.int32), 0)
        scene.build(fcpw.aggregate_type.bvh_surface_area, True)
        self.scene = scene

    def _faces(self, pts32: np.ndarray, r2: np.ndarray) -> np.ndarray:
        inter = self._fcpw.interaction_3D_list()
        self.scene.find_closest_points(pts32, r2, inter)
        return np.fromiter((i.primitive_index for i in inter), dtype=np.int64, count=pts32.shape[0])

    def query(self, points: np.ndarray, radius: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(exact float64 distance to the triangle found (P,), that triangle (P,) int64).

        ``radius`` (P,): a known upper value of each point's distance; it only prunes the
        search (padded for float32 rounding; points found nothing within it are asked again
        without a limit).
        """
        n = points.shape[0]
        if n == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        pts32 = np.asfortranarray(points, dtype=np.float32)
        if radius is None:
            r2 = np.full(n, np.inf, dtype=np.float32)
        else:
            r = np.asarray(radius, dtype=np.float64) * (1.0 + 1e-4) + 1e-5
            r2 = np.ascontiguousarray(np.where(np.isfinite(r), r * r, np.inf), dtype=np.float32)
        faces = self._faces(pts32, r2)
        miss = faces < 0
        if miss.any():
            faces[miss] = self._faces(np.asfortranarray(pts32[miss]),
                                      np.full(int(miss.sum()), np.inf, dtype=np.float32))
        return _tri_distance(points, self.a[faces], self.b[faces], self.c[faces]), faces

    def distance_to(self, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Exact distance from each point to the given triangle (not the nearest)."""
        return _tri_distance(points, self.a[faces], self.b[faces], self.c[faces])


# ----------------------------------------------------------------------------- the bound


@dataclass
class _Side:
    """One mesh of a measurement, in the reference's local frame."""

    positions: np.ndarray            # (N, 3) float64
    tri: np.ndarray                  # (M, 3) int64
    _engine: _Engine | None = None
    _welded: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def welded(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions, tri) with vertices at identical positions merged: UV/normal seams
        split vertices, but two triangles across a seam still share an edge."""
        if self._welded is None:
            uniq, inv = np.unique(self.positions, axis=0, return_inverse=True)
            self._welded = (uniq, inv.reshape(-1)[self.tri])
        return self._welded

    @property
    def engine(self) -> _Engine:
        if self._engine is None:
            self._engine = _Engine(self.positions, self.tri)
        return self._engine


@dataclass
class _Direction:
    upper: float = 0.0
    lower: float = 0.0       # the largest distance evaluated in this direction
    converged: bool = True
    queries: int = 0


def _lipschitz_bound(v: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Upper bound of a 1-Lipschitz function on triangles v (K, 3, 3) with corner values d."""
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    ub = d.max(axis=1) + covering_radius(a, b, c)
    e = np.stack([np.linalg.norm(b - c, axis=1), np.linalg.norm(c - a, axis=1),
                  np.linalg.norm(a - b, axis=1)], 1)  # opposite a, b, c
    # from corner i the farthest point of T is a corner: d_i + max_j |v_j - v_i|
    far = np.stack([np.maximum(e[:, 1], e[:, 2]), np.maximum(e[:, 0], e[:, 2]),
                    np.maximum(e[:, 0], e[:, 1])], 1)
    return np.minimum(ub, (d + far).min(axis=1) * (1.0 + 1e-12))


def _pair_bound(v: np.ndarray, f1: np.ndarray, f2: np.ndarray, target: "_Side") -> np.ndarray:
    """Upper bound of the distance to target over cells v (K, 3, 3), from two target triangles
    f1, f2 (K,): the cell is cut by a plane; on f1's side ``d <= d_f1``, on the other
    ``d <= d_f2``, both convex, so each side's maximum is at its polygon's corners (the cell's
    corners on that side and the cut points on its edges). Valid for any plane. Triangles
    sharing an edge (also across a seam of split vertices) are cut by the plane through it
    halfway between their walls: exact across a flat or gently folded edge. Others (two
    sheets of a thin part) by the mid-plane of their points nearest to the cell's centroid."""
    k = v.shape[0]
    out = np.full(k, np.inf)
    keep = f1 != f2
    if not keep.any():
        return out
    idx = np.flatnonzero(keep)
    fa, fb, vv = f1[idx], f2[idx], v[idx]
    n = idx.shape[0]
    P, wtri = target.welded
    t1, t2 = wtri[fa], wtri[fb]
    in2 = (t1[:, :, None] == t2[:, None, :]).any(axis=2)  # which of f1's corners f2 has too
    edge = in2.sum(axis=1) == 2
    origin = np.empty((n, 3))
    m = np.empty((n, 3))
    if edge.any():
        r = np.flatnonzero(edge)
        u1, u2, i2 = t1[r], t2[r], in2[r]
        order = np.argsort(~i2, axis=1, kind="stable")  # the two shared corners first
        rr = np.arange(r.shape[0])
        e0, e1, o1 = P[u1[rr, order[:, 0]]], P[u1[rr, order[:, 1]]], P[u1[rr, order[:, 2]]]
        o2 = P[u2[rr, np.argmin((u2[:, :, None] == u1[:, None, :]).any(axis=2), axis=1)]]
        ed = e1 - e0
        ed = ed / np.maximum(np.linalg.norm(ed, axis=1, keepdims=True), 1e-300)

        def wall(o):  # unit in-plane normal of the edge, pointing into the triangle (e0, e1, o)
            w = (o - e0) - np.einsum("ij,ij->i", o - e0, ed)[:, None] * ed
            return w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-300)
        origin[r], m[r] = e0, wall(o1) - wall(o2)
    if (~edge).any():
        r = np.flatnonzero(~edge)
        c = vv[r].mean(axis=1)
        eng = target.engine
        q1 = closest_point_on_triangles(c, eng.a[fa[r]], eng.b[fa[r]], eng.c[fa[r]])
        q2 = closest_point_on_triangles(c, eng.a[fb[r]], eng.b[fb[r]], eng.c[fb[r]])
        origin[r], m[r] = 0.5 * (q1 + q2), q1 - q2
    s = np.einsum("kij,kj->ki", vv - origin[:, None], m)  # (n, 3) signed, >= 0: f1's side
    side1 = s >= 0
    pts = vv.reshape(-1, 3)
    d1 = target.engine.distance_to(pts, np.repeat(fa, 3)).reshape(-1, 3)
    d2 = target.engine.distance_to(pts, np.repeat(fb, 3)).reshape(-1, 3)
    best = np.where(side1, d1, d2).max(axis=1)
    nxt = np.array([1, 2, 0])
    sj = s[:, nxt]
    cut = side1 != side1[:, nxt]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cut, s / (s - sj), 0.0)
    x = vv + np.clip(t, 0.0, 1.0)[:, :, None] * (vv[:, nxt] - vv)
    x = x.reshape(-1, 3)
    c1 = target.engine.distance_to(x, np.repeat(fa, 3)).reshape(-1, 3)
    c2 = target.engine.distance_to(x, np.repeat(fb, 3)).reshape(-1, 3)
    best = np.maximum(best, np.where(cut, np.maximum(c1, c2), 0.0).max(axis=1))
    good = np.isfinite(best) & np.all(np.isfinite(m), axis=1) & np.any(m != 0, axis=1)
    out[idx] = np.where(good, best * (1.0 + 1e-12), np.inf)
    return out


def _bound_direction(v: np.ndarray, d: np.ndarray, f: np.ndarray, target: _Side,
                     own: float, lower: float, tolerance: float, budget: int) -> _Direction:
    """Upper bound of ``max over the triangles v of distance to target``.

    Args: v (K, 3, 3) float64 corners; d (K, 3) upper values of the corners' distances;
    f (K, 3) int64 a target triangle near each corner (for the convexity bound); own: the
    largest distance this direction evaluated already; lower: the largest either direction
    did (the value to beat). ``budget`` engine queries at most.
    """
    out = _Direction(lower=max(own, float(d.max()) if d.size else 0.0))
    lower = max(lower, out.lower)
    settled = 0.0
    hint = f[:, 0].copy()  # best candidate triangle so far, inherited by children
    while v.shape[0]:
        thr = max(lower * (1.0 + tolerance), lower + ABS_TOLERANCE)
        ub = _lipschitz_bound(v, d)
        keep = ub > thr
        if not keep.all():
            settled = max(settled, float(ub[~keep].max()))
            v, d, f, hint, ub = v[keep], d[keep], f[keep], hint[keep], ub[keep]
        if not v.shape[0]:
            break
        k = v.shape[0]
        if out.queries + 4 * k > budget:
            settled = max(settled, float(ub.max()))
            out.converged = False
            break
        # the centroid's nearest triangle: usually the one whose plane the whole of T is near
        cen = v.mean(axis=1)
        dc, fc = target.engine.query(cen, ub)
        out.queries += k
        out.lower = max(out.lower, float(dc.max()))
        lower = max(lower, out.lower)
        thr = max(lower * (1.0 + tolerance), lower + ABS_TOLERANCE)
        # convexity: d_target <= d_F for any target triangle F, and d_F is convex on T
        # (every distinct candidate of every cell, in one batch)
        cand = np.stack([fc, hint, f[:, 0], f[:, 1], f[:, 2]], 1)  # (K, 5)
        new = np.ones_like(cand, dtype=bool)
        for j in range(1, 5):
            new[:, j] = np.all(cand[:, :j] != cand[:, j:j + 1], axis=1)
        rows, cols = np.nonzero(new)
        dist = target.engine.distance_to(v[rows].reshape(-1, 3), np.repeat(cand[rows, cols], 3))
        val = np.full((k, 5), np.inf)
        val[rows, cols] = dist.reshape(-1, 3).max(axis=1) * (1.0 + 1e-12)
        best = val.argmin(axis=1)
        ub = np.minimum(ub, val[np.arange(k), best])
        hint = cand[np.arange(k), best]
        keep = ub > thr
        if not keep.all():
            settled = max(settled, float(ub[~keep].max()))
            v, d, f, hint, ub, fc = v[keep], d[keep], f[keep], hint[keep], ub[keep], fc[keep]
        # a cell straddling the edge between two target triangles: cut it along the plane
        # between them and bound each side by its own triangle (all pairs in one batch)
        if v.shape[0]:
            others = np.stack([fc, f[:, 0], f[:, 1], f[:, 2]], 1)
            rows, cols = np.nonzero(others != hint[:, None])
            if rows.size:
                pb = _pair_bound(v[rows], hint[rows], others[rows, cols], target)
                np.minimum.at(ub, rows, pb)
            keep = ub > thr
            if not keep.all():
                settled = max(settled, float(ub[~keep].max()))
                v, d, f, hint, ub, fc = v[keep], d[keep], f[keep], hint[keep], ub[keep], fc[keep]
        k = v.shape[0]
        if not k:
            break
        # split 4 ways at the edge midpoints; query the midpoints (3 per triangle)
        a, b, c = v[:, 0], v[:, 1], v[:, 2]
        mids = np.stack([(a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5], 1)  # ab, bc, ca
        half = np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                         np.linalg.norm(a - c, axis=1)], 1) * 0.5
        rad = np.minimum(np.minimum(d, np.roll(d, -1, axis=1)) + half, ub[:, None])
        dm, fm = target.engine.query(mids.reshape(-1, 3), rad.reshape(-1))
        out.queries += 3 * k
        dm, fm = dm.reshape(k, 3), fm.reshape(k, 3)
        out.lower = max(out.lower, float(dm.max()))
        lower = max(lower, out.lower)
        mab, mbc, mca = mids[:, 0], mids[:, 1], mids[:, 2]
        v = np.concatenate([np.stack(t, 1) for t in
                            ((a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))])
        d = np.concatenate([np.stack(t, 1) for t in
                            ((d[:, 0], dm[:, 0], dm[:, 2]), (dm[:, 0], d[:, 1], dm[:, 1]),
                             (dm[:, 2], dm[:, 1], d[:, 2]), (dm[:, 0], dm[:, 1], dm[:, 2]))])
        f = np.concatenate([np.stack(t, 1) for t in
                            ((f[:, 0], fm[:, 0], fm[:, 2]), (fm[:, 0], f[:, 1], fm[:, 1]),
                             (fm[:, 2], fm[:, 1], f[:, 2]), (fm[:, 0], fm[:, 1], fm[:, 2]))])
        hint = np.tile(hint, 4)
    out.upper = max(settled, out.lower)
    return out


# ----------------------------------------------------------------------------- measuring


@dataclass(frozen=True, eq=False)
class Reference:
    """A reference mesh prepared for repeated measurements (see :func:`prepare_reference`).

    ``positions`` (N, 3) float64 are in the local frame (centred, unit diagonal);
    ``samples`` (S, 3) float64 are its area-weighted samples (RMS estimate); ``vertex_used``
    (N,) bool marks the vertices its triangles use. ``centre`` and ``scale`` map back to model
    units (model = local * scale + centre); ``diagonal`` is the bounding-box diagonal (model
    units). Its BVH is built on first use and reused by every later measurement.
    """

    positions: np.ndarray
    indices: np.ndarray
    samples: np.ndarray
    vertex_used: np.ndarray
    centre: np.ndarray
    diagonal: float
    scale: float
    n_samples: int
    seed: int
    tolerance: float = DEFAULT_TOLERANCE
    _side: _Side | None = field(default=None, repr=False)

    @property
    def side(self) -> _Side:
        assert self._side is not None
        return self._side


def _used_mask(indices: np.ndarray, n: int) -> np.ndarray:
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(indices).reshape(-1)] = True
    return mask


def _check_finite(local: np.ndarray, tri: np.ndarray, what: str) -> None:
    if tri.size and not np.isfinite(local[tri.reshape(-1)]).all():
        raise ValueError(f"surface error: the {what} has non-finite vertex positions "
                         "(NaN/Inf must be filtered before measuring)")


def prepare_reference(
    positions: np.ndarray, indices: np.ndarray, *, samples: int = DEFAULT_SAMPLES,
    seed: int = DEFAULT_SEED, tolerance: float = DEFAULT_TOLERANCE,
) -> Reference:
    """Normalise a reference mesh and draw its fixed sample set.

    Args: positions (N, 3) float (model units), indices (M, 3) int. ``samples`` area-weighted
    points are drawn with ``seed`` (the reference side of every RMS estimate, so all levels
    of a chain are measured against the same points). ``tolerance``: the bound of every
    measurement against this reference stops at ``(1 + tolerance)`` x the largest distance
    it evaluated. The spatial structure (BVH) is built once, on first use.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    tri = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.int64)
    used = _used_mask(tri, pos.shape[0])
    if not np.isfinite(pos[used]).all():
        raise ValueError("surface error: the reference has non-finite vertex positions "
                         "(NaN/Inf must be filtered before measuring)")
    centre, diag = local_frame(pos, tri)
    scale = diag if diag > 0 and math.isfinite(diag) else 1.0
    local = (pos - centre) / scale
    return Reference(
        positions=local, indices=tri, samples=sample_surface(local, tri, samples, seed),
        vertex_used=used, centre=centre, diagonal=diag, scale=scale, n_samples=samples,
        seed=seed, tolerance=tolerance, _side=_Side(local, tri))


def _vertex_face(tri: np.ndarray, n: int) -> np.ndarray:
    """(n,) int64: one triangle using each vertex (-1 for unused vertices)."""
    vf = np.full(n, -1, dtype=np.int64)
    vf[tri.reshape(-1)] = np.repeat(np.arange(tri.shape[0], dtype=np.int64), 3)
    return vf


def _triangle_keys(tri: np.ndarray, n: int) -> np.ndarray:
    """A key per triangle equal for the same three vertices in any order and orientation."""
    s = np.sort(tri, axis=1)
    if n < (1 << 21):
        return (s[:, 0] << 42) | (s[:, 1] << 21) | s[:, 2]
    return np.ascontiguousarray(s).view(np.dtype((np.void, 24))).reshape(-1)


def _direction(src: _Side, dst: _Side, shared: np.ndarray | None, samples: np.ndarray,
               tolerance: float, work: int, lower: float = 0.0) -> tuple[_Direction, float]:
    """Bound src -> dst. ``shared`` (N,) bool: vertices of src that are corners of dst (both
    index one vertex array), or None. Returns the bound and the samples' mean square."""
    n = src.positions.shape[0]
    tri = src.tri
    used = _used_mask(tri, n)
    d_vert = np.zeros(n)
    f_vert = np.zeros(n, dtype=np.int64)
    ask = used.copy()
    if shared is not None:
        # a shared vertex is a corner of one of dst's triangles: distance exactly 0
        vf = _vertex_face(dst.tri, n)
        ask &= ~shared
        f_vert[used & shared] = vf[used & shared]
        # a triangle that dst has too (same three vertices) is 0 away everywhere
        dst_keys = np.sort(_triangle_keys(dst.tri, n))
        keys = _triangle_keys(tri, n)
        pos = np.searchsorted(dst_keys, keys)
        pos = np.minimum(pos, dst_keys.shape[0] - 1)
        tri = tri[dst_keys[pos] != keys]
    qi = np.flatnonzero(ask)
    pts = np.concatenate([src.positions[qi], samples])
    dq, fq = dst.engine.query(pts)
    d_vert[qi], f_vert[qi] = dq[:qi.shape[0]], fq[:qi.shape[0]]
    ds = dq[qi.shape[0]:]
    mean_sq = float(np.mean(ds * ds)) if ds.size else 0.0
    own = float(dq.max()) if dq.size else 0.0
    if tri.shape[0] == 0:
        return _Direction(upper=own, lower=own), mean_sq
    v = src.positions[tri]
    res = _bound_direction(v, d_vert[tri], f_vert[tri], dst, own, max(own, lower), tolerance, work)
    res.queries += pts.shape[0]
    return res, mean_sq


def _measure(ref: Reference, meshes: list[tuple[np.ndarray, np.ndarray, bool]],
             work_per_triangle: float | None = None) -> list[SurfaceError]:
    if work_per_triangle is None:
        work_per_triangle = DEFAULT_WORK_PER_TRIANGLE
    """meshes: (local positions, (M, 3) int64 indices, shares ref's vertices)."""
    results: list[SurfaceError] = []
    ref_empty = ref.indices.shape[0] == 0
    for i, (local, tri, shared) in enumerate(meshes):
        if tri.shape[0] == 0 or ref_empty:
            results.append(ZERO_ERROR if (tri.shape[0] == 0 and ref_empty) else _INF_ERROR)
            continue
        if not shared:
            _check_finite(local, tri, "measured mesh")
        side = _Side(local, tri)
        used = _used_mask(tri, local.shape[0])
        # reference -> mesh: what the simplification lost
        work = int(min(DEFAULT_WORK_MIN + work_per_triangle * (ref.indices.shape[0] + tri.shape[0]),
                       DEFAULT_WORK_MAX))
        fwd, f_ms = _direction(ref.side, side, used if shared else None, ref.samples,
                               ref.tolerance, work)
        # mesh -> reference: what it added
        s = sample_surface(local, tri, ref.n_samples, ref.seed + 1)
        # (the forward direction's lower value settles what cannot exceed it by the tolerance)
        bwd, b_ms = _direction(side, ref.side, ref.vertex_used if shared else None, s,
                               ref.tolerance, work, fwd.lower)
        h = max(fwd.upper, bwd.upper)
        lo = max(fwd.lower, bwd.lower)
        r = math.sqrt(0.5 * (f_ms + b_ms))
        results.append(SurfaceError(
            h * ref.scale, r * ref.scale, h, r, fwd.upper, bwd.upper, lo * ref.scale, lo,
            fwd.converged and bwd.converged))
    return results


def measure_against(
    ref: Reference, meshes: Sequence[tuple[np.ndarray, np.ndarray]]
) -> list[SurfaceError]:
    """Measure several meshes against one prepared reference.

    Args:
      ref: from :func:`prepare_reference`.
      meshes: ``(positions (N, 3) model units, indices (M, 3))`` pairs.

    The reference's BVH is built once (first use) and shared by all meshes; each mesh gets
    its own for the reference-to-mesh direction.
    """
    prepared = []
    for pos, idx in meshes:
        local = (np.asarray(pos, dtype=np.float64).reshape(-1, 3) - ref.centre) / ref.scale
        prepared.append((local, np.ascontiguousarray(np.asarray(idx).reshape(-1, 3), dtype=np.int64), False))
    return _measure(ref, prepared)


def measure_levels(ref: Reference, levels: Sequence[np.ndarray]) -> list[SurfaceError]:
    """Measure index buffers over the reference's *own* vertex array (LOD levels).

    Args: ref from :func:`prepare_reference`; levels: (K, 3) int arrays indexing the
    reference's positions. Same bound as :func:`measure_against` with the reference's
    positions, faster: vertices and triangles shared by both meshes are exactly 0 apart and
    not queried.
    """
    prepared = [(ref.positions, np.ascontiguousarray(np.asarray(l).reshape(-1, 3), dtype=np.int64), True)
                for l in levels]
    return _measure(ref, prepared)


def measure_error(
    ref_pos: np.ndarray, ref_idx: np.ndarray, pos: np.ndarray, idx: np.ndarray, *,
    samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
    tolerance: float = DEFAULT_TOLERANCE,
) -> SurfaceError:
    """Two-sided Hausdorff bound and RMS estimate between a mesh and a reference.

    Args:
      ref_pos: (N, 3) float, ref_idx: (M, 3) int: the reference (e.g. LOD0), model units.
      pos: (N2, 3) float, idx: (M2, 3) int: the mesh measured (may share ``ref_pos``).
      samples: area-weighted samples per side for the RMS estimate. seed: fixed.
      tolerance: see :func:`prepare_reference`.

    Returns: :class:`SurfaceError` (model units and fractions of the reference's diagonal).
    """
    ref = prepare_reference(ref_pos, ref_idx, samples=samples, seed=seed, tolerance=tolerance)
    return measure_against(ref, [(pos, idx)])[0]


def points_to_mesh_distance(points: np.ndarray, positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the nearest triangle (fcpw BVH, float64 recheck).

    Args: points (P, 3), positions (N, 3), indices (M, 3) with M >= 1. Returns (P,) float64.
    The BVH runs in float32 in the mesh's local frame; the distance to the triangle it finds
    is recomputed in float64 (never below the true distance; above it by at most the float32
    search's slack, about 1e-7 of the mesh's diagonal).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        return np.zeros(0)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    tri = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.int64)
    centre, diag = local_frame(pos, tri)
    scale = diag if diag > 0 and math.isfinite(diag) else 1.0
    d, _ = _Engine((pos - centre) / scale, tri).query((p - centre) / scale)
    return d * scale
