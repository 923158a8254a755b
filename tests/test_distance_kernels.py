"""The compiled kernels of the surface-error bound: exact distances and closest points against
the numpy reference (Ericson's closest point), the covering radius against brute force, and
every bound (Lipschitz, convexity, pair) never below the true distance on dense samples of its
cell, and exact where it should be."""

from __future__ import annotations

import numpy as np
import pytest

from assetpipe.pipelines.distance_kernels import (
    closest_points, convex_bound, covering_radius, lipschitz_bound, pair_bound, tri_distance)
from assetpipe.pipelines.surface_error import _closest_on_segment, closest_point_on_triangles


def _bary(n: int = 24) -> np.ndarray:
    """(S, 3) barycentric weights of a regular grid on a triangle, corners included."""
    t = np.linspace(0, 1, n + 1)
    u, v = np.meshgrid(t, t)
    keep = u + v <= 1 + 1e-12
    u, v = u[keep], v[keep]
    return np.stack([1 - u - v, u, v], 1)


def _sphere(subdiv: int = 1):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdiv)
    return (np.ascontiguousarray(m.vertices, dtype=np.float64),
            np.ascontiguousarray(m.faces, dtype=np.int64), m)


def _corners(pos, tri):
    return tuple(np.ascontiguousarray(pos[tri[:, j]]) for j in range(3))


def _brute(points, a, b, c):
    """True distance to the mesh: the smallest over every triangle (small meshes only)."""
    k, f = points.shape[0], a.shape[0]
    p = np.repeat(points, f, axis=0)
    faces = np.tile(np.arange(f, dtype=np.int64), k)
    return tri_distance(p, faces, a, b, c).reshape(k, f).min(axis=1)


def _cells(rng, a, b, c, k, scale):
    """k random cells near the mesh: a jittered copy of a random triangle, pushed off it."""
    f = rng.integers(0, a.shape[0], k)
    v = np.stack([a[f], b[f], c[f]], 1) * (1 + scale) + rng.normal(size=(k, 3, 3)) * scale
    return np.ascontiguousarray(v)


def test_covering_radius_is_exact():
    rng = np.random.default_rng(7)
    a, b, c = rng.normal(size=(3, 120, 3))
    c[:20] = a[:20] + 0.3 * (b[:20] - a[:20])  # collinear
    c[20:25] = a[20:25]                         # a repeated corner
    r = covering_radius(a, b, c)
    # brute force: max over a dense barycentric grid of the distance to the nearest corner
    w = _bary(120)
    pts = w[None, :, 0, None] * a[:, None] + w[None, :, 1, None] * b[:, None] + w[None, :, 2, None] * c[:, None]
    near = np.min(np.stack([np.linalg.norm(pts - x[:, None], axis=2) for x in (a, b, c)]), axis=0)
    brute = near.max(axis=1)
    assert np.all(r >= brute * (1 - 1e-12))
    # the grid misses the exact maximiser by at most one grid step's worth
    step = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1)]), axis=0) / 120
    assert np.all(r <= brute + 1.5 * step)
    # known values: equilateral (circumradius s / sqrt 3), right triangle (half the hypotenuse)
    eq = covering_radius(np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.5, np.sqrt(3) / 2, 0]]))
    assert eq[0] == pytest.approx(1 / np.sqrt(3), rel=1e-9)
    rt = covering_radius(np.array([[0.0, 0, 0]]), np.array([[3.0, 0, 0]]), np.array([[0.0, 4, 0]]))
    assert rt[0] == pytest.approx(2.5, rel=1e-9)


def test_covering_radius_of_corners_within_rounding_of_each_other_is_an_upper_value():
    """Two corners 1e-17 apart beside a third 0.075 away (a UV sphere's pole cell, from a real
    chain): the squared sides do not add up exactly and a denominator rounds to 0. numba raises
    on a division by zero, which stopped the chain; the radius is now the longest side."""
    cell = np.array([[[7.2168783648703286e-02, -1.9337567297406523e-02, -2.7883876791260265e-01],
                      [3.0616169978683824e-17, -1.7676253978748463e-17, -2.8867513459481292e-01],
                      [3.4147900460236046e-17, -9.1499023515386430e-18, -2.8867513459481292e-01]]])
    a, b, c = (np.ascontiguousarray(cell[:, k]) for k in range(3))
    r = covering_radius(a, b, c)[0]
    longest = np.linalg.norm(a[0] - b[0])
    assert longest / 2 <= r <= longest * (1 + 1e-12)
    ub = lipschitz_bound(cell, np.zeros((1, 3)))
    assert np.isfinite(ub).all() and ub[0] >= longest / 2
    # and the same kind of cells by the hundred: corners 1e-17..1e-15 apart, any third corner
    rng = np.random.default_rng(12)
    a = rng.normal(size=(500, 3))
    b = rng.normal(size=(500, 3)) * 1e-3
    c = b + rng.normal(size=(500, 3)) * 10.0 ** rng.uniform(-17, -15, size=(500, 1))
    r = covering_radius(a, b, c)
    assert np.isfinite(r).all()
    assert np.all(r >= 0.5 * np.linalg.norm(a - b, axis=1) * (1 - 1e-9))


def test_triangle_distance_matches_closest_point():
    rng = np.random.default_rng(9)
    a, b, c = rng.normal(size=(3, 3000, 3))
    c[:300] = a[:300] + 0.4 * (b[:300] - a[:300])  # collinear
    b[300:400] = a[300:400]                        # segment
    b[400:450] = c[400:450] = a[400:450]           # point
    p = rng.normal(size=(3000, 3)) * 2
    ref = np.linalg.norm(closest_point_on_triangles(p, a, b, c) - p, axis=1)
    # degenerate rows: the exact answer is the nearest of the three segments
    seg = np.min([np.linalg.norm(_closest_on_segment(p, s, e) - p, axis=1)
                  for s, e in ((a, b), (b, c), (c, a))], axis=0)
    ref[:450] = seg[:450]
    faces = np.arange(3000, dtype=np.int64)
    np.testing.assert_allclose(tri_distance(p, faces, a, b, c), ref, rtol=1e-9, atol=1e-12)
    # the compiled closest point agrees with the numpy one (where that one is defined)
    q = closest_points(p, faces, a, b, c)
    np.testing.assert_allclose(np.linalg.norm(q - p, axis=1), ref, rtol=1e-9, atol=1e-12)


def test_lipschitz_bound_holds_and_is_exact_on_a_plane():
    pos, tri, _ = _sphere()
    a, b, c = _corners(pos, tri)
    rng = np.random.default_rng(3)
    v = _cells(rng, a, b, c, 300, 0.05)
    d = _brute(v.reshape(-1, 3), a, b, c).reshape(-1, 3)
    ub = lipschitz_bound(v, d)
    w = _bary()
    dense = _brute(np.einsum("sj,kjx->ksx", w, v).reshape(-1, 3), a, b, c).reshape(300, -1).max(axis=1)
    assert np.all(ub >= dense)
    # an equilateral cell at height h over a plane: every point is h away, the bound is
    # h + the circumradius (the Lipschitz bound knows nothing else)
    v1 = np.array([[[0.0, 0, 1], [1, 0, 1], [0.5, np.sqrt(3) / 2, 1]]])
    assert lipschitz_bound(v1, np.ones((1, 3)))[0] == pytest.approx(1 + 1 / np.sqrt(3), rel=1e-9)


def test_convex_bound_holds_and_picks_the_best_candidate():
    pos, tri, _ = _sphere()
    a, b, c = _corners(pos, tri)
    rng = np.random.default_rng(4)
    k = 300
    v = _cells(rng, a, b, c, k, 0.02)
    cand = np.ascontiguousarray(rng.integers(0, tri.shape[0], (k, 5)))
    cand[:, 3] = cand[:, 0]  # a repeat is evaluated once and changes nothing
    val, best = convex_bound(v, cand, a, b, c)
    assert np.all((cand == best[:, None]).any(axis=1))
    w = _bary()
    pts = np.einsum("sj,kjx->ksx", w, v)
    per = np.stack([tri_distance(pts.reshape(-1, 3), np.repeat(cand[:, j], w.shape[0]), a, b, c)
                    .reshape(k, -1).max(axis=1) for j in range(5)], 1)
    # the bound is the best candidate's maximum over the cell (convex: at a corner)
    np.testing.assert_allclose(val, per.min(axis=1), rtol=1e-9)
    assert np.all(val >= per.min(axis=1))


def test_pair_bound_holds_and_is_exact_across_a_flat_edge():
    pos, tri, m = _sphere()
    a, b, c = _corners(pos, tri)
    wtri = tri  # the sphere has no split vertices: welded ids are the vertex ids
    rng = np.random.default_rng(5)
    k = 400
    adj = m.face_adjacency
    pick = rng.integers(0, adj.shape[0], k)
    f1, f2 = adj[pick, 0].astype(np.int64), adj[pick, 1].astype(np.int64)
    # cells over the shared edge of two neighbours, and (a quarter) over unrelated pairs
    far = rng.random(k) < 0.25
    f2 = np.where(far, rng.integers(0, tri.shape[0], k), f2)
    mid = 0.5 * (a[f1] + b[f1] + c[f1]) / 3 + 0.5 * (a[f2] + b[f2] + c[f2]) / 3
    v = np.ascontiguousarray(mid[:, None] * 1.01 + rng.normal(size=(k, 3, 3)) * 0.1)
    others = np.ascontiguousarray(np.stack([f2, f1, f2], 1))  # f1 itself and repeats skipped
    pb = pair_bound(v, f1, others, a, b, c, wtri, np.inf)
    w = _bary()
    pts = np.einsum("sj,kjx->ksx", w, v).reshape(-1, 3)
    d1 = tri_distance(pts, np.repeat(f1, w.shape[0]), a, b, c).reshape(k, -1)
    d2 = tri_distance(pts, np.repeat(f2, w.shape[0]), a, b, c).reshape(k, -1)
    pair_true = np.minimum(d1, d2).max(axis=1)   # the best any split between f1 and f2 can do
    fin = np.isfinite(pb)
    assert fin[~far].all()
    assert np.all(pb[fin] >= pair_true[fin] * (1 - 1e-12))
    # two coplanar triangles sharing an edge, a cell lying on both: distance 0 everywhere,
    # which neither triangle alone can show
    P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    T = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int64)
    A, B, C = _corners(P, T)
    cell = np.array([[[0.2, 0.2, 0], [0.9, 0.6, 0], [0.3, 0.9, 0]]])
    alone = convex_bound(cell, np.array([[0, 1]], dtype=np.int64), A, B, C)[0][0]
    assert alone > 0.1
    assert pair_bound(cell, np.array([0]), np.array([[1]]), A, B, C, T, np.inf)[0] == pytest.approx(0.0, abs=1e-12)


def test_near_bounds_equal_the_three_kernels_one_after_another():
    """near_bounds is the Lipschitz, convexity and pair bounds in one pass: the same values
    and hints as the three kernels with the cells each settles dropped before the next."""
    from assetpipe.pipelines.distance_kernels import near_bounds

    pos, tri, m = _sphere()
    a, b, c = _corners(pos, tri)
    rng = np.random.default_rng(21)
    k = 600
    base = rng.integers(0, tri.shape[0], k)
    cen = (a[base] + b[base] + c[base]) / 3
    v = np.ascontiguousarray(cen[:, None] * 1.002 + rng.normal(size=(k, 3, 3)) * 0.03)
    f = np.ascontiguousarray(np.stack([base, rng.integers(0, tri.shape[0], k), base], 1))
    d = np.ascontiguousarray(rng.random((k, 3)) * 0.01)
    hint = base.copy()
    for thr in (0.0, 0.01, 0.03, 0.1):
        for pair in (True, False):
            ub, h = near_bounds(v, d, f, hint, thr, a, b, c, tri, pair)
            want = lipschitz_bound(v, d)
            want_h = hint.copy()
            live = want > thr
            known = np.ascontiguousarray(np.stack([hint, f[:, 0], f[:, 1], f[:, 2]], 1))
            val, best = convex_bound(v, known, a, b, c)
            want[live] = np.minimum(want[live], val[live])
            want_h[live] = best[live]
            live &= want > thr
            if pair:
                pb = pair_bound(v, want_h, f, a, b, c, tri, np.inf)
                want[live] = np.minimum(want[live], pb[live])
            np.testing.assert_array_equal(ub, want)
            np.testing.assert_array_equal(h, want_h)


def test_a_cell_across_a_vertex_of_a_flat_fan_is_settled_by_two_of_its_triangles():
    """A cell (nearly a segment) through the centre of a flat fan of six triangles lies over two
    opposite ones, which meet only at the centre; the cell's best single triangle is a third.
    Paired with that one only, the bound stays far above 0; two of the others, coplanar, settle
    it (LOD step 22: a subdivided box's zero-area cells split until the work ran out)."""
    ang = np.radians(np.arange(7) * 60.0)
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros(7)], 1)
    a = np.zeros((6, 3))
    b, c = ring[:6].copy(), ring[1:7].copy()
    wtri = np.stack([np.zeros(6, np.int64), np.arange(1, 7), np.r_[np.arange(2, 7), 1]], 1)
    u = np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0])
    cell = np.array([[[0.0, 0.0, 0.0], 0.3 * u + [0, 0, 0], -0.3 * u + [1e-9, 0, 0]]])
    thr = 1e-9
    # over triangle 0 (0-60 degrees) and triangle 3 (180-240); the hint, 1, touches the centre only
    with_hint = min(pair_bound(cell, np.array([1]), np.array([[f]]), a, b, c, wtri, thr)[0] for f in (0, 3))
    assert with_hint > 0.1
    both = pair_bound(cell, np.array([1]), np.array([[1, 0, 3]]), a, b, c, wtri, thr)[0]
    assert both <= thr
