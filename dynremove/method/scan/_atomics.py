"""Atomic operations on int64 counters for compiled code (numba has none on the CPU).

The scan's row pipeline (``_kernels._scan``) publishes each row's progress with
these: a thread stores how far its row has got (``store_release``), the thread
of the next row reads it (``load_acquire``) before it visits pixels that the
first one may still touch, and rows are claimed with ``fetch_add``. Release and
acquire order the plain stores of the state around them, so what a row wrote
before it published its progress is seen by the row that read it. Each is one
LLVM atomic instruction (``load atomic``, ``store atomic``, ``atomicrmw``).
``cpu_yield`` gives the core away while a thread waits (``sched_yield``), so a
waiting thread never holds the core that the thread it waits for needs.
Without compilation (``NUMBA_DISABLE_JIT=1``) they are the plain Python
operations, on one thread.
"""

import os

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic


def _pointer(context, builder, sig, args):
    aryty = sig.args[0]
    ary = context.make_array(aryty)(context, builder, args[0])
    idx = context.cast(builder, args[1], sig.args[1], types.intp)
    return cgutils.get_item_pointer(context, builder, aryty, ary, [idx], wraparound=False)


def _check(arr, idx):
    return (isinstance(arr, types.Array) and arr.ndim == 1 and arr.dtype == types.int64
            and isinstance(idx, types.Integer))


@intrinsic
def load_acquire(typingctx, arr, idx):
    """arr[idx] of a 1-D int64 array, read with acquire ordering."""
    if not _check(arr, idx):
        return None

    def codegen(context, builder, sig, args):
        return builder.load_atomic(_pointer(context, builder, sig, args), "acquire", 8)
    return types.int64(arr, idx), codegen


@intrinsic
def store_release(typingctx, arr, idx, val):
    """arr[idx] = val (1-D int64 array), written with release ordering."""
    if not _check(arr, idx) or not isinstance(val, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        v = context.cast(builder, args[2], sig.args[2], types.int64)
        builder.store_atomic(v, _pointer(context, builder, sig, args), "release", 8)
        return context.get_dummy_value()
    return types.none(arr, idx, val), codegen


@intrinsic
def fetch_add(typingctx, arr, idx, val):
    """arr[idx] += val atomically (1-D int64 array, sequentially consistent);
    returns the value before."""
    if not _check(arr, idx) or not isinstance(val, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        v = context.cast(builder, args[2], sig.args[2], types.int64)
        return builder.atomic_rmw("add", _pointer(context, builder, sig, args), v, "seq_cst")
    return types.int64(arr, idx, val), codegen


@intrinsic
def cpu_yield(typingctx):
    """Give the core to another runnable thread, if any (POSIX ``sched_yield``)."""
    def codegen(context, builder, sig, args):
        fnty = ir.FunctionType(ir.IntType(32), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "sched_yield")
        builder.call(fn, [])
        return context.get_dummy_value()
    return types.none(), codegen


if numba.config.DISABLE_JIT:  # the same operations in Python (one thread: no race)
    def load_acquire(arr, idx):  # noqa: F811
        return arr[idx]

    def store_release(arr, idx, val):  # noqa: F811
        arr[idx] = val

    def fetch_add(arr, idx, val):  # noqa: F811
        old = arr[idx]
        arr[idx] += val
        return old

    def cpu_yield():  # noqa: F811
        os.sched_yield()
