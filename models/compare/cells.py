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

Mirror symmetry (``docs/models.md`` §3, "Mirror symmetry"): lit from ``l_y = 0`` exactly (``phi_l =
0``), the cells of a classic or half grid map onto each other under the mirror ``v -> (v_x, -v_y,
v_z)`` (:func:`mirrors`, :func:`mirror_half`); a model that declares the symmetry is evaluated on half
of them and the others take the values of their mirrors (:func:`cell_sums`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from goniometer.grids.slice_grid import SliceGrid

#: the most the sub-cell cache keeps (bytes): the 7 incident directions of a 90 x 360 grid at
#: 5 x 5 sub-cells take 182 MB (directions 19 MB and weights 6.5 MB per direction), and 68 MB more
#: for the half of the directions a mirror-symmetric model is evaluated at (:func:`mirror_half`)
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


@dataclass(frozen=True)
class MirrorHalf:
    """The sub-cells a mirror-symmetric model is evaluated at: ``v`` (n_theta n_eval s s, 3), the
    very directions of :class:`CellGeometry`'s ``v`` in the cell columns ``j < n_eval = ceil(n_phi /
    2)`` (same order), read-only. Column ``n_phi - 1 - j`` (``j < n_phi - n_eval``) is the mirror of
    column ``j`` and, inside it, sub-cell column ``s - 1 - b`` the mirror of ``b``
    (:func:`cell_sums`); an odd ``n_phi``'s middle column is its own mirror and is evaluated."""

    v: np.ndarray
    n_eval: int

    @property
    def nbytes(self) -> int:
        return self.v.nbytes


#: the parametrizations whose cells map onto each other under ``phi -> -phi`` when ``l_y = 0``:
#: classic cells bin ``phi_v``, half cells ``phi_h`` of ``h = normalize(l + v)`` (``v`` mirrored to
#: the upper side first for transmission), and the mirror of ``v`` is the mirror of ``h`` when
#: ``l_y = 0``; both bin the azimuth in ``n_phi`` equal cells from 0, and a half sub-cell's weight
#: depends on ``l.h`` and ``v_z`` only, which the mirror keeps
MIRRORED_PARAMETRIZATIONS = ("classic", "half")


def mirrors(grid: SliceGrid, light: np.ndarray) -> bool:
    """Whether ``grid``'s cells, lit from ``light``, map onto each other under the mirror about the
    plane of incidence: a classic or half grid and a light with ``l_y == 0`` exactly (``phi_l = 0``;
    ``light_direction(theta, 180)`` has ``l_y = sin(pi) sin(theta) != 0`` and is not mirrored)."""
    l = np.asarray(light, dtype=np.float64).reshape(3)
    return grid.parametrization in MIRRORED_PARAMETRIZATIONS and l[1] == 0.0


def mirror_half(grid: SliceGrid, light: np.ndarray, s: int = 5) -> MirrorHalf | None:
    """The :class:`MirrorHalf` of ``grid`` lit from ``light`` at ``s x s`` sub-cells (computed on
    first use, then shared), or None when the cells do not mirror onto each other (:func:`mirrors`)."""
    if not mirrors(grid, light):
        return None

    def make() -> MirrorHalf:
        n_eval = (grid.n_phi + 1) // 2
        v = cell_geometry(grid, light, s).v.reshape(grid.n_theta, grid.n_phi, s, s, 3)
        half = np.ascontiguousarray(v[:, :n_eval]).reshape(-1, 3)
        _read_only(half)
        return MirrorHalf(half, n_eval)
    return _GEOMETRY.get(("mirror",) + _key(grid, light, s), make, lambda h: h.nbytes)


def cell_sums(values: np.ndarray, geo: CellGeometry, half: MirrorHalf | None = None, power: int = 1) -> np.ndarray:
    """``sum_k values_k w_k^power`` over each cell's sub-cells, (C, n_theta, n_phi), of ``values``
    (N, C) at ``geo``'s sub-cells or, with ``half``, at ``half``'s: the evaluated columns with their
    own weights, each mirrored column ``n_phi - 1 - j`` with the values of column ``j`` and its own
    weights, sub-cell column ``s - 1 - b`` against ``b`` (summed in the mirror's sub-cell order)."""
    w = geo.w if power == 1 else geo.w ** power
    nt, nph, s, _ = w.shape
    if half is None:
        return np.einsum("ijabc,ijab->cij", values.reshape(w.shape + (-1,)), w, optimize=True)
    n_eval = half.n_eval
    f = values.reshape((nt, n_eval, s, s, -1))
    out = np.empty((f.shape[-1], nt, nph))
    out[:, :, :n_eval] = np.einsum("ijabc,ijab->cij", f, w[:, :n_eval], optimize=True)
    mirrors_w = w[:, n_eval:][:, ::-1, :, ::-1]          # [i, j, a, b]: the weight of the mirror of (i, j, a, b)
    out[:, :, n_eval:] = np.einsum("ijabc,ijab->cij", f[:, :nph - n_eval], mirrors_w, optimize=True)[:, :, ::-1]
    return out


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
