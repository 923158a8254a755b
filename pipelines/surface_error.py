"""Measured surface error between two triangle meshes: two-sided Hausdorff and RMS distance.

Method (deterministic: fixed seed)
----------------------------------
1. Both meshes are put in the *reference's* local frame: centred on the reference's bounding
   box and scaled to a unit diagonal, in float64. The same relative error then comes out for
   a model offset by 1e7 or scaled by 1e-6 (in model units it scales with the model).
2. Each mesh is sampled: ``samples`` points drawn area-weighted (uniform on the surface) plus
   every vertex its triangles use.
3. Each sample's distance to the *other* mesh's triangles is computed exactly (closest point
   on a triangle, through point-cloud-utils' AABB tree: libigl's
   ``point_mesh_squared_distance``). trimesh.proximity is not used: it overstated distances
   1.2-6x on small-unit meshes, and point-to-point distances to samples overstate the RMS
   (NOTES-measurements.md).
4. ``hausdorff`` is the largest distance over both directions and all samples (area samples
   and vertices): a lower bound of the true Hausdorff distance that converges with
   ``samples``. ``rms`` is ``sqrt((mean_ab + mean_ba) / 2)`` of the squared distances of the
   area-weighted samples only (vertices are not uniform on the surface), i.e. the mean of the
   two one-sided mean-square distances.

Results are in model units and as a fraction of the reference's bounding-box diagonal
(``*_rel``). An empty mesh against a non-empty one is infinitely far (``inf``); two empty
meshes are 0 apart. Degenerate triangles are fine (they count as segments or points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

DEFAULT_SAMPLES = 50_000
DEFAULT_SEED = 0


@dataclass(frozen=True)
class SurfaceError:
    """Two-sided surface distance between a mesh and its reference.

    ``hausdorff`` and ``rms`` are in model units; ``hausdorff_rel`` and ``rms_rel`` are the
    same divided by the reference's bounding-box diagonal. ``forward_max`` is the one-sided
    maximum from the reference to the mesh (what is lost), ``backward_max`` from the mesh to
    the reference (what is added), both relative.
    """

    hausdorff: float
    rms: float
    hausdorff_rel: float
    rms_rel: float
    forward_max_rel: float = 0.0
    backward_max_rel: float = 0.0


ZERO_ERROR = SurfaceError(0.0, 0.0, 0.0, 0.0)


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


# ----------------------------------------------------------------------------- distances


def points_to_mesh_distance(points: np.ndarray, positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the nearest triangle (point-cloud-utils AABB tree).

    Args: points (P, 3), positions (N, 3), indices (M, 3) with M >= 1. Returns (P,) float64.
    """
    import point_cloud_utils as pcu

    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.shape[0] == 0:
        return np.zeros(0)
    v = np.ascontiguousarray(positions, dtype=np.float64)
    f = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.int32)
    d, _, _ = pcu.closest_points_on_mesh(p, v, f)
    return np.asarray(d, dtype=np.float64)


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact closest point on triangle (a, b, c) to p, elementwise (Ericson, RTCD 5.1.5).

    All arguments (K, 3) float64 (broadcastable). Handles degenerate triangles (segments,
    points). Returns (K, 3) float64. Used as the brute-force reference in the tests.
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


# ----------------------------------------------------------------------------- measuring


@dataclass(frozen=True, eq=False)
class Reference:
    """A reference mesh prepared for repeated measurements (see :func:`prepare_reference`).

    ``positions`` (N, 3) float64 are in the local frame (centred, unit diagonal);
    ``samples`` (S, 3) float64 are its area-weighted samples; ``vertex_used`` (N,) bool marks
    the vertices its triangles use. ``centre`` and ``scale`` map back to model units
    (model = local * scale + centre); ``diagonal`` is the bounding-box diagonal (model units).
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


def _used_mask(indices: np.ndarray, n: int) -> np.ndarray:
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(indices).reshape(-1)] = True
    return mask


def prepare_reference(
    positions: np.ndarray, indices: np.ndarray, *, samples: int = DEFAULT_SAMPLES,
    seed: int = DEFAULT_SEED,
) -> Reference:
    """Normalise a reference mesh and draw its fixed sample set.

    Args: positions (N, 3) float (model units), indices (M, 3) int. ``samples`` area-weighted
    points are drawn with ``seed``; with the used vertices they are the reference side of
    every later measurement, so all levels of a chain are measured against the same points.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    tri = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.int64)
    used = _used_mask(tri, pos.shape[0])
    centre, diag = local_frame(pos, tri)
    scale = diag if diag > 0 and math.isfinite(diag) else 1.0
    local = (pos - centre) / scale
    return Reference(
        positions=local, indices=tri, samples=sample_surface(local, tri, samples, seed),
        vertex_used=used, centre=centre, diagonal=diag, scale=scale, n_samples=samples,
        seed=seed)


_INF_ERROR = SurfaceError(math.inf, math.inf, math.inf, math.inf, math.inf, math.inf)


def _measure(ref: Reference, meshes: list[tuple[np.ndarray, np.ndarray, bool]]) -> list[SurfaceError]:
    """meshes: (local positions, (M, 3) int64 indices, shares ref's vertices)."""
    results: list[SurfaceError | None] = [None] * len(meshes)
    back_points: list[np.ndarray] = []
    back_owner: list[tuple[int, int]] = []  # (mesh, number of area samples first)
    forward: dict[int, tuple[float, float]] = {}
    ref_empty = ref.indices.shape[0] == 0
    ns_ref = ref.samples.shape[0]
    for i, (local, tri, shared) in enumerate(meshes):
        if tri.shape[0] == 0 or ref_empty:
            results[i] = ZERO_ERROR if (tri.shape[0] == 0 and ref_empty) else _INF_ERROR
            continue
        used = _used_mask(tri, local.shape[0])
        # reference -> mesh (what the simplification lost). A reference vertex the mesh also
        # uses is a corner of one of its triangles: its distance is exactly 0, skip it.
        ref_vertices = ref.vertex_used & ~used if shared else ref.vertex_used
        pts = np.concatenate([ref.samples, ref.positions[ref_vertices]])
        d = points_to_mesh_distance(pts, local, tri)
        f_max = float(d.max()) if d.size else 0.0
        f_ms = float(np.mean(d[:ns_ref] ** 2)) if ns_ref else float(np.mean(d**2)) if d.size else 0.0
        forward[i] = (f_max, f_ms)
        # mesh -> reference (what it added), batched into one query below; again the mesh's
        # vertices that are used reference vertices are exactly on the reference.
        s = sample_surface(local, tri, ref.n_samples, ref.seed + 1)
        mesh_vertices = used & ~ref.vertex_used if shared else used
        back_points.append(np.concatenate([s, local[mesh_vertices]]))
        back_owner.append((i, s.shape[0]))
    if back_points:
        d_all = points_to_mesh_distance(np.concatenate(back_points), ref.positions, ref.indices)
        start = 0
        for (i, ns), pts in zip(back_owner, back_points):
            d = d_all[start:start + pts.shape[0]]
            start += pts.shape[0]
            b_max = float(d.max()) if d.size else 0.0
            b_ms = float(np.mean(d[:ns] ** 2)) if ns else float(np.mean(d**2)) if d.size else 0.0
            f_max, f_ms = forward[i]
            h = max(f_max, b_max)
            r = math.sqrt(0.5 * (f_ms + b_ms))
            results[i] = SurfaceError(h * ref.scale, r * ref.scale, h, r, f_max, b_max)
    return results  # type: ignore[return-value]


def measure_against(
    ref: Reference, meshes: Sequence[tuple[np.ndarray, np.ndarray]]
) -> list[SurfaceError]:
    """Measure several meshes against one prepared reference.

    Args:
      ref: from :func:`prepare_reference`.
      meshes: ``(positions (N, 3) model units, indices (M, 3))`` pairs.

    The mesh-to-reference distances of all meshes are computed in one query against the
    reference (one tree build), the reference-to-mesh distances with one query per mesh.
    """
    prepared = []
    for pos, idx in meshes:
        local = (np.asarray(pos, dtype=np.float64).reshape(-1, 3) - ref.centre) / ref.scale
        prepared.append((local, np.ascontiguousarray(np.asarray(idx).reshape(-1, 3), dtype=np.int64), False))
    return _measure(ref, prepared)


def measure_levels(ref: Reference, levels: Sequence[np.ndarray]) -> list[SurfaceError]:
    """Measure index buffers over the reference's *own* vertex array (LOD levels).

    Args: ref from :func:`prepare_reference`; levels: (K, 3) int arrays indexing the
    reference's positions. Same results as :func:`measure_against` with the reference's
    positions, faster: vertices shared by both meshes are exactly 0 apart and not queried.
    """
    prepared = [(ref.positions, np.ascontiguousarray(np.asarray(l).reshape(-1, 3), dtype=np.int64), True)
                for l in levels]
    return _measure(ref, prepared)


def measure_error(
    ref_pos: np.ndarray, ref_idx: np.ndarray, pos: np.ndarray, idx: np.ndarray, *,
    samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
) -> SurfaceError:
    """Two-sided Hausdorff and RMS surface distance between a mesh and a reference.

    Args:
      ref_pos: (N, 3) float, ref_idx: (M, 3) int: the reference (e.g. LOD0), model units.
      pos: (N2, 3) float, idx: (M2, 3) int: the mesh measured (may share ``ref_pos``).
      samples: area-weighted samples per side (plus all used vertices). seed: fixed.

    Returns: :class:`SurfaceError` (model units and fractions of the reference's diagonal).
    """
    ref = prepare_reference(ref_pos, ref_idx, samples=samples, seed=seed)
    return measure_against(ref, [(pos, idx)])[0]
