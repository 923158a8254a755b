"""LOD chains with measured error.

:func:`build_lod_chain` turns one mesh into a chain of index buffers over the *same* vertex
array: level 0 is the input unchanged; each coarser level is simplified both from the level
above and from level 0 (``LodOptions.chain``), and the one with the lower *measured* error
against level 0 (:mod:`pipelines.surface_error`) is kept. Neither always wins
(benchmarks/lod.py, variants ours-chained and ours-direct): a chain accumulates error, while
a stalled step can do better from the level above.
No level moves or adds a vertex, so every level indexes level 0's vertices and
:func:`reorder_for_lod_prefix` can still permute the vertices so that each level uses a prefix
of the vertex range (the ``vertexCount`` of the sidecar's ``lods`` entries, docs/FORMAT.md).
A level whose measured error exceeds ``max_error`` is not emitted.

Local frame
-----------
Simplification and measurement run in a local frame: positions are centred on their bounding
box and scaled to a unit diagonal in float64, and only then cast to float32 for meshoptimizer.
A model offset by 1e7 or scaled by anything from 1e-6 to 1e6 therefore gives the same levels
and the same relative errors; errors in model units are scaled back.

Monotonic error
---------------
Each level is measured against level 0 with the *same* fixed reference (prepared once), so
measured errors normally grow down the chain. They
are reported exactly as measured. A coarser level *can* measure slightly lower than a finer
one: the mesh-side samples differ per level, and a further collapse can genuinely remove a
deviation the level above had (the true Hausdorff distance is not monotonic under
simplification). ``switch_distance`` uses the running maximum of the measured Hausdorff
distance down the chain, so switch distances never decrease (a coarser level never switches
in nearer than a finer one); the reported ``hausdorff`` is never altered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from assetpipe.core.rows import column_bounds, edge_runs, unique_first
from assetpipe.pipelines import meshopt_wasm
from assetpipe.pipelines import simplify as simp
from assetpipe.pipelines.lod_options import DEFAULT_LOD_OPTIONS, SIMPLIFIERS, LodOptions  # noqa: F401 (re-exported)
from assetpipe.pipelines.surface_error import (
    Reference, SurfaceError, local_frame, measure_levels, points_to_mesh_distance,
    prepare_reference, sample_surface)

#: Bump when the output of this step changes for the same input and options (cache key).



@dataclass(frozen=True, eq=False)
class LodLevel:
    """One level of a chain.

    indices: (K, 3) uint32 into the same vertex array as level 0.
    simplifier_error: the simplifier's own estimate summed over the steps from level 0, as a
      fraction of the bounding-box diagonal (NaN for fast-simplification, which gives none).
    hausdorff: a proven upper bound of the two-sided Hausdorff distance to level 0, model units
      (:mod:`pipelines.surface_error`); rms: a sampled estimate of the RMS distance;
      hausdorff_rel, rms_rel: the same as fractions of level 0's bounding-box diagonal.
    hausdorff_lower_rel: the largest distance the bound evaluated (the true Hausdorff distance
      lies between it and ``hausdorff_rel``); converged: whether the bound got within its
      tolerance of it before its work budget ran out (a bound either way).
    switch_distance: view distance (model units) from which this level's error projects to
      at most one pixel: max Hausdorff of levels 0..k * (resolution/2) / tan(fov/2).
    sloppy: whether the sloppy fallback made this level. Sloppy clustering ignores UV seams
      and borders, so this level (and any level simplified from it) may have cracks.
    from_level: the level it was simplified from (``level - 1``: chained; 0: direct).
    """

    level: int
    indices: np.ndarray = field(repr=False)
    triangles: int
    simplifier_error: float
    hausdorff: float
    rms: float
    hausdorff_rel: float
    rms_rel: float
    switch_distance: float
    sloppy: bool = False
    from_level: int = 0  # the level this one was simplified from (the level above, or 0)
    hausdorff_lower_rel: float = 0.0  # the largest distance the bound evaluated: the truth lies between
    converged: bool = True  # the bound reached its tolerance (else it holds but may be loose)
    #: None: the level indexes level 0's vertices where they are; else (N, 3) float64 model
    #: units, the positions of the vertices it uses (moved by the simplifier; the rows it does
    #: not use are level 0's): it gets its own vertex rows (docs/FORMAT.md)
    positions: np.ndarray | None = field(default=None, repr=False)

    def error_json(self) -> dict[str, float]:
        """The sidecar's ``error`` object (docs/FORMAT.md)."""
        return {"simplifier": self.simplifier_error, "hausdorff": self.hausdorff,
                "rms": self.rms, "hausdorffRel": self.hausdorff_rel, "rmsRel": self.rms_rel,
                "hausdorffLowerRel": self.hausdorff_lower_rel, "boundConverged": self.converged}


@dataclass(frozen=True, eq=False)
class LodChain:
    """``levels[0]`` is the input; each further level is coarser (fewer triangles)."""

    levels: tuple[LodLevel, ...]
    diagonal: float  # bounding-box diagonal of level 0's used vertices, model units


def _normalised(positions: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    pos = np.asarray(positions, dtype=np.float64)
    centre, diag = local_frame(pos, indices)
    scale = diag if diag > 0 and math.isfinite(diag) else 1.0
    return (pos - centre) / scale, centre, diag


def weld_for_simplification(
    indices: np.ndarray, positions: np.ndarray, uv: np.ndarray | None = None,
    normals: np.ndarray | None = None, other_attributes: Sequence[np.ndarray] = (),
    weld_normal_seams: bool = True,
) -> np.ndarray:
    """The index buffer levels 1+ are simplified from (see ``LodOptions.weld_normal_seams``).

    Vertices identical in position, UV and ``other_attributes`` (and normal, unless hard
    edges are welded) are merged to the first of them. Hard edges are welded only when that
    adds no non-manifold edge. Shapes: indices (M, 3), positions (N, 3), uv (N, 2),
    normals (N, 3). Returns (M, 3) uint32 over the same N vertices.
    """
    welded = simp.weld_identical(indices, positions, uv, normals, *other_attributes)
    if weld_normal_seams and normals is not None:
        across = simp.weld_identical(indices, positions, uv, *other_attributes)
        # Welding hard edges must not glue coincident sheets (CAD models often have them)
        # into non-manifold edges, which the simplifier cannot collapse.
        if _non_manifold_edges(across) <= _non_manifold_edges(welded):
            welded = across
    return welded


def _non_manifold_edges(tri: np.ndarray) -> int:
    """Number of distinct undirected edges used by more than two triangles. tri: (M, 3)."""
    return int(np.count_nonzero(edge_runs(tri)[3] > 2))


def _attributes(uv: np.ndarray | None, normals: np.ndarray | None, opts: LodOptions,
                n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Attribute columns and weights for meshoptimizer. UVs are shifted to 0 and divided by
    the larger side of their bounding box (float64 first), so the weight does not depend on
    the UV scale: tiled UVs (x100, x1e4) weigh as much as UVs in [0, 1]."""
    cols, weights = [], []
    if uv is not None and opts.uv_weight > 0:
        u = np.asarray(uv, dtype=np.float64).reshape(n, 2)
        u = np.where(np.isfinite(u), u, 0.0)
        if n:
            lo, hi = column_bounds(u)
            extent = float((hi - lo).max())
            u = (u - lo) / extent if extent > 0 else u - lo
        cols.append(u.astype(np.float32))
        weights += [opts.uv_weight] * 2
    if normals is not None and opts.normal_weight > 0:
        cols.append(np.asarray(normals, dtype=np.float32).reshape(n, 3))
        weights += [opts.normal_weight] * 3
    if not cols:
        return None, None
    return np.concatenate(cols, axis=1), np.asarray(weights, np.float32)


#: (indices (K, 3) uint32, simplifier error, sloppy, from level, moved): ``moved`` is None
#: when the level indexes level 0's vertices where they are, else (N, 3) float32 positions in
#: the chain's local frame (the vertices it uses moved by ``meshopt_simplifyWithUpdate``, or
#: inherited from a moved level it was simplified from)
_Candidate = tuple


def _candidates(pos32: np.ndarray, src: np.ndarray, src_level: int, src_err: float, target: int,
                target_error: float, attrs: np.ndarray | None, weights: np.ndarray | None,
                opts: LodOptions, src_moved: np.ndarray | None = None) -> list[_Candidate]:
    """Simplifications of ``src`` towards ``target`` triangles.

    The regular simplifier first (with attributes), then, with ``geometry_candidate``, the
    same on positions alone, and with ``move_vertices`` meshoptimizer 1.3's
    ``simplifyWithUpdate`` on positions alone (its kept vertices moved to where they minimise
    the quadric error, :mod:`pipelines.meshopt_wasm`). When the regular one stops above
    ``sloppy_slack`` x the target (topology allows no more collapses), meshoptimizer's
    component pruning (keeps seams closed) and, with ``sloppy_fallback``, the sloppy
    simplifier are tried too. The caller picks by measured error. Simplifier errors are
    summed along the chain (an estimate). ``src_moved``: the positions ``src`` has when it is
    a moved level (None: ``pos32``); its candidates keep them."""
    pos = pos32 if src_moved is None else src_moved
    if opts.simplifier == "fast-simplification":
        out, err = simp.simplify_fast(pos, src, target, preserve_border=opts.lock_border)
        return [(out, src_err + err, False, src_level, src_moved)]
    out, err = simp.simplify(pos, src, target, attributes=attrs, attribute_weights=weights,
                             lock_border=opts.lock_border, target_error=target_error)
    cands = [(out, src_err + err, False, src_level, src_moved)]
    if attrs is not None and opts.geometry_candidate:
        # the same simplification on positions alone (UV seams still stay closed): it wins
        # only where its measured error is lower (see LodOptions.geometry_candidate)
        g_out, g_err = simp.simplify(pos, src, target, lock_border=opts.lock_border,
                                     target_error=target_error)
        cands.append((g_out, src_err + g_err, False, src_level, src_moved))
    if opts.move_vertices and meshopt_wasm.available():
        u_out, u_pos, u_err = _simplify_moving(pos, src, target, target_error)
        if u_out.shape[0] > 0:
            cands.append((u_out, src_err + u_err, False, src_level, u_pos))
    if target_error < simp.NO_ERROR_LIMIT or out.shape[0] <= opts.sloppy_slack * target \
            or opts.lock_border:
        return cands
    p_out, p_err = simp.simplify(pos, src, target, attributes=attrs, attribute_weights=weights,
                                 target_error=target_error, prune=True)
    if p_out.shape[0] > 0:
        cands.append((p_out, src_err + p_err, False, src_level, src_moved))
    if opts.sloppy_fallback:
        s_out, s_err = simp.simplify_sloppy(pos, src, target, cleanup=True)
        if s_out.shape[0] > 0:
            cands.append((s_out, src_err + s_err, True, src_level, src_moved))
    return cands


def _simplify_moving(pos32: np.ndarray, src: np.ndarray, target: int,
                     target_error: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``meshopt_simplifyWithUpdate`` with :func:`pipelines.simplify.simplify`'s conventions
    (sparse, absolute error limit from the relative one; error returned as a fraction of the
    diagonal of ``pos32``). Returns (indices (K, 3) uint32, positions (N, 3) float32, error)."""
    extent, diag = simp._extent_and_diagonal(pos32)
    # open borders stay where they are, always: moved border vertices open cracks where two
    # sides of a seam are only nearly coincident (a UV sphere's seam at sin(2 pi) = -2.4e-16
    # against 0 is a border on both sides to the simplifier; moved apart, the validate
    # fixtures' sphere showed 1.68 diagonals of open edges at LOD1). Exact seams move together.
    options = meshopt_wasm.SPARSE | meshopt_wasm.ERROR_ABSOLUTE | meshopt_wasm.LOCK_BORDER
    limit = min(float(target_error) * extent if extent > 0 else float(target_error), 3.0e38)
    try:
        out, moved, err = meshopt_wasm.simplify_with_update(pos32, src, target, target_error=limit,
                                                            options=options)
    except meshopt_wasm.SimplifierFailed:
        # no moved candidate for this step (a mesh beyond the WASM's memory): the others stand
        return np.zeros((0, 3), np.uint32), pos32, math.inf
    if not np.isfinite(moved[np.unique(out.reshape(-1))]).all():
        return np.zeros((0, 3), np.uint32), moved, math.inf  # never a non-finite vertex
    return out, moved, err / diag if diag > 0 else err


#: locked re-simplifications per step at most (each kept only while it lowers the estimate).
#: More rounds measured no better: stanford-bunny at 1/2, 1.22x / 1.26x / 1.34x gltfpack's
#: Hausdorff distance with 1 / 2 / 3 rounds (100k samples, locks then placed by the
#: estimator's own samples; beast and spider unchanged)
LOCK_ROUNDS = 1


def _lock_rounds(est, lock_pts, pos32, welded, prev, prev_err, k_prev, best, target, max_tris, attrs,
                 weights, opts):
    """:func:`_refine_with_locks` applied to the chosen candidate ``best`` = (candidate,
    estimate): the result replaces it only when the estimator says it is closer to level 0
    (a second check, the largest distance from ``lock_pts`` and the level-0 vertices either
    removed, changed no level of beast, stanford-bunny or spider and was dropped: 2 more
    distance queries per step). Up to LOCK_ROUNDS rounds, locks accumulating."""
    cand, e_best = best
    src, src_err = (prev, prev_err) if cand[3] == k_prev else (welded, 0.0)
    lock = np.zeros(pos32.shape[0], np.uint8)
    base = np.zeros(pos32.shape[0], bool)
    base[welded.reshape(-1)] = True
    for _ in range(LOCK_ROUNDS):
        ref = _refine_with_locks(lock_pts, pos32, base, src, src_err, cand, target, attrs, weights,
                                 opts, lock)
        if ref is None or not 0 < ref[0].shape[0] <= max_tris:
            break
        if e_best is None or math.isnan(e_best):
            e_best, e_ref = est([cand, ref])
        else:
            (e_ref,) = est([ref])
        if not e_ref < e_best:
            break
        cand, e_best = ref, e_ref
    return cand, e_best


def _uses(tri: np.ndarray, n: int) -> np.ndarray:
    used = np.zeros(n, bool)
    used[tri.reshape(-1)] = True
    return used


def _refine_with_locks(samples: np.ndarray, pos32: np.ndarray, base: np.ndarray, src: np.ndarray,
                       src_err: float, best: _Candidate, target: int, attrs: np.ndarray | None,
                       weights: np.ndarray | None, opts: LodOptions,
                       lock: np.ndarray) -> _Candidate | None:
    """``best`` simplified again from ``src`` to the same target with the vertices at its worst
    places locked (``LodOptions.lock_fraction``); ``lock`` (N,) uint8 gains them.

    The places are ``samples`` (level-0 area samples, P x 3) and the level-0 vertices
    (``base``: (N,) bool, used by level 0) that ``best`` removed, whose distance to ``best`` is
    at least ``lock_fraction`` x the largest; the vertex of ``src`` nearest each is locked, so
    the simplifier spends its collapses elsewhere. meshoptimizer minimises a sum of quadric
    errors, the Hausdorff distance is a maximum: the worst places of a level are few and
    often avoidable. Returns None when nothing is far."""
    from scipy.spatial import cKDTree

    tri = best[0]
    pts = np.concatenate([samples, pos32[base & ~_uses(tri, base.size)]])
    d = points_to_mesh_distance(pts, pos32, tri)
    top = float(d.max()) if d.size else 0.0
    if not top > 0:
        return None
    src_ids = np.unique(src.reshape(-1)).astype(np.int64)
    _, nearest = cKDTree(pos32[src_ids]).query(pts[d >= opts.lock_fraction * top])
    lock[src_ids[np.atleast_1d(nearest)]] = 1
    out, err = simp.simplify(pos32, src, target, attributes=attrs, attribute_weights=weights,
                             lock_border=opts.lock_border, vertex_lock=lock)
    return (out, src_err + err, False, best[3], None)


def _unique(cands: list[_Candidate]) -> list[_Candidate]:
    """Drop candidates whose index buffer equals an earlier one's (same result, one measure)."""
    seen, out = set(), []
    for c in cands:
        key = (c[0].shape, c[0].tobytes(), None if c[4] is None else c[4].tobytes())
        if key not in seen:
            seen.add(key)
            out.append(c)
    return out


#: area samples a side for comparing candidates (besides the vertices): enough to rank them
ESTIMATE_SAMPLES = 8192


def unmoved_rows(moved: np.ndarray, pos32: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows of a moved level's float32 positions ``moved`` (N, 3) that the
    simplifier left as they were in level 0's ``pos32`` (N, 3) (meshoptimizer's
    ``simplifyWithUpdate`` moves only the vertices collapses ended on: on CAD meshes about
    half of a level's vertices at 1/2 stay). Such a row is level 0's vertex, and is written
    and measured as exactly that."""
    return np.all(moved == pos32, axis=1)


class _Estimator:
    """A quick *sampled* two-sided Hausdorff distance to level 0, used only to choose among
    candidates (chained or direct, pruned, sloppy): ``n`` area samples a side, plus up to ``n``
    of the level-0 vertices a candidate removed (a vertex it keeps is 0 away) and of the
    candidate's vertices level 0 lacks, exact point-to-triangle distances. It is a lower
    value of the true distance; the recorded error of the chosen level is the bound of
    :func:`measure_levels`, computed once per emitted level. Choosing by the bound instead
    doubled the measuring time of chain="best" (Duck, 5 levels: 12.4 s against 6.5 s
    chained, under load). Level 0's BVH is built on the first call and kept; ``side``: the
    recorded bound's reference side over ``local`` and ``idx`` (its frame, which the estimator
    then shares), whose BVH (built on first use by either) is used instead."""

    def __init__(self, local: np.ndarray, idx: np.ndarray, n: int, seed: int,
                 side=None, frame: tuple[np.ndarray, float] = (np.zeros(3), 1.0),
                 pos32: np.ndarray | None = None) -> None:
        self.local, self.idx, self.n, self.seed = local, idx, n, seed
        self.frame = frame  # (centre, scale): the chain's local frame -> this one
        self.pos32 = pos32  # (N, 3) float32: level 0 as the simplifiers get it (chain's frame)
        used = np.zeros(local.shape[0], bool)
        used[idx.reshape(-1)] = True
        self.used = used
        self.samples = sample_surface(local, idx, n, seed)
        self.rng_seed = seed + 7
        self._side = side
        self._engine = None
        # the BVH each candidate's forward half built, by the candidate's index array (kept
        # alive here): the recorded bound of the chosen level reuses it (keep() drops the rest)
        self._built: dict[int, tuple[np.ndarray, object]] = {}
        self._moved: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def positions(self, moved: np.ndarray | None) -> np.ndarray:
        """A candidate's vertex positions in this frame: level 0's, or its moved ones (float64;
        the same array for the same ``moved``, so BVHs built over it are reused). A row the
        simplifier did not move (equal to ``pos32``'s) is level 0's row, bit for bit
        (:func:`unmoved_rows`): the bound then shares it, and the triangles over such rows."""
        if moved is None:
            return self.local
        got = self._moved.get(id(moved))
        if got is None or got[0] is not moved:
            own = (np.asarray(moved, np.float64) - self.frame[0]) / self.frame[1]
            if self.pos32 is not None:
                keep = unmoved_rows(moved, self.pos32)
                own[keep] = self.local[keep]
            got = (moved, own)
            self._moved[id(moved)] = got
        return got[1]

    def engine_for(self, tri: np.ndarray):
        """The BVH the forward half built over ``tri`` (this very array), or None."""
        got = self._built.get(id(tri))
        return got[1] if got is not None and got[0] is tri else None

    def keep(self, tris: Sequence[np.ndarray]) -> None:
        """Forget the BVHs of every candidate but ``tris`` (the chosen levels)."""
        ids = {id(t) for t in tris}
        self._built = {k: v for k, v in self._built.items() if k in ids}
        self._moved = {}

    def _subset(self, ids: np.ndarray) -> np.ndarray:
        if ids.shape[0] <= self.n:
            return ids
        rng = np.random.default_rng(self.rng_seed)
        return np.sort(rng.choice(ids, self.n, replace=False))

    def __call__(self, cands: list[_Candidate], lowest_of: Sequence[int] | None = None) -> list[float]:
        """The estimate of every candidate. ``lowest_of``: only the lowest estimate among these
        candidates is wanted: the candidate with the lowest value and that value are the same
        as without it, every other one of them gets a lower value above it (its backward half
        alone, or its forward half stopped there), and candidates not among them get NaN (not
        estimated)."""
        if not cands:
            return []
        from assetpipe.pipelines.surface_error import _Engine

        if self._engine is None:
            self._engine = self._side.engine if self._side is not None else _Engine(self.local, self.idx)

        def backward(i: int) -> tuple[float, np.ndarray, np.ndarray | None]:
            """(the largest distance of candidate i's points to level 0; its used vertices; its
            moved vertices or None)."""
            c = cands[i]
            tri, pos = c[0], self.positions(c[4])
            used = np.zeros(self.local.shape[0], bool)
            used[tri.reshape(-1)] = True
            # vertices shared with level 0 (and not moved) are on it (distance 0): only the others
            off = used & ~self.used
            moved = None
            if c[4] is not None:
                moved = np.any(pos != self.local, axis=1)
                off |= used & moved
            pts = np.concatenate([sample_surface(pos, tri, self.n, self.seed + 1),
                                  pos.take(self._subset(np.flatnonzero(off)), axis=0)])
            # exact, without finding every point's nearest triangle (max_distance)
            return self._engine.tree.max_distance(pts)[0], used, moved

        def forward(i: int, used: np.ndarray, moved: np.ndarray | None, stop: float = math.inf) -> float:
            gone = ~used if moved is None else ~used | moved
            removed = self._subset(np.flatnonzero(self.used & gone))
            pts = np.concatenate([self.samples, self.local.take(removed, axis=0)])
            tri = cands[i][0]
            eng = self.engine_for(tri)
            if eng is None:
                eng = _Engine(self.positions(cands[i][4]), tri.astype(np.int64))
                self._built[id(tri)] = (tri, eng)
            return eng.tree.max_distance(pts, stop=stop)[0]

        if lowest_of is None:
            out = []
            for i in range(len(cands)):
                b, used, moved = backward(i)
                out.append(max(forward(i, used, moved), b))
            return out
        # the backward halves of these candidates (exact), then the forward halves (a BVH of
        # the candidate each) in order of them, each only where the backward half does not
        # already exceed the lowest estimate so far and stopping once above it: such a
        # candidate cannot be the lowest (ties are computed: > only). Ordered by the
        # simplifier's own error instead, with the backward halves stopping too, the forward
        # halves ran 183 times instead of 134 on the corpus (2.08 s against 1.89 s).
        out = [math.nan] * len(cands)
        back = {i: backward(i) for i in lowest_of}
        best = math.inf
        for i in sorted(lowest_of, key=lambda i: (back[i][0], i)):
            b, used, moved = back[i]
            out[i] = b
            if b > best:
                continue
            out[i] = max(forward(i, used, moved, best), b)
            best = min(best, out[i])
        return out


def _measure(est: _Estimator | None, cands: list[_Candidate]) -> list[float | None]:
    if est is None or not cands:
        return [None] * len(cands)
    if len(cands) == 1:
        return [math.nan]  # nothing to choose: no estimate needed
    return est(cands)


def _cost(c: _Candidate, e: float | None) -> float:
    return e if e is not None and not math.isnan(e) else c[1]


def build_lod_chain(
    positions: np.ndarray,
    indices: np.ndarray,
    *,
    uv: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    other_attributes: Sequence[np.ndarray] = (),
    options: LodOptions = DEFAULT_LOD_OPTIONS,
    threads: int = 1,
) -> LodChain:
    """Build an LOD chain with measured errors.

    Args:
      positions: (N, 3) float64, model space.
      indices: (M, 3) uint32, each < N.
      uv: (N, 2) float32 or None; normals: (N, 3) float32 or None: attributes the
        "meshopt-attr" simplifier preserves. Vertices split along UV seams (same position,
        different UV) stay split and the seams stay closed.
      other_attributes: any further per-vertex arrays (N rows: tangents, colours, uv1, ...)
        the vertex buffer holds. They are not simplified against, but vertices are only
        welded (see below) when these are identical too.
      options: :class:`LodOptions`.
      threads: the chosen levels' bounds computed on up to this many threads (the result does
        not depend on it).

    Returns:
      :class:`LodChain`; ``levels[0]`` holds ``indices`` unchanged (errors 0). Every level's
      ``indices`` is (K, 3) uint32 into ``positions``; triangle counts strictly decrease by at
      least ``min_saving``; no level is empty; with ``options.max_error`` no level's measured
      Hausdorff distance exceeds it. The input arrays are not modified.

    Before simplifying, vertices identical in position, UV, ``other_attributes`` and (unless
    ``options.weld_normal_seams``) normal are welded (:func:`pipelines.simplify.weld_identical`): levels 1+ use the first vertex of
    each identical set, which renders the same and lets the simplifier collapse across
    duplicates instead of treating them as seams.

    Each level is made (``options.chain``) from the level above, from level 0, or from both
    with the lower measured Hausdorff distance kept (``from_level`` says which).
    """
    idx = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.uint32)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    n, m0 = pos.shape[0], idx.shape[0]
    local, centre, diag = _normalised(pos, idx)
    pos32 = np.ascontiguousarray(local, dtype=np.float32)
    attrs = weights = None
    if options.simplifier == "meshopt-attr":
        attrs, weights = _attributes(uv, normals, options, n)

    # Identical duplicate vertices are welded first (levels 1+ then use the first of each set
    # of identical vertices): duplicates would act as seams and block collapses.
    welded = weld_for_simplification(idx, pos, uv, normals, other_attributes,
                                     options.weld_normal_seams)
    # Candidates are compared by a quick sampled estimate; the chosen levels are measured
    # (bounded) against the reference at the end, in one batch.
    # The reference of the recorded bound is prepared first: the estimator works in its frame
    # (within rounding of ``local``) and shares its level-0 BVH, and the estimates of the
    # chosen levels (distances evaluated between the level and level 0) start their bounds.
    est = ref = None
    if options.measure and m0 > 0:
        ref = prepare_reference(local, idx, samples=options.bound_samples_for(m0),
                                seed=options.error_seed)
        est = _Estimator(ref.positions, ref.indices, min(options.samples_for(m0), ESTIMATE_SAMPLES),
                         options.error_seed + 101, side=ref.side, frame=(ref.centre, ref.scale),
                         pos32=pos32)
    error_targets = options.error_targets()
    chained = options.chain in ("best", "chained") or options.simplifier == "fast-simplification"
    direct = options.chain in ("best", "direct") and options.simplifier != "fast-simplification"
    budget = options.max_error if options.max_error is not None else math.inf
    lock_pts = None  # level-0 samples placing the locks of _refine_with_locks (made on first use)
    # (indices, simplifier error, sloppy, from level, moved), measured error
    chosen: list[tuple[_Candidate, SurfaceError | None]] = [((welded, 0.0, False, 0, None), None)]
    steps = error_targets if error_targets is not None else options.ratios
    scale32 = simp._scale_ratio(pos32, welded) if welded.size else 1.0
    for step in steps[1:]:
        (prev, prev_err, _, _, prev_moved), _ = chosen[-1]
        prev_n = prev.shape[0]
        k_prev = len(chosen) - 1
        max_allowed = math.floor((1.0 - options.min_saving) * prev_n)
        if prev_n <= options.min_triangles or max_allowed < 1:
            break
        if error_targets is not None:
            best = _error_targeted(pos32, welded, chosen, float(step), max_allowed, scale32,
                                   attrs, weights, options, est, chained, direct)
            if best is None:
                break
        else:
            target = max(int(round(step * m0)), options.min_triangles)
            if target > max_allowed:
                break
            cands = []
            if chained:
                cands += _candidates(pos32, prev, k_prev, prev_err, target, simp.NO_ERROR_LIMIT,
                                     attrs, weights, options, prev_moved)
            if direct and (k_prev > 0 or not chained):
                cands += _candidates(pos32, welded, 0, 0.0, target, simp.NO_ERROR_LIMIT,
                                     attrs, weights, options)
            cands = [c for c in _unique(cands) if 0 < c[0].shape[0] <= max_allowed]
            if not cands:
                break
            slack = options.sloppy_slack * target
            within = [i for i, c in enumerate(cands) if c[0].shape[0] <= slack]
            # with candidates within the slack, only the lowest estimate among them is used
            errs = est(cands, within) if est is not None and len(cands) > 1 and within else \
                _measure(est, cands)
            if within:
                i = min(within, key=lambda i: (_cost(cands[i], errs[i]), cands[i][0].shape[0], i))
            else:
                i = min(range(len(cands)), key=lambda i: (cands[i][0].shape[0], i))
            best = (cands[i], errs[i])
            if within and est is not None and options.lock_fraction > 0 and not cands[i][2] \
                    and cands[i][4] is None and prev_moved is None:
                if lock_pts is None:
                    lock_pts = sample_surface(local, idx.astype(np.int64), est.n,
                                              options.error_seed + 202)
                best = _lock_rounds(est, lock_pts, pos32, welded, prev, prev_err, k_prev, best,
                                    target, min(max_allowed, slack), attrs, weights, options)
        e = best[1]
        if e is not None and not math.isnan(e) and not e <= budget:
            break  # over the error budget even by the estimate (a lower value): not emitted
        chosen.append(best)
        if est is not None:
            est.keep([c[0][0] for c in chosen])

    # --- measure every chosen level against level 0 (one prepared reference, one batch)
    measured: list[SurfaceError | None] = [None] * len(chosen)
    if ref is not None and len(chosen) > 1:
        measured[1:] = measure_levels(ref, [c[0][0] for c in chosen[1:]],
                                      lower=[c[1] for c in chosen[1:]],
                                      engines=[est.engine_for(c[0][0]) for c in chosen[1:]],
                                      positions=[None if c[0][4] is None else est.positions(c[0][4])
                                                 for c in chosen[1:]], threads=threads)
        for k in range(1, len(chosen)):
            target = error_targets[k] if error_targets is not None else math.inf
            if not measured[k].hausdorff_rel <= min(budget, target if target > 0 else math.inf):
                chosen, measured = chosen[:k], measured[:k]  # over the budget (or target)
                break
    chosen = [(c, m) for (c, _), m in zip(chosen, measured)]

    ppu = options.pixels_per_unit_at_unit_distance()
    levels = [LodLevel(0, idx, m0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)]
    scale = diag if diag > 0 and math.isfinite(diag) else 0.0
    running = 0.0
    nan = math.nan
    unit = diag if diag > 0 and math.isfinite(diag) else 1.0
    for k, ((out, err, sloppy, src, moved), e) in enumerate(chosen[1:], start=1):
        # a moved level's positions back in model units (float64; rows it did not move, and
        # rows it does not use, are level 0's, bit for bit)
        own = None
        if moved is not None:
            own = np.asarray(moved, np.float64) * unit + centre
            keep = unmoved_rows(moved, pos32)
            own[keep] = pos[keep]
        if e is None:
            levels.append(LodLevel(k, out, int(out.shape[0]), err, nan, nan, nan, nan, nan, sloppy, src,
                                   positions=own))
            continue
        h_model = e.hausdorff_rel * scale
        running = max(running, h_model)
        levels.append(LodLevel(
            level=k, indices=out, triangles=int(out.shape[0]), simplifier_error=err,
            hausdorff=h_model, rms=e.rms_rel * scale, hausdorff_rel=e.hausdorff_rel,
            rms_rel=e.rms_rel, switch_distance=running * ppu, sloppy=sloppy, from_level=src,
            hausdorff_lower_rel=e.hausdorff_lower_rel, converged=e.converged, positions=own))
    return LodChain(levels=tuple(levels), diagonal=diag)


#: the sampled estimate must be this far within an error target, so that the bound measured
#: afterwards (at most 1 + the measurement tolerance above the truth) stays within it too
TARGET_MARGIN = 0.85


def _error_targeted(pos32, welded, chosen, target_rel: float, max_allowed: int, scale32: float,
                    attrs, weights, options: LodOptions, est: _Estimator | None,
                    chained: bool, direct: bool):
    """The level with the fewest triangles whose estimated Hausdorff distance is within
    ``TARGET_MARGIN`` x ``target_rel`` (fraction of the diagonal): meshoptimizer's error
    limit starts at the target and is halved (up to 6 times) while no candidate is. Without
    measuring the simplifier's own estimate decides. The level's bound is checked against
    the target afterwards (the chain ends at a level over it)."""
    (prev, prev_err, _, _, prev_moved), _ = chosen[-1]
    k_prev = len(chosen) - 1
    # meshopt's error is relative to the extent (largest side), ours to the diagonal
    limit = target_rel / scale32
    for _ in range(7):
        cands = []
        if chained:
            cands += _candidates(pos32, prev, k_prev, prev_err, options.min_triangles, limit,
                                 attrs, weights, options, prev_moved)
        if direct and (k_prev > 0 or not chained):
            cands += _candidates(pos32, welded, 0, 0.0, options.min_triangles, limit,
                                 attrs, weights, options)
        cands = [c for c in _unique(cands) if 0 < c[0].shape[0] <= max_allowed]
        if not cands:
            return None  # even the loosest limit saves too little
        errs = est(cands) if est is not None else [None] * len(cands)
        ok = [i for i, c in enumerate(cands) if _cost(c, errs[i]) <= TARGET_MARGIN * target_rel]
        if ok:
            i = min(ok, key=lambda i: (cands[i][0].shape[0], _cost(cands[i], errs[i]), i))
            return cands[i], errs[i]
        limit *= 0.5
    return None


@dataclass(frozen=True, eq=False)
class LodVertexOrder:
    """A vertex permutation that makes every level use a prefix of the vertex range.

    order: (N,) int64, new -> old: ``new_attribute = old_attribute[order]`` for *every*
      vertex attribute (positions, UVs, normals, ...).
    remap: (N,) int64, old -> new: ``new_indices = remap[old_indices]``; ``order[remap] ==
      arange(N)``.
    indices: per level, (K, 3) uint32 already remapped (same order as given).
    vertex_counts: per level, the prefix length its indices stay below: every index of level
      k is < vertex_counts[k], and vertex_counts never grows from a level to a coarser one.
      vertex_counts[0] counts the vertices level 0 uses; unreferenced vertices come after it.
    """

    order: np.ndarray
    remap: np.ndarray
    indices: tuple[np.ndarray, ...]
    vertex_counts: tuple[int, ...]


def reorder_for_lod_prefix(levels: Sequence[np.ndarray], vertex_count: int) -> LodVertexOrder:
    """Order vertices so each coarser level uses a prefix of the vertex range.

    Args:
      levels: index arrays, finest first (level 0 first), each (K, 3) integer < vertex_count
        (e.g. ``[l.indices for l in chain.levels]``). Each level should use a subset of the
        vertices of the finer levels (true for :func:`build_lod_chain`); when it does not,
        the prefix still holds (a vertex is placed by the coarsest level that uses it).
      vertex_count: N, the length of the vertex array.

    Vertices come grouped coarsest level first: the coarsest level's vertices, then those
    first used by the next finer level, ..., then level 0's, then unreferenced vertices.
    Within a group, vertices are in order of first use in that level's index buffer (good
    for vertex fetch); unreferenced vertices keep their relative order.
    """
    n = int(vertex_count)
    level_of = np.full(n, len(levels), dtype=np.int64)  # coarsest level that uses the vertex
    first_use = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
    for k in range(len(levels) - 1, -1, -1):
        flat = np.asarray(levels[k], dtype=np.int64).reshape(-1)
        if flat.size and (flat.min() < 0 or flat.max() >= n):
            raise ValueError(f"level {k} indexes outside 0..{n - 1}")
        uniq, first = unique_first(flat)
        new = uniq[level_of[uniq] == len(levels)]
        if new.size:
            level_of[new] = k
            first_use[new] = first[np.searchsorted(uniq, new)]
    # Sort: coarsest level first (higher level number first), then first use, then old index.
    unref = level_of == len(levels)
    group = np.where(unref, -1, level_of)
    # (one default sort of a combined key where it fits: distinct values, the same order as the
    # lexsort's three stable passes)
    top = int(first_use[~unref].max()) + 1 if (~unref).any() else 1  # first uses are < top
    span = len(levels) + 2
    if n and span * (top + 1) * n < (1 << 62):
        fu = np.where(unref, top, first_use)
        order = np.argsort(((len(levels) - group) * (top + 1) + fu) * n + np.arange(n, dtype=np.int64))
    else:
        order = np.lexsort((np.arange(n), first_use, -group)).astype(np.int64)
    remap = np.empty(n, np.int64)
    remap[order] = np.arange(n)
    new_levels = tuple(remap[np.asarray(l, dtype=np.int64).reshape(-1, 3)].astype(np.uint32)
                       for l in levels)
    counts = []
    for k in range(len(levels)):
        counts.append(int(np.count_nonzero((level_of >= k) & ~unref)))
    return LodVertexOrder(order=order, remap=remap, indices=new_levels, vertex_counts=tuple(counts))
