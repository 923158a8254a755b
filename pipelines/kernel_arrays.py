"""Arrays inside compiled kernels without reference counting (:func:`borrow`).

numba counts references to every array a compiled function holds: each call of a helper that
takes arrays increments and decrements the count of each one (a locked instruction apiece),
and so does each view made of one. In the bound's kernels those calls sit in the inner loops
(a cell's convexity bound called ``_cell_max`` four times, each calling ``_dist2`` three
times, with four and three arrays): ``perf`` put 6-7% of a cold corpus build's CPU in numba's
``NRT_incref``/``NRT_decref``, 35% of ``near_bounds``'s and 21% of the height field's.

:func:`borrow` gives a kernel the same array (data, shape, strides) with no owner attached:
numba skips the count of such an array (``NRT_incref`` tests for a null owner first), for it
and every view of it. The results are the same, bit for bit; only the counting goes.

The contract: borrow only what outlives the whole call, i.e. the kernel's own arguments (the
caller holds them until the kernel returns), never an array the kernel makes (numba frees it
after its last use, and a borrowed view would then point at freed memory), and never return
or keep a borrowed array. A kernel whose scratch arrays are passed to helpers allocates them in
a thin wrapper and hands them to the kernel proper as arguments (:mod:`pipelines.patch_bound`).

numba's cache of a kernel is checked against its own file only: a change to this file must be
followed by a change to (or a touch of) the files whose kernels use it.
"""

from __future__ import annotations

from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def borrow(typingctx, arr):
    """``arr`` (any numba array type) without its owner (meminfo and parent null): see the
    module docstring for when that is safe."""

    def codegen(context, builder, sig, args):
        src = context.make_array(sig.args[0])(context, builder, value=args[0])
        out = context.make_array(sig.return_type)(context, builder)
        out.data = src.data
        out.shape = src.shape
        out.strides = src.strides
        out.itemsize = src.itemsize
        out.nitems = src.nitems
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        out.parent = cgutils.get_null_value(out.parent.type)
        return out._getvalue()

    return arr(arr), codegen


__all__ = ["borrow"]
