"""Geometry of the report's figures: where a slice cell appears in a top view or on the
plane-of-incidence curves, the paper's display remap and the exposure of a view.

Top views are orthographic views of the outgoing hemisphere in ``v`` (pixel = direction
``(v_x, v_y)``, row 0 at ``+y``, seen from above; for a BTDF the lower hemisphere seen through the
surface); each pixel shows the cell its direction falls in, so half-vector slices are drawn with
their true cell geometry. The incident-plane curves use the cells next to the plane
``phi = phi_l, phi_l + 180`` (mean of the two adjacent columns) at the direction of the cell
centre; their abscissa is the signed elevation of ``v``, positive on the side of the mirror (BRDF)
or straight-through (BTDF) direction. Angles in degrees. See ``docs/report.md`` (figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from goniometer.grids.slice_grid import SliceGrid, cell_index
from models._jit import njit

#: top views are exposed so that this fraction of the projected solid angle saturates
SATURATED_FRACTION = 0.005


@njit(cache=True)
def _pixel_cells(param: int, transmission: bool, lx: float, ly: float, lz: float, size: int,
                 n_theta: int, n_phi: int):
    """Cell (i, j) of every pixel of an orthographic top view (row 0 at +y); -1 outside the disk."""
    ii = np.full((size, size), -1, dtype=np.int64)
    jj = np.full((size, size), -1, dtype=np.int64)
    for r in range(size):
        y = 1.0 - (2.0 * r + 1.0) / size
        for c in range(size):
            x = (2.0 * c + 1.0) / size - 1.0
            rr = x * x + y * y
            if rr >= 1.0:
                continue
            z = math.sqrt(1.0 - rr)
            vz = -z if transmission else z
            i, j = cell_index(param, transmission, lx, ly, lz, x, y, vz, n_theta, n_phi)
            ii[r, c] = i
            jj[r, c] = j
    return ii, jj


@dataclass
class PixelMap:
    """Where every top-view pixel reads its value: ``ii``/``jj`` cells, ``ok`` valid pixels,
    ``inside`` the pixels of the disk. A map is sampled many times (the reference, every model,
    several panels each): what every sample needs is worked out once (:attr:`ring`, and the valid
    pixels' positions and cells)."""

    ii: np.ndarray
    jj: np.ndarray
    ok: np.ndarray
    inside: np.ndarray
    size: int

    @cached_property
    def _valid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The flat positions of the valid pixels, and the (row, column) of their cells."""
        return np.flatnonzero(self.ok), self.ii[self.ok], self.jj[self.ok]

    @cached_property
    def ring(self) -> np.ndarray:
        """The disk's outline: its pixels with a 4-neighbour outside it (size, size)."""
        inside = self.inside
        return inside & ~np.pad(inside, 1)[2:, 1:-1] | inside & ~np.pad(inside, 1)[1:-1, 2:] \
            | inside & ~np.pad(inside, 1)[:-2, 1:-1] | inside & ~np.pad(inside, 1)[1:-1, :-2]

    def sample(self, cells: np.ndarray) -> np.ndarray:
        """``cells`` (..., n_theta, n_phi) -> (..., size, size), NaN where invalid."""
        pos, ii, jj = self._valid
        lead = cells.shape[:-2]
        out = np.full(lead + (self.size * self.size,), np.nan)
        out[..., pos] = np.take(cells.reshape(lead + (-1,)), ii * cells.shape[-1] + jj, axis=-1)
        return out.reshape(lead + (self.size, self.size))


def pixel_map(grid: SliceGrid, light: np.ndarray, mask: np.ndarray, size: int) -> PixelMap:
    """The :class:`PixelMap` of a ``size`` x ``size`` top view of ``grid`` lit from ``light``;
    pixels on cells where ``mask`` is False are invalid."""
    ii, jj = _pixel_cells(grid.code, grid.transmission, float(light[0]), float(light[1]), float(light[2]), size,
                          grid.n_theta, grid.n_phi)
    inside = ii >= 0
    ok = inside.copy()
    ok[inside] = mask[ii[inside], jj[inside]]
    return PixelMap(ii, jj, ok, _disk(size), size)


def _disk(size: int) -> np.ndarray:
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    return c[None, :] ** 2 + c[::-1, None] ** 2 < 1.0


def _nearest_columns(centres: np.ndarray, azimuth: float) -> np.ndarray:
    d = np.abs((centres - azimuth + 180.0) % 360.0 - 180.0)
    cols = np.flatnonzero(d <= d.min() + 1e-6)[:2]
    return cols if len(cols) == 2 else np.array([cols[0], cols[0]])


def _cell_direction(grid: SliceGrid, light: np.ndarray, theta_deg: float, azimuth_deg: float) -> np.ndarray | None:
    t, a = math.radians(theta_deg), math.radians(azimuth_deg)
    d = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    if grid.parametrization == "half":
        d = 2.0 * float(light @ d) * d - light
        if d[2] <= 0.0:
            return None
    if grid.transmission:
        d[2] = -d[2]
    return d


def plane_cells(grid: SliceGrid, light: np.ndarray, phi_l_deg: float, mask: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells along the plane of incidence: ``(x_deg, rows, cols)`` sorted by ``x``.

    ``x`` is the signed elevation of the cell-centre direction ``v`` in the plane, positive on
    the side of the mirror / straight-through direction (``phi_v = phi_l + 180``); ``cols`` (n, 2)
    are the two columns next to the plane (values are their mean); masked cells are left out.
    """
    e = np.array([math.cos(math.radians(phi_l_deg)), math.sin(math.radians(phi_l_deg)), 0.0])
    centres, th = grid.phi_centers_deg(), grid.theta_centers_deg()
    pts = []
    for az in (phi_l_deg, phi_l_deg + 180.0):
        cols = _nearest_columns(centres, az % 360.0)
        for i in range(grid.n_theta):
            if not mask[i, cols].all():
                continue
            v = _cell_direction(grid, light, float(th[i]), az)
            if v is None:
                continue
            pts.append((math.degrees(math.atan2(-float(v @ e), abs(float(v[2])))), i, cols[0], cols[1]))
    pts.sort()
    arr = np.array(pts, dtype=float).reshape(-1, 4)
    return arr[:, 0], arr[:, 1].astype(int), arr[:, 2:].astype(int)


def remap(f: np.ndarray) -> np.ndarray:
    """The paper's display remap ``log(1 + sqrt(f))`` (negative values clipped to 0)."""
    return np.log1p(np.sqrt(np.maximum(f, 0.0)))


def unremap(g: np.ndarray | float) -> np.ndarray:
    """The inverse of :func:`remap`: the value ``f = (exp(g) - 1)^2`` drawn at ``g >= 0`` (colour-bar
    ticks in 1/sr)."""
    return np.expm1(np.maximum(g, 0.0)) ** 2


def exposure(g: np.ndarray, omega: np.ndarray, mask: np.ndarray, saturated: float = SATURATED_FRACTION) -> float:
    """The value of ``g`` (n_theta, n_phi) exceeded on only ``saturated`` of the valid projected
    solid angle: a display scale that a sharp peak (tiny solid angle) does not dictate."""
    w = (omega * mask).ravel()
    v = g.ravel()
    if not np.any(w > 0):
        return 1.0
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[order])
    val = float(v[order[min(int(np.searchsorted(cw, (1.0 - saturated) * cw[-1])), v.size - 1)]])
    if val > 0.0:
        return val
    top = float(np.max(v[w > 0]))
    return top if top > 0.0 else 1.0
