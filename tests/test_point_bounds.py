"""The compiled box and bounding sphere against the numpy computation it replaced in
``assetpipe.format.bounds_of``: the same float64 values, bit for bit, on float32 rows of any
strides, from tiny to huge coordinates; non-finite coordinates are counted (the caller then
takes the numpy way)."""

from __future__ import annotations

import numpy as np

from assetpipe.core.rows import column_bounds
from assetpipe.format import bounds_of
from assetpipe.pipelines.point_bounds import box_and_radius2


def _numpy(rows: np.ndarray):
    p = rows.astype(np.float64)
    lo, hi = column_bounds(p)
    c = (lo + hi) * 0.5
    return lo, hi, np.max(np.einsum("ij,ij->i", p - c, p - c))


def test_the_same_values_as_numpy_bit_for_bit():
    rng = np.random.default_rng(1)
    for t in range(600):
        n = int(rng.integers(1, 1500))
        scale = 10.0 ** rng.uniform(-6, 7)
        a = (rng.standard_normal((n, 5)) * scale + rng.uniform(-1, 1) * scale * rng.uniform(0, 1e3)).astype(np.float32)
        rows = a[:, :3] if t % 2 else a[:, 1:4]  # an interleaved vertex buffer's positions: strided
        lo, hi, r2 = _numpy(rows)
        lo2, hi2, r22, bad = box_and_radius2(rows)
        assert bad == 0
        assert np.array_equal(lo, lo2) and np.array_equal(hi, hi2) and r2 == r22, t


def test_non_finite_coordinates_are_counted_and_bounds_of_takes_numpys_values():
    p = np.array([[0, 0, 0], [1, 2, 3], [np.nan, 0, 0], [0, np.inf, 0]], dtype=np.float32)
    assert box_and_radius2(p)[3] == 2
    b = bounds_of(p)
    assert b["min"][0] is None and b["max"][1] is None  # NaN and inf: null in the JSON, as before
    one = bounds_of(np.array([[1.5, -2.0, 3.0]], dtype=np.float32))
    assert one == {"min": [1.5, -2.0, 3.0], "max": [1.5, -2.0, 3.0], "center": [1.5, -2.0, 3.0], "radius": 0.0}
