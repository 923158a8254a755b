"""The float64 BVH (pipelines/closest_point.py) against brute force over every triangle."""

import numpy as np
import pytest

from assetpipe.pipelines.closest_point import ClosestTriangles, spatial_order
from assetpipe.pipelines.distance_kernels import tri_distance
from assetpipe.pipelines.surface_error import closest_point_on_triangles


def _brute(points, pos, tri):
    """(nearest distance, first triangle at that distance) over all triangles, float64."""
    tri = np.asarray(tri, np.int64)
    a, b, c = (np.ascontiguousarray(pos[tri[:, k]]) for k in range(3))
    d = np.stack([tri_distance(np.repeat(p[None], tri.shape[0], 0), np.arange(tri.shape[0]), a, b, c)
                  for p in points])
    return d.min(axis=1), d


def _soup(rng, m, slivers=0.0):
    pos = rng.normal(size=(3 * m, 3))
    if slivers:  # squash a share of the triangles to width ~1e-7 of their length
        k = int(m * slivers)
        pos[2:3 * k:3] = pos[0:3 * k:3] + (pos[1:3 * k:3] - pos[0:3 * k:3]) * 0.5 \
            + rng.normal(scale=1e-7, size=(k, 3))
    return pos, np.arange(3 * m).reshape(-1, 3)


@pytest.mark.parametrize("m,slivers", [(1, 0.0), (7, 0.0), (300, 0.0), (300, 0.5), (2000, 0.1)])
def test_nearest_matches_brute_force(m, slivers):
    rng = np.random.default_rng(m)
    pos, tri = _soup(rng, m, slivers)
    pts = rng.normal(scale=1.5, size=(400, 3))
    d, f = ClosestTriangles.build(pos, tri).query(pts)
    want, all_d = _brute(pts, pos, tri)
    # the same kernel computes both: the nearest distance is bit-identical, and the triangle
    # returned is one at exactly that distance
    np.testing.assert_array_equal(d, want)
    np.testing.assert_array_equal(all_d[np.arange(len(pts)), f], want)


def test_sliver_next_to_a_plane_is_judged_in_float64():
    # a fan of long slivers (width 1e-6 of their length) hugging a plane, and a big triangle
    # 0.2 below: points just above the slivers are nearest to a sliver
    rng = np.random.default_rng(3)
    n = 200
    x = np.sort(rng.uniform(-1, 1, n + 1))
    top = np.stack([np.stack([x[:-1], np.full(n, -1.0), np.zeros(n)], 1),
                    np.stack([x[1:], np.full(n, 1.0), np.zeros(n)], 1),
                    np.stack([x[:-1] + 1e-6, np.full(n, 1.0), np.zeros(n)], 1)], 1)
    floor = np.array([[[-5, -5, -0.2], [5, -5, -0.2], [0, 5, -0.2]]])
    corners = np.concatenate([top, floor]).reshape(-1, 3)
    tri = np.arange(corners.shape[0]).reshape(-1, 3)
    pts = np.stack([rng.uniform(-0.9, 0.9, 500), rng.uniform(-0.9, 0.9, 500),
                    np.full(500, 0.013)], 1)
    d, f = ClosestTriangles.build(corners, tri).query(pts)
    want, _ = _brute(pts, corners, tri)
    np.testing.assert_array_equal(d, want)
    assert (f < n).all()  # a sliver, never the floor 0.2 away
    # and the answer is the exact closest point's distance (numpy Ericson reference)
    q = closest_point_on_triangles(pts, corners[tri[f, 0]], corners[tri[f, 1]], corners[tri[f, 2]])
    np.testing.assert_allclose(d, np.linalg.norm(pts - q, axis=1), rtol=1e-12, atol=1e-15)


def test_radius_and_hint_prune_without_changing_answers():
    rng = np.random.default_rng(5)
    pos, tri = _soup(rng, 500)
    pts = rng.normal(size=(1000, 3))
    ct = ClosestTriangles.build(pos, tri)
    d, f = ct.query(pts)
    # an upper value as radius and any triangle as hint: same answer
    d2, f2 = ct.query(pts, radius=d * 1.5 + 1e-9, hint=rng.integers(0, tri.shape[0], pts.shape[0]))
    np.testing.assert_array_equal(d2, d)
    np.testing.assert_array_equal(_brute(pts, pos, tri)[1][np.arange(len(pts)), f2], d)
    # a radius below the distance finds nothing there: inf and -1
    d3, f3 = ct.query(pts, radius=d * 0.5)
    assert np.isinf(d3).all() and (f3 == -1).all()


def test_empty_mesh_and_no_points():
    ct = ClosestTriangles.build(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    d, f = ct.query(np.ones((3, 3)))
    assert np.isinf(d).all() and (f == -1).all()
    d, f = ClosestTriangles.build(np.eye(3), [[0, 1, 2]]).query(np.zeros((0, 3)))
    assert d.shape == (0,) and f.shape == (0,)


def test_degenerate_triangles_count_as_segments_and_points():
    pos = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5]], float)
    tri = np.array([[0, 1, 2], [3, 3, 3]])  # a segment and a point
    pts = np.array([[1.0, 1.0, 0.0], [5.0, 5.0, 6.0], [3.0, 0.0, 0.0]])
    d, f = ClosestTriangles.build(pos, tri).query(pts)
    np.testing.assert_allclose(d, [1.0, 1.0, 1.0], rtol=1e-15)
    np.testing.assert_array_equal(f, [0, 1, 0])


def test_same_tree_and_answers_for_any_input_order_of_queries():
    rng = np.random.default_rng(9)
    pos, tri = _soup(rng, 800)
    pts = rng.normal(size=(2000, 3))
    ct = ClosestTriangles.build(pos, tri)
    d, f = ct.query(pts)
    perm = rng.permutation(pts.shape[0])
    dp, fp = ct.query(pts[perm])
    np.testing.assert_array_equal(dp, d[perm])
    np.testing.assert_array_equal(fp, f[perm])
    o = spatial_order(pts)
    assert np.array_equal(np.sort(o), np.arange(pts.shape[0]))


def test_deep_unbalanced_input_keeps_the_tree_within_its_stack():
    # triangles at geometrically shrinking distances: SAH splits would peel one at a time;
    # the depth cap falls back to median splits (no overflow, right answers)
    k = 3000
    off = 2.0 ** -np.arange(k, dtype=float) * 1e3
    pos = np.concatenate([np.stack([off, np.zeros(k), np.zeros(k)], 1),
                          np.stack([off, np.full(k, 1e-3), np.zeros(k)], 1),
                          np.stack([off, np.zeros(k), np.full(k, 1e-3)], 1)])
    tri = np.stack([np.arange(k), np.arange(k) + k, np.arange(k) + 2 * k], 1)
    pts = np.stack([np.geomspace(1e-300, 1e3, 300), np.full(300, 0.5), np.zeros(300)], 1)
    d, _ = ClosestTriangles.build(pos, tri).query(pts)
    np.testing.assert_array_equal(d, _brute(pts, pos, tri)[0])


def test_non_finite_input_is_refused():
    with pytest.raises(ValueError, match="non-finite triangle corners"):
        ClosestTriangles.build(np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), [[0, 1, 2]])
    ct = ClosestTriangles.build(np.eye(3), [[0, 1, 2]])
    with pytest.raises(ValueError, match="non-finite points"):
        ct.query(np.array([[0.0, np.inf, 0.0]]))


@pytest.mark.parametrize("m,slivers", [(1, 0.0), (300, 0.0), (300, 0.5), (2000, 0.1)])
def test_max_distance_is_the_largest_query_answer_bit_for_bit(m, slivers):
    rng = np.random.default_rng(40 + m)
    pos, tri = _soup(rng, m, slivers)
    ct = ClosestTriangles.build(pos, tri)
    for n in (1, 5, 63, 64, 3000):  # below and above the size sorted spatially, and the seeds
        pts = rng.normal(scale=1.5, size=(n, 3))
        want = ct.query(pts)[0].max()
        got, stopped = ct.max_distance(pts)
        assert got == want and not stopped


def test_max_distance_stops_above_the_bar_with_a_distance_it_evaluated():
    rng = np.random.default_rng(41)
    pos, tri = _soup(rng, 400)
    ct = ClosestTriangles.build(pos, tri)
    pts = rng.normal(scale=1.5, size=(2000, 3))
    d = ct.query(pts)[0]
    bar = float(np.median(d))
    got, stopped = ct.max_distance(pts, stop=bar)
    assert stopped and bar < got <= d.max() and got in set(d.tolist())
    # a bar at the answer itself is not exceeded: the exact answer
    assert ct.max_distance(pts, stop=float(d.max())) == (d.max(), False)
    # bars at and one float below distances: a stopped value is above the bar after its root
    # (a squared comparison rounds: it let a value equal to the bar through)
    for bar in np.concatenate([np.nextafter(np.sort(d)[-50:-1], -np.inf), np.sort(d)[-400:-1]]):
        got, stopped = ct.max_distance(pts, stop=float(bar))
        assert stopped and got > bar


def test_max_distance_of_no_points_and_of_an_empty_mesh():
    assert ClosestTriangles.build(np.eye(3), [[0, 1, 2]]).max_distance(np.zeros((0, 3))) == (0.0, False)
    empty = ClosestTriangles.build(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert empty.max_distance(np.ones((2, 3)))[0] == np.inf
