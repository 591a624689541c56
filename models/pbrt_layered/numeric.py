"""Arithmetic the ``pbrt-layered`` kernels share."""

from __future__ import annotations

from models._jit import njit


@njit(cache=True, error_model="numpy")
def quotient(a: float, b: float) -> float:
    """``a / b`` as :mod:`goniometer.optics` divides (no exception for ``b = 0``): for optics'
    expressions that the fused steps compute themselves, which keep optics' arithmetic."""
    return a / b
