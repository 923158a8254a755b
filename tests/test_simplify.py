"""The simplifier wrappers: targets reached, attributes declared, cleanup, welding."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from assetpipe.pipelines import simplify as S


def _sphere(sub: int = 4) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.uint32)


def test_reaches_triangle_target_and_indexes_same_vertices():
    pos, tri = _sphere()  # 5120 triangles
    out, err = S.simplify(pos, tri, 640)
    assert out.dtype == np.uint32 and out.shape[1] == 3
    assert 600 <= len(out) <= 640  # the default error limit no longer stops it early
    assert out.max() < len(pos) and 0 < err < 0.1
    # the wrapper's default (0.01) would have stopped far earlier: ours is a real bound
    limited, _ = S.simplify(pos, tri, 640, target_error=1e-4)
    assert len(limited) > len(out)


def test_with_attributes_does_not_raise_and_respects_shapes():
    pos, tri = _sphere(3)
    uv = (pos[:, :2] * 0.5 + 0.5).astype(np.float32)
    out, err = S.simplify(pos, tri, 200, attributes=uv, attribute_weights=[1.0, 1.0])
    assert 150 <= len(out) <= 200 and np.isfinite(err)
    lock = np.zeros(len(pos), bool)
    lock[:10] = True
    out2, _ = S.simplify(pos, tri, 200, attributes=uv, vertex_lock=lock)
    assert np.isin(np.arange(10), out2).all()  # locked vertices are kept
    with pytest.raises(ValueError, match="one weight per attribute column"):
        S.simplify(pos, tri, 200, attributes=uv, attribute_weights=[1.0])


def test_non_contiguous_inputs():
    pos, tri = _sphere(3)
    wide = np.zeros((len(pos), 6))
    wide[:, ::2] = pos  # a strided view
    out_a, _ = S.simplify(wide[:, ::2], tri[:, :], 300)
    out_b, _ = S.simplify(pos, tri, 300)
    np.testing.assert_array_equal(out_a, out_b)


def test_sloppy_is_cleaned():
    pos, tri = _sphere(4)
    out, err = S.simplify_sloppy(pos, tri, 300)
    assert len(out) > 0 and np.isfinite(err)
    assert np.all((out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 0] != out[:, 2]))
    assert len(np.unique(np.sort(out, axis=1), axis=0)) == len(out)


def test_cleanup_triangles():
    tri = np.array([[0, 1, 2], [1, 2, 0], [2, 1, 0], [0, 0, 1], [0, 1, 3], [3, 4, 5]], np.uint32)
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 2, 2], [2, 2, 2.0]])
    out = S.cleanup_triangles(tri)
    np.testing.assert_array_equal(out, [[0, 1, 2], [0, 1, 3], [3, 4, 5]])
    # with positions: 4 and 5 coincide, so the last triangle is degenerate too
    np.testing.assert_array_equal(S.cleanup_triangles(tri, pos), [[0, 1, 2], [0, 1, 3]])
    assert S.cleanup_triangles(np.zeros((0, 3))).shape == (0, 3)


def test_weld_identical():
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 0], [0.5, 1], [1, 1]], np.float32)
    tri = np.array([[0, 1, 2], [3, 5, 4]], np.uint32)
    # vertex 3 is identical to 1; vertex 4 differs from 2 in UV (a seam): kept apart
    np.testing.assert_array_equal(S.weld_identical(tri, pos, uv), [[0, 1, 2], [1, 5, 4]])
    np.testing.assert_array_equal(S.weld_identical(tri, pos), [[0, 1, 2], [1, 5, 2]])
    np.testing.assert_array_equal(S.weld_identical(tri, pos, None), [[0, 1, 2], [1, 5, 2]])


def test_fast_simplification_keeps_vertex_array():
    pos, tri = _sphere(4)
    out, err = S.simplify_fast(pos, tri, 640)
    assert np.isnan(err)
    assert out.dtype == np.uint32 and out.max() < len(pos)
    assert 500 <= len(out) <= 700


def test_empty_and_tiny():
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    tri = np.array([[0, 1, 2]], np.uint32)
    for fn in (S.simplify, S.simplify_sloppy, S.simplify_fast):
        out, _ = fn(pos, np.zeros((0, 3), np.uint32), 0)
        assert out.shape == (0, 3)
        out, _ = fn(pos, tri, 1)
        assert out.shape[1] == 3 and len(out) <= 1
    with pytest.raises(ValueError, match="indices out of range"):
        S.simplify(pos, np.array([[0, 1, 7]], np.uint32), 1)


def test_unreferenced_twins_do_not_lock_vertices():
    """Welding leaves unreferenced copies of vertices in the buffer (and a coarser LOD level
    stops using vertices): meshoptimizer without SimplifySparse paired each vertex with its
    unreferenced twin, called it an unmatched seam and locked it, so nothing collapsed."""
    pos, tri = _sphere()  # 5120 triangles
    twins = np.concatenate([pos, pos])  # vertices N..2N-1: same positions, never referenced
    out, err = S.simplify(twins, tri, 640)
    assert 600 <= len(out) <= 640 and out.max() < len(pos)
    uv = (twins[:, :2] * 0.5 + 0.5).astype(np.float32)
    out, _ = S.simplify(twins, tri, 640, attributes=uv)
    assert 600 <= len(out) <= 640
    # same result and the same error as without the twins (errors keep their meaning)
    ref, ref_err = S.simplify(pos, tri, 640)
    out, err = S.simplify(twins, tri, 640)
    np.testing.assert_array_equal(out, ref)
    assert err == pytest.approx(ref_err, rel=1e-6)


def test_prune_flag_keeps_the_big_part():
    """Smoke test of ``prune=True`` (meshopt_SimplifyPrune): the target is met and the tiny
    loose parts go before the main surface. (meshoptimizer also collapses these tetrahedra
    away without pruning; a corpus case where only pruning helps is in test_lod.py.)"""
    pos, tri = _sphere(4)  # 5120 triangles, radius 1
    # 50 tiny closed tetrahedra far from the sphere
    extra_p, extra_t = [], []
    for k in range(50):
        c = np.array([3.0 + k * 0.1, 0, 0])
        extra_p.append(c + 0.01 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
        extra_t.append(len(pos) + 4 * k + np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]))
    p = np.concatenate([pos, *extra_p])
    t = np.concatenate([tri, *extra_t]).astype(np.uint32)
    pruned, err = S.simplify(p, t, 300, prune=True)
    assert 0 < len(pruned) <= 300 and np.isfinite(err)
    assert pruned.max() < len(pos)  # the tiny parts went first, the sphere stays


def test_vertex_lock_without_attributes():
    """Locks go through meshopt_simplifyWithAttributes with one weight-0 column: the locked
    vertices stay, and with nothing locked the result is meshopt_simplify's, index for index."""
    pos, tri = _sphere(3)
    plain, _ = S.simplify(pos, tri, 300)
    none_locked, _ = S.simplify(pos, tri, 300, vertex_lock=np.zeros(len(pos), bool))
    np.testing.assert_array_equal(plain, none_locked)
    lock = np.zeros(len(pos), bool)
    lock[::7] = True
    out, _ = S.simplify(pos, tri, 300, vertex_lock=lock)
    assert np.isin(np.flatnonzero(lock), out).all()
    assert len(out) <= len(tri) and out.max() < len(pos)
    with pytest.raises(ValueError, match="one entry per vertex"):
        S.simplify(pos, tri, 300, vertex_lock=lock[:-1])
