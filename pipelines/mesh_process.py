"""Mesh processing: the seed generator's Assimp flags, done with numpy and meshoptimizer.

``process_mesh(mesh, material, options) -> ProcessedMesh``

1. choose the vertex attributes the layout needs (the seed layout: position + the UV set the
   base colour texture samples); missing UVs are zero-filled as the seed does;
2. sanitise non-finite UVs / normals (set to 0, counted in a warning);
3. join identical vertices (exact equality of every kept attribute, like
   ``aiProcess_JoinIdenticalVertices``);
4. round positions to float32 (what the output stores; relative to an ``offset`` when the
   model is recentred) and drop degenerate triangles *of that data*: a repeated index, or zero
   area (measured in float64 in a local frame, relative to the mesh size), so a model far
   from its origin, whose float32 positions collapse, is counted and dropped the same way
   whether it came as float64 OBJ text or float32 glTF;
5. generate smooth normals where the layout needs them and the source has none, and tangents
   where the layout carries them (``aiProcess_GenSmoothNormals``; MikkTSpace tangents, as glTF
   specifies, from ``pipelines/tangents.py``);
6. drop duplicate triangles (after the weld, so they are found by vertex identity): exact
   ones (the same three vertices, the same winding, from any starting vertex) always, and
   reversed ones (the same three vertices, opposite winding) when the material is double-sided,
   where the two faces cover the same pixels from both sides and z-fight; a single-sided
   material keeps a reversed pair (back-face culling shows exactly one of them from each side:
   the pair is how a one-sided material shows both sides);
7. vertex cache then vertex fetch optimisation (meshoptimizer), which also drops unreferenced
   vertices.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from assetpipe.core.rows import column_bounds, position_ids
from assetpipe.pipelines import simplify as simp
from assetpipe.pipelines.mesh_options import ATTRIBUTE_COMPONENTS, DEFAULT_MESH_OPTIONS, MeshOptions
from assetpipe.pipelines.model import MeshData
from assetpipe.pipelines.tangents import mikktspace_tangents


# warn when the float32 position grid, at the model's largest coordinate, is coarser than this
# fraction of the bounding-box diagonal (1e-4: a 1 m model's vertices snap to 0.1 mm steps; reached
# near |x| = 840 to 1700 diagonals from the origin); docs/FORMAT.md, "Precision"
FLOAT32_WARN_FRACTION = 1e-4


@dataclass(frozen=True, eq=False)
class ProcessedMesh:
    """A mesh ready for LODs and writing.

    ``vertices`` (N, C) float64: the layout's attributes side by side, in layout order
    (position first; C = stride / 4). ``indices`` (M, 3) uint32, each < N.
    """

    name: str
    material: int
    vertices: np.ndarray
    indices: np.ndarray
    degenerate_dropped: int = 0
    welded: int = 0
    duplicates_dropped: int = 0
    warnings: tuple[str, ...] = field(default=())

    @property
    def positions(self) -> np.ndarray:
        return self.vertices[:, :3]


def process_mesh(mesh: MeshData, options: MeshOptions = DEFAULT_MESH_OPTIONS, uv_set: int = 0,
                 double_sided: bool = False, offset=None, order_plans: dict | None = None) -> ProcessedMesh:
    """Process one mesh. ``uv_set``: the UV set the material's base colour texture samples
    (its ``texCoord``); it goes into the layout's ``uv0`` slot, the other set into ``uv1``.
    ``double_sided``: the material's; reversed duplicate triangles are dropped only then.
    ``offset`` (3,): subtracted from the positions (in float64) before they are rounded to
    float32 (a recentred model). ``order_plans``: a dict shared by one model's meshes, which
    lets :func:`optimize_order` optimise each distinct index buffer once (the same output)."""
    warnings: list[str] = []
    pos = np.asarray(mesh.positions, dtype=np.float64)
    if offset is not None:
        pos = pos - np.asarray(offset, dtype=np.float64).reshape(1, 3)
    # what the output stores: every later step (degenerates, normals, LODs and their errors)
    # sees exactly the float32 positions written
    pos = to_float32_exact(pos)
    n = pos.shape[0]
    tris = np.asarray(mesh.indices, dtype=np.uint32).reshape(-1, 3)
    uv_a, uv_b = (mesh.uv1, mesh.uv0) if uv_set == 1 and mesh.uv1 is not None else (mesh.uv0, mesh.uv1)
    provided = {"position": pos, "uv0": uv_a, "uv1": uv_b, "normal": mesh.normals,
                "tangent": mesh.tangents, "color": mesh.colors}

    # 2. sanitise what the layout keeps, and what generated tangents are derived from, first
    needed = set(options.layout)
    if "tangent" in needed and mesh.tangents is None:
        needed |= {"uv0", "normal"}
    for name in sorted(needed - {"position"}, key=list(provided).index):
        arr = provided[name]
        if arr is None:
            continue
        k = ATTRIBUTE_COMPONENTS[name]
        arr = np.asarray(arr, dtype=np.float64)
        arr = arr.reshape(n, -1)[:, :k] if n else arr.reshape(0, k)
        bad = ~np.isfinite(arr)
        if bad.any():
            warnings.append(f"{mesh.name}: {int(bad.any(axis=1).sum())} non-finite {name} values replaced by 0")
            arr = np.where(bad, 0.0, arr)
        provided[name] = arr
    uv_a = provided["uv0"]

    # 4. degenerate triangles of the float32 data
    degenerate = 0
    finite = np.isfinite(pos).all(axis=1)
    if not finite.all():  # beyond float32's range (|x| > 3.4e38): such a vertex cannot be written
        warnings.append(f"{mesh.name}: {int((~finite).sum())} position(s) beyond float32's range; "
                        "their triangles dropped")
        pos = np.where(finite[:, None], pos, 0.0)
        provided["position"] = pos
        off_range = ~finite[tris].all(axis=1) if tris.shape[0] else np.zeros(0, dtype=bool)
        degenerate += int(off_range.sum())
        tris = tris[~off_range]
    if options.drop_degenerate and tris.shape[0]:
        rep = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
        degenerate += int(rep.sum())
        tris = tris[~rep]
    # 6 (first pass, on the source's indices: cheap, and spares the area test, the normals
    # and the weld the work of a mesh made of copies); the second pass follows the weld
    tris, duplicates = drop_duplicate_triangles(tris, drop_reversed=double_sided)
    if options.drop_degenerate and tris.shape[0]:
        area_bad = _zero_area(pos, tris, options.degenerate_area_tolerance)
        degenerate += int(area_bad.sum())
        tris = tris[~area_bad]

    if not double_sided and tris.shape[0] and inside_out(pos, tris):
        warnings.append(f"{mesh.name}: a closed surface whose triangles face inward (negative volume): "
                        "inside out? An engine that culls back faces shows its inside only (fine for a sky "
                        "dome or a room seen from within; otherwise flip its winding in the source)")

    columns = []
    for name in options.layout:
        k = ATTRIBUTE_COMPONENTS[name]
        arr = provided.get(name)
        if name == "normal" and arr is None:
            arr = smooth_normals(pos, tris)
        elif name == "tangent" and arr is None:
            normals = provided["normal"] if provided["normal"] is not None else smooth_normals(pos, tris)
            arr = (mikktspace_tangents(pos, tris, normals, uv_a) if uv_a is not None
                   else tangents_from_uv(pos, tris, normals, uv_a))
            if uv_a is None:
                warnings.append(f"{mesh.name}: tangents requested without UVs; an arbitrary tangent frame was generated")
        elif arr is None:
            arr = np.ones((n, k)) if name == "color" else np.zeros((n, k))
        columns.append(np.asarray(arr, dtype=np.float64).reshape(n, k))
    verts = np.hstack(columns) if columns else pos.copy()

    welded = 0
    if options.weld and n:
        verts, tris, welded = weld_vertices(verts, tris)

    tris, welded_duplicates = drop_duplicate_triangles(tris, drop_reversed=double_sided)
    duplicates += welded_duplicates

    if options.optimize and tris.shape[0]:
        verts, tris = optimize_order(verts, tris, order_plans)
    else:
        verts, tris = compact(verts, tris)
    return ProcessedMesh(name=mesh.name, material=mesh.material, vertices=verts, indices=tris,
                         degenerate_dropped=degenerate, welded=welded, duplicates_dropped=duplicates,
                         warnings=tuple(warnings))


def to_float32_exact(pos: np.ndarray) -> np.ndarray:
    """(N, 3) float64 holding exactly the float32 values the output will store (round to
    nearest, as numpy and every glTF writer do); a value beyond float32's range becomes inf."""
    with np.errstate(over="ignore"):
        return np.asarray(pos, dtype=np.float64).astype(np.float32).astype(np.float64)


def float32_resolution(pos32: np.ndarray) -> tuple[float, float]:
    """(step, diagonal): the float32 spacing at the largest coordinate magnitude of ``pos32``
    (the coarsest position step anywhere in the mesh: a vertex can only sit on that grid) and
    the bounding box diagonal. ``step / diagonal`` is the shape's resolution in float32."""
    if pos32.shape[0] == 0:
        return 0.0, 0.0
    p = np.asarray(pos32, dtype=np.float64)
    lo, hi = column_bounds(p)
    diag = float(np.sqrt(np.sum((hi - lo) ** 2)))
    step = float(np.spacing(np.float32(np.max(np.maximum(np.abs(lo), np.abs(hi))))))
    return step, diag


def inside_out(pos: np.ndarray, tris: np.ndarray) -> bool:
    """Whether ``tris`` (M, 3) over ``pos`` (N, 3) is a closed, consistently wound surface (every
    edge, with vertices at equal positions taken as one, used once in each direction) whose
    signed volume is negative: its triangles face inward. An open or non-manifold mesh is
    never called inside out (its volume means nothing)."""
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if tris.shape[0] < 4:
        return False
    # the signed volume first (one pass): most meshes face outward or are open, and only a
    # negative volume needs the closedness test
    p = np.asarray(pos, np.float64)
    p = p - p[tris[0, 0]]  # volumes about a point of the mesh: no cancellation far out
    x, y, z = (np.ascontiguousarray(p[:, k]) for k in range(3))
    i, j, k = tris[:, 0], tris[:, 1], tris[:, 2]
    volume6 = (x[i] * (y[j] * z[k] - z[j] * y[k]) - y[i] * (x[j] * z[k] - z[j] * x[k])
               + z[i] * (x[j] * y[k] - y[j] * x[k])).sum()
    if float(volume6) >= 0.0:
        return False
    from assetpipe.pipelines.simplify import weld_identical

    t = weld_identical(tris, np.asarray(pos, np.float64)).astype(np.int64)  # one id per position
    n = int(t.max()) + 1
    a = t.reshape(-1)
    b = np.roll(t, -1, axis=1).reshape(-1)
    if (a == b).any():
        return False
    directed = np.sort(a * n + b)
    if (directed[1:] == directed[:-1]).any():  # an edge used twice the same way
        return False
    # every edge with its opposite, once: closed and consistently wound
    return bool(np.array_equal(directed, np.sort(b * n + a)))


def drop_duplicate_triangles(tris: np.ndarray, drop_reversed: bool = False) -> tuple[np.ndarray, int]:
    """(tris without duplicates, count dropped); the first of each kept, order kept.

    Exact duplicates: the same three vertex indices in the same cyclic order (from any starting
    vertex). With ``drop_reversed`` also the opposite cyclic order. Sort-based, vectorised,
    O(M log M): each triangle becomes one integer key (its sorted indices, packed, and its
    winding parity); when key and triangle number fit in 63 bits together, one plain sort of
    the combined integers groups duplicates with the first one leading, else an argsort and
    the smallest triangle number per group."""
    m = tris.shape[0]
    if m < 2:
        return tris, 0
    t0, t1, t2 = (tris[:, k].astype(np.int64) for k in range(3))
    lo = np.minimum(np.minimum(t0, t1), t2)
    hi = np.maximum(np.maximum(t0, t1), t2)
    mid = t0 + t1 + t2 - lo - hi
    bits = max(int(hi.max()).bit_length(), 1)
    key = (lo << bits | mid) << bits | hi
    kbits = 3 * bits
    if not drop_reversed:
        # a cyclic order of ascending indices has exactly two ascending steps, a reversed one one
        flipped = ((t0 < t1).astype(np.int8) + (t1 < t2) + (t2 < t0)) == 1
        key = key << 1 | flipped
        kbits += 1
    ibits = (m - 1).bit_length()
    if kbits + ibits <= 63:
        s = np.sort(key << ibits | np.arange(m, dtype=np.int64))
        k = s >> ibits
        first = np.empty(m, dtype=bool)
        first[0] = True
        np.not_equal(k[1:], k[:-1], out=first[1:])
        keep = s[first] & ((1 << ibits) - 1)
    elif kbits <= 63:
        order = np.argsort(key)
        k = key[order]
        starts = np.flatnonzero(np.concatenate(([True], k[1:] != k[:-1])))
        keep = np.minimum.reduceat(order, starts)
    else:  # > 2^20 vertices: rows of (lo, mid, hi[, flipped]) instead of one packed integer
        cols = [lo, mid, hi] if drop_reversed else [lo, mid, hi, flipped.astype(np.int64)]
        rows = np.ascontiguousarray(np.stack(cols, axis=1))
        _, keep = np.unique(rows.view(np.dtype((np.void, 8 * rows.shape[1]))).reshape(m), return_index=True)
    if keep.size == m:
        return tris, 0
    keep = np.sort(keep)
    return tris[keep], int(m - keep.size)


def _doubled_areas(local: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(M,) float64 ``|(b - a) x (c - a)|`` of triangles ``tris`` (M, 3) over ``local`` (N, 3)
    float64: the values of ``sqrt(einsum("ij,ij->i", x, x))`` of ``x = np.cross(b - a, c - a)``,
    operation for operation (``np.cross``'s three differences of products; the squares summed
    ``(x0 x0 + x2 x2) + x1 x1``, the order numpy 2.4's einsum adds three terms in here), with
    row gathers by ``take`` and no (M, 3) temporaries beyond the corners (2-3x faster)."""
    a = local.take(tris[:, 0], axis=0)
    u = local.take(tris[:, 1], axis=0)
    w = local.take(tris[:, 2], axis=0)
    u -= a
    w -= a
    x = u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1]
    y = u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2]
    z = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
    return np.sqrt((x * x + z * z) + y * y)


def _zero_area(pos: np.ndarray, tris: np.ndarray, tolerance: float) -> np.ndarray:
    """(M,) bool: triangles whose area is zero relative to the mesh's size (float64, centred)."""
    if tris.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    mask = np.zeros(pos.shape[0], dtype=bool)
    mask[tris.reshape(-1)] = True
    used = pos.take(np.flatnonzero(mask), axis=0)  # the referenced vertices: the size of what is drawn
    lo, hi = column_bounds(used)
    centre = (lo + hi) * 0.5
    diag2 = float(np.sum((hi - lo) ** 2))
    area2 = _doubled_areas(pos - centre, tris)
    if diag2 == 0.0:
        return np.ones(tris.shape[0], dtype=bool)
    return area2 <= tolerance * diag2


def weld_vertices(verts: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Join vertices whose every component is bit-identical; keeps first-occurrence order."""
    n = verts.shape[0]
    if n == 0:
        return verts, np.asarray(tris, np.uint32), 0
    v = np.ascontiguousarray(verts)
    v = np.where(v == 0.0, 0.0, v)  # -0.0 and 0.0 are the same vertex
    # meshoptimizer's hash of the records (byte for byte, as np.unique over them compared):
    # ids in first-occurrence order directly, 5-6x faster than the sort
    remap, first = simp.distinct_records(np.ascontiguousarray(v).view(np.uint8).reshape(n, -1))
    return verts[first], remap[tris].astype(np.uint32), n - first.size


def compact(verts: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices, keeping order."""
    used = np.zeros(verts.shape[0], dtype=bool)
    used[tris.reshape(-1)] = True
    if used.all():
        return verts, tris
    remap = np.cumsum(used) - 1
    return verts[used], remap[tris].astype(np.uint32)


def optimize_order(verts: np.ndarray, tris: np.ndarray,
                   plans: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """meshoptimizer's vertex cache optimisation, then vertex fetch reordering (and compaction).

    Both depend on the index buffer and vertex count alone: ``plans`` (a dict the caller keeps
    for one model) remembers them by those, so primitives with the same index buffer (a grid
    of copied spheres: MetalRoughSpheres has 123) are optimised once."""
    import meshoptimizer

    n = verts.shape[0]
    flat = np.ascontiguousarray(tris.reshape(-1), dtype=np.uint32)
    key = (n, flat.tobytes()) if plans is not None else None
    if key is not None and key in plans:
        cache_opt, remap, unique = plans[key]
    else:
        cache_opt = np.empty_like(flat)
        meshoptimizer.optimize_vertex_cache(cache_opt, flat, flat.size, n)
        remap = np.empty(n, dtype=np.uint32)
        unique = meshoptimizer.optimize_vertex_fetch_remap(remap, cache_opt, cache_opt.size, n)
        if key is not None:
            plans[key] = (cache_opt, remap, unique)
    # remap[i] = new position of old vertex i (0xFFFFFFFF for unreferenced ones)
    used = remap != np.uint32(0xFFFFFFFF)
    out = np.empty((unique, verts.shape[1]), dtype=verts.dtype)
    out[remap[used]] = verts[used]
    return out, remap[cache_opt].reshape(-1, 3).astype(np.uint32)


def smooth_normals(pos: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(N, 3) float64 area-weighted vertex normals, shared across vertices at one position."""
    n = pos.shape[0]
    if tris.shape[0] == 0:
        return np.tile([0.0, 0.0, 1.0], (n, 1))
    group = position_ids(pos)
    a, b, c = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
    face = np.cross(b - a, c - a)  # length = 2 * area: area weighting for free
    acc = np.zeros((group.max() + 1, 3))
    for k in range(3):
        np.add.at(acc, group[tris[:, k]], face)
    out = acc[group]
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(norm > 0, out / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, 1.0]))


def tangents_from_uv(pos: np.ndarray, tris: np.ndarray, normals: np.ndarray,
                     uv: np.ndarray | None) -> np.ndarray:
    """(N, 4) float64 tangents (xyz unit, w = handedness) from UV gradients, Gram-Schmidt'd."""
    n = pos.shape[0]
    normals = np.asarray(normals, dtype=np.float64)
    t_acc = np.zeros((n, 3))
    b_acc = np.zeros((n, 3))
    if uv is not None and tris.shape[0]:
        uv = np.asarray(uv, dtype=np.float64)
        p0, p1, p2 = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
        w0, w1, w2 = uv[tris[:, 0]], uv[tris[:, 1]], uv[tris[:, 2]]
        e1, e2 = p1 - p0, p2 - p0
        d1, d2 = w1 - w0, w2 - w0
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        r = np.where(np.abs(det) > 1e-20, 1.0 / np.where(det == 0, 1.0, det), 0.0)[:, None]
        t = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r
        b = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r
        for k in range(3):
            np.add.at(t_acc, tris[:, k], t)
            np.add.at(b_acc, tris[:, k], b)
    # Gram-Schmidt against the normal; fall back to any perpendicular where UVs say nothing
    t = t_acc - normals * np.einsum("ij,ij->i", normals, t_acc)[:, None]
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    fallback = np.cross(normals, helper)
    fallback /= np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), 1e-30)
    t = np.where(norm > 1e-20, t / np.maximum(norm, 1e-30), fallback)
    w = np.where(np.einsum("ij,ij->i", np.cross(normals, t), b_acc) < 0.0, -1.0, 1.0)
    return np.hstack([t, w[:, None]])
