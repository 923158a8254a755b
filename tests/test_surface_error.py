"""Surface error: exact point-triangle distances, determinism, frame invariance."""

from __future__ import annotations

import numpy as np
import pytest

from assetpipe.pipelines.surface_error import (
    closest_point_on_triangles, measure_error, points_to_mesh_distance, prepare_reference,
    measure_levels, sample_surface)


def _grid(n: int = 8, z=None) -> tuple[np.ndarray, np.ndarray]:
    """An n x n quad grid in the unit square, (n+1)^2 vertices, 2 n^2 triangles."""
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    zz = np.zeros_like(x) if z is None else z(x, y)
    pos = np.stack([x, y, zz], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + (n + 1), a + (n + 2), a + 1
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.uint32)
    return pos, tri


def _brute_force(points: np.ndarray, pos: np.ndarray, tri: np.ndarray) -> np.ndarray:
    p = np.repeat(points, len(tri), axis=0)
    a, b, c = (np.tile(pos[tri[:, k]], (len(points), 1)) for k in range(3))
    q = closest_point_on_triangles(p, a, b, c)
    return np.linalg.norm(q - p, axis=1).reshape(len(points), len(tri)).min(axis=1)


def test_closest_point_matches_dense_barycentric_search():
    rng = np.random.default_rng(3)
    a, b, c = rng.normal(size=(3, 200, 3))
    p = rng.normal(size=(200, 3)) * 2
    q = closest_point_on_triangles(p, a, b, c)
    exact = np.linalg.norm(q - p, axis=1)
    # dense barycentric grid: never closer than the exact answer, and close to it
    t = np.linspace(0, 1, 121)
    u, v = np.meshgrid(t, t)
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    pts = a[:, None] + u[None, :, None] * (b - a)[:, None] + v[None, :, None] * (c - a)[:, None]
    dense = np.linalg.norm(pts - p[:, None], axis=2).min(axis=1)
    assert np.all(dense >= exact - 1e-12)
    assert np.all(dense - exact <= 0.05 * np.linalg.norm(b - a, axis=1).clip(1) + 0.05)


def test_degenerate_triangles_are_segments_and_points():
    p = np.array([[0.0, 1.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    a = np.zeros((3, 3))
    b = np.array([[2.0, 0, 0], [2.0, 0, 0], [0, 0, 0]])
    c = np.array([[2.0, 0, 0], [1.0, 0, 0], [0, 0, 0]])  # segment, collinear, point
    d = np.linalg.norm(closest_point_on_triangles(p, a, b, c) - p, axis=1)
    np.testing.assert_allclose(d, [1.0, 3.0, 2.0])


def test_tree_distance_matches_brute_force():
    rng = np.random.default_rng(1)
    pos, tri = _grid(6, z=lambda x, y: 0.2 * np.sin(4 * x) * np.cos(3 * y))
    pts = rng.normal(size=(400, 3)) * 0.7 + 0.5
    np.testing.assert_allclose(points_to_mesh_distance(pts, pos, tri), _brute_force(pts, pos, tri),
                               atol=1e-12)
    # a random soup with degenerate triangles too
    v = rng.normal(size=(25, 3))
    f = rng.integers(0, 25, size=(40, 3))
    np.testing.assert_allclose(points_to_mesh_distance(pts, v, f), _brute_force(pts, v, f), atol=1e-12)


def test_known_offset_surfaces():
    pos, tri = _grid(10)
    lifted = pos + [0, 0, 0.01]
    e = measure_error(pos, tri, lifted, tri, samples=2000)
    diag = np.sqrt(2.0)
    assert e.hausdorff == pytest.approx(0.01, rel=1e-9)
    assert e.rms == pytest.approx(0.01, rel=1e-9)
    assert e.hausdorff_rel == pytest.approx(0.01 / diag, rel=1e-9)
    same = measure_error(pos, tri, pos, tri, samples=2000)
    assert same.hausdorff == pytest.approx(0.0, abs=1e-12) and same.rms == pytest.approx(0.0, abs=1e-12)


def test_two_sided():
    # the mesh covers only half of the reference: the forward side sees the missing half
    pos, tri = _grid(10)
    half = tri[pos[tri].mean(axis=1)[:, 0] < 0.5]
    e = measure_error(pos, tri, pos, half, samples=5000)
    assert e.forward_max_rel == pytest.approx(0.5 / np.sqrt(2), rel=1e-6)
    assert e.backward_max_rel == pytest.approx(0.0, abs=1e-12)
    assert e.hausdorff_rel == e.forward_max_rel


def test_deterministic_and_frame_invariant():
    pos, tri = _grid(12, z=lambda x, y: 0.1 * np.sin(6 * x + 2 * y))
    coarse = _grid(4, z=lambda x, y: 0.1 * np.sin(6 * x + 2 * y))
    e1 = measure_error(pos, tri, *coarse, samples=5000)
    e2 = measure_error(pos, tri, *coarse, samples=5000)
    assert e1 == e2
    for offset, scale in ((1e7, 1.0), (0.0, 1e-6), (1e3, 1e6), (-1e7, 1e-3)):
        t = lambda p: p * scale + offset  # noqa: E731
        e = measure_error(t(pos), tri, t(coarse[0]), coarse[1], samples=5000)
        assert e.hausdorff_rel == pytest.approx(e1.hausdorff_rel, rel=0.05)
        assert e.rms_rel == pytest.approx(e1.rms_rel, rel=0.05)
        assert e.hausdorff == pytest.approx(e1.hausdorff * scale, rel=0.05)


def test_shared_vertex_levels_match_general_path():
    pos, tri = _grid(12, z=lambda x, y: 0.1 * np.sin(6 * x + 2 * y))
    sub = tri[::2]
    ref = prepare_reference(pos, tri, samples=3000)
    fast = measure_levels(ref, [sub])[0]
    slow = measure_error(pos, tri, pos, sub, samples=3000)
    assert fast.hausdorff == pytest.approx(slow.hausdorff, rel=1e-12)
    assert fast.rms == pytest.approx(slow.rms, rel=1e-12)


def test_empty_meshes():
    pos, tri = _grid(2)
    empty = np.zeros((0, 3), np.uint32)
    assert measure_error(pos, empty, pos, empty).hausdorff == 0.0
    assert measure_error(pos, tri, pos, empty).hausdorff == np.inf
    assert sample_surface(pos, empty, 10).shape == (0, 3)
