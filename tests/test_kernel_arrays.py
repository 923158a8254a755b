"""``borrow``: the same array inside a compiled kernel, without an owner (no reference counting).

What it must keep: the data pointer, shape and strides (reads and writes go to the caller's
array, views of it too); what it must drop: the owner (meminfo), so that numba counts nothing
for it. The kernels that borrow (the bound's) are checked for their values by their own tests;
here the contract itself, seen through a test-only intrinsic that reads the array's fields."""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

from assetpipe.pipelines.kernel_arrays import borrow


@intrinsic
def _fields(typingctx, arr):
    """(data pointer, meminfo pointer, parent pointer) of an array value, as integers."""
    sig = types.UniTuple(types.intp, 3)(arr)

    def codegen(context, builder, signature, args):
        a = context.make_array(signature.args[0])(context, builder, value=args[0])
        intp = context.get_value_type(types.intp)
        vals = [builder.ptrtoint(a.data, intp), builder.ptrtoint(a.meminfo, intp),
                builder.ptrtoint(a.parent, intp)]
        return context.make_tuple(builder, signature.return_type, vals)

    return sig, codegen


@njit
def _own_and_borrowed(a):
    b = borrow(a)
    return _fields(a), _fields(b), b.shape[0], b.shape[1], b.strides[0], b.strides[1]


@njit
def _helper_sum(a, i):
    s = 0.0
    for j in range(a.shape[1]):
        s += a[i, j]
    return s


@njit
def _write_through(a, rows):
    a = borrow(a)
    out = np.empty(rows.shape[0])
    for k in range(rows.shape[0]):
        row = a[rows[k]]          # a view of a borrowed array: no owner either
        row[0] = -row[0]
        out[k] = _helper_sum(a, rows[k])
    return out


def test_a_borrowed_array_keeps_data_shape_and_strides_and_drops_its_owner():
    a = np.arange(24.0).reshape(6, 4)[:, ::2]  # strided: (6, 2), strides (32, 16)
    own, lent, n0, n1, s0, s1 = _own_and_borrowed(a)
    assert own[0] == lent[0] == a.ctypes.data
    assert (n0, n1, s0, s1) == (6, 2) + a.strides
    assert own[1] != 0          # numba's view of a numpy argument has an owner...
    assert lent[1] == 0 and lent[2] == 0   # ...the borrowed one has none (nothing to count)


def test_writes_and_views_through_a_borrowed_array_reach_the_callers_array():
    a = np.arange(12.0).reshape(4, 3)
    expect = a.copy()
    rows = np.array([2, 0, 2], dtype=np.int64)
    got = _write_through(a, rows)
    for r in rows:
        expect[r, 0] = -expect[r, 0]
    np.testing.assert_array_equal(a, expect)
    # each sum read the row as it was after its own write
    ref = expect.copy()
    ref[2, 0] = -ref[2, 0]   # row 2 was flipped twice in all; after the first flip it was this
    assert got[0] == ref[2].sum() and got[1] == expect[0].sum() and got[2] == expect[2].sum()
