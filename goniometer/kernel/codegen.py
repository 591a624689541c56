"""LLVM-level helpers of the lane kernel (``docs/kernel.md``): bit casts between ``float64`` and
``uint64`` (from :mod:`goniometer.bits`; the lane state stores path keys and generator states in
the bits of doubles), a block of doubles on the stack of the calling function, a cache prefetch,
and the hint that lets LLVM use 512-bit vectors in the calling function. None changes a computed
value."""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from goniometer.bits import double_as_uint64 as u64_bits
from goniometer.bits import uint64_as_double as u64_as_double

#: doubles in the block :func:`stack_block` reserves
STACK_BLOCK = 2048


@intrinsic
def stack_block(typingctx):
    """A pointer to :data:`STACK_BLOCK` doubles on the stack of the calling function.

    The event loop copies the stack's table there: LLVM then knows that the per-lane table reads
    (gathers, indexed by each lane's region or interface) cannot alias the lane state it writes,
    which an argument array would not tell it (no vectorisation: "cannot identify array bounds")."""
    sig = types.CPointer(types.float64)()

    def codegen(context, builder, signature, args):
        with builder.goto_entry_block():
            p = builder.alloca(ir.ArrayType(ir.DoubleType(), STACK_BLOCK))
        return builder.bitcast(p, ir.DoubleType().as_pointer())

    return sig, codegen


@intrinsic
def prefer_wide_vectors(typingctx):
    """Mark the calling function ``"prefer-vector-width"="512"``: on CPUs with AVX-512, LLVM
    otherwise keeps to 256-bit vectors (the "prefer-256-bit" tuning of those CPUs). Elsewhere,
    and for the values computed, it changes nothing (IEEE operations give the same results in
    any vector width)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        # llvmlite checks attribute names against a list without key-value attributes
        set.add(builder.function.attributes, '"prefer-vector-width"="512"')
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def prefetch(typingctx, arr, idx):
    """Hint the CPU to fetch the cache line of the 1-D ``arr[idx]`` for writing (``llvm.prefetch``,
    no bounds check)."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = builder.gep(ary.data, [context.cast(builder, args[1], signature.args[1], types.intp)])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = builder.module.declare_intrinsic("llvm.prefetch", [i8p], fnty)
        # rw = 1 (write), locality = 3 (keep in all cache levels), data cache
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


