"""Bit casts between 64-bit floats and integers, as numba intrinsics (an LLVM ``bitcast``: no
computed value changes, and loops using them still vectorise, unlike ``ldexp``/``frexp``).

The lane kernel keeps path keys and generator states in the bits of doubles
(:mod:`goniometer.kernel.codegen`); :mod:`goniometer.optics` reads and builds exponents with them.
"""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic

__all__ = ["double_as_int64", "int64_as_double", "double_as_uint64", "uint64_as_double"]


def _bitcast(source, target, doc: str):
    """An intrinsic ``target(source)`` that reinterprets the 64 bits of its argument."""

    @intrinsic
    def cast(typingctx, x):
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))

        return target(source), codegen

    cast.__doc__ = doc
    return cast


double_as_int64 = _bitcast(types.float64, types.int64, "The int64 whose bits are the float64 ``x``.")
int64_as_double = _bitcast(types.int64, types.float64, "The float64 whose bits are the int64 ``x``.")
double_as_uint64 = _bitcast(types.float64, types.uint64, "The uint64 whose bits are the float64 ``x``.")
uint64_as_double = _bitcast(types.uint64, types.float64, "The float64 whose bits are the uint64 ``x``.")
