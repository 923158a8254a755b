"""assetpipe/core/rows.py: distinct rows against np.unique."""

import numpy as np

from assetpipe.core.rows import column_bounds, position_ids, unique_rows


def test_unique_rows_matches_numpy():
    rng = np.random.default_rng(0)
    rows = rng.integers(0, 4, size=(500, 3))
    firsts, ids = unique_rows(rows)
    _, want_first, want_inv = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    # the same rows in the same (sorted) order: the same first occurrences and ids
    np.testing.assert_array_equal(firsts, want_first)
    np.testing.assert_array_equal(ids, want_inv.reshape(-1))
    assert unique_rows(np.zeros((0, 3), np.int64))[0].shape == (0,)


def test_position_ids_group_equal_positions_and_only_those():
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(300, 3))
    pos = np.concatenate([pos, pos[:100], -0.0 * pos[:1]])
    pos[-1] = 0.0
    pos[0] = [-0.0, 0.0, -0.0]  # -0.0 equals 0.0, as == has it
    ids = position_ids(pos)
    same = (pos[:, None, :] == pos[None, :, :]).all(axis=2)
    np.testing.assert_array_equal(ids[:, None] == ids[None, :], same)


def test_column_bounds_equal_numpy_min_max():
    rng = np.random.default_rng(2)
    for dtype in (np.float32, np.float64, np.int64):
        rows = (rng.normal(size=(1000, 3)) * 100).astype(dtype)
        lo, hi = column_bounds(rows)
        assert lo.dtype == rows.dtype and hi.dtype == rows.dtype
        np.testing.assert_array_equal(lo, rows.min(axis=0))
        np.testing.assert_array_equal(hi, rows.max(axis=0))
    one = np.array([[np.nan, 1.0]])  # NaN propagates as numpy's does
    np.testing.assert_array_equal(column_bounds(one)[0], one.min(axis=0))


def test_edge_runs_group_each_undirected_edge_once():
    from assetpipe.core.rows import edge_runs

    # a quad of two triangles, a fin on their shared edge, and a degenerate triangle
    tri = np.array([[0, 1, 2], [2, 1, 3], [1, 2, 4], [5, 5, 6]])
    key, order, start, count = edge_runs(tri)
    # the shared edge 1-2 in both directions and the fin's: three slots in one run
    assert count.sum() == 12 and sorted(count.tolist()) == [1, 1, 1, 1, 1, 1, 1, 2, 3]
    three = order[start[count == 3][0]:][:3]
    assert sorted(three.tolist()) == [1, 3, 6]  # slots 0*3+1 (1-2), 1*3+0 (2-1), 2*3+0 (1-2)
    # the degenerate edge 5-5 and the edge 6-5 / 5-6 of the degenerate triangle: 6-5 twice
    assert key[9 + 1] == key[9 + 2] and key[9] != key[9 + 1]
    assert edge_runs(np.zeros((0, 3), int))[3].size == 0


def test_stable_argsort_and_unique_first_are_numpys_stable_results():
    """The faster sorts give numpy's own stable answers: equal keys in index order, and per
    distinct key its lowest index (what ``np.unique(return_index=True)`` gives), on keys with
    many repeats, few repeats, one value, and uint64 keys using all 64 bits."""
    from assetpipe.core.rows import stable_argsort, unique_first

    rng = np.random.default_rng(5)
    for n, top in ((1, 1), (7, 1), (500, 3), (3000, 3000), (20000, 50)):
        k = rng.integers(0, top, n).astype(np.int64)
        np.testing.assert_array_equal(stable_argsort(k, top), np.argsort(k, kind="stable"))
        np.testing.assert_array_equal(stable_argsort(k, 1 << 62), np.argsort(k, kind="stable"))  # no room: stable sort
        np.testing.assert_array_equal(unique_first(k)[1], np.unique(k, return_index=True)[1])
    wide = rng.integers(0, 2**63 - 1, 4000, dtype=np.int64).astype(np.uint64) * np.uint64(2)
    wide = wide[rng.integers(0, 4000, 9000)]
    np.testing.assert_array_equal(unique_first(wide)[1], np.unique(wide, return_index=True)[1])
    assert unique_first(np.zeros(0, np.uint64))[1].size == 0


def test_unique_first_and_first_use_order_are_numpys_answers():
    from assetpipe.core.rows import first_use_order, unique_first

    rng = np.random.default_rng(8)
    for n, top in ((0, 1), (1, 1), (300, 7), (5000, 4000)):
        k = rng.integers(0, top, n).astype(np.int64)
        u, f = np.unique(k, return_index=True)
        u2, f2 = unique_first(k)
        np.testing.assert_array_equal(u, u2)
        np.testing.assert_array_equal(f, f2)
        np.testing.assert_array_equal(first_use_order(k), u[np.argsort(f, kind="stable")])
