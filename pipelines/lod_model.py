"""LOD chains for a whole model: merge what may be merged, simplify each distinct mesh once.

:func:`build_model_lods` takes the meshes ("parts") of one model and

1. merges the parts that share a material, a vertex format and sidedness into one mesh
   (``LodOptions.merge_meshes``): one triangle budget across the parts, as gltfpack does, so
   a small part is not simplified at the same ratio as a large one;
2. drops duplicate triangles (:func:`dedupe_triangles`): exact duplicates always, reversed
   ones where the material is double-sided;
3. finds meshes that are copies of one another under an affine map (instanced nodes, copied
   primitives: the importer flattens node transforms into the positions,
   :func:`find_affine_copies`): a copy reuses the chain of the first and its error bound,
   scaled by the map's largest singular value (plus the fit's residual, twice);
4. with ``LodOptions.balance_meshes`` (on by default), shares each level's triangle budget
   among the distinct meshes by error (:func:`balanced_ratios`): one model-wide ratio, each
   mesh at the count meshoptimizer reaches at a common model-unit error;
5. builds one chain per distinct mesh (:func:`pipelines.lod.build_lod_chain`) and orders
   its vertices so every level uses a prefix (:func:`pipelines.lod.reorder_for_lod_prefix`).

Pure: arrays in, arrays out.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Hashable, Sequence

import numpy as np

from assetpipe.core.cores import map_spare
from assetpipe.core.rows import column_bounds, first_use_order, unique_first
from assetpipe.pipelines import simplify as simp
from assetpipe.pipelines.lod import LodChain, LodLevel, build_lod_chain, reorder_for_lod_prefix
from assetpipe.pipelines.lod_options import DEFAULT_LOD_OPTIONS, LodOptions

#: threads measuring a model's distinct meshes at once (its chains are independent; the
#: distance kernels release the GIL). Output does not depend on it.
LOD_THREADS = min(4, os.cpu_count() or 1)


@dataclass(frozen=True, eq=False)
class LodPart:
    """One mesh of a model as the LOD step gets it.

    vertices: (N, C) float32 interleaved, written as they are (reordered).
    positions: (N, 3) float (model units); uv: (N, 2) or None; normals: (N, 3) or None;
      others: further (N, k) attributes welding must respect (tangents, colours, ...).
    indices: (M, 3) uint32 < N.
    group_key: parts with equal keys (material, vertex format, ...) may be merged.
    double_sided: the material renders back faces (reversed duplicates are then redundant).
    exact: attributes an affine copy must have identical (UVs, colours; not normals or
      tangents, which a transform turns).
    """

    vertices: np.ndarray
    positions: np.ndarray
    indices: np.ndarray
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None
    others: tuple[np.ndarray, ...] = ()
    group_key: Hashable = None
    double_sided: bool = False
    exact: tuple[np.ndarray, ...] = ()


@dataclass(frozen=True, eq=False)
class LodMesh:
    """One output mesh: ``parts`` (indices into the input, in order) merged.

    vertices: (N, C) float32, the parts' vertices concatenated then reordered (prefix layout).
    levels: the chain's levels (``LodLevel``; ``indices`` remapped into ``vertices``).
    vertex_counts: per level, the vertex prefix it uses (for a level with its own vertex rows,
      the end of them).
    vertex_starts: per level, 0, or the first of its own vertex rows (a moved level).
    duplicates: triangles dropped as duplicates before simplifying.
    copy_of: the output mesh whose chain this one reuses (an affine copy), or None.
    """

    parts: tuple[int, ...]
    vertices: np.ndarray
    levels: tuple[LodLevel, ...]
    vertex_counts: tuple[int, ...]
    duplicates: int = 0
    vertex_starts: tuple[int, ...] = ()
    copy_of: int | None = None


# ----------------------------------------------------------------------------- duplicates


def dedupe_triangles(indices: np.ndarray, positions: np.ndarray, double_sided: bool) -> np.ndarray:
    """Drop triangles whose corners coincide with an earlier triangle's.

    Args: indices (M, 3) integer; positions (N, 3). Corners are compared by position (two
    vertices at one position with different UVs still coincide). A triangle with the same
    corners in the same winding as an earlier one is dropped; with the reverse winding only
    when ``double_sided`` (a single-sided material needs both faces to show both sides).
    Triangles with coinciding corners (degenerate) are left alone. Returns (K, 3) uint32,
    the kept triangles in their order.
    """
    tri = np.asarray(indices).reshape(-1, 3)
    if tri.shape[0] < 2:
        return np.ascontiguousarray(tri, dtype=np.uint32)
    pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
    # corners at one position get one index (the first vertex there; meshoptimizer's hash
    # remap: np.unique over position rows took 4.7 s of 9.8 on MetalRoughSpheres' 1M triangles)
    t = simp.weld_identical(tri, pos).astype(np.int64)
    key = np.sort(t, axis=1)
    # winding class: parity of the permutation from sorted order (rotations keep it)
    parity = ((t[:, 0] > t[:, 1]).astype(np.int64) + (t[:, 0] > t[:, 2]) + (t[:, 1] > t[:, 2])) & 1
    degenerate = (key[:, 0] == key[:, 1]) | (key[:, 1] == key[:, 2])
    live = np.flatnonzero(~degenerate)  # degenerate triangles are left alone
    k = key[live]
    if pos.shape[0] < (1 << 21):  # one uint64 per triangle: 3 x 21 bits + the parity bit
        code = ((k[:, 0].astype(np.uint64) << np.uint64(43)) | (k[:, 1].astype(np.uint64) << np.uint64(22))
                | (k[:, 2].astype(np.uint64) << np.uint64(1)))
        if not double_sided:
            code |= parity[live].astype(np.uint64)
        first = unique_first(code)[1]
    else:
        rows = k if double_sided else np.concatenate([k, parity[live, None]], axis=1)
        _, first = np.unique(rows, axis=0, return_index=True)
    keep = degenerate.copy()
    keep[live[first]] = True
    return np.ascontiguousarray(tri[keep], dtype=np.uint32)


# ----------------------------------------------------------------------------- affine copies


def _affine_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(3x3 linear part, max residual) of the affine map taking src (N, 3) to dst (N, 3), or
    None when no invertible affine map fits within float32 precision."""
    if src.shape != dst.shape or src.shape[0] < 4:
        return None
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - cs, dst - cd
    sol, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < 3:
        return None
    resid = float(np.sqrt(np.max(np.sum((a @ sol - b) ** 2, axis=1))))
    lo, hi = column_bounds(dst)
    size = float(np.linalg.norm(hi - lo))
    # float32 vertex data: positions carry ~6e-8 relative rounding; allow a few ulps of it
    if not (size > 0 and resid <= 1e-5 * size and np.all(np.isfinite(sol))):
        return None
    return sol.T, resid


def find_affine_copies(meshes: Sequence[tuple[np.ndarray, np.ndarray, bytes]]
                       ) -> list[tuple[int, np.ndarray, float, bool] | None]:
    """Per mesh, None (distinct) or ``(first, linear (3, 3), residual, mirrored)``: the mesh is
    an affine image of mesh ``first`` (which is distinct), with the same index buffer (its
    winding reversed when ``mirrored``) and the same non-geometric attributes.

    meshes: ``(positions (N, 3) float64, indices (M, 3), attribute bytes)`` per mesh; the
    bytes hold what must match exactly (UVs, ...), not what a transform changes.
    """
    out: list[tuple[int, np.ndarray, float, bool] | None] = [None] * len(meshes)
    seen: dict[tuple, list[int]] = {}
    for i, (pos, idx, extra) in enumerate(meshes):
        tri = np.ascontiguousarray(np.asarray(idx).reshape(-1, 3), dtype=np.uint32)
        key = (pos.shape[0], tri.tobytes(), extra)
        mkey = (pos.shape[0], np.ascontiguousarray(tri[:, [0, 2, 1]]).tobytes(), extra)
        for k, mirrored in ((key, False), (mkey, True)):
            for j in seen.get(k, ()):
                fit = _affine_fit(np.asarray(meshes[j][0], np.float64), np.asarray(pos, np.float64))
                if fit is not None and (np.linalg.det(fit[0]) < 0) == mirrored:
                    out[i] = (j, fit[0], fit[1], mirrored)
                    break
            if out[i] is not None:
                break
        if out[i] is None:
            seen.setdefault(key, []).append(i)
    return out


def _scaled_levels(levels: Sequence[LodLevel], sigma: float, resid: float, diag: float,
                   options: LodOptions, mirrored: bool) -> tuple[LodLevel, ...]:
    """A copy's levels: the same index buffers (winding reversed if mirrored), errors scaled
    by the map's largest singular value ``sigma`` plus twice the fit residual (every vertex
    of the copy is within ``resid`` of the exact affine image)."""
    ppu = options.pixels_per_unit_at_unit_distance()
    out, running = [], 0.0
    for lv in levels:
        idx = np.ascontiguousarray(lv.indices[:, [0, 2, 1]]) if mirrored else lv.indices
        if lv.level == 0:
            out.append(dataclasses.replace(lv, indices=idx))
            continue
        h = lv.hausdorff * sigma + 2.0 * resid
        rms = lv.rms * sigma + 2.0 * resid
        running = max(running, h) if math.isfinite(h) else running
        scale = diag if diag > 0 else math.nan
        out.append(dataclasses.replace(
            lv, indices=idx, hausdorff=h, rms=rms, hausdorff_rel=h / scale, rms_rel=rms / scale,
            # the copy's own distance is not measured: 0 is the lower value that always holds
            hausdorff_lower_rel=lv.hausdorff_lower_rel if (sigma == 1.0 and resid == 0.0) else 0.0,
            switch_distance=running * ppu if math.isfinite(h) else lv.switch_distance))
    return tuple(out)


# ----------------------------------------------------------------------------- the model


#: model-unit errors at which each mesh's count-against-error curve is sampled: log-spaced
#: from this fraction of the largest mesh diagonal up to half of it. 10 points from 1e-4 cut
#: 2CylinderEngine's curves from 0.71 to 0.47 s but took spider at 1/4 from 0.56x to 1.30x
#: gltfpack's Hausdorff distance (benchmarks/lod.py TABLE 1: 41 -> 40 of 44 cells)
CURVE_POINTS = 16
CURVE_LOW = 1e-5
#: a curve point whose limit is above this fraction of the error meshoptimizer reached at the
#: next larger limit takes that point's result (:func:`_count_curve`): the margin covers the
#: float32 squares meshoptimizer compares in (1e-7 relative) many times over
SAME_BELOW = 1.0 - 1e-4
#: the fewest triangles a mesh's share of a level is (at least ``min_triangles``): a closed
#: surface needs 4, and smaller targets can simplify to nothing
MIN_SHARE = 4
#: no mesh's share of a level is below this part of its even share (``ratio`` x its triangles):
#: meshoptimizer's error, which the shares follow, underrates the loss of thin parts, and at
#: 0.5-0.7 spider's coarse levels gave its legs' triangles away (6.27% of the diagonal at 1/4
#: against 3.08% with one ratio for every mesh); at 0.75, 2.32%. Every level of the corpus's
#: multi-mesh models is then at or below its one-ratio error (docs/BUILD.md)
SHARE_KEEP = 0.75


#: triangles of a simplified mesh whose facing is checked (:func:`_flipped_fraction`): an
#: area-weighted draw with a fixed seed when it has more
FLIP_SAMPLES = 4096


def _face_normals(pos: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (M, 3) float64, zero for degenerate triangles; areas x 2 (M,) float64)."""
    n = np.cross(pos[tri[:, 1]] - pos[tri[:, 0]], pos[tri[:, 2]] - pos[tri[:, 0]])
    a = np.linalg.norm(n, axis=1)
    return n / np.where(a > 0, a, 1.0)[:, None], a


def _flipped_fraction(local: np.ndarray, tri: np.ndarray, ref_normals: np.ndarray, engine) -> tuple[float, int]:
    """(part of the area of the simplified mesh ``tri`` (K, 3) over ``local`` (N, 3) float64
    whose nearest level-0 triangle faces the other way, number of triangles it was judged on).

    A triangle counts as flipped when the level-0 triangle nearest its centroid has a normal at
    more than 90 degrees to its own: where the simplifier folded a thin part flat (a leg
    collapsed to a ribbon), back-face culling leaves holes a Hausdorff distance does not see.
    At most :data:`FLIP_SAMPLES` triangles, drawn by area with a fixed seed."""
    tri = np.asarray(tri, np.int64).reshape(-1, 3)
    n, area = _face_normals(local, tri)
    ok = np.flatnonzero(area > 0)
    if ok.size == 0:
        return 0.0, 0
    if ok.size > FLIP_SAMPLES:
        rng = np.random.default_rng(0)
        pick = rng.choice(ok, FLIP_SAMPLES, p=area[ok] / area[ok].sum())
        weight = np.ones(pick.size)
    else:
        pick, weight = ok, area[ok]
    cen = local[tri[pick]].mean(axis=1)
    _, near = engine.query(cen)
    flipped = (n[pick] * ref_normals[near]).sum(axis=1) < 0
    return float(weight[flipped].sum() / weight.sum()), int(pick.size)


def _count_curve(pos: np.ndarray, idx: np.ndarray, uv, normals, others, errors: np.ndarray,
                 options: LodOptions, facing_from: float = math.inf,
                 enough: float = math.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles meshoptimizer keeps of one mesh at each model-unit error limit of ``errors``
    (K,) float64, increasing, with the same welding and attributes as its chain
    (:func:`pipelines.lod.build_lod_chain`), simplified from level 0 each time.

    Returns ``(counts, flipped, judged)``, each (K,): counts float64 (as simplified, not made
    monotone), the part of each result's area that faces away from level 0
    (:func:`_flipped_fraction`) float64, and the number of triangles that was judged on (0
    and 0 where not judged: at points with ``facing_from`` triangles or more, except the last
    of them; by default every point is judged).

    ``enough``: the points are simplified from the largest error down, and once one keeps
    ``enough`` triangles or more the smaller errors are not simplified: their counts are given
    as the mesh's whole count (a share is capped below ``enough`` anyway, so only the point
    where the curve reaches it matters)."""
    from assetpipe.pipelines.closest_point import ClosestTriangles
    from assetpipe.pipelines.lod import _attributes, _normalised, weld_for_simplification

    local, _, diag = _normalised(pos, idx)
    pos32 = np.ascontiguousarray(local, dtype=np.float32)
    welded = weld_for_simplification(idx, pos, uv, normals, others, options.weld_normal_seams)
    attrs = weights = None
    if options.simplifier == "meshopt-attr":
        attrs, weights = _attributes(uv, normals, options, pos.shape[0])
    # meshoptimizer's limit is relative to the mesh's largest side; ours to its diagonal
    scale = simp._scale_ratio(pos32, welded) if welded.size else 1.0
    unit = diag if diag > 0 and math.isfinite(diag) else 1.0
    local64 = np.asarray(local, np.float64)
    tri0 = np.asarray(idx, np.int64).reshape(-1, 3)
    engine = ClosestTriangles.build(local64, tri0) if tri0.size else None
    ref_normals = _face_normals(local64, tri0)[0]
    counts, flipped, judged = (np.zeros(errors.shape[0]) for _ in range(3))
    outs: list = [None] * errors.shape[0]
    reached = math.inf  # meshoptimizer's error of the last point simplified (fraction of the diagonal)
    for k in range(errors.shape[0] - 1, -1, -1):
        limit = float(errors[k]) / unit  # a fraction of the diagonal
        if k + 1 < errors.shape[0] and reached <= limit * SAME_BELOW:
            # every collapse the larger limit made was within this one: meshoptimizer's limit
            # only cuts its passes short (``c.error > limit: break``), so it makes the same
            # collapses and stops where it stopped (the target, or no collapse left): the same
            # result, not simplified again (the large-error end of a curve, where a mesh stalls)
            out = outs[k + 1]
        else:
            out, reached = simp.simplify(pos32, welded, options.min_triangles, attributes=attrs,
                                         attribute_weights=weights, lock_border=options.lock_border,
                                         target_error=limit / scale)
        counts[k] = min(out.shape[0], idx.shape[0])
        outs[k] = out
        if counts[k] >= enough:
            counts[:k] = idx.shape[0]
            break
    # the facing is judged only where a share can fall (:func:`_facing_floor`): below
    # ``facing_from`` triangles and at the point nearest above it
    above = np.flatnonzero(counts >= facing_from)
    first = int(above.max()) if above.size else 0
    for k in range(first, errors.shape[0]):
        if engine is not None and outs[k] is not None and outs[k].size:
            flipped[k], judged[k] = _flipped_fraction(local64, outs[k], ref_normals, engine)
    return counts, flipped, judged


def _facing_floor(counts: np.ndarray, flipped: np.ndarray, judged: np.ndarray, even: float) -> float:
    """The fewest triangles a mesh may be given at a level where its even share is ``even``
    without more of its area facing away from level 0 than at the even share (0: no limit).

    ``counts``/``flipped``/``judged``: a mesh's curve (:func:`_count_curve`). The part at the
    even share is taken, conservatively, from the curve's point nearest above it (its fewest
    triangles at or above ``even``); a count is allowed while the curve stays within that part
    plus twice its standard error (the difference a draw of that many triangles shows by
    chance), with the crossing interpolated in log count: a part is given fewer triangles than
    one ratio would give it only where its facing is not measurably worse. Where the part
    turned away already rises between that point and the next, the crossing, and so the
    floor, can lie above ``even``: such a part keeps more than its even share while the budget
    allows (where the floors do not fit it, :func:`balanced_ratios` gives every mesh its even
    share for that level)."""
    order = np.argsort(-counts, kind="stable")  # most triangles first
    c, f, n = counts[order], flipped[order], np.maximum(judged[order], 1.0)
    live = c > 0
    c, f, n = c[live], f[live], n[live]
    above = np.flatnonzero(c >= even)
    if c.size == 0 or even <= 0 or above.size == 0:
        return 0.0
    j0 = int(above[-1])
    p = min(max(float(f[j0]), 1.0 / n[j0]), 1.0)
    allowed = float(f[j0]) + 2.0 * math.sqrt(p * (1.0 - p) / n[j0])
    for j in range(j0 + 1, c.size):
        if f[j] > allowed:
            # the crossing between the last allowed point and this one
            t = (allowed - f[j - 1]) / (f[j] - f[j - 1]) if f[j] > f[j - 1] else 1.0
            return float(math.exp(math.log(c[j - 1]) + t * (math.log(c[j]) - math.log(c[j - 1]))))
    return 0.0


def balanced_ratios(meshes: Sequence[tuple], weights: Sequence[int],
                    options: LodOptions, threads: int = 1) -> list[tuple[float, ...]]:
    """Per distinct mesh, the ratios of its own chain that share each level's model-wide budget
    (``LodOptions.balance_meshes``).

    ``meshes``: per distinct mesh ``(positions (N, 3) float64 model units, indices (M, 3), uv,
    normals, others)``; ``weights``: how many times each is drawn (itself and its affine copies).
    Level k's budget is ``ratios[k]`` x the weighted triangles; each mesh gets the triangles its
    curve (:func:`_count_curve`) keeps at one common model-unit error ``e_k``, at most
    ``(1 - min_saving)`` x its previous level's and at least :data:`SHARE_KEEP` x its even
    share, and ``e_k`` is the smallest error whose weighted total fits the budget (bisection on
    the curves, interpolated in log error).
    Pure and deterministic."""
    from assetpipe.pipelines.surface_error import local_frame

    m = np.array([np.asarray(ix).reshape(-1, 3).shape[0] for _, ix, *_ in meshes], np.float64)
    w = np.asarray(weights, np.float64)
    diags = [local_frame(np.asarray(p, np.float64), np.asarray(ix).reshape(-1, 3))[1] for p, ix, *_ in meshes]
    top = max([d for d in diags if d > 0 and math.isfinite(d)], default=1.0)
    grid = np.geomspace(CURVE_LOW * top, 0.5 * top, CURVE_POINTS)
    first = options.ratios[1] if len(options.ratios) > 1 else 0.0
    def curve(i: int):
        p, ix, uv, nm, ot = meshes[i]
        return _count_curve(p, ix, uv, nm, ot, grid, options, facing_from=first * m[i],
                            enough=math.floor((1.0 - options.min_saving) * m[i]))

    # each curve is a pure function of its mesh: on ``threads`` threads, largest first
    # (meshoptimizer and the BVH query release the GIL); the result does not depend on them
    if threads > 1 and len(meshes) > 1:
        order = sorted(range(len(meshes)), key=lambda i: -m[i])
        got = dict(zip(order, map_spare(curve, order, threads)))
        raw = [got[i] for i in range(len(meshes))]
    else:
        raw = [curve(i) for i in range(len(meshes))]
    curves = np.stack([np.minimum.accumulate(c) for c, _, _ in raw])
    # the fewest triangles each mesh can be given: MIN_SHARE (and min_triangles); for a mesh
    # its curve shows collapsing to nothing (an open part can), the fewest it kept before that
    # (a mesh that stalls above its share is taken further by its chain's pruning and sloppy
    # candidates, as before)
    least = float(max(options.min_triangles, MIN_SHARE))
    reach = np.array([c[c > 0].min() if (c == 0).any() and (c > 0).any() else least
                      for c in curves])
    floor = np.minimum(np.maximum(reach, least), m)
    curves = np.maximum(curves, floor[:, None])
    log_grid = np.log(grid)

    def counts_at(log_e: float) -> np.ndarray:
        return np.array([np.interp(log_e, log_grid, c) for c in curves])

    prev = m.copy()
    out = [[1.0] for _ in meshes]
    total = float((w * m).sum())
    for r in options.ratios[1:]:
        cap = np.floor((1.0 - options.min_saving) * prev)
        budget = r * total
        lo, hi = log_grid[0], log_grid[-1]
        # no mesh below SHARE_KEEP of its even share, nor where its facing gets worse than there
        facing = np.array([_facing_floor(*raw[i], r * m[i]) for i in range(len(meshes))])
        keep = np.minimum(np.maximum(SHARE_KEEP * r * m, facing), cap)

        def share(log_e: float) -> np.ndarray:
            return np.maximum(np.minimum(counts_at(log_e), cap), keep)

        if (w * share(lo)).sum() > budget:
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                if (w * share(mid)).sum() > budget:
                    lo = mid
                else:
                    hi = mid
            c = share(hi)
        else:
            c = share(lo)
        # where the curves stop above the budget at every error (meshoptimizer stalls: borders,
        # seams, many small closed parts), the largest error does not say how to share it: it
        # is where the parts that can still go collapse (a box below its 12 triangles), while the
        # stalled ones stay put. Every mesh then gets its even share, as with one ratio, and its
        # chain's pruning and sloppy candidates take it there. (Giving up the same part of every
        # share instead put the boxes of a generated assembly at 10 of their 24 triangles at
        # 1/16: 11% of the model's diagonal against 1.4% with even shares.)
        if float((w * c).sum()) > budget:
            c = np.minimum(r * m, prev)
        # never below what a chain can make (a mesh left without the level would keep all of
        # its triangles there), never above the previous level (its chain then ends)
        c = np.minimum(np.maximum(np.floor(c), floor), prev)
        for i in range(len(meshes)):
            out[i].append(float(min(1.0, c[i] / m[i])) if m[i] > 0 else r)
        prev = c
    return [tuple(o) for o in out]


def merge_groups(keys: Sequence[Hashable], merge: bool) -> list[list[int]]:
    """Parts grouped by key, in order of first appearance (one group per part if not merge)."""
    if not merge:
        return [[i] for i in range(len(keys))]
    groups: dict[Hashable, list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    return list(groups.values())


def _concat(arrays: Sequence[np.ndarray | None]) -> np.ndarray | None:
    if any(a is None for a in arrays):
        return None
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def build_model_lods(parts: Sequence[LodPart], options: LodOptions = DEFAULT_LOD_OPTIONS,
                     threads: int | None = None) -> list[LodMesh]:
    """LOD chains for a model's meshes (see the module docstring). Returns the output meshes
    in order of their first part; parts with no triangles are never merged (kept alone).
    ``threads``: distinct meshes measured at once, at most (None: :data:`LOD_THREADS`, which
    also caps it); the result does not depend on it."""
    keys = [(p.group_key, p.double_sided, p.uv is not None, p.normals is not None, len(p.others))
            if p.indices.size else ("empty", i) for i, p in enumerate(parts)]
    groups = merge_groups(keys, options.merge_meshes)
    merged = []
    for g in groups:
        ps = [parts[i] for i in g]
        offsets = np.cumsum([0] + [p.vertices.shape[0] for p in ps])
        idx = np.concatenate([np.asarray(p.indices, np.int64).reshape(-1, 3) + o
                              for p, o in zip(ps, offsets)]).astype(np.uint32)
        pos = np.concatenate([np.asarray(p.positions, np.float64).reshape(-1, 3) for p in ps])
        verts = _concat([p.vertices for p in ps])
        uv, normals = _concat([p.uv for p in ps]), _concat([p.normals for p in ps])
        others = tuple(_concat([p.others[k] for p in ps]) for k in range(len(ps[0].others)))
        m_in = idx.shape[0]
        if options.dedupe_triangles:
            idx = dedupe_triangles(idx, pos, ps[0].double_sided)
        exact = b"".join(np.ascontiguousarray(a).tobytes() for p in ps for a in p.exact)
        merged.append((g, verts, pos, idx, uv, normals, others, m_in - idx.shape[0], exact))

    copies = find_affine_copies([(m[2], m[3], m[8]) for m in merged])
    distinct = [i for i in range(len(merged)) if copies[i] is None]
    weights = {i: 1 for i in distinct}
    for c in copies:
        if c is not None:
            weights[c[0]] += 1
    # never more than LOD_THREADS (the cores, at most 4): -j 8 on 2 cores is 8 processes already
    asked = min(LOD_THREADS, max(1, int(threads)) if threads is not None else LOD_THREADS)
    threads = min(asked, len(distinct))
    # threads the distinct meshes leave idle measure a chain's levels at once (a model of one
    # big mesh, a scan, used one core of -j 2 for all of its bounds)
    level_threads = max(1, asked // max(1, len(distinct)))
    shares = None
    if options.balance_meshes and options.error_targets() is None and len(distinct) > 1:
        shares = balanced_ratios([merged[i][2:6] + (merged[i][6],) for i in distinct],
                                 [weights[i] for i in distinct], options, threads=threads)
        shares = dict(zip(distinct, shares))

    def chain_of(i: int) -> tuple[LodLevel, ...]:
        _, _, pos, idx, uv, normals, others, _, _ = merged[i]
        opts = options if shares is None else dataclasses.replace(options, ratios=shares[i])
        return build_lod_chain(pos, idx, uv=uv, normals=normals, other_attributes=others,
                               options=opts, threads=level_threads).levels

    # distinct meshes are independent: largest first on LOD_THREADS threads (the measuring
    # kernels release the GIL; in a build's worker, the threads beyond this one use only idle
    # workers' cores: assetpipe/core/cores.py); each chain is a pure function of its mesh, so
    # the result does not depend on the thread count or order
    if threads > 1:
        distinct.sort(key=lambda i: -merged[i][3].shape[0])
        source_levels = dict(zip(distinct, map_spare(chain_of, distinct, threads)))
    else:
        source_levels = {i: chain_of(i) for i in distinct}
    out: list[LodMesh] = []
    # a copy has its source's index buffers (reversed when mirrored): the same row layout
    plans: dict[tuple[int, bool], LayoutPlan] = {}
    for i, (g, verts, pos, idx, uv, normals, others, dups, _) in enumerate(merged):
        copy = copies[i]
        if copy is None:
            levels = source_levels[i]
            plan_key = (i, False)
        else:
            j, lin, resid, mirrored = copy
            sigma = float(np.linalg.svd(lin, compute_uv=False)[0])
            mask = np.zeros(pos.shape[0], bool)
            mask[idx.reshape(-1)] = True
            used = pos[mask]
            lo, hi = column_bounds(used) if used.size else (np.zeros(3), np.zeros(3))
            diag = float(np.linalg.norm(hi - lo))
            levels = _scaled_levels(source_levels[j], sigma, resid, diag, options, mirrored)
            # a moved level's vertices through the same map: copy(x) = lin x + t, so
            # copy(moved) = copy(original) + lin (moved - original), within the fit's residual
            src_pos = merged[j][2]
            levels = tuple(lv if lv.positions is None else dataclasses.replace(
                lv, positions=pos + (lv.positions - src_pos) @ lin.T) for lv in levels)
            plan_key = (copy[0], bool(mirrored))
        if plan_key not in plans:
            plans[plan_key] = layout_plan(levels, verts.shape[0])
        vertices, new_levels, counts, starts = vertex_layout(verts, levels, plans[plan_key])
        out.append(LodMesh(parts=tuple(g), vertices=vertices, levels=new_levels, vertex_counts=counts,
                           duplicates=dups, copy_of=None if copy is None else copy[0],
                           vertex_starts=starts))
    return out


@dataclass(frozen=True, eq=False)
class LayoutPlan:
    """Where a mesh's vertex rows go (:func:`layout_plan`), from its levels' indices alone: the
    same for every mesh with the same index buffers (a mesh and its affine copies).

    order: (N,) int64 new -> old row of level 0's vertices; indices: per level, (K, 3) uint32
    into the laid-out rows; counts, starts: per level, the end of the rows it uses and the
    start of its own rows (0 for levels over level 0's rows); own: per level, None or the
    (U,) int64 vertices whose moved copies are its own rows, in order of first use."""

    order: np.ndarray
    indices: tuple[np.ndarray, ...]
    counts: tuple[int, ...]
    starts: tuple[int, ...]
    own: tuple[np.ndarray | None, ...]


def layout_plan(levels: Sequence[LodLevel], n: int) -> LayoutPlan:
    """The row layout of a mesh of ``n`` vertices with these levels (see :func:`vertex_layout`)."""
    empty = np.zeros((0, 3), np.uint32)
    order = reorder_for_lod_prefix([lv.indices if lv.positions is None else empty for lv in levels], n)
    idx, counts = list(order.indices), list(order.vertex_counts)
    starts = [0] * len(levels)
    own: list[np.ndarray | None] = [None] * len(levels)
    end = n
    for k, lv in enumerate(levels):
        if lv.positions is None:
            continue
        flat = np.asarray(lv.indices, np.int64).reshape(-1)
        ids = first_use_order(flat)
        local = np.zeros(n, np.int64)
        local[ids] = np.arange(ids.size)
        idx[k] = (local[np.asarray(lv.indices, np.int64)] + end).astype(np.uint32).reshape(-1, 3)
        own[k] = ids
        starts[k] = end
        end += ids.size
        counts[k] = end
    return LayoutPlan(order.order, tuple(idx), tuple(counts), tuple(starts), tuple(own))


def vertex_layout(verts: np.ndarray, levels: Sequence[LodLevel], plan: LayoutPlan | None = None
                  ) -> tuple[np.ndarray, tuple[LodLevel, ...], tuple[int, ...], tuple[int, ...]]:
    """The mesh's vertex rows and its levels' indices into them (docs/FORMAT.md).

    verts: (N, C) float32 rows of level 0 (position in the first three columns). Levels over
    level 0's vertices (``positions`` None) share them, ordered by
    :func:`pipelines.lod.reorder_for_lod_prefix` so that each uses a prefix; each level with
    its own (moved) positions gets its own rows after them, in order of first use: a copy of
    the row of the vertex it moved, with the moved position. Returns (rows (N + extra, C),
    levels with remapped ``indices`` and ``positions`` dropped, per level the end of the rows
    it uses (its prefix, or the end of its own rows), per level the start of its own rows or
    0). ``plan``: :func:`layout_plan` of levels with these same indices (a copy's source's),
    or None to make it."""
    if plan is None:
        plan = layout_plan(levels, verts.shape[0])
    rows = [verts[plan.order]]
    for lv, ids in zip(levels, plan.own):
        if ids is not None:
            own = np.array(verts[ids], dtype=verts.dtype, copy=True)
            own[:, :3] = lv.positions[ids]
            rows.append(own)
    new_levels = tuple(dataclasses.replace(lv, indices=i, positions=None) for lv, i in zip(levels, plan.indices))
    return (rows[0] if len(rows) == 1 else np.concatenate(rows)), new_levels, plan.counts, plan.starts


__all__ = ["LodPart", "LodMesh", "balanced_ratios", "build_model_lods", "dedupe_triangles",
           "find_affine_copies", "layout_plan", "merge_groups", "vertex_layout", "LayoutPlan", "LodChain"]
