"""What the integration of a model onto a reference's cells needs that does not depend on the model:
each cell's sub-cell directions and weights (:func:`cell_geometry`) and the cells a grid can
compare (:func:`grid_mask`), computed once per (grid, light direction, sub-cells) and shared by
every model and every material of a process (``docs/models.md`` §3, "Cost").

A grid's sub-cells depend only on its parametrization, resolution and side, the light direction and
``s`` (:meth:`goniometer.grids.slice_grid.SliceGrid.subcells`): every classic material of a database shares
one set per incident direction, every half material one set per incident direction too. The arrays
are the very ones :meth:`~goniometer.grids.slice_grid.SliceGrid.subcells` and
:meth:`~goniometer.grids.slice_grid.SliceGrid.mask` return (same values, same bits), made read-only, so that
a model cannot change what the next one reads. The cache holds at most :data:`CACHE_BYTES` of them,
least recently used first out.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from goniometer.grids.slice_grid import SliceGrid

#: the most the sub-cell cache keeps (bytes): the 7 incident directions of a 90 x 360 grid at
#: 5 x 5 sub-cells take 182 MB (directions 19 MB and weights 6.5 MB per direction)
CACHE_BYTES = 400 * 2**20


@dataclass(frozen=True)
class CellGeometry:
    """The sub-cells of one grid for one light direction: ``v`` (N, 3) unit outgoing directions,
    N = n_theta n_phi s s in the order of :meth:`~goniometer.grids.slice_grid.SliceGrid.subcells` (cell row,
    cell column, sub-cell row, sub-cell column), ``w`` (n_theta, n_phi, s, s) their projected
    solid angles (sr) and ``inv`` (n_theta, n_phi) ``1 / sum(w)`` per cell (0 for a cell of no
    projected solid angle). Read-only."""

    v: np.ndarray
    w: np.ndarray
    inv: np.ndarray

    @property
    def nbytes(self) -> int:
        return self.v.nbytes + self.w.nbytes + self.inv.nbytes


class _Cache:
    """A least-recently-used map bounded by the bytes of its values."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.items: OrderedDict[tuple, object] = OrderedDict()
        self.bytes = 0
        self.lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple, make, size) -> object:
        with self.lock:
            if key in self.items:
                self.items.move_to_end(key)
                self.hits += 1
                return self.items[key]
        value = make()
        with self.lock:
            self.misses += 1
            if key not in self.items:
                self.items[key] = value
                self.bytes += size(value)
                while self.bytes > self.limit and len(self.items) > 1:
                    _, old = self.items.popitem(last=False)
                    self.bytes -= size(old)
            return self.items[key]

    def clear(self) -> None:
        with self.lock:
            self.items.clear()
            self.bytes = 0
            self.hits = 0
            self.misses = 0


_GEOMETRY = _Cache(CACHE_BYTES)
_MASKS = _Cache(64 * 2**20)


def _key(grid: SliceGrid, light: np.ndarray, s: int | None) -> tuple:
    """The light's exact bits enter the key: two lights that differ in the last bit are two keys."""
    return (grid, np.asarray(light, dtype=np.float64).reshape(3).tobytes(), s)


def _read_only(*arrays: np.ndarray) -> None:
    for a in arrays:
        a.setflags(write=False)


def cell_geometry(grid: SliceGrid, light: np.ndarray, s: int = 5) -> CellGeometry:
    """The :class:`CellGeometry` of ``grid`` lit from ``light`` at ``s x s`` sub-cells (computed on
    first use, then shared)."""
    def make() -> CellGeometry:
        v, w = grid.subcells(light, s)
        den = w.sum(axis=(2, 3))
        inv = np.divide(1.0, den, out=np.zeros_like(den), where=den > 0)
        v = v.reshape(-1, 3)
        _read_only(v, w, inv)
        return CellGeometry(v, w, inv)
    return _GEOMETRY.get(_key(grid, light, s), make, lambda g: g.nbytes)


def grid_mask(grid: SliceGrid, light: np.ndarray, s: int | None = None) -> np.ndarray:
    """:meth:`SliceGrid.mask` of ``grid`` for ``light`` (``s=None``: the grid's default sub-cells),
    shared and read-only."""
    def make() -> np.ndarray:
        m = grid.mask(light) if s is None else grid.mask(light, s)
        _read_only(m)
        return m
    return _MASKS.get(_key(grid, light, s), make, lambda m: m.nbytes)


def clear_cache() -> None:
    """Forget every shared geometry and mask (tests; a process that needs the memory back)."""
    _GEOMETRY.clear()
    _MASKS.clear()


def cache_stats() -> dict[str, int]:
    """Hits and misses of the geometry cache and the bytes it holds (benchmarks, tests)."""
    return {"hits": _GEOMETRY.hits, "misses": _GEOMETRY.misses, "bytes": _GEOMETRY.bytes,
            "entries": len(_GEOMETRY.items)}
