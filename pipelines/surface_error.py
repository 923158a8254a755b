"""Surface error between two triangle meshes: a proven upper bound of the two-sided Hausdorff
distance, and an RMS estimate.

Method (deterministic)
----------------------
1. Both meshes are put in the *reference's* local frame: centred on the reference's bounding
   box and scaled to a unit diagonal, in float64. The same relative error then comes out for
   a model offset by 1e7 or scaled by 1e-6. Non-finite coordinates are refused
   (``ValueError``): the caller filters them before.
2. Closest points come from our float64 BVH (:mod:`pipelines.closest_point`): every
   distance it compares is the exact float64 point-triangle distance of
   :func:`pipelines.distance_kernels.tri_distance`, so the triangle it returns is the nearest
   up to float64 rounding, and the value is the distance to *a* triangle of the mesh, hence
   never below the true distance: every number the bound is built from is an upper value. The
   bound's inner arithmetic (distances to given triangles, the Lipschitz, convexity and pair
   bounds below) runs in compiled kernels (:mod:`pipelines.distance_kernels`);
   :func:`closest_point_on_triangles` stays here in numpy as the independent reference the
   tests hold them to.
3. One direction, A -> B (reference -> level: what was lost; level -> reference: what was
   added), is bounded by branch and bound over A's triangles. ``d_B`` (distance to B) is
   1-Lipschitz, so on a triangle T with corner values ``d_i``
   ``max_T d_B <= max_i d_i + R(T)``, R the covering radius of the corners on T (the
   circumradius for a non-obtuse triangle; for one obtuse at C, ``max(|CA|/(2 cos A),
   |CB|/(2 cos B))``; exact), and ``<= min_i (d_i + max_j |v_j - v_i|)``. And ``d_B <= d_F``
   for any triangle F of B, where ``d_F`` is convex: ``max_T d_B <= max_i d_F(v_i)``, tried
   for the triangles nearest to T's corners and centroid (exact on a surface that is a
   parallel offset). A global lower value ``L`` is the largest distance evaluated (corners,
   centroids, samples). Triangles whose bound is <= ``(1 + tolerance) L`` (or ``L + ABS_TOLERANCE``)
   are settled; the others are split 4 ways at the edge midpoints and bounded again, until
   none is left or ``work_budget`` queries are spent. The direction's result is the largest
   bound of any settled or remaining triangle: an *upper bound*, within ``(1 + tolerance)``
   of the true maximum when ``converged``.
4. ``hausdorff`` is the larger of the two directions' upper bounds; ``hausdorff_lower`` the
   largest distance evaluated (a lower bound up to float64 rounding). Triangles both meshes share (same three vertices,
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

from assetpipe.core.cores import map_spare
from assetpipe.core.rows import column_bounds, edge_runs
from assetpipe.pipelines.closest_point import ClosestTriangles
from assetpipe.pipelines.distance_kernels import (
    area_cumsum, area_samples, convex_bound, near_bounds, pair_bound)
from assetpipe.pipelines.patch_bound import patch_bound_seeded
from assetpipe.pipelines.simplify import distinct_records

DEFAULT_SAMPLES = 50_000
DEFAULT_SEED = 0
# The bound stops refining a direction once it is within this factor of the largest distance
# evaluated: the recorded Hausdorff is at most (1 + DEFAULT_TOLERANCE) x the true one.
DEFAULT_TOLERANCE = 0.05
# Absolute slack (fraction of the diagonal) below which a triangle's bound is settled: lets
# identical surfaces (true distance 0, float64 rounding ~1e-16) terminate. One float32 step at
# the unit diagonal's scale (2^-23): finer than the built level's float32 positions resolve.
# At 1e-12 the flat faces of benchmarks/cad_models.py's boxes (levels exactly on level 0)
# refined until the work budget ran out: 2.4 s of the assembly's 6.7 s, bounds unconverged
# at up to 2.4e-6; at 2^-23 they converge at 1e-8-8e-8 (the corpus's levels and bounds are
# bit-identical either way).
ABS_TOLERANCE = 2.0 ** -23
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
PATCH_BOUND = True  # the height-field bound (pipelines/patch_bound.py); False: without it
# the pair bound over the triangles near the cell's corners before the height field: it costs
# about a fifth as much a cell and settles many cells that straddle one edge of the target
# (2CylinderEngine, bunny, beast, spider: their chains 10.87/10.13 s -> 9.83/9.57 s, 38 of 188
# recorded bounds 0.964-1.012x of before, each still within the tolerance of its lower value)
PAIR_FIRST = True


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
    lo, hi = column_bounds(pos)
    return (lo + hi) * 0.5, float(np.linalg.norm(hi - lo))


def sample_surface(
    positions: np.ndarray, indices: np.ndarray, count: int, seed: int = DEFAULT_SEED
) -> np.ndarray:
    """``count`` points drawn uniformly on the surface (area-weighted), deterministic.

    Args: positions (N, 3) float, indices (M, 3) int. Returns (count, 3) float64 (empty when
    the mesh has no area).
    """
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    tri = np.ascontiguousarray(np.asarray(indices, dtype=np.int64).reshape(-1, 3))
    if tri.shape[0] == 0 or count <= 0:
        return np.zeros((0, 3))
    if tri.min() < 0 or tri.max() >= pos.shape[0]:
        raise IndexError("sample_surface: indices outside the positions")
    # compiled (distance_kernels.area_cumsum / area_samples): the same numbers as numpy's
    # cross, norm, cumsum, searchsorted and weighted sums, without their (M, 3) arrays
    cum = area_cumsum(pos, tri)
    if not cum[-1] > 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    u = rng.random(count)
    r1 = rng.random(count)
    r2 = rng.random(count)
    return area_samples(pos, tri, cum, u, r1, r2)


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


# ----------------------------------------------------------------------------- the engine


class _Engine:
    """The BVH over one mesh (local frame): exact float64 nearest triangles
    (:class:`pipelines.closest_point.ClosestTriangles`)."""

    def __init__(self, positions: np.ndarray, tri: np.ndarray) -> None:
        self.tree = ClosestTriangles.build(positions, tri)
        self.a, self.b, self.c = self.tree.a, self.tree.b, self.tree.c

    def query(self, points: np.ndarray, radius: np.ndarray | None = None,
              hint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(exact float64 distance to the nearest triangle (P,), that triangle (P,) int64).

        ``radius`` (P,): a known upper value of each point's distance; it only prunes the
        search (padded by a relative 1e-9 for the rounding of how it was computed; a point
        that found nothing within it is asked again without a limit). ``hint`` (P,): a
        triangle likely near, tried first (prunes sooner; the answer is the same).
        """
        n = points.shape[0]
        if n == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        if radius is not None:
            radius = np.asarray(radius, dtype=np.float64) * (1.0 + 1e-9)
        d, faces = self.tree.query(points, radius, hint)
        miss = faces < 0
        if miss.any():
            d[miss], faces[miss] = self.tree.query(points[miss])
        return d, faces



# ----------------------------------------------------------------------------- the bound


def edge_neighbours(wtri: np.ndarray) -> np.ndarray:
    """(M, 3) int64 for triangles ``wtri`` (M, 3) int64 over welded ids: per triangle and edge
    (corner e to e + 1), the other triangle of an edge exactly two triangles share, else -1
    (a border, a non-manifold or a degenerate edge)."""
    out = np.full((wtri.shape[0], 3), -1, dtype=np.int64)
    _, order, start, count = edge_runs(wtri)
    pair = start[count == 2]
    a, b = order[pair], order[pair + 1]  # slots t * 3 + e
    ok = wtri.reshape(-1)[a] != wtri[:, [1, 2, 0]].reshape(-1)[a]  # a degenerate edge: no neighbour
    a, b = a[ok], b[ok]
    flat = out.reshape(-1)
    flat[a] = b // 3
    flat[b] = a // 3
    return out


@dataclass
class _Side:
    """One mesh of a measurement, in the reference's local frame."""

    positions: np.ndarray            # (N, 3) float64
    tri: np.ndarray                  # (M, 3) int64
    _engine: _Engine | None = None
    _welded: np.ndarray | None = None
    # the id of each vertex's position (N,): shared by the sides of one vertex array (the
    # levels measured against their reference: measure_levels)
    _weld: np.ndarray | None = None
    _neighbours: np.ndarray | None = None

    @property
    def weld(self) -> np.ndarray:
        """(N,) int64: one id per distinct position (equal ids: equal positions)."""
        if self._weld is None:
            self._weld = _position_groups(self.positions)
        return self._weld

    @property
    def welded_tri(self) -> np.ndarray:
        """(M, 3) int64: the triangles over :attr:`weld`'s ids (vertices at identical
        positions merged): UV/normal seams split vertices, but two triangles across a seam
        still share an edge."""
        if self._welded is None:
            self._welded = self.weld[self.tri]
        return self._welded

    @property
    def engine(self) -> _Engine:
        if self._engine is None:
            self._engine = _Engine(self.positions, self.tri)
        return self._engine

    @property
    def neighbours(self) -> np.ndarray:
        """(M, 3) int64: per triangle and edge (corner e to corner e + 1), the other triangle
        of the edge when exactly two triangles share it (over :attr:`weld`'s ids), else -1
        (a border, a non-manifold or a degenerate edge)."""
        if self._neighbours is None:
            self._neighbours = edge_neighbours(self.welded_tri)
        return self._neighbours


@dataclass
class _Direction:
    upper: float = 0.0
    lower: float = 0.0       # the largest distance evaluated in this direction
    converged: bool = True
    queries: int = 0


def _position_groups(positions: np.ndarray) -> np.ndarray:
    """(N,) int64: one id per distinct position of (N, 3) float64 ``positions``, the grouping of
    :func:`assetpipe.core.rows.position_ids` (-0.0 equal to 0.0; a NaN row grouped by its bits)
    by meshoptimizer's hash instead of a lexsort (5-8x faster), numbered in first-occurrence
    order instead of sorted order: the bound only compares these ids (shared vertices, edges)."""
    p = np.ascontiguousarray(np.asarray(positions, np.float64) + 0.0)  # + 0.0: -0.0 -> 0.0
    return _distinct_rows(p)[0]


def _distinct_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the id of each row's distinct row (R,) int64, numbered in order of first occurrence;
    the index of each distinct row's first occurrence (U,) int64) of C-contiguous (R, 3)
    float64 rows, compared bit for bit (meshoptimizer's vertex remap over their bytes)."""
    remap, first = distinct_records(rows.view(np.uint8).reshape(rows.shape[0], rows.shape[1] * rows.itemsize))
    return remap.astype(np.int64), first


def _settle(ub: np.ndarray, thr: float, settled: float, *cells: np.ndarray):
    """Cells whose bound ``ub`` is within ``thr`` are done: returns (the largest bound settled
    so far, ``ub`` and each of ``cells`` restricted to the cells still live). A NaN bound (the
    kernels divide with numpy's semantics: a zero divisor gives inf or NaN, not an exception)
    settles nothing: the cell stays live."""
    done = ub <= thr
    if not done.any():
        return (settled, ub, *cells)
    # the live rows taken by index, once for every array (3x faster than a mask per array)
    live = np.flatnonzero(~done)
    return (max(settled, float(ub[done].max())), ub.take(live),
            *(c.take(live, axis=0) for c in cells))


def _largest(ub: np.ndarray) -> float:
    """The largest of the live cells' bounds, a NaN one counting as infinite (unbounded)."""
    return float(np.where(np.isnan(ub), np.inf, ub).max())


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
    # (the height field is tried on every cell, also where it failed on the cell's parent: a
    # cell whose edge reaches over a crease, a border or a fold fails, but most of its
    # children do not. Skipping the children of failed cells left a cylinder's moved level of
    # 256 triangles splitting its side's slivers, which all reach both rims, until the work
    # ran out: 3.3 s and unconverged at 0.00079 of the diagonal; tried on every cell, 0.83 s
    # and 0.00032. The corpus's 37 models took no longer: 12 bounds 0.9% tighter at most.)
    while v.shape[0]:
        thr = max(lower * (1.0 + tolerance), lower + ABS_TOLERANCE)
        # the Lipschitz bound; where it leaves the cell above thr, convexity over the
        # triangles already known near the cell (corners' and inherited: a cell settled here
        # needs no centroid query); then the pair bound (PAIR_FIRST): one compiled pass
        eng = target.engine
        f = np.ascontiguousarray(f)
        ub, hint = near_bounds(v, d, f, hint, thr, eng.a, eng.b, eng.c, target.welded_tri,
                               PAIR_FIRST)
        settled, ub, v, d, f, hint = _settle(ub, thr, settled, v, d, f, hint)
        if not v.shape[0]:
            break
        # the height field of the target's patch under the cell (pipelines/patch_bound.py):
        # only triangles within thr of the cell can settle it, so the patch is gathered there
        if PATCH_BOUND and eng.tree.nodes is not None:
            # seeds of the patch: the target triangles known near the cell's corners
            seeds = np.ascontiguousarray(np.stack([hint, f[:, 0], f[:, 1], f[:, 2]], 1))
            val, _ = patch_bound_seeded(v, np.full(v.shape[0], thr), *eng.tree.nodes, eng.a, eng.b,
                                        eng.c, target.welded_tri, target.neighbours, seeds)
            ub = np.minimum(ub, val)
            settled, ub, v, d, f, hint = _settle(ub, thr, settled, v, d, f, hint)
            if not v.shape[0]:
                break
        k = v.shape[0]
        if out.queries + k > budget:  # the centroids' queries (the midpoints' are checked below)
            settled = max(settled, _largest(ub))
            out.converged = False
            break
        # the centroid's nearest triangle: usually the one whose plane the whole of T is near
        cen = v.mean(axis=1)
        dc, fc = eng.query(cen, ub, hint)
        out.queries += k
        out.lower = max(out.lower, float(dc.max()))
        lower = max(lower, out.lower)
        thr = max(lower * (1.0 + tolerance), lower + ABS_TOLERANCE)
        # convexity: d_target <= d_F for any target triangle F, and d_F is convex on T
        cand = np.ascontiguousarray(np.stack([fc, hint, f[:, 0], f[:, 1], f[:, 2]], 1))  # (K, 5)
        val, hint = convex_bound(v, cand, eng.a, eng.b, eng.c)
        ub = np.minimum(ub, val)
        settled, ub, v, d, f, hint, fc = _settle(ub, thr, settled, v, d, f, hint, fc)
        # a cell straddling the edge between two target triangles: cut it along the plane
        # between them and bound each side by its own triangle
        if v.shape[0]:
            others = np.ascontiguousarray(np.stack([fc, f[:, 0], f[:, 1], f[:, 2]], 1))
            ub = np.minimum(ub, pair_bound(v, hint, others, eng.a, eng.b, eng.c, target.welded_tri, thr))
            settled, ub, v, d, f, hint, fc = _settle(ub, thr, settled, v, d, f, hint, fc)
        k = v.shape[0]
        if not k:
            break
        # split 4 ways at the edge midpoints; query the midpoints (3 per triangle)
        a, b, c = v[:, 0], v[:, 1], v[:, 2]
        mids = np.stack([(a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5], 1)  # ab, bc, ca
        half = np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                         np.linalg.norm(a - c, axis=1)], 1) * 0.5
        rad = np.minimum(np.minimum(d, np.roll(d, -1, axis=1)) + half, ub[:, None])
        # an edge shared by two live cells has one midpoint (bit-identical: (a + b) / 2 is
        # symmetric): ask it once, with the smaller of the two radii (both are upper values).
        # Rows equal bit for bit, found by meshoptimizer's hash of their 24 bytes, numbered in
        # first-occurrence order (each point's answer does not depend on the others or their
        # order; the hint is the first occurrence's either way): 3-4x a lexsort of the rows
        flat = np.ascontiguousarray(mids.reshape(-1, 3))
        inv, first = _distinct_rows(flat)
        uniq = flat.take(first, axis=0)
        uhint = f.reshape(-1)[first]  # the triangle near the edge's first corner (ab: a, ...)
        urad = np.full(uniq.shape[0], np.inf)
        np.minimum.at(urad, inv, rad.reshape(-1))
        if out.queries + uniq.shape[0] > budget:
            settled = max(settled, _largest(ub))
            out.converged = False
            v = v[:0]
            break
        du, fu = eng.query(uniq, urad, uhint)
        out.queries += uniq.shape[0]
        dm, fm = du[inv].reshape(k, 3), fu[inv].reshape(k, 3)
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
               tolerance: float, work: int, lower: float = 0.0,
               same: np.ndarray | None = None) -> tuple[_Direction, float]:
    """Bound src -> dst. ``shared`` (N,) bool: vertices of src that are corners of dst (both
    index one vertex array: row i of src is row i of dst wherever ``same`` (N,) bool says so,
    everywhere when it is None), or None. Returns the bound and the samples' mean square."""
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
        # a triangle that dst has too (same three vertices, at the same places) is 0 away
        # everywhere
        dst_tri = dst.tri if same is None else dst.tri[same[dst.tri].all(axis=1)]
        if dst_tri.shape[0]:
            dst_keys = np.sort(_triangle_keys(dst_tri, n))
            keys = _triangle_keys(tri, n)
            pos = np.searchsorted(dst_keys, keys)
            pos = np.minimum(pos, dst_keys.shape[0] - 1)
            tri = tri.take(np.flatnonzero((dst_keys[pos] != keys) if same is None else
                                          (dst_keys[pos] != keys) | ~same[tri].all(axis=1)), axis=0)
    qi = np.flatnonzero(ask)
    pts = np.concatenate([src.positions.take(qi, axis=0), samples])
    dq, fq = dst.engine.query(pts)
    d_vert[qi], f_vert[qi] = dq[:qi.shape[0]], fq[:qi.shape[0]]
    ds = dq[qi.shape[0]:]
    mean_sq = float(np.mean(ds * ds)) if ds.size else 0.0
    own = float(dq.max()) if dq.size else 0.0
    if tri.shape[0] == 0:
        return _Direction(upper=own, lower=own), mean_sq
    # (take: numpy's row gather, 3-4x faster here than fancy indexing, the same values)
    v = np.take(src.positions, tri, axis=0)
    res = _bound_direction(v, d_vert[tri], f_vert[tri], dst, own, max(own, lower), tolerance, work)
    res.queries += pts.shape[0]
    return res, mean_sq


def _measure(ref: Reference, meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]],
             work_per_triangle: float | None = None,
             lower: Sequence[float | None] | None = None,
             engines: Sequence[_Engine | None] | None = None, threads: int = 1) -> list[SurfaceError]:
    """meshes: (local positions (N, 3), (M, 3) int64 indices, None or (N,) bool: the rows equal
    to ref's rows (its vertex array then has ref's rows, some of them moved)). ``threads``: the
    meshes measured at once, at most (each is independent of the others: the same results)."""
    if work_per_triangle is None:
        work_per_triangle = DEFAULT_WORK_PER_TRIANGLE
    ref_empty = ref.indices.shape[0] == 0

    def one(i: int) -> SurfaceError:
        local, tri, same = meshes[i]
        if tri.shape[0] == 0 or ref_empty:
            return ZERO_ERROR if (tri.shape[0] == 0 and ref_empty) else _INF_ERROR
        shared = same is not None
        if same is not None and same.all():
            same = None  # every row is ref's: the reference's own vertex array
        if same is not None or not shared:
            _check_finite(local, tri, "measured mesh")
        # a level over the reference's own vertices shares its welding (np.unique of the rows:
        # 40 ms for the bunny's 35k vertices, once per chain instead of once per level)
        side = _Side(local, tri, _engine=engines[i] if engines is not None else None,
                     _weld=ref.side.weld if shared and same is None else None)
        used = _used_mask(tri, local.shape[0])
        work = int(min(DEFAULT_WORK_MIN + work_per_triangle * (ref.indices.shape[0] + tri.shape[0]),
                       DEFAULT_WORK_MAX))
        known = lower[i] if lower is not None else None
        known = float(known) if known is not None and math.isfinite(known) else 0.0
        # mesh -> reference (what it added) first: for a level it has the fewer cells, and its
        # lower value then settles more of the reference's cells in the other direction (the
        # cells that cannot exceed it by the tolerance), which has a cell per reference triangle
        s = sample_surface(local, tri, ref.n_samples, ref.seed + 1)
        bwd, b_ms = _direction(side, ref.side, (ref.vertex_used if same is None else
                                                ref.vertex_used & same) if shared else None, s,
                               ref.tolerance, work, known, same)
        # reference -> mesh: what the simplification lost
        fwd, f_ms = _direction(ref.side, side, (used if same is None else used & same) if shared
                               else None, ref.samples, ref.tolerance, work, max(bwd.lower, known), same)
        h = max(fwd.upper, bwd.upper)
        lo = max(fwd.lower, bwd.lower, known)
        r = math.sqrt(0.5 * (f_ms + b_ms))
        return SurfaceError(h * ref.scale, r * ref.scale, h, r, fwd.upper, bwd.upper, lo * ref.scale, lo,
                            fwd.converged and bwd.converged)

    if threads > 1 and len(meshes) > 1 and not ref_empty:
        # what the meshes share is made before the threads start (built once, then only read;
        # the compiled kernels and the BVH queries release the GIL); in a build's worker, the
        # threads beyond this one use only idle workers' cores (assetpipe/core/cores.py)
        ref.side.engine, ref.side.weld, ref.side.welded_tri, ref.side.neighbours  # noqa: B018
        return map_spare(one, range(len(meshes)), threads)
    return [one(i) for i in range(len(meshes))]


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
        prepared.append((local, np.ascontiguousarray(np.asarray(idx).reshape(-1, 3), dtype=np.int64), None))
    return _measure(ref, prepared)


def measure_levels(ref: Reference, levels: Sequence[np.ndarray],
                   lower: Sequence[float | None] | None = None,
                   engines: Sequence[_Engine | None] | None = None,
                   positions: Sequence[np.ndarray | None] | None = None,
                   threads: int = 1) -> list[SurfaceError]:
    """Measure index buffers over the reference's *own* vertex array (LOD levels).

    Args: ref from :func:`prepare_reference`; levels: (K, 3) int arrays indexing the
    reference's positions. Same bound as :func:`measure_against` with the reference's
    positions, faster: vertices and triangles shared by both meshes are exactly 0 apart and
    not queried. ``lower``: per level, a distance already evaluated between it and the
    reference (or None), which starts its bound. ``engines``: per level, None or a BVH
    already built over that level's positions and triangles (``_Engine``), reused.
    ``positions``: per level, None (the reference's positions) or its own (N, 3) float64
    positions in the reference's local frame (a level whose vertices moved): only its rows
    equal to the reference's (bit for bit), and the triangles over them alone, are then
    shared; the rest is measured as a separate mesh. ``threads``: levels measured at once,
    at most (the results do not depend on it).
    """
    prepared = []
    for i, l in enumerate(levels):
        own = positions[i] if positions is not None else None
        tri = np.ascontiguousarray(np.asarray(l).reshape(-1, 3), dtype=np.int64)
        if own is None:
            prepared.append((ref.positions, tri, np.ones(ref.positions.shape[0], bool)))
        else:
            # a moved level keeps the rows it did not move (level 0's, bit for bit): those rows'
            # vertices and the triangles over them only are shared
            own = np.asarray(own, np.float64)
            same = np.all(own == ref.positions, axis=1) if own.shape == ref.positions.shape \
                else None
            prepared.append((own, tri, same if same is not None and same.any() else None))
    return _measure(ref, prepared, lower=lower, engines=engines, threads=threads)


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
    """Exact distance from each point to the nearest triangle (float64 BVH).

    Args: points (P, 3), positions (N, 3), indices (M, 3) with M >= 1. Returns (P,) float64.
    Computed in the mesh's local frame (centred, unit diagonal), in float64 throughout.
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
