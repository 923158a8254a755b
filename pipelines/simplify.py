"""Thin, correct wrappers over the mesh simplifiers (meshoptimizer, fast-simplification).

Every function here is pure: it takes index and vertex arrays and returns a *new index
buffer into the same vertex array* (no vertex is moved, added or removed), plus the
simplifier's own error estimate. Callers normalise positions first (see :mod:`pipelines.lod`):
meshoptimizer works in float32, which loses everything for coordinates offset by 1e7.

meshoptimizer is used through its PyPI ctypes wrapper (``meshoptimizer==0.2.30a0``), calling
the loaded library directly, because that wrapper

* declares no ctypes argument types for ``meshopt_simplifyWithAttributes`` (it raises
  ``ctypes.ArgumentError``): they are declared here, once, on the library function;
* defaults ``target_error`` to 0.01, which stops long before a triangle target: here the
  default is :data:`NO_ERROR_LIMIT`, so a triangle target is reached when it can be;
* does not make its inputs C-contiguous (a strided view would be read wrongly).

:func:`simplify` always passes ``meshopt_SimplifySparse``: without it meshoptimizer (0.22)
pairs every vertex with *all* vertices at the same position, referenced or not, and a vertex
whose twin is unreferenced (what :func:`weld_identical` leaves behind, or an earlier LOD level
stops using) is classified as a seam it cannot match, i.e. locked. That stalled chains far
above their targets (CesiumMan with normals: 861 triangles for a target of 584, measured
Hausdorff 9.1% of the diagonal; 584 at 0.42% with sparse). Sparse mode also makes each call
cost in proportion to the vertices the input indices use, not the whole vertex array.
``meshopt_SimplifyErrorAbsolute`` goes with it (sparse errors would otherwise be relative to
the subset's extent), so target and result errors keep the meaning documented below.

The error a simplifier returns is *relative to the mesh extent* (meshoptimizer's
``meshopt_simplifyScale``: the largest side of the bounding box); the functions below convert it
to a fraction of the bounding-box *diagonal* so that it compares with the measured errors of
:mod:`pipelines.surface_error`. It is an estimate that ranks results well but is not a bound
(measured Hausdorff distances were 1.6-17x larger on real scans, NOTES-measurements.md).
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from assetpipe.core.rows import column_bounds, unique_rows

SIMPLIFY_LOCK_BORDER = 1 << 0
SIMPLIFY_SPARSE = 1 << 1
SIMPLIFY_ERROR_ABSOLUTE = 1 << 2
#: remove disconnected components once they are cheaper than further collapses (meshopt 0.22+)
SIMPLIFY_PRUNE = 1 << 3

#: A target error large enough never to stop meshoptimizer before the triangle target.
NO_ERROR_LIMIT = 1.0e9

_c_uint_p = ctypes.POINTER(ctypes.c_uint)
_c_float_p = ctypes.POINTER(ctypes.c_float)
_c_ubyte_p = ctypes.POINTER(ctypes.c_ubyte)

_LIB = None


def _lib():
    """The meshoptimizer shared library, with every function used here fully declared."""
    global _LIB
    if _LIB is None:
        from meshoptimizer._loader import lib

        lib.meshopt_simplify.argtypes = [
            _c_uint_p, _c_uint_p, ctypes.c_size_t, _c_float_p, ctypes.c_size_t, ctypes.c_size_t,
            ctypes.c_size_t, ctypes.c_float, ctypes.c_uint, _c_float_p]
        lib.meshopt_simplify.restype = ctypes.c_size_t
        # size_t meshopt_simplifyWithAttributes(unsigned* destination, const unsigned* indices,
        #   size_t index_count, const float* vertex_positions, size_t vertex_count,
        #   size_t vertex_positions_stride, const float* vertex_attributes,
        #   size_t vertex_attributes_stride, const float* attribute_weights,
        #   size_t attribute_count, const unsigned char* vertex_lock, size_t target_index_count,
        #   float target_error, unsigned options, float* result_error)
        lib.meshopt_simplifyWithAttributes.argtypes = [
            _c_uint_p, _c_uint_p, ctypes.c_size_t, _c_float_p, ctypes.c_size_t, ctypes.c_size_t,
            _c_float_p, ctypes.c_size_t, _c_float_p, ctypes.c_size_t, _c_ubyte_p,
            ctypes.c_size_t, ctypes.c_float, ctypes.c_uint, _c_float_p]
        lib.meshopt_simplifyWithAttributes.restype = ctypes.c_size_t
        lib.meshopt_simplifySloppy.argtypes = [
            _c_uint_p, _c_uint_p, ctypes.c_size_t, _c_float_p, ctypes.c_size_t, ctypes.c_size_t,
            ctypes.c_size_t, ctypes.c_float, _c_float_p]
        lib.meshopt_simplifySloppy.restype = ctypes.c_size_t
        lib.meshopt_generateVertexRemap.argtypes = [
            _c_uint_p, _c_uint_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t]
        lib.meshopt_generateVertexRemap.restype = ctypes.c_size_t
        lib.meshopt_simplifyScale.argtypes = [_c_float_p, ctypes.c_size_t, ctypes.c_size_t]
        lib.meshopt_simplifyScale.restype = ctypes.c_float
        _LIB = lib
    return _LIB


# meshoptimizer's attribute-aware simplifier accepts at most this many attribute floats.
MAX_ATTRIBUTES = 16


def _prepare(positions: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pos = np.ascontiguousarray(positions, dtype=np.float32)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"positions must be (N, 3), got {pos.shape}")
    idx = np.ascontiguousarray(indices, dtype=np.uint32).reshape(-1)
    if idx.size % 3:
        raise ValueError("indices must hold 3 per triangle")
    if idx.size and int(idx.max()) >= pos.shape[0]:
        raise ValueError("indices out of range")
    return pos, idx


def _extent_and_diagonal(pos: np.ndarray) -> tuple[float, float]:
    """(largest side, diagonal) of the bounding box of *all* of ``pos`` (N, 3); (0, 0) if empty.

    The largest side is meshoptimizer's ``meshopt_simplifyScale``, the unit of its relative
    errors."""
    if pos.shape[0] == 0:
        return 0.0, 0.0
    lo, hi = column_bounds(pos)
    size = hi.astype(np.float64) - lo
    size = np.where(np.isfinite(size), size, 0.0)
    return float(size.max()), float(np.linalg.norm(size))


def _scale_ratio(pos: np.ndarray, idx: np.ndarray) -> float:
    # meshoptimizer's relative errors are relative to the extent of *all* vertices in the
    # buffer (meshopt_simplifyScale); convert that to a fraction of the same box's diagonal.
    extent, diag = _extent_and_diagonal(np.asarray(pos))
    return extent / diag if extent > 0 and diag > 0 else 1.0


def simplify(
    positions: np.ndarray,
    indices: np.ndarray,
    target_triangles: int,
    *,
    attributes: np.ndarray | None = None,
    attribute_weights: np.ndarray | None = None,
    lock_border: bool = False,
    vertex_lock: np.ndarray | None = None,
    target_error: float = NO_ERROR_LIMIT,
    prune: bool = False,
) -> tuple[np.ndarray, float]:
    """Simplify a triangle mesh with meshoptimizer's edge-collapse simplifier.

    Args:
      positions: (N, 3) float32 or float64. Converted to float32: normalise first.
      indices: (M, 3) (or flat (3M,)) unsigned/int, each < N.
      target_triangles: the triangle count to reach (>= 0). Fewer may come out: meshoptimizer
        removes whole collapses at a time; more come out when the topology forbids collapses.
      attributes: (N, K) float32, K <= 16, e.g. normals and UVs: makes the simplifier keep
        their variation (``meshopt_simplifyWithAttributes``). ``attribute_weights`` (K,) float
        then weighs each column (default 1). Attribute discontinuities (UV seams: vertices
        with the same position and different attributes) are kept closed either way.
      lock_border: never move vertices on open borders (``meshopt_SimplifyLockBorder``).
      vertex_lock: (N,) bool/uint8 per-vertex lock: these vertices are never collapsed
        (without ``attributes``, one attribute column of weight 0 is passed to
        ``meshopt_simplifyWithAttributes``, which alone takes locks).
      target_error: stop once the error would exceed this (relative to the mesh extent:
        the largest side of the bounding box of all ``positions``); the default never stops
        before ``target_triangles``.
      prune: ``meshopt_SimplifyPrune``: also remove whole disconnected components (small
        parts, loose pieces) when that costs less error than further collapses, and, once
        collapses run out, remove the smallest components until the target is reached. Can
        undershoot the target; lets meshes of many small parts reach it.

    Returns:
      ``(indices (K, 3) uint32, error)``: K <= M triangles indexing the same vertices, and
      meshoptimizer's error estimate as a fraction of the bounding-box diagonal of
      ``positions`` (0 when nothing was collapsed).
    """
    pos, idx = _prepare(positions, indices)
    if idx.size == 0:
        return np.zeros((0, 3), np.uint32), 0.0
    lib = _lib()
    target_index_count = max(0, int(target_triangles)) * 3
    dest = np.empty(idx.size, np.uint32)
    err = ctypes.c_float(0.0)
    extent, diag = _extent_and_diagonal(pos)
    # Sparse: only the vertices the indices use are considered (see the module docstring).
    # Absolute errors (positions' units), so that the sparse subset's extent does not matter.
    options = SIMPLIFY_SPARSE | SIMPLIFY_ERROR_ABSOLUTE
    if lock_border:
        options |= SIMPLIFY_LOCK_BORDER
    if prune:
        options |= SIMPLIFY_PRUNE
    abs_target = float(target_error) * extent if extent > 0 else float(target_error)
    abs_target = min(abs_target, 3.0e38)
    if attributes is None and vertex_lock is not None:
        # only meshopt_simplifyWithAttributes takes locks: one attribute column of weight 0
        # (the same collapses as meshopt_simplify otherwise)
        attributes = np.zeros((pos.shape[0], 1), np.float32)
        attribute_weights = np.zeros(1, np.float32)
    if attributes is None:
        n = lib.meshopt_simplify(
            dest.ctypes.data_as(_c_uint_p), idx.ctypes.data_as(_c_uint_p), idx.size,
            pos.ctypes.data_as(_c_float_p), pos.shape[0], 12,
            target_index_count, abs_target, options, ctypes.byref(err))
    else:
        attr = np.ascontiguousarray(attributes, dtype=np.float32)
        if attr.ndim == 1:
            attr = attr[:, None]
        if attr.shape[0] != pos.shape[0]:
            raise ValueError("attributes must have one row per vertex")
        k = attr.shape[1]
        if not 1 <= k <= MAX_ATTRIBUTES:
            raise ValueError(f"attributes must have 1..{MAX_ATTRIBUTES} columns, got {k}")
        attr = np.where(np.isfinite(attr), attr, 0.0).astype(np.float32)
        if attribute_weights is None:
            weights = np.ones(k, np.float32)
        else:
            weights = np.ascontiguousarray(attribute_weights, dtype=np.float32).reshape(-1)
            if weights.size != k:
                raise ValueError("attribute_weights must have one weight per attribute column")
        lock_ptr = _c_ubyte_p()
        if vertex_lock is not None:
            lock = np.ascontiguousarray(vertex_lock, dtype=np.uint8).reshape(-1)
            if lock.size != pos.shape[0]:
                raise ValueError("vertex_lock must have one entry per vertex")
            lock_ptr = lock.ctypes.data_as(_c_ubyte_p)
        n = lib.meshopt_simplifyWithAttributes(
            dest.ctypes.data_as(_c_uint_p), idx.ctypes.data_as(_c_uint_p), idx.size,
            pos.ctypes.data_as(_c_float_p), pos.shape[0], 12,
            attr.ctypes.data_as(_c_float_p), 4 * k, weights.ctypes.data_as(_c_float_p), k,
            lock_ptr, target_index_count, abs_target, options, ctypes.byref(err))
    out = dest[:n].reshape(-1, 3).copy()
    return out, float(err.value) / diag if diag > 0 else float(err.value)


def simplify_sloppy(
    positions: np.ndarray,
    indices: np.ndarray,
    target_triangles: int,
    *,
    target_error: float = NO_ERROR_LIMIT,
    cleanup: bool = True,
) -> tuple[np.ndarray, float]:
    """Simplify with meshoptimizer's sloppy (vertex-clustering) simplifier.

    Much faster than :func:`simplify` and reaches any target, but about 6x the error, does not
    respect topology (holes close, seams and borders move) and may undershoot the target by
    several percent. Its raw output has duplicate faces and non-manifold edges; with
    ``cleanup`` (the default) :func:`cleanup_triangles` removes the degenerate and duplicate
    faces (non-manifold edges remain).

    Shapes as in :func:`simplify`. Returns ``(indices (K, 3) uint32, error)`` with the error a
    fraction of the bounding-box diagonal.
    """
    pos, idx = _prepare(positions, indices)
    if idx.size == 0:
        return np.zeros((0, 3), np.uint32), 0.0
    lib = _lib()
    dest = np.empty(idx.size, np.uint32)
    err = ctypes.c_float(0.0)
    n = lib.meshopt_simplifySloppy(
        dest.ctypes.data_as(_c_uint_p), idx.ctypes.data_as(_c_uint_p), idx.size,
        pos.ctypes.data_as(_c_float_p), pos.shape[0], 12,
        max(0, int(target_triangles)) * 3, float(target_error), ctypes.byref(err))
    out = dest[:n].reshape(-1, 3).copy()
    if cleanup:
        out = cleanup_triangles(out, positions)
    return out, float(err.value) * _scale_ratio(pos, idx)


def cleanup_triangles(indices: np.ndarray, positions: np.ndarray | None = None) -> np.ndarray:
    """Remove degenerate and duplicate triangles (vectorised; order of the rest kept).

    Args:
      indices: (M, 3) integer triangle indices.
      positions: optional (N, 3) positions: then a triangle with two corners at exactly the
        same position (duplicate vertices) is degenerate too. Thin but non-zero-area
        triangles (slivers) are kept: they are real geometry.

    A triangle is a duplicate of an earlier one when it uses the same three vertices, in
    either winding (a back-to-back pair left by clustering is one sheet: the first is kept).

    Returns: (K, 3) uint32, K <= M.
    """
    tri = np.asarray(indices).reshape(-1, 3).astype(np.uint32, copy=False)
    if tri.shape[0] == 0:
        return np.zeros((0, 3), np.uint32)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    keep = (a != b) & (b != c) & (c != a)
    if positions is not None:
        p = np.asarray(positions)
        pa, pb, pc = p[a], p[b], p[c]
        keep &= ~(np.all(pa == pb, axis=1) | np.all(pb == pc, axis=1) | np.all(pc == pa, axis=1))
    kept = np.flatnonzero(keep)
    if kept.size == 0:
        return np.zeros((0, 3), np.uint32)
    key = np.sort(tri[kept], axis=1)
    first = unique_rows(key)[0]
    return np.ascontiguousarray(tri[kept[np.sort(first)]])


def simplify_fast(
    positions: np.ndarray,
    indices: np.ndarray,
    target_triangles: int,
    *,
    preserve_border: bool = False,
    aggressiveness: float = 7.0,
) -> tuple[np.ndarray, float]:
    """Simplify with fast-simplification (Fast-Quadric-Mesh-Simplification), same contract.

    fast-simplification moves the surviving vertices to quadric-optimal positions. An LOD
    must index the *same* vertex array, so the collapses it reports are replayed onto the
    original vertices instead: each collapsed vertex is merged into the vertex that absorbed
    it, and each surviving vertex keeps its original position. The topology is
    fast-simplification's; the geometry is therefore somewhat worse than its own output.
    It drops UVs and can open UV seams (NOTES-measurements.md); prefer :func:`simplify`.

    Args:
      positions: (N, 3) float (used in float64). indices: (M, 3) integer.
      target_triangles: triangle target. preserve_border: never collapse border edges.
      aggressiveness: fast-simplification's ``agg`` (higher: faster, worse).

    Returns: ``(indices (K, 3) uint32, error)``; the error is NaN: this simplifier gives no
    estimate.
    """
    import fast_simplification

    pos = np.ascontiguousarray(positions, dtype=np.float64)
    tri = np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), dtype=np.int64)
    m = tri.shape[0]
    target = int(max(0, min(int(target_triangles), m)))
    if m == 0 or target >= m:
        return tri.astype(np.uint32), math.nan
    # fast-simplification numbers only referenced vertices consistently: compact first.
    used, inverse = np.unique(tri.reshape(-1), return_inverse=True)
    local = inverse.reshape(-1, 3).astype(np.int32)
    _, _, collapses = fast_simplification.simplify(
        pos[used], local, target_count=max(target, 1), agg=aggressiveness,
        return_collapses=True, preserve_border=preserve_border)
    parent = np.arange(used.size, dtype=np.int64)
    collapses = np.asarray(collapses, dtype=np.int64).reshape(-1, 2)
    if collapses.size:
        parent[collapses[:, 1]] = collapses[:, 0]
        # Follow merge chains to their end by pointer jumping (log2(depth) passes).
        while True:
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
    merged = parent[local]
    out = cleanup_triangles(used[merged].astype(np.uint32))
    return out, math.nan


def weld_identical(indices: np.ndarray, *streams: np.ndarray | None) -> np.ndarray:
    """Point every triangle corner at the first of the vertices identical to it in all streams.

    Meshes often carry duplicate vertices (same position, UV and normal). The simplifier sees
    each duplicate as a seam it must keep, which blocks collapses and costs quality (the Duck
    at 1/16: measured Hausdorff 28.5% of the diagonal without welding, 4.8% with). Welding
    only changes *which* of identical vertices an index uses, so the result still indexes the
    same vertex array and renders identically. Vertices are compared byte for byte
    (``meshopt_generateVertexRemap``): exact, no tolerance.

    Args:
      indices: (M, 3) integer, each < N.
      streams: per-vertex arrays with N rows (e.g. positions (N, 3) float64, uv (N, 2),
        normals (N, 3)); None entries are skipped.

    Returns: (M, 3) uint32 indices over the same N vertices.
    """
    tri = np.ascontiguousarray(np.asarray(indices).reshape(-1), dtype=np.uint32)
    if tri.size == 0:
        return tri.reshape(-1, 3)
    cols = [np.asarray(s) for s in streams if s is not None]
    if not cols:
        return tri.reshape(-1, 3)
    n = cols[0].shape[0]
    cols = [c.reshape(n, -1) for c in cols]
    # One packed record per vertex: the raw bytes of every stream, side by side.
    packed = np.ascontiguousarray(np.concatenate(
        [np.ascontiguousarray(c).view(np.uint8).reshape(n, -1) for c in cols], axis=1))
    remap, unique = vertex_remap(packed, tri)
    used = remap != np.uint32(0xFFFFFFFF)
    ids = np.flatnonzero(used)
    new = remap[ids].astype(np.int64)
    # the first (lowest) vertex of each set of identical ones (no sort: a stable argsort by new
    # id took 3.5x a minimum per id here)
    canonical_of_new = np.full(unique, n, dtype=np.int64)
    np.minimum.at(canonical_of_new, new, ids)
    canonical = np.arange(n, dtype=np.int64)
    canonical[ids] = canonical_of_new[new]
    return canonical[tri].astype(np.uint32).reshape(-1, 3)


def vertex_remap(packed: np.ndarray, indices: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """``meshopt_generateVertexRemap`` over ``packed`` (N, B) uint8 vertex records, compared byte
    for byte (a hash, no sort). Returns (remap (N,) uint32, count of distinct records): with
    ``indices`` ((K,) uint32), ids in order of first use by them and 0xFFFFFFFF for vertices they
    do not use; without, every vertex, ids in order of first occurrence (vertex order)."""
    packed = np.ascontiguousarray(packed, dtype=np.uint8)
    n = packed.shape[0]
    remap = np.empty(n, np.uint32)
    if n == 0:
        return remap, 0
    if indices is None:
        ip, count = None, n
    else:
        idx = np.ascontiguousarray(indices, dtype=np.uint32).reshape(-1)
        ip, count = idx.ctypes.data_as(_c_uint_p), idx.size
    unique = _lib().meshopt_generateVertexRemap(
        remap.ctypes.data_as(_c_uint_p), ip, count, packed.ctypes.data_as(ctypes.c_void_p), n,
        packed.shape[1])
    return remap, int(unique)


def distinct_records(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Records of ``packed`` (N, B) uint8 that are equal byte for byte, grouped by
    :func:`vertex_remap` (a hash, no sort): (the id of each record's group (N,) uint32, numbered
    in order of first occurrence; the index of each group's first record (U,) int64, increasing)."""
    remap, _ = vertex_remap(packed)
    if remap.size == 0:
        return remap, np.zeros(0, np.int64)
    top = np.maximum.accumulate(remap)  # ids are handed out in vertex order: a new one is a new maximum
    return remap, np.flatnonzero(np.r_[True, top[1:] > top[:-1]])


def simplifier_names() -> tuple[str, ...]:
    """The simplifier names :mod:`pipelines.lod` accepts."""
    return ("meshopt", "meshopt-attr", "meshopt-sloppy", "fast-simplification")
